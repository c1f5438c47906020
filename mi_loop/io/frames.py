"""Sequences of frames: one NPZ file of vertex arrays, or one mesh or point-cloud file per frame.

Frames are listed at once and read one at a time (a long capture need not fit
in memory). In a directory, only mesh and point-cloud files count as frames
(:data:`FRAME_SUFFIXES`), hidden files are skipped, and ``.txt`` files are
ignored (a ``readme.txt`` is not a frame); a ``.txt`` point cloud given by
name or matched by a glob pattern is read as XYZ text.
"""
from __future__ import annotations

import glob
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.meshes import read_mesh
from mi_loop.io.points import load_oriented_points

__all__ = ["FRAME_SUFFIXES", "Frame", "FrameData", "frame_range", "read_frames", "select_frames"]

#: Suffixes of the files that :func:`read_frames` takes from a directory, sorted by name.
FRAME_SUFFIXES = (".ply", ".obj", ".off", ".glb", ".gltf", ".xyz", ".pts", ".npz")
_MESHES = (".obj", ".off", ".glb", ".gltf")


@dataclass(frozen=True, eq=False)
class FrameData:
    """One frame of a sequence as read: a mesh, or a point cloud with or without normals.

    Attributes
    ----------
    name : str
        The frame's name: its file name, ``stem[t]`` in an NPZ sequence, or the baked animation's frame name.
    vertices : (k, 3) float NumPy array
        A mesh's vertices, or a point cloud's points.
    faces : (m, 3) int NumPy array or None
        A mesh's triangles; None for a point cloud.
    normals : (k, 3) float NumPy array or None
        A point cloud's normals; None for a mesh or for a point cloud whose file has none.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray | None = None
    normals: np.ndarray | None = None


class Frame:
    """One frame of a sequence, read when called: ``frame()`` -> :class:`FrameData`.

    Parameters
    ----------
    read : callable
        Reads the frame (no arguments) and returns its :class:`FrameData`.
    correspondence : bool
        See :attr:`correspondence`.

    Attributes
    ----------
    correspondence : bool
        Whether every frame of its sequence has the same vertex order (an NPZ
        sequence of meshes with the same faces or of points, a baked
        animation): vertex ``i`` is the same material point in every frame.
    """

    def __init__(self, read, correspondence: bool = False):
        self._read, self.correspondence = read, bool(correspondence)

    def __call__(self) -> FrameData:
        return self._read()


def frame_range(text: str) -> slice:
    """Parse ``--frames START:STOP:STEP`` (Python slice syntax, every part optional) into a slice.

    Parameters
    ----------
    text : str
        ``START:STOP:STEP`` or ``START:STOP``; negative values count from the end.

    Returns
    -------
    slice

    Raises
    ------
    ValueError
        No colon, a part that is not an integer, a STEP below 1.

    Examples
    --------
    >>> frame_range("2:10:2"), frame_range("5:"), frame_range("::3")
    (slice(2, 10, 2), slice(5, None, None), slice(None, None, 3))
    """
    parts = str(text).split(":")
    try:
        if not 2 <= len(parts) <= 3:
            raise ValueError
        values = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        fail("frame_range", "START:STOP:STEP with integers, each optional (e.g. 0:24:2, 5:, ::3)", f"'{text}'")
    values += [None] * (3 - len(values))
    if values[2] is not None and values[2] < 1:
        fail("frame_range", "a STEP of at least 1", f"'{text}'")
    return slice(*values)


def select_frames(frames: list, selection: slice | None, what: str = "select_frames") -> list:
    """The frames a slice keeps (``None``: all).

    Parameters
    ----------
    frames : list
        Frames (or captures, or reference frames).
    selection : slice or None
    what : str
        Who asks, for the message.

    Returns
    -------
    list

    Raises
    ------
    ValueError
        If the selection keeps no frame.
    """
    if selection is None:
        return list(frames)
    kept = list(frames)[selection]
    if not kept:
        fail(what, f"a selection that keeps at least one of the {len(frames)} frames",
             f"{selection.start}:{selection.stop}:{selection.step} keeps none")
    return kept


def read_frames(inputs, *, animation: str | None = None, fps: float = 24.0) -> list:
    """List the frames of a sequence without reading them (they are read one at a time).

    Parameters
    ----------
    inputs : list of str or os.PathLike
        One NPZ file with ``vertices (T, V, 3)`` and ``faces (F, 3)``, or with
        ``points (T, N, 3)`` (point clouds in correspondence); or mesh /
        point-cloud files (any suffix :func:`~mi_loop.io.points.load_oriented_points`
        reads), directories (their files with a suffix in :data:`FRAME_SUFFIXES`,
        sorted by name; hidden files skipped) or glob patterns such as
        ``'scan_*.ply'`` (sorted; ``.txt`` matches count too). With
        ``animation``: one animated glTF/GLB file.
    animation : str, optional
        Bake this animation of the glTF/GLB (skinning or node animation,
        :func:`mi_loop.io.animation.bake_animation`) into mesh frames.
    fps : float
        Frames per second of the baked animation.

    Returns
    -------
    list of Frame
        ``frames[t]()`` reads frame ``t`` and returns its :class:`FrameData`:
        a mesh's vertices and faces, or a point cloud's points and normals
        (None when the file has none).

    Raises
    ------
    ValueError
        Empty sequence, missing paths, a pattern that matches nothing, an NPZ
        without ``vertices``/``faces`` or with arrays of the wrong shape.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     for name in ("b.xyz", "a.xyz", "readme.txt"):
    ...         _ = open(os.path.join(d, name), "w").write("0 0 0\\n1 0 0\\n0 1 0\\n")
    ...     frames = read_frames([d])
    ...     [frame().name for frame in frames]
    ['a.xyz', 'b.xyz']
    """
    if animation is not None:
        return _animation(inputs, animation, fps)
    paths = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            paths += sorted(q for q in p.iterdir()
                            if q.is_file() and not q.name.startswith(".") and q.suffix.lower() in FRAME_SUFFIXES)
        elif p.exists():
            paths.append(p)
        elif any(c in str(item) for c in "*?["):   # a quoted glob pattern
            matches = sorted(Path(m) for m in glob.glob(str(item)))
            matches = [m for m in matches if m.is_file() and m.suffix.lower() in (*FRAME_SUFFIXES, ".txt")]
            if not matches:
                fail("read_frames", "frame files matching the pattern", f"none for '{item}'")
            paths += matches
        else:
            fail("read_frames", "an existing file, directory or glob pattern", f"'{p}': no such file or directory")
    if not paths:
        fail("read_frames", "at least one frame file", f"none in {[str(i) for i in inputs]}")
    if len(paths) == 1 and paths[0].suffix.lower() == ".npz" and not _npz_point_cloud(paths[0]):
        return _npz_sequence(paths[0])
    return [Frame(_reader(p)) for p in paths]


def _npz_point_cloud(path: Path) -> bool:
    """Whether an NPZ holds one point cloud (``points (N, 3)``, as D-FAUST's frames), not a sequence."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return "points" in data.files and "vertices" not in data.files and data["points"].ndim == 2
    except (OSError, EOFError, ValueError):
        return False                                  # reported by the sequence reader


def _npz_sequence(path: Path) -> list:
    want = "arrays 'vertices' (T, V, 3) and 'faces' (F, 3), or 'points' (T, N, 3)"
    try:
        with np.load(path, allow_pickle=False) as data:
            names = sorted(data.files)
            if "points" in names and "vertices" not in names:
                return _points_sequence(path, np.asarray(data["points"], dtype=np.float64))
            if "vertices" not in names or "faces" not in names:
                fail("read_frames", f"{want} in '{path}'", f"arrays {names}")
            Vs, F = np.asarray(data["vertices"], dtype=np.float64), np.asarray(data["faces"])
    except (OSError, EOFError) as exc:
        fail("read_frames", f"a readable NPZ file '{path}'", f"{type(exc).__name__}: {exc}")
    except ValueError as exc:
        if str(exc).startswith("read_frames():"):
            raise
        fail("read_frames", f"a readable NPZ file '{path}'", f"{type(exc).__name__}: {exc}")
    if Vs.ndim != 3 or Vs.shape[2] != 3 or len(Vs) == 0 or Vs.shape[1] == 0:
        fail("read_frames", f"{want} in '{path}', with T > 0", f"vertices of shape {Vs.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        fail("read_frames", f"{want} in '{path}'", f"faces of shape {F.shape} and dtype {F.dtype}")
    return [Frame(lambda t=t: FrameData(f"{path.stem}[{t}]", Vs[t], F), correspondence=True) for t in range(len(Vs))]


def _points_sequence(path: Path, Ps: np.ndarray) -> list:
    """Point clouds in correspondence: ``points (T, N, 3)``, point ``k`` the same material point in every frame."""
    if Ps.ndim != 3 or Ps.shape[2] != 3 or len(Ps) == 0 or Ps.shape[1] < 3:
        fail("read_frames", f"'points' of shape (T, N, 3) with T > 0 and N >= 3 in '{path}'",
             f"points of shape {Ps.shape}")
    if not np.isfinite(Ps).all():
        fail("read_frames", f"finite points in '{path}'", f"{int((~np.isfinite(Ps)).any(2).sum())} non-finite")
    return [Frame(lambda t=t: FrameData(f"{path.stem}[{t}]", Ps[t]), correspondence=True) for t in range(len(Ps))]


def _animation(inputs, animation: str, fps: float) -> list:
    from mi_loop.io.animation import bake_animation

    paths = [Path(p) for p in inputs]
    if len(paths) != 1 or paths[0].suffix.lower() not in (".glb", ".gltf"):
        fail("read_frames --animation", "one animated glTF/GLB file", f"{[str(p) for p in paths]}")
    if not paths[0].is_file():
        fail("read_frames --animation", "an existing glTF/GLB file", f"'{paths[0]}': no such file")
    baked = bake_animation(paths[0], animation, fps=fps)
    return [Frame(lambda t=t: FrameData(baked.names[t], baked.vertices[t], baked.faces), correspondence=True)
            for t in range(len(baked.vertices))]


def _reader(p: Path):
    def read():
        if p.suffix.lower() in _MESHES or _ply_has_faces(p):
            V, F = read_mesh(p)
            return FrameData(p.name, V, F)
        P, N, _ = load_oriented_points(p)
        return FrameData(p.name, P, None, N)
    return read


def _ply_has_faces(path: Path) -> bool:
    """Whether a PLY file declares a non-empty face element (header only)."""
    if path.suffix.lower() != ".ply":
        return False
    with open(path, "rb") as f:
        head = f.read(65536).split(b"end_header")[0]
    match = re.search(rb"^element face (\d+)", head, flags=re.MULTILINE)
    return bool(match) and int(match.group(1)) > 0
