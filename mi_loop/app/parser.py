"""The ``mi-loop`` argument parser: subcommands, flags, help.

Every flag of an option field (of :class:`~mi_loop.fitting.options.FitOptions`,
:class:`~mi_loop.fitting.options.SequenceOptions`,
:class:`~mi_loop.fitting.options.ImageFitOptions`) is generated from the field's
declaration in :mod:`mi_loop.fitting.options` by :func:`add_options`: the flag,
its destination (the field's name), type, default, choices, metavar, help, its
deprecated spellings and special forms. Only what is not an option field is
written here (inputs, ``-o``, ``--template``, ``--images``, ``--frames`` ...).
:data:`FLAGS` and :func:`flag` map a field to its flag. ``--quiet`` and ``--debug``
are accepted before or after the subcommand.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from pathlib import Path

from mi_loop import datasets
from mi_loop.app.cluster import LOCAL_WORKERS
from mi_loop.app.compare_job import CONTROL_VERTEX_LIMIT, DEFINITIONS, LEVEL
from mi_loop.app.export_job import FORMATS, LIMIT_LEVELS, VIEW_LEVELS
from mi_loop.fitting.declarations import declared, option_flag
from mi_loop.fitting.options import FitOptions, ImageFitOptions, SequenceOptions
from mi_loop.render.variant import DEFAULT_VARIANT, VARIANT_ENV, default_variant

__all__ = ["FLAGS", "add_options", "build_parser", "flag"]

#: Option field -> its flag, from the fields' declarations (one flag per name in every command).
FLAGS = {f.name: option_flag(f) for cls in (FitOptions, SequenceOptions, ImageFitOptions) for f in fields(cls)}

QUIET_HELP = "no progress lines or bars on stderr (errors, warnings and the written paths still appear)"
DEBUG_HELP = "show the Python traceback behind an error (as does the environment MI_LOOP_TRACEBACK=1)"


def flag(name: str) -> str:
    """Return the command-line flag of an option field (:data:`FLAGS`); a name that is no field as it is.

    Parameters
    ----------
    name : str
        A field of an option class (:mod:`mi_loop.fitting.options`).

    Returns
    -------
    str

    Examples
    --------
    >>> flag("n_vertices"), flag("views_per_iteration"), flag("image")
    ('--vertices', '--views-per-iteration', '--no-image')
    """
    return FLAGS.get(name, name)


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line on stderr.

    ``switch=(flag, other)``: when ``flag`` (or an abbreviation of it) is among
    the arguments, the parser ``other`` parses them instead (``fit-batch
    --sequences`` takes fit-sequence's options, which clash with fit's).
    """

    def __init__(self, *args, switch=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.switch = switch

    def parse_known_args(self, args=None, namespace=None):
        if self.switch is not None:
            flag, other = self.switch
            given = sys.argv[1:] if args is None else args
            if any(a.startswith("--") and len(a) > 4 and flag.startswith(a) for a in given):
                return other.parse_known_args(args, namespace)
        return super().parse_known_args(args, namespace)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n")


class _Version(argparse.Action):
    """``--version``: mi_loop's version and the installed Mitsuba and Dr.Jit, without importing them."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from importlib import metadata

        import mi_loop

        def version(name):
            try:
                return metadata.version(name)
            except metadata.PackageNotFoundError:
                return "not installed"

        print(f"mi-loop {mi_loop.__version__} (mitsuba {version('mitsuba')}, drjit {version('drjit')})")
        parser.exit(0)


def _common(top: bool) -> argparse.ArgumentParser:
    """``--quiet`` and ``--debug``; after the subcommand they must not reset a value given before it."""
    p = argparse.ArgumentParser(add_help=False)
    extra = {} if top else {"default": argparse.SUPPRESS}
    p.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP, **extra)
    p.add_argument("--debug", action="store_true", help=DEBUG_HELP, **extra)
    return p


def _variant(p) -> None:
    p.add_argument("--variant", default=default_variant(),
                   help="Mitsuba variant, a JIT autodiff one: llvm_ad_* (CPU) or cuda_ad_* (GPU) "
                        f"(default %(default)s: ${VARIANT_ENV} if set, else {DEFAULT_VARIANT})")


def _integer(name: str, low: int, high: float, what: str):
    """An argparse type called ``name`` (argparse's "invalid NAME value" says it): an integer in ``low..high``."""
    def parse(text: str) -> int:
        value = int(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text}")
        return value
    parse.__name__ = name
    return parse


positive = _integer("positive", 1, float("inf"), "a positive integer")
level = _integer("level", 0, 6, "a level in 0..6")


def _output(p, text: str = "output directory", **kwargs) -> None:
    p.add_argument("-o", "--output", type=Path, help=text, **{"required": True, **kwargs})


def _view_level(p, kind: str) -> None:
    """``--view-level``: the tessellation of the GLB file and of the report's viewer (``kind``: fit or sequence)."""
    glb, limit = ("limit.glb", "limit.ply") if kind == "fit" else ("sequence.glb", "limit/NNNN.ply")
    p.add_argument("--view-level", type=level, metavar="L", default=VIEW_LEVELS[kind],
                   help=f"tessellation level of {glb} and of the report's viewer, 4**L triangles per control "
                        f"face (default %(default)s; {limit} has level {LIMIT_LEVELS[kind]})")


def _render_options(p) -> None:
    p.add_argument("--level", type=level, metavar="L", default=3,
                   help="tessellation level of the rendered limit surface, 4**L triangles per control face "
                        "(default %(default)s)")
    p.add_argument("--resolution", type=positive, metavar="R", default=256,
                   help="image width and height, in pixels (default %(default)s)")
    p.add_argument("--spp", type=positive, default=64, help="samples per pixel (default %(default)s)")
    _variant(p)


class _Deprecated(argparse.Action):
    """An old spelling of a flag (hidden from the help): stores as the flag does and warns on stderr."""

    def __init__(self, option_strings, dest, use: str, **kwargs):
        super().__init__(option_strings, dest, **kwargs)
        self.use = use

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"mi-loop: warning: {option_string} is deprecated; use {self.use}", file=sys.stderr, flush=True)
        setattr(namespace, self.dest, values)


def _arguments(f, declaration) -> dict:
    """``add_argument`` keywords of an option field, from its declaration."""
    rule, text = declaration.rule, declaration.help
    if declaration.deprecated:
        text += f" (deprecated spelling: {', '.join(declaration.deprecated)})"
    if rule.parse is None:                             # a switch: the flag stores the opposite of the default
        return {"dest": f.name, "action": "store_const", "const": not f.default, "default": f.default, "help": text}
    kwargs = {"dest": f.name, "type": rule.parse, "default": f.default, "metavar": declaration.metavar, "help": text}
    if rule.choices and not declaration.paths:
        kwargs["choices"] = rule.choices
    if declaration.capped_by:                          # the cli caps the default by the other flag's value
        kwargs.update(default=None, help=text % {"default": f.default})
    return kwargs


def add_options(p, cls, extras: dict | None = None) -> None:
    """Add the flag of every field of the option class ``cls``, as its declaration says.

    Parameters
    ----------
    p : argparse.ArgumentParser
        The command's parser.
    cls : type
        :class:`~mi_loop.fitting.options.FitOptions`, :class:`~mi_loop.fitting.options.SequenceOptions`
        or :class:`~mi_loop.fitting.options.ImageFitOptions`.
    extras : dict, optional
        Name of an exclusive group -> ``add(group)``, which adds the group's
        hand-written flags (``'template'``: ``--template``) after its first field.
    """
    groups = {}
    for f, declaration in declared(cls):
        key = declaration.exclusive or (f.name if declaration.presets else None)
        new = key is not None and key not in groups
        if new:
            groups[key] = p.add_mutually_exclusive_group()
        where = p if key is None else groups[key]
        where.add_argument(option_flag(f), **_arguments(f, declaration))
        for name, value, text in declaration.presets:
            where.add_argument(name, dest=f.name, action="store_const", const=value, default=argparse.SUPPRESS,
                               help=text)
        for old in declaration.deprecated:
            p.add_argument(old, dest=f.name, type=declaration.rule.parse, action=_Deprecated, use=option_flag(f),
                           default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        if new and key in (extras or {}):
            extras[key](groups[key])


def _template(group) -> None:
    group.add_argument("--template", type=Path, metavar="PATH",
                       help="control mesh to start from instead, in the data's units and position")


def _emitters(p) -> None:
    p.add_argument("--emitters", type=Path, metavar="F",
                   help="the photos' lighting: a Mitsuba XML file holding only emitters, in the photos' world frame "
                        "(default: a constant environment of radiance 1)")


def _frames_option(p, note: str = "") -> None:
    p.add_argument("--frames", dest="frame_range", type=_frame_range, metavar="START:STOP:STEP",
                   help=f"fit only these frames (Python slice syntax{note})")


def _fit_parser(sub, common) -> None:
    p = sub.add_parser("fit", parents=[common], help="fit a Loop control mesh to a point cloud or mesh")
    p.add_argument("input", type=Path, nargs="?",
                   help="points (PLY/XYZ/PTS/NPZ; normals estimated when missing) or mesh (PLY/OBJ/OFF); "
                        "omit with --demo")
    _output(p)
    add_options(p, FitOptions, {"template": _template})
    p.add_argument("--demo", action="store_true", help="fit the built-in noisy torus point cloud (no input file)")
    _view_level(p, "fit")
    _variant(p)


def _sequence_parser(sub, common) -> None:
    p = sub.add_parser("fit-sequence", parents=[common], help="fit one control mesh to every frame of a sequence")
    p.add_argument("frames", type=Path, nargs="+",
                   help="an NPZ (vertices (T,V,3), faces), or frame files / directories / quoted globs: "
                        "meshes, or point clouds with or without normals (PLY/XYZ/NPZ); or one animated "
                        "glTF/GLB with --animation")
    _output(p)
    p.add_argument("--images", nargs="+", metavar="CAPTURE",
                   help="one transforms.json per frame (files, directories, or quoted globs; sorted): "
                        "the frame's calibrated photos with masks, fitted together with the geometry")
    _emitters(p)
    p.add_argument("--reference", type=Path, metavar="NPZ",
                   help="clean meshes (vertices (T,V,3), faces) or points (points (T,N,3)) in correspondence, "
                        "one per frame: metrics.csv then measures distances, folds and drift against them")
    _frames_option(p, "; applies to the captures and the reference too")
    p.add_argument("--animation", metavar="NAME",
                   help="bake this animation of a skinned glTF/GLB into the frames")
    p.add_argument("--fps", type=float, default=24.0,
                   help="frame rate of sequence.glb and of the baked --animation (default %(default)s)")
    add_options(p, SequenceOptions, {"template": _template})
    p.add_argument("--resume", action="store_true",
                   help="continue after the last finished frame, bit for bit as an uninterrupted run "
                        "(with the options stored in OUTDIR/sequence.json)")
    _view_level(p, "sequence")
    _variant(p)


BATCH_DESCRIPTION = ("Fit every INPUT like `mi-loop fit INPUT -o OUTDIR/<name>/` (with --sequences: like "
                     "fit-sequence) on a Dask cluster; OUTDIR/summary.csv lists each input's status, time, worker, "
                     "error and metrics, OUTDIR/report.html the same with a link to each input's report. A "
                     "complete OUTDIR/<name>/ is skipped when the batch runs again (remove it "
                     "to refit), a failed input is fitted again. Not taken with --sequences (they belong to one "
                     "sequence or run): --images, --emitters, --reference, --animation, --fps, --resume.")


def _batch_parser(sub, common) -> None:
    """``fit-batch`` with fit's options, switching to fit-sequence's when ``--sequences`` is given."""
    def batch(p, sequences: bool):
        p.add_argument("inputs", type=Path, nargs="+", metavar="INPUT",
                       help="sequences (directories of frames or NPZ files) or quoted globs of them"
                       if sequences else "point-cloud or mesh files (as for fit) or quoted globs of them")
        _output(p, "output directory: OUTDIR/<input name>/ per input, OUTDIR/summary.csv, OUTDIR/report.html")
        where = p.add_mutually_exclusive_group()
        where.add_argument("--scheduler", metavar="ADDRESS",
                           help="run on a running Dask cluster: its scheduler's address (tcp://host:port) or "
                                "the JSON file of `dask scheduler --scheduler-file` (default: a local cluster)")
        where.add_argument("--workers", type=positive, metavar="N",
                           help=f"worker processes of the local cluster, one thread each (default {LOCAL_WORKERS})")
        p.add_argument("--sequences", action="store_true",
                       help="each input is a sequence, fitted like fit-sequence; the options are then "
                            "fit-sequence's (see fit-batch --sequences --help)")
        if sequences:
            _frames_option(p, "; of every sequence")
        add_options(p, SequenceOptions if sequences else FitOptions, {"template": _template})
        _view_level(p, "sequence" if sequences else "fit")
        _variant(p)
        return p

    kwargs = {"parents": [common], "description": BATCH_DESCRIPTION}
    sequences = batch(_Parser(prog="mi-loop fit-batch", **kwargs), True)
    batch(sub.add_parser("fit-batch", help="fit many inputs on a Dask cluster, one output directory each",
                         switch=("--sequences", sequences), **kwargs), False)


def _images_parser(sub, common) -> None:
    p = sub.add_parser("fit-images", parents=[common],
                       help="fit a Loop surface and its albedo to calibrated photos (transforms.json)",
                       description="Shape and per-control-vertex albedo from photos with known cameras "
                                   "(NeRF/Blender transforms.json) through Mitsuba's differentiable "
                                   "renderer: silhouettes (the masks: alpha or mask_path) and shading, "
                                   "coarse to fine by exact Loop refinement.")
    p.add_argument("capture", type=Path, help="the photos and their cameras: a transforms.json, or a directory of an "
                   "IDR / NeuS (cameras_sphere.npz), LLFF (poses_bounds.npy) or COLMAP (sparse/0) capture")
    _output(p)
    _emitters(p)
    add_options(p, ImageFitOptions)
    _view_level(p, "fit")
    _variant(p)


def _frame_range(text: str):
    from mi_loop.io.frames import frame_range

    try:
        return frame_range(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).split(": ", 1)[-1]) from None


def _compare_epilog() -> str:
    lines = [(f"FITTED with more than {CONTROL_VERTEX_LIMIT:,} vertices is measured as a plain mesh unless "
              f"--control is given; otherwise as a control mesh (its limit surface at level {LEVEL})."), ""]
    for group, entries in DEFINITIONS.items():
        lines.append(f"{group}:")
        lines += [f"  {key}: {text}" for key, text in entries.items()]
    return "\n".join(lines)


def _compare_parser(sub, common) -> None:
    p = sub.add_parser("compare", parents=[common], help="distances between a fitted surface and a target",
                       epilog=_compare_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Two-sided distances (and, for a target mesh, the Neural Parametric "
                                   "Surfaces metrics P2S, HD, NAE) between FITTED and TARGET, as JSON.")
    p.add_argument("fitted", type=Path, help="control mesh (its limit surface is measured) or a plain mesh")
    p.add_argument("target", type=Path, help="target points or mesh")
    how = p.add_mutually_exclusive_group()
    how.add_argument("--mesh", action="store_true", help="measure FITTED as a plain triangle mesh")
    how.add_argument("--control", action="store_true",
                     help="measure FITTED's limit surface, however many vertices it has")
    p.add_argument("--json", type=Path, help="also write the numbers to this JSON file")


def _export_parser(sub, common) -> None:
    p = sub.add_parser("export", parents=[common], help="write a result's limit surface as GLB, OBJ or PLY",
                       description="The limit surface of a result directory (of fit, fit-images or fit-sequence) "
                                   "at a tessellation level: glb (a sequence as one mesh animated by morph "
                                   "targets), obj, ply (a sequence: one file per frame, in a directory). Without "
                                   "-o the files go to OUT/export/; the result's own files are never replaced.")
    p.add_argument("result", type=Path, metavar="OUT", help="the output directory of fit, fit-images or fit-sequence")
    p.add_argument("--format", dest="fmt", choices=FORMATS, default="glb", help="file format (default %(default)s)")
    p.add_argument("--level", type=level, metavar="L",
                   help=f"tessellation level, 4**L triangles per control face (default: glb {VIEW_LEVELS['fit']} "
                        f"for fits and {VIEW_LEVELS['sequence']} for sequences, as limit.glb and sequence.glb; "
                        f"obj and ply {LIMIT_LEVELS['fit']} and {LIMIT_LEVELS['sequence']}, as limit.ply and "
                        "limit/NNNN.ply)")
    _output(p, "the file to write (its suffix the format's), or for a sequence's obj / ply frames a directory "
               "(default: in OUT/export/)", required=False, metavar="PATH")
    p.add_argument("--fps", type=float,
                   help="frame rate of a sequence's glb (default: the run's, from sequence.json, else 24)")


def build_parser() -> argparse.ArgumentParser:
    """The ``mi-loop`` parser with all subcommands."""
    parser = _Parser(prog="mi-loop", parents=[_common(top=True)],
                     description="Exact Loop subdivision limit surfaces in Mitsuba 3.")
    parser.add_argument("--version", action=_Version, help="print the versions of mi_loop, Mitsuba, Dr.Jit")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    common = _common(top=False)

    demo = sub.add_parser("demo", parents=[common], help="render the limit surface of a procedural control mesh")
    _output(demo)
    demo.add_argument("--shape", choices=sorted(datasets.CONTROL_MESHES), default="blob")
    _render_options(demo)

    render = sub.add_parser("render", parents=[common], help="render the limit surface of a control mesh file")
    render.add_argument("control", type=Path, help="control mesh (PLY, OBJ or OFF)")
    _output(render, "PNG file to write")
    render.add_argument("--creases", default="",
                        help="sharp edges as vertex pairs, optional sharpness (default inf), e.g. '0 1, 1 2 2.5'; "
                             "default: the creases of a PLY control mesh (its edge element)")
    render.add_argument("--corners", default="",
                        help="sharp vertices with an optional sharpness (default inf), e.g. '4, 7 1.5'")
    render.add_argument("--boundary", choices=["edge_and_corner", "edge_only", "none"], default="edge_and_corner",
                        help="boundary interpolation, as OpenSubdiv's (default: edge_and_corner)")
    render.add_argument("--crease-method", choices=["uniform", "chaikin"], default="uniform",
                        help="how semi-sharp creases decay, as OpenSubdiv's (default: uniform)")
    _render_options(render)

    _fit_parser(sub, common)
    _sequence_parser(sub, common)
    _batch_parser(sub, common)
    _images_parser(sub, common)
    _compare_parser(sub, common)
    _export_parser(sub, common)

    control = sub.add_parser("control", parents=[common], help="write a procedural control mesh")
    control.add_argument("name", choices=sorted(datasets.CONTROL_MESHES))
    _output(control, "PLY file to write")
    return parser
