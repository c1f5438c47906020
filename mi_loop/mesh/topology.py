"""Validation of Loop control meshes and crease arguments (NumPy).

Connectivity only, except :func:`validate_mesh`, which also checks the
coordinates. Every rejected input raises :class:`ValueError` with a message
``function(): expected ..., got ...`` that names the offending face, edge,
vertex or crease. The adjacency structure of a validated mesh is
:class:`mi_loop.mesh.halfedge.Topology`.
"""
from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from mi_loop.errors import fail
from mi_loop.mesh.halfedge import Topology

__all__ = ["BOUNDARY_RULES", "CREASE_METHODS", "check_corners", "check_creases", "check_rules", "sharp_topology",
           "validate_faces", "validate_mesh"]


#: Boundary interpolation rules (OpenSubdiv's ``VtxBoundaryInterpolation``).
BOUNDARY_RULES = ("edge_and_corner", "edge_only", "none")
#: Crease methods (OpenSubdiv's ``CreasingMethod``).
CREASE_METHODS = ("uniform", "chaikin")
#: Sharpness from which an edge or vertex is infinitely sharp (OpenSubdiv's ``SHARPNESS_INFINITE``).
INFINITE_SHARPNESS = 10.0


def _sharpness_values(s, count: int, what: str, func: str) -> np.ndarray:
    """``count`` sharpness values >= 0 as float64, ``>= 10`` made ``inf`` (else a named ValueError)."""
    s = np.full(count, np.inf) if s is None else np.asarray(s, dtype=np.float64).reshape(-1)
    if len(s) != count:
        fail(func, f"one sharpness per {what} ({count})", f"{len(s)} sharpness values")
    bad = np.flatnonzero(~(s >= 0))
    if len(bad):
        element = what.split()[0]
        fail(func, f"{element} sharpness >= 0 (0 smooth, 10 or more or inf infinitely sharp)",
             f"sharpness {s[bad[0]]} at {element} {bad[0]}")
    return np.where(s >= INFINITE_SHARPNESS, np.inf, s)


def _split(tagged):
    """``(items as an array, sharpness or None)`` of a ``creases`` / ``corners`` argument; ``(None, None)`` if empty."""
    items, s = tagged if isinstance(tagged, tuple) and len(tagged) == 2 else (tagged, None)
    if items is None or np.asarray(items).size == 0:
        return None, None
    return np.asarray(items), s


def check_creases(creases, F: np.ndarray, n: int, func: str):
    """Normalise a ``creases`` argument to ``(E (c, 2) int64, s (c,) float64)`` or None.

    Parameters
    ----------
    creases : None, (c, 2) int array_like, or tuple ``(E, sharpness)``
        None; vertex pairs of infinitely sharp edges; or pairs with one
        sharpness each, any value ``>= 0`` as in OpenSubdiv (0 smooth,
        fractional values blend the sharp and smooth rules at the last step,
        10 or more, or ``inf``, infinitely sharp).
    F : (m, 3) int64 numpy array
        Faces of the mesh, already validated.
    n : int
        Number of vertices.
    func : str
        Name of the calling public function, for the message.

    Returns
    -------
    tuple ``(E (c, 2) int64 numpy array, s (c,) float64 numpy array)`` or None
        None when there are no creases; sharpness ``>= 10`` is returned as ``inf``.

    Raises
    ------
    ValueError
        Wrong shape or dtype, a sharpness count that differs from the edge
        count, a negative or NaN sharpness, a pair that is not an edge of the
        mesh; the first offending crease is named.

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3]])
    >>> E, s = check_creases((np.array([[2, 0], [0, 1]]), [2.5, 12]), F, 4, "f")
    >>> E.tolist(), s.tolist()
    ([[2, 0], [0, 1]], [2.5, inf])
    >>> check_creases(np.array([[1, 3]]), F, 4, "f")
    Traceback (most recent call last):
    ...
    ValueError: f(): expected crease edges that are edges of the mesh, got crease 0 = [1, 3]
    """
    E, s = _split(creases)
    if E is None:
        return None
    if E.ndim != 2 or E.shape[1] != 2 or not np.issubdtype(E.dtype, np.integer):
        fail(func, "creases as an integer array of shape (c, 2)", f"{E.dtype} array of shape {E.shape}")
    E = E.astype(np.int64)
    s = _sharpness_values(s, len(E), "crease edge", func)
    bad = np.flatnonzero((E < 0).any(1) | (E >= n).any(1) | (E[:, 0] == E[:, 1]))
    if len(bad):
        fail(func, f"creases as pairs of distinct vertex indices in [0, {n})",
             f"crease {bad[0]} = {E[bad[0]].tolist()}")
    keys = np.unique(np.sort(np.stack([F.ravel(), F[:, [1, 2, 0]].ravel()], 1), 1) @ [n, 1])
    ck = np.sort(E, 1) @ [n, 1]
    bad = np.flatnonzero(~np.isin(ck, keys))
    if len(bad):
        fail(func, "crease edges that are edges of the mesh", f"crease {bad[0]} = {E[bad[0]].tolist()}")
    return E, s


