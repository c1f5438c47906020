"""The ``mi-loop fit-images`` job: read a capture, fit shape and albedo, write OUTDIR.

Outputs (written together at the end, nothing half-written):

- ``control.ply``: the control mesh with its albedo as vertex colours (8-bit
  sRGB ``red green blue`` and float linear ``albedo_r albedo_g albedo_b``);
  a ``loop_subdiv`` shape reads both back;
- ``limit.ply``: the limit surface at level 3 with exact limit normals and colours;
- ``limit.glb``: the same at the viewer's level (``--view-level``, default 2) as
  glTF 2.0 binary, the albedo as linear ``COLOR_0``;
- ``report.json``: ``input``, ``params`` (the options), ``lighting``, ``stages``
  (control vertices, level, image size, iterations, time), ``views`` (each
  photo's loss at the start and at the end, at the finest resolution, mean
  L1 over linear RGB), ``timings_s``, ``parameters`` (optimised scalars),
  ``machine``, ``variant``;
- ``report.html``: the fit in a browser, offline (:mod:`~mi_loop.app.html_report`):
  the limit surface at the viewer's level coloured by its albedo, the control
  cage, the cameras' frusta, the photos next to renders of the fit from the
  same cameras, the per-view losses and the loss plot;
- ``progress.png``: four photos (composited over the lighting), the renders
  of the start and of the fit from the same cameras, and the fit's geometry
  alone: grey, lit from above the camera's right (relief in the geometry shows
  there, relief painted into the albedo does not);
- ``loss.png``: the image loss per iteration, stages marked;
- ``holdout.png`` (with ``--holdout K``): the photos left out of the fit, renders
  of the fit from their cameras, and where the silhouettes agree.

Held-out views (``--holdout K``, :mod:`mi_loop.fitting.holdout`): the photos
``i % K == K - 1`` are left out of everything the fit sees (the hull, the
template, the image loss); ``views`` lists the fitted ones. Afterwards each
held-out photo is rendered from the fitted limit surface (the fit's
tessellation level, its albedo, the lighting, at the finest stage's size,
:func:`~mi_loop.render.captures.render_views`) and scored: the silhouette IoU
of the render's alpha against the photo's mask, and the PSNR of sRGB values
inside the photo's mask (both thresholded at 0.5; pixels the photo did not see,
``valid < 0.5``, left out). ``report.json``'s ``holdout`` holds ``k``, each
view's ``index``, ``name``, ``iou`` and ``psnr_db``, and their means and
medians (null without ``--holdout``).
"""
from __future__ import annotations

import json
import platform
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.app.results import VIEW_LEVELS, static_view
from mi_loop.fitting.options import ImageFitOptions
from mi_loop.render.variant import DEFAULT_VARIANT

__all__ = ["OUTPUTS", "run"]

#: The files ``mi-loop fit-images`` writes into OUTDIR, in this order.
OUTPUTS = ("control.ply", "limit.ply", "limit.glb", "report.json", "report.html", "progress.png", "loss.png")

#: Views shown in ``progress.png``.
SHOWN = 4


def _start(init: Path | None, log):
    """A start mesh from ``--init MESH`` (arrays), or None (``options.init`` decides)."""
    if init is None:
        return None
    from mi_loop.mesh.topology import validate_mesh

    mesh = io.read_control_mesh(init)
    if mesh.n_split:
        log.warning(f"--init '{init}': {mesh.n_split} polygons split into triangles")
    validate_mesh(mesh.V, mesh.F)
    return mesh.V, mesh.F


def _finest(views, options: ImageFitOptions):
    """The views at the finest stage's size (as read: :func:`run` reads at ``options.resolution``)."""
    longest = max(max(v.camera.width, v.camera.height) for v in views)
    scale = 1.0 if options.resolution is None else min(1.0, options.resolution / longest)
    return [v.resized(scale) if scale < 1 else v for v in views]


def _evaluate(result, views, emitters, options, log):
    """Per-view losses and renders of the start and of the fit at the finest resolution."""
    import mitsuba as mi

    from mi_loop.fitting.images import tessellation_level
    from mi_loop.render.images import ImageRenderer

    finest = _finest(views, options)
    shown = np.linspace(0, len(finest) - 1, min(SHOWN, len(finest))).round().astype(int).tolist()
    out = {}
    for name, (V, F, c) in {"start": (result.V0, result.F0, result.albedo0),
                            "end": (result.V, result.F, result.albedo)}.items():
        r = ImageRenderer(V, F, finest, emitters, albedo=c, level=tessellation_level(len(F), options.triangles),
                          spp=options.spp, integrator=options.integrator, lighting=result.lighting)
        x, a = mi.Float(V.ravel().astype(np.float32)), mi.Float(c.ravel().astype(np.float32))
        out[name] = {"losses": r.losses(x, a, seed=99, spp=4 * options.spp),
                     "images": [np.asarray(r.render(x, a, k, seed=7, spp=4 * options.spp)) for k in shown]}
        out.setdefault("targets", [np.asarray(r.targets[k]) for k in shown])   # the same for both
    out["relief"] = _relief(result, [finest[k].camera for k in shown], options)
    log.say(f"mean L1 over the {len(finest)} photos: {np.mean(out['start']['losses']):.4f} at the start, "
            f"{np.mean(out['end']['losses']):.4f} at the end")
    return out, shown


