"""The ``mi-loop fit-sequence`` job: read frames, fit each, write each atomically, resume bit for bit.

Layout of OUTDIR (every path is printed on stdout as it is written):

- ``control/0000.ply ...``: the fitted control mesh of every frame, in the
  frames' units (one connectivity for all frames), with the per-vertex
  albedo as colours when the frames come with photos;
- ``limit/0000.ply ...``: its limit surface (level-2 tessellation, albedo too);
- ``state/0000.npz ...``: ``x``, the exact float64 control points of the frame
  in the unit box, ``F``, the faces, and ``albedo`` (photos only): what
  ``--resume`` starts the next frame from (the PLY files in world units do not
  map back bit for bit);
- ``metrics.csv``: one row per finished frame (:data:`CSV_HEADER`): ``mean,
  rms, hausdorff`` two-sided, relative to the target's bounding-box diagonal
  (the clean reference frame where there is one, else the frame's mesh or
  points); ``flipped_pct``, the share of the limit surface's area facing
  against the target (folds); ``drift_mean, drift_p95``, the correspondence
  drift relative to the diagonal (sequences in correspondence only: each
  control vertex's limit point attached at frame 0 to the clean frame 0 and
  followed to the same barycentric point of frame ``t``; empty otherwise);
  ``seconds``, ``time_render``, ``iterations``; a frame is finished once its
  row is there;
- ``sequence.json``: what the run needs to continue, written before the first frame:

  ``centre`` (3 floats) and ``scale``
      the normalisation: unit-box coordinates are ``(world - centre) / scale``;
  ``lr``
      base step size in the unit box (2 % of the template's mean edge length);
  ``camera_box``
      ``[lo, hi]``, the unit-box box the camera rig frames, fixed for the whole run;
  ``options``
      every field of :class:`~mi_loop.fitting.options.SequenceOptions`
      (``--resume`` keeps these and says which given options differ);
  ``n_frames``
      frames in the sequence at the start;
  ``template``
      its ``source`` (``file``, ``mesh`` or ``poisson``), ``n_vertices``,
      ``n_faces``; for ``--template`` also ``path``, ``split_polygons``
      (polygons triangulated on reading), ``size_ratio`` and ``centre_offset``
      (against the first frame);
  ``normals_estimated``
      whether the first frame's normals were estimated (point clouds without normals);
  ``images``
      the captures (``transforms.json`` per frame) or null;
  ``emitters``
      the photos' lighting file, or null (a constant environment);
  ``reference``
      whether distances, folds and drift are measured against clean meshes in correspondence;
  ``variant``
      the Mitsuba variant of the run;
  ``fps``
      the frame rate of ``sequence.glb`` (``--fps``; ``--resume`` keeps it);
- ``drift.png`` (per-frame error) and ``strip.png`` (target and fit for a few
  frames), drawn when the run completes;
- ``sequence.glb``: every finished frame as one glTF 2.0 mesh in
  correspondence, frame 0 with a morph target per frame, animated at ``fps``
  (Blender and three.js play it), at the viewer's tessellation level
  (``--view-level``, default 1); written after the frames (and after those of
  ``--resume``) from ``control/``, atomically;
- ``report.html``: the same frames in a browser, offline
  (:mod:`~mi_loop.app.html_report`): a frame slider with play and pause, each
  frame's limit surface coloured by its distance to the frame's target (the
  clean reference where there is one), the control cage, and the per-frame
  distance, fold and drift plots with the current frame marked; written
  with ``sequence.glb``.
"""
from __future__ import annotations

import contextlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.app.export_job import VIEW_LEVELS, read_result, sequence_view, write_view
from mi_loop.fitting.options import SequenceOptions
from mi_loop.render.variant import DEFAULT_VARIANT

__all__ = ["CSV_HEADER", "STATE_DIR", "run"]

