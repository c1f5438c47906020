"""Mesh file formats as polygon lists: PLY, OBJ, OFF, glTF/GLB (NumPy).

Every reader returns ``(V, counts, items)``: vertex positions in stored order
and the faces as polygons, face ``f`` being ``items[offset_f : offset_f +
counts[f]]``; :func:`fan_triangulate` turns them into triangles. OBJ and OFF
are parsed here (vertex order as in the file, whatever texture coordinates
or materials the file holds), PLY by :func:`mi_loop.io.ply.read_ply`, glTF by
trimesh. Coordinates are checked finite and indices in range; the messages
name the file and the vertex, face or line.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.ply import read_ply

__all__ = ["MESH_SUFFIXES", "fan_triangulate", "ply_polygons", "read_gltf", "read_obj", "read_off",
           "read_polygons"]

#: Suffixes of the mesh formats that :func:`read_polygons` reads.
MESH_SUFFIXES = (".ply", ".obj", ".off", ".glb", ".gltf")


def read_polygons(path, func: str, objects: str = "one"):
    """Read a mesh file of any supported format as polygons.

    Parameters
    ----------
    path : str or os.PathLike
        An existing ``.ply``, ``.obj``, ``.off``, ``.glb`` or ``.gltf`` file.
    func : str
        Name of the calling public function, for messages.
    objects : {'one', 'all'}
        glTF only: refuse a file with several meshes (``'one'``), or place
        every mesh by its node transform and concatenate them (``'all'``).

    Returns
    -------
    V : (n, 3) float64 numpy array
        Finite vertex positions.
    counts : (m,) int64 numpy array
        Corners of every face (at least 3).
    items : (counts.sum(),) int64 numpy array
        Face corners as vertex indices in ``[0, n)``, face after face.

    Raises
    ------
    ValueError
        Unreadable or malformed file, a non-finite vertex, a face index out of
        range, a face with fewer than 3 corners, several glTF meshes with
        ``objects='one'``; the message names the file and the element.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        V, counts, items = read_obj(path, func)
    elif suffix == ".off":
        V, counts, items = read_off(path, func)
    elif suffix == ".ply":
        V, counts, items = ply_polygons(read_ply(path, func), path, func)
    elif suffix in (".glb", ".gltf"):
        V, F = read_gltf(path, func, objects)
        counts, items = np.full(len(F), 3, dtype=np.int64), F.ravel()
    else:
        fail(func, f"a {', '.join(MESH_SUFFIXES)} file", f"'{path}'")
    _check_finite(V, path, func)
    return V, counts, items


def _check_finite(V, path, func):
    bad = np.flatnonzero(~np.isfinite(V).all(1))
    if len(bad):
        fail(func, f"finite vertex coordinates in '{path}'",
             f"vertex {bad[0]} = {V[bad[0]].tolist()} ({len(bad)} such vertices)")


