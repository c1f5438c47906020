"""Benchmark ``mi-loop fit-sequence`` on simulated captures: partial noisy depth plus multi-view photos.

The captures come from ``bench/capture_sequence.py`` (per frame: depth from 3
cameras on one side, 160 x 120, noise sigma 0.15 % of the diagonal, no normals;
20 RGBA photos over the sphere at 128^2; ``clean.npz``, the clean frames in
correspondence). Each configuration is run as a user would run it:

``imls``
    ``mi-loop fit-sequence DEPTH --reference clean.npz --no-image``: depth only
    (the template from screened Poisson of the first frame's points).
``imls_hull``
    the same with ``--images`` for the template only (``--no-image``): the
    visual hull fills the first frame's holes, no image term.
``image``
    ``--images CAPTURES`` (IMLS + images).
``dr``
    ``--images CAPTURES --image-only``.

``metrics.csv`` then holds, per frame, the two-sided mean / RMS distance to the
clean frame, the flipped area and the correspondence drift (all relative to the
frame's bounding-box diagonal). ``table`` prints one Markdown row per run and
the per-frame comparison of ``image`` against ``imls``.

Usage::

    .venv/bin/python bench/capture_sequence.py spot fox fox_tex          # write the captures
    .venv/bin/python bench/bench_capture.py fit --seq spot --configs imls image dr
    .venv/bin/python bench/bench_capture.py table --seq spot fox fox_tex

Runs go to ``bench/results/capture_fit/<seq>/<config><tag>/`` (not tracked).
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
CAPTURES = ROOT / "bench" / "results" / "capture_seq"
RESULTS = ROOT / "bench" / "results" / "capture_fit"
CONFIGS = {"imls": ["--no-image"], "imls_hull": ["--no-image", "IMAGES"], "image": ["IMAGES"],
           "dr": ["IMAGES", "--image-only"]}
LABELS = {"imls": "IMLS only (depth)", "imls_hull": "IMLS only, hull template", "image": "IMLS + images",
          "dr": "images only"}
MEAN_TARGET, RMS_TARGET, FLIP_TARGET, DRIFT_TARGET = 0.0015, 0.003, 0.3, 0.005


def load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def command(seq: str, config: str, out: Path, extra: list, captures: Path = CAPTURES) -> list:
    """The ``mi-loop fit-sequence`` command line of one run."""
    src = captures / seq
    cmd = [str(ROOT / ".venv" / "bin" / "mi-loop"), "-q", "fit-sequence", str(src / "depth"), "-o", str(out),
           "--reference", str(src / "clean.npz"), "--vertices", "1000"]
    for arg in CONFIGS[config]:
        cmd += ["--images", str(src / "images")] if arg == "IMAGES" else [arg]
    return cmd + extra


def fit_part(args):
    for seq in args.seq:
        for config in args.configs:
            out = RESULTS / seq / f"{config}{args.tag}"
            if (out / "metrics.csv").exists() and not args.force:
                print(f"{out} exists (--force to run again)", flush=True)
                continue
            if out.exists():
                subprocess.run(["rm", "-rf", str(out)], check=True)
            cmd = command(seq, config, out, shlex.split(args.extra), args.captures)
            if args.frames:
                cmd += ["--frames", args.frames]
            print(" ".join(cmd), f"[{load()}]", flush=True)
            t = time.perf_counter()
            subprocess.run(cmd, check=True)
            print(f"  {time.perf_counter() - t:.0f} s", flush=True)


def rows(out: Path) -> list:
    with open(out / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def column(r, key) -> np.ndarray:
    return np.array([float(x[key]) if x[key] else np.nan for x in r])


def table_part(args):
    print(f"\nSimulated captures, runs tagged '{args.tag}' [{load()}]\n")
    print("| sequence | config | last frame mean / RMS | worst frame mean / RMS | frames meeting mean <= 0.0015 "
          "and RMS <= 0.003 | flipped % largest (frame) | drift last frame mean / p95 | s / frame |")
    print("|---|---|---|---|---|---|---|---|")
    for seq in args.seq:
        for config in args.configs:
            out = RESULTS / seq / f"{config}{args.tag}"
            if not (out / "metrics.csv").exists():
                continue
            r = rows(out)
            mean, rms, flip = column(r, "mean"), column(r, "rms"), column(r, "flipped_pct")
            dm, dp, sec = column(r, "drift_mean"), column(r, "drift_p95"), column(r, "seconds")
            worst = int(np.argmax(mean))
            ok = int(np.sum((mean <= MEAN_TARGET) & (rms <= RMS_TARGET)))
            f_worst = int(np.argmax(flip))
            print(f"| {seq} | {LABELS[config]} | {mean[-1]:.6f} / {rms[-1]:.6f} | {mean[worst]:.6f} / "
                  f"{rms[worst]:.6f} ({worst}) | {ok}/{len(r)} | {flip[f_worst]:.2f} ({f_worst}) | "
                  f"{dm[-1]:.5f} / {dp[-1]:.5f} | {np.median(sec[1:]) if len(sec) > 1 else sec[0]:.1f} |")
    print("\nIMLS + images against IMLS only, per frame (mean distance ratio):\n")
    for seq in args.seq:
        a, b = RESULTS / seq / f"image{args.tag}", RESULTS / seq / f"{args.baseline}{args.tag}"
        if not ((a / "metrics.csv").exists() and (b / "metrics.csv").exists()):
            continue
        ma, mb = column(rows(a), "mean"), column(rows(b), "mean")
        n = min(len(ma), len(mb))
        ratio = ma[:n] / mb[:n]
        below = int(np.sum(ratio[3:] < 1.0))
        print(f"- {seq} (against {LABELS[args.baseline]}): ratio per frame "
              f"{' '.join(f'{x:.2f}' for x in ratio)}; below 1 at {below}/{max(0, n - 3)} frames from frame 3; "
              f"last frame {100 * (1 - ratio[-1]):.0f} % lower")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="part", required=True)
    fit = sub.add_parser("fit")
    fit.add_argument("--seq", nargs="+", default=["spot", "fox"])
    fit.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=["imls", "image", "dr"])
    fit.add_argument("--tag", default="")
    fit.add_argument("--frames", default=None, help="--frames START:STOP:STEP of fit-sequence")
    fit.add_argument("--extra", default="", help="more fit-sequence arguments")
    fit.add_argument("--force", action="store_true")
    fit.add_argument("--captures", type=Path, default=CAPTURES,
                     help="where capture_sequence.py wrote the captures (its --out)")
    table = sub.add_parser("table")
    table.add_argument("--seq", nargs="+", default=["spot", "fox", "fox_tex"])
    table.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=list(CONFIGS))
    table.add_argument("--tag", default="")
    table.add_argument("--baseline", choices=list(CONFIGS), default="imls")
    args = parser.parse_args()
    {"fit": fit_part, "table": table_part}[args.part](args)


if __name__ == "__main__":
    main()