CSV_HEADER = "frame,name,mean,rms,hausdorff,flipped_pct,drift_mean,drift_p95,seconds,time_render,iterations"
#: Voxels along each side of the first frame's visual hull (thin legs need about 100).
HULL_RESOLUTION = 128
#: Sub-directory of OUTDIR with the exact per-frame state (``NNNN.npz``).
STATE_DIR = "state"


@dataclass
class Sources:
    """What the frames are fitted with besides themselves: photos, lighting and a clean reference.

    Attributes
    ----------
    captures : list of pathlib.Path or None
        One ``transforms.json`` per (selected) frame.
    emitters : pathlib.Path or None
        Mitsuba XML of the capture's lighting (None: constant environment, radiance 1).
    reference : list of Frame or None
        Clean meshes in correspondence, one per (selected) frame, for the
        distances, folds and drift (the frames themselves when they are such meshes).
    """

    captures: list | None = None
    emitters: Path | None = None
    reference: list | None = None


@dataclass
class _Run:
    """What the frame loop carries: outputs, frames, options, normalisation, control mesh, step, photos."""

    out: Path
    reader: object
    options: SequenceOptions
    norm: object
    x: np.ndarray
    F: np.ndarray
    lr: float
    rows: list             # metrics.csv rows of the finished frames
    done: int              # last finished frame (-1: none)
    pending: list          # files written before the first frame, printed with it
    sources: Sources
    rest: np.ndarray       # the template (second ARAP rest shape)
    albedo: np.ndarray | None = None
    albedo_opt: object = None
    lights: list | None = None
    photo: object = None   # the PhotoRenderer of the latest frame (reused while the cameras stay)
    attachment: object = None


def _template(first, norm, options: SequenceOptions, log, hull=None):
    """The first frame's automatic template (normalised units): from its mesh, else Poisson.

    A mesh frame is refined and decimated directly (:func:`mesh_template`),
    which keeps thin parts that a coarse Poisson octree loses; a point-cloud
    frame, a mesh that is not a clean manifold, or ``poisson_template`` goes
    through screened Poisson + decimation (:func:`make_template`), of the
    points and, with photos, of the visual hull where the points have holes
    (``hull``: the combined oriented points).
    """
    from mi_loop.fitting.template import make_template, mesh_template

    if first[3] is not None and not options.poisson_template:
        try:
            x, F, _ = mesh_template(norm.forward(first[3][0]), first[3][1], options.n_vertices)
            log.say(f"template: first frame's mesh decimated to {len(x)} vertices")
            return x, F, {"source": "mesh", "n_vertices": len(x), "n_faces": len(F)}
        except ValueError as exc:
            log.say(f"template: first frame's mesh cannot be used ({exc}); screened Poisson instead")
    P, N = hull if hull is not None else (first[1], first[2])
    source = "poisson+hull" if hull is not None else "poisson"
    log.say(f"template: screened Poisson{' of the points and the visual hull' if hull is not None else ''} "
            f"+ decimation to {options.n_vertices} vertices")
    x, F, _ = make_template(norm.forward(P), N, options.n_vertices, seed=options.seed)
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

    P, N = first[1], first[2]
    H, NH, _ = visual_hull(views, resolution=HULL_RESOLUTION)
    oriented = np.linalg.norm(NH, axis=1) > 0.5        # a flat patch of the occupancy has no gradient
    H, NH = H[oriented], NH[oriented]
    tree = cKDTree(P)
    spacing = float(np.median(tree.query(P, k=2)[0][:, 1]))
    d, _ = tree.query(H)
    voxel = float(np.median(cKDTree(H).query(H, k=2)[0][:, 1]))
    far = d > max(3.0 * spacing, 2.0 * voxel)
    _, nearest = cKDTree(H).query(P)
    N = np.where((np.sum(N * NH[nearest], axis=1) < 0)[:, None], -N, N)
    log.say(f"visual hull: {far.sum()} of its {len(H)} boundary points fill holes of the first frame's points")
    return np.concatenate([P, H[far]]), np.concatenate([N, NH[far]])