def fan_triangulate(counts, items):
    """Split polygons into triangle fans ``(p0, p_i, p_i+1)``, keeping the faces' order.

    Parameters
    ----------
    counts : (m,) int numpy array
        Corners of every polygon (at least 3).
    items : (counts.sum(),) int numpy array
        Corners, polygon after polygon.

    Returns
    -------
    F : (counts.sum() - 2 m, 3) int64 numpy array
        Triangles; those of polygon ``f`` follow those of polygon ``f - 1``.
    n_split : int
        Number of polygons with more than three corners.

    Examples
    --------
    >>> F, n_split = fan_triangulate(np.array([4, 3]), np.array([0, 1, 2, 3, 1, 4, 2]))
    >>> F.tolist(), n_split
    ([[0, 1, 2], [0, 2, 3], [1, 4, 2]], 1)
    """
    counts = np.asarray(counts, dtype=np.int64)
    items = np.asarray(items, dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    tris = counts - 2
    poly = np.repeat(np.arange(len(counts)), tris)                 # polygon of every triangle
    k = np.arange(int(tris.sum())) - np.repeat(np.cumsum(tris) - tris, tris) + 1   # 1 .. count - 2
    F = np.stack([items[start[poly]], items[start[poly] + k], items[start[poly] + k + 1]], axis=1)
    return F, int((counts > 3).sum())


def _faces_in_range(counts, items, n, path, func, describe):
    """Check corner counts and indices; ``describe(f)`` names face ``f`` as the file writes it."""
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    bad = np.flatnonzero(counts < 3)
    if len(bad):
        fail(func, f"faces with at least 3 corners in '{path}'", describe(bad[0]))
    wrong = (items < 0) | (items >= n)
    if wrong.any():
        f = int(np.searchsorted(start, np.argmax(wrong), side="right") - 1)
        fail(func, f"face corners that index the file's {n} vertices in '{path}'", describe(f))


def _text(path: Path, func: str) -> list:
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        fail(func, f"a readable file '{path}'", f"{type(exc).__name__}: {exc.strerror or exc}")


def read_obj(path, func: str = "read_obj"):
    """Read the positions (``v``) and polygons (``f``) of a Wavefront OBJ file.

    Texture coordinates, normals, groups, objects and materials are ignored:
    the vertex list is the file's own, in its order, and face corners
    ``i``, ``i/t``, ``i//n``, ``i/t/n`` (1-based, or negative: relative to the
    vertices defined so far) index it.

    Parameters
    ----------
    path : str or os.PathLike
        An existing OBJ file.
    func : str, optional
        Name of the calling public function, for messages.

    Returns
    -------
    V : (n, 3) float64 numpy array
    counts : (m,) int64 numpy array
    items : (counts.sum(),) int64 numpy array
        As in :func:`read_polygons` (0-based).

    Raises
    ------
    ValueError
        A ``v`` line without three numbers, an ``f`` line with a corner that
        is not an index, fewer than 3 corners or an index out of range; the
        message gives the line number and the line.
    """
    path = Path(path)
    v_rows, v_lines, f_rows, f_lines, f_base = [], [], [], [], []
    for k, line in enumerate(_text(path, func), start=1):
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "v":
            v_rows.append(tok[1:4])
            v_lines.append(k)
        elif tok[0] == "f":
            f_rows.append(tok[1:])
            f_lines.append(k)
            f_base.append(len(v_rows))
    try:
        V = np.array(v_rows, dtype=np.float64).reshape(len(v_rows), 3)
    except ValueError:
        i = next(i for i, r in enumerate(v_rows) if not _three_numbers(r))
        fail(func, f"vertex lines 'v x y z' with three numbers in '{path}'",
             f"line {v_lines[i]} = {'v ' + ' '.join(v_rows[i])!r}")
    counts = np.array([len(r) for r in f_rows], dtype=np.int64)
    try:
        items = np.array([t.split("/", 1)[0] for r in f_rows for t in r], dtype=np.int64)
    except ValueError:
        r, line = next((r, k) for r, k in zip(f_rows, f_lines) if not _integers(t.split("/", 1)[0] for t in r))
        fail(func, f"face corners 'i', 'i/t', 'i//n' or 'i/t/n' with integer i in '{path}'",
             f"line {line} = {'f ' + ' '.join(r)!r}")
    base = np.repeat(np.array(f_base, dtype=np.int64), counts)   # vertices defined before each face
    items = np.where(items > 0, items - 1, np.where(items < 0, base + items, -1))
    _faces_in_range(counts, items, len(V), path, func,
                    lambda f: f"line {f_lines[f]} = {'f ' + ' '.join(f_rows[f])!r}")
    return V, counts, items


def _integers(tokens) -> bool:
    try:
        [int(t) for t in tokens]
        return True
    except ValueError:
        return False


def _three_numbers(tokens) -> bool:
    try:
        return len([float(t) for t in tokens]) == 3
    except ValueError:
        return False


def read_off(path, func: str = "read_off"):
    """Read an ASCII OFF file (``OFF``, ``COFF``, ``NOFF``, ``CNOFF`` or no header line).

    Parameters
    ----------
    path : str or os.PathLike
        An existing OFF file; ``#`` starts a comment; per-vertex and per-face
        colours or normals after the coordinates and indices are ignored.
    func : str, optional
        Name of the calling public function, for messages.

    Returns
    -------
    V : (n, 3) float64 numpy array
    counts : (m,) int64 numpy array
    items : (counts.sum(),) int64 numpy array
        As in :func:`read_polygons`.

    Raises
    ------
    ValueError
        Binary or higher-dimensional OFF, missing counts, too few vertex or
        face lines, a line that does not parse, a face index out of range;
        the message gives the line number and the line.
    """
    path = Path(path)
    rows = [(k, line.split("#", 1)[0].split()) for k, line in enumerate(_text(path, func), start=1)]
    rows = [(k, t) for k, t in rows if t]
    if not rows:
        fail(func, f"an OFF header and counts in '{path}'", "an empty file")
    k0, head = rows[0]
    if head[0].upper().endswith("OFF"):
        if (head[0].upper() not in ("OFF", "COFF", "NOFF", "CNOFF", "STOFF", "STNOFF")
                or "BINARY" in map(str.upper, head)):
            fail(func, f"an ASCII 3-D OFF file (header OFF, COFF, NOFF or CNOFF) in '{path}'",
                 f"line {k0} = {' '.join(head)!r}")
        head, rows = head[1:], rows[1:]
        if not head:
            if not rows:
                fail(func, f"the counts 'n_vertices n_faces n_edges' in '{path}'", "none")
            (k0, head), rows = rows[0], rows[1:]
    else:
        rows = rows[1:]
    try:
        nv, nf = int(head[0]), int(head[1])
    except (ValueError, IndexError):
        fail(func, f"the counts 'n_vertices n_faces n_edges' in '{path}'", f"line {k0} = {' '.join(head)!r}")
    if len(rows) < nv + nf:
        fail(func, f"{nv} vertex and {nf} face lines in '{path}'", f"{len(rows)} lines (the file ends early)")
    try:
        V = np.array([t[:3] for _, t in rows[:nv]], dtype=np.float64).reshape(nv, 3)
    except ValueError:
        k, t = next((k, t) for k, t in rows[:nv] if not _three_numbers(t[:3]))
        fail(func, f"vertex lines 'x y z' in '{path}'", f"line {k} = {' '.join(t)!r}")
    counts = np.zeros(nf, dtype=np.int64)
    items = []
    for f, (k, t) in enumerate(rows[nv:nv + nf]):
        try:
            counts[f] = int(t[0])
            corners = [int(x) for x in t[1:1 + counts[f]]]
            if len(corners) != counts[f]:
                raise ValueError
        except ValueError:
            fail(func, f"face lines 'k i_1 ... i_k' in '{path}'", f"line {k} = {' '.join(t)!r}")
        items += corners
    faces = rows[nv:nv + nf]
    _faces_in_range(counts, np.array(items, dtype=np.int64), nv, path, func,
                    lambda f: f"line {faces[f][0]} = {' '.join(faces[f][1])!r}")
    return V, counts, np.array(items, dtype=np.int64)


def ply_polygons(ply: dict, path, func: str):
    """Vertex positions and faces of a parsed PLY file (see :func:`mi_loop.io.ply.read_ply`).

    Parameters
    ----------
    ply : dict
        From :func:`~mi_loop.io.ply.read_ply`.
    path : str or os.PathLike
        The file, for messages.
    func : str
        Name of the calling public function, for messages.

    Returns
    -------
    V : (n, 3) float64 numpy array
    counts : (m,) int64 numpy array
        Empty when the file has no ``face`` element (a point cloud).
    items : (counts.sum(),) int64 numpy array
        As in :func:`read_polygons`.

    Raises
    ------
    ValueError
        No ``vertex`` element with ``x, y, z``, a face element without a
        ``vertex_indices`` (or ``vertex_index``) list, a face out of range,
        a non-finite vertex of a mesh (point clouds are checked by their reader).
    """
    vertex = ply.get("vertex", {})
    if not all(c in vertex for c in "xyz"):
        fail(func, f"a PLY 'vertex' element with properties x, y, z in '{path}'",
             f"elements {sorted(ply)} with vertex properties {sorted(vertex)}")
    V = np.stack([np.asarray(vertex[c], dtype=np.float64) for c in "xyz"], axis=1)
    face = ply.get("face", {})
    lists = [p for p in ("vertex_indices", "vertex_index") if isinstance(face.get(p), tuple)]
    sizes = [len(v[0]) if isinstance(v, tuple) else len(v) for v in face.values()]
    if not sizes or max(sizes) == 0:                 # no face element, or an empty one: a point cloud
        return V, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    if not lists:
        fail(func, f"a PLY 'face' element with a list property vertex_indices in '{path}'",
             f"face properties {sorted(face)}")
    counts, items = face[lists[0]]
    counts, items = counts.astype(np.int64), items.astype(np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    _faces_in_range(counts, items, len(V), path, func,
                    lambda f: f"face {f} = {items[start[f]:start[f] + counts[f]].tolist()}")
    _check_finite(V, path, func)
    return V, counts, items


def read_gltf(path, func: str = "read_gltf", objects: str = "one"):
    """Read the triangles of a glTF 2.0 file (``.gltf`` or binary ``.glb``) in its rest pose.

    All primitives of one glTF mesh are merged; vertices with identical
    positions are welded (glTF splits them at UV and normal seams), keeping
    the order of their first appearance (meshes and primitives taken in the
    natural order of their names, the same in every run). Skins, morph
    targets and animations are not applied.

    Parameters
    ----------
    path : str or os.PathLike
        An existing glTF file.
    func : str, optional
        Name of the calling public function, for messages.
    objects : {'one', 'all'}
        Refuse a file with several mesh instances (``'one'``), or place each
        by its node transform and concatenate them (``'all'``).

    Returns
    -------
    V : (n, 3) float64 numpy array
    F : (m, 3) int64 numpy array

    Raises
    ------
    ValueError
        Unreadable file, no triangles, several meshes with ``objects='one'``.
    """
    import trimesh

    if objects not in ("one", "all"):
        fail("read_gltf", "objects 'one' or 'all'", repr(objects))
    path = Path(path)
    try:
        scene = trimesh.load(str(path), process=False, force="scene")
    except Exception as exc:  # noqa: BLE001 -- trimesh raises many types for malformed files
        fail(func, f"a readable glTF file '{path}'", f"{type(exc).__name__}: {exc}")
    parents = scene.graph.transforms.parents
    parts = []   # (object, geometry name, world transform, mesh); trimesh gives each primitive of a
    for node in scene.graph.nodes_geometry:         # multi-primitive mesh its own child node
        T, name = scene.graph[node]
        geometry = scene.geometry[name]
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
            obj = parents.get(node, node) if geometry.metadata.get("from_gltf_primitive") else node
            parts.append((str(obj), str(name), np.asarray(T, dtype=np.float64), geometry))
    if not parts:
        fail(func, f"a glTF file with triangles in '{path}'", "none")
    parts.sort(key=lambda p: (_natural(p[0]), _natural(p[1])))     # the same order in every run
    names = list(dict.fromkeys(p[0] for p in parts))
    if objects == "one" and len(names) > 1:
        listed = ", ".join(map(repr, names[:4])) + (", ..." if len(names) > 4 else "")
        fail(func, f"one mesh in '{path}'", f"{len(names)} meshes (nodes {listed}); export the one to use alone")
    Vs, Fs, offset = [], [], 0
    for _, _, T, geometry in parts:
        V = np.asarray(geometry.vertices, dtype=np.float64)
        Vs.append(V if np.array_equal(T, np.eye(4)) else V @ T[:3, :3].T + T[:3, 3])
        Fs.append(np.asarray(geometry.faces, dtype=np.int64) + offset)
        offset += len(V)
    V, F = np.concatenate(Vs), np.concatenate(Fs)
    _check_finite(V, path, func)
    return _weld_in_order(V, F)


def _natural(name: str) -> list:
    """Sort key that puts ``'x_2'`` before ``'x_10'``."""
    return [(0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", name) if t]


def _weld_in_order(V, F):
    """Merge vertices with equal positions; the survivors keep their first appearance's order."""
    _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)                       # unique rows by first appearance
    rank = np.empty(len(first), dtype=np.int64)
    rank[order] = np.arange(len(first))
    return V[first[order]], rank[inverse.ravel()][F]
