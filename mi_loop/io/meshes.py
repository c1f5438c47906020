"""Mesh files: read control meshes (PLY, OBJ, OFF, glTF/GLB), write PLY and OBJ atomically.

Vertex order is kept as stored (the control points of a Loop surface are
addressed by index); polygons are split into triangle fans in the file's
face order, and :func:`read_control_mesh` says how many were split. glTF
files are the one exception to "as stored": their vertices are welded (see
:func:`mi_loop.io.formats.read_gltf`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.files import atomic_open
from mi_loop.io.formats import MESH_SUFFIXES, fan_triangulate, read_polygons
from mi_loop.io.ply import read_ply
from mi_loop.io.srgb import linear_to_srgb, srgb_to_linear

__all__ = ["MESH_SUFFIXES", "ControlMesh", "read_control_mesh", "read_creases", "read_mesh", "read_vertex_colors",
           "write_obj", "write_ply"]

#: Float32 linear vertex colours in the PLY files mi_loop writes (next to 8-bit sRGB ``red green blue``).
_ALBEDO = ("albedo_r", "albedo_g", "albedo_b")


@dataclass(frozen=True)
class ControlMesh:
    """A triangle mesh as read from a file, and how many of the file's polygons were split.

    Parameters
    ----------
    V : (n, 3) float64 numpy array
        Vertex positions, in the file's order (glTF: welded).
    F : (m, 3) int64 numpy array
        Triangles; a polygon of ``k > 3`` corners became ``k - 2`` consecutive
        triangles (a fan from its first corner), in the file's face order.
    n_split : int
        Number of the file's faces with more than three corners (0 for a
        triangle mesh); ``len(F)`` minus the number of the file's faces is
        how many triangles the splitting added.
    """

    V: np.ndarray
    F: np.ndarray
    n_split: int


def read_control_mesh(path) -> ControlMesh:
    """Read a mesh file and say how many polygons were split into triangles.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply``, ``.obj``, ``.off``, ``.glb`` or ``.gltf`` file. A glTF file
        must hold one mesh (its primitives are merged); it is read in its rest
        pose.

    Returns
    -------
    ControlMesh
        ``V``, ``F`` and ``n_split``. The mesh is not validated as a Loop
        control mesh: call :func:`mi_loop.mesh.topology.validate_mesh`.

    Raises
    ------
    ValueError
        Missing file, unsupported suffix, a file that does not parse, a
        non-finite vertex, a face index out of range, no vertices or no faces,
        several meshes in a glTF file; the message names the file and the
        offending vertex, face or line.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = os.path.join(d, "quad.obj")
    ...     _ = open(p, "w").write("v 0 0 0\\nv 1 0 0\\nv 1 1 0\\nv 0 1 0\\nf 1 2 3 4\\n")
    ...     mesh = read_control_mesh(p)
    >>> mesh.F.tolist(), mesh.n_split
    ([[0, 1, 2], [0, 2, 3]], 1)
    """
    return _read(path, "read_control_mesh")


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh from a PLY, OBJ, OFF or glTF/GLB file.

    The same as :func:`read_control_mesh` without the count of split polygons.

    Parameters
    ----------
    path : str or os.PathLike
        File to read.

    Returns
    -------
    V : (n, 3) float64 numpy array
        Vertex positions, in the file's order (glTF: welded).
    F : (m, 3) int64 numpy array
        Triangles (polygons fan-triangulated in the file's order).

    Raises
    ------
    ValueError
        As :func:`read_control_mesh`.
    """
    mesh = _read(path, "read_mesh")
    return mesh.V, mesh.F


def _read(path, func: str) -> ControlMesh:
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        fail(func, f"a {', '.join(MESH_SUFFIXES)} file", f"'{path}' (suffix '{path.suffix}')")
    if not path.is_file():
        fail(func, "an existing file", f"'{path}': no such file")
    V, counts, items = read_polygons(path, func, objects="one")
    if len(V) == 0:
        fail(func, f"vertices in '{path}'", "none")
    if len(counts) == 0:
        fail(func, f"faces in '{path}'", f"{len(V)} vertices and no faces (a point cloud?)")
    F, n_split = fan_triangulate(counts, items)
    return ControlMesh(V, F, n_split)


