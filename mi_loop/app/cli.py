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
    Fit a Loop control mesh to a point cloud or mesh (IMLS + ARAP); writes
    ``control.ply``, ``limit.ply``, ``report.json``, ``loss.png``, ``render.png``.
``mi-loop fit-sequence FRAMES... -o OUTDIR [--template PATH | --vertices N] ...``
    Fit one control mesh frame by frame to a sequence (IMLS + ARAP + multi-view
    differentiable rendering); writes ``control/``, ``limit/``, ``metrics.csv``,
    ``drift.png``, ``strip.png``; ``--resume`` continues an interrupted run.
``mi-loop compare A B``
    Two-sided distances and the Neural Parametric Surfaces metrics between
    a control mesh's limit surface (or any mesh) and a target file.

Progress goes to stderr, written paths to stdout. Bad input ends with one
line ``mi-loop: error: ...`` on stderr and exit status 1 (2 for bad usage).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mi_loop import datasets

from mi_loop import io

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line on stderr."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _positive(text: str) -> int:
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text}")
    return value


def _level(text: str) -> int:
    value = int(text)
    if not 0 <= value <= 6:
        raise argparse.ArgumentTypeError(f"expected a level in 0..6, got {text}")
    return value


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mi-loop", description="Exact Loop subdivision limit surfaces in Mitsuba 3.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    def render_options(p):
        p.add_argument("--level", type=_level, default=3, help="4**level triangles per control face (default 3)")
        p.add_argument("--resolution", type=_positive, default=256, help="image width and height (default 256)")
        p.add_argument("--spp", type=_positive, default=64, help="samples per pixel (default 64)")

    demo = sub.add_parser("demo", help="render the limit surface of a procedural control mesh")
    demo.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    demo.add_argument("--shape", choices=sorted(datasets.CONTROL_MESHES), default="blob")
    render_options(demo)

    render = sub.add_parser("render", help="render the limit surface of a control mesh file")
    render.add_argument("control", type=Path, help="control mesh (PLY, OBJ or OFF)")
    render.add_argument("-o", "--output", required=True, type=Path, help="PNG file to write")
    render.add_argument("--creases", default="", help="sharp edges as vertex pairs, e.g. '0 1, 1 2'")
    render_options(render)

    fit = sub.add_parser("fit", help="fit a Loop control mesh to a point cloud or mesh")
    fit.add_argument("input", type=Path, nargs="?",
                     help="points (PLY/XYZ/PTS/NPZ) or mesh (PLY/OBJ/OFF); omit with --demo")
    fit.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    fit_options(fit)
    fit.add_argument("--demo", action="store_true",
                     help="fit the built-in noisy torus point cloud (no input file)")

    seq = sub.add_parser("fit-sequence", help="fit one control mesh to every frame of a sequence")
    seq.add_argument("frames", type=Path, nargs="+",
                     help="an NPZ (vertices (T,V,3), faces), or frame files / directories")
    seq.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    group = seq.add_mutually_exclusive_group()
    group.add_argument("--vertices", type=int, default=1000, help="template control vertices (default 1000)")
    group.add_argument("--template", type=Path, help="control mesh to use for every frame")
    seq.add_argument("--poisson-template", action="store_true",
                     help="build the automatic template by screened Poisson even when the first frame is a mesh")
    seq.add_argument("--views", type=_positive, default=20, help="cameras around the subject (default 20)")
    seq.add_argument("--views-per-iteration", type=_positive, default=2, help="random views per iteration (default 2)")
    seq.add_argument("--res", type=_positive, default=96, help="image size (default 96)")
    seq.add_argument("--spp", type=_positive, default=4, help="samples per pixel of the renders (default 4)")
    seq.add_argument("--beta", type=float, default=1.0, help="image-loss weight (default 1)")
    seq.add_argument("--alpha", type=float, default=0.01, help="ARAP weight (default 0.01)")
    seq.add_argument("--samples", choices=["vertices", "level1", "random"], default="level1",
                     help="limit samples of the geometric terms (default level1)")
    seq.add_argument("--cover", type=float, default=3.0,
                     help="weight of the coverage term: data points pull their nearest samples (default 3)")
    seq.add_argument("--loss", choices=["l1", "l2"], default="l1")
    seq.add_argument("--mode", choices=["shading", "silhouette"], default="shading",
                     help="shaded images (default) or silhouettes only")
    seq.add_argument("--iterations", type=_positive, default=200, help="geometric iterations per frame (default 200)")
    seq.add_argument("--image-iterations", type=_positive, default=8,
                     help="iterations with the image term per frame (default 8)")
    seq.add_argument("--points", type=_positive, default=20_000, help="points sampled per mesh frame")
    exclusive = seq.add_mutually_exclusive_group()
    exclusive.add_argument("--no-image", action="store_true", help="geometric terms only (baseline)")
    exclusive.add_argument("--image-only", action="store_true", help="image term (+ ARAP) only (baseline)")
    seq.add_argument("--resume", action="store_true", help="continue after the last finished frame")
    seq.add_argument("--seed", type=int, default=0)

    compare = sub.add_parser("compare", help="distances between a fitted surface and a target")
    compare.add_argument("fitted", type=Path, help="control mesh (its limit surface is used) or --mesh")
    compare.add_argument("target", type=Path, help="target points or mesh")
    compare.add_argument("--mesh", action="store_true",
                         help="treat FITTED as a plain triangle mesh, not a control mesh")
    compare.add_argument("--json", type=Path, help="also write the numbers to this JSON file")

    control = sub.add_parser("control", help="write a procedural control mesh")
    control.add_argument("name", choices=sorted(datasets.CONTROL_MESHES))
    control.add_argument("-o", "--output", required=True, type=Path, help="PLY file to write")
    return parser


