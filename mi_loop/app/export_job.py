"""The ``mi-loop export`` job: a result directory's limit surface as GLB, OBJ or PLY.

A result directory is what ``mi-loop fit``, ``fit-images`` or ``fit-sequence``
wrote (:func:`~mi_loop.app.results.read_result`); the surface is evaluated and
written as the jobs themselves do it (:mod:`mi_loop.app.results`), so an
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

from pathlib import Path

import numpy as np

from mi_loop import io
from mi_loop.app.results import (  # FORMATS and the levels: re-exported, parser.py reads them from here
    FORMATS,
    LIMIT_LEVELS,
    VIEW_LEVELS,
    Result,
    read_result,
    sequence_view,
    static_view,
    write_view,
)
from mi_loop.errors import fail

__all__ = ["FORMATS", "LIMIT_LEVELS", "VIEW_LEVELS", "run"]


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
