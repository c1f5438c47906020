"""Mesh files: read control meshes and sequences of frames, write PLY atomically.

Vertex order is always kept as stored: the control points of a Loop surface are
addressed by index.
"""
from __future__ import annotations

import glob
from pathlib import Path

import numpy as np

from mi_loop.io.files import atomic_open

__all__ = ["MESH_SUFFIXES", "read_frames", "read_mesh", "write_ply"]

MESH_SUFFIXES = (".ply", ".obj", ".off")


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle control mesh from a PLY, OBJ or OFF file.

    Vertex order is kept as stored (no merging, no reordering), because the
    control points of a Loop surface are addressed by index.

    Parameters
    ----------
    path : str or os.PathLike
        File to read.

    Returns
    -------
    V : (n, 3) float64 NumPy array
        Vertex positions.
    F : (m, 3) int64 NumPy array
        Triangles as vertex indices (polygons are fan-triangulated by trimesh).

    Raises
    ------
    ValueError
        If the file is missing, has an unsupported suffix, cannot be parsed,
        or holds no vertices or no faces.
    """
    import trimesh

    path = Path(path)
    where = f"read_mesh: '{path}'"
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{where}: expected a {'/'.join(MESH_SUFFIXES)} file, got suffix '{path.suffix}'")
    if not path.is_file():
        raise ValueError(f"{where}: no such file")
    try:
        mesh = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise ValueError(f"{where}: cannot parse mesh ({type(exc).__name__}: {exc})") from exc
    if isinstance(mesh, trimesh.Scene):
        parts = list(mesh.geometry.values())
        if len(parts) > 1:
            raise ValueError(f"{where}: file holds {len(parts)} separate meshes, expected one")
        mesh = parts[0] if parts else None
    V = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    F = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    if len(V) == 0:
        raise ValueError(f"{where}: file holds no vertices")
    if len(F) == 0:
        raise ValueError(f"{where}: file holds {len(V)} vertices but no faces")
    return V, F


def write_ply(path, V, F, normals=None) -> Path:
    """Write a triangle mesh as a binary little-endian PLY file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist.
    V : (n, 3) float array-like
        Vertex positions, stored as float64 so control meshes round-trip exactly.
    F : (m, 3) int array-like
        Triangles, indices in ``[0, n)``.
    normals : (n, 3) float array-like, optional
        Per-vertex normals, stored as float32 (``nx ny nz``).

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    ValueError
        If the arrays have the wrong shape or face indices are out of range.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        raise ValueError(f"write_ply: expected V of shape (n, 3) with n > 0, got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise ValueError(f"write_ply: expected integer F of shape (m, 3), got {F.dtype} {F.shape}")
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        bad = int(np.flatnonzero((F < 0).any(1) | (F >= len(V)).any(1))[0])
        raise ValueError(f"write_ply: face {bad} = {F[bad].tolist()} indexes outside [0, {len(V)})")
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    header = ["ply", "format binary_little_endian 1.0", "comment written by mi_loop",
              f"element vertex {len(V)}", "property double x", "property double y", "property double z"]
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float32)
        if normals.shape != V.shape:
            raise ValueError(f"write_ply: expected normals of shape {V.shape}, got {normals.shape}")
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
        header += ["property float nx", "property float ny", "property float nz"]
    header += [f"element face {len(F)}", "property list uchar int vertex_indices", "end_header"]

    vertices = np.empty(len(V), dtype=fields)
    for i, axis in enumerate("xyz"):
        vertices[axis] = V[:, i]
        if normals is not None:
            vertices["n" + axis] = normals[:, i]
    faces = np.empty(len(F), dtype=[("count", "u1"), ("indices", "<i4", (3,))])
    faces["count"] = 3
    faces["indices"] = F
    path = Path(path)
    with atomic_open(path) as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vertices.tobytes())
        f.write(faces.tobytes())
    return path


def read_frames(inputs) -> list:
    """List the frames of a sequence without reading them (they are read one at a time).

    Parameters
    ----------
    inputs : list of str or os.PathLike
        One NPZ file with ``vertices (T, V, 3)`` and ``faces (F, 3)``; or mesh /
        point-cloud files, directories (their PLY/OBJ/OFF/XYZ/PTS/NPZ files,
        sorted by name) or glob patterns such as ``'scan_*.ply'`` (sorted).

    Returns
    -------
    list of callables
        ``frames[t]()`` reads frame ``t`` and returns ``(name, V_or_P, F_or_None, N_or_None)``.

    Raises
    ------
    ValueError
        Empty sequence, missing paths, an NPZ without ``vertices``/``faces``.
    """
    suffixes = {".ply", ".obj", ".off", ".xyz", ".pts", ".txt", ".npz"}
    paths = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            paths += sorted(q for q in p.iterdir() if q.suffix.lower() in suffixes)
        elif p.exists():
            paths.append(p)
        elif any(c in str(item) for c in "*?["):   # a quoted glob pattern
            matches = sorted(Path(m) for m in glob.glob(str(item)))
            matches = [m for m in matches if m.is_file() and m.suffix.lower() in suffixes]
            if not matches:
                raise ValueError(f"read_frames: no frame file matches '{item}'")
            paths += matches
        else:
            raise ValueError(f"read_frames: no such file or directory: '{p}'")
    if not paths:
        raise ValueError("read_frames: the sequence is empty (no frame files found)")
    if len(paths) == 1 and paths[0].suffix.lower() == ".npz":
        try:
            data = np.load(paths[0])
            Vs, F = np.asarray(data["vertices"], dtype=np.float64), np.asarray(data["faces"])
        except KeyError as exc:
            raise ValueError(f"read_frames: '{paths[0]}' has no array {exc}; expected "
                             "'vertices' (T, V, 3) and 'faces' (F, 3)") from exc
        except (OSError, ValueError) as exc:
            raise ValueError(f"read_frames: cannot read '{paths[0]}': {exc}") from exc
        if Vs.ndim != 3 or Vs.shape[2] != 3 or len(Vs) == 0:
            raise ValueError(f"read_frames: '{paths[0]}' vertices must be (T, V, 3) with T > 0, "
                             f"got {Vs.shape}")
        return [(lambda t=t: (f"{paths[0].stem}[{t}]", Vs[t], F, None)) for t in range(len(Vs))]

    def reader(p):
        def read():
            from mi_loop.io.points import load_oriented_points

            if p.suffix.lower() in {".obj", ".off"} or _has_faces(p):
                V, F = read_mesh(p)
                return p.name, V, F, None
            P, N, _ = load_oriented_points(p)
            return p.name, P, None, N
        return read
    return [reader(p) for p in paths]


def _has_faces(path: Path) -> bool:
    """Whether a PLY file declares faces (header only)."""
    if path.suffix.lower() != ".ply":
        return False
    with open(path, "rb") as f:
        head = f.read(4096).split(b"end_header")[0]
    return b"element face" in head and not b"element face 0" in head
