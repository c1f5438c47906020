"""Command-line interface ``mi-loop``: the only module that parses arguments.

Subcommands
-----------
``mi-loop demo -o OUTDIR``
    Build a procedural control mesh, evaluate its Loop limit surface, render
    it and write ``control.ply``, ``limit.ply`` and ``render.png`` to OUTDIR.
``mi-loop render CONTROL -o OUT.png [--level L]``
    Render the limit surface of a control mesh file (PLY/OBJ/OFF).
``mi-loop control NAME -o OUT.ply``
    Write a procedural control mesh (``blob``, ``icosphere``, ``torus``).
``mi-loop fit INPUT -o OUTDIR [--vertices N | --template PATH] ...``
    Fit a Loop control mesh to a point cloud or mesh (IMLS + coverage + ARAP);
    writes ``control.ply``, ``limit.ply``, ``limit.glb``, ``report.json``, ``loss.png``, ``render.png``.
``mi-loop fit-sequence FRAMES... -o OUTDIR [--template PATH | --vertices N] ...``
    Fit one control mesh frame by frame to a sequence (IMLS + coverage + ARAP
    + multi-view differentiable rendering); writes ``control/``, ``limit/``,
    ``state/``, ``sequence.json``, ``metrics.csv``, ``drift.png``, ``strip.png``,
    ``sequence.glb`` (the frames as morph targets, played at ``--fps``);
    ``--resume`` continues an interrupted run bit for bit.
``mi-loop fit-batch INPUTS... -o OUTDIR [--scheduler ADDRESS | --workers N] [--sequences] ...``
    Fit many inputs on a Dask cluster, each like ``fit`` (or ``fit-sequence``)
    into ``OUTDIR/<name>/``; ``OUTDIR/summary.csv`` lists every input's status,
    time, worker, error and metrics, ``OUTDIR/report.html`` the same with a
    link to each input's report; exit status 1 when any input failed.
``mi-loop fit-images transforms.json -o OUTDIR [--vertices N] [--init sphere|hull|MESH] ...``
    Fit a Loop control mesh and its per-vertex albedo to calibrated photos
    (silhouettes and shading through Mitsuba's differentiable renderer,
    coarse to fine); writes ``control.ply``, ``limit.ply``, ``limit.glb``, ``report.json``,
    ``progress.png``, ``loss.png``.
``mi-loop compare FITTED TARGET``
    Two-sided distances and the Neural Parametric Surfaces metrics between
    a control mesh's limit surface (or any mesh) and a target file.
``mi-loop export OUT [--format glb|obj|ply] [--level L] [-o PATH] [--fps F]``
    Write the limit surface of a result directory of ``fit``, ``fit-images``
    or ``fit-sequence`` at a tessellation level (a sequence: one animated GLB,
    or one OBJ / PLY per frame); default into ``OUT/export/``.
``mi-loop --version``
    mi_loop's version and those of the installed Mitsuba and Dr.Jit.

Progress goes to stderr (``--quiet``: none), written paths to stdout. Every
option is checked before any input is read. Bad input ends with one line
``mi-loop: error: ...`` on stderr and exit status 1 (2 for bad usage);
``--debug`` (before or after the subcommand) or the environment variable
``MI_LOOP_TRACEBACK=1`` prints the traceback above that line.
"""
from __future__ import annotations

import os
import sys
import traceback

from mi_loop import datasets, io
from mi_loop.app.parser import build_parser
from mi_loop.app.progress import Reporter
from mi_loop.errors import FitError, expected
from mi_loop.fitting.declarations import OptionError, declared, option_flag
from mi_loop.fitting.options import IMAGE_INITS, FitOptions, ImageFitOptions, SequenceOptions

__all__ = ["main", "options_from_args"]