def check_corners(corners, n: int, func: str):
    """Normalise a ``corners`` argument (vertex sharpness) to ``(ids (c,) int64, s (c,) float64)`` or None.

    Parameters
    ----------
    corners : None, (c,) int array_like, or tuple ``(vertex_ids, sharpness)``
        None; vertices that are infinitely sharp corners; or vertices with
        one sharpness each, ``>= 0`` as for creases (OpenSubdiv's vertex
        sharpness: the corner rule while it lasts, decremented by one a step).
    n : int
        Number of vertices.
    func : str
        Name of the calling public function, for the message.

    Raises
    ------
    ValueError
        Wrong shape or dtype, a count mismatch, a vertex outside ``[0, n)``,
        a negative or NaN sharpness; the first offending corner is named.

    Examples
    --------
    >>> ids, s = check_corners(([3, 0], [0.5, np.inf]), 4, "f")
    >>> ids.tolist(), s.tolist()
    ([3, 0], [0.5, inf])
    >>> check_corners([4], 4, "f")
    Traceback (most recent call last):
    ...
    ValueError: f(): expected corner vertices in [0, 4), got vertex 4 at corner 0
    """
    ids, s = _split(corners)
    if ids is None:
        return None
    if ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer):
        fail(func, "corners as a 1-D integer array of vertex ids", f"{ids.dtype} array of shape {ids.shape}")
    ids = ids.astype(np.int64)
    s = _sharpness_values(s, len(ids), "corner vertex", func)
    bad = np.flatnonzero((ids < 0) | (ids >= n))
    if len(bad):
        fail(func, f"corner vertices in [0, {n})", f"vertex {ids[bad[0]]} at corner {bad[0]}")
    return ids, s


def check_rules(boundary: str, crease_method: str, func: str):
    """The boundary rule and crease method, checked against :data:`BOUNDARY_RULES` and :data:`CREASE_METHODS`.

    Parameters
    ----------
    boundary : str
        OpenSubdiv's boundary interpolation.
    crease_method : str
        OpenSubdiv's crease method.
    func : str
        Name of the calling public function, for the message.

    Returns
    -------
    tuple ``(boundary, crease_method)``

    Raises
    ------
    ValueError
        For a name outside the lists (the message lists them).
    """
    if boundary not in BOUNDARY_RULES:
        fail(func, f"boundary one of {', '.join(map(repr, BOUNDARY_RULES))}", repr(boundary))
    if crease_method not in CREASE_METHODS:
        fail(func, f"crease_method one of {', '.join(map(repr, CREASE_METHODS))}", repr(crease_method))
    return boundary, crease_method


def sharp_topology(F, n_vertices: int, func: str, creases=None, corners=None,
                   boundary: str = "edge_and_corner", crease_method: str = "uniform"):
    """Validate a control mesh and its crease model and build its :class:`~mi_loop.mesh.halfedge.Topology`.

    Parameters
    ----------
    F : (m, 3) int array_like
        Control faces (checked by :func:`validate_faces`).
    n_vertices : int
        Number of control vertices.
    func : str
        Name of the calling public function, for messages.
    creases, corners : optional
        See :func:`check_creases` and :func:`check_corners`.
    boundary : {'edge_and_corner', 'edge_only', 'none'}
        OpenSubdiv's boundary interpolation. Boundary edges are infinitely
        sharp under every rule; ``'edge_and_corner'`` also makes a boundary
        vertex of one face an infinitely sharp corner; ``'none'`` makes the
        faces at a boundary vertex holes unless all of its boundary edges are
        given as infinitely sharp creases (see :attr:`Topology.hole`).
    crease_method : {'uniform', 'chaikin'}
        How semi-sharp creases decay (see :func:`mi_loop.subdivision_matrix`).

    Returns
    -------
    Topology
    """
    boundary, crease_method = check_rules(boundary, crease_method, func)
    F = validate_faces(F, n_vertices, func)
    n = int(n_vertices)
    return Topology.build(F, n, check_creases(creases, F, n, func), check_corners(corners, n, func),
                          boundary, crease_method)