def _read_csv(path: Path):
    if not path.exists():
        return []
    lines = path.read_text().strip().splitlines()
    if lines and lines[0] != CSV_HEADER:
        from mi_loop.errors import fail

        fail("fit-sequence --resume", f"a metrics.csv with the columns {CSV_HEADER}",
             f"'{lines[0]}' in '{path}' (a run of an older version: start it again without --resume)")
    return [line.split(",") for line in lines[1:] if line]


def _state_path(out: Path, t: int) -> Path:
    return out / STATE_DIR / f"{t:04d}.npz"


def _write_state(run: _Run, t: int, x) -> Path:
    """``state/NNNN.npz``: exact normalised control points, faces, template, albedo and its optimiser."""
    path = _state_path(run.out, t)
    extra = {}
    if run.albedo is not None:
        o = run.albedo_opt
        extra = {"albedo": run.albedo, "albedo_m": o.m, "albedo_v": o.v, "albedo_t": np.array(o.t)}
    with io.atomic_open(path) as f:
        np.savez(f, x=np.asarray(x, dtype=np.float64), F=np.asarray(run.F, dtype=np.int64),
                 rest=np.asarray(run.rest, dtype=np.float64), **extra)
    return path


def _start(out, reader, first, options, template, variant, sources, fps, log):
    """A fresh run: normalisation, template, step size and cameras, written to ``sequence.json``.

    Returns ``(state, norm, x, F)``: the ``sequence.json`` dict, the
    normalisation, the template's control points (unit box) and faces.
    """
    from mi_loop.fitting.static import Normalisation
    from mi_loop.mesh.geometry import mean_edge_length

    hull = None
    if sources.captures and first[3] is None and template is None:
        hull = _hull_points(first, _read_views(sources.captures[0], 0, first, log), log)
    norm = Normalisation.of(first[1] if hull is None else hull[0])
    if template is not None:
        from mi_loop.app.inputs import read_template

        V_t, F, tinfo = read_template(template, first[1], f"fit-sequence --template '{template}'", log)
        x = norm.forward(V_t)
    else:
        x, F, tinfo = _template(first, norm, options, log, hull)
    lr = 0.02 * mean_edge_length(x, F)
    lo, hi = x.min(0), x.max(0)
    pad = 0.15 * (hi - lo).max()
    state = {"centre": norm.centre.tolist(), "scale": norm.scale, "lr": lr,
             "camera_box": [(lo - pad).tolist(), (hi + pad).tolist()], "options": asdict(options),
             "n_frames": len(reader), "template": tinfo, "normals_estimated": reader.normals_estimated,
             "images": [str(p) for p in sources.captures] if sources.captures else None,
             "emitters": str(sources.emitters) if sources.emitters else None,
             "reference": sources.reference is not None, "variant": variant, "fps": fps}
    from mi_loop.app.report import plain

    io.write_text(out / "sequence.json", json.dumps(plain(state), indent=2) + "\n")
    return state, norm, x, F


