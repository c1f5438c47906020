"""Benchmark reading a real capture at the working resolution: time and peak memory of ``read_capture``.

The capture is ``../shared/data/real/ethiopian_head`` (66 photos of 1000 x 1000
and their JPEG masks, LLFF ``poses_bounds.npy``) blown up to camera size:
every photo and mask upsampled (Lanczos) to ``--size`` (default 4000 x 4000)
and written as a JPEG of quality ``--quality`` (92) into ``--work`` (default
``/tmp/mi_loop_bench_read``, not tracked; reused when it holds the same size),
with a ``transforms.json`` from the LLFF poses: each row of 17 is a 3 x 5
matrix and two depth bounds; its rotation columns (down, right, back) become
OpenGL's (right, up, back), column 3 is the camera centre, column 4 is
``(h, w, focal)``, the focal scaled to the new size.

``new``
    ``read_capture(path, resolution=R)`` (default 400) in a fresh process:
    each JPEG decoded reduced by libjpeg, area-averaged to R, only R kept.
``old``
    The reading before: every photo decoded whole to float32 and kept
    (``read_capture(path)``), then resized to R (``View.resized``), as
    ``fit-images`` did; run once on ``--old-subset`` photos (default 4; 0: not
    run) and extrapolated per photo, since all 66 would need about 17 GB.

Each run is a new Python process; it reports the seconds inside ``read_capture``
(imports excluded), the process's wall time and its peak resident memory
(``resource.getrusage(RUSAGE_SELF).ru_maxrss``, which includes the ~0.3 GB of
NumPy, Pillow, OpenCV and Mitsuba's import). The figures are the median of
``--runs`` (3). Targets (GitHub issue 22): at most 3 GB and 20 s on 2 cores.

Usage::

    cd <repository root>
    PYTHONPATH=. .venv/bin/python bench/bench_read.py              # ~2 min to write the copies
    PYTHONPATH=. .venv/bin/python bench/bench_read.py --old-subset 0 --runs 5
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT.parent / "shared" / "data" / "real" / "ethiopian_head"

CHILD = """
import json, resource, sys, time
t0 = time.perf_counter()
from mi_loop.io.capture import read_capture
path, mode, resolution = sys.argv[1], sys.argv[2], int(sys.argv[3])
t = time.perf_counter()
if mode == "new":
    views = read_capture(path, resolution=resolution).views
else:                                   # the old path: whole photos kept, then resized
    views = read_capture(path).views
    scale = resolution / max(max(v.camera.width, v.camera.height) for v in views)
    views = [v.resized(scale) for v in views]
