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

``--keyframe`` measures instead what :func:`mi_loop.fitting.flow.pin_to_keyframe` does with those
targets (``optical_flow``'s): each is tracked again from the vertex's pixel in the first frame's
photos (the :class:`~mi_loop.fitting.flow.Keyframe` of the clean frame 0). Per frame: the share of
the targets pinned, and the error of the pinned ones before and after; the targets it does not pin
keep the chained error. In a fit the chained targets also carry the drift of the frames before,
which the pin does not see; here they start from the clean frame ``t-1``.

Usage::

    .venv/bin/python bench/capture_sequence.py spot spot_fine
    PYTHONPATH=. .venv/bin/python bench/bench_flow.py spot spot_fine --frames 1:6
    PYTHONPATH=. .venv/bin/python bench/bench_flow.py spot spot_fine --frames 1:16 --keyframe
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


def measure(root: Path, frames, consistency: float = 1.0) -> None:
    from mi_loop.fitting import flow
    from mi_loop.io.capture import read_capture
    from mi_loop.mesh.geometry import vertex_normals

    with np.load(root / "clean.npz") as clean:
        Vs, F = clean["vertices"], clean["faces"]
    methods = {"optical_flow (full resolution)": flow.optical_flow, "DIS medium preset alone": medium}
    errors, motion, shares, seconds = ({k: [] for k in methods} for _ in range(4))
    for t in frames:
        before = list(read_capture(root / "images" / f"{t - 1:04d}" / "transforms.json").views)
        after = list(read_capture(root / "images" / f"{t:04d}" / "transforms.json").views)
        V, N, surface = Vs[t - 1], vertex_normals(Vs[t - 1], F), midpoint_split(Vs[t - 1], F)[0]
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


def measure_keyframe(root: Path, frames) -> None:
    from mi_loop.fitting import flow
    from mi_loop.io.capture import read_capture
    from mi_loop.mesh.geometry import vertex_normals

    with np.load(root / "clean.npz") as clean:
        Vs, F = clean["vertices"], clean["faces"]

    def views(t):
        return list(read_capture(root / "images" / f"{t:04d}" / "transforms.json").views)

    key = flow.keyframe(views(0), Vs[0], vertex_normals(Vs[0], F), midpoint_split(Vs[0], F)[0])
    before = views(frames[0] - 1)
    for t in frames:
        after = views(t)
        V, N, surface = Vs[t - 1], vertex_normals(Vs[t - 1], F), midpoint_split(Vs[t - 1], F)[0]
        corr = flow.flow_correspondences(before, after, V, N, surface)
        start = time.perf_counter()
        pinned = flow.pin_to_keyframe(key, after, corr)
        ms = 1000 * (time.perf_counter() - start)
        moved = np.any(pinned.target != corr.target, axis=1)
        p1 = project_all(corr, Vs[t])
        chained, now = (np.linalg.norm(c.target[moved] - p1[moved], axis=1) for c in (corr, pinned))
        total = np.linalg.norm(p1[moved] - project_all(corr, Vs[0])[moved], axis=1)
        print(f"| {root.name} | {t} | {moved.mean():.2f} | {np.mean(chained):.3f} / {np.quantile(chained, 0.9):.3f} | "
              f"{np.mean(now):.3f} / {np.quantile(now, 0.9):.3f} | {np.median(total):.1f} | {ms:.0f} |", flush=True)
        before = after


def project_all(corr, V) -> np.ndarray:
    """Each correspondence's vertex projected into its own camera at frame ``t-1``, ``(k, 2)``."""
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
    ap.add_argument("--frames", default="1:6", help="START:STOP of the frames t (flow from t-1 to t)")
    ap.add_argument("--consistency", type=float, default=1.0,
                    help="largest disagreement of the forward and backward flows kept, pixels (fit-sequence: 1)")
    ap.add_argument("--keyframe", action="store_true",
                    help="measure the targets pinned to the first frame's photos (pin_to_keyframe) instead")
    args = ap.parse_args()
    start, stop = (int(v) for v in args.frames.split(":"))
    print(f"frames {start}-{stop - 1}, {os.cpu_count()} cores; pixels\n")
    if args.keyframe:
        print("| capture | frame | share pinned | chained error of the pinned, mean / p90 | pinned error, mean / p90 | "
              "their motion since frame 0, median | ms (20 photos) |")
        print("|---|---|---|---|---|---|---|")
        for name in args.captures:
            measure_keyframe(args.root / name, list(range(start, stop)))
        return
    print("| capture | flow | kept per vertex (20 photos) | error median / mean / p90 | "
          "true motion of the kept, median / mean | ms per frame pair (20 photos, both directions) |")
    print("|---|---|---|---|---|---|")
    for name in args.captures:
        measure(args.root / name, range(start, stop), args.consistency)


if __name__ == "__main__":
    main()