def _resume(out, rows, options, log):
    """Continue after the last finished frame; ``(options, state, norm, x, F, done, saved)``.

    The stored options and normalisation, and the exact state of the last
    finished frame from ``state/NNNN.npz`` (``saved``: its arrays).
    """
    from mi_loop.errors import fail
    from mi_loop.fitting.static import Normalisation

    path = out / "sequence.json"
    if not path.is_file():
        fail("fit-sequence --resume", "the run's sequence.json next to its metrics.csv", f"no '{path}'")
    state = json.loads(path.read_text())
    stored = SequenceOptions.from_dict(state["options"])
    given = asdict(options)
    changed = [f"{k} {v!r} (this command line: {given[k]!r})" for k, v in asdict(stored).items()
               if given[k] != v]
    if changed:
        log.warning("--resume keeps the options of sequence.json: " + ", ".join(changed))
    norm = Normalisation(np.asarray(state["centre"], dtype=np.float64), float(state["scale"]))
    done = int(rows[-1][0])
    if _state_path(out, done).is_file():
        with np.load(_state_path(out, done)) as z:
            saved = {k: np.array(z[k]) for k in z.files}
    else:
        V, F = io.read_mesh(out / "control" / f"{done:04d}.ply")
        saved = {"x": norm.forward(V), "F": F}
        for other in sorted((out / STATE_DIR).glob("*.npz")):     # the template is in every state file
            with np.load(other) as z:
                if "rest" in z.files:
                    saved["rest"] = np.array(z["rest"])
                    break
        log.warning(f"{_state_path(out, done)} is missing (an older run?): resuming from "
                    f"control/{done:04d}.ply, which is not bit-exact")
    log.say(f"resuming after frame {done} ({len(rows)} frames done)")
    return stored, state, norm, saved["x"], saved["F"], done, saved


def _read_views(path: Path, t: int, frame, log):
    """Frame ``t``'s photos (:func:`~mi_loop.io.capture.read_capture`), checked against the frame's points.

    Raises
    ------
    ValueError
        A capture without masks (every view all foreground), or cameras that do
        not see the frame's points (another frame's capture, other units).
    """
    from mi_loop.errors import expected
    from mi_loop.fitting.hull import in_mask
    from mi_loop.io.capture import read_capture

    views = list(read_capture(path).views)
    if len(views) < 2:
        raise ValueError(expected("fit-sequence --images", f"at least two photos in '{path}' (frame {t})",
                                  f"{len(views)}"))
    if all(v.mask.min() >= 1.0 for v in views):
        raise ValueError(expected("fit-sequence --images", f"masks in the capture of frame {t} (an alpha "
                                  "channel or mask_path: the silhouettes come from them)",
                                  f"none in '{path}' (every pixel of every photo is foreground)"))
    P = frame[1]
    P = P[np.random.default_rng(0).choice(len(P), min(len(P), 2000), replace=False)]
    share = float(np.median([np.sum(in_mask(v, P)[1]) / len(P) for v in views]))
    if share < 0.5:
        raise ValueError(expected(
            "fit-sequence --images", f"cameras of '{path}' that see frame {t}'s points inside the masks",
            f"{100 * share:.0f} % of them in the median photo (a capture of another frame, or other "
            "units or coordinates than the frames?)"))
    return views


def _frame_metrics(run: _Run, t, V, target, P, N):
    """``(mean, rms, hausdorff, flipped %, drift dict or None)`` of frame ``t``'s fit ``V`` (unit box)."""
    from mi_loop.metrics import attach, drift, flipped_fraction, two_sided
    from mi_loop.subdiv.masks import limit_mesh, limit_positions

    V_world = run.norm.inverse(V)
    limit = limit_mesh(V_world, run.F, level=2)
    clean = None
    if run.sources.reference is not None:
        _, Vr, Fr, _ = run.sources.reference[t]()
        clean = (Vr, Fr)
    mesh = clean if clean is not None else target
    if mesh is not None:
        m = two_sided(limit[0], limit[1], mesh[0], mesh[1], n_samples=30_000)
        flipped = flipped_fraction(limit[0], limit[1], mesh[0], mesh[1])
    else:
        m = two_sided(limit[0], limit[1], P, n_samples=30_000)
        flipped = flipped_fraction(limit[0], limit[1], P, N_target=N)
    d = None
    if clean is not None:
        L = limit_positions(V_world, run.F)
        if run.attachment is None:
            if t != 0 and not _state_path(run.out, 0).is_file():
                return m, 100 * flipped, None, limit
            L0 = L if t == 0 else limit_positions(run.norm.inverse(np.load(_state_path(run.out, 0))["x"]), run.F)
            _, V0, F0, _ = run.sources.reference[0]()
            run.attachment = attach(L0, V0, F0)
        d = drift(L, run.attachment, clean[0])
    return m, 100 * flipped, d, limit


