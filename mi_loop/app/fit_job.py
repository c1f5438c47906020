"""The ``mi-loop fit`` and ``mi-loop compare`` jobs: read, fit, measure, draw, write.

Everything is computed before the first output file is written; the files are
written into a staging directory and moved into place together, so a failed or
interrupted run leaves no partial output (and removes the directories it created).
"""
from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

from mi_loop import io


def load_input(path: Path, say):
    """Oriented points of INPUT (normals estimated when missing) and a render target."""
    from mi_loop.io.points import load_oriented_points
    from mi_loop.mesh.points import estimate_normals

    P, N, info = load_oriented_points(path)
    if N is None:
        say(f"{path.name}: {len(P)} points without normals: estimating and orienting normals")
        N = estimate_normals(P)
        info["normals_estimated"] = True
    target = ("points", P, N)
    if info.get("kind") == "mesh":
        V, F = io.read_mesh(path)
        target = ("mesh", V, F)
    return P, N, target, info


def _progress(quiet: bool):
    if quiet:
        return None, lambda: None
    from tqdm import tqdm

    bars = []   # created at the first iteration, so early errors print one line only

    def update(i, total, energy):
        if not bars:
            bars.append(tqdm(total=total, desc="fitting", unit="it", leave=False, dynamic_ncols=True))
        bars[0].set_postfix_str(f"E={energy:.3e}", refresh=False)
        bars[0].update(i - bars[0].n)

    return update, lambda: bars and bars[0].close()


def run(args, start, say):
    """Run ``mi-loop fit``; return the written paths."""
    from mi_loop.datasets import noisy_torus_points
    from mi_loop.fitting.static import fit
    from mi_loop.metrics import two_sided
    from mi_loop.app.report import loss_plot, side_by_side
    from mi_loop.render.variant import set_variant

    if args.vertices is not None and args.template is None and args.vertices < 4:
        raise ValueError(f"fit: --vertices must be at least 4, got {args.vertices}")
    if args.demo:
        P, N, clean = noisy_torus_points()
        target, info = ("points", P, N), {"kind": "points", "source": "built-in noisy torus",
                                          "n_points": len(P)}
        say(f"built-in noisy torus: {len(P)} points (0.5% noise, 1% outliers)", start)
    else:
        P, N, target, info = load_input(args.input, lambda m: say(m, start))
        say(f"{args.input.name}: {len(P)} oriented points", start)
    template = None
    if args.template is not None:
        from mi_loop.mesh.topology import validate_mesh

        V_t, F_t = io.read_mesh(args.template)
        validate_mesh(V_t, F_t, f"--template {args.template}")
        template = (V_t, F_t)
    created = io.first_missing_ancestor(args.output)
    out = io.ensure_writable_dir(args.output)
    try:
        set_variant("llvm_ad_rgb")
        say("fitting (template, limit operator, IMLS + ARAP with Adam)", start)
        update, close = _progress(args.quiet)
        try:
            result = fit(P, N, n_vertices=args.vertices, template=template, alpha=args.alpha,
                         h0=args.h0, samples=args.samples, max_iterations=args.iterations,
                         cover=args.cover, seed=args.seed, progress=update)
        finally:
            close()
        say(f"fitted {len(result.V)} control vertices in {result.params['iterations']} iterations "
            f"({result.timings['total']:.1f} s)", start)
        t = time.perf_counter()
        V_lim, F_lim, N_lim = result.limit_mesh(3)
        metrics = two_sided(V_lim, F_lim, P if target[0] == "points" else target[1],
                            None if target[0] == "points" else target[2], seed=args.seed)
        result.timings["metrics"] = time.perf_counter() - t
        say(f"distance to the data (relative to bbox diagonal): mean {metrics['mean']:.2e}, "
            f"RMS {metrics['rms']:.2e}, Hausdorff {metrics['hausdorff']:.2e}", start)
        t = time.perf_counter()
        loss = loss_plot(result.history)
        render = side_by_side(target, result.V, result.F)
        result.timings["pictures"] = time.perf_counter() - t
        report = {"input": str(args.input) if args.input else info["source"], "input_info": info,
                  "params": result.params, "timings_s": result.timings, "metrics": metrics,
                  "template": result.info["template"], "machine": platform.node(),
                  "final_energy": {k: result.history[k][-1] for k in ("imls", "cover", "arap", "total")}}
        with io.staged_outputs(out) as stage:
            io.write_ply(stage / "control.ply", result.V, result.F)
            io.write_ply(stage / "limit.ply", V_lim, F_lim, normals=N_lim)
            io.write_text(stage / "report.json", json.dumps(_plain(report), indent=2) + "\n")
            io.write_png(stage / "loss.png", loss)
            io.write_png(stage / "render.png", render)
    except BaseException:
        io.remove_if_empty(created, out)
        raise
    return [out / name for name in ("control.ply", "limit.ply", "report.json", "loss.png", "render.png")]


def _plain(x):
    """JSON-friendly copy (NumPy scalars and arrays to Python)."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def compare(fitted: Path, target: Path, plain_mesh: bool = False) -> dict:
    """Distances between FITTED (limit surface of a control mesh, or a mesh) and TARGET."""
    from mi_loop.io.points import load_oriented_points
    from mi_loop.subdiv.masks import limit_mesh
    from mi_loop.metrics import nps_metrics, two_sided
    from mi_loop.mesh.topology import validate_mesh

    V, F = io.read_mesh(fitted)
    if not plain_mesh:
        V, F, _ = validate_mesh(V, F, f"compare: {fitted}")
        V, F, _ = limit_mesh(V, F, level=3)
    P, _, info = load_oriented_points(target)
    out = {"two_sided": None, "nps": None}
    if info.get("kind") == "mesh":
        Vt, Ft = io.read_mesh(target)
        out["two_sided"] = two_sided(V, F, Vt, Ft)
        out["nps"] = nps_metrics((V, F), (Vt, Ft))
    else:
        out["two_sided"] = two_sided(V, F, P)
        del out["nps"]
    return _plain(out)
