"""How well the optical flow between a camera's photos of consecutive frames follows the material.

For the simulated captures of ``bench/capture_sequence.py`` (their ``clean.npz`` holds the clean
frames in correspondence), every clean vertex seen by a photo at frames ``t-1`` and ``t`` (in front
in a z-buffer of the clean mesh at both) projects to a pixel at each: the true flow. The flow
computed between the two photos, read there, is kept as ``flow_correspondences`` keeps it
(foreground 2 pixels inside both masks, forward and backward flows agreeing within 1 pixel), and its
error against the true flow is reported, with the true motion of the kept vertices, for:

- ``optical_flow`` (what ``fit-sequence`` uses: DIS, medium preset, refined to full resolution);
- DIS's medium preset alone (finest scale 1, the flow before 2026-12-07).

Usage::

    .venv/bin/python bench/capture_sequence.py spot spot_fine
    PYTHONPATH=. .venv/bin/python bench/bench_flow.py spot spot_fine --frames 1:6
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CAPTURES = ROOT / "bench" / "results" / "capture_seq"


def dense(V, F, k: int = 6):
    """Points on every triangle (barycentric steps of ``1/k``): the clean surface for the z-buffer."""
    b = np.array([(i, j, k - i - j) for i in range(k + 1) for j in range(k + 1 - i)]) / k
    return np.einsum("kb,fbd->fkd", b, V[F]).reshape(-1, 3)


def medium(a, b):
    import cv2

    return cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(a, b, None)


def measure(root: Path, frames) -> None:
    from scipy.ndimage import binary_erosion

    from mi_loop.fitting.flow import _bilinear, _grey, _in_front, optical_flow
    from mi_loop.io.capture import read_capture
    from mi_loop.render.cameras import project

    with np.load(root / "clean.npz") as clean:
        Vs, F = clean["vertices"], clean["faces"]
    methods = {"optical_flow (full resolution)": lambda a, b: optical_flow(a.rgb, b.rgb),
               "DIS medium preset alone": lambda a, b: medium(_grey(a.rgb), _grey(b.rgb))}
    errors, kept, seconds = {k: [] for k in methods}, {k: [] for k in methods}, {k: 0.0 for k in methods}
    motion = []
    for t in frames:
        before = list(read_capture(root / "images" / f"{t - 1:04d}" / "transforms.json").views)
        after = list(read_capture(root / "images" / f"{t:04d}" / "transforms.json").views)
        seen0, seen1 = dense(Vs[t - 1], F), dense(Vs[t], F)
        for a, b in zip(before, after):
            cam = a.camera
            ok = _in_front(cam, Vs[t - 1], seen0, 0.003) & _in_front(cam, Vs[t], seen1, 0.003)
            p = project(cam, Vs[t - 1])[ok]
            true = project(cam, Vs[t])[ok] - p
            fore = binary_erosion(a.mask >= 0.5, iterations=2) & binary_erosion(b.mask >= 0.5, iterations=2)
            motion.append(np.linalg.norm(true, axis=1))
            for name, flow in methods.items():
                start = time.perf_counter()
                fw, bw = flow(a, b), flow(b, a)
                seconds[name] += time.perf_counter() - start
                u = _bilinear(fw, p)
                q = p + u
                px = np.clip(p.astype(np.int64), 0, [cam.width - 1, cam.height - 1])
                qx = np.clip(np.nan_to_num(q).astype(np.int64), 0, [cam.width - 1, cam.height - 1])
                keep = (fore[px[:, 1], px[:, 0]] & fore[qx[:, 1], qx[:, 0]]
                        & (np.linalg.norm(u + _bilinear(bw, q), axis=1) <= 1.0))
                errors[name].append(np.linalg.norm(u - true, axis=1)[keep])
                kept[name].append(keep)
    moved = np.concatenate(motion)
    for name in methods:
        e, k = np.concatenate(errors[name]), np.concatenate(kept[name])
        print(f"| {root.name} | {name} | {100 * k.mean():.0f} % | {np.median(e):.3f} / {e.mean():.3f} / "
              f"{np.quantile(e, 0.9):.3f} | {np.median(moved[k]):.3f} / {moved[k].mean():.3f} | "
              f"{1000 * seconds[name] / (2 * len(errors[name])):.0f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("captures", nargs="+", help="capture names under --root (capture_sequence.py's)")
    ap.add_argument("--root", type=Path, default=CAPTURES)
    ap.add_argument("--frames", default="1:6", help="START:STOP of the frames t (flow from t-1 to t)")
    args = ap.parse_args()
    start, stop = (int(v) for v in args.frames.split(":"))
    print(f"frames {start}-{stop - 1}, {os.cpu_count()} cores; pixels\n")
    print("| capture | flow | kept | error median / mean / p90 | true motion of the kept, median / mean | "
          "ms per flow |")
    print("|---|---|---|---|---|---|")
    for name in args.captures:
        measure(args.root / name, range(start, stop))


if __name__ == "__main__":
    main()
