"""Synthetic captures of deforming sequences, written as a user's capture would be, for ``fit-sequence``.

For every frame ``t`` of a sequence in correspondence (vertices ``(T, V, 3)``, one face list):

- depth: 3 depth cameras on one side of the subject (azimuth -60, 0, +60 degrees, right-handed
  about +Y with 0 on +X: both quadrupeds lie along Z, so the fan faces their +X flank; elevation
  15 degrees, distance 1.9, horizontal field of view 40 degrees, 160 x 120 pixels), each looking
  at the origin. One ray per pixel centre (NumPy, from the
  camera's OpenGL intrinsics and pose) is intersected with the frame's mesh by Mitsuba
  (``scene.ray_intersect``); the hit is moved along the ray by Gaussian noise of sigma 0.0015
  (0.15 % of the bbox diagonal), seeded per frame and camera. The union of the 3 cameras' points
  is ``depth/NNNN.ply`` (x y z only, no normals, no faces). The back of the subject is never seen.
- RGB: 20 cameras on a Fibonacci sphere (``mi_loop.render.cameras.fibonacci_cameras``,
  distance 1.9, horizontal field of view 35 degrees, 128 x 128), 64 spp, ``direct`` integrator,
  the default constant environment, smooth vertex normals, a diffuse per-vertex albedo:
  ``captures.procedural_albedo`` of the frame-0 positions (it moves with the material), the
  sequence's own texture colours, or a texture fine enough for optical flow to follow
  (``spot_fine``, ``fox_fine``): :func:`fine_albedo` of the frame-0 positions, on the mesh split
  twice at its edge midpoints (16 flat triangles per face, the same surface) so that vertex
  colours carry it;
  ``images/NNNN/transforms.json`` + RGBA PNGs.
- ``clean.npz``: the normalised clean vertices ``(T, V, 3)`` and faces (for the evaluation);
  ``meta.json``: normalisation, cameras, noise, seeds, counts, coverage and seconds.

The whole sequence is normalised once, by frame 0: ``V_norm = (V - centre) / scale`` with
``centre`` the frame-0 bbox centre and ``scale`` its diagonal. Then::

    .venv/bin/python bench/capture_sequence.py spot spot_fine fox fox_tex [--frames N] [--out DIR]
    mi-loop fit-sequence DIR/spot/depth/*.ply --images DIR/spot/images -o fit/
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import captures  # noqa: E402

import mi_loop  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
SEQ = REPO.parent / "shared" / "data" / "sequences"
OUT = REPO / "bench" / "results" / "capture_seq"
#: name -> (source file, albedo kind, glTF animation or None)
SEQUENCES = {"spot": (SEQ / "spot_arap_16f.npz", "procedural", None),
             "spot_fine": (SEQ / "spot_arap_16f.npz", "fine", None),
             "fox": (SEQ / "fox_walk_24f.npz", "procedural", None),
             "fox_fine": (SEQ / "fox_walk_24f.npz", "fine", None),
             "fox_tex": (SEQ / "Fox.glb", "texture", "Walk")}
FOX_FRAMES = 24                      # fox_walk_24f.npz: the Walk clip at t = k T / 24, k = 0..23
DEPTH = dict(azimuths=(-60.0, 0.0, 60.0), elevation=15.0, distance=captures.DISTANCE, fov_x_deg=40.0,
             width=160, height=120)
RGB = dict(n=20, distance=captures.DISTANCE, fov_x_deg=captures.FOV, width=128, height=128)
SIGMA, SPP, SEED = 0.0015, captures.SPP, 0
SEEN_RADIUS = 0.01                  # a vertex is "near depth" within this distance of a depth point


# -- cameras and rays ------------------------------------------------------------
def depth_cameras(*, azimuths, elevation, distance, fov_x_deg, width, height, centre=(0.0, 0.0, 0.0)) -> list:
    """Depth cameras at ``distance`` from ``centre``, one per azimuth (degrees about +Y, 0 on +X, 90 on -Z)."""
    from mi_loop.io import Camera
    from mi_loop.render.cameras import look_at

    c = np.asarray(centre, dtype=np.float64)
    el = math.radians(elevation)
    f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
    cams = []
    for az in np.radians(azimuths):
        eye = c + distance * np.array([math.cos(el) * math.cos(az), math.sin(el), -math.cos(el) * math.sin(az)])
        cams.append(Camera(look_at(eye, c), f, f, 0.5 * width, 0.5 * height, width, height))
    return cams


def pixel_rays(camera):
    """Rays through the pixel centres: origin ``(3,)``, unit directions ``(h * w, 3)`` and pixels ``(h * w, 2)``.

    Row-major (``y`` then ``x``); pixel ``(x, y)`` has centre ``(x + 0.5, y + 0.5)``, and the
    OpenGL camera looks down its -Z with +Y up, so the direction in camera axes is
    ``((x + 0.5 - cx) / fx, -(y + 0.5 - cy) / fy, -1)``.
    """
    y, x = np.mgrid[0:camera.height, 0:camera.width]
    pixels = np.stack([x.ravel() + 0.5, y.ravel() + 0.5], axis=1)
    d = np.stack([(pixels[:, 0] - camera.cx) / camera.fx, -(pixels[:, 1] - camera.cy) / camera.fy,
                  -np.ones(len(pixels))], axis=1)
    d = d @ camera.c2w[:3, :3].T
    return camera.c2w[:3, 3].copy(), d / np.linalg.norm(d, axis=1, keepdims=True), pixels


def ray_scene(V, F):
    """A Mitsuba scene holding only the triangle mesh (for ``ray_intersect``)."""
    import mitsuba as mi

    from mi_loop.render.plugin import plain_mesh

    return mi.load_dict({"type": "scene", "mesh": plain_mesh(V, F)})


def hit_distances(scene, origin, directions) -> np.ndarray:
    """Ray parameter of the first hit per ray, ``(k,)`` float64, ``inf`` on a miss."""
    import mitsuba as mi

    o = np.broadcast_to(np.asarray(origin, dtype=np.float32), directions.shape)
    d = np.asarray(directions, dtype=np.float32)
    ray = mi.Ray3f(mi.Point3f(*(mi.Float(np.ascontiguousarray(o[:, i])) for i in range(3))),
                   mi.Vector3f(*(mi.Float(np.ascontiguousarray(d[:, i])) for i in range(3))))
    si = scene.ray_intersect(ray)
    t = np.asarray(si.t, dtype=np.float64)
    return np.where(np.asarray(si.is_valid(), dtype=bool), t, np.inf)


def depth_scan(scene, camera, sigma: float, rng):
    """One depth image as points: ``(P (k, 3), pixels (k, 2))``, the hits moved by ``N(0, sigma)`` along the ray."""
    origin, d, pixels = pixel_rays(camera)
    t = hit_distances(scene, origin, d)
    hit = np.isfinite(t)
    t = t[hit] + sigma * rng.standard_normal(int(hit.sum()))
    return origin + t[:, None] * d[hit], pixels[hit]


# -- coverage --------------------------------------------------------------------
def frame_margin(cameras, Vs) -> float:
    """Smallest distance in pixels from any vertex of any frame to the image border (negative: out of frame)."""
    from mi_loop.render.cameras import project

    P = np.asarray(Vs).reshape(-1, 3)
    margins = []
    for cam in cameras:
        uv = project(cam, P)
        margins.append(np.nanmin(np.minimum(np.minimum(uv[:, 0], cam.width - uv[:, 0]),
                                            np.minimum(uv[:, 1], cam.height - uv[:, 1]))))
    return float(min(margins))


def seen_area(scene, V, F, cameras, n_samples: int = 20_000, seed: int = 0) -> float:
    """Share of the surface area that some depth camera sees (area samples, unoccluded and in frame)."""
    from mi_loop.mesh.sampling import sample_surface
    from mi_loop.render.cameras import project

    P, _, _ = sample_surface(V, F, n_samples, seed)
    seen = np.zeros(len(P), bool)
    for cam in cameras:
        o = cam.c2w[:3, 3]
        dist = np.linalg.norm(P - o, axis=1)
        t = hit_distances(scene, o, (P - o) / dist[:, None])
        uv = project(cam, P)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        seen |= inside & (t > dist - 1e-4)
    return float(seen.mean())


def near_depth(V, points, radius: float = SEEN_RADIUS) -> float:
    """Share of the vertices ``V`` within ``radius`` of some depth point."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(V, distance_upper_bound=radius)
    return float(np.isfinite(d).mean())


