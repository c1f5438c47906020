"""The pictures and the page of a ``fit-sequence`` run, drawn from its finished frames.

- :func:`write_pictures`: ``drift.png`` (distances, folds and drift per frame)
  and ``strip.png`` (a few frames: the photo with the largest mask next to a
  render of the fit from its camera, or target and fit, cropped to the subject);
- :func:`report_page`: ``report.html`` of every finished frame
  (:func:`~mi_loop.app.report_data.sequence_report`).
"""
from __future__ import annotations

import numpy as np

from mi_loop import io

__all__ = ["report_page", "write_pictures"]


def write_pictures(run, log) -> list:
    """Write ``drift.png`` and ``strip.png`` of every finished frame, atomically; print them.

    Parameters
    ----------
    run : mi_loop.app.sequence_frames.SequenceRun
        The run; its ``rows`` are the finished frames.
    log : mi_loop.app.progress.Reporter

    Returns
    -------
    list of pathlib.Path
    """
    from mi_loop.app.report import crop_to_content, drift_figure, figure_pixels, side_by_side, strip_figure

    rows = run.rows

    def column(key):
        return [np.nan if getattr(r, key) is None else getattr(r, key) for r in rows]

    t = np.array([r.frame for r in rows])
    drift = drift_figure(t, column("mean"), column("rms"), flipped=column("flipped_pct"), drift=column("drift_mean"))
    paths = [io.write_png(run.out / "drift.png", figure_pixels(drift))]
    picks = sorted(set(np.linspace(0, len(rows) - 1, min(4, len(rows))).round().astype(int)))
    strips = []
    for i in picks:
        frame = rows[i].frame
        control = run.out / "control" / f"{frame:04d}.ply"
        V, _ = io.read_mesh(control)
        if run.sources.captures:
            image = _photo_strip(run, frame, V, io.read_vertex_colors(control))
        else:
            image = crop_to_content(side_by_side(run.reader.target(frame), V, run.F, resolution=200, spp=16),
                                    halves=2)
        strips.append((frame, rows[i].mean, image))
    label = "photo (left), fit (right)" if run.sources.captures else "target (left), fit (right)"
    paths.append(io.write_png(run.out / "strip.png", figure_pixels(strip_figure(strips, label=label))))
    log.wrote(*paths)
    return paths


def _photo_strip(run, t: int, V_world, albedo):
    """The photo of frame ``t`` whose mask is largest next to a render of the fit from its camera, cropped."""
    from mi_loop.io.capture import read_capture
    from mi_loop.io.srgb import linear_to_srgb
    from mi_loop.mesh.geometry import vertex_normals
    from mi_loop.render.captures import render_views
    from mi_loop.subdiv.masks import limit_colors, limit_mesh

    views = list(read_capture(run.sources.captures[t]).views)
    view = max(views, key=lambda v: float(v.mask.sum()))
    Vl, Fl, _ = limit_mesh(V_world, run.F, level=2)
    colors = None if albedo is None else limit_colors(albedo, run.F, 2)
    fit = render_views(Vl, Fl, [view.camera], run.lights, colors=colors, normals=vertex_normals(Vl, Fl), spp=16)[0]
    a = view.mask[..., None]
    ys, xs = np.nonzero(np.maximum(view.mask, fit.mask) > 0.02)
    pad = max(4, int(0.08 * max(np.ptp(ys), np.ptp(xs))))
    y0, y1 = max(0, ys.min() - pad), min(view.mask.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(view.mask.shape[1], xs.max() + pad + 1)
    white = np.ones_like(view.rgb)
    photo = a * view.rgb + (1 - a) * white
    render = fit.mask[..., None] * fit.rgb + (1 - fit.mask[..., None]) * white
    both = np.concatenate([photo[y0:y1, x0:x1], render[y0:y1, x0:x1]], axis=1)
    return linear_to_srgb(np.clip(both, 0.0, 1.0))


def report_page(run, finished, view, fps: float) -> str:
    """Return ``report.html`` of every finished frame.

    Parameters
    ----------
    run : mi_loop.app.sequence_frames.SequenceRun
        The run; its ``rows`` are the finished frames.
    finished : mi_loop.app.results.Result
        The run's result directory as read back.
    view : tuple
        :func:`~mi_loop.app.results.sequence_view` of it.
    fps : float
        Frame rate of the player.

    Returns
    -------
    str
    """
    from mi_loop.app.report_data import sequence_report

    frames = [r.frame for r in run.rows]

    def target(i):
        if run.sources.reference is not None:
            ref = run.sources.reference[frames[i]]()
            return ("points", ref.vertices, None) if ref.faces is None else ("mesh", ref.vertices, ref.faces)
        return run.reader.target(frames[i])

    cages = [io.read_mesh(p) for p in finished.controls]
    return sequence_report(view, finished.names, target, (np.stack([V for V, _ in cages]), cages[0][1]), run.rows,
                           fps)
