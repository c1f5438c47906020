"""The ``mi-loop fit`` job: read, fit, measure, draw, write.

Everything is computed before the first output file is written; the files are
written into a staging directory and moved into place together, so a failed or
interrupted run leaves no partial output (and removes the directories it created).

``limit.ply`` is the limit surface at level 3 with exact limit normals;
``limit.glb`` the same surface at the viewer's level (``--view-level``,
default 2) as glTF 2.0 binary, which Blender, three.js and other viewers open.
``report.html`` shows that surface in a browser, offline (:mod:`~mi_loop.app.html_report`),
coloured by the distance to the data (with ``--demo`` also to the clean torus), with a
subsample of the data points, the control cage, the creases, the tables of
``report.json`` and the loss plot.

``report.json`` holds ``input`` and ``input_info`` (what was read, whether
normals were estimated), ``params`` (the options actually used), ``converged``,
``timings_s``, ``metrics`` (two-sided distances to the data, relative to its
bounding-box diagonal; ``flipped_area_pct``, the share of the limit surface's
area facing against the nearest data normal, and ``self_intersecting_pct`` /
``self_intersecting_faces``, the limit triangles crossed by another part of
the surface; for a mesh input ``input_self_intersecting_pct``, the same of the
input), ``template`` (its source; for ``--template`` the
polygons split into triangles and its size and offset relative to the data),
``final_energy``, ``machine``, ``variant``; with ``--demo`` also
``metrics_clean`` (the same distances to the noise-free torus: from its
points to the limit surface, and from the limit surface to the torus itself,
in closed form), and always ``noise`` (the noise level of the data against its
point spacing, which sets the ARAP weight unless ``--alpha`` is given).
"""
from __future__ import annotations

import json
import platform
import time
from pathlib import Path

from mi_loop import io
from mi_loop.app.results import FIT_OUTPUTS, VIEW_LEVELS
from mi_loop.fitting.options import FitOptions
from mi_loop.render.variant import DEFAULT_VARIANT

__all__ = ["OUTPUTS", "run"]

#: The files ``mi-loop fit`` writes into OUTDIR, in this order (:data:`mi_loop.app.results.FIT_OUTPUTS`).
OUTPUTS = FIT_OUTPUTS

_TERM_WEIGHTS = {"IMLS": None, "coverage": "cover", "ARAP": "alpha", "fold": "fold"}


def _load(input: Path | None, log):
    """``(P, N, target, info, clean)``: the data, its picture target, what was read, the clean demo surface."""
    if input is None:
        from mi_loop.datasets import noisy_torus_points

        P, N, clean = noisy_torus_points()
        log.say(f"built-in noisy torus: {len(P)} points (0.5% noise, 1% outliers)")
        return P, N, ("points", P, N), {"kind": "points", "source": "built-in noisy torus",
                                        "n_points": len(P)}, clean
    from mi_loop.app.inputs import load_input

    P, N, target, info = load_input(input, log)
    log.say(f"{input.name}: {len(P)} oriented points")
    return P, N, target, info, None


def _stage_line(options: FitOptions) -> str:
    """The terms actually on, with their weights: ``IMLS + 3 x coverage + 0.001 x ARAP + 0.01 x fold``."""
    parts = [name if weight is None else f"{name} (weight chosen for the noise)"
             if getattr(options, weight) is None else f"{getattr(options, weight):g} x {name}"
             for name, weight in _TERM_WEIGHTS.items() if name in options.terms]
    from mi_loop.app.inputs import NO_CROSSING_NOTE

    guard = NO_CROSSING_NOTE if options.no_crossing else ""
    return f"fitting: template, limit operator, then Adam on {' + '.join(parts)}{guard}"


