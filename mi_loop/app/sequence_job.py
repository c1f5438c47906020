"""The ``mi-loop fit-sequence`` job: read frames, fit each, write each atomically, resume bit for bit.

Layout of OUTDIR (every path is printed on stdout as it is written):

- ``control/0000.ply ...``: the fitted control mesh of every frame, in the
  frames' units (one connectivity for all frames);
- ``limit/0000.ply ...``: its limit surface (level-2 tessellation);
- ``state/0000.npz ...``: ``x``, the exact float64 control points of the frame
  in the unit box, and ``F``, the faces: what ``--resume`` starts the next
  frame from (the PLY files in world units do not map back bit for bit);
- ``metrics.csv``: one row per finished frame (``frame, name, mean, rms,
  hausdorff`` relative to the target's bounding-box diagonal, ``seconds``,
  ``time_render``, ``iterations``); a frame is finished once its row is there;
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
  ``variant``
      the Mitsuba variant of the run;
- ``drift.png`` (per-frame error) and ``strip.png`` (target and fit for a few
  frames), drawn when the run completes.
"""
from __future__ import annotations

import contextlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.fitting.options import SequenceOptions
from mi_loop.render.variant import DEFAULT_VARIANT

__all__ = ["CSV_HEADER", "STATE_DIR", "run"]

CSV_HEADER = "frame,name,mean,rms,hausdorff,seconds,time_render,iterations"
#: Sub-directory of OUTDIR with the exact per-frame state (``NNNN.npz``).
STATE_DIR = "state"


@dataclass
class _Run:
    """What the frame loop carries: outputs, frames, options, normalisation, control mesh, step."""

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


def _template(first, norm, options: SequenceOptions, log):
    """The first frame's automatic template (normalised units): from its mesh, else Poisson.

    A mesh frame is refined and decimated directly (:func:`mesh_template`),
    which keeps thin parts that a coarse Poisson octree loses; a point-cloud
    frame, a mesh that is not a clean manifold, or ``poisson_template`` goes
    through screened Poisson + decimation (:func:`make_template`).
    """
    from mi_loop.fitting.template import make_template, mesh_template

    if first[3] is not None and not options.poisson_template:
        try:
            x, F, _ = mesh_template(norm.forward(first[3][0]), first[3][1], options.n_vertices)
            log.say(f"template: first frame's mesh decimated to {len(x)} vertices")
            return x, F, {"source": "mesh", "n_vertices": len(x), "n_faces": len(F)}
        except ValueError as exc:
            log.say(f"template: first frame's mesh cannot be used ({exc}); screened Poisson instead")
    log.say(f"template: screened Poisson + decimation to {options.n_vertices} vertices")
    x, F, _ = make_template(norm.forward(first[1]), first[2], options.n_vertices, seed=options.seed)
    return x, F, {"source": "poisson", "n_vertices": len(x), "n_faces": len(F)}


def _read_csv(path: Path):
    if not path.exists():
        return []
    lines = path.read_text().strip().splitlines()[1:]
    return [line.split(",") for line in lines if line]


def _state_path(out: Path, t: int) -> Path:
    return out / STATE_DIR / f"{t:04d}.npz"


def _write_state(out: Path, t: int, x, F) -> Path:
    """``state/NNNN.npz`` with the exact normalised control points and the faces, atomically."""
    path = _state_path(out, t)
    with io.atomic_open(path) as f:
        np.savez(f, x=np.asarray(x, dtype=np.float64), F=np.asarray(F, dtype=np.int64))
    return path