def fine_albedo(V) -> np.ndarray:
    """Per-vertex RGB in [0.1, 0.9]: three crossed waves of 6-13 cycles per bbox diagonal (a period of 8-18
    pixels in the photos), the detail a real surface's texture gives optical flow to follow."""
    f = 2 * np.pi * np.array([[9.0, 4.0, -6.0], [-5.0, 11.0, 3.0], [4.0, -3.0, 12.0]])
    waves = np.sin(V @ f.T + np.array([0.3, 1.7, 3.1]))
    grey = 0.5 + 0.4 * np.tanh(1.5 * waves.sum(axis=1, keepdims=True) / 3.0)
    return np.clip(grey * np.array([1.0, 0.85, 0.7]) + 0.08 * waves, 0.1, 0.9)


def midpoint_split(V, F, levels: int = 2):
    """Split every triangle into 4 at its edge midpoints, ``levels`` times: ``(V, F, W)``, ``W`` the sparse
    ``(new, old)`` matrix of the new vertices as averages of the old (apply it to every frame).
    ``mi_loop.datasets._split_midpoints`` makes the same triangles with other first corners, which changes
    the renders' sampling: the captures measured in BENCHMARKS.md were written with this order."""
    import scipy.sparse as sp

    from mi_loop.mesh.geometry import edges

    W = sp.identity(len(V), format="csr")
    for _ in range(levels):
        n, E = W.shape[0], edges(F)
        key = {(int(a), int(b)): n + i for i, (a, b) in enumerate(E)}
        rows = np.repeat(np.arange(n, n + len(E)), 2)
        mid = sp.csr_matrix((np.full(2 * len(E), 0.5), (rows, E.ravel())), shape=(n + len(E), n))
        W = (sp.vstack([sp.identity(n, format="csr"), mid[n:]]) @ W).tocsr()
        m = np.array([[key[tuple(sorted((int(f[i]), int(f[(i + 1) % 3]))))] for i in range(3)] for f in F])
        F = np.concatenate([np.stack([F[:, 0], m[:, 0], m[:, 2]], 1), np.stack([F[:, 1], m[:, 1], m[:, 0]], 1),
                            np.stack([F[:, 2], m[:, 2], m[:, 1]], 1), m])
    return W @ V, F, W


