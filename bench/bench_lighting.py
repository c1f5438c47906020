"""Photos under lighting nobody states: a glossy target under a sky and a sun, fitted with the lighting estimated.

The capture (``glossy_capture``): a benchmark target of ``bench/captures.py`` (centred,
bbox diagonal 1, its smooth procedural albedo), Mitsuba's ``principled`` BSDF (the albedo as
its base colour, roughness 0.25, specular 0.6: a highlight on every view), lit by an
environment map (a procedural sky: blue above, warm ground, brighter towards the sun) plus
a ``directional`` sun, 16 cameras on a Fibonacci sphere at 256^2, 64 spp, ``path`` depth 3,
written as transforms.json with the true lights as a Mitsuba XML of emitters (the masks from
the alpha of a plain render of the same cameras: the path integrator's alpha is 1 wherever
the sky is seen).

Each setting is ``mi-loop fit-images CAPTURE -o OUT`` as a user runs it, with:

- ``true``: ``--emitters lights.xml`` (the true sky and sun; the fit's surface is diffuse);
- ``uniform``: no flags (a uniform white light, the default before lighting estimation);
- ``sh``: ``--lighting sh`` (spherical-harmonic lighting and per-photo gains estimated);
- ``sh-highlights``: ``--lighting sh --highlights 1.5``.

Metric: two-sided mean and RMS distance to the normalised target (30,000 samples per side,
seed 0) of the level-3 limit surface; the fit's seconds. ``relief.png``: each fit's limit
surface rendered grey under a light from the side (``render_geometry``), from two of the
capture's cameras, below the photos: relief in the geometry shows there, relief painted into
the albedo does not.

    .venv/bin/python bench/bench_lighting.py bunny --settings true uniform sh sh-highlights \
        --json bench/results/lighting.jsonl [--fit-args "--iterations 200"]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import captures  # noqa: E402

import mi_loop  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "bench" / "results" / "lighting"
SETTINGS = {"true": ["--emitters", "{lights}"], "uniform": [], "sh": ["--lighting", "sh"],
            "sh-highlights": ["--lighting", "sh", "--highlights", "1.5"]}
SUN = np.array([0.5, 0.75, 0.45]) / np.linalg.norm([0.5, 0.75, 0.45])


def sky(width: int = 64) -> np.ndarray:
    """An equirectangular sky (Mitsuba's envmap layout, +y up): blue above, warm ground, a glow towards the sun."""
    h = width // 2
    theta = (np.arange(h) + 0.5) / h * np.pi                          # from +y down
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    T, P = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], axis=-1)   # Mitsuba's envmap frame
    up = np.clip(d[..., 1], -1, 1)[..., None]
    blue, ground = np.array([0.35, 0.5, 0.8]), np.array([0.35, 0.28, 0.2])
    glow = 0.6 * np.clip(d @ SUN, 0, 1)[..., None] ** 8
    return np.where(up > 0, blue * (0.6 + 0.4 * up), ground * (0.8 + 0.2 * up)) + glow


