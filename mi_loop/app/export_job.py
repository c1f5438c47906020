"""The ``mi-loop export`` job, and the viewer tessellations that ``limit.glb`` and ``sequence.glb`` hold.

A result directory is what ``mi-loop fit`` or ``fit-images`` wrote
(``control.ply``, with its creases or its albedo) or what ``fit-sequence``
wrote (``sequence.json``, ``metrics.csv`` and ``control/NNNN.ply`` of every
finished frame, a row of ``metrics.csv`` each). :func:`read_result` finds
which and refuses anything else; :func:`static_view` and
:func:`sequence_view` evaluate the limit surface of its control meshes at a
tessellation level, which the jobs themselves use for their GLB files, so an
export at the same level gives the same file bit for bit.

- glb: one mesh with exact unit limit normals (``COLOR_0``: the linear albedo
  of fit-images), or, for a sequence, one mesh in correspondence animated by
  morph targets (:func:`~mi_loop.io.glb.write_glb_sequence`);
- obj: positions and normals; ply: positions, normals and colours
  (:func:`~mi_loop.io.meshes.write_ply`). A sequence gives one file per frame,
  ``NNNN.obj`` or ``NNNN.ply``, in a directory.

Without ``-o`` the files go to ``OUT/export/`` (``limit.glb``, ``limit.obj``,
``limit.ply``; ``sequence.glb``, ``NNNN.obj``, ``NNNN.ply``): an export never
replaces the result's own files.
"""
from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.errors import fail

__all__ = ["FORMATS", "LIMIT_LEVELS", "VIEW_LEVELS", "Result", "read_result", "run", "sequence_view", "static_view",
           "write_view"]

#: The formats ``mi-loop export`` writes.
FORMATS = ("glb", "obj", "ply")
#: Tessellation level of the viewer (``limit.glb``, ``sequence.glb``, the report), by result kind.
VIEW_LEVELS = {"fit": 2, "sequence": 1}
#: Level of the jobs' ``limit.ply`` and ``limit/NNNN.ply``: the default of an obj or ply export.
LIMIT_LEVELS = {"fit": 3, "sequence": 2}

_OUT = "export OUT"
_WANT = ("a result directory of mi-loop fit or fit-images (control.ply) or of fit-sequence (sequence.json, "
         "metrics.csv, control/NNNN.ply)")


@dataclass(frozen=True)
class Result:
    """A result directory as :func:`read_result` found it.

    Attributes
    ----------
    path : pathlib.Path
        The directory.
    kind : {'fit', 'sequence'}
        ``fit`` (also fit-images) or ``sequence`` (fit-sequence).
    controls : list of pathlib.Path
        ``control.ply``, or ``control/NNNN.ply`` of every finished frame in order.
    names : list of str
        The frames' names (``metrics.csv``'s ``name``), or the directory's name for a fit.
    fps : float or None
        The sequence's frame rate from ``sequence.json`` (None for a fit, or a run older than it).
    """

    path: Path
    kind: str
    controls: list
    names: list
    fps: float | None = None