# -- writing ---------------------------------------------------------------------
def write_frames(out: Path, Vs, F, colors, *, depth_cams, rgb_cams, sigma: float = SIGMA, spp: int = SPP,
                 seed: int = SEED, log=print, split=None) -> list:
    """Write the depth clouds and RGB captures of normalised frames ``Vs (T, V, 3)``; return per-frame stats.

    Depth noise of frame ``t``, camera ``k`` is drawn from ``default_rng([seed, t, k])``; the RGB
    render of frame ``t``, view ``k`` uses sampler seed ``seed + t * len(rgb_cams) + k``. ``split``,
    ``(W, F_split)`` of :func:`midpoint_split`: the photos show the split mesh (``colors`` are per split
    vertex), shaded with the frame's smooth normals carried by ``W``.
    """
    from mi_loop.io import write_capture, write_ply
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.mesh.geometry import vertex_normals
    from mi_loop.render.captures import render_views

    (out / "depth").mkdir(parents=True, exist_ok=True)
    stats = []
    for t, V in enumerate(Vs):
        start = time.perf_counter()
        scene = ray_scene(V, F)
        scans = [depth_scan(scene, cam, sigma, np.random.default_rng([seed, t, k]))[0]
                 for k, cam in enumerate(depth_cams)]
        points = np.concatenate(scans)
        write_ply(out / "depth" / f"{t:04d}.ply", points, np.zeros((0, 3), np.int64))
        shown, faces, normals = V, F, vertex_normals(V, F)
        if split is not None:
            shown, faces, normals = split[0] @ V, split[1], split[0] @ normals
            normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        views = render_views(shown, faces, rgb_cams, [dict(e) for e in DEFAULT_EMITTERS], colors=colors,
                             normals=normals, spp=spp, seed=seed + t * len(rgb_cams))
        write_capture(out / "images" / f"{t:04d}", views)
        stats.append({"frame": t, "points": [len(s) for s in scans], "n_points": len(points),
                      "seen_area": seen_area(scene, V, F, depth_cams, seed=t),
                      "near_depth_vertices": near_depth(V, points),
                      "mask_coverage": float(np.mean([v.mask.mean() for v in views])),
                      "seconds": time.perf_counter() - start})
        s = stats[-1]
        log(f"  frame {t:04d}: {s['n_points']} depth points {s['points']}, seen area {s['seen_area']:.3f}, "
            f"mask {s['mask_coverage']:.3f}, {s['seconds']:.1f} s")
    return stats


