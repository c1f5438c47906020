"""A real capture, fitted three ways and scored on the same held-out photos.

Every ``--holdout`` K-th photo (``i % K == K - 1``) is left out; the rest are read at
``--res`` (the longest side) by ``read_capture`` exactly as ``mi-loop fit-images`` reads them.

- ``mi-loop``: ``mi-loop fit-images CAPTURE -o OUT --res R --vertices N --holdout K`` plus
  ``--fit-args``, as a user runs it (a subprocess); held-out scores from its report.json.
- ``hull``: the same command with ``--lr 1e-9``: the geometry stays the visual hull's
  template (its limit surface), the appearance (albedo, and the lighting where
  ``--fit-args`` estimate it) is fitted the same way: what the masks alone give.
- ``largesteps``: Mitsuba's shape-optimisation pipeline (``bench/peer_largesteps.py``:
  LargeSteps, ``direct_projective``, a per-vertex albedo, remeshing), on the same fitted
  photos composited over the same white background, under its own lighting model (a
  uniform white environment: the pipeline has no estimated lighting), from an icosphere in
  the visual hull's box, with a wall-clock budget equal to our fit's seconds.

Scores (``mi_loop.fitting.holdout``): per held-out photo the silhouette IoU of the render's
alpha against the mask and the PSNR of sRGB inside the mask; median, mean and range. The
peer's held-out renders use its own lighting (white environment) and its albedo.

    .venv/bin/python bench/bench_real.py ../shared/data/real/dtu_scan24 --json bench/results/real.jsonl \
        [--fit-args "--lighting sh"] [--methods mi-loop hull largesteps]
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mi_loop  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
MI_LOOP = Path(sys.executable).with_name("mi-loop")
OUT = REPO / "bench" / "results" / "real"


def summary(scores: list) -> dict:
    """Median, mean, min and max of the held-out IoU and PSNR (views without a value left out)."""
    out = {}
    for key in ("iou", "psnr_db"):
        x = np.array([s[key] for s in scores if s[key] is not None], dtype=float)
        out |= {f"{key}_median": float(np.median(x)), f"{key}_mean": float(x.mean()),
                f"{key}_min": float(x.min()), f"{key}_max": float(x.max())}
    return out


def run_cli(capture: Path, out: Path, args, extra: list) -> dict:
    """``mi-loop fit-images`` in a subprocess: its held-out scores, fit seconds and peak RSS."""
    cmd = [str(MI_LOOP), "fit-images", str(capture), "-o", str(out), "--quiet", "--res", str(args.res),
           "--vertices", str(args.vertices), "--holdout", str(args.holdout), *extra]
    t = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-f", "%M", *cmd], check=True, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t
    peak_gb = int(proc.stderr.strip().splitlines()[-1]) / 1024 ** 2
    report = json.loads((out / "report.json").read_text())
    return {"fit_s": report["timings_s"]["fit"], "wall_s": wall, "peak_gb": peak_gb,
            "control_vertices": report["parameters"]["control_points"] // 3, "command": " ".join(cmd[1:]),
            "views": report["holdout"]["views"], **summary(report["holdout"]["views"])}


def run_largesteps(capture: Path, args, budget: float) -> dict:
    """The peer on the fitted photos, scored on the held-out ones (module docstring)."""
    import peer_largesteps

    from mi_loop.fitting.holdout import masked_psnr, silhouette_iou, split_views
    from mi_loop.fitting.hull import carve
    from mi_loop.io.capture import read_capture
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.io.srgb import linear_to_srgb
    from mi_loop.mesh.geometry import vertex_normals
    from mi_loop.render.cameras import sensor_dict
    from mi_loop.render.captures import background, render_views

    shot = read_capture(capture, resolution=args.res)
    fitted, held = split_views(len(shot.views), args.holdout)
    views = [shot.views[i] for i in fitted]
    white = [dict(e) for e in DEFAULT_EMITTERS]
    B = background([v.camera for v in views], white)
    targets = [v.mask[..., None] * v.rgb + (1 - v.mask[..., None]) * b for v, b in zip(views, B)]
    carving = carve(views, resolution=96)
    kept = carving.centres[carving.occupied]
    bbox = (kept.min(axis=0), kept.max(axis=0))
    res = peer_largesteps.fit_largesteps([sensor_dict(v.camera, spp=4) for v in views], targets, budget_s=budget,
                                         bbox=bbox, albedo=None, progress=False)
    photos = [shot.views[i] for i in held]
    renders = render_views(res["V"], res["F"], [p.camera for p in photos], white, colors=res["colors"],
                           normals=vertex_normals(res["V"], res["F"]), spp=16, seed=7)
    scores = [{"index": i, "iou": silhouette_iou(r.mask, p.mask, p.valid),
               "psnr_db": masked_psnr(linear_to_srgb(r.rgb), linear_to_srgb(p.rgb), p.mask, p.valid)}
              for i, p, r in zip(held, photos, renders)]
    for s in scores:
        s.update({k: s[k] if np.isfinite(s[k]) else None for k in ("iou", "psnr_db")})
    return {"fit_s": res["time_s"], "setup_s": res["setup_s"], "steps": res["steps"], "vertices": len(res["V"]),
            "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2, "views": scores,
            **summary(scores)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("capture", type=Path)
    parser.add_argument("--holdout", type=int, default=8)
    parser.add_argument("--res", type=int, default=400)
    parser.add_argument("--vertices", type=int, default=2000)
    parser.add_argument("--methods", nargs="+", choices=["mi-loop", "hull", "largesteps"],
                        default=["mi-loop", "hull", "largesteps"])
    parser.add_argument("--fit-args", default="", help="extra fit-images flags for mi-loop and hull, one string")
    parser.add_argument("--budget", type=float, help="the peer's wall budget (default: our fit's seconds)")
    parser.add_argument("--json", type=Path, help="append one JSON line per method")
    args = parser.parse_args()
    mi_loop.set_variant()
    name = args.capture.resolve().name
    extra = args.fit_args.split()
    tag = "-".join(a.strip("-") for a in extra) or "default"
    budget = args.budget
    for method in args.methods:
        if method == "largesteps":
            row = run_largesteps(args.capture, args, budget or 600.0)
        else:
            flags = extra + (["--lr", "1e-9"] if method == "hull" else [])
            row = run_cli(args.capture, OUT / name / f"{method}-{tag}", args, flags)
            if method == "mi-loop" and budget is None:
                budget = row["fit_s"]
        row = {"capture": name, "method": method, "fit_args": args.fit_args, "res": args.res,
               "holdout": args.holdout, **row}
        print(f"{method:10s} {name}: IoU median {row['iou_median']:.3f} (mean {row['iou_mean']:.3f}, "
              f"{row['iou_min']:.3f}-{row['iou_max']:.3f}), PSNR median {row['psnr_db_median']:.2f} dB "
              f"({row['psnr_db_min']:.1f}-{row['psnr_db_max']:.1f}), fit {row['fit_s']:.0f} s, "
              f"peak {row['peak_gb']:.2f} GB", flush=True)
        if args.json:
            with args.json.open("a") as f:
                f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