def read_result(path) -> Result:
    """Recognise a result directory of ``fit``, ``fit-images`` or ``fit-sequence``; read nothing heavy.

    Parameters
    ----------
    path : str or os.PathLike
        OUT of one of those jobs (for ``fit-batch``: one ``OUTDIR/<name>``).

    Returns
    -------
    Result

    Raises
    ------
    ValueError
        A missing path, a file, a directory with neither ``control.ply`` nor
        ``sequence.json`` (a ``fit-batch`` OUTDIR is named as such), a
        sequence without ``metrics.csv`` or without a finished frame, a
        frame's control mesh missing.
    """
    path = Path(path)
    if not path.exists():
        fail(_OUT, _WANT, f"'{path}': no such directory")
    if not path.is_dir():
        fail(_OUT, _WANT, f"'{path}': a file")
    if not (path / "sequence.json").is_file():
        if (path / "control.ply").is_file():
            return Result(path, "fit", [path / "control.ply"], [path.absolute().name])
        batch = " (a fit-batch OUTDIR: export each OUTDIR/<name>)" if (path / "summary.csv").is_file() else ""
        fail(_OUT, _WANT, f"'{path}' without control.ply or sequence.json{batch}")
    if not (path / "metrics.csv").is_file():
        fail(_OUT, "a fit-sequence directory with its metrics.csv (the finished frames)",
             f"no '{path / 'metrics.csv'}'")
    with open(path / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or "frame" not in rows[0]:
        fail(_OUT, "a fit-sequence directory with at least one finished frame (a row of metrics.csv)",
             f"none in '{path / 'metrics.csv'}'")
    controls = [path / "control" / f"{int(r['frame']):04d}.ply" for r in rows]
    missing = [p for p in controls if not p.is_file()]
    if missing:
        fail(_OUT, "the control mesh of every finished frame", f"no '{missing[0]}'")
    fps = json.loads((path / "sequence.json").read_text()).get("fps")
    return Result(path, "sequence", controls, [r.get("name") or f"frame {r['frame']}" for r in rows],
                  None if fps is None else float(fps))


def static_view(V, F, level: int, creases=None, albedo=None):
    """The limit surface of one control mesh at ``level``, with limit normals and the albedo carried to it.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Control points.
    F : (m, 3) int NumPy array
        Control faces.
    level : int
        Tessellation level (``4**level`` triangles per control face).
    creases : optional
        The control mesh's creases, as :func:`mi_loop.io.read_creases` returns them.
    albedo : (n, 3) float NumPy array, optional
        Linear RGB per control vertex.

    Returns
    -------
    tuple ``(P, F_t, N, C)``
        ``(k, 3)`` limit points, ``(m 4**level, 3)`` triangles, ``(k, 3)`` unit
        limit normals (float64) and ``(k, 3)`` colours in [0, 1] or None.
    """
    from mi_loop.subdiv.masks import limit_colors, limit_mesh

    P, F_t, N = limit_mesh(V, F, level, creases=creases)
    return P, F_t, N, None if albedo is None else limit_colors(albedo, F, level)


def sequence_view(result: Result, level: int):
    """The limit surface of every finished frame of a sequence at ``level`` (one connectivity).

    Parameters
    ----------
    result : Result
        A ``fit-sequence`` result (:func:`read_result`).
    level : int
        Tessellation level.

    Returns
    -------
    tuple ``(P, F_t, N, C)``
        ``(T, k, 3)`` limit points and ``(T, k, 3)`` unit limit normals of the
        ``T`` frames, the ``(m 4**level, 3)`` triangles, and ``(T, k, 3)``
        colours (the frames' albedo, with photos) or None.

    Raises
    ------
    ValueError
        A control mesh that does not parse, or frames of different connectivity.
    """
    from mi_loop.subdiv.masks import limit_colors, limit_mesh

    P, N, C, F0 = [], [], [], None
    for path in result.controls:
        V, F = io.read_mesh(path)
        if F0 is None:
            F0 = F
        elif not np.array_equal(F, F0):
            fail(_OUT, f"one connectivity in every frame of '{path.parent}'", f"other faces in '{path.name}'")
        p, F_t, n = limit_mesh(V, F, level)
        P.append(p)
        N.append(n)
        albedo = io.read_vertex_colors(path)
        C.append(None if albedo is None else limit_colors(albedo, F, level))
    colors = None if any(c is None for c in C) else np.stack(C)
    return np.stack(P), F_t, np.stack(N), colors


def _destination(result: Result, fmt: str, output) -> Path:
    """The file (or, for a sequence's obj / ply frames, the directory) to write; its parent checked."""
    frames = result.kind == "sequence" and fmt != "glb"
    if output is None:
        name = "" if frames else f"{'sequence' if result.kind == 'sequence' else 'limit'}.{fmt}"
        return result.path / "export" / name if name else result.path / "export"
    output = Path(output)
    if frames and output.suffix.lower() in (".glb", ".obj", ".ply"):
        fail("export -o", f"a directory for the frames of a sequence (one NNNN.{fmt} per frame)", f"'{output}'")
    if frames and output.is_file():
        fail("export -o", f"a directory for the frames of a sequence (one NNNN.{fmt} per frame)",
             f"'{output}': a file")
    if not frames and output.suffix.lower() != f".{fmt}":
        fail("export -o", f"a .{fmt} file (--format {fmt})", f"'{output}'")
    if not frames and output.is_dir():
        fail("export -o", f"a .{fmt} file (--format {fmt})", f"'{output}': a directory")
    return output


def write_view(path, fmt: str, view, names=None, fps: float = 24.0) -> Path:
    """Write a view of :func:`static_view` (or :func:`sequence_view`, as glb) to one file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist.
    fmt : {'glb', 'obj', 'ply'}
        The format; obj has no colours.
    view : tuple ``(P, F_t, N, C)``
        One surface (``P`` of shape ``(k, 3)``), or the frames of a sequence
        (``(T, k, 3)``, glb only: one mesh with a morph target per frame,
        coloured by the last frame's colours, the most refined albedo).
    names : list of str, optional
        The frames' names (a sequence).
    fps : float, optional
        The frame rate of a sequence.

    Returns
    -------
    pathlib.Path
    """
    P, F, N, C = view
    if fmt == "glb" and P.ndim == 3:
        return io.write_glb_sequence(path, P, F, N, fps=fps, names=names, colors=None if C is None else C[-1])
    if fmt == "glb":
        return io.write_glb(path, P, F, N, colors=C)
    if fmt == "obj":
        return io.write_obj(path, P, F, normals=N)
    return io.write_ply(path, P, F, normals=N, colors=C)


def run(path, fmt: str = "glb", *, level: int | None = None, output=None, fps: float | None = None, log) -> list:
    """Run ``mi-loop export``: write a result directory's limit surface as GLB, OBJ or PLY.

    Parameters
    ----------
    path : str or os.PathLike
        The result directory (:func:`read_result`).
    fmt : {'glb', 'obj', 'ply'}
        The format.
    level : int, optional
        Tessellation level; default :data:`VIEW_LEVELS` for glb (what the jobs
        write), :data:`LIMIT_LEVELS` for obj and ply (as ``limit.ply``).
    output : str or os.PathLike, optional
        A file of the format's suffix, or for a sequence's obj / ply frames a
        directory; default in ``OUT/export/``.
    fps : float, optional
        Frame rate of a sequence's ``sequence.glb``; default the one in
        ``sequence.json``, else 24.
    log : mi_loop.app.progress.Reporter

    Returns
    -------
    list of pathlib.Path
        The written files, also printed by ``log``.

    Raises
    ------
    ValueError
        Not a result directory (:func:`read_result`), an unknown format, an
        output of the wrong kind or suffix, ``fps`` not finite and positive or
        given for a fit or with obj / ply, a control mesh that does not parse.
    """
    if fmt not in FORMATS:
        fail("export --format", f"one of {', '.join(FORMATS)}", repr(fmt))
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        fail("export --fps", "a finite number > 0", float(fps))
    result = read_result(path)
    if fps is not None and (result.kind != "sequence" or fmt != "glb"):
        fail("export --fps", "a fit-sequence result exported as glb (the frame rate of its animation)",
             f"--fps {fps:g} for {'a fit result' if result.kind == 'fit' else f'--format {fmt}'}")
    level = (VIEW_LEVELS if fmt == "glb" else LIMIT_LEVELS)[result.kind] if level is None else level
    dest = _destination(result, fmt, output)
    frames = result.kind == "sequence" and fmt != "glb"
    created = io.first_missing_ancestor(dest if frames else dest.parent)
    io.ensure_writable_dir(dest if frames else dest.parent)
    try:
        if result.kind == "fit":
            control = result.controls[0]
            V, F = io.read_mesh(control)
            view = static_view(V, F, level, io.read_creases(control), io.read_vertex_colors(control))
            log.say(f"{control}: {len(V)} control vertices; limit surface at level {level}: {len(view[0])} "
                    f"vertices, {len(view[1])} triangles")
            paths = [write_view(dest, fmt, view)]
        else:
            view = sequence_view(result, level)
            log.say(f"{result.path}: {len(result.controls)} frames; limit surface at level {level}: "
                    f"{view[0].shape[1]} vertices, {len(view[1])} triangles per frame")
            if not frames:
                rate = fps or result.fps or 24.0
                paths = [write_view(dest, fmt, view, names=result.names, fps=rate)]
            else:
                with io.staged_outputs(dest) as stage:
                    for k, control in enumerate(result.controls):
                        write_view(stage / f"{control.stem}.{fmt}", fmt,
                                   (view[0][k], view[1], view[2][k], None if view[3] is None else view[3][k]))
                paths = [dest / f"{c.stem}.{fmt}" for c in result.controls]
    except BaseException:
        io.remove_if_empty(created, dest if frames else dest.parent)
        raise
    log.wrote(*paths)
    return paths