def load_sequence(name: str, n_frames: int | None = None):
    """The raw sequence: ``(Vs (T, V, 3) float64, F (m, 3) int, colors (V, 3) linear or None)``."""
    path, albedo, animation = SEQUENCES[name]
    if animation is None:
        with np.load(path) as data:
            Vs, F, colors = np.asarray(data["vertices"], np.float64), np.asarray(data["faces"]), None
    else:
        from mi_loop.io.animation import bake_animation

        baked = bake_animation(path, animation, frames=FOX_FRAMES)
        Vs, F, colors = np.asarray(baked.vertices, np.float64), np.asarray(baked.faces), baked.colors
        if albedo == "texture" and colors is None:
            raise RuntimeError(f"capture_sequence: '{name}': bake_animation('{path.name}') gave no texture colours")
    return Vs[:n_frames], F, colors


def normalise(Vs):
    """Centre at the frame-0 bbox centre, scale the frame-0 bbox diagonal to 1: ``(Vs, centre, scale)``."""
    lo, hi = Vs[0].min(axis=0), Vs[0].max(axis=0)
    centre, scale = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    return (Vs - centre) / scale, centre, scale


def _clear_frames(directory: Path) -> None:
    """Remove the frame files of an earlier run (a shorter run must not leave stale frames behind)."""
    import shutil

    for ply in directory.glob("depth/[0-9][0-9][0-9][0-9].ply"):
        ply.unlink()
    for frame in directory.glob("images/[0-9][0-9][0-9][0-9]"):
        if (frame / "transforms.json").is_file():
            shutil.rmtree(frame)


def _camera_json(cam, **extra) -> dict:
    return {**extra, "c2w": cam.c2w.tolist(), "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
            "width": cam.width, "height": cam.height}