def _write_frame(run: _Run, t, name, V, info, target, P, N, t0, log):
    """Write frame ``t``'s limit, control and state files and its CSV row (the commit); print them."""

    from mi_loop.subdiv.masks import limit_colors as limit_colors_of

    metrics, flipped, d, limit = _frame_metrics(run, t, V, target, P, N)
    seconds = time.perf_counter() - t0
    drift_cells = [f"{d['mean']:.6g}", f"{d['p95']:.6g}"] if d is not None else ["", ""]
    run.rows.append([str(t), name, f"{metrics['mean']:.6g}", f"{metrics['rms']:.6g}",
                     f"{metrics['hausdorff']:.6g}", f"{flipped:.4g}", *drift_cells, f"{seconds:.3f}",
                     f"{info['time_render']:.3f}", str(info["iterations"])])
    V_world = run.norm.inverse(V)
    colors = limit_colors = None
    if run.albedo is not None:
        colors = run.albedo
        limit_colors = limit_colors_of(run.albedo, run.F, 2)
    paths = [io.write_ply(run.out / "control" / f"{t:04d}.ply", V_world, run.F, colors=colors),
             io.write_ply(run.out / "limit" / f"{t:04d}.ply", *limit, colors=limit_colors),
             _write_state(run, t, V)]
    io.write_text(run.out / "metrics.csv", CSV_HEADER + "\n" + "\n".join(",".join(r) for r in run.rows) + "\n")
    paths += run.pending
    run.pending = []
    log.wrote(*paths)
    extra = f", drift {d['mean']:.2e}" if d is not None else ""
    if info.get("noise") is not None:   # how much the images counted where the data saw the surface
        extra += f", data noise {info['noise']:.1e}, image weight there {info['seen_weight']:.2g}"
    log.say(f"frame {t + 1}/{len(run.reader)} {name}: mean {metrics['mean']:.2e} RMS {metrics['rms']:.2e}, "
            f"flipped {flipped:.2f} %{extra} ({seconds:.1f} s, render {info['time_render']:.1f} s)")
    return paths


def _orient(run: _Run, P, N):
    """Turn estimated normals (unit box points ``P``) to agree with the current fit's nearest limit normal."""
    from scipy.spatial import cKDTree

    from mi_loop.subdiv.masks import limit_mesh

    Vl, _, Nl = limit_mesh(run.x, run.F, level=1)
    _, i = cKDTree(Vl).query(P, workers=-1)
    return np.where((np.sum(N * Nl[i], axis=1) < 0)[:, None], -N, N)


def _photo_term(run: _Run, t, frame, log):
    """Frame ``t``'s :class:`~mi_loop.fitting.sequence.PhotoTerm` (the renderer kept while the cameras stay)."""
    from mi_loop.fitting.largesteps import AdamUniform
    from mi_loop.fitting.sequence import PhotoTerm
    from mi_loop.render.photo import PhotoRenderer

    views = _read_views(run.sources.captures[t], t, frame, log)
    o = run.options
    if run.photo is None or not run.photo.set_photos(views):
        run.photo = PhotoRenderer(run.norm.inverse(run.x), run.F, run.albedo, views, run.lights, level=o.level,
                                  spp=o.spp, deterministic=o.deterministic)
    if run.albedo_opt is None:
        run.albedo_opt = AdamUniform(run.albedo, lr=max(o.albedo_lr, 1e-12), uniform=False)
    lr = o.albedo_lr * (1.0 if t == 0 else o.albedo_refine)
    term = PhotoTerm(run.photo, run.norm, run.albedo, lr, state=run.albedo_opt)
    return term


