"""Time per iteration of each fit, through its public function, on the code of this checkout.

Runs in one process, each fit once after an untimed warm-up of the same fit
(kernels compiled and cached), and times every iteration by the fit's own
progress callback (``perf_counter`` between consecutive calls, with
``dr.sync_thread``): the median and the mean over the timed iterations.

- ``static``: :func:`mi_loop.fitting.static.fit` on the README demo's noisy torus
  (20,000 points, 1000 control vertices, ``alpha`` 0.001 given so that no
  selection runs, at most 60 iterations, tolerance 1e-9: both codes take the
  same steps);
- ``images``: :func:`mi_loop.fitting.images.fit_images` on a synthetic capture
  (``bench/captures.py spot --variants grey``: 16 photos of 256^2), one stage
  (``refinements`` 0) of 40 iterations at 128^2 from the hull's template;
- ``sequence``: :func:`mi_loop.fitting.sequence.fit_frame` on frame 0 of a
  simulated capture (``bench/capture_sequence.py spot``: depth points of 3
  cameras and 20 photos of 128^2) from a 1000-vertex template of the clean
  frame, 60 iterations with the image term refreshed every 6 (the defaults).

The same script runs on the code before the core issue (``PYTHONPATH=<old
checkout>``): it detects which API it has. ``solve`` times the smoothing step
alone, the old host round trip and the device solve side by side. Usage::

    .venv/bin/python bench/bench_loop.py --captures DIR --sequence DIR [--json out.json]
    PYTHONPATH=/path/to/old/checkout .venv/bin/python bench/bench_loop.py ...   # the same on older code
"""
from __future__ import annotations

import argparse
import inspect
import json
import os
import time
from pathlib import Path

import numpy as np

import mi_loop


class Clock:
    """Progress callback recording the time of every iteration (after a device sync)."""

    def __init__(self):
        self.t = [time.perf_counter()]

    def __call__(self, *args):
        import drjit as dr

        dr.sync_thread()
        self.t.append(time.perf_counter())

    def summary(self, skip: int = 2) -> dict:
        dt = 1e3 * np.diff(self.t)[skip:]
        return {"iterations": int(len(dt)), "median_ms": float(np.median(dt)), "mean_ms": float(np.mean(dt))}


def static_case() -> dict:
    from mi_loop.datasets import noisy_torus_points
    from mi_loop.fitting import static

    P, N, _ = noisy_torus_points()
    # a tolerance this small stops nothing early but keeps the step halvings of both codes (before the core, 0
    # halved the step after 12 iterations without improvement; now 0 turns the convergence test off)
    settings = dict(n_vertices=1000, alpha=0.001, iterations=60, tolerance=1e-9)
    new_api = "options" in inspect.signature(static.fit).parameters

    def run(progress):
        if new_api:
            from mi_loop.fitting.options import FitOptions

            return static.fit(P, N, FitOptions(**settings), progress=progress)
        old = {("max_iterations" if k == "iterations" else k): v for k, v in settings.items()}
        return static.fit(P, N, progress=progress, **old)

    run(None)
    clock = Clock()
    run(clock)
    return clock.summary()


