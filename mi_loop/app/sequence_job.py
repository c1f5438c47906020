"""The ``mi-loop fit-sequence`` job: read frames, fit each, write each atomically, resume.

Layout of OUTDIR: ``control/0000.ply ...`` (one connectivity for all frames),
``limit/0000.ply ...``, ``metrics.csv`` (one row per finished frame),
``sequence.json`` (normalisation, step size, options: what ``--resume`` needs),
``drift.png`` and ``strip.png`` (written when the run completes).
"""
from __future__ import annotations

import contextlib
import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from mi_loop import io

CSV_HEADER = "frame,name,mean,rms,hausdorff,seconds,time_render,iterations"


def _frame_data(frame, n_points, seed):
    """Oriented points and (for meshes) the target mesh of one frame."""
    from mi_loop.mesh.sampling import sample_surface

    name, X, F, N = frame
    if not np.isfinite(X).all():
        bad = int(np.flatnonzero(~np.isfinite(X).all(1))[0])
        raise ValueError(f"frame {name}: vertex {bad} has a non-finite coordinate")
    if F is None:
        return name, X, N, None
    P, Np, _ = sample_surface(X, F, n_points, seed=seed)
    return name, P, Np, (X, F)


def _template(first, norm, args, start, say):
    """The first frame's automatic template (normalised units): from its mesh, else Poisson.

    A mesh frame is refined and decimated directly (:func:`mesh_template`),
    which keeps thin parts that a coarse Poisson octree loses; a point-cloud
    frame, a mesh that is not a clean manifold, or ``--poisson-template`` goes
    through screened Poisson + decimation (:func:`make_template`).
    """
    from mi_loop.fitting.template import make_template, mesh_template

    if first[3] is not None and not args.poisson_template:
        try:
            x, F, _ = mesh_template(norm.forward(first[3][0]), first[3][1], args.vertices)
            say(f"template: first frame's mesh decimated to {len(x)} vertices", start)
            return x, F
        except ValueError as exc:
            say(f"template: first frame's mesh cannot be used ({exc}); screened Poisson instead", start)
    say(f"template: screened Poisson + decimation to {args.vertices} vertices", start)
    x, F, _ = make_template(norm.forward(first[1]), first[2], args.vertices, seed=args.seed)
    return x, F


def _read_csv(path: Path):
    if not path.exists():
        return []
    lines = path.read_text().strip().splitlines()[1:]
    return [line.split(",") for line in lines if line]


def run(args, start, say):
    """Run ``mi-loop fit-sequence``; returns the written paths of the last frame and pictures.

    A run that fails (or is interrupted) before its first frame is written
    leaves nothing behind: the state file and the directories it created are
    removed. Finished frames are always kept (``--resume`` continues them).
    """
    out = Path(args.output)
    created = io.first_missing_ancestor(out)
    existed = {p: p.exists() for p in (out / "control", out / "limit", out / "sequence.json")}
    try:
        return _run(args, start, say)
    except BaseException:
        with contextlib.suppress(OSError):
            if not (out / "metrics.csv").exists():
                if not existed[out / "sequence.json"]:
                    (out / "sequence.json").unlink(missing_ok=True)
                for sub in ("control", "limit"):
                    if not existed[out / sub]:
                        io.remove_if_empty(out / sub, out / sub)
                io.remove_if_empty(created, out)
        raise


