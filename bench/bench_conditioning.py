"""How a tiny perturbation grows through a fitted sequence, and in which direction.

With bit-reproducible runs, the question of run-to-run spread becomes one of
conditioning: how much does a perturbation of size ``--eps`` (relative to the
bounding-box diagonal, added to the control points after frame 0, random
direction) change the later frames? Each later frame's control points of the
perturbed run are compared with the unperturbed run's:

- ``ctrl max`` / ``ctrl median``: distance between the same control point, / diagonal;
- ``tangential``: share of the squared control-point difference that lies in
  the tangent plane of the limit surface at that vertex (its limit normal from
  :func:`mi_loop.limit_normals`); 2/3 would be an isotropic difference;
- ``limit mean``: mean distance between the same limit-surface point (level 2), / diagonal;
- ``gain``: ``ctrl max`` / ``eps``.

Frames: fox_walk_24f.npz frames 0, 3, 6, 9, 12 at 200 control vertices (the
case of the reproducibility issue), the defaults of ``mi-loop fit-sequence``;
``--image`` adds the image term (20 views, run with ``deterministic=True`` so
that the only difference is the perturbation).

Two experiments probe where the growth comes from (neither is a package option):

- ``--refresh-once``: IMLS neighbour lists and coverage assignments are built
  once per frame instead of every 10 iterations (the energy is then smooth
  within a frame);
- ``--adam-epsilon E``: Adam's epsilon (Dr.Jit's default 1e-8). Adam divides
  each coordinate's step by the root of its running squared gradient, so a
  coordinate whose gradient is tiny (a control point sliding along a flat
  valley) still takes a full step; a larger epsilon damps such steps.

Usage::

    .venv/bin/python bench/bench_conditioning.py [--eps 1e-6] [--image] [--alpha A] [--json out.json]
    .venv/bin/python bench/bench_conditioning.py --eps 1e-8 --refresh-once
    .venv/bin/python bench/bench_conditioning.py --eps 1e-8 --adam-epsilon 1e-5
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FOX = ROOT.parent / "shared" / "data" / "sequences" / "fox_walk_24f.npz"
FRAMES = [0, 3, 6, 9, 12]


def run(frames, F_data, options, perturb=None, seed=0):
    """Fit the frames; return the normalised control points after every frame and the cage faces."""
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.fitting.sequence import Rig, fit_frame
    from mi_loop.fitting.static import Normalisation, sample_parameters
    from mi_loop.fitting.template import mesh_template
    from mi_loop.mesh.geometry import mean_edge_length
    from mi_loop.mesh.sampling import sample_surface

    norm = Normalisation.of(frames[0])
    x, F, _ = mesh_template(norm.forward(frames[0]), F_data, 200)
    lr = 0.02 * mean_edge_length(x, F)
    op = LimitOperator(F, len(x), *sample_parameters(F, len(x), "level1"), derivatives=False)
    rig = None
    if options.image:
        lo, hi = x.min(0), x.max(0)
        pad = 0.15 * (hi - lo).max()
        rig = Rig(options, (lo - pad, hi + pad))
    fits = []
    for t, X in enumerate(frames):
        P, N, _ = sample_surface(X, F_data, 20_000, seed=seed + t)
        images = rig.images(x, F, (norm.forward(X), F_data), t) if rig is not None else None
        x, _ = fit_frame(x, F, norm.forward(P), N, op, images, options, t, lr)
        if t == 0 and perturb is not None:
            x = x + perturb
        fits.append(x.copy())
    return fits, F


def _experiments(args) -> None:
    """Patch the package for the ``--refresh-once`` and ``--adam-epsilon`` experiments (this process only)."""
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS

    if args.refresh_once:
        for cls in (IMLS, Coverage):
            def once(self, Q, _update=cls.update):
                if not getattr(self, "_built_once", False):
                    self._built_once = True
                    _update(self, Q)
            cls.update = once
    if args.adam_epsilon is not None:
        from mi_loop.fitting.optimisers import Adam

        adam_init = Adam.__init__

        def init(self, *a, _init=adam_init, **k):
            k.setdefault("epsilon", args.adam_epsilon)
            _init(self, *a, **k)
        Adam.__init__ = init


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eps", type=float, default=1e-6)
    parser.add_argument("--image", action="store_true")
    parser.add_argument("--alpha", type=float, help="ARAP weight (default: SequenceOptions's)")
    parser.add_argument("--refresh-once", action="store_true",
                        help="experiment: neighbour lists built once per frame, not every 10 iterations")
    parser.add_argument("--adam-epsilon", type=float, help="experiment: Adam's epsilon (default 1e-8)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)

    import mi_loop
    from mi_loop.fitting.options import SequenceOptions
    from mi_loop.subdiv.masks import limit_mesh, limit_normals

    mi_loop.set_variant("llvm_ad_rgb")
    _experiments(args)
    data = np.load(FOX)
    frames = [np.asarray(data["vertices"][t], dtype=np.float64) for t in FRAMES]
    options = SequenceOptions(image=args.image, deterministic=True,
                              **({} if args.alpha is None else {"alpha": args.alpha}))
    base, F = run(frames, data["faces"], options)
    diag = float(np.linalg.norm(base[0].max(0) - base[0].min(0)))
    rng = np.random.default_rng(1)
    d = rng.standard_normal(base[0].shape)
    perturb = args.eps * diag * d / np.linalg.norm(d, axis=1).max()
    other, _ = run(frames, data["faces"], options, perturb)
    print(f"# bench_conditioning: {os.cpu_count()} cores, eps {args.eps:g} of the diagonal, "
          f"image term {'on' if args.image else 'off'}, alpha {options.alpha:g}"
          f"{', neighbour lists once per frame' if args.refresh_once else ''}"
          f"{f', Adam epsilon {args.adam_epsilon:g}' if args.adam_epsilon else ''}")
    print("| frame | ctrl max | ctrl median | tangential | limit mean | gain |")
    print("|---:|---:|---:|---:|---:|---:|")
    rows = []
    for t, (a, b) in enumerate(zip(base, other)):
        delta = b - a
        n = limit_normals(a, F)
        normal2 = np.sum(delta * n, axis=1) ** 2
        total2 = np.sum(delta * delta, axis=1)
        tangential = float(1.0 - normal2.sum() / max(total2.sum(), 1e-300))
        dist = np.sqrt(total2) / diag
        La, Lb = limit_mesh(a, F, 2)[0], limit_mesh(b, F, 2)[0]
        limit_mean = float(np.linalg.norm(La - Lb, axis=1).mean() / diag)
        row = {"frame": FRAMES[t], "ctrl_max": float(dist.max()), "ctrl_median": float(np.median(dist)),
               "tangential": tangential, "limit_mean": limit_mean, "gain": float(dist.max() / args.eps)}
        rows.append(row)
        print(f"| {FRAMES[t]} | {row['ctrl_max']:.2e} | {row['ctrl_median']:.2e} | {tangential:.2f} | "
              f"{limit_mean:.2e} | {row['gain']:.1f} |", flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"eps": args.eps, "image": args.image, "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