def _start(out, reader, first, options, template, variant, log):
    """A fresh run: normalisation, template, step size and cameras, written to ``sequence.json``.

    Returns ``(state, norm, x, F)``: the ``sequence.json`` dict, the
    normalisation, the template's control points (unit box) and faces.
    """
    from mi_loop.fitting.static import Normalisation
    from mi_loop.mesh.geometry import mean_edge_length

    norm = Normalisation.of(first[1])
    if template is not None:
        from mi_loop.app.inputs import read_template

        V_t, F, tinfo = read_template(template, first[1], f"fit-sequence --template '{template}'", log)
        x = norm.forward(V_t)
    else:
        x, F, tinfo = _template(first, norm, options, log)
    lr = 0.02 * mean_edge_length(x, F)
    lo, hi = x.min(0), x.max(0)
    pad = 0.15 * (hi - lo).max()
    state = {"centre": norm.centre.tolist(), "scale": norm.scale, "lr": lr,
             "camera_box": [(lo - pad).tolist(), (hi + pad).tolist()], "options": asdict(options),
             "n_frames": len(reader), "template": tinfo, "normals_estimated": reader.normals_estimated,
             "variant": variant}
    from mi_loop.app.report import plain

    io.write_text(out / "sequence.json", json.dumps(plain(state), indent=2) + "\n")
    return state, norm, x, F


def _resume(out, rows, options, log):
    """Continue after the last finished frame; ``(options, state, norm, x, F, done)``.

    The stored options and normalisation, and the exact control points of the
    last finished frame from ``state/NNNN.npz``.
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
            x, F = np.array(z["x"]), np.array(z["F"])
    else:
        V, F = io.read_mesh(out / "control" / f"{done:04d}.ply")
        x = norm.forward(V)
        log.warning(f"{_state_path(out, done)} is missing (an older run?): resuming from "
                 f"control/{done:04d}.ply, which is not bit-exact")
    log.say(f"resuming after frame {done} ({len(rows)} frames done)")
    return stored, state, norm, x, F, done


def _frame_metrics(limit, target, P):
    from mi_loop.metrics import two_sided

    if target is not None:
        return two_sided(limit[0], limit[1], target[0], target[1], n_samples=30_000)
    return two_sided(limit[0], limit[1], P, n_samples=30_000)


def _write_frame(run: _Run, t, name, V, info, target, P, t0, log):
    """Write frame ``t``'s limit, control and state files and its CSV row (the commit); print them."""
    from mi_loop.subdiv.masks import limit_mesh

    V_world = run.norm.inverse(V)
    limit = limit_mesh(V_world, run.F, level=2)
    metrics = _frame_metrics(limit, target, P)
    seconds = time.perf_counter() - t0
    run.rows.append([str(t), name, f"{metrics['mean']:.6g}", f"{metrics['rms']:.6g}",
                     f"{metrics['hausdorff']:.6g}", f"{seconds:.3f}", f"{info['time_render']:.3f}",
                     str(info["iterations"])])
    paths = [io.write_ply(run.out / "control" / f"{t:04d}.ply", V_world, run.F),
             io.write_ply(run.out / "limit" / f"{t:04d}.ply", *limit),
             _write_state(run.out, t, V, run.F)]
    io.write_text(run.out / "metrics.csv", CSV_HEADER + "\n" + "\n".join(",".join(r) for r in run.rows) + "\n")
    paths += run.pending
    run.pending = []
    log.wrote(*paths)
    log.say(f"frame {t + 1}/{len(run.reader)} {name}: mean {metrics['mean']:.2e} RMS {metrics['rms']:.2e} "
            f"({seconds:.1f} s, render {info['time_render']:.1f} s)")
    return paths


def _fit_frames(run: _Run, first, op, renderer, log) -> list:
    """Fit every frame after ``run.done``; returns the written paths."""
    from mi_loop.fitting import sequence
    from mi_loop.mesh.geometry import vertex_normals

    paths, todo = [], range(run.done + 1, len(run.reader))
    with log.bar("fit-sequence") as update:
        for k, t in enumerate(todo):
            t0 = time.perf_counter()
            name, P, N, target = first if t == 0 else run.reader(t)
            targets = None
            if renderer is not None and target is not None:
                Vt = run.norm.forward(target[0])
                targets = renderer.targets(Vt, target[1], vertex_normals(Vt, target[1]))

            def progress(i, n, k=k, t=t):
                update(k * n + i, n * len(todo), f"frame {t + 1}/{len(run.reader)}")

            V, info = sequence.fit_frame(run.x, run.F, run.norm.forward(P), N, op, targets, renderer,
                                         run.options, t, run.lr, progress=progress)
            paths += _write_frame(run, t, name, V, info, target, P, t0, log)
            run.x = V
    return paths


