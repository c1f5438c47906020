"""How well the optical flow between a camera's photos of consecutive frames follows the material.

For the simulated captures of ``bench/capture_sequence.py`` (their ``clean.npz`` holds the clean
frames in correspondence), the clean vertices at frame ``t-1`` go through
:func:`mi_loop.fitting.flow.flow_correspondences` with the photos of ``t-1`` and ``t``, as the limit
samples of a fit do in ``fit-sequence``: those a photo sees (facing it, in front in a z-buffer of
the clean surface) and whose flow it keeps (2 pixels inside both masks, forward and backward flows
agreeing within 1 pixel, ``--consistency``) get a target pixel. Each target is compared with the vertex's projection
at frame ``t``, the true flow, and the error is reported with the true motion of the kept vertices,
for:

- ``optical_flow`` (what ``fit-sequence`` uses: DIS, medium preset, refined to full resolution);
- DIS's medium preset alone (finest scale 1, the flow before 2026-12-07).

``--gap K`` measures the flow from frame ``t-K`` to ``t`` instead, one of those ``fit-sequence
--track-key`` adds to the coarse stage (gaps 2, 4 and 8 by default).

Usage::

    .venv/bin/python bench/capture_sequence.py spot spot_fine
    PYTHONPATH=. .venv/bin/python bench/bench_flow.py spot spot_fine --frames 1:6
    PYTHONPATH=. .venv/bin/python bench/bench_flow.py spot_fine fox_fine --frames 4:12 --gap 4
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from capture_sequence import midpoint_split  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CAPTURES = ROOT / "bench" / "results" / "capture_seq"


def medium(rgb0, rgb1):
    """DIS's medium preset alone, on the grey images ``optical_flow`` uses."""
    import cv2

    from mi_loop.fitting.flow import _grey

    return cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(_grey(rgb0), _grey(rgb1), None)


def measure(root: Path, frames, consistency: float = 1.0, gap: int = 1) -> None:
    from mi_loop.fitting import flow
    from mi_loop.io.capture import read_capture
    from mi_loop.mesh.geometry import vertex_normals

    with np.load(root / "clean.npz") as clean:
        Vs, F = clean["vertices"], clean["faces"]
    methods = {"optical_flow (full resolution)": flow.optical_flow, "DIS medium preset alone": medium}
    errors, motion, shares, seconds = ({k: [] for k in methods} for _ in range(4))
    for t in frames:
        before = list(read_capture(root / "images" / f"{t - gap:04d}" / "transforms.json").views)
        after = list(read_capture(root / "images" / f"{t:04d}" / "transforms.json").views)
        V, N, surface = Vs[t - gap], vertex_normals(Vs[t - gap], F), midpoint_split(Vs[t - gap], F)[0]
        for name, method in methods.items():
            kept = flow.optical_flow
            flow.optical_flow = method                         # what flow_correspondences calls
            try:
                start = time.perf_counter()
                corr = flow.flow_correspondences(before, after, V, N, surface, consistency=consistency)
                seconds[name].append(time.perf_counter() - start)
            finally:
                flow.optical_flow = kept
            p0, p1 = project_all(corr, V), project_all(corr, Vs[t])
            errors[name].append(np.linalg.norm(corr.target - p1, axis=1))
            motion[name].append(np.linalg.norm(p1 - p0, axis=1))
            shares[name].append(len(corr.sample) / len(V))
    for name in methods:
        e, m = np.concatenate(errors[name]), np.concatenate(motion[name])
        print(f"| {root.name} | {name} | {np.mean(shares[name]):.2f} | {np.median(e):.3f} / {e.mean():.3f} / "
              f"{np.quantile(e, 0.9):.3f} | {np.median(m):.3f} / {m.mean():.3f} | "
              f"{1000 * np.median(seconds[name]):.0f} |", flush=True)


def project_all(corr, V) -> np.ndarray:
    """Each correspondence's vertex of ``V`` (a frame's clean vertices) projected into its own camera, ``(k, 2)``."""
    from mi_loop.render.cameras import project

    out = np.empty((len(corr.sample), 2))
    for i, cam in enumerate(corr.cameras):
        rows = corr.camera == i
        out[rows] = project(cam, V[corr.sample[rows]])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("captures", nargs="+", help="capture names under --root (capture_sequence.py's)")
    ap.add_argument("--root", type=Path, default=CAPTURES)
    ap.add_argument("--frames", default="1:6", help="START:STOP of the frames t (flow from t-GAP to t)")
    ap.add_argument("--consistency", type=float, default=1.0,
                    help="largest disagreement of the forward and backward flows kept, pixels (fit-sequence: 1)")
    ap.add_argument("--gap", type=int, default=1,
                    help="flow from frame t-GAP to t (fit-sequence: 1, and 2, 4, 8 with --track-key 8)")
    args = ap.parse_args()
    start, stop = (int(v) for v in args.frames.split(":"))
    print(f"frames {start}-{stop - 1}, {os.cpu_count()} cores; pixels\n")
    print("| capture | flow | kept per vertex (20 photos) | error median / mean / p90 | "
          "true motion of the kept, median / mean | ms per frame pair (20 photos, both directions) |")
    print("|---|---|---|---|---|---|")
    for name in args.captures:
        measure(args.root / name, range(start, stop), args.consistency, args.gap)


if __name__ == "__main__":
    main()