def _fit_frames(run: _Run, first, op, vertex_op, renderer, log) -> list:
    """Fit every frame after ``run.done``; returns the written paths."""
    from mi_loop.fitting import sequence
    from mi_loop.mesh.geometry import vertex_normals

    o = run.options
    paths, todo = [], list(range(run.done + 1, len(run.reader)))
    steps = [o.first_iterations if t == 0 else o.iterations for t in todo]
    with log.bar("fit-sequence") as update:
        for k, t in enumerate(todo):
            t0 = time.perf_counter()
            frame = first if t == 0 else run.reader(t)
            name, P, N, target = frame
            Pn = run.norm.forward(P)
            if run.reader.normals_estimated and target is None:
                N = _orient(run, Pn, N)
            image = None
            if o.image and run.sources.captures:
                image = _photo_term(run, t, frame, log)
            elif renderer is not None and target is not None:
                Vt = run.norm.forward(target[0])
                image = sequence.RenderedTerm(renderer, lambda Vt=Vt, Ft=target[1]:   # rendered if used
                                              renderer.targets(Vt, Ft, vertex_normals(Vt, Ft)))

            def progress(i, n, k=k, t=t):
                update(sum(steps[:k]) + i, sum(steps), f"frame {t + 1}/{len(run.reader)}")

            V, info = sequence.fit_frame(run.x, run.F, Pn, N, op, image, o, t, run.lr, progress=progress,
                                         rest=run.rest, vertex_op=vertex_op, iterations=steps[k],
                                         complete=target is not None)
            if isinstance(image, sequence.PhotoTerm):
                run.albedo = image.albedo
            paths += _write_frame(run, t, name, V, info, target, P, N if target is None else None, t0, log)
            run.x = V
    return paths


def _pictures(run: _Run, log) -> list:
    """``drift.png`` (per-frame error, folds, drift) and ``strip.png`` (target vs fit for a few frames)."""
    from mi_loop.app.report import (
        crop_to_content,
        drift_figure,
        figure_pixels,
        side_by_side,
        strip_figure,
    )

    rows = run.rows
    t = np.array([int(r[0]) for r in rows])

    def column(j):
        return [float(r[j]) if r[j] else np.nan for r in rows]

    drift = drift_figure(t, column(2), column(3), flipped=column(5), drift=column(6))
    paths = [io.write_png(run.out / "drift.png", figure_pixels(drift))]
    picks = sorted(set(np.linspace(0, len(rows) - 1, min(4, len(rows))).round().astype(int)))
    strips = []
    for i in picks:
        frame = int(rows[i][0])
        V, _ = io.read_mesh(run.out / "control" / f"{frame:04d}.ply")
        if run.sources.captures:
            image = _photo_strip(run, frame, V)
        else:
            image = crop_to_content(side_by_side(run.reader.target(frame), V, run.F, resolution=200, spp=16),
                                    halves=2)
        strips.append((frame, float(rows[i][2]), image))
    label = "photo (left), fit (right)" if run.sources.captures else "target (left), fit (right)"
    paths.append(io.write_png(run.out / "strip.png", figure_pixels(strip_figure(strips, label=label))))
    log.wrote(*paths)
    return paths


def _photo_strip(run: _Run, t: int, V_world):
    """The photo of frame ``t`` whose mask is largest next to a render of the fit from its camera, cropped."""
    from mi_loop.io.capture import read_capture
    from mi_loop.io.srgb import linear_to_srgb
    from mi_loop.mesh.geometry import vertex_normals
    from mi_loop.render.photo import render_views
    from mi_loop.subdiv.masks import limit_colors, limit_mesh

    views = list(read_capture(run.sources.captures[t]).views)
    view = max(views, key=lambda v: float(v.mask.sum()))
    Vl, Fl, _ = limit_mesh(V_world, run.F, level=2)
    colors = None
    if run.albedo is not None:
        with np.load(_state_path(run.out, t)) as z:
            albedo = np.array(z["albedo"]) if "albedo" in z.files else run.albedo
        colors = limit_colors(albedo, run.F, 2)
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
    subs = ("control", "limit", STATE_DIR)
    existed = {p: p.exists() for p in [out / s for s in subs] + [out / "sequence.json"]}
    try:
        return _run(inputs, out, options, template, resume, variant, log,
                    images=images, emitters=emitters, reference=reference, selection=frames,
                    animation=animation, fps=fps, view_level=view_level)
    except BaseException:
        with contextlib.suppress(OSError):
            if not (out / "metrics.csv").exists():
                if not existed[out / "sequence.json"]:
                    (out / "sequence.json").unlink(missing_ok=True)
                for sub in subs:
                    if not existed[out / sub]:
                        io.remove_if_empty(out / sub, out / sub)
                io.remove_if_empty(created, out)
        raise


