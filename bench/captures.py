"""Synthetic captures of the benchmark targets, written as a user's capture would be (transforms.json + RGBA PNGs).

Each target mesh is centred at the origin and scaled to a bounding-box diagonal of 1, then
photographed by 16 cameras on a Fibonacci sphere (``mi_loop.render.cameras.fibonacci_cameras``,
distance 1.9, horizontal field of view 35 degrees: the bounding sphere fills about 90 % of the
frame), 256 x 256 pixels, 64 spp, Mitsuba's ``direct`` integrator, under the default capture
lighting (uniform white environment, radiance 1), with smooth (area-weighted) vertex normals and
a diffuse BSDF: grey 0.5 (``grey``) or a smooth procedural per-vertex albedo (``tex``):
``0.5 + 0.35 sin(2 pi f_c . p + phi_c)`` per channel, f_c about 1.5 cycles per diagonal.

    .venv/bin/python bench/captures.py bunny armadillo spot --variants grey tex    # -> bench/results/captures/
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import mi_loop

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
TARGETS = {"bunny": DATA / "multiview" / "bunny.obj", "armadillo": DATA / "multiview" / "armadillo.obj",
           "lucy": DATA / "multiview" / "lucy.obj", "horse": DATA / "multiview" / "horse.obj",
           "spot": DATA / "static" / "spot.obj"}
OUT = REPO / "bench" / "results" / "captures"
VIEWS, RES, SPP, DISTANCE, FOV = 16, 256, 64, 1.9, 35.0
MI_LOOP = Path(sys.executable).with_name("mi-loop")


def normalised_target(name: str):
    """The target mesh centred at the origin with bbox diagonal 1: ``(V, F)``."""
    from mi_loop import io

    V, F = io.read_mesh(TARGETS[name])
    lo, hi = V.min(axis=0), V.max(axis=0)
    return (V - 0.5 * (lo + hi)) / np.linalg.norm(hi - lo), F


def procedural_albedo(V) -> np.ndarray:
    """Smooth per-vertex RGB in [0.15, 0.85] (about 1.5 cycles per bbox diagonal)."""
    f = 2 * np.pi * np.array([[1.5, 0.4, -0.6], [-0.5, 1.4, 0.7], [0.6, -0.8, 1.3]])
    phase = np.array([0.3, 1.7, 3.1])
    return 0.5 + 0.35 * np.sin(V @ f.T + phase)


def make_capture(name: str, variant: str, out: Path = OUT, *, views: int = VIEWS, res: int = RES,
                 spp: int = SPP) -> Path:
    """Render and write one capture; return its transforms.json."""
    from mi_loop.io.capture import write_capture
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.mesh.geometry import vertex_normals
    from mi_loop.render.cameras import fibonacci_cameras
    from mi_loop.render.captures import render_views

    V, F = normalised_target(name)
    cameras = fibonacci_cameras(views, [0, 0, 0], DISTANCE, fov_x_deg=FOV, width=res, height=res)
    colors = procedural_albedo(V) if variant == "tex" else None
    shots = render_views(V, F, cameras, [dict(e) for e in DEFAULT_EMITTERS], colors=colors,
                         normals=vertex_normals(V, F), spp=spp)
    return write_capture(out / f"{name}_{variant}", shots)


def fit_and_measure(capture: Path, out: Path, name: str, flags: list, n_samples: int = 30_000) -> dict:
    """Run ``mi-loop fit-images CAPTURE -o OUT --quiet FLAGS`` as a user does and measure the fit against the
    normalised target ``name``: ``command``, ``wall_s``, ``report`` (report.json), ``V`` (control points),
    ``mean`` and ``rms`` (two-sided, of the level-3 limit surface, ``n_samples`` per side, seed 0)."""
    from mi_loop import io
    from mi_loop.metrics import two_sided
    from mi_loop.subdiv.masks import limit_mesh

    cmd = [str(MI_LOOP), "fit-images", str(capture), "-o", str(out), "--quiet", *flags]
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    V, F = io.read_mesh(out / "control.ply")
    P, F_lim, _ = limit_mesh(V, F, 3)
    m = two_sided(P, F_lim, *normalised_target(name), n_samples=n_samples, seed=0)
    return {"command": " ".join(cmd[1:]), "wall_s": wall, "report": json.loads((out / "report.json").read_text()),
            "V": V, "mean": m["mean"], "rms": m["rms"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("targets", nargs="+", choices=sorted(TARGETS))
    parser.add_argument("--variants", nargs="+", choices=["grey", "tex"], default=["grey", "tex"])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    mi_loop.set_variant()
    for name in args.targets:
        for variant in args.variants:
            t = time.perf_counter()
            path = make_capture(name, variant, args.out)
            print(f"{path} ({time.perf_counter() - t:.1f} s)")


if __name__ == "__main__":
    main()
