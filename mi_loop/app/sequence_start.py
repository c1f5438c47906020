"""How a ``fit-sequence`` run begins: the options it runs with, the template, a fresh start or a resume.

- :func:`settle_options`: the options as the run uses them, decided before
  ``sequence.json`` records them (point-cloud frames without photos have no
  surface to render, so the image term is off);
- :func:`begin`: a fresh run (normalisation, template, visual hull with
  photos, step size and camera box, written to ``sequence.json``) or a resumed
  one (the recorded options and normalisation, the exact state of the last
  finished frame), as a :class:`Start`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.app.inputs import FrameReader
from mi_loop.app.sequence_sources import captures_phrase, read_views
from mi_loop.errors import expected, fail
from mi_loop.fitting.options import SequenceOptions
from mi_loop.io import runs

__all__ = ["HULL_RESOLUTION", "IMAGE_OFF", "Start", "begin", "settle_options"]

#: Voxels along each side of the first frame's visual hull (thin legs need about 100).
HULL_RESOLUTION = 128
#: What the log says when point-cloud frames without photos turn the image term off.
IMAGE_OFF = ("point-cloud frames without --images: no surface to render, so the image term is off "
             "(the geometric terms only)")
_RESUME = "fit-sequence --resume"


@dataclass(eq=False)
class Start:
    """Where the frame loop begins.

    Attributes
    ----------
    reader : mi_loop.app.inputs.FrameReader
        The frames, read one at a time with the run's ``n_points`` and ``seed``.
    first : mi_loop.app.inputs.FitFrame
        Frame 0, read already.
    options : SequenceOptions
        What the run uses: the options ``sequence.json`` records.
    record : mi_loop.io.runs.RunRecord
        ``sequence.json``.
    norm : mi_loop.fitting.static.Normalisation
        World to unit box.
    x : (n, 3) float64 NumPy array
        Control points to start from (unit box): the template, or the last finished frame's.
    F : (m, 3) int NumPy array
        Control faces.
    rest : (n, 3) float64 NumPy array
        The template (the second ARAP rest shape).
    done : int
        The last finished frame (-1: none).
    rows : list of mi_loop.io.runs.MetricsRow
        ``metrics.csv``'s rows of the finished frames.
    pending : list of pathlib.Path
        Files written before the first frame, printed with it.
    saved : dict
        The last finished frame's other state arrays (:attr:`mi_loop.io.runs.FrameState.extra`).
    """

    reader: FrameReader
    first: object
    options: SequenceOptions
    record: runs.RunRecord
    norm: object
    x: np.ndarray
    F: np.ndarray
    rest: np.ndarray
    done: int
    rows: list
    pending: list
    saved: dict = field(default_factory=dict)


def settle_options(options: SequenceOptions, first, photos: bool):
    """Return the options a run uses, and a note when they differ from those given.

    Parameters
    ----------
    options : SequenceOptions
        As given (or as an older run recorded them).
    first : mi_loop.app.inputs.FitFrame
        The first frame: a mesh has a surface to render, a point cloud has none.
    photos : bool
        Whether the frames come with photos (``--images``).

    Returns
    -------
    options : SequenceOptions
        ``options``, or a copy with ``image`` off for point-cloud frames without photos.
    note : str or None
        :data:`IMAGE_OFF` when the image term was turned off.

    Raises
    ------
    ValueError
        ``--image-only`` (no geometric terms) with point-cloud frames and no photos.
    """
    if first.mesh is not None or photos:
        return options, None
    if not options.geometric:
        raise ValueError(expected("fit-sequence --image-only", "mesh frames (a surface to render) or --images",
                                  "point-cloud frames"))
    return (replace(options, image=False), IMAGE_OFF) if options.image else (options, None)


def begin(out: Path, frames: list, rows: list, options: SequenceOptions, template: Path | None, variant: str,
          sources, fps: float, log) -> Start:
    """Begin a run: fresh (``rows`` empty; writes ``sequence.json``) or resumed after ``rows[-1]``.

    Parameters
    ----------
    out : pathlib.Path
        OUTDIR (created).
    frames : list of mi_loop.io.frames.Frame
        The (selected) frames.
    rows : list of mi_loop.io.runs.MetricsRow
        ``metrics.csv``'s rows with ``--resume``, else empty.
    options : SequenceOptions
        As given; a resumed run keeps the recorded ones and warns about those that differ.
    template : pathlib.Path or None
        ``--template``.
    variant : str
        The Mitsuba variant (recorded).
    sources : mi_loop.app.sequence_sources.Sources
        Photos and reference.
    fps : float
        ``--fps`` (recorded; a resumed run keeps the recorded one).
    log : mi_loop.app.progress.Reporter

    Returns
    -------
    Start

    Raises
    ------
    ValueError
        A template in another frame or invalid, a ``sequence.json`` missing or incomplete on
        ``--resume``, photos given to a resumed run fitted without them or missing from one fitted to
        them, ``--image-only`` without a surface to render (:func:`settle_options`).
    """
    photos = bool(sources.captures)
    if rows:
        record = runs.read_run_json(out / "sequence.json", _RESUME)
        missing = [k for k in ("centre", "scale", "lr", "camera_box", "options") if getattr(record, k) is None]
        if missing:
            fail(_RESUME, "a sequence.json with centre, scale, lr, camera_box and options",
                 f"'{out / 'sequence.json'}' without {', '.join(missing)}")
        fitted, given = len(record.images or []), len(sources.captures or [])
        if fitted and not given:          # the same inputs: a run does not change what it fits midway
            fail(_RESUME, f"--images (the run was fitted to {captures_phrase(fitted)}, as its sequence.json records)",
                 "none")
        if given and not fitted:
            fail(_RESUME, "no --images (the run was fitted without photos)", captures_phrase(given))
        recorded = SequenceOptions.from_dict(record.options)
        reader = FrameReader(frames, recorded.n_points, recorded.seed, log)
        first = reader(0)
        ran, note = settle_options(recorded, first, photos)    # older runs recorded the image term on
        if note:
            log.say(note)
        return _resume(out, reader, first, rows, record, ran, options, photos, fps, log)
    reader = FrameReader(frames, options.n_points, options.seed, log)
    first = reader(0)
    options, note = settle_options(options, first, photos)
    if note:
        log.say(note)
    return _start(out, reader, first, options, template, variant, sources, fps, log)


def _start(out, reader, first, options, template, variant, sources, fps, log) -> Start:
    """A fresh run: normalisation, template, step size and cameras, written to ``sequence.json``."""
    from mi_loop.app.report import plain
    from mi_loop.fitting.static import Normalisation
    from mi_loop.mesh.geometry import mean_edge_length

    hull = None
    if sources.captures and first.mesh is None and template is None:
        hull = _hull_points(first, read_views(sources.captures[0], 0, first), log)
    norm = Normalisation.of(first.P if hull is None else hull[0])
    if template is not None:
        from mi_loop.app.inputs import read_template

        V_t, F, tinfo = read_template(template, first.P, f"fit-sequence --template '{template}'", log)
        x = norm.forward(V_t)
    else:
        x, F, tinfo = _template(first, norm, options, log, hull)
    lr = 0.02 * mean_edge_length(x, F)
    lo, hi = x.min(0), x.max(0)
    pad = 0.15 * (hi - lo).max()
    record = runs.RunRecord(**plain({
        "centre": norm.centre.tolist(), "scale": norm.scale, "lr": lr,
        "camera_box": [(lo - pad).tolist(), (hi + pad).tolist()], "options": asdict(options),
        "n_frames": len(reader), "template": tinfo, "normals_estimated": reader.normals_estimated,
        "images": [str(p) for p in sources.captures] if sources.captures else None,
        "emitters": str(sources.emitters) if sources.emitters else None,
        "reference": sources.reference is not None, "variant": variant, "fps": fps}))
    runs.write_run_json(out / "sequence.json", record)
    return Start(reader, first, options, record, norm, x, F, x, -1, [], [out / "sequence.json", out / "metrics.csv"])


def _resume(out, reader, first, rows, record, ran, given, photos, fps, log) -> Start:
    """Continue after the last finished frame, from its exact state (``state/NNNN.npz``) where there is one."""
    from mi_loop.fitting.static import Normalisation

    if first.mesh is None and not photos:          # nothing to render: the given image flag does not matter
        given = replace(given, image=ran.image)
    now = asdict(given)
    changed = [f"{k} {v!r} (this command line: {now[k]!r})" for k, v in asdict(ran).items() if now[k] != v]
    if changed:
        log.warning("--resume keeps the options of sequence.json: " + ", ".join(changed))
    norm = Normalisation(np.asarray(record.centre, dtype=np.float64), float(record.scale))
    done = rows[-1].frame
    path = runs.state_path(out, done)
    if path.is_file():
        state = runs.read_state(path, _RESUME)
    else:
        V, F = io.read_mesh(out / "control" / f"{done:04d}.ply")
        state = runs.FrameState(norm.forward(V), F)
        for other in sorted(path.parent.glob("*.npz")):       # the template is in every state file
            state.rest = runs.read_state(other, _RESUME).rest
            if state.rest is not None:
                break
        log.warning(f"{path} is missing (an older run?): resuming from control/{done:04d}.ply, which is not bit-exact")
    log.say(f"resuming after frame {done} ({len(rows)} frames done)")
    if record.fps is not None and record.fps != fps:
        log.warning(f"--resume keeps the frame rate of sequence.json: fps {record.fps:g} (this command line: {fps:g})")
    rest = state.rest if state.rest is not None else state.x
    return Start(reader, first, ran, record, norm, state.x, state.F, rest, done, rows, [out / "metrics.csv"],
                 state.extra)


def _template(first, norm, options: SequenceOptions, log, hull=None):
    """The first frame's automatic template (normalised units): from its mesh, else Poisson.

    A mesh frame is refined and decimated directly (:func:`mesh_template`),
    which keeps thin parts that a coarse Poisson octree loses; a point-cloud
    frame, a mesh that is not a clean manifold, ``poisson_template`` or a
    ``template_depth`` goes through screened Poisson + decimation
    (:func:`make_template`), of the points and, with photos, of the visual
    hull where the points have holes (``hull``: the combined oriented points).
    With ``template_genus``, either template has its handles beyond that genus
    cut (:func:`mi_loop.mesh.handles.cut_handles`).
    """
    from mi_loop.app.inputs import say_handles
    from mi_loop.fitting.template import make_template, mesh_template

    if first.mesh is not None and not options.poisson_template and options.template_depth is None:
        try:
            x, F, info = mesh_template(norm.forward(first.mesh[0]), first.mesh[1], options.n_vertices,
                                       genus=options.template_genus)
            log.say(f"template: first frame's mesh decimated to {len(x)} vertices")
            say_handles(info, options.template_genus, log)
            return x, F, {"source": "mesh", "n_vertices": len(x), "n_faces": len(F)}
        except ValueError as exc:
            log.say(f"template: first frame's mesh cannot be used ({exc}); screened Poisson instead")
    P, N = hull if hull is not None else (first.P, first.N)
    source = "poisson+hull" if hull is not None else "poisson"
    depth = f" at depth {options.template_depth}" if options.template_depth is not None else ""
    log.say(f"template: screened Poisson{' of the points and the visual hull' if hull is not None else ''}{depth} "
            f"+ decimation to {options.n_vertices} vertices")
    x, F, info = make_template(norm.forward(P), N, options.n_vertices, depth=options.template_depth,
                               seed=options.seed, genus=options.template_genus)
    say_handles(info, options.template_genus, log)
    return x, F, {"source": source, "n_vertices": len(x), "n_faces": len(F)}


def _hull_points(first, views, log):
    """Oriented points of the first frame completed by the photos' visual hull: ``(P, N)``, capture units.

    The hull's boundary points are added where the frame's points leave
    holes (farther than three point spacings from any), and estimated point
    normals are turned to agree with the hull's nearest normal (a partial,
    one-sided scan has no inside to orient them by).
    """
    from scipy.spatial import cKDTree

    from mi_loop.fitting.hull import visual_hull

    P, N = first.P, first.N
    H, NH, _ = visual_hull(views, resolution=HULL_RESOLUTION)    # unit normals only (hull_points)
    tree, hull = cKDTree(P), cKDTree(H)
    spacing = float(np.median(tree.query(P, k=2)[0][:, 1]))
    d, _ = tree.query(H)
    voxel = float(np.median(hull.query(H, k=2)[0][:, 1]))
    far = d > max(3.0 * spacing, 2.0 * voxel)
    _, nearest = hull.query(P)
    N = np.where((np.sum(N * NH[nearest], axis=1) < 0)[:, None], -N, N)
    log.say(f"visual hull: {far.sum()} of its {len(H)} boundary points fill holes of the first frame's points")
    return np.concatenate([P, H[far]]), np.concatenate([N, NH[far]])
