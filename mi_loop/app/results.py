"""Result directories of the jobs, and the viewer tessellations that ``limit.glb`` and ``sequence.glb`` hold.

A result directory is what ``mi-loop fit`` or ``fit-images`` wrote
(``control.ply``, with its creases or its albedo) or what ``fit-sequence``
wrote (``sequence.json``, ``metrics.csv`` and ``control/NNNN.ply`` of every
finished frame, a row of ``metrics.csv`` each). :func:`read_result` finds
which and refuses anything else; :func:`static_view` and
:func:`sequence_view` evaluate the limit surface of its control meshes at a
tessellation level and :func:`write_view` writes it, so the jobs and
``mi-loop export`` at the same level write the same file bit for bit.

Shared by the jobs (``fit``, ``fit-images``, ``fit-sequence``, ``export``) and
by ``fit-batch``'s summary; it imports no job.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.errors import fail
from mi_loop.io import runs

__all__ = ["FIT_OUTPUTS", "FORMATS", "LIMIT_LEVELS", "SEQUENCE_OUTPUTS", "VIEW_LEVELS", "Result", "read_result",
           "sequence_view", "static_view", "write_view"]

#: The formats of :func:`write_view` (and ``mi-loop export``).
FORMATS = ("glb", "obj", "ply")
#: Tessellation level of the viewer (``limit.glb``, ``sequence.glb``, the report), by result kind.
VIEW_LEVELS = {"fit": 2, "sequence": 1}
#: Level of the jobs' ``limit.ply`` and ``limit/NNNN.ply``: the default of an obj or ply export.
LIMIT_LEVELS = {"fit": 3, "sequence": 2}
#: The files ``mi-loop fit`` writes into OUTDIR, in this order.
FIT_OUTPUTS = ("control.ply", "limit.ply", "limit.glb", "report.json", "report.html", "loss.png", "render.png")
#: The files a finished ``fit-sequence`` has written besides ``control/``, ``limit/`` and ``state/``.
SEQUENCE_OUTPUTS = ("sequence.json", "metrics.csv", "drift.png", "strip.png", "sequence.glb", "report.html")

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
        frame's control mesh missing, a ``metrics.csv`` of other columns
        (:func:`mi_loop.io.runs.read_metrics`, older runs' read too).
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
    rows = runs.read_metrics(path / "metrics.csv", _OUT, older=True)
    if not rows:
        fail(_OUT, "a fit-sequence directory with at least one finished frame (a row of metrics.csv)",
             f"none in '{path / 'metrics.csv'}'")
    controls = [path / "control" / f"{r.frame:04d}.ply" for r in rows]
    missing = [p for p in controls if not p.is_file()]
    if missing:
        fail(_OUT, "the control mesh of every finished frame", f"no '{missing[0]}'")
    fps = runs.read_run_json(path / "sequence.json", _OUT).fps
    return Result(path, "sequence", controls, [r.name or f"frame {r.frame}" for r in rows],
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
