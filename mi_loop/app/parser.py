"""The ``mi-loop`` argument parser: subcommands, flags, help; defaults read from the option classes.

The fitting defaults live in :mod:`mi_loop.fitting.options` only; the flags
below store into destinations named like the fields (``--vertices`` into
``n_vertices``), and :data:`FLAGS` maps a field back to its flag for error
messages. ``--quiet`` and ``--debug`` are accepted before or after the subcommand.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mi_loop import datasets
from mi_loop.app.cluster import LOCAL_WORKERS
from mi_loop.app.compare_job import CONTROL_VERTEX_LIMIT, DEFINITIONS, LEVEL
from mi_loop.app.export_job import FORMATS, LIMIT_LEVELS, VIEW_LEVELS
from mi_loop.fitting.options import SAMPLE_MODES, FitOptions, ImageFitOptions, SequenceOptions
from mi_loop.render.variant import DEFAULT_VARIANT

__all__ = ["FLAGS", "build_parser", "flag"]

#: Option field -> its flag, where the two names differ.
FLAGS = {"n_vertices": "--vertices", "iterations": "--iterations", "iterations": "--iterations",
         "resolution": "--res", "n_points": "--points",
         "geometric": "--image-only", "image": "--no-image"}

SAMPLES_HELP = ("limit samples of the distance terms: 'level1' (default) the points of a level-1 "
                "tessellation, about 4 per control vertex (closer fits); 'vertices' one per control vertex "
                "(its limit point: faster, the thesis's choice); 'random' four uniformly random points per "
                "control face, drawn once from --seed")
SEED_HELP = ("random seed: of the automatic template's sampling and of --samples random{} (default 0); "
             "the same seed, input and thread count give the same result")
QUIET_HELP = "no progress lines or bars on stderr (errors, warnings and the written paths still appear)"
DEBUG_HELP = "show the Python traceback behind an error (as does the environment MI_LOOP_TRACEBACK=1)"


def flag(name: str) -> str:
    """Return the command-line flag of an option field, for error messages.

    Parameters
    ----------
    name : str
        A field of :class:`~mi_loop.fitting.options.FitOptions` or
        :class:`~mi_loop.fitting.options.SequenceOptions`.

    Returns
    -------
    str
        Its flag: from :data:`FLAGS` where the names differ, else ``--`` and the
        name with dashes.

    Examples
    --------
    >>> flag("n_vertices"), flag("views_per_iteration")
    ('--vertices', '--views-per-iteration')
    """
    return FLAGS.get(name, "--" + name.replace("_", "-"))


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
    p.add_argument("--variant", default=DEFAULT_VARIANT,
                   help="Mitsuba variant, a JIT autodiff one: llvm_ad_* (CPU) or cuda_ad_* (GPU) "
                        "(default %(default)s)")


def positive(text: str) -> int:
    """argparse type: an integer > 0."""
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text}")
    return value


def level(text: str) -> int:
    """argparse type: a tessellation level in 0..6."""
    value = int(text)
    if not 0 <= value <= 6:
        raise argparse.ArgumentTypeError(f"expected a level in 0..6, got {text}")
    return value


def _view_level(p, kind: str) -> None:
    """``--view-level``: the tessellation of the GLB file and of the report's viewer (``kind``: fit or sequence)."""
    glb, limit = ("limit.glb", "limit.ply") if kind == "fit" else ("sequence.glb", "limit/NNNN.ply")
    p.add_argument("--view-level", type=level, metavar="L", default=VIEW_LEVELS[kind],
                   help=f"tessellation level of {glb} and of the report's viewer, 4**L triangles per control "
                        f"face (default %(default)s; {limit} has level {LIMIT_LEVELS[kind]})")


def _render_options(p) -> None:
    p.add_argument("--level", type=level, default=3, help="4**level triangles per control face (default 3)")
    p.add_argument("--resolution", type=positive, default=256, help="image width and height (default 256)")
    p.add_argument("--spp", type=positive, default=64, help="samples per pixel (default 64)")
    _variant(p)


def _template_options(p, options) -> None:
    group = p.add_mutually_exclusive_group()
    group.add_argument("--vertices", dest="n_vertices", type=int, metavar="N", default=options.n_vertices,
                       help="control vertices of the automatic template (default %(default)s)")
    group.add_argument("--template", type=Path, metavar="PATH",
                       help="control mesh to start from instead, in the data's units and position")