def options_from_args(cls, args, command: str):
    """The ``cls`` options (:mod:`mi_loop.fitting.options`) of parsed arguments, checked.

    Parameters
    ----------
    cls : type
        :class:`FitOptions`, :class:`SequenceOptions` or :class:`ImageFitOptions`.
    args : argparse.Namespace
        Parsed by :func:`~mi_loop.app.parser.build_parser` (a field's value under its name).
    command : str
        The command, for messages (``'fit'``, ``'fit-batch'``).

    Returns
    -------
    object
        ``cls(...)``: a capped default is capped by its other flag (``--views-per-iteration``
        at most ``--views``); a file given to a flag that also takes one leaves the field
        at its default (``fit-images --init MESH``).

    Raises
    ------
    ValueError
        A rejected value, named by its flag: ``fit --alpha: expected a finite number >= 0, got -1.0``.
    """
    values = {}
    for f, declaration in declared(cls):
        value = getattr(args, f.name)
        if value is None and declaration.capped_by:
            value = min(f.default, getattr(args, declaration.capped_by))
        if declaration.paths and value not in declaration.rule.choices:
            value = f.default
        values[f.name] = value
    try:
        return cls(**values)
    except OptionError as exc:
        flags = {f.name: option_flag(f) for f, _ in declared(cls)}
        raise ValueError(expected(f"{command} {flags.get(exc.name, exc.name)}", exc.what, exc.shown)) from None


def _no_template_to_build(args, command: str) -> None:
    """``--poisson-template``, ``--template-depth`` and ``--template-genus`` build the template: refuse them with
    ``--template``."""
    if args.template is None:
        return
    for given, flag in ((getattr(args, "poisson_template", False), "--poisson-template"),
                        (args.template_depth is not None, "--template-depth"),
                        (args.template_genus is not None, "--template-genus")):
        if given:
            raise ValueError(expected(f"{command} {flag}", "no --template (it builds the template)",
                                      f"--template '{args.template}'"))


def check_variant(name: str, command: str) -> None:
    """Refuse a variant that is not a JIT autodiff variant of the installed Mitsuba (before any work)."""
    from mi_loop.render.variant import jit_ad_variants

    usable = jit_ad_variants()
    if name not in usable:
        raise ValueError(expected(f"{command} --variant", f"one of {', '.join(usable)}", repr(name)))


def _render(V, F, args, model, log):
    """Set the variant, render the limit surface; returns (sRGB image, shape)."""
    from mi_loop.render import scene as render
    from mi_loop.render.variant import set_variant

    log.say(f"setting Mitsuba variant {args.variant} (first kernel compilation takes a few seconds)")
    set_variant(args.variant)
    log.say(f"evaluating the limit surface at level {args.level} and rendering "
            f"{args.resolution}x{args.resolution} at {args.spp} spp")
    return render.render_limit_surface(V, F, level=args.level, **model,
                                       resolution=args.resolution, spp=args.spp)


def _demo(args, log) -> None:
    from mi_loop.mesh.topology import validate_mesh
    from mi_loop.render import plugin

    check_variant(args.variant, "demo")
    out = io.ensure_writable_dir(args.output)
    V, F = datasets.control_mesh(args.shape)
    validate_mesh(V, F)
    log.say(f"control mesh '{args.shape}': {len(V)} vertices, {len(F)} faces")
    written = [io.write_ply(out / "control.ply", V, F)]
    image, shape = _render(V, F, args, {}, log)
    P, N, F_tess = plugin.mesh_arrays(shape)
    log.say(f"limit surface: {len(P)} vertices, {len(F_tess)} triangles")
    written.append(io.write_ply(out / "limit.ply", P, F_tess, normals=N))
    written.append(io.write_png(out / "render.png", image))
    log.wrote(*written)


def _render_file(args, log) -> None:
    from mi_loop.render.plugin import parse_corner_text, parse_crease_text

    if args.output.suffix.lower() != ".png":
        raise ValueError(expected("render --output", "a .png file", f"'{args.output}'"))
    model = dict(creases=parse_crease_text(args.creases), corners=parse_corner_text(args.corners),
                 boundary=args.boundary, crease_method=args.crease_method)
    check_variant(args.variant, "render")
    io.ensure_writable_dir(args.output.parent)
    V, F = io.read_mesh(args.control)
    if model["creases"] is None:
        model["creases"] = io.read_creases(args.control)      # e.g. a control.ply written by mi-loop fit
    n_creases = 0 if model["creases"] is None else len(model["creases"][0])
    log.say(f"control mesh '{args.control}': {len(V)} vertices, {len(F)} faces, {n_creases} crease edges")
    image, _ = _render(V, F, args, model, log)
    log.wrote(io.write_png(args.output, image))