read = time.perf_counter() - t
print(json.dumps({"read_s": read, "wall_s": time.perf_counter() - t0, "views": len(views),
                  "size": [views[0].camera.width, views[0].camera.height],
                  "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}))
"""


def llff_frames(size: int) -> list[dict]:
    """transforms.json frames of ``ethiopian_head`` from ``poses_bounds.npy``, intrinsics for ``size`` pixels."""
    poses = np.load(SOURCE / "poses_bounds.npy")[:, :15].reshape(-1, 3, 5)
    images = sorted(p.name for p in (SOURCE / "images").iterdir())
    masks = {p.stem.lower(): p.name for p in (SOURCE / "masks").iterdir()}
    if len(images) != len(poses):
        raise SystemExit(f"{len(images)} images but {len(poses)} poses in {SOURCE}")
    frames = []
    for name, p in zip(images, poses):
        h, w, f = p[:, 4]
        c2w = np.eye(4)
        c2w[:3, :3] = np.concatenate([p[:, 1:2], -p[:, 0:1], p[:, 2:3]], axis=1)
        c2w[:3, 3] = p[:, 3]
        s = size / w
        mask = masks[Path(name).stem.lower()]
        frames.append({"file_path": f"images/{Path(name).stem}.jpg", "mask_path": f"masks/{mask}",
                       "fl_x": f * s, "fl_y": f * s, "cx": w * s / 2, "cy": h * s / 2, "w": size,
                       "h": int(round(h * s)), "transform_matrix": c2w.tolist()})
    return frames


def prepare(work: Path, size: int, quality: int) -> Path:
    """Write the upsampled copies and ``transforms.json`` into ``work`` unless they are there already."""
    from PIL import Image

    path = work / "transforms.json"
    if path.is_file() and json.loads(path.read_text()).get("bench_size") == [size, quality]:
        return path
    frames = llff_frames(size)
    (work / "images").mkdir(parents=True, exist_ok=True)
    (work / "masks").mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    for k, (frame, name) in enumerate(zip(frames, sorted((SOURCE / "images").iterdir()))):
        for src, dst in ((name, frame["file_path"]), (SOURCE / frame["mask_path"], frame["mask_path"])):
            with Image.open(src) as image:
                big = image.resize((size, frame["h"]), Image.Resampling.LANCZOS)
            big.save(work / dst, quality=quality)
        print(f"\rwriting {size}x{size} copies: {k + 1}/{len(frames)}", end="", flush=True)
    print(f" ({time.perf_counter() - t:.0f} s)")
    path.write_text(json.dumps({"bench_size": [size, quality], "frames": frames}, indent=1))
    return path


def subset(path: Path, n: int) -> Path:
    """A transforms.json with the first ``n`` frames of ``path``, beside it."""
    meta = json.loads(path.read_text())
    out = path.with_name(f"transforms_{n}.json")
    out.write_text(json.dumps({**meta, "frames": meta["frames"][:n]}))
    return out


def distorted(path: Path, k1: float) -> Path:
    """The capture of ``path`` with camera_model SIMPLE_RADIAL and ``k1``, beside it."""
    meta = json.loads(path.read_text())
    out = path.with_name("transforms_k1.json")
    out.write_text(json.dumps({**meta, "camera_model": "SIMPLE_RADIAL", "k1": k1}))
    return out


def run(path: Path, mode: str, resolution: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-c", CHILD, str(path), mode, str(resolution)], capture_output=True,
                            text=True, env=env)
    if result.returncode != 0:
        raise SystemExit(f"{mode} run failed:\n{result.stderr[-3000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/mi_loop_bench_read"))
    parser.add_argument("--size", type=int, default=4000)
    parser.add_argument("--quality", type=int, default=92)
    parser.add_argument("--resolution", type=int, default=400)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--old-subset", type=int, default=4)
    parser.add_argument("--k1", type=float, default=None)
    args = parser.parse_args()
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    print(f"{time.strftime('%Y-%m-%d %H:%M')}, cores: os.cpu_count() {os.cpu_count()}, usable "
          f"{len(os.sched_getaffinity(0))}, commit {commit}, load {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    path = prepare(args.work, args.size, args.quality)
    cases = [("new", path)] + ([(f"new, k1 = {args.k1}", distorted(path, args.k1))] if args.k1 else [])
    for label, source in cases:
        runs = [run(source, "new", args.resolution) for _ in range(args.runs)]
        n, size = runs[0]["views"], runs[0]["size"]
        med = {k: statistics.median(r[k] for r in runs) for k in ("read_s", "wall_s", "peak_gb")}
        print(f"{label}: {n} photos {args.size}x{args.size} JPEG q{args.quality} -> {size[0]}x{size[1]}: "
              f"read {med['read_s']:.2f} s (runs {', '.join(format(r['read_s'], '.2f') for r in runs)}), "
              f"process {med['wall_s']:.2f} s, peak RSS {med['peak_gb']:.2f} GB (median of {args.runs})")
    if args.old_subset > 0:
        old = run(subset(path, args.old_subset), "old", args.resolution)
        print(f"old: {old['views']} photos decoded whole and kept, then resized to {old['size'][0]}x"
              f"{old['size'][1]}: read {old['read_s']:.2f} s, peak RSS {old['peak_gb']:.2f} GB; per photo "
              f"{old['read_s'] / old['views']:.2f} s, so {n} photos ~{old['read_s'] / old['views'] * n:.0f} s; "
              f"their float32 RGB + mask alone {n * args.size**2 * 16 / 2**30:.1f} GB")
    print(f"load {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