def _run(args, start, say):
    from mi_loop.fitting.static import Normalisation, sample_parameters
    from mi_loop.subdiv.masks import limit_mesh
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.fitting.sequence import SequenceOptions, fit_frame
    from mi_loop.mesh.geometry import mean_edge_length, vertex_normals
    from mi_loop.render.multiview import Renderer
    from mi_loop.mesh.topology import validate_mesh
    from mi_loop.render.variant import set_variant

    frames = io.read_frames(args.frames)
    out = io.ensure_writable_dir(args.output)
    for sub in ("control", "limit"):
        io.ensure_writable_dir(out / sub)
    state_path, csv_path = out / "sequence.json", out / "metrics.csv"
    rows = _read_csv(csv_path) if args.resume else []
    set_variant("llvm_ad_rgb")
    options = SequenceOptions(alpha=args.alpha, beta=args.beta, views=args.views,
                              views_per_iteration=min(args.views_per_iteration, args.views),
                              resolution=args.res, spp=args.spp, loss=args.loss, mode=args.mode,
                              geometric=not args.image_only, image=not args.no_image,
                              geo_iterations=args.iterations, joint_iterations=args.image_iterations,
                              cover=args.cover, seed=args.seed)
    first = _frame_data(frames[0](), args.points, args.seed)
    if args.resume and rows:
        state = json.loads(state_path.read_text())
        norm = Normalisation(np.asarray(state["centre"]), state["scale"])
        options = SequenceOptions(**state["options"])
        done = int(rows[-1][0])
        V_prev, F = io.read_mesh(out / "control" / f"{done:04d}.ply")
        x = norm.forward(V_prev)
        lr = state["lr"]
        say(f"resuming after frame {done} ({len(rows)} frames done)", start)
    else:
        norm = Normalisation.of(first[1])
        if args.template is not None:
            V_t, F = io.read_mesh(args.template)
            V_t, F, _ = validate_mesh(V_t, F, f"--template {args.template}")
            x = norm.forward(V_t)
        else:
            x, F = _template(first, norm, args, start, say)
        lr = 0.02 * mean_edge_length(x, F)
        lo, hi = x.min(0), x.max(0)
        pad = 0.15 * (hi - lo).max()
        state = {"centre": norm.centre.tolist(), "scale": norm.scale, "lr": lr,
                 "camera_box": [(lo - pad).tolist(), (hi + pad).tolist()],
                 "options": asdict(options), "n_frames": len(frames)}
        io.write_text(state_path, json.dumps(state, indent=2) + "\n")
        rows, done = [], -1
    if first[3] is None and not options.geometric:
        raise ValueError("fit-sequence: --image-only needs mesh frames; point-cloud frames have no "
                         "surface to render")
    if first[3] is None and options.image:
        say("point-cloud frames: no surface to render, so the image term is off (IMLS + ARAP only)", start)
        options.image = False
    fid, uv = sample_parameters(F, len(x), args.samples)
    op = LimitOperator(F, len(x), fid, uv, derivatives=False)
    renderer = None
    if options.image:   # cameras fixed for the whole run (resume included): stored box
        box = tuple(np.asarray(c) for c in state["camera_box"])
        renderer = Renderer(x, F, box, options.rig)
    say(f"{len(frames)} frames, {len(x)} control vertices, image term "
        f"{'on (' + options.mode + ', ' + str(options.views) + ' views)' if options.image else 'off'}", start)
    for t in range(done + 1, len(frames)):
        t0 = time.perf_counter()
        name, P, N, target = first if t == 0 else _frame_data(frames[t](), args.points, args.seed + t)
        Pn = norm.forward(P)
        targets = None
        if renderer is not None and target is not None:
            Vt = norm.forward(target[0])
            targets = renderer.targets(Vt, target[1], vertex_normals(Vt, target[1]))
        V, info = fit_frame(x, F, Pn, N, op, targets, renderer, options, t, lr)
        x = V
        V_world = norm.inverse(V)
        limit = limit_mesh(V_world, F, level=2)
        metrics = _frame_metrics(limit, target, P)
        seconds = time.perf_counter() - t0
        rows.append([str(t), name, f"{metrics['mean']:.6g}", f"{metrics['rms']:.6g}",
                     f"{metrics['hausdorff']:.6g}", f"{seconds:.3f}", f"{info['time_render']:.3f}",
                     str(info["iterations"])])
        io.write_ply(out / "limit" / f"{t:04d}.ply", *limit)
        io.write_ply(out / "control" / f"{t:04d}.ply", V_world, F)
        io.write_text(csv_path, CSV_HEADER + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
        say(f"frame {t + 1}/{len(frames)} {name}: mean {metrics['mean']:.2e} RMS {metrics['rms']:.2e} "
            f"({seconds:.1f} s, render {info['time_render']:.1f} s)", start)
    return [csv_path] + _pictures(out, rows, frames, norm, F, args)


def _frame_metrics(limit, target, P):
    from mi_loop.metrics import two_sided

    if target is not None:
        return two_sided(limit[0], limit[1], target[0], target[1], n_samples=30_000)
    return two_sided(limit[0], limit[1], P, n_samples=30_000)


def _pictures(out, rows, frames, norm, F, args):
    """drift.png (per-frame error) and strip.png (target vs fit for a few frames)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mi_loop.app.report import figure_pixels, side_by_side

    t = np.array([int(r[0]) for r in rows])
    mean = np.array([float(r[2]) for r in rows])
    rms = np.array([float(r[3]) for r in rows])
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=100)
    ax.plot(t, mean, "o-", label="mean")
    ax.plot(t, rms, "s-", label="RMS")
    ax.set_xlabel("frame")
    ax.set_ylabel("distance to target / bbox diagonal")
    ax.set_title("per-frame error (drift)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    paths = [io.write_png(out / "drift.png", figure_pixels(fig))]
    picks = sorted(set(np.linspace(0, len(rows) - 1, min(4, len(rows))).round().astype(int)))
    strips = []
    for i in picks:
        name, X, Ft, N = frames[int(rows[i][0])]()
        target = ("mesh", X, Ft) if Ft is not None else ("points", X, N)
        V, _ = io.read_mesh(out / "control" / f"{int(rows[i][0]):04d}.ply")
        strips.append((int(rows[i][0]), float(rows[i][2]), side_by_side(target, V, F, resolution=200, spp=16)))
    fig, axes = plt.subplots(len(strips), 1, figsize=(4.0, 2.1 * len(strips)), dpi=100, squeeze=False)
    for ax, (t, mean, image) in zip(axes[:, 0], strips):
        ax.imshow(image)
        ax.set_axis_off()
        ax.set_title(f"frame {t}: target (left), fit (right); mean {mean:.1e}", fontsize=8)
    fig.tight_layout()
    paths.append(io.write_png(out / "strip.png", figure_pixels(fig)))
    return paths
