"""What determinism costs per iteration: deterministic gathers, atomics, one thread, the image term.

One process, side by side on the same data, medians over ``--runs`` timed
iterations after ``--warmup`` untimed ones (kernels compiled and cached):

- ``geometric``: one static-fit iteration on the merged bunny range scan
  (limit samples at level 1, IMLS + coverage + ARAP forward and backward,
  ARAP rotations, one Adam step), with
  - ``deterministic``: mi_loop's gathers (:mod:`mi_loop.ad.sparse`, transposed
    gathers in the reverse pass; the default);
  - ``atomics``: the same energy with plain ``dr.gather`` (scatter-add atomics
    in the reverse pass; what mi_loop did before);
  - ``one thread``: the atomics version with ``dr.set_thread_count(1)``
    (determinism by serialising everything).
- ``image``: one view of the image term on a 4-camera rig (:class:`~mi_loop.render.images.ImageRenderer`,
  ``direct_projective``, 96x96, 4 spp, level-1 limit surface of the same cage) forward and backward,
  default and with the reverse render on one thread (``--deterministic``);
  and the same render with ``direct_projective``'s default ``sppi`` instead
  of ``sppi: 0`` (gradients of indirect visibility: shadows), the setting a
  Mitsuba-tutorial-style loop gets unless it says otherwise.

Usage::

    .venv/bin/python bench/bench_iteration.py [--vertices 1000 4667] [--runs 15] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCAN = ROOT.parent / "shared" / "data" / "scans" / "bunny_rangescans_merged_stride3.ply"


def _median_ms(step, runs, warmup):
    import drjit as dr

    for _ in range(warmup):
        step()
    times = []
    for _ in range(runs):
        dr.sync_thread()
        t = time.perf_counter()
        step()
        dr.sync_thread()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def geometric_step(P, N, n_vertices):
    """A closure running one fit iteration, and its template (normalised units)."""
    import drjit as dr
    import mitsuba as mi

    from mi_loop.ad.control import ControlPoints
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.coverage import Coverage
    from mi_loop.energies.imls import IMLS
    from mi_loop.fitting.static import Normalisation, sample_parameters
    from mi_loop.fitting.template import make_template

    norm = Normalisation.of(P)
    Pn = norm.forward(P)
    V0, F, _ = make_template(Pn, N, n_vertices)
    op = LimitOperator(F, len(V0), *sample_parameters(F, len(V0), "level1"), derivatives=False)
    imls, arap = IMLS(Pn, N), ARAP(V0, F)
    cover = Coverage(Pn, N, tree=imls.tree)
    Q0 = np.array(op.positions(mi.Float(V0.ravel().astype(np.float32))), dtype=np.float64).T
    imls.update(Q0)
    cover.update(Q0)
    opt = dr.opt.Adam(lr=1e-4, params={"x": mi.Float(V0.ravel().astype(np.float32))})
    alpha = dr.opaque(mi.Float, 0.001 / len(V0))

    def step():
        x = ControlPoints(opt["x"])
        Q = op.positions(x)
        E = imls.energy(Q, reduce="mean") + 3.0 * cover.energy(Q) + alpha * arap.energy(x, arap.rotations(x))
        dr.backward(E)
        opt.step()
        dr.eval(opt["x"])
    return step, (V0, F)


def image_step(V0, F, deterministic, sppi_default=False):
    import drjit as dr
    import mitsuba as mi

    from mi_loop.render.cameras import rig_cameras
    from mi_loop.render.captures import camera_scene, render_targets
    from mi_loop.render.images import ImageRenderer
    from mi_loop.render.scene import rig_emitters

    box = (V0.min(0) - 0.1, V0.max(0) + 0.1)
    cameras, emitters, grey = rig_cameras(4, box, 96), rig_emitters(box), np.full(V0.shape, 0.6)
    targets = render_targets(V0 * 1.02, F, cameras, emitters, albedo=grey, spp=16)
    renderer = ImageRenderer(V0, F, targets, emitters, albedo=grey, level=1, spp=4, deterministic=deterministic)
    if sppi_default:      # the same scene with direct_projective's own sppi
        renderer.scene = camera_scene(renderer.shape, cameras, emitters, integrator={"type": "direct_projective"},
                                      spp=4)
        renderer.params = mi.traverse(renderer.scene)
        renderer.params.keep(list(renderer.keys.values()))
    x = mi.Float(V0.ravel().astype(np.float32))
    dr.enable_grad(x)

    def step():
        renderer.backward(x, None, [1], seed=3)
        dr.eval(dr.grad(x))
    return step


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, nargs="+", default=[1000, 4667])
    parser.add_argument("--runs", type=int, default=15)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)

    import drjit as dr

    import mi_loop
    from mi_loop.ad import sparse
    from mi_loop.io import load_oriented_points

    mi_loop.set_variant("llvm_ad_rgb")
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    print(f"# bench_iteration: commit {commit}, {os.cpu_count()} cores, Dr.Jit threads {dr.thread_count()}, "
          f"load {os.getloadavg()[0]:.2f}; median of {args.runs} iterations, ms")
    P, N, _ = load_oriented_points(SCAN)
    deterministic_call = sparse.IndexMap.__call__
    rows = []
    print("| control vertices | deterministic | atomics | one thread | image view | image view, --deterministic "
          "| image view, default sppi |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for n in args.vertices:
        step, (V0, F) = geometric_step(P, N, n)
        t_det = _median_ms(step, args.runs, args.warmup)
        sparse.IndexMap.__call__ = lambda self, x: dr.gather(type(x), x, self.index)
        try:
            t_atomic = _median_ms(step, args.runs, args.warmup)
            threads = dr.thread_count()
            dr.set_thread_count(1)
            try:
                t_one = _median_ms(step, args.runs, args.warmup)
            finally:
                dr.set_thread_count(threads)
        finally:
            sparse.IndexMap.__call__ = deterministic_call
        t_img = _median_ms(image_step(V0, F, False), max(3, args.runs // 3), 2)
        t_img_det = _median_ms(image_step(V0, F, True), max(3, args.runs // 3), 2)
        t_img_sppi = _median_ms(image_step(V0, F, False, sppi_default=True), 3, 1)
        rows.append({"vertices": n, "deterministic_ms": t_det, "atomics_ms": t_atomic, "one_thread_ms": t_one,
                     "image_view_ms": t_img, "image_view_deterministic_ms": t_img_det,
                     "image_view_default_sppi_ms": t_img_sppi})
        print(f"| {n} | {t_det:.1f} | {t_atomic:.1f} | {t_one:.1f} | {t_img:.0f} | {t_img_det:.0f} | "
              f"{t_img_sppi:.0f} |", flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"commit": commit, "cores": os.cpu_count(), "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