def _relief(result, cameras, options) -> list:
    """The fit's geometry alone under a side light (:func:`~mi_loop.render.captures.render_geometry`)."""
    from mi_loop.fitting.images import tessellation_level
    from mi_loop.render.captures import render_geometry

    P, F, N, _ = _limit(result.V, result.F, result.albedo, tessellation_level(len(result.F), options.triangles))
    return render_geometry(P, F, N, cameras, spp=4 * options.spp)


def _holdout(result, views, held, emitters, options, log) -> tuple:
    """Render the held-out photos ``held`` (indices into ``views``) from the fit and score them (module docstring):
    ``(report section, photos, renders)``."""
    from mi_loop.fitting.holdout import masked_psnr, silhouette_iou
    from mi_loop.fitting.images import tessellation_level
    from mi_loop.io.srgb import linear_to_srgb
    from mi_loop.render.captures import render_views

    photos = _finest([views[i] for i in held], options)
    P, F, N, C = _limit(result.V, result.F, result.albedo, tessellation_level(len(result.F), options.triangles))
    if result.lighting is not None:      # an unseen photo's gain is the fitted photos' geometric mean, 1
        C = result.lighting.shade(C, N)
    renders = render_views(P, F, [v.camera for v in photos], emitters, colors=C, normals=N, spp=4 * options.spp,
                           seed=7, emission=result.lighting is not None)
    scores = [{"index": i, "name": photo.name, "iou": silhouette_iou(render.mask, photo.mask, photo.valid),
               "psnr_db": masked_psnr(linear_to_srgb(render.rgb), linear_to_srgb(photo.rgb), photo.mask, photo.valid)}
              for i, photo, render in zip(held, photos, renders)]
    section = {"k": options.holdout, "rule": "photos i with i % k == k - 1",
               "psnr": "sRGB in [0, 1], inside the photo's mask", "views": scores,
               **_summary(scores, "iou"), **_summary(scores, "psnr_db")}
    log.say(f"held out {len(held)} views: IoU median {section['iou_median']:.3f}, "
            f"PSNR median {section['psnr_median_db']:.2f} dB")
    for s in scores:                    # JSON has no NaN: null where a view had nothing to score
        s.update({key: s[key] if np.isfinite(s[key]) else None for key in ("iou", "psnr_db")})
    return section, photos, renders


def _summary(scores, key: str) -> dict:
    """Mean and median of ``key`` over the views where it is finite (NaN: none is): ``iou_mean``,
    ``psnr_mean_db`` (the unit suffix kept last)."""
    x = np.array([s[key] for s in scores], dtype=float)
    x = x[np.isfinite(x)]
    name, _, unit = key.partition("_")
    unit = f"_{unit}" if unit else ""
    return {f"{name}_mean{unit}": float(x.mean()) if len(x) else float("nan"),
            f"{name}_median{unit}": float(np.median(x)) if len(x) else float("nan")}


def _lighting(result, emitters) -> dict | str:
    """The report's ``lighting``: the emitters given, or the estimate (shading coefficients, gains per photo)."""
    backdrop = str(emitters) if emitters is not None else "constant environment, radiance 1"
    if result.lighting is None:
        return backdrop
    est = result.lighting.numpy()
    return {"model": "spherical harmonics, bands 0-2 (shading = sum_j s_j Y_j(n), radiance = gain * albedo * "
                     "shading)", "coefficients": est["coefficients"], "gains": est["gains"], "backdrop": backdrop}


def _limit(V, F, albedo, level: int = 3):
    return static_view(V, F, level, albedo=albedo)