def validate_faces(F, n_vertices: int, func: str = "validate_mesh") -> np.ndarray:
    """Check the connectivity of a Loop control mesh and return its faces as int64.

    Parameters
    ----------
    F : (m, 3) int array_like
        Triangles (float arrays of whole numbers are accepted).
    n_vertices : int
        Number of vertices ``n``.
    func : str, optional
        Name of the calling public function (or CLI option), for the message.

    Returns
    -------
    (m, 3) int64 numpy array

    Raises
    ------
    ValueError
        No faces or vertices, non-triangles, non-integer indices, an index
        outside ``[0, n)``, a degenerate face, a non-manifold edge (three or
        more faces) or vertex (several fans), inconsistent orientation, or two
        faces on the same three vertices (see Notes); the message names the
        first offending face, edge or vertex.

    Notes
    -----
    Two faces on the same three vertices form a closed two-triangle component
    (``[[0, 1, 2], [0, 2, 1]]``). Its limit surface is degenerate (flat and
    covered twice: the only control points are the three vertices, and
    swapping the two faces maps the surface onto itself), and its refinement
    has two distinct edges between the same two vertices at every level
    (around the valence-2 vertices), which no vertex-indexed mesh can hold;
    it is refused rather than evaluated wrongly.

    Examples
    --------
    >>> validate_faces([[0, 1, 2], [0, 2, 3]], 4).dtype
    dtype('int64')
    >>> validate_faces([[0, 1, 2], [0, 1, 3]], 4)
    Traceback (most recent call last):
    ...
    ValueError: validate_mesh(): expected consistently oriented faces (each directed edge in one face), got edge (0, 1) used in the same direction by faces 0 and 1
    """  # noqa: E501 (a doctest's exception line cannot be wrapped)
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        fail(func, "faces of shape (m, 3) with m > 0 (triangles only)", f"shape {F.shape}")
    if not np.issubdtype(F.dtype, np.integer):
        whole = np.issubdtype(F.dtype, np.floating) and np.isfinite(F).all() and np.all(F == np.round(F))
        if not whole:
            bad = np.flatnonzero(~(F == np.round(F)).all(1)) if np.issubdtype(F.dtype, np.number) else [0]
            fail(func, "integer face indices", f"dtype {F.dtype}, face {bad[0]} = {F[bad[0]].tolist()}")
    F = F.astype(np.int64)
    n = int(n_vertices)
    if n <= 0:
        fail(func, "a mesh with vertices", f"n_vertices = {n}")
    bad = np.flatnonzero((F < 0).any(1) | (F >= n).any(1))
    if len(bad):
        fail(func, f"face indices in [0, {n})", f"face {bad[0]} = {F[bad[0]].tolist()}")
    bad = np.flatnonzero((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0]))
    if len(bad):
        fail(func, "faces with three distinct vertices", f"face {bad[0]} = {F[bad[0]].tolist()} (degenerate)")
    _check_edges(F, n, func)
    _check_vertex_fans(F, n, func)
    _check_double_faces(F, n, func)
    return F


def _faces_on_edge(F: np.ndarray, a: int, b: int) -> np.ndarray:
    """Faces that contain both ``a`` and ``b``."""
    return np.flatnonzero((F == a).any(1) & (F == b).any(1))