def _fit(P, N, template, options: FitOptions, log, mesh=None):
    """Run :func:`~mi_loop.fitting.static.fit` with a progress bar; ``(result, converged)``."""
    from mi_loop.app.inputs import say_handles
    from mi_loop.fitting.static import fit

    log.say(_stage_line(options))
    with log.bar("fitting") as update:
        result = fit(P, N, options, template=template, mesh=mesh,
                     progress=lambda i, n, E: update(i, n, f"E={E:.3e}"))
    tinfo = result.info["template"]
    if "feature_curves" in tinfo:
        log.say(f"sharp features: {tinfo['feature_curves']} feature curves ({tinfo['feature_edges']} mesh edges "
                f"above {tinfo['feature_angle']:g} degrees), {tinfo['creases']} crease edges on the control mesh")
    elif options.features == "auto" and mesh is not None:
        log.say("sharp features: none found (no feature curve of at least 5 % of the diagonal)")
    say_handles(tinfo, options.template_genus, log)
    noise = result.info["noise"]
    log.say(f"noise: {noise['sigma_diagonal']:.2e} of the diagonal, {noise['ratio']:.2f} x the point spacing; "
            f"ARAP weight {result.params['alpha']:g} ({noise['alpha']})")
    n, converged = result.params["iterations_run"], result.converged
    how = (f"converged after {n} iterations (best energy improved by less than {options.tolerance:g})"
           if converged else f"stopped at the iteration cap ({n}) before converging; raise --iterations")
    log.say(f"fitted {len(result.V)} control vertices: {how} ({result.timings['total']:.1f} s)")
    return result, converged


def _measure(result, target, P, clean, seed, log):
    """Two-sided distances to the data (and to the clean demo surface); ``(metrics, clean_metrics, limit)``."""
    from mi_loop.metrics import two_sided

    t = time.perf_counter()
    V_lim, F_lim, N_lim = result.limit_mesh(3)
    metrics = two_sided(V_lim, F_lim, P if target[0] == "points" else target[1],
                        None if target[0] == "points" else target[2], seed=seed)
    log.say(f"distance to the data (relative to its bbox diagonal): mean {metrics['mean']:.2e}, "
            f"RMS {metrics['rms']:.2e}, Hausdorff {metrics['hausdorff']:.2e}")
    metrics_clean = None
    if clean is not None:
        from mi_loop.datasets import torus_distance

        metrics_clean = two_sided(V_lim, F_lim, clean, seed=seed, exact=torus_distance)
        log.say(f"distance to the clean torus (without noise and outliers): mean "
                f"{metrics_clean['mean']:.2e}, RMS {metrics_clean['rms']:.2e}, "
                f"Hausdorff {metrics_clean['hausdorff']:.2e}")
    metrics.update(_folds(V_lim, F_lim, target, log, guarded=bool(result.params.get("no_crossing"))))
    result.timings["metrics"] = time.perf_counter() - t
    return metrics, metrics_clean, (V_lim, F_lim, N_lim)


def _folds(V_lim, F_lim, target, log, guarded: bool = False) -> dict:
    """Flipped area and self-intersections of the limit surface (and of a mesh input), warned about when non-zero;
    ``guarded``: the fit ran with ``--no-crossing``."""
    from mi_loop.metrics import flipped_fraction, self_intersections

    if target[0] == "points":
        flipped = flipped_fraction(V_lim, F_lim, target[1], N_target=target[2])
    else:
        flipped = flipped_fraction(V_lim, F_lim, target[1], target[2])
    crossed = self_intersections(V_lim, F_lim)
    out = {"flipped_area_pct": 100.0 * flipped, "self_intersecting_pct": 100.0 * float(crossed.mean()),
           "self_intersecting_faces": int(crossed.sum())}
    source = ""
    if target[0] == "mesh":
        out["input_self_intersecting_pct"] = 100.0 * float(self_intersections(target[1], target[2]).mean())
        source = f"; the input has {out['input_self_intersecting_pct']:.3g} %"
    log.say(f"folds: {out['flipped_area_pct']:.3g} % of the limit surface's area faces against the data, "
            f"{out['self_intersecting_faces']} of {len(F_lim)} limit faces intersect the surface elsewhere")
    if flipped > 0:
        log.warning(f"{out['flipped_area_pct']:.3g} % of the limit surface's area faces against the nearest data "
                    "normal (a fold, or a part too thin for the control mesh): see render.png; more --vertices "
                    "or a larger --fold may remove it")
    if crossed.any():
        log.warning(f"{out['self_intersecting_faces']} of {len(F_lim)} limit faces "
                    f"({out['self_intersecting_pct']:.3g} %) intersect another part of the surface{source}; "
                    + ("more --vertices or a larger --fold may remove them (--no-crossing keeps apart only limit "
                       "triangles whose control faces share no corner)" if guarded else
                       "more --vertices, a larger --fold or --no-crossing may remove them"))
    return out


