"""The ``mi-loop fit-sequence`` job: read frames, fit each, write each atomically, resume bit for bit.

Layout of OUTDIR (every path is printed on stdout as it is written; the files
that the run reads back are those of :mod:`mi_loop.io.runs`, which documents
their fields):

- ``control/0000.ply ...``: the fitted control mesh of every frame, in the
  frames' units (one connectivity for all frames), with the per-vertex
  albedo as colours when the frames come with photos;
- ``limit/0000.ply ...``: its limit surface (level-2 tessellation, albedo too);
- ``state/0000.npz ...``: the exact state a frame leaves for ``--resume``
  (:class:`~mi_loop.io.runs.FrameState`);
- ``metrics.csv``: one row per finished frame (:class:`~mi_loop.io.runs.MetricsRow`,
  :data:`CSV_HEADER`); a frame is finished once its row is there;
- ``sequence.json``: what the run needs to continue and the options it ran with
  (:class:`~mi_loop.io.runs.RunRecord`), written before the first frame;
- ``drift.png`` and ``strip.png`` (:mod:`~mi_loop.app.sequence_pictures`), then
  ``sequence.glb`` (every finished frame as one glTF 2.0 mesh in correspondence,
  frame 0 with a morph target per frame, animated at ``fps``, at ``--view-level``)
  and ``report.html`` (the frames in a browser, offline), written together after
  the frames (and after those of ``--resume``).

The run, top-down: :func:`~mi_loop.app.sequence_sources.read_sources` (photos,
reference), :func:`~mi_loop.app.sequence_start.begin` (options as run, template,
``sequence.json``, or the resumed state), :func:`~mi_loop.app.sequence_frames.fit_frames`
(the frames, through :class:`~mi_loop.app.sequence_frames.FrameFitter`), then the
pictures and the viewer files.
"""
from __future__ import annotations

import contextlib
from pathlib import Path

from mi_loop import io
from mi_loop.app.results import VIEW_LEVELS, read_result, sequence_view, write_view
from mi_loop.app.sequence_frames import FrameFitter, SequenceRun, fit_frames
from mi_loop.app.sequence_pictures import report_page, write_pictures
from mi_loop.app.sequence_sources import read_sources
from mi_loop.app.sequence_start import begin
from mi_loop.fitting.options import SequenceOptions
from mi_loop.io.runs import CSV_HEADER, STATE_DIR
from mi_loop.render.variant import DEFAULT_VARIANT

__all__ = ["CSV_HEADER", "STATE_DIR", "run"]

#: The sub-directories of OUTDIR, one file per frame each.
_SUBDIRS = ("control", "limit", STATE_DIR)


def run(inputs, output, options: SequenceOptions, *, template: Path | None = None, resume: bool = False,
        variant: str = DEFAULT_VARIANT, log, images=None, emitters: Path | None = None,
        reference: Path | None = None, frames: slice | None = None, animation: str | None = None,
        fps: float = 24.0, view_level: int = VIEW_LEVELS["sequence"]) -> list:
    """Run ``mi-loop fit-sequence``; returns every written path (each also printed as it is written).

    Parameters
    ----------
    inputs : list of str or os.PathLike
        Frames: an NPZ, frame files, directories or quoted globs
        (:func:`mi_loop.io.read_frames`), or one animated glTF/GLB with ``animation``.
    output : pathlib.Path
        OUTDIR.
    options : SequenceOptions
        Ignored on ``resume`` (the stored ones are kept; differences are named).
        Never modified: what the run uses (:func:`~mi_loop.app.sequence_start.settle_options`)
        is a copy, recorded in ``sequence.json``.
    template : pathlib.Path, optional
        Control mesh for every frame (checked against the first frame's frame).
    resume : bool
        Continue after the last finished frame, from its exact stored state.
    variant : str
        Mitsuba variant.
    log : mi_loop.app.progress.Reporter
    images : list of str or os.PathLike, optional
        One ``transforms.json`` per frame (files, directories, globs:
        :func:`mi_loop.io.capture.list_captures`), as many as the frames.
    emitters : pathlib.Path, optional
        The photos' lighting (Mitsuba XML); default a constant environment of radiance 1.
    reference : pathlib.Path, optional
        Clean meshes in correspondence (an NPZ), one per frame, for the distances,
        folds and drift in ``metrics.csv``.
    frames : slice, optional
        The frames to fit (``--frames START:STOP:STEP``), applied alike to the
        frames, the captures and the reference.
    animation : str, optional
        Name of the glTF/GLB animation to bake (``--animation``).
    fps : float
        The frames' rate: of the baked animation and of ``sequence.glb``.
    view_level : int
        Tessellation level of ``sequence.glb`` (and of the report's viewer).

    Notes
    -----
    A run that fails (or is interrupted) before its first frame is written
    leaves nothing behind: the state file and the directories it created are
    removed. Finished frames are always kept (``--resume`` continues them).
    """
    out = Path(output)
    created = io.first_missing_ancestor(out)
    existed = {p: p.exists() for p in [out / s for s in _SUBDIRS] + [out / "sequence.json"]}
    try:
        return _run(inputs, out, options, template, resume, variant, log,
                    images=images, emitters=emitters, reference=reference, selection=frames,
                    animation=animation, fps=fps, view_level=view_level)
    except BaseException:
        with contextlib.suppress(OSError):
            if not (out / "metrics.csv").exists():
                if not existed[out / "sequence.json"]:
                    (out / "sequence.json").unlink(missing_ok=True)
                for sub in _SUBDIRS:
                    if not existed[out / sub]:
                        io.remove_if_empty(out / sub, out / sub)
                io.remove_if_empty(created, out)
        raise


def _run(inputs, out, options, template, resume, variant, log, *, images, emitters, reference, selection,
         animation, fps, view_level) -> list:
    """The run, once its outputs are guarded by :func:`run`."""
    from mi_loop.io.frames import select_frames
    from mi_loop.io.runs import read_metrics
    from mi_loop.render.variant import set_variant

    all_frames = io.read_frames(inputs, animation=animation, fps=fps)
    sources = read_sources(all_frames, images, emitters, reference, selection, log)
    frames = select_frames(all_frames, selection, "fit-sequence --frames")
    out = io.ensure_writable_dir(out)
    metrics = out / "metrics.csv"
    rows = read_metrics(metrics, "fit-sequence --resume") if resume and metrics.exists() else []
    for sub in _SUBDIRS:
        io.ensure_writable_dir(out / sub)
    set_variant(variant)
    start = begin(out, frames, rows, options, template, variant, sources, fps, log)
    run_ = SequenceRun(out, start.reader, start.options, start.norm, start.x, start.F, start.rest,
                       float(start.record.lr), start.record.camera_box, sources, start.rows, start.done, start.pending)
    fitter = FrameFitter(run_, start.saved, log)
    paths = fit_frames(run_, start.first, fitter, log)
    paths += write_pictures(run_, log)
    finished = read_result(out)                  # every finished frame, resumed ones too, read back from control/
    view = sequence_view(finished, view_level)   # (V (T, k, 3), F, N (T, k, 3), colours or None): the viewer's
    rate = float(start.record.fps if start.record.fps is not None else fps)   # sequence.json's: --resume keeps it
    page = report_page(run_, finished, view, rate)
    with io.staged_outputs(out) as stage:
        write_view(stage / "sequence.glb", "glb", view, names=finished.names, fps=rate)
        io.write_text(stage / "report.html", page)
    log.wrote(out / "sequence.glb", out / "report.html")
    return paths + [out / "sequence.glb", out / "report.html"]
