"""Benchmark the noise-aware defaults (issue 12 section 3): the noise estimate, and fits with and without it.

Three parts, each printed as a Markdown table:

1. ``ratios``: the noise estimate (:func:`mi_loop.fitting.noise.noise_estimate`)
   of every data set the fits meet: the demo torus, the bunny range scans,
   the Demosthenes scan, 100k area samples of static meshes, and the NPS
   protocol's noisy bunny; with what the fit does with it.
2. ``torus``: the README demo's data (``noisy_torus_points``, data seeds
   ``--seeds``) at 1000 control vertices: the fit as before this change
   (``alpha`` 0.001 and pymeshlab's screened-Poisson defaults for the
   template) against the automatic defaults. Distances to the clean torus in
   the unit of its bbox diagonal: mean of the clean points' distance to the
   limit surface and of the limit surface's distance to the exact torus
   (:func:`mi_loop.datasets.torus_distance`).
3. ``scan``: the bunny range scans with Gaussian noise (sigma ``--sigma`` of
   the diagonal, along x, y, z; the given normals kept) at 1000 control
   vertices: the mean distance from the clean scan points to the template's
   and to the fit's limit surface, before and after.

Usage::

    PYTHONPATH=. .venv/bin/python bench/bench_noise.py                 # all three, seeds 0 1 2
    PYTHONPATH=. .venv/bin/python bench/bench_noise.py torus --seeds 0
"""
from __future__ import annotations

import argparse
import os
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def load() -> str:
    return "load avg " + " / ".join(f"{x:.2f}" for x in os.getloadavg())


@contextmanager
def before_this_change():
    """The static fit's template as before the noise-aware defaults: pymeshlab's screened Poisson settings."""
    import mi_loop.fitting.static as static

    saved = static.template_options
    static.template_options = lambda ratio: {}
    try:
        yield {"alpha": 0.001}
    finally:
        static.template_options = saved


def fit_both(P, N, seed):
    """``{"before": result, "after": result}`` at 1000 control vertices."""
    from mi_loop.fitting.options import FitOptions
    from mi_loop.fitting.static import fit

    out = {}
    with before_this_change() as kw:
        t = time.perf_counter()
        out["before"] = (fit(P, N, FitOptions(seed=seed, **kw)), time.perf_counter() - t)
    t = time.perf_counter()
    out["after"] = (fit(P, N, FitOptions(seed=seed)), time.perf_counter() - t)
    return out


def bench_ratios(args) -> None:
    from mi_loop import datasets
    from mi_loop.fitting.noise import RATIO_CLEAN, noise_estimate, template_options
    from mi_loop.io import read_mesh
    from mi_loop.io.points import load_oriented_points
    from mi_loop.mesh.sampling import sample_surface

    rows = [("demo torus (README)", datasets.noisy_torus_points()[0]),
            ("bunny range scans", load_oriented_points(DATA / "scans" / "bunny_rangescans_merged_stride3.ply")[0]),
            ("Demosthenes scan", load_oriented_points(DATA / "scans" / "demosthenes-low-res.obj")[0])]
    for name in ("bunny", "fandisk", "dragon_20k", "penguin"):
        V, F = read_mesh(DATA / "static" / f"{name}.obj")
        P = sample_surface(V, F, 100_000, 0)[0]
        rows.append((f"{name}.obj, 100k area samples", P))
        if name == "bunny":
            rng = np.random.default_rng(0)
            rows.append(("bunny.obj + NPS noise (0.005 x extent)", P + 0.005 * np.ptp(P, axis=0).max()
                         * rng.normal(size=P.shape)))
    print("\n| data | points | sigma / diagonal | spacing / diagonal | sigma / spacing | ARAP weight | "
          "template: Poisson point weight, samples per node |")
    print("|---|---|---|---|---|---|---|")
    for name, P in rows:
        e = noise_estimate(P)
        diag = np.linalg.norm(np.ptp(P, axis=0))
        print(f"| {name} | {len(P)} | {e['sigma_diagonal']:.2e} | {e['spacing'] / diag:.2e} | {e['ratio']:.3f} "
              f"| {'0.001 (clean)' if e['ratio'] <= RATIO_CLEAN else 'selected on held-out points'} "
              f"| {template_options(e['ratio'])['point_weight']:.2f}, "
              f"{template_options(e['ratio'])['samples_per_node']:.2f} |", flush=True)


def bench_torus(args) -> None:
    from mi_loop import datasets
    from mi_loop.metrics import two_sided

    print("\n| data seed | defaults | ARAP weight | iterations | fit s | mean to clean torus | "
          "RMS | after / before | load |")
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        P, N, clean = datasets.noisy_torus_points(seed=seed)
        res = fit_both(P, N, 0)
        d = {}
        for key, (r, seconds) in res.items():
            V, F, _ = r.limit_mesh(3)
            d[key] = two_sided(V, F, clean, exact=datasets.torus_distance)
            ratio = "" if key == "before" else f"{d['after']['mean'] / d['before']['mean']:.2f}"
            print(f"| {seed} | {key} | {r.params['alpha']:.3g} | {r.params['iterations_run']} | {seconds:.1f} | "
                  f"{d[key]['mean']:.3e} | {d[key]['rms']:.3e} | {ratio} | {load()} |", flush=True)


def bench_scan(args) -> None:
    from mi_loop.io.points import load_oriented_points
    from mi_loop.metrics import surface_distances

    P0, N, _ = load_oriented_points(DATA / "scans" / "bunny_rangescans_merged_stride3.ply")
    diag = float(np.linalg.norm(np.ptp(P0, axis=0)))
    print(f"\nbunny range scans + Gaussian noise sigma {args.sigma:g} x diagonal ({len(P0)} points)")
    print("| noise seed | defaults | ARAP weight | fit s | template: clean scan to limit, mean % | "
          "fit: mean % | fit / template | load |")
    print("|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        P = P0 + args.sigma * diag * np.random.default_rng(seed).normal(size=P0.shape)
        for key, (r, seconds) in fit_both(P, N, 0).items():
            V, F, _ = r.limit_mesh(2)
            Vt, Ft, _ = _limit(r.V_template, r.F)
            fit_d = surface_distances(V, F, P0).mean() / diag
            tpl_d = surface_distances(Vt, Ft, P0).mean() / diag
            print(f"| {seed} | {key} | {r.params['alpha']:.3g} | {seconds:.1f} | {100 * tpl_d:.4f} | "
                  f"{100 * fit_d:.4f} | {fit_d / tpl_d:.2f} | {load()} |", flush=True)


def _limit(V, F):
    from mi_loop.subdiv.masks import limit_mesh

    return limit_mesh(V, F, level=2)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("parts", nargs="*", default=["ratios", "torus", "scan"], help="ratios, torus and/or scan")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--sigma", type=float, default=0.0025, help="noise added to the scan, x its diagonal")
    args = ap.parse_args(argv)
    import mi_loop

    mi_loop.set_variant("llvm_ad_rgb")
    print(f"# bench_noise  {time.strftime('%Y-%m-%d %H:%M')}  nproc={os.cpu_count()}  {load()}")
    parts = {"ratios": bench_ratios, "torus": bench_torus, "scan": bench_scan}
    for part in args.parts:
        if part not in parts:
            ap.error(f"unknown part {part!r}: expected ratios, torus or scan")
        parts[part](args)


if __name__ == "__main__":
    main()
