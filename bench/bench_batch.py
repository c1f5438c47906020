"""Benchmark ``mi-loop fit-batch``: 8 scans on a local Dask cluster against one process, one after another.

The scans are area samples (with face normals) of 8 meshes of
``../shared/data/static``, each scaled to a unit bounding-box diagonal, with
Gaussian noise of 0.2 % of the diagonal on the points, written as NPZ files
(``points``, ``normals``) to ``bench/results/batch/inputs``. Every scan is
fitted with the same options (``--vertices``, default 1000; the default
iteration cap, so a fit takes 10-20 s on two cores):

``sequential``
    :func:`mi_loop.app.batch_job.fit_task` for each scan in turn, in this
    process (warm after the first: Dr.Jit's kernels compiled, Mitsuba loaded).
``fit-batch --workers N``
    ``mi-loop fit-batch`` as a user runs it (a new process, its local cluster
    started and stopped), for each ``--workers`` value.

It prints the wall time of each mode with the speed-up over ``sequential``,
and each task's seconds (from ``summary.csv``), and checks that every mode
wrote the same ``control.ply`` files, bit for bit. On a machine of few cores
the speed-up is bounded: each fit already runs on all of Dr.Jit's threads, so
two workers share the cores (and the memory bandwidth) rather than add any.

Usage::

    cd <repository root>
    PYTHONPATH=. .venv/bin/python bench/bench_batch.py                 # ~5 min on 2 cores
    PYTHONPATH=. .venv/bin/python bench/bench_batch.py --workers 1 2 --vertices 500
"""
from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STATIC = ROOT.parent / "shared" / "data" / "static"
MESHES = ("bunny.obj", "spot.obj", "armadillo.obj", "fandisk.obj", "penguin.obj", "dragon_20k.obj", "lucy.ply",
          "decimated-max.obj")
RESULTS = ROOT / "bench" / "results" / "batch"


def load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def header() -> str:
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip() or "?"
    return f"{time.strftime('%Y-%m-%d %H:%M')}, nproc {os.cpu_count()}, commit {commit}, {load()}"


def table(title: str, columns, rows) -> None:
    print(f"\n### {title} ({load()})\n")
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for r in rows:
        print("| " + " | ".join(str(c) for c in r) + " |")


def make_scans(n_points: int, noise: float, folder: Path) -> list:
    """Noisy oriented samples of :data:`MESHES` as NPZ files in ``folder``; returns their paths."""
    from mi_loop import io
    from mi_loop.mesh.sampling import sample_surface

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, name in enumerate(MESHES):
        V, F = io.read_mesh(STATIC / name)
        V = (V - V.min(0)) / np.linalg.norm(np.ptp(V, axis=0))
        P, N, _ = sample_surface(V, F, n_points, seed=i)
        P = P + noise * np.random.default_rng(100 + i).normal(size=P.shape)
        path = folder / f"{Path(name).stem}.npz"
        np.savez(path, points=P, normals=N)
        paths.append(path)
    return paths


def sequential(scans: list, out: Path, vertices: int) -> tuple:
    """Fit every scan in turn in this process; ``(wall seconds, {name: task seconds})``."""
    from mi_loop.app.batch_job import Task, fit_task
    from mi_loop.fitting.options import FitOptions
    from mi_loop.render.variant import set_variant

    out.mkdir(parents=True)
    set_variant("llvm_ad_rgb")
    options = FitOptions(n_vertices=vertices)
    t = time.perf_counter()
    seconds = {}
    for scan in scans:
        row = fit_task(Task(scan, out / scan.stem, options, {"variant": "llvm_ad_rgb"}))
        if row["status"] != "done":
            sys.exit(f"{scan.name}: {row['error']}")
        seconds[scan.stem] = row["seconds"]
    return time.perf_counter() - t, seconds, {s.stem: "this process" for s in scans}


def batch(scans: list, out: Path, vertices: int, workers: int) -> tuple:
    """``mi-loop fit-batch --workers N``; ``(wall seconds, {name: task seconds}, {name: worker})``."""
    cli = Path(sys.executable).with_name("mi-loop")
    t = time.perf_counter()
    result = subprocess.run([str(cli), "fit-batch", *map(str, scans), "-o", str(out), "--workers", str(workers),
                             "--vertices", str(vertices), "--quiet"], capture_output=True, text=True)
    wall = time.perf_counter() - t
    if result.returncode != 0:
        sys.exit(result.stderr)
    with open(out / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return wall, {Path(r["input"]).stem: float(r["seconds"]) for r in rows}, \
        {Path(r["input"]).stem: r["worker"] for r in rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[2], help="local cluster sizes (default 2)")
    parser.add_argument("--vertices", type=int, default=1000, help="control vertices of every fit (default 1000)")
    parser.add_argument("--points", type=int, default=50_000, help="points per scan (default 50000)")
    args = parser.parse_args()

    shutil.rmtree(RESULTS, ignore_errors=True)
    scans = make_scans(args.points, 0.002, RESULTS / "inputs")
    print(f"bench_batch: {header()}; {len(scans)} scans of {args.points} points, --vertices {args.vertices}")
    modes = {"sequential (one process)": sequential(scans, RESULTS / "sequential", args.vertices)}
    for n in args.workers:
        modes[f"fit-batch --workers {n}"] = batch(scans, RESULTS / f"workers{n}", args.vertices, n)

    base = modes["sequential (one process)"][0]
    table("wall time of the 8 fits", ["mode", "wall s", "sum of task s", "speed-up"],
          [[m, f"{w:.1f}", f"{sum(s.values()):.1f}", f"{base / w:.2f}x"] for m, (w, s, _) in modes.items()])
    names = [s.stem for s in scans]
    columns = ["scan"] + [f"{m} s" for m in modes] + [f"worker ({m})" for m in list(modes)[1:]]
    table("seconds per task (summary.csv; sequential: the same task timer)", columns,
          [[n] + [f"{s[n]:.1f}" for _, s, _ in modes.values()] + [w[n].rsplit(":", 1)[-1] for _, _, w in
                                                                   list(modes.values())[1:]] for n in names])
    same = all((RESULTS / "sequential" / n / "control.ply").read_bytes() ==
               (RESULTS / f"workers{k}" / n / "control.ply").read_bytes() for n in names for k in args.workers)
    print(f"\ncontrol.ply identical in every mode: {same}")


if __name__ == "__main__":
    main()