def _operators(run: _Run, first, state, log):
    """Switch the image term off where there is nothing to compare; limit operators and the rig (or None)."""
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.errors import expected
    from mi_loop.fitting.static import sample_parameters
    from mi_loop.render.multiview import Renderer
    from mi_loop.subdiv.masks import vertex_samples

    options = run.options
    photos = bool(run.sources.captures)
    if first[3] is None and not options.geometric and not photos:
        raise ValueError(expected("fit-sequence --image-only", "mesh frames (a surface to render) or --images",
                                  "point-cloud frames"))
    if first[3] is None and options.image and not photos:
        log.say("point-cloud frames without --images: no surface to render, so the image term is off "
                "(IMLS + ARAP only)")
        options.image = False
    fid, uv = sample_parameters(run.F, len(run.x), options.samples, options.seed)
    op = LimitOperator(run.F, len(run.x), fid, uv, derivatives=True)   # normals: facing data only
    vertex_op = LimitOperator(run.F, len(run.x), *vertex_samples(run.F, len(run.x)), derivatives=True)
    renderer = None
    if options.image and not photos:   # cameras fixed for the whole run (resume included): stored box
        box = tuple(np.asarray(c) for c in state["camera_box"])
        renderer = Renderer(run.x, run.F, box, options.rig)
    terms = (["IMLS", "coverage"] if options.cover > 0 else ["IMLS"]) if options.geometric else []
    terms += ["ARAP"] + (["ARAP to the template"] if options.alpha_rest > 0 else [])
    if options.image:
        terms += [f"photos ({len(run.sources.captures)} captures)" if photos
                  else f"image ({options.mode}, {options.views} views)"]
    log.say(f"{len(run.reader)} frames, {len(run.x)} control vertices; terms: {' + '.join(terms)}")
    return op, vertex_op, renderer


def _sources(frames, images, emitters, reference, selection, log) -> Sources:
    """Captures and reference of the frames (counts checked), all cut by ``selection``."""
    from mi_loop.errors import fail
    from mi_loop.io.capture import list_captures
    from mi_loop.io.frames import select_frames

    n = len(frames)
    captures = None
    if images:
        captures = list_captures(images, where="fit-sequence --images")
        if len(captures) != n:
            fail("fit-sequence --images", f"one transforms.json per frame ({n} frames)",
                 f"{len(captures)} captures")
        captures = select_frames(captures, selection, "fit-sequence --frames")
    ref = None
    if reference is not None:
        ref = io.read_frames([reference])
        if len(ref) != n:
            fail("fit-sequence --reference", f"one clean mesh per frame ({n} frames)", f"{len(ref)} in '{reference}'")
        if not all(f.correspondence for f in ref):
            fail("fit-sequence --reference", "meshes in correspondence (an NPZ with vertices (T, V, 3) and faces)",
                 f"'{reference}'")
        ref = select_frames(ref, selection, "fit-sequence --frames")
    elif all(getattr(f, "correspondence", False) for f in frames):
        ref = select_frames(frames, selection, "fit-sequence --frames")
        log.say("frames in correspondence: the correspondence drift is measured against them")
    return Sources(captures, emitters, ref)


