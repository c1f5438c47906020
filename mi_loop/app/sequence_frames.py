"""The frame loop of ``fit-sequence``: fit each frame, measure it, write it atomically.

- :class:`SequenceRun`: what the loop carries from frame to frame;
- :class:`FrameFitter`: the job's one caller of :mod:`mi_loop.fitting` and
  :mod:`mi_loop.render` for the frames (limit operators, camera rig or photo
  renderer, image term, albedo and its optimiser, ``fit_frame``);
- :func:`fit_frames`: every frame after the last finished one; each frame's
  ``control/``, ``limit/`` and ``state/`` files, then its ``metrics.csv`` row
  (the commit: a frame is finished once its row is there).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.app.sequence_sources import Sources, captures_phrase, read_views
from mi_loop.io import runs

__all__ = ["FrameFitter", "SequenceRun", "fit_frames", "key_gaps", "stage_note"]


@dataclass(eq=False)
class SequenceRun:
    """What the frame loop carries from frame to frame.

    Attributes
    ----------
    out : pathlib.Path
        OUTDIR.
    reader : mi_loop.app.inputs.FrameReader
        The frames.
    options : SequenceOptions
        What the run uses (as ``sequence.json`` records them).
    norm : mi_loop.fitting.static.Normalisation
        World to unit box.
    x : (n, 3) float64 NumPy array
        Control points of the latest frame (unit box): where the next frame starts.
    F : (m, 3) int NumPy array
        Control faces.
    rest : (n, 3) float64 NumPy array
        The template (the second ARAP rest shape).
    lr : float
        Base step size.
    camera_box : list ``[lo, hi]``
        The unit-box box the camera rig frames.
    sources : Sources
        Photos and reference.
    rows : list of mi_loop.io.runs.MetricsRow
        ``metrics.csv``'s rows of the finished frames.
    done : int
        The last finished frame (-1: none).
    pending : list of pathlib.Path
        Files written before the first frame, printed with it.
    albedo : (n, 3) float NumPy array or None
        Per-control-vertex albedo (photos only).
    lights : list of dict or None
        The photos' emitters (photos only).
    attachment : object or None
        Each control vertex's limit point attached to the clean frame 0 (:func:`mi_loop.metrics.attach`), for
        the drift; made at the first frame measured.
    """

    out: Path
    reader: object
    options: object
    norm: object
    x: np.ndarray
    F: np.ndarray
    rest: np.ndarray
    lr: float
    camera_box: list
    sources: Sources
    rows: list
    done: int
    pending: list
    albedo: np.ndarray | None = None
    lights: list | None = None
    attachment: object = None


class FrameFitter:
    """Fit the frames of a run one at a time: the job's one caller of ``mi_loop.fitting`` and ``mi_loop.render``.

    Built once per run: the limit operators of the control mesh, the fixed camera
    rig of mesh frames without photos, or the photos' lighting and the albedo with
    its optimiser (restored from ``saved`` on ``--resume``). Per frame
    (:meth:`fit`): the image term (the frame's photos, or renders of its mesh),
    then :func:`mi_loop.fitting.sequence.fit_frame`.

    Parameters
    ----------
    run : SequenceRun
        Sets ``run.lights`` and ``run.albedo`` (photos), and ``run.albedo`` after each frame.
    saved : dict
        The last finished frame's extra state arrays (:meth:`state_arrays`); empty for a fresh run.
    log : mi_loop.app.progress.Reporter
        Told the frames, control vertices and terms.
    """

    def __init__(self, run: SequenceRun, saved: dict, log):
        from mi_loop.ad.operator import LimitOperator
        from mi_loop.fitting.static import sample_parameters
        from mi_loop.subdiv.masks import vertex_samples

        o, n = run.options, len(run.x)
        self.run, self.photo, self.albedo_opt, self.saved_lighting = run, None, None, None
        self.views = None                  # the latest frame's photos (the optical flow from them; silhouettes)
        photos = bool(run.sources.captures)
        if photos:       # the photos' lighting: of the image term, and of the pictures (also with --no-image)
            from mi_loop.io.emitters import DEFAULT_EMITTERS, read_emitters

            emitters = run.sources.emitters
            run.lights = read_emitters(emitters) if emitters is not None else [dict(e) for e in DEFAULT_EMITTERS]
        if photos and o.image:
            self._albedo(saved)
        fid, uv = sample_parameters(run.F, n, o.samples, o.seed)
        self.op = LimitOperator(run.F, n, fid, uv, derivatives=True)   # normals: facing data only
        self.vertex_op = LimitOperator(run.F, n, *vertex_samples(run.F, n), derivatives=True)
        self.graph = self.matrices = None
        self.rays = _rays_on(o, photos)    # the coarse stage holds material points on the optical flow's rays
        self.crossings = None
        if o.no_crossing:      # the fold guard's crossing test, of every frame's steps and the coarse stage's
            from mi_loop.fitting.guard import CrossingTest

            self.crossings = CrossingTest(run.F, n)
        if o.track > 0 and o.geometric:      # the coarse stage of every frame after the first
            from mi_loop.fitting.track import DeformationGraph

            self.graph = DeformationGraph(run.rest, run.F, spacing=o.track)
            self.matrices = self.op.matrix((None, "u", "v"))
        self.rig = None
        if o.image and not photos:         # cameras fixed for the whole run (resume included): the recorded box
            from mi_loop.fitting.sequence import Rig

            self.rig = Rig(o, tuple(np.asarray(c) for c in run.camera_box))
        fitted = photos and o.image          # the image term fits photos
        cover = o.cover_weight(mesh_frame=True), o.cover_weight(mesh_frame=False, photos=fitted)
        terms = (["IMLS"] + _weighted("coverage", *cover)) if o.geometric else []
        rest = o.rest_weight(photos=fitted)
        terms += ["ARAP"] + ([f"{rest:g} x ARAP to the template"] if rest > 0 else [])
        terms += _weighted("fold barrier", o.fold_weight(mesh_frame=True), o.fold_weight(mesh_frame=False))
        if o.image and photos and o.flow > 0:
            terms += ["optical flow"]
        if o.image and photos:
            terms += [f"photos ({captures_phrase(len(run.sources.captures))})"]
        elif o.image:
            terms += [f"image ({o.mode}, {o.views} views)"]
        from mi_loop.app.inputs import NO_CROSSING_NOTE

        guard = NO_CROSSING_NOTE if o.no_crossing else ""
        log.say(f"{len(run.reader)} frames, {n} control vertices; terms: {' + '.join(terms)}{guard}"
                f"{stage_note(o, photos)}")

    def _albedo(self, saved: dict) -> None:
        """The albedo (0.5 grey, or restored with its optimiser's state), and the estimated lighting's saved state."""
        from mi_loop.fitting.optimisers import Adam

        run = self.run
        run.albedo = np.full((len(run.x), 3), 0.5)
        self.albedo_opt = Adam()
        if "albedo" in saved:
            run.albedo = saved["albedo"]
            state = {k: saved[f"albedo_{k}"] for k in ("t", "m", "v") if f"albedo_{k}" in saved}
            self.albedo_opt.load_state_dict(state)
        if "light_coefficients" in saved:      # the estimated lighting, for the first renderer after a resume
            self.saved_lighting = (saved["light_coefficients"], saved["light_log_gain"])

    def _images(self, t: int, frame):
        """Frame ``t``'s :class:`~mi_loop.fitting.sequence.FrameImages`: its photos, renders of its mesh, or None."""
        from mi_loop.fitting import sequence

        run, o = self.run, self.run.options
        if o.image and run.sources.captures:
            from mi_loop.render.images import ImageRenderer

            views = read_views(run.sources.captures[t], t, frame)
            flow = None
            if (o.flow > 0 or self.rays) and t > 0:    # the previous frame's photos, camera by camera
                if self.views is None:               # after a resume
                    self.views = self._photos(t - 1)
                if len(self.views) == len(views):
                    flow = (self.views, views)
            self.views = views
            if self.photo is None or not self.photo.set_photos(views):    # kept while the cameras stay
                self.photo = ImageRenderer(run.norm.inverse(run.x), run.F, views, run.lights, albedo=run.albedo,
                                           level=o.level, spp=o.spp, deterministic=o.deterministic,
                                           lighting=self._lighting(views))
            lr = o.albedo_lr * (1.0 if t == 0 else o.albedo_refine)
            pixel = sequence.pixel_size(self.photo.cameras, run.norm.centre, run.norm.scale)
            return sequence.FrameImages(self.photo, run.albedo, lr, self.albedo_opt,
                                        (run.norm.scale, run.norm.centre), pixel, light_lr=o.light_lr,
                                        exposure=o.exposure, flow=flow, photos=True)
        if self.rig is not None and frame.mesh is not None:
            return self.rig.images(run.x, run.F, (run.norm.forward(frame.mesh[0]), frame.mesh[1]), t)
        return None

    def _photos(self, t: int) -> list:
        """Frame ``t``'s photos as read back from its capture, for a flow that starts there (already checked)."""
        from mi_loop.io.capture import read_capture

        return list(read_capture(self.run.sources.captures[t]).views)

    def _rays(self, t: int, images):
        """The coarse stage's rays at frame ``t`` (:func:`~mi_loop.fitting.flow.sample_rays`), or None: the previous
        fit's, and the fits' of the frames :func:`key_gaps` before ``t`` (those at frame 0 or later), each carried by
        the flow from its frame's photos to ``t``'s."""
        from mi_loop.fitting.flow import sample_rays

        if not self.rays or images is None or images.flow is None:
            return None
        run = self.run
        to_world = (run.norm.scale, run.norm.centre)
        rays = sample_rays(*images.flow, run.x, run.F, self.matrices, to_world)
        for gap in key_gaps(run.options.track_key):
            if gap > t:                      # and the flow from frame t-gap's photos, that frame's fit carried
                break
            views = self._photos(t - gap)    # read again, not kept: K frames of photos would bound no memory
            if len(views) == len(images.flow[1]):
                x = runs.read_state(runs.state_path(run.out, t - gap)).x
                more = sample_rays(views, images.flow[1], x, run.F, self.matrices, to_world)
                rays = tuple(np.concatenate([a, b]) for a, b in zip(rays, more))
        return rays

    def _held(self, x0, tracked: dict, complete: bool):
        """How hard to hold each tracked control point ``x0`` (:func:`~mi_loop.fitting.track.anchor_weights`).

        Complete data: by the share of its support that found data (``tracked["held"]``: what found none
        was lost). Partial depth: by the share inside the photos' silhouettes (what found no depth may be
        unseen; what falls outside a mask was lost); without photos every point is trusted. Times
        :func:`~mi_loop.fitting.track.pinned_hold` where the flow's rays pinned its support.
        """
        from mi_loop.fitting.track import anchor_weights, in_silhouettes, pinned_hold

        M = self.matrices[0]
        if complete:
            held = anchor_weights(M, tracked["held"])
        elif self.views is None:
            held = np.ones(len(x0))
        else:
            held = anchor_weights(M, in_silhouettes(self.views, self.run.norm.inverse(M @ x0)))
        return held * pinned_hold(M, tracked["pinned"], self.run.options.pinned_hold)

    def _lighting(self, views):
        """The estimated lighting of a new renderer (``--lighting sh``, else None): the previous renderer's
        coefficients (or the saved ones after a resume, or the start of :func:`~mi_loop.fitting.images.start_lighting`),
        and gains of 1 for the new cameras (the saved ones where the cameras are those of the save)."""
        import mitsuba as mi

        from mi_loop.fitting.images import start_lighting

        if self.run.options.lighting != "sh":
            return None
        light = start_lighting(views, 0.5)                 # the sequence's albedo starts grey 0.5
        if self.photo is not None and self.photo.lighting is not None:
            light.coefficients = mi.Float(self.photo.lighting.coefficients)
        elif self.saved_lighting is not None:
            coefficients, log_gain = self.saved_lighting
            light.coefficients = mi.Float(np.asarray(coefficients, dtype=np.float32))
            if len(log_gain) == 3 * len(views):
                light.log_gain = mi.Float(np.asarray(log_gain, dtype=np.float32))
        return light

    def fit(self, t: int, frame, P, N, iterations: int, progress):
        """Fit frame ``t`` from the latest frame's control points.

        Parameters
        ----------
        t : int
            The frame.
        frame : mi_loop.app.inputs.FitFrame
            The frame.
        P, N : (k, 3) float NumPy arrays
            Its points in the unit box and their unit normals (oriented).
        iterations : int
            Iterations of this frame.
        progress : callable
            ``progress(i, n)`` after each iteration.

        Returns
        -------
        V : (n, 3) float64 NumPy array
            The frame's control points (unit box).
        info : dict
            :func:`~mi_loop.fitting.sequence.fit_frame`'s (``iterations``, ``time_render``, ...).
        """
        from mi_loop.fitting import sequence

        run = self.run
        images = self._images(t, frame)
        x0, held = run.x, None
        if self.graph is not None and t > 0:
            from mi_loop.fitting.track import track

            x0, tracked = track(self.graph, run.x, self.matrices, P, N, rays=self._rays(t, images),
                                ray=run.options.track_flow)
            if self.crossings is not None:       # the graph's step crosses nothing new either
                from mi_loop.fitting.guard import hold_apart

                x0 = hold_apart(self.crossings, run.x, x0)
            held = self._held(x0, tracked, frame.mesh is not None)
        V, info = sequence.fit_frame(x0, run.F, P, N, self.op, images, run.options, t, run.lr, progress=progress,
                                     rest=run.rest, vertex_op=self.vertex_op, iterations=iterations,
                                     complete=frame.mesh is not None, held=held,
                                     previous=None if held is None else run.x, crossings=self.crossings)
        if run.sources.captures and info["albedo"] is not None:
            run.albedo = info["albedo"]
        return V, info

    def state_arrays(self) -> dict:
        """Return what ``state/NNNN.npz`` keeps besides ``x``, ``F`` and ``rest``: the albedo and its optimiser, and
        the estimated lighting (``light_coefficients``, ``light_log_gain``) with ``--lighting sh``.

        Returns
        -------
        dict
            Name -> NumPy array (empty without photos); :meth:`__init__` restores from it.
        """
        if self.run.albedo is None:
            return {}
        state = self.albedo_opt.state_dict()
        extra = {"albedo": self.run.albedo, "albedo_t": np.array(state["t"])}
        if "m" in state:
            extra |= {"albedo_m": state["m"], "albedo_v": state["v"]}
        if self.photo is not None and self.photo.lighting is not None:
            import drjit as dr

            extra |= {"light_coefficients": np.array(dr.detach(self.photo.lighting.coefficients)),
                      "light_log_gain": np.array(dr.detach(self.photo.lighting.log_gain))}
        return extra


def stage_note(options, photos: bool) -> str:
    """What the terms line says of the coarse stage: ``""`` without ``--track``, else how it carries each frame.

    Parameters
    ----------
    options : mi_loop.fitting.options.SequenceOptions
    photos : bool
        The frames come with photos (``--images``).

    Examples
    --------
    >>> from mi_loop.fitting.options import SequenceOptions
    >>> stage_note(SequenceOptions(track=10), photos=True)  # doctest: +NORMALIZE_WHITESPACE
    "; each frame first carried by a deformation graph (--track 10), on the optical flow's rays
    (--track-flow 1) and on those from 2, 4 and 8 frames before (--track-key 8), what they pinned held
    10 times as hard (--pinned-hold 10)"
    >>> stage_note(SequenceOptions(track=10, track_key=2), photos=True)  # doctest: +NORMALIZE_WHITESPACE
    "; each frame first carried by a deformation graph (--track 10), on the optical flow's rays
    (--track-flow 1) and on those from 2 frames before (--track-key 2), what they pinned held 10 times
    as hard (--pinned-hold 10)"
    >>> stage_note(SequenceOptions(track=10, track_key=0), photos=True)  # doctest: +NORMALIZE_WHITESPACE
    "; each frame first carried by a deformation graph (--track 10), on the optical flow's rays
    (--track-flow 1), what they pinned held 10 times as hard (--pinned-hold 10)"
    >>> stage_note(SequenceOptions(track=10, track_flow=0), photos=True)
    '; each frame first carried by a deformation graph (--track 10)'
    >>> stage_note(SequenceOptions(), photos=True)
    ''
    """
    if options.track <= 0 or not options.geometric:
        return ""
    note = f"; each frame first carried by a deformation graph (--track {options.track})"
    if not _rays_on(options, photos):
        return note
    gaps = [str(gap) for gap in key_gaps(options.track_key)]
    note += f", on the optical flow's rays (--track-flow {options.track_flow:g})"
    if gaps:
        before = f"{', '.join(gaps[:-1])} and {gaps[-1]}" if len(gaps) > 1 else gaps[0]
        note += f" and on those from {before} frames before (--track-key {options.track_key})"
    hold = options.pinned_hold
    return note + f", what they pinned held {hold:g} times as hard (--pinned-hold {hold:g})"


def key_gaps(key: int) -> list:
    """How many frames before the flow's key rays start (``--track-key K``): every power of two below ``K``, then ``K``.

    Each gap's flow carries its own error once, not chained through every frame in between; gaps that
    double keep the oldest key within ``K`` frames at ``log2 K`` flows.

    Parameters
    ----------
    key : int
        The largest gap; 0 or 1: none.

    Examples
    --------
    >>> key_gaps(8), key_gaps(6), key_gaps(2), key_gaps(1)
    ([2, 4, 8], [2, 4, 6], [2], [])
    """
    gaps, gap = [], 2
    while gap < key:
        gaps.append(gap)
        gap *= 2
    return gaps + [key] if key > 1 else []


def _rays_on(options, photos: bool) -> bool:
    """Whether the coarse stage (``--track``) holds material points on the optical flow's rays (``--track-flow``)."""
    return options.track > 0 and options.geometric and photos and options.image and options.track_flow > 0


def _weighted(term: str, mesh: float, points: float) -> list:
    """``[term with its weight]`` for the log line, by the kind of frame where the two differ; ``[]`` where it is 0."""
    if mesh == points:
        return [f"{mesh:g} x {term}"] if mesh > 0 else []
    return [f"{term} ({mesh:g} x on mesh frames, {points:g} x on point clouds)"]


def fit_frames(run: SequenceRun, first, fitter: FrameFitter, log) -> list:
    """Fit and write every frame after ``run.done``.

    Parameters
    ----------
    run : SequenceRun
        Updated as frames finish (``x``, ``rows``, ``albedo``).
    first : mi_loop.app.inputs.FitFrame
        Frame 0, read already.
    fitter : FrameFitter
        The run's fitter.
    log : mi_loop.app.progress.Reporter
        Progress bar, a line per frame, the written paths.

    Returns
    -------
    list of pathlib.Path
        Every written path, in order.
    """
    o = run.options
    paths, todo = [], list(range(run.done + 1, len(run.reader)))
    steps = [o.frame_iterations(t == 0) for t in todo]
    with log.bar("fit-sequence") as update:
        for k, t in enumerate(todo):
            t0 = time.perf_counter()
            frame = first if t == 0 else run.reader(t)
            P, N = run.norm.forward(frame.P), frame.N
            if run.reader.normals_estimated and frame.mesh is None:
                N = _orient(run, P, N)

            def progress(i, n, k=k, t=t):
                update(sum(steps[:k]) + i, sum(steps), f"frame {t + 1}/{len(run.reader)}")

            V, info = fitter.fit(t, frame, P, N, steps[k], progress)
            paths += _write_frame(run, t, frame, N, V, info, fitter.state_arrays(), t0, log)
            run.x = V
    return paths


def _orient(run: SequenceRun, P, N):
    """Turn estimated normals (unit box points ``P``) to agree with the current fit's nearest limit normal."""
    from scipy.spatial import cKDTree

    from mi_loop.subdiv.masks import limit_mesh

    Vl, _, Nl = limit_mesh(run.x, run.F, level=1)
    _, i = cKDTree(Vl).query(P, workers=-1)
    return np.where((np.sum(N * Nl[i], axis=1) < 0)[:, None], -N, N)


def _frame_metrics(run: SequenceRun, t: int, V, frame, N):
    """``(distances, flipped %, drift or None, limit mesh)`` of frame ``t``'s fit ``V`` (unit box)."""
    from mi_loop.metrics import attach, attach_points, drift, flipped_fraction, two_sided
    from mi_loop.subdiv.masks import limit_mesh, limit_positions

    V_world = run.norm.inverse(V)
    limit = limit_mesh(V_world, run.F, level=2)
    clean = None
    if run.sources.reference is not None:
        ref = run.sources.reference[t]()
        clean = (ref.vertices, ref.faces)            # faces None: points in correspondence
    mesh = clean if clean is not None and clean[1] is not None else frame.mesh
    if mesh is not None:
        m = two_sided(limit[0], limit[1], mesh[0], mesh[1], n_samples=30_000)
        flipped = flipped_fraction(limit[0], limit[1], mesh[0], mesh[1])
    else:            # points: the reference's where there is one (a partial frame is measured against all of it)
        m = two_sided(limit[0], limit[1], frame.P if clean is None else clean[0], n_samples=30_000)
        flipped = flipped_fraction(limit[0], limit[1], frame.P, N_target=N)
    d = None
    if clean is not None:
        L = limit_positions(V_world, run.F)
        if run.attachment is None:
            first = runs.state_path(run.out, 0)
            if t != 0 and not first.is_file():
                return m, 100 * flipped, None, limit
            L0 = L if t == 0 else limit_positions(run.norm.inverse(runs.read_state(first).x), run.F)
            ref0 = run.sources.reference[0]()
            run.attachment = (attach_points(L0, ref0.vertices) if ref0.faces is None
                              else attach(L0, ref0.vertices, ref0.faces))
        d = drift(L, run.attachment, clean[0])
    return m, 100 * flipped, d, limit


def _write_frame(run: SequenceRun, t: int, frame, N, V, info: dict, arrays: dict, t0: float, log) -> list:
    """Write frame ``t``'s limit, control and state files and its ``metrics.csv`` row (the commit); print them."""
    from mi_loop.subdiv.masks import limit_colors

    m, flipped, d, limit = _frame_metrics(run, t, V, frame, N if frame.mesh is None else None)
    seconds = time.perf_counter() - t0
    row = runs.MetricsRow(t, frame.name, float(m["mean"]), float(m["rms"]), float(m["hausdorff"]), float(flipped),
                          None if d is None else float(d["mean"]), None if d is None else float(d["p95"]), seconds,
                          float(info["time_render"]), int(info["iterations"]))
    run.rows.append(row.rounded())                 # as metrics.csv reads back: a resumed run holds the same rows
    colors = run.albedo
    paths = [io.write_ply(run.out / "control" / f"{t:04d}.ply", run.norm.inverse(V), run.F, colors=colors),
             io.write_ply(run.out / "limit" / f"{t:04d}.ply", *limit,
                          colors=None if colors is None else limit_colors(colors, run.F, 2)),
             runs.write_state(runs.state_path(run.out, t), runs.FrameState(V, run.F, run.rest, arrays))]
    runs.write_metrics(run.out / "metrics.csv", run.rows)
    paths += run.pending
    run.pending = []
    log.wrote(*paths)
    extra = f", drift {d['mean']:.2e}" if d is not None else ""
    if info.get("noise") is not None:   # how much the images counted where the data saw the surface
        extra += f", data noise {info['noise']:.1e}, image weight there {info['seen_weight']:.2g}"
    log.say(f"frame {t + 1}/{len(run.reader)} {frame.name}: mean {m['mean']:.2e} RMS {m['rms']:.2e}, "
            f"flipped {flipped:.2f} %{extra} ({seconds:.1f} s, render {info['time_render']:.1f} s)")
    return paths