def _fit_parser(sub, common) -> None:
    p = sub.add_parser("fit", parents=[common], help="fit a Loop control mesh to a point cloud or mesh")
    p.add_argument("input", type=Path, nargs="?",
                   help="points (PLY/XYZ/PTS/NPZ; normals estimated when missing) or mesh (PLY/OBJ/OFF); "
                        "omit with --demo")
    p.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    _fit_options(p)
    p.add_argument("--demo", action="store_true", help="fit the built-in noisy torus point cloud (no input file)")
    _view_level(p, "fit")
    _variant(p)


def _fit_options(p) -> None:
    """The options of :class:`FitOptions` and ``--template`` (``fit`` and ``fit-batch``)."""
    o = FitOptions
    _template_options(p, o)
    p.add_argument("--alpha", type=float, default=o.alpha,
                   help="ARAP weight (default: 0.001 on clean data; on noisy data the best of 0.001, 0.01, "
                        "0.1, 1 on a tenth of the points held out of the fit)")
    p.add_argument("--h0", type=float, default=o.h0,
                   help="IMLS radius in the unit box (default: from the point spacing)")
    p.add_argument("--cover", type=float, default=o.cover,
                   help="coverage weight: data points pull their nearest limit samples (default %(default)s; "
                        "0: off)")
    p.add_argument("--samples", choices=SAMPLE_MODES, default=o.samples, help=SAMPLES_HELP)
    p.add_argument("--iterations", dest="iterations", type=int, metavar="N", default=o.iterations,
                   help="iteration cap; the fit usually converges earlier (default %(default)s)")
    p.add_argument("--tolerance", type=float, default=o.tolerance,
                   help="relative improvement below which the fit has converged (default %(default)s)")
    p.add_argument("--seed", type=int, default=o.seed, help=SEED_HELP.format(""))
    p.add_argument("--fold", type=float, default=o.fold,
                   help="weight of the barrier on limit normals turned by more than 60 degrees from the nearest "
                        "data normals (default %(default)s; 0: off)")
    p.add_argument("--features", choices=["auto", "off"], default=o.features,
                   help="for a mesh input, keep its sharp features (edges above 40 degrees) as creases of the "
                        "control mesh (default %(default)s; point clouds have none here)")


def _sequence_parser(sub, common) -> None:
    p = sub.add_parser("fit-sequence", parents=[common], help="fit one control mesh to every frame of a sequence")
    p.add_argument("frames", type=Path, nargs="+",
                   help="an NPZ (vertices (T,V,3), faces), or frame files / directories / quoted globs: "
                        "meshes, or point clouds with or without normals (PLY/XYZ/NPZ); or one animated "
                        "glTF/GLB with --animation")
    p.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    p.add_argument("--images", nargs="+", metavar="CAPTURE",
                   help="one transforms.json per frame (files, directories, or quoted globs; sorted): "
                        "the frame's calibrated photos with masks, fitted together with the geometry")
    p.add_argument("--emitters", type=Path, metavar="F",
                   help="the photos' lighting as a Mitsuba XML file of emitters (default: a constant "
                        "environment of radiance 1)")
    p.add_argument("--reference", type=Path, metavar="NPZ",
                   help="clean meshes in correspondence (vertices (T,V,3), faces), one per frame: "
                        "metrics.csv then measures distances, folds and drift against them")
    _frames_option(p, "; applies to the captures and the reference too")
    p.add_argument("--animation", metavar="NAME",
                   help="bake this animation of a skinned glTF/GLB into the frames")
    p.add_argument("--fps", type=float, default=24.0,
                   help="frame rate of sequence.glb and of the baked --animation (default %(default)s)")
    _sequence_options(p)
    p.add_argument("--resume", action="store_true",
                   help="continue after the last finished frame, bit for bit as an uninterrupted run "
                        "(with the options stored in OUTDIR/sequence.json)")
    _view_level(p, "sequence")
    _variant(p)


def _frames_option(p, note: str = "") -> None:
    p.add_argument("--frames", dest="frame_range", type=_frame_range, metavar="START:STOP:STEP",
                   help=f"fit only these frames (Python slice syntax{note})")