def fit_options(p):
    group = p.add_mutually_exclusive_group()
    group.add_argument("--vertices", type=int, default=1000,
                       help="control vertices of the automatic template (default 1000)")
    group.add_argument("--template", type=Path, help="control mesh to start from instead")
    p.add_argument("--alpha", type=float, help="ARAP weight (default 0.001; raise it for noisy data)")
    p.add_argument("--h0", type=float, help="IMLS radius in the unit box (default: from point spacing)")
    p.add_argument("--cover", type=float, default=3.0,
                   help="coverage weight: data points pull their nearest limit samples (default 3; 0: off)")
    p.add_argument("--samples", choices=["vertices", "level1", "random"], default="level1",
                   help="limit samples: level-1 tessellation points (default) or one per control vertex")
    p.add_argument("--iterations", type=_positive, default=400, help="iteration cap (default 400)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _say(message: str, start: float) -> None:
    print(f"[mi-loop {time.perf_counter() - start:6.1f}s] {message}", file=sys.stderr, flush=True)


def _render(V, F, args, creases, start):
    """Set the variant, render the limit surface; returns (sRGB image, shape)."""
    from mi_loop.render import scene as render
    from mi_loop.render.variant import set_variant

    _say("setting Mitsuba variant llvm_ad_rgb (first kernel compilation takes a few seconds)", start)
    set_variant("llvm_ad_rgb")
    _say(f"evaluating the limit surface at level {args.level} and rendering "
         f"{args.resolution}x{args.resolution} at {args.spp} spp", start)
    return render.render_limit_surface(V, F, level=args.level, creases=creases,
                                       resolution=args.resolution, spp=args.spp)


def _demo(args, start) -> None:
    from mi_loop.render import plugin
    from mi_loop.mesh.topology import validate_mesh

    out = io.ensure_writable_dir(args.output)
    V, F = datasets.control_mesh(args.shape)
    validate_mesh(V, F)
    _say(f"control mesh '{args.shape}': {len(V)} vertices, {len(F)} faces", start)
    written = [io.write_ply(out / "control.ply", V, F)]
    image, shape = _render(V, F, args, None, start)
    P, N, F_tess = plugin.mesh_arrays(shape)
    _say(f"limit surface: {len(P)} vertices, {len(F_tess)} triangles", start)
    written.append(io.write_ply(out / "limit.ply", P, F_tess, normals=N))
    written.append(io.write_png(out / "render.png", image))
    for path in written:
        print(path)


def _render_file(args, start) -> None:
    from mi_loop.render.plugin import parse_crease_text

    if args.output.suffix.lower() != ".png":
        raise ValueError(f"render: output must be a .png file, got '{args.output}'")
    io.ensure_writable_dir(args.output.parent)
    creases = parse_crease_text(args.creases)
    V, F = io.read_mesh(args.control)
    _say(f"control mesh '{args.control}': {len(V)} vertices, {len(F)} faces", start)
    image, _ = _render(V, F, args, creases, start)
    print(io.write_png(args.output, image))


def _fit(args, start) -> None:
    from mi_loop.app import fit_job

    if args.demo == (args.input is not None):
        raise ValueError("fit: give either an INPUT file or --demo")
    for path in fit_job.run(args, start, _say):
        print(path)


def _fit_sequence(args, start) -> None:
    from mi_loop.app import sequence_job

    if args.vertices is not None and args.template is None and args.vertices < 4:
        raise ValueError(f"fit-sequence: --vertices must be at least 4, got {args.vertices}")
    if args.template is not None and args.poisson_template:
        raise ValueError("fit-sequence: --poisson-template builds a template, so it cannot go with --template")
    for path in sequence_job.run(args, start, _say):
        print(path)


def _compare(args, start) -> None:
    import json

    from mi_loop.app import fit_job

    result = fit_job.compare(args.fitted, args.target, plain_mesh=args.mesh)
    text = json.dumps(result, indent=2)
    print(text)
    if args.json:
        io.ensure_writable_dir(args.json.parent)
        io.write_text(args.json, text + "\n")


def _control(args, start) -> None:
    io.ensure_writable_dir(args.output.parent)
    V, F = datasets.control_mesh(args.name)
    print(io.write_ply(args.output, V, F))


def main(argv=None) -> int:
    """Run ``mi-loop``; return the exit status.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        0 on success, 1 on bad input or a failed run, 2 on bad usage,
        130 on Ctrl-C.
    """
    args = _parser().parse_args(argv)
    start = time.perf_counter()
    commands = {"demo": _demo, "render": _render_file, "control": _control,
                "fit": _fit, "compare": _compare, "fit-sequence": _fit_sequence}
    try:
        commands[args.command](args, start)
    except (ValueError, TypeError, OSError, RuntimeError, ImportError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"mi-loop: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("mi-loop: error: interrupted", file=sys.stderr)
        return 130
    _say("done", start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