def run(capture: Path, output: Path, options: ImageFitOptions, *, init=None, emitters: Path | None = None,
        variant: str = DEFAULT_VARIANT, log, view_level: int = VIEW_LEVELS["fit"]) -> list:
    """Run ``mi-loop fit-images``: fit a Loop surface and its albedo to a capture, write OUTDIR.

    Parameters
    ----------
    capture : pathlib.Path
        ``transforms.json`` of the photos, read at ``options.resolution``, the
        finest stage's longest side (:func:`~mi_loop.io.capture.read_capture`:
        undistorted, JPEGs decoded reduced, no photo kept at full size).
    output : pathlib.Path
        OUTDIR (created).
    options : ImageFitOptions
        With ``holdout`` K, every K-th photo is left out of the fit and scored (module docstring).
    init : pathlib.Path, optional
        Start control mesh (instead of ``options.init``).
    emitters : pathlib.Path, optional
        Mitsuba XML file of the capture's lighting (default: white environment).
    variant : str
        Mitsuba variant.
    log : mi_loop.app.progress.Reporter
    view_level : int
        Tessellation level of ``limit.glb`` (and of the report's viewer).

    Returns
    -------
    list of pathlib.Path
        The written files (:data:`OUTPUTS` in OUTDIR, and ``holdout.png`` with ``options.holdout``).
    """
    from mi_loop.app.image_report import holdout_grid, image_loss_plot, progress_grid
    from mi_loop.app.report import plain
    from mi_loop.app.report_data import images_page
    from mi_loop.fitting.holdout import split_views
    from mi_loop.fitting.images import fit_images
    from mi_loop.io.capture import read_capture
    from mi_loop.io.emitters import DEFAULT_EMITTERS, read_emitters
    from mi_loop.render.variant import set_variant

    t0 = time.perf_counter()
    shot = read_capture(capture, resolution=options.resolution)     # straight to the finest stage's size
    log.say(f"{capture}: {shot.format} capture, {len(shot.views)} photos, read at {shot.views[0].camera.width}x"
            f"{shot.views[0].camera.height}")
    try:
        fitted, held = split_views(len(shot.views), options.holdout)
    except ValueError as error:
        raise ValueError(f"fit-images --holdout: {str(error).removeprefix('split_views(): ')} ({capture})") from None
    views = [shot.views[i] for i in fitted]
    if held:
        log.say(f"holding out {len(held)} of the {len(shot.views)} photos (--holdout {options.holdout}): "
                + ", ".join(Path(shot.views[i].name).name for i in held))
    start = _start(init, log)
    created = io.first_missing_ancestor(output)
    out = io.ensure_writable_dir(output)
    try:
        set_variant(variant)
        lights = read_emitters(emitters) if emitters is not None else [dict(e) for e in DEFAULT_EMITTERS]
        timings = {"read": time.perf_counter() - t0}
        t = time.perf_counter()
        with log.bar("fitting") as update:
            result = fit_images(views, lights, options, start=start,
                                progress=lambda i, n, k, loss: update(i, n, f"stage {k} L1={loss:.4f}"))
        timings["fit"] = time.perf_counter() - t
        stages = ", ".join(f"{s['n_vertices']} vertices at {s['width']}x{s['height']}" for s in result.stages)
        log.say(f"fitted {len(result.V)} control vertices ({stages}) in {timings['fit']:.1f} s")
        t = time.perf_counter()
        evaluation, shown = _evaluate(result, views, lights, options, log)
        holdout, held_grid = None, None
        if held:
            holdout, photos, renders = _holdout(result, shot.views, held, lights, options, log)
            held_grid = holdout_grid(photos, renders)
        limit = _limit(result.V, result.F, result.albedo)
        view = _limit(result.V, result.F, result.albedo, view_level)    # (V, F, N, colours): limit.glb, the report
        grid, loss = progress_grid(evaluation, shown), image_loss_plot(result.history)
        timings["report"] = time.perf_counter() - t
        report = {"input": str(capture), "params": asdict(options), "init": str(init or options.init),
                  "lighting": _lighting(result, emitters),
                  "stages": result.stages, "parameters": {"control_points": result.V.size,
                                                          "albedo": result.albedo.size if options.albedo_lr > 0 else 0},
                  "views": [{"name": v.name, "loss_start": s, "loss_end": e} for v, s, e in
                            zip(views, evaluation["start"]["losses"], evaluation["end"]["losses"])],
                  "holdout": holdout, "timings_s": timings, "machine": platform.node(), "variant": variant}
        t = time.perf_counter()
        page = images_page(result, view, views, evaluation, shown, report, loss, holdout_png=held_grid)
        timings["report_html"] = time.perf_counter() - t
        with io.staged_outputs(out) as stage:
            io.write_ply(stage / "control.ply", result.V, result.F, colors=np.clip(result.albedo, 0, 1))
            io.write_ply(stage / "limit.ply", limit[0], limit[1], normals=limit[2], colors=limit[3])
            io.write_glb(stage / "limit.glb", *view)
            io.write_text(stage / "report.json", json.dumps(plain(report), indent=2) + "\n")
            io.write_text(stage / "report.html", page)
            io.write_png(stage / "progress.png", grid)
            io.write_png(stage / "loss.png", loss)
            if held:
                io.write_png(stage / "holdout.png", held_grid)
    except BaseException:
        io.remove_if_empty(created, out)
        raise
    paths = [out / name for name in OUTPUTS + (("holdout.png",) if held else ())]
    log.wrote(*paths)
    return paths