def write_sequence_capture(name: str, out: Path = OUT, n_frames: int | None = None, log=print,
                           rgb_res: int = RGB["width"]) -> Path:
    """Write the simulated capture of sequence ``name`` to ``out/name``; return that directory.

    ``rgb_res``: width and height of the photos (the field of view stays).
    """
    from mi_loop.render.cameras import fibonacci_cameras

    start = time.perf_counter()
    if name not in SEQUENCES:
        raise ValueError(f"write_sequence_capture(): expected one of {sorted(SEQUENCES)}, got '{name}'")
    Vs, F, colors = load_sequence(name, n_frames)
    Vs, centre, scale = normalise(Vs)
    split = None
    if SEQUENCES[name][1] == "fine":
        _, F_split, W = midpoint_split(Vs[0], F)
        split, colors = (W, F_split), fine_albedo(W @ Vs[0])
    elif colors is None:
        colors = captures.procedural_albedo(Vs[0])
    depth_cams = depth_cameras(**DEPTH)
    rgb_cams = fibonacci_cameras(RGB["n"], [0, 0, 0], RGB["distance"], fov_x_deg=RGB["fov_x_deg"],
                                 width=rgb_res, height=rgb_res)
    margins = {"depth": frame_margin(depth_cams, Vs), "rgb": frame_margin(rgb_cams, Vs)}
    log(f"{name}: {len(Vs)} frames, {Vs.shape[1]} vertices, {len(F)} faces; smallest margin to the image "
        f"border {margins['depth']:.1f} px (depth), {margins['rgb']:.1f} px (RGB)")
    if min(margins.values()) < 0:
        log(f"{name}: WARNING: the subject leaves the frame of some camera")
    directory = Path(out) / name
    directory.mkdir(parents=True, exist_ok=True)
    _clear_frames(directory)
    np.savez_compressed(directory / "clean.npz", vertices=Vs, faces=F)
    stats = write_frames(directory, Vs, F, colors, depth_cams=depth_cams, rgb_cams=rgb_cams, log=log, split=split)
    path, albedo, animation = SEQUENCES[name]
    meta = {
        "sequence": name, "source": str(path), "animation": animation,
        "fps": FOX_FRAMES / 0.70833331 if animation else None, "frames": len(Vs), "vertices": int(Vs.shape[1]),
        "faces": len(F),
        "normalisation": {"rule": "V_norm = (V - centre) / scale (frame-0 bbox centre and diagonal)",
                          "centre": centre.tolist(), "scale": scale},
        "depth": {**DEPTH, "noise": "Gaussian along the ray", "sigma": SIGMA,
                  "seed": "default_rng([seed, frame, camera])", "normals": False,
                  "cameras": [_camera_json(c, azimuth=a) for c, a in zip(depth_cams, DEPTH["azimuths"])]},
        "rgb": {**RGB, "width": rgb_res, "height": rgb_res,
                "spp": SPP, "integrator": "direct", "emitters": "DEFAULT_EMITTERS (constant, radiance 1)",
                "albedo": albedo, "seed": "seed + frame * n + view"},
        "seed": SEED, "margin_px": margins, "seen_radius": SEEN_RADIUS, "per_frame": stats,
        "seconds": time.perf_counter() - start,
    }
    (directory / "meta.json").write_text(json.dumps(meta, indent=1))
    counts = [s["n_points"] for s in stats]
    log(f"{directory}: depth points per frame {min(counts)}-{max(counts)}, seen area "
        f"{np.mean([s['seen_area'] for s in stats]):.3f}, mask coverage "
        f"{np.mean([s['mask_coverage'] for s in stats]):.3f} ({meta['seconds']:.1f} s)")
    return directory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequences", nargs="+", choices=sorted(SEQUENCES))
    parser.add_argument("--frames", type=int, default=None, help="only the first N frames")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--rgb-res", type=int, default=RGB["width"], help="photo width and height (default 128)")
    args = parser.parse_args()
    mi_loop.set_variant()
    failed = []
    for name in args.sequences:
        try:
            write_sequence_capture(name, args.out, args.frames, rgb_res=args.rgb_res)
        except RuntimeError as exc:
            print(exc, file=sys.stderr)
            failed.append(name)
    if failed:
        sys.exit(f"capture_sequence: not written: {' '.join(failed)}")


if __name__ == "__main__":
    main()
