"""Benchmark real motion: ``mi-loop fit-sequence`` on D-FAUST (a person hopping), complete and one-sided.

The 17 frames of ``../shared/data/real/dfaust_50002_hopping/`` are NPZ files of
100,000 points (float16, ``loc``, ``scale``) in which point ``k`` is the same
material point in every frame. The bench

1. writes the points in correspondence, in the capture's frame
   (``points * scale + loc``), as one ``ref.npz`` with ``points (T, N, 3)``:
   the ``--reference`` from which ``metrics.csv`` takes the drift;
2. ``complete``: fits the published frames as they are (``fit-sequence`` reads
   the NPZ files directly);
   ``one-sided``: fits what 3 depth cameras on one side would see: each
   frame's points seen from 3 cameras 2.5 m in front of the subject (at -40,
   0 and 40 degrees), kept where they are within 1 cm of the nearest point of
   their pixel in a splatted z-buffer (a pixel about twice the points'
   spacing), written as XYZ files without normals;
3. prints per frame the two-sided mean / RMS distance to the complete points,
   the drift (mean, p95), the flipped area and the seconds, and a summary
   row per solver (worst frame of each column, median seconds); one-sided,
   also the drift of the control vertices on the seen surface (the unseen
   back is far from the body from frame 0 on, which the drift of all
   vertices mostly measures).

Usage::

    cd <repository root>
    PYTHONPATH=. .venv/bin/python bench/bench_dfaust.py complete --solvers adam gauss-newton
    PYTHONPATH=. .venv/bin/python bench/bench_dfaust.py one-sided --solvers gauss-newton --extra="--alpha 0.1"

Runs go to ``bench/results/dfaust/`` (not tracked). The load average is
printed with each table: other jobs inflate the timings.
"""
from __future__ import annotations

import argparse
import csv
import os
import shlex
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "dfaust_50002_hopping"
RESULTS = ROOT / "bench" / "results" / "dfaust"


def load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def frames_in_world(data: Path) -> list:
    """``(name, points (N, 3))`` of every frame, ``points * scale + loc`` (the capture's frame, metres)."""
    out = []
    for p in sorted(data.glob("*.npz")):
        with np.load(p) as d:
            out.append((p.stem, d["points"].astype(np.float64) * float(d["scale"]) + d["loc"]))
    return out


def visible(P, centre, radius, n_cameras: int = 3, spread: float = 40.0, distance: float = 2.5,
            tolerance: float = 0.01) -> np.ndarray:
    """Mask of the points a depth camera sees, for ``n_cameras`` cameras on the subject's +z side.

    Each camera looks at ``centre`` from ``distance`` metres, at azimuths
    spread over ``[-spread, spread]`` degrees. A point is seen by a camera when
    its depth is within ``tolerance`` of the smallest depth in its pixel; the
    pixel is twice the median spacing of the points at the subject's distance.
    """
    from scipy.spatial import cKDTree

    spacing = float(np.median(cKDTree(P[::20]).query(P[::20], k=2)[0][:, 1]))
    pixel = 2.0 * spacing
    seen = np.zeros(len(P), dtype=bool)
    for az in np.radians(np.linspace(-spread, spread, n_cameras)):
        eye = centre + distance * np.array([np.sin(az), 0.0, np.cos(az)])
        fwd = (centre - eye) / np.linalg.norm(centre - eye)
        right = np.cross(fwd, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        d = P - eye
        z = d @ fwd
        u = np.floor((d @ right) / z * distance / pixel).astype(np.int64)
        v = np.floor((d @ up) / z * distance / pixel).astype(np.int64)
        key = (u - u.min()) * (v.max() - v.min() + 1) + (v - v.min())
        nearest = np.full(key.max() + 1, np.inf)
        np.minimum.at(nearest, key, z)
        seen |= z <= nearest[key] + tolerance
    return seen


def write_one_sided(frames: list, out: Path) -> Path:
    """XYZ files of the one-sided frames (no normals); the share of points kept, printed."""
    folder = out / "one_sided"
    folder.mkdir(parents=True, exist_ok=True)
    shares = []
    for name, P in frames:
        lo, hi = P.min(0), P.max(0)
        keep = visible(P, 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo)))
        shares.append(keep.mean())
        np.savetxt(folder / f"{name}.xyz", P[keep], fmt="%.6f")
    print(f"one-sided frames: {100 * np.mean(shares):.0f} % of the points kept "
          f"({100 * min(shares):.0f}-{100 * max(shares):.0f} %)")
    return folder


