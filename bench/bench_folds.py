"""Benchmark folds in static fits (issue 12 section 4): flipped area and self-intersections, barrier on and off.

For each static mesh, ``fit()`` as ``mi-loop fit MESH --vertices 1000`` runs it
(100k area samples with face normals in, the mesh passed for feature
detection), once with the fold barrier at its default weight and once with
``fold=0``, for each ``--seeds`` (of the 100k samples and of the fit). Per fit, on the level-3 limit mesh: flipped
area % (face normals against the nearest target face's,
:func:`mi_loop.metrics.flipped_fraction`), self-intersecting limit faces
(:func:`mi_loop.metrics.self_intersections`), the NPS P2S / HD (x 1e-3 at
extent 2) and NAE (degrees), iterations and fit seconds.

Usage::

    .venv/bin/python bench/bench_folds.py                         # dragon_20k, bunny, fandisk, penguin; seeds 0 1
    .venv/bin/python bench/bench_folds.py --meshes dragon_20k --seeds 0
    .venv/bin/python bench/bench_folds.py --meshes dragon_20k penguin --folds default   # the default fit only
    .venv/bin/python bench/bench_folds.py --meshes dragon_20k --folds default --cover 0.3
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

STATIC = Path(__file__).resolve().parents[2] / "shared" / "data" / "static"


def load() -> str:
    return "load avg " + " / ".join(f"{x:.2f}" for x in os.getloadavg())


def run(name: str, fold: float | None, seed: int, cover: float | None = None) -> list:
    from mi_loop.fitting.options import FitOptions
    from mi_loop.fitting.static import fit
    from mi_loop.io import read_mesh
    from mi_loop.io.points import load_oriented_points
    from mi_loop.metrics import flipped_fraction, nps_metrics, self_intersections

    path = STATIC / f"{name}.obj"
    V, F = read_mesh(path)
    P, N, _ = load_oriented_points(path, seed=seed)      # the seed draws the samples too: the spread
    kw = ({} if fold is None else {"fold": fold}) | ({} if cover is None else {"cover": cover})
    t = time.perf_counter()
    r = fit(P, N, FitOptions(n_vertices=1000, seed=seed, **kw), mesh=(V, F))
    seconds = time.perf_counter() - t
    V_lim, F_lim, _ = r.limit_mesh(3)
    crossed = self_intersections(V_lim, F_lim)
    m = nps_metrics((V_lim, F_lim), (V, F))
    return [name, "default" if fold is None else f"{fold:g}", f"{r.params['fold']:g}", str(seed),
            f"{100 * flipped_fraction(V_lim, F_lim, V, F):.3f}",
            f"{crossed.sum()} ({100 * crossed.mean():.3f} %)", f"{1e3 * m['P2S']:.3f}", f"{1e3 * m['HD']:.2f}",
            f"{m['NAE']:.2f}", str(r.params["iterations_run"]), f"{seconds:.1f}", load()]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", nargs="+", default=["dragon_20k", "bunny", "fandisk", "penguin"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--folds", nargs="+", default=["0", "default"], help="barrier weights: 0 and/or default")
    ap.add_argument("--cover", type=float, default=None, help="the coverage weight of every fit (default: fit()'s)")
    args = ap.parse_args(argv)

    import mi_loop
    from mi_loop.io import read_mesh
    from mi_loop.metrics import self_intersections

    mi_loop.set_variant("llvm_ad_rgb")
    print(f"# bench_folds  {time.strftime('%Y-%m-%d %H:%M')}  nproc={os.cpu_count()}  {load()}")
    for name in args.meshes:
        V, F = read_mesh(STATIC / f"{name}.obj")
        s = self_intersections(V, F)
        print(f"{name}: {len(F)} faces, {s.sum()} self-intersecting ({100 * s.mean():.3f} %)")
    print("\n| mesh | fold asked | fold used | seed | flipped area % | self-intersecting limit faces | P2S | HD "
          "| NAE | iterations | fit s | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.meshes:
        for seed in args.seeds:
            for fold in (None if f == "default" else float(f) for f in args.folds):
                print("| " + " | ".join(run(name, fold, seed, args.cover)) + " |", flush=True)


if __name__ == "__main__":
    main()