def _run(inputs, out, options, template, resume, variant, log, *, images=None, emitters=None, reference=None,
         selection=None, animation=None, fps=24.0, view_level=VIEW_LEVELS["sequence"]):
    from mi_loop.app.inputs import FrameReader
    from mi_loop.io.frames import select_frames
    from mi_loop.render.variant import set_variant

    all_frames = io.read_frames(inputs, animation=animation, fps=fps)
    sources = _sources(all_frames, images, emitters, reference, selection, log)
    frames = select_frames(all_frames, selection, "fit-sequence --frames")
    out = io.ensure_writable_dir(out)
    for sub in ("control", "limit", STATE_DIR):
        io.ensure_writable_dir(out / sub)
    rows = _read_csv(out / "metrics.csv") if resume else []
    set_variant(variant)
    saved = None
    if rows:
        options, state, norm, x, F, done, saved = _resume(out, rows, options, log)
        pending = [out / "metrics.csv"]
        if state.get("fps", fps) != fps:
            log.warning(f"--resume keeps the frame rate of sequence.json: fps {state['fps']:g} "
                        f"(this command line: {fps:g})")
    reader = FrameReader(frames, options.n_points, options.seed, log)
    first = reader(0)
    if not rows:
        state, norm, x, F = _start(out, reader, first, options, template, variant, sources, fps, log)
        done, pending = -1, [out / "sequence.json", out / "metrics.csv"]
    rest = saved["rest"] if saved is not None and "rest" in saved else x
    run_ = _Run(out, reader, options, norm, x, F, float(state["lr"]), rows, done, pending, sources, rest)
    if sources.captures and options.image:
        from mi_loop.io.emitters import DEFAULT_EMITTERS, read_emitters

        run_.lights = read_emitters(emitters) if emitters is not None else [dict(e) for e in DEFAULT_EMITTERS]
        run_.albedo = np.full((len(x), 3), 0.5)
        if saved is not None and "albedo" in saved:
            from mi_loop.fitting.largesteps import AdamUniform

            run_.albedo = saved["albedo"]
            run_.albedo_opt = AdamUniform(run_.albedo, lr=1.0, uniform=False)
            run_.albedo_opt.m, run_.albedo_opt.v = saved["albedo_m"], saved["albedo_v"]
            run_.albedo_opt.t = int(saved["albedo_t"])
    op, vertex_op, renderer = _operators(run_, first, state, log)
    paths = _fit_frames(run_, first, op, vertex_op, renderer, log)
    paths += _pictures(run_, log)
    finished = read_result(out)                  # every finished frame, resumed ones too, read back from control/
    view = sequence_view(finished, view_level)   # (V (T, k, 3), F, N (T, k, 3), colours or None): the viewer's
    rate = float(state.get("fps", fps))           # sequence.json's: --resume keeps it
    page = _report_html(run_, finished, view, rate)
    with io.staged_outputs(out) as stage:
        write_view(stage / "sequence.glb", "glb", view, names=finished.names, fps=rate)
        io.write_text(stage / "report.html", page)
    log.wrote(out / "sequence.glb", out / "report.html")
    return paths + [out / "sequence.glb", out / "report.html"]


def _report_html(run: _Run, finished, view, fps: float) -> str:
    """``report.html`` of every finished frame (:func:`~mi_loop.app.report_data.sequence_report`)."""
    from mi_loop.app.report_data import sequence_report

    rows = [dict(zip(CSV_HEADER.split(","), r)) for r in run.rows]
    frames = [int(r["frame"]) for r in rows]

    def target(i):
        if run.sources.reference is not None:
            _, V, F, _ = run.sources.reference[frames[i]]()
            return ("mesh", V, F)
        return run.reader.target(frames[i])

    cages = [io.read_mesh(p) for p in finished.controls]
    return sequence_report(view, finished.names, target, (np.stack([V for V, _ in cages]), cages[0][1]), rows, fps)