def _fit(args, log) -> None:
    from mi_loop.app import fit_job

    options = options_from_args(FitOptions, args, "fit")
    _no_template_to_build(args, "fit")
    if args.demo == (args.input is not None):
        raise ValueError(expected("fit INPUT", "an input file or --demo (one of them)",
                                  "both" if args.demo else "neither"))
    check_variant(args.variant, "fit")
    fit_job.run(args.input, args.output, options, template=args.template, variant=args.variant, log=log,
                view_level=args.view_level)


def _fit_sequence(args, log) -> None:
    from mi_loop.app import sequence_job

    options = options_from_args(SequenceOptions, args, "fit-sequence")
    _no_template_to_build(args, "fit-sequence")
    check_variant(args.variant, "fit-sequence")
    _check_fps(args.fps, "fit-sequence")
    sequence_job.run(args.frames, args.output, options, template=args.template, resume=args.resume,
                     variant=args.variant, log=log, images=args.images, emitters=args.emitters,
                     reference=args.reference, frames=args.frame_range, animation=args.animation, fps=args.fps,
                     view_level=args.view_level)


def _fit_batch(args, log) -> None:
    from mi_loop.app import batch_job

    options = options_from_args(SequenceOptions if args.sequences else FitOptions, args, "fit-batch")
    _no_template_to_build(args, "fit-batch")
    check_variant(args.variant, "fit-batch")
    batch_job.run(args.inputs, args.output, options, scheduler=args.scheduler, workers=args.workers,
                  template=args.template, variant=args.variant, frames=getattr(args, "frame_range", None), log=log,
                  view_level=args.view_level)


def _fit_images(args, log) -> None:
    from pathlib import Path

    from mi_loop.app import images_job

    options = options_from_args(ImageFitOptions, args, "fit-images")
    init = None if args.init in IMAGE_INITS else Path(args.init)
    if init is not None and not init.is_file():
        raise ValueError(expected("fit-images --init", "sphere, hull or an existing control mesh file",
                                  f"'{args.init}'"))
    check_variant(args.variant, "fit-images")
    images_job.run(args.capture, args.output, options, init=init, emitters=args.emitters, variant=args.variant,
                   log=log, view_level=args.view_level)


def _compare(args, log) -> None:
    import json

    from mi_loop.app import compare_job

    as_ = "mesh" if args.mesh else "control" if args.control else "auto"
    result = compare_job.run(args.fitted, args.target, as_=as_, log=log)
    text = json.dumps(result, indent=2)
    print(text)
    if args.json:
        io.ensure_writable_dir(args.json.parent)
        io.write_text(args.json, text + "\n")


def _check_fps(fps, command: str) -> None:
    import math

    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise ValueError(expected(f"{command} --fps", "a finite number > 0", fps))


def _export(args, log) -> None:
    from mi_loop.app import export_job

    _check_fps(args.fps, "export")
    export_job.run(args.result, args.fmt, level=args.level, output=args.output, fps=args.fps, log=log)


def _control(args, log) -> None:
    io.ensure_writable_dir(args.output.parent)
    V, F = datasets.control_mesh(args.name)
    log.wrote(io.write_ply(args.output, V, F))


COMMANDS = {"demo": _demo, "render": _render_file, "control": _control, "fit": _fit, "compare": _compare,
            "fit-sequence": _fit_sequence, "fit-batch": _fit_batch, "fit-images": _fit_images, "export": _export}


def _traceback_wanted(args) -> bool:
    return bool(getattr(args, "debug", False)) or os.environ.get("MI_LOOP_TRACEBACK", "") not in ("", "0")


def main(argv=None) -> int:
    """Run ``mi-loop``; return the exit status.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        0 on success, 1 on bad input or a failed run (:class:`~mi_loop.errors.FitError`),
        2 on bad usage, 130 on Ctrl-C.
    """
    args = build_parser().parse_args(argv)
    log = Reporter(quiet=args.quiet)
    try:
        COMMANDS[args.command](args, log)
    except (FitError, ValueError, TypeError, OSError, RuntimeError, ImportError) as exc:
        if _traceback_wanted(args):
            traceback.print_exc(file=sys.stderr)
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"mi-loop: error: {message}", file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        if _traceback_wanted(args):
            traceback.print_exc(file=sys.stderr)
        print("mi-loop: error: interrupted", file=sys.stderr, flush=True)
        return 130
    log.say("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
