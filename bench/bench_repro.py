"""Run-to-run spread: the same ``mi-loop`` command twice, outputs compared.

Each case runs ``--runs`` times (fresh processes, same seed, same thread count)
and reports, per output frame, how far the control points and the limit
surfaces of the runs are apart, relative to the bounding-box diagonal of the
first run's limit surface:

- ``ctrl_max`` / ``ctrl_median``: largest / median distance between the same
  control point in two runs;
- ``limit_mean``: mean distance between the same limit-surface vertex;
- ``identical``: the control meshes are equal bit for bit.

Cases: ``fit-demo`` (the README demo), ``fit-bunny`` (the merged bunny range
scans, 1000 control vertices), ``seq-geo`` and ``seq-image`` (fox_walk_24f.npz
frames 0, 3, 6, 9, 12 with 200 control vertices, ``--no-image`` and defaults),
``seq-image-det`` (the same with ``--deterministic``).

Usage::

    python bench/bench_repro.py --cases fit-demo fit-bunny seq-geo seq-image \
        --runs 2 --json bench/results/repro.json [--mi-loop PATH/TO/mi-loop]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
FOX_FRAMES = [0, 3, 6, 9, 12]


def _fox_subset(tmp: Path) -> Path:
    data = np.load(DATA / "sequences" / "fox_walk_24f.npz")
    path = tmp / "fox_5f.npz"
    np.savez(path, vertices=data["vertices"][FOX_FRAMES], faces=data["faces"])
    return path


def _cases(tmp: Path, extra: dict) -> dict:
    fox = str(_fox_subset(tmp))
    seq = ["fit-sequence", fox, "--vertices", "200"]
    return {
        "fit-demo": ["fit", "--demo", "--quiet"],
        "fit-bunny": ["fit", str(DATA / "scans" / "bunny_rangescans_merged_stride3.ply"), "--quiet"],
        "seq-geo": seq + ["--no-image"] + extra.get("seq", []),
        "seq-image": seq + extra.get("seq", []),
        "seq-image-det": seq + ["--deterministic"] + extra.get("seq", []),
    }


def _read(path: Path) -> np.ndarray:
    return np.asarray(trimesh.load(path, process=False).vertices, dtype=np.float64)


def _outputs(out: Path):
    """``[(name, control_vertices, limit_vertices)]`` of a fit or a sequence directory."""
    if (out / "control.ply").exists():
        return [("static", _read(out / "control.ply"), _read(out / "limit.ply"))]
    names = sorted(p.name for p in (out / "control").glob("*.ply"))
    return [(n, _read(out / "control" / n), _read(out / "limit" / n)) for n in names]


def compare(a: Path, b: Path) -> list:
    rows = []
    for (name, Ca, La), (_, Cb, Lb) in zip(_outputs(a), _outputs(b)):
        diag = float(np.linalg.norm(La.max(0) - La.min(0)))
        dc = np.linalg.norm(Ca - Cb, axis=1) / diag
        dl = np.linalg.norm(La - Lb, axis=1) / diag
        rows.append({"frame": name, "ctrl_max": float(dc.max()), "ctrl_median": float(np.median(dc)),
                     "limit_mean": float(dl.mean()), "identical": bool(np.array_equal(Ca, Cb))})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["fit-demo", "fit-bunny", "seq-geo", "seq-image"])
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--mi-loop", default=str(REPO / ".venv" / "bin" / "mi-loop"))
    parser.add_argument("--seq-args", default="", help="extra arguments for the sequence cases")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    results = {"cores": os.cpu_count(), "mi_loop": args.mi_loop, "cases": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cases = _cases(tmp, {"seq": args.seq_args.split()})
        for case in args.cases:
            outs, seconds = [], []
            for r in range(args.runs):
                out = tmp / f"{case}-{r}"
                t = time.perf_counter()
                proc = subprocess.run([args.mi_loop, *cases[case], "-o", str(out)],
                                      capture_output=True, text=True)
                seconds.append(time.perf_counter() - t)
                if proc.returncode != 0:
                    print(proc.stderr, file=sys.stderr)
                    raise SystemExit(f"{case}: run {r} failed")
                outs.append(out)
            pairs = [compare(outs[0], o) for o in outs[1:]]
            results["cases"][case] = {"command": cases[case], "seconds": seconds, "pairs": pairs}
            for rows in pairs:
                for row in rows:
                    print(f"{case:14s} {row['frame']:12s} ctrl max {row['ctrl_max']:.2e} "
                          f"median {row['ctrl_median']:.2e} limit mean {row['limit_mean']:.2e} "
                          f"identical {row['identical']}", flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