def _check_edges(F: np.ndarray, n: int, func: str):
    """At most two faces per edge (manifold), each directed edge in one face (oriented)."""
    a, b = F.ravel(), F[:, [1, 2, 0]].ravel()
    und, ucounts = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_counts=True)
    if (ucounts > 2).any():
        k = und[np.argmax(ucounts > 2)]
        faces = _faces_on_edge(F, k // n, k % n)
        fail(func, "a manifold mesh (at most two faces per edge)",
             f"non-manifold edge ({k // n}, {k % n}) shared by {len(faces)} faces "
             f"({', '.join(map(str, faces[:6]))}{', ...' if len(faces) > 6 else ''})")
    directed, counts = np.unique(a * n + b, return_counts=True)
    if (counts > 1).any():
        k = directed[np.argmax(counts > 1)]
        v, w = k // n, k % n
        faces = [f for f in _faces_on_edge(F, v, w) if any(F[f, c] == v and F[f, (c + 1) % 3] == w for c in range(3))]
        fail(func, "consistently oriented faces (each directed edge in one face)",
             f"edge ({v}, {w}) used in the same direction by faces {faces[0]} and {faces[1]}")


def _check_vertex_fans(F: np.ndarray, n: int, func: str):
    """Each vertex's incident faces must form a single fan (manifold vertex)."""
    m = len(F)
    corner_v = F.ravel()
    nxt = F[:, [1, 2, 0]].ravel()
    prv = F[:, [2, 0, 1]].ravel()
    # Corner A (edge v -> w leaving it) and corner B (edge w -> v entering it)
    # of the same vertex v belong to the same fan.
    key_in = prv * n + corner_v
    rev_out = nxt * n + corner_v
    order = np.argsort(key_in)
    pos = np.minimum(np.searchsorted(key_in[order], rev_out), 3 * m - 1)
    hit = key_in[order][pos] == rev_out
    A, B = np.flatnonzero(hit), order[pos[hit]]
    graph = sp.coo_matrix((np.ones(len(A)), (A, B)), shape=(3 * m, 3 * m))
    _, label = connected_components(graph, directed=False)     # the fans, as components of the corner graph
    fans = np.unique(corner_v.astype(np.int64) * (3 * m) + label) // (3 * m)
    per_vertex = np.bincount(fans, minlength=n)
    bad = np.flatnonzero(per_vertex > 1)
    if len(bad):
        fail(func, "a manifold mesh (the faces around each vertex form one fan)",
             f"non-manifold vertex {bad[0]}, whose faces form {per_vertex[bad[0]]} separate fans")


def _check_double_faces(F: np.ndarray, n: int, func: str):
    """No two faces on the same three vertices (see :func:`validate_faces`, Notes)."""
    S = np.sort(F, axis=1)
    key = (S[:, 0] * n + S[:, 1]) * n + S[:, 2]
    order = np.argsort(key, kind="stable")
    same = np.flatnonzero(key[order][1:] == key[order][:-1])
    if len(same):
        f, g = sorted(order[[same[0], same[0] + 1]])
        fail(func, "no two faces on the same three vertices",
             f"faces {f} = {F[f].tolist()} and {g} = {F[g].tolist()}: a closed two-triangle component, "
             "whose limit surface is flat and doubly covered and whose refinement has double edges; "
             "remove it")


def check_vertices(V, func: str) -> np.ndarray:
    """Vertex positions of shape ``(n, 3)``, ``n > 0``, numeric and finite, as float64 (else a named ValueError)."""
    V = np.asarray(V)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        fail(func, "vertices of shape (n, 3) with n > 0", f"shape {V.shape}")
    if not np.issubdtype(V.dtype, np.number):
        fail(func, "numeric vertex coordinates", f"dtype {V.dtype}")
    V = V.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(V).all(1))
    if len(bad):
        fail(func, "finite vertex coordinates", f"vertex {bad[0]} = {V[bad[0]].tolist()} ({len(bad)} such vertices)")
    return V


def validate_mesh(V, F, func: str = "validate_mesh"):
    """Validate a control mesh and drop unreferenced vertices.

    Parameters
    ----------
    V : (n, 3) float array_like
        Vertex positions.
    F : (m, 3) int array_like
        Triangle faces, consistently oriented, manifold (boundaries allowed).
    func : str, optional
        Name of the calling public function (or CLI option), for the message.

    Returns
    -------
    V : (n', 3) float64 numpy array
        Referenced vertices only.
    F : (m, 3) int64 numpy array
        Faces re-indexed into ``V``.
    kept : (n',) int64 numpy array
        Original index of every kept vertex.

    Raises
    ------
    ValueError
        Empty mesh, non-triangle faces, out-of-range or negative indices,
        NaN/Inf coordinates, degenerate faces, non-manifold edges or vertices,
        inconsistent orientation, two faces on the same three vertices (see
        :func:`validate_faces`); the message names the offending element.

    Warns
    -----
    UserWarning
        When unreferenced vertices are dropped (says how many).

    Examples
    --------
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> V2, F2, kept = validate_mesh(V, [[0, 1, 2]])
    >>> F2.tolist(), kept.tolist()
    ([[0, 1, 2]], [0, 1, 2])
    >>> validate_mesh(V, [[0, 1, 2], [0, 2, 1]])
    Traceback (most recent call last):
    ...
    ValueError: validate_mesh(): expected no two faces on the same three vertices, got faces 0 = [0, 1, 2] and 1 = [0, 2, 1]: a closed two-triangle component, whose limit surface is flat and doubly covered and whose refinement has double edges; remove it
    """  # noqa: E501 (a doctest's exception line cannot be wrapped)
    V = check_vertices(V, func)
    F = validate_faces(F, len(V), func)
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    kept = np.flatnonzero(used)
    if len(kept) < len(V):
        head = func if func.endswith(")") or " " in func else f"{func}()"
        warnings.warn(f"{head}: dropped {len(V) - len(kept)} unreferenced vertices", stacklevel=2)
        remap = np.full(len(V), -1, dtype=np.int64)
        remap[kept] = np.arange(len(kept))
        V, F = V[kept], remap[F]
    return V, F, kept