def _written_mesh(func: str, V, F):
    """``(V float64, F)`` of a mesh to write, checked: shapes and face indices (an empty ``F`` allowed)."""
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        fail(func, "V of shape (n, 3) with n > 0", f"shape {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        fail(func, "integer F of shape (m, 3)", f"{F.dtype} array of shape {F.shape}")
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        bad = int(np.flatnonzero((F < 0).any(1) | (F >= len(V)).any(1))[0])
        fail(func, f"face indices in [0, {len(V)})", f"face {bad} = {F[bad].tolist()}")
    return V, F


def write_ply(path, V, F, normals=None, colors=None, creases=None) -> Path:
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
    colors : (n, 3) float array-like, optional
        Per-vertex linear RGB (an albedo) in [0, 1], stored twice: as 8-bit
        sRGB ``red green blue`` (what mesh viewers show) and as float32 linear
        ``albedo_r albedo_g albedo_b`` (exact; :func:`read_vertex_colors`
        prefers it).
    creases : tuple ``((c, 2) int, (c,) float)`` or (c, 2) int array-like, optional
        Crease edges and their sharpness (``inf`` when only edges are given),
        stored as an ``edge`` element ``vertex1 vertex2 crease`` (float32
        sharpness, the convention of mesh tools that read creases from PLY);
        :func:`read_creases` reads them back.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    ValueError
        If the arrays have the wrong shape or face or crease indices are out of range.
    """
    V, F = _written_mesh("write_ply", V, F)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    header = ["ply", "format binary_little_endian 1.0", "comment written by mi_loop",
              f"element vertex {len(V)}", "property double x", "property double y", "property double z"]
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float32)
        if normals.shape != V.shape:
            fail("write_ply", f"normals of shape {V.shape}", f"shape {normals.shape}")
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
        header += ["property float nx", "property float ny", "property float nz"]
    if colors is not None:
        colors = np.asarray(colors, dtype=np.float32)
        if colors.shape != V.shape or not np.isfinite(colors).all():
            fail("write_ply", f"finite colors of shape {V.shape}", f"shape {colors.shape}"
                 + ("" if colors.shape != V.shape else " with non-finite values"))
        fields += [(c, "u1") for c in ("red", "green", "blue")] + [(c, "<f4") for c in _ALBEDO]
        header += [f"property uchar {c}" for c in ("red", "green", "blue")]
        header += [f"property float {c}" for c in _ALBEDO]
    header += [f"element face {len(F)}", "property list uchar int vertex_indices"]
    edges = None
    if creases is not None:
        E, sharp = creases if isinstance(creases, tuple) else (creases, None)
        E = np.asarray(E)
        sharp = np.full(len(E), np.inf) if sharp is None else np.asarray(sharp, dtype=np.float64)
        if E.ndim != 2 or E.shape[1] != 2 or not np.issubdtype(E.dtype, np.integer) or sharp.shape != (len(E),):
            fail("write_ply", "creases as (c, 2) integer vertex pairs with one sharpness each",
                 f"{E.dtype} array of shape {E.shape} and {sharp.shape[0] if sharp.ndim else 0} sharpness values")
        if E.size and (E.min() < 0 or E.max() >= len(V)):
            bad = int(np.flatnonzero((E < 0).any(1) | (E >= len(V)).any(1))[0])
            fail("write_ply", f"crease vertices in [0, {len(V)})", f"crease {bad} = {E[bad].tolist()}")
        edges = np.empty(len(E), dtype=[("vertex1", "<i4"), ("vertex2", "<i4"), ("crease", "<f4")])
        edges["vertex1"], edges["vertex2"], edges["crease"] = E[:, 0], E[:, 1], sharp
        header += [f"element edge {len(E)}", "property int vertex1", "property int vertex2", "property float crease"]
    header.append("end_header")

    vertices = np.empty(len(V), dtype=fields)
    for i, axis in enumerate("xyz"):
        vertices[axis] = V[:, i]
        if normals is not None:
            vertices["n" + axis] = normals[:, i]
    if colors is not None:
        encoded = np.round(255.0 * linear_to_srgb(colors)).astype(np.uint8)
        for i, c in enumerate(("red", "green", "blue")):
            vertices[c] = encoded[:, i]
            vertices[_ALBEDO[i]] = colors[:, i]
    faces = np.empty(len(F), dtype=[("count", "u1"), ("indices", "<i4", (3,))])
    faces["count"] = 3
    faces["indices"] = F
    path = Path(path)
    with atomic_open(path) as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vertices.tobytes())
        f.write(faces.tobytes())
        if edges is not None:
            f.write(edges.tobytes())
    return path


def write_obj(path, V, F, normals=None) -> Path:
    """Write a triangle mesh as a Wavefront OBJ file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist.
    V : (n, 3) float array-like
        Vertex positions, written with 17 significant digits (float64 round-trips exactly).
    F : (m, 3) int array-like
        Triangles, indices in ``[0, n)`` (written 1-based).
    normals : (n, 3) float array-like, optional
        Per-vertex normals (``vn``, 9 digits), one per vertex: corners are ``i//i``.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    ValueError
        If the arrays have the wrong shape or face indices are out of range.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = write_obj(os.path.join(d, "t.obj"), np.eye(3), [[0, 1, 2]])
    ...     V, F = read_mesh(p)
    >>> V.tolist(), F.tolist()
    ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [[0, 1, 2]])
    """
    V, F = _written_mesh("write_obj", V, F)
    lines = ["# written by mi_loop", *(f"v {x!r} {y!r} {z!r}" for x, y, z in V.tolist())]
    face = "f {0} {1} {2}"
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != V.shape:
            fail("write_obj", f"normals of shape {V.shape}", f"shape {normals.shape}")
        lines += [f"vn {x:.9g} {y:.9g} {z:.9g}" for x, y, z in normals.tolist()]
        face = "f {0}//{0} {1}//{1} {2}//{2}"
    lines += [face.format(a, b, c) for a, b, c in (F + 1).tolist()]
    path = Path(path)
    with atomic_open(path) as f:
        f.write(("\n".join(lines) + "\n").encode("ascii"))
    return path


def read_creases(path):
    """Read crease edges from a PLY file's ``edge`` element, or None if it has none (or is not a PLY).

    Parameters
    ----------
    path : str or os.PathLike
        A mesh file (only ``.ply`` files carry creases here).

    Returns
    -------
    tuple ``((c, 2) int64 NumPy array, (c,) float64 NumPy array)`` or None
        Edges ``vertex1 vertex2`` and their sharpness: the ``crease``
        property (written by :func:`write_ply`), else infinitely sharp.

    Raises
    ------
    ValueError
        If the PLY file cannot be parsed, or its edge element lacks ``vertex1`` / ``vertex2``.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = write_ply(os.path.join(d, "c.ply"), np.eye(3), [[0, 1, 2]], creases=([[0, 1]], [2.5]))
    ...     E, s = read_creases(p)
    >>> E.tolist(), s.tolist()
    ([[0, 1]], [2.5])
    """
    path = Path(path)
    if path.suffix.lower() != ".ply":
        return None
    edge = read_ply(path, "read_creases").get("edge")
    if not edge:
        return None
    if "vertex1" not in edge or "vertex2" not in edge:
        fail("read_creases", f"an edge element with vertex1 and vertex2 in '{path}'",
             f"properties {', '.join(edge) or 'none'}")
    E = np.stack([np.asarray(edge["vertex1"], dtype=np.int64), np.asarray(edge["vertex2"], dtype=np.int64)], 1)
    sharp = np.asarray(edge["crease"], dtype=np.float64) if "crease" in edge else np.full(len(E), np.inf)
    return E, sharp


def read_vertex_colors(path) -> np.ndarray | None:
    """Read per-vertex linear RGB from a PLY file, or None if it has none (or is not a PLY).

    Parameters
    ----------
    path : str or os.PathLike
        A mesh file (only ``.ply`` files carry colours here).

    Returns
    -------
    (n, 3) float32 NumPy array or None
        ``albedo_r albedo_g albedo_b`` if present (written by :func:`write_ply`),
        else ``red green blue`` decoded from sRGB (display colours: integers
        over their type's maximum, floats taken as in [0, 1]).

    Raises
    ------
    ValueError
        If the PLY file cannot be parsed.
    """
    path = Path(path)
    if path.suffix.lower() != ".ply":
        return None
    vertex = read_ply(path, "read_vertex_colors").get("vertex", {})
    if all(c in vertex for c in _ALBEDO):
        return np.stack([np.asarray(vertex[c], dtype=np.float32) for c in _ALBEDO], axis=1)
    if not all(c in vertex for c in ("red", "green", "blue")):
        return None
    rgb = np.stack([np.asarray(vertex[c]) for c in ("red", "green", "blue")], axis=1)
    if np.issubdtype(rgb.dtype, np.integer):
        return srgb_to_linear(rgb / float(np.iinfo(rgb.dtype).max))
    return srgb_to_linear(rgb)