def _clean_field(clean, metrics_clean):
    """The demo's second colouring in report.html: ``('the clean torus', distance relative to its diagonal)``."""
    if clean is None:
        return None
    from mi_loop.datasets import torus_distance

    return "the clean torus", lambda X: torus_distance(X) / metrics_clean["diagonal"]


def _report(input, info, result, converged, metrics, metrics_clean, template_info, variant):
    report = {"input": str(input) if input is not None else info["source"], "input_info": info,
              "params": result.params, "converged": converged, "timings_s": result.timings,
              "metrics": metrics, "template": template_info or result.info["template"],
              "noise": result.info["noise"],
              "machine": platform.node(), "variant": variant,
              "final_energy": {k: result.history[k][-1] for k in ("imls", "cover", "arap", "fold", "total")}}
    if metrics_clean is not None:
        report["metrics_clean"] = metrics_clean
        report["metrics_note"] = ("metrics: distances to the noisy input points (outliers included); "
                                  "metrics_clean: to the noise-free torus the points were drawn from")
    return report


def run(input: Path | None, output: Path, options: FitOptions, *, template: Path | None = None,
        variant: str = DEFAULT_VARIANT, log, view_level: int = VIEW_LEVELS["fit"]) -> list:
    """Run ``mi-loop fit``: fit ``input`` (None: the built-in noisy torus), write OUTDIR.

    Parameters
    ----------
    input : pathlib.Path or None
        Points or mesh file; None fits the demo torus.
    output : pathlib.Path
        OUTDIR (created).
    options : FitOptions
    template : pathlib.Path, optional
        Control mesh to start from (checked against the data's frame).
    variant : str
        Mitsuba variant.
    log : mi_loop.app.progress.Reporter
    view_level : int
        Tessellation level of ``limit.glb`` (and of the report's viewer).

    Returns
    -------
    list of pathlib.Path
        The written files (:data:`OUTPUTS` in OUTDIR), also printed by ``log``.
    """
    from mi_loop.app.report import loss_plot, plain, side_by_side
    from mi_loop.app.report_data import fit_page
    from mi_loop.render.variant import set_variant

    P, N, target, info, clean = _load(input, log)
    V_t = template_info = None
    if template is not None:
        from mi_loop.app.inputs import read_template

        V_t, F_t, template_info = read_template(template, P, f"fit --template '{template}'", log)
    created = io.first_missing_ancestor(output)
    out = io.ensure_writable_dir(output)
    try:
        set_variant(variant)
        mesh = target[1:] if target[0] == "mesh" and V_t is None else None
        result, converged = _fit(P, N, None if V_t is None else (V_t, F_t), options, log, mesh)
        metrics, metrics_clean, limit = _measure(result, target, P, clean, options.seed, log)
        view = result.limit_mesh(view_level)          # (V, F, N) of the viewer: limit.glb (and the report)
        t = time.perf_counter()
        loss = loss_plot(result.history)
        render = side_by_side(target, result.V, result.F, creases=result.creases)
        result.timings["pictures"] = time.perf_counter() - t
        report = _report(input, info, result, converged, metrics, metrics_clean, template_info, variant)
        t = time.perf_counter()
        page = fit_page(result, view, view_level, target, report, loss, _clean_field(clean, metrics_clean))
        result.timings["report_html"] = time.perf_counter() - t
        with io.staged_outputs(out) as stage:
            io.write_ply(stage / "control.ply", result.V, result.F, creases=result.creases)
            io.write_ply(stage / "limit.ply", limit[0], limit[1], normals=limit[2])
            io.write_glb(stage / "limit.glb", *view)
            io.write_text(stage / "report.json", json.dumps(plain(report), indent=2) + "\n")
            io.write_text(stage / "report.html", page)
            io.write_png(stage / "loss.png", loss)
            io.write_png(stage / "render.png", render)
    except BaseException:
        io.remove_if_empty(created, out)
        raise
    paths = [out / name for name in OUTPUTS]
    log.wrote(*paths)
    return paths