def _pictures(run: _Run, log) -> list:
    """``drift.png`` (per-frame error) and ``strip.png`` (target vs fit for a few frames)."""
    from mi_loop.app.report import (
        drift_figure,
        figure_pixels,
        side_by_side,
        strip_figure,
    )

    rows = run.rows
    t = np.array([int(r[0]) for r in rows])
    drift = drift_figure(t, [float(r[2]) for r in rows], [float(r[3]) for r in rows])
    paths = [io.write_png(run.out / "drift.png", figure_pixels(drift))]
    picks = sorted(set(np.linspace(0, len(rows) - 1, min(4, len(rows))).round().astype(int)))
    strips = []
    for i in picks:
        frame = int(rows[i][0])
        V, _ = io.read_mesh(run.out / "control" / f"{frame:04d}.ply")
        strips.append((frame, float(rows[i][2]),
                       side_by_side(run.reader.target(frame), V, run.F, resolution=200, spp=16)))
    paths.append(io.write_png(run.out / "strip.png", figure_pixels(strip_figure(strips))))
    log.wrote(*paths)
    return paths


def run(inputs, output, options: SequenceOptions, *, template: Path | None = None, resume: bool = False,
        variant: str = DEFAULT_VARIANT, log) -> list:
    """Run ``mi-loop fit-sequence``; returns every written path (each also printed as it is written).

    Parameters
    ----------
    inputs : list of str or os.PathLike
        Frames: an NPZ, frame files, directories or quoted globs (:func:`mi_loop.io.read_frames`).
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
        return _run(inputs, out, options, template, resume, variant, log)
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
    """Switch the image term off for point clouds; the limit operator and the renderer (or None)."""
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.errors import expected
    from mi_loop.fitting.static import sample_parameters
    from mi_loop.render.multiview import Renderer

    options = run.options
    if first[3] is None and not options.geometric:
        raise ValueError(expected("fit-sequence --image-only", "mesh frames (a surface to render)",
                                  "point-cloud frames"))
    if first[3] is None and options.image:
        log.say("point-cloud frames: no surface to render, so the image term is off (IMLS + ARAP only)")
        options.image = False
    fid, uv = sample_parameters(run.F, len(run.x), options.samples, options.seed)
    op = LimitOperator(run.F, len(run.x), fid, uv, derivatives=False)
    renderer = None
    if options.image:   # cameras fixed for the whole run (resume included): stored box
        box = tuple(np.asarray(c) for c in state["camera_box"])
        renderer = Renderer(run.x, run.F, box, options.rig)
    terms = (["IMLS", "coverage"] if options.cover > 0 else ["IMLS"]) if options.geometric else []
    terms += ["ARAP"] + ([f"image ({options.mode}, {options.views} views)"] if options.image else [])
    log.say(f"{len(run.reader)} frames, {len(run.x)} control vertices; terms: {' + '.join(terms)}")
    return op, renderer


def _run(inputs, out, options, template, resume, variant, log):
    from mi_loop.app.inputs import FrameReader
    from mi_loop.render.variant import set_variant

    frames = io.read_frames(inputs)
    out = io.ensure_writable_dir(out)
    for sub in ("control", "limit", STATE_DIR):
        io.ensure_writable_dir(out / sub)
    rows = _read_csv(out / "metrics.csv") if resume else []
    set_variant(variant)
    if rows:
        options, state, norm, x, F, done = _resume(out, rows, options, log)
        pending = [out / "metrics.csv"]
    reader = FrameReader(frames, options.n_points, options.seed, log)
    first = reader(0)
    if not rows:
        state, norm, x, F = _start(out, reader, first, options, template, variant, log)
        done, pending = -1, [out / "sequence.json", out / "metrics.csv"]
    run_ = _Run(out, reader, options, norm, x, F, float(state["lr"]), rows, done, pending)
    op, renderer = _operators(run_, first, state, log)
    paths = _fit_frames(run_, first, op, renderer, log)
    return paths + _pictures(run_, log)