def images_case(capture: Path) -> dict:
    from dataclasses import fields

    from mi_loop.fitting.images import fit_images
    from mi_loop.fitting.options import ImageFitOptions
    from mi_loop.io.capture import read_capture

    views = list(read_capture(capture).views)
    names = {f.name for f in fields(ImageFitOptions)}
    settings = dict(refinements=0, iterations=40, resolution=128, n_vertices=900)
    settings[("tolerance" if "tolerance" in names else "stall")] = 0.0
    options = ImageFitOptions(**settings)
    emitters = [{"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}]
    fit_images(views, emitters, options)
    clock = Clock()
    fit_images(views, emitters, options, progress=clock)
    return clock.summary()


def sequence_case(root: Path) -> dict:
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.fitting import sequence
    from mi_loop.fitting.options import SequenceOptions
    from mi_loop.fitting.static import Normalisation, sample_parameters
    from mi_loop.fitting.template import mesh_template
    from mi_loop.io.capture import read_capture
    from mi_loop.io.points import load_oriented_points
    from mi_loop.mesh.points import estimate_normals
    from mi_loop.subdiv.masks import vertex_samples

    with np.load(root / "clean.npz") as z:
        Vc, Fc = z["vertices"][0], z["faces"]
    P, N, _ = load_oriented_points(root / "depth" / "0000.ply")
    N = estimate_normals(P) if N is None else N
    norm = Normalisation.of(P)
    x0, F, _ = mesh_template(norm.forward(Vc), Fc, 1000)
    Pn = norm.forward(P)
    names = set(inspect.signature(SequenceOptions).parameters)
    options = SequenceOptions(**{("iterations" if "iterations" in names else "geo_iterations"): 60})
    op = LimitOperator(F, len(x0), *sample_parameters(F, len(x0), options.samples), derivatives=True)
    vertex_op = LimitOperator(F, len(x0), *vertex_samples(F, len(x0)), derivatives=True)
    views = list(read_capture(root / "images" / "0000" / "transforms.json").views)
    emitters = [{"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}]
    albedo = np.full((len(x0), 3), 0.5)

    def image():
        if hasattr(sequence, "FrameImages"):
            from mi_loop.render.images import ImageRenderer

            renderer = ImageRenderer(norm.inverse(x0), F, views, emitters, albedo=albedo, level=options.level,
                                     spp=options.spp)
            return sequence.FrameImages(renderer, albedo, options.albedo_lr, None, (norm.scale, norm.centre),
                                        sequence.pixel_size([v.camera for v in views], norm.centre, norm.scale))
        from mi_loop.render.photo import PhotoRenderer  # the older code this script also times

        renderer = PhotoRenderer(norm.inverse(x0), F, albedo, views, emitters, level=options.level, spp=options.spp)
        return sequence.PhotoTerm(renderer, norm, albedo, options.albedo_lr)

    def run(progress):
        return sequence.fit_frame(x0, F, Pn, N, op, image(), options, 0, 0.02, progress, rest=x0,
                                  vertex_op=vertex_op, iterations=60)

    run(None)
    clock = Clock()
    _, info = run(clock)
    out = clock.summary()
    out["render_s"] = float(info["time_render"])
    return out


def solve_case(sizes=(2, 3, 4), runs: int = 50) -> dict:
    """The ``(I + lambda L)^-1`` step of a gradient alone, the old way and the new, in one process.

    ``host``: the gradient copied to NumPy, three SciPy solves with a factor made
    once (``scipy.sparse.linalg.factorized``), copied back (what the image and
    sequence fits did every iteration); ``device``: :meth:`SmoothParameterisation.solve`
    (cholespy's factor where the variant runs, no copy). Icospheres of level 2-4
    (162-2562 control vertices), lambda 20; median ms over ``runs`` calls.
    """
    import drjit as dr
    import mitsuba as mi
    import scipy.sparse.linalg as spla

    from mi_loop.ad.smoothing import SmoothParameterisation
    from mi_loop.datasets import icosphere

    out = {}
    for level in sizes:
        V, F = icosphere(level)
        p = SmoothParameterisation(F, len(V), 20.0)
        factor = spla.factorized(p.M.tocsc())
        g = mi.Float(np.random.default_rng(0).normal(size=3 * len(V)).astype(np.float32))

        def host(g=g, factor=factor):
            G = np.array(g, dtype=np.float64).reshape(-1, 3)
            return mi.Float(np.stack([factor(G[:, k]) for k in range(3)], axis=1).astype(np.float32).ravel())

        row = {}
        for name, step in (("host", host), ("device", lambda p=p, g=g: p.solve(g))):
            times = []
            for i in range(runs + 3):
                dr.sync_thread()
                t = time.perf_counter()
                dr.eval(step())
                dr.sync_thread()
                if i >= 3:
                    times.append(1e3 * (time.perf_counter() - t))
            row[f"{name}_ms"] = float(np.median(times))
        out[str(len(V))] = row
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--captures", type=Path, help="directory of bench/captures.py (holds spot_grey/)")
    parser.add_argument("--sequence", type=Path, help="directory of bench/capture_sequence.py's spot")
    parser.add_argument("--cases", nargs="+", default=["static", "images", "sequence"],
                        help="static, images, sequence (both codes), solve (this code: old and new way)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    mi_loop.set_variant("llvm_ad_rgb")
    results = {"code": str(Path(mi_loop.__file__).parents[1]), "cores": os.cpu_count()}
    for case in args.cases:
        if case == "static":
            results[case] = static_case()
        elif case == "images":
            results[case] = images_case(args.captures / "spot_grey" / "transforms.json")
        elif case == "solve":
            results[case] = solve_case()
        else:
            results[case] = sequence_case(args.sequence)
        print(case, results[case], flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
