"""Benchmark ``mi-loop fit-images`` against Mitsuba's shape-optimisation pipeline, side by side.

For each target and albedo variant: the capture of ``bench/captures.py`` (16 views, 256^2,
written as transforms.json + RGBA PNGs) is fitted by

- ``mi-loop fit-images CAPTURE -o OUT`` run as a user runs it (a subprocess; wall time includes
  start-up, reading, the fit and writing the outputs), then
- the peer (``bench/peer_largesteps.py``: LargeSteps + ``direct_projective`` + remeshing) on the
  same images composited over the same background, with a wall-time budget equal to our
  fit time (its setup is reported separately and not counted).

Metric: two-sided mean and RMS distance between the result and the normalised target mesh
(``mi_loop.metrics.two_sided``, 30,000 area samples per side, seed 0), relative to the target's
bbox diagonal (1); for ours the limit surface at level 3. Also: optimised parameters (3 per
position, plus 3 per albedo when estimated), and for ``tex`` the mean absolute albedo error at
the result's vertices against the target's colour at the nearest target vertex.

    .venv/bin/python bench/bench_images.py bunny --variants grey --json bench/results/images.jsonl \
        [--ours-only] [--fit-args "--iterations 200"]
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
N_SAMPLES = 30_000


def albedo_error(P, C, name):
    """Mean |C - target colour at the nearest target vertex| over the points P."""
    from scipy.spatial import cKDTree

    V, _ = captures.normalised_target(name)
    _, j = cKDTree(V).query(P)
    return float(np.abs(C - captures.procedural_albedo(V)[j]).mean())


def run_ours(capture: Path, out: Path, name: str, variant: str, extra: list) -> dict:
    from mi_loop import io

    fit = captures.fit_and_measure(capture, out, name, extra, n_samples=N_SAMPLES)
    report = fit["report"]
    row = {"method": "mi-loop", "target": name, "variant": variant, "mean": fit["mean"], "rms": fit["rms"],
           "wall_s": fit["wall_s"], "fit_s": report["timings_s"]["fit"], "params": sum(report["parameters"].values()),
           "control_vertices": len(fit["V"]), "stages": report["stages"], "command": fit["command"]}
    if variant == "tex":
        limit = io.read_vertex_colors(out / "limit.ply")
        row["albedo_error"] = albedo_error(io.read_mesh(out / "limit.ply")[0], limit, name)
    return row


def run_peer(capture: Path, name: str, variant: str, budget: float, settings: dict) -> dict:
    import peer_largesteps

    from mi_loop.io.capture import read_capture
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.metrics import two_sided
    from mi_loop.render.cameras import sensor_dict
    from mi_loop.render.captures import background

    shot = read_capture(capture)
    cameras = [v.camera for v in shot.views]
    B = background(cameras, [dict(e) for e in DEFAULT_EMITTERS])
    targets = [v.mask[..., None] * v.rgb + (1 - v.mask[..., None]) * b for v, b in zip(shot.views, B)]
    bbox = (np.full(3, -0.5 / np.sqrt(3)), np.full(3, 0.5 / np.sqrt(3)))
    t = time.perf_counter()
    res = peer_largesteps.fit_largesteps([sensor_dict(c, spp=4) for c in cameras], targets, budget_s=budget,
                                         bbox=bbox, albedo=None if variant == "tex" else 0.5, progress=False,
                                         **settings)
    wall = time.perf_counter() - t
    T, F_t = captures.normalised_target(name)
    m = two_sided(res["V"], res["F"], T, F_t, n_samples=N_SAMPLES, seed=0)
    row = {"method": "largesteps", "target": name, "variant": variant, "mean": m["mean"], "rms": m["rms"],
           "wall_s": wall, "fit_s": res["time_s"], "setup_s": res["setup_s"], "params": res["params"],
           "vertices": len(res["V"]), "steps": res["steps"], "settings": res["settings"]}
    if variant == "tex" and res.get("colors") is not None:
        row["albedo_error"] = albedo_error(res["V"], res["colors"], name)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("targets", nargs="*", help=f"any of {', '.join(sorted(captures.TARGETS))}")
    parser.add_argument("--variants", nargs="+", choices=["grey", "tex"], default=["grey", "tex"])
    parser.add_argument("--ours-only", action="store_true")
    parser.add_argument("--peer-budget", type=float, help="peer wall-time budget (default: our fit time)")
    parser.add_argument("--json", type=Path, help="append one JSON line per run")
    parser.add_argument("--table", type=Path, metavar="JSONL", help="print the Markdown table of a results file")
    parser.add_argument("--fit-args", default="", help="extra fit-images flags, one string ('--iterations 200')")
    args = parser.parse_args()
    args.extra = args.fit_args.split()
    if args.table:
        print(table(args.table))
        return
    unknown = sorted(set(args.targets) - set(captures.TARGETS))
    if unknown or not args.targets:
        parser.error(f"targets: expected some of {sorted(captures.TARGETS)}, got {args.targets}")
    mi_loop.set_variant()
    for name, variant in [(n, v) for n in args.targets for v in args.variants]:
        capture = captures.OUT / f"{name}_{variant}" / "transforms.json"
        if not capture.is_file():
            captures.make_capture(name, variant)
        rows = [run_ours(capture, REPO / "bench" / "results" / "images" / f"{name}_{variant}", name, variant,
                         args.extra)]
        if not args.ours_only:
            rows.append(run_peer(capture, name, variant, args.peer_budget or rows[0]["fit_s"], {}))
        for row in rows:
            print(f"{row['method']:10s} {name:9s} {variant:4s} mean {row['mean']:.5f} rms {row['rms']:.5f} "
                  f"wall {row['wall_s']:.0f} s params {row['params']}"
                  + (f" albedo err {row['albedo_error']:.4f}" if "albedo_error" in row else ""), flush=True)
            if args.json:
                with args.json.open("a") as f:
                    f.write(json.dumps(row) + "\n")


def table(path: Path) -> str:
    """Markdown table of a JSON-lines file of runs: one row per target and variant, both methods."""
    runs = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    by = {(r["target"], r["variant"], r["method"]): r for r in runs}
    lines = ["| target | albedo | mi-loop mean | RMS | params | fit s | LargeSteps mean | RMS | params | steps | "
             "ratio of means | albedo error (ours / peer) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for (target, variant, method), ours in by.items():
        if method != "mi-loop":
            continue
        peer = by.get((target, variant, "largesteps"), {})
        err = (f"{ours['albedo_error']:.3f} / {peer['albedo_error']:.3f}" if "albedo_error" in ours
               and "albedo_error" in peer else "")
        lines.append(f"| {target} | {variant} | {ours['mean']:.5f} | {ours['rms']:.5f} | {ours['params']} | "
                     f"{ours['fit_s']:.0f} | {peer.get('mean', np.nan):.5f} | {peer.get('rms', np.nan):.5f} | "
                     f"{peer.get('params', '')} | {peer.get('steps', '')} | "
                     f"{ours['mean'] / peer['mean'] if peer else float('nan'):.2f} | {err} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