def fit(frames_arg: Path, ref: Path, out: Path, solver: str, vertices: int, extra: str) -> list:
    """Run ``mi-loop fit-sequence``; its ``metrics.csv`` rows."""
    extra = shlex.split(extra)
    size = [] if "--template" in extra else ["--vertices", str(vertices)]
    cmd = [str(ROOT / ".venv" / "bin" / "mi-loop"), "-q", "fit-sequence", str(frames_arg), "--reference", str(ref),
           *size, "--solver", solver, "-o", str(out), *extra]
    print("$", " ".join(cmd), flush=True)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    print(f"  {time.perf_counter() - t0:.0f} s in all ({load()})", flush=True)
    with open(out / "metrics.csv") as f:
        return list(csv.DictReader(f))


def seen_drift(out: Path, ref: Path) -> None:
    """Drift of the control vertices on the seen surface (limit point within 0.5 % of the complete cloud at
    frame 0): a one-sided fit's unseen back is far from the body from the start, and its 'drift' says so."""
    from mi_loop import io
    from mi_loop.metrics import attach_points
    from mi_loop.subdiv.masks import limit_positions

    R = np.load(ref)["points"]
    V0, F = io.read_mesh(out / "control" / "0000.ply")
    L0 = limit_positions(V0, F)
    a = attach_points(L0, R[0])
    diag = float(np.linalg.norm(np.ptp(R[0], axis=0)))
    on = np.linalg.norm(L0 - a.points(R[0]), axis=1) / diag < 0.005
    cells = []
    for t in range(len(R)):
        Lt = limit_positions(io.read_mesh(out / "control" / f"{t:04d}.ply")[0], F)
        d = 100 * np.linalg.norm(Lt - a.points(R[t]), axis=1)[on] / diag
        cells.append((d.mean(), np.percentile(d, 95)))
    print(f"\ndrift of the {100 * on.mean():.0f} % of the control vertices on the seen surface, mean / p95 %: "
          + " ".join(f"{t}: {m:.2f} / {p:.2f}" for t, (m, p) in enumerate(cells))
          + f"; worst {max(c[0] for c in cells):.3f} / {max(c[1] for c in cells):.3f}")


def table(label: str, rows: list) -> None:
    print(f"\n### {label}\n")
    print("| frame | mean | RMS | drift mean % | drift p95 % | flipped % | s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['frame']} | {float(r['mean']):.5f} | {float(r['rms']):.5f} | {100 * float(r['drift_mean']):.3f} "
              f"| {100 * float(r['drift_p95']):.3f} | {float(r['flipped_pct']):.3f} | {float(r['seconds']):.1f} |")


def summary(results: dict) -> None:
    print(f"\n| solver | worst mean | worst RMS | drift mean %: frame 1 / worst | drift p95 %: worst | "
          f"flipped %: worst | s per frame (median, frames 1+) |   ({load()}, {os.cpu_count()} cores)")
    print("|---|---|---|---|---|---|---|")
    for label, rows in results.items():
        col = {k: np.array([float(r[k]) for r in rows]) for k in ("mean", "rms", "drift_mean", "drift_p95",
                                                                 "flipped_pct", "seconds")}
        print(f"| {label} | {col['mean'].max():.5f} | {col['rms'].max():.5f} | "
              f"{100 * col['drift_mean'][1]:.3f} / {100 * col['drift_mean'].max():.3f} | "
              f"{100 * col['drift_p95'].max():.3f} | {col['flipped_pct'].max():.3f} | "
              f"{np.median(col['seconds'][1:]):.1f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mode", choices=("complete", "one-sided"))
    ap.add_argument("--solvers", nargs="+", default=["adam", "gauss-newton"])
    ap.add_argument("--vertices", type=int, default=1000)
    ap.add_argument("--extra", default="", help="more fit-sequence options, e.g. '--alpha 0.1'")
    ap.add_argument("--tag", default="")
    ap.add_argument("--data", type=Path, default=DATA)
    args = ap.parse_args()
    out = RESULTS / args.mode
    out.mkdir(parents=True, exist_ok=True)
    frames = frames_in_world(args.data)
    ref = out / "ref.npz"
    np.savez(ref, points=np.stack([P for _, P in frames]))
    source = args.data if args.mode == "complete" else write_one_sided(frames, out)
    results = {}
    for solver in args.solvers:
        label = f"{solver}{args.tag}"
        results[label] = fit(source, ref, out / label, solver, args.vertices, args.extra)
        table(f"{args.mode}, {label} {args.extra}", results[label])
        if args.mode == "one-sided":
            seen_drift(out / label, ref)
    summary(results)


if __name__ == "__main__":
    main()