def _sequence_options(p) -> None:
    """The options of :class:`SequenceOptions` and ``--template`` (``fit-sequence`` and ``fit-batch --sequences``)."""
    o = SequenceOptions
    _template_options(p, o)
    p.add_argument("--poisson-template", action="store_true",
                   help="build the automatic template by screened Poisson even when the first frame is a mesh")
    p.add_argument("--views", type=int, default=o.views,
                   help="cameras around the subject for mesh frames without --images (default %(default)s)")
    p.add_argument("--views-per-iteration", type=int, metavar="K",
                   help=f"views rendered per image refresh, at most --views (default {o.views_per_iteration}, "
                        "or --views if fewer)")
    p.add_argument("--image-every", type=int, metavar="N", default=o.image_every,
                   help="iterations between image refreshes; the latest image gradient is added to every "
                        "step (default %(default)s)")
    p.add_argument("--res", dest="resolution", type=int, metavar="R", default=o.resolution,
                   help="image size of the rendered rig (default %(default)s; photos keep theirs)")
    p.add_argument("--spp", type=int, default=o.spp, help="samples per pixel of the renders (default %(default)s)")
    p.add_argument("--level", type=int, default=o.level,
                   help="tessellation level of the rendered limit surface (default %(default)s)")
    p.add_argument("--beta", type=float, default=o.beta,
                   help="image weight relative to the geometric gradient (default %(default)s)")
    p.add_argument("--seen", type=float, default=o.seen,
                   help="image weight where the data covers the surface, relative to where it does not "
                        "(default %(default)s)")
    p.add_argument("--lam", "--image-smooth", type=float, default=o.lam,
                   help="lambda of the (I + lambda L)^-1 smoothing of the image gradient (default %(default)s; "
                        "0: off)")
    p.add_argument("--alpha", type=float, default=o.alpha,
                   help="ARAP weight relative to the previous frame (default %(default)s)")
    p.add_argument("--alpha-rest", type=float, default=o.alpha_rest,
                   help="ARAP weight relative to the template: against folds (default %(default)s; 0: off)")
    p.add_argument("--fold", type=float, default=o.fold,
                   help="weight of the barrier on limit normals that turned by more than 60 degrees since the "
                        "previous frame (default %(default)s; 0: off)")
    p.add_argument("--reach", type=int, default=o.reach,
                   help="IMLS reaches h0 * 2^REACH from a sample; farther ones are not pulled "
                        "(default %(default)s)")
    p.add_argument("--samples", choices=SAMPLE_MODES, default=o.samples, help=SAMPLES_HELP)
    p.add_argument("--cover", type=float, default=o.cover,
                   help="coverage weight: data points pull their nearest samples (default %(default)s; 0: off)")
    p.add_argument("--loss", choices=["l1", "l2"], default=o.loss,
                   help="pixel loss of the rendered rig: mean absolute (l1, default) or mean squared (l2) "
                        "difference between the render and the target render")
    p.add_argument("--mode", choices=["shading", "silhouette"], default=o.mode,
                   help="shaded images (default) or silhouettes only, for the rendered rig")
    p.add_argument("--iterations", dest="iterations", type=int, metavar="N", default=o.iterations,
                   help="iterations per frame (default %(default)s)")
    p.add_argument("--first-iterations", type=int, metavar="N", default=o.first_iterations,
                   help="iterations of the first frame, from the template (default %(default)s)")
    p.add_argument("--albedo-lr", type=float, default=o.albedo_lr,
                   help="albedo step on the first frame (photos; default %(default)s)")
    p.add_argument("--albedo-refine", type=float, default=o.albedo_refine,
                   help="albedo step of later frames relative to --albedo-lr (default %(default)s; 0: kept)")
    p.add_argument("--points", dest="n_points", type=int, metavar="N", default=o.n_points,
                   help="points sampled on every mesh frame for the geometric terms (default %(default)s); "
                        "point-cloud frames are used as they are")
    exclusive = p.add_mutually_exclusive_group()
    exclusive.add_argument("--no-image", action="store_true", help="geometric terms only (baseline)")
    exclusive.add_argument("--image-only", action="store_true", help="image term (+ ARAP) only (baseline)")
    p.add_argument("--deterministic", action="store_true",
                   help="bit-reproducible image term: the reverse render runs on one thread (slower)")
    p.add_argument("--seed", type=int, default=o.seed, help=SEED_HELP.format(", of the views and of the "
                                                                                "frames' samples"))


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
        p.add_argument("-o", "--output", required=True, type=Path,
                       help="output directory: OUTDIR/<input name>/ per input, OUTDIR/summary.csv, "
                            "OUTDIR/report.html")
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
            _sequence_options(p)
        else:
            _fit_options(p)
        _view_level(p, "sequence" if sequences else "fit")
        _variant(p)
        return p

    kwargs = {"parents": [common], "description": BATCH_DESCRIPTION}
    sequences = batch(_Parser(prog="mi-loop fit-batch", **kwargs), True)
    batch(sub.add_parser("fit-batch", help="fit many inputs on a Dask cluster, one output directory each",
                         switch=("--sequences", sequences), **kwargs), False)