def glossy_capture(name: str, out: Path, *, views: int = 16, res: int = 256, spp: int = 64) -> Path:
    """Render and write the capture and its lights; return its transforms.json."""
    import mitsuba as mi

    from mi_loop.io.capture import View, write_capture
    from mi_loop.io.emitters import read_emitters
    from mi_loop.mesh.geometry import vertex_normals
    from mi_loop.render.cameras import fibonacci_cameras
    from mi_loop.render.captures import camera_scene, render_views
    from mi_loop.render.plugin import COLOR_ATTRIBUTE, plain_mesh

    V, F = captures.normalised_target(name)
    out.mkdir(parents=True, exist_ok=True)
    mi.Bitmap(sky().astype(np.float32)).write(str(out / "sky.exr"))
    sun = [float(v) for v in SUN]
    (out / "lights.xml").write_text(
        '<scene version="3.0.0">\n'
        '    <emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>\n'
        f'    <emitter type="directional"><vector name="direction" x="{-sun[0]}" y="{-sun[1]}" z="{-sun[2]}"/>\n'
        '        <rgb name="irradiance" value="2.5, 2.3, 2.0"/></emitter>\n'
        '</scene>\n')
    bsdf = mi.load_dict({"type": "principled", "roughness": 0.25, "specular": 0.6,
                         "base_color": {"type": "mesh_attribute", "name": COLOR_ATTRIBUTE}})
    mesh = plain_mesh(V, F, normals=vertex_normals(V, F), bsdf=bsdf, colors=captures.procedural_albedo(V))
    cameras = fibonacci_cameras(views, [0, 0, 0], captures.DISTANCE, fov_x_deg=captures.FOV, width=res, height=res)
    scene = camera_scene(mesh, cameras, read_emitters(out / "lights.xml"),
                         integrator={"type": "path", "max_depth": 3}, spp=spp, alpha=True)
    # the masks: the alpha of a plain render (the path integrator's alpha is 1 wherever the sky is seen)
    masks = [v.mask for v in render_views(V, F, cameras, [{"type": "constant"}], spp=spp)]
    shots = []
    for k, (camera, mask) in enumerate(zip(cameras, masks)):
        image = np.asarray(mi.render(scene, spp=spp, seed=k, sensor=k), dtype=np.float32)
        shots.append(View(camera=camera, rgb=np.clip(image[..., :3], 0, 1), mask=mask, name=f"view_{k:03d}"))
    return write_capture(out / "capture", shots)


def run(capture: Path, out: Path, name: str, setting: str, extra: list) -> dict:
    flags = [f.format(lights=capture.parent.parent / "lights.xml") for f in SETTINGS[setting]]
    fit = captures.fit_and_measure(capture, out, name, flags + extra)
    return {"target": name, "setting": setting, "mean": fit["mean"], "rms": fit["rms"], "wall_s": fit["wall_s"],
            "fit_s": fit["report"]["timings_s"]["fit"], "command": fit["command"]}


def relief(capture: Path, fits: dict, path: Path, shown=(0, 5)) -> None:
    """Photos beside grey renders of each fit under a light from the side (module docstring)."""
    from mi_loop import io
    from mi_loop.io.capture import read_capture
    from mi_loop.io.srgb import linear_to_srgb
    from mi_loop.render.captures import render_geometry
    from mi_loop.subdiv.masks import limit_mesh

    views = [read_capture(capture).views[k] for k in shown]
    rows = [[linear_to_srgb(v.rgb) for v in views]]
    for out in fits.values():
        V, F = io.read_mesh(out / "control.ply")
        P, F_lim, N = limit_mesh(V, F, 3)
        rows.append([linear_to_srgb(im) for im in render_geometry(P, F_lim, N, [v.camera for v in views])])
    io.write_png(path, np.concatenate([np.concatenate(r, axis=1) for r in rows], axis=0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("target", choices=sorted(captures.TARGETS))
    parser.add_argument("--settings", nargs="+", choices=sorted(SETTINGS), default=list(SETTINGS))
    parser.add_argument("--json", type=Path, help="append one JSON line per run")
    parser.add_argument("--fit-args", default="", help="extra fit-images flags, one string")
    parser.add_argument("--relief-only", action="store_true", help="only redraw relief.png from the fits on disk")
    args = parser.parse_args()
    mi_loop.set_variant()
    base = OUT / args.target
    capture = base / "capture" / "transforms.json"
    if not capture.is_file():
        t = time.perf_counter()
        capture = glossy_capture(args.target, base)
        print(f"{capture} ({time.perf_counter() - t:.0f} s)", flush=True)
    fits = {}
    for setting in args.settings:
        fits[setting] = base / setting
        if args.relief_only:
            continue
        row = run(capture, fits[setting], args.target, setting, args.fit_args.split())
        print(f"{setting:14s} mean {row['mean']:.5f} rms {row['rms']:.5f} fit {row['fit_s']:.0f} s", flush=True)
        if args.json:
            with args.json.open("a") as f:
                f.write(json.dumps(row) + "\n")
    relief(capture, fits, base / "relief.png")
    print(base / "relief.png")


if __name__ == "__main__":
    main()