def _frame_range(text: str):
    from mi_loop.io.frames import frame_range

    try:
        return frame_range(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).split(": ", 1)[-1]) from None


def _images_parser(sub, common) -> None:
    from mi_loop.render.photo import INTEGRATORS

    o = ImageFitOptions
    p = sub.add_parser("fit-images", parents=[common],
                       help="fit a Loop surface and its albedo to calibrated photos (transforms.json)",
                       description="Shape and per-control-vertex albedo from photos with known cameras "
                                   "(NeRF/Blender transforms.json) through Mitsuba's differentiable "
                                   "renderer: silhouettes (the masks: alpha or mask_path) and shading, "
                                   "coarse to fine by exact Loop refinement.")
    p.add_argument("capture", type=Path, help="transforms.json of the photos")
    p.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    p.add_argument("--vertices", dest="n_vertices", type=int, metavar="N", default=o.n_vertices,
                   help="most control vertices after the refinements (default %(default)s)")
    p.add_argument("--init", default=o.init, metavar="hull|sphere|MESH",
                   help="start shape: a template of the visual hull of the masks (hull, default), an "
                        "icosphere in the hull's box (sphere), or a control mesh file")
    p.add_argument("--refinements", type=int, default=o.refinements,
                   help="exact Loop refinements of the control mesh, coarse to fine (default %(default)s)")
    p.add_argument("--res", dest="resolution", type=int, metavar="R", default=o.resolution,
                   help="longest image side at the finest stage (default: the photos' own; coarser "
                        "stages halve it)")
    p.add_argument("--spp", type=int, default=o.spp, help="samples per pixel of the renders (default %(default)s)")
    p.add_argument("--iterations", type=int, metavar="N", default=o.iterations,
                   help="most iterations, all stages together (default %(default)s)")
    p.add_argument("--views-per-iteration", type=int, metavar="K", default=o.views_per_iteration,
                   help="photos rendered per iteration (default %(default)s)")
    p.add_argument("--emitters", type=Path, metavar="F",
                   help="Mitsuba XML file holding only the capture's emitters (default: a uniform white "
                        "environment of radiance 1)")
    p.add_argument("--lr", type=float, default=o.lr,
                   help="step size relative to the visual hull's box diagonal (default %(default)s)")
    p.add_argument("--lam", type=float, default=o.lam,
                   help="lambda of the (I + lambda L) smooth parameterisation (default %(default)s; 0: plain)")
    p.add_argument("--laplacian", "--smooth", type=float, default=o.laplacian,
                   help="weight of the cage's Laplacian term (default %(default)s; 0: off)")
    p.add_argument("--albedo", type=float, default=o.albedo, help="start albedo, grey (default %(default)s)")
    p.add_argument("--fixed-albedo", dest="albedo_lr", action="store_const", const=0.0, default=o.albedo_lr,
                   help="keep the albedo at --albedo instead of estimating it")
    p.add_argument("--integrator", choices=INTEGRATORS, default=o.integrator,
                   help="differentiable integrator (default %(default)s)")
    p.add_argument("--deterministic", action="store_true",
                   help="bit-reproducible runs: the reverse renders run on one thread (slower)")
    p.add_argument("--seed", type=int, default=o.seed,
                   help="random seed of the view order and the renders (default 0)")
    _view_level(p, "fit")
    _variant(p)


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
    p.add_argument("-o", "--output", type=Path, metavar="PATH",
                   help="the file to write (its suffix the format's), or for a sequence's obj / ply frames a "
                        "directory (default: in OUT/export/)")
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
    demo.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    demo.add_argument("--shape", choices=sorted(datasets.CONTROL_MESHES), default="blob")
    _render_options(demo)

    render = sub.add_parser("render", parents=[common], help="render the limit surface of a control mesh file")
    render.add_argument("control", type=Path, help="control mesh (PLY, OBJ or OFF)")
    render.add_argument("-o", "--output", required=True, type=Path, help="PNG file to write")
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
    control.add_argument("-o", "--output", required=True, type=Path, help="PLY file to write")
    return parser
