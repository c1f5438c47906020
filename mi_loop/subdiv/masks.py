"""Limit positions and normals at the control vertices, and dense limit meshes (NumPy/SciPy).

The masks themselves (:func:`~mi_loop.subdiv.limit.position_masks`,
:func:`~mi_loop.subdiv.limit.vertex_rows`) live in :mod:`mi_loop.subdiv.limit`,
whose :func:`~mi_loop.subdiv.limit.limit_matrix` takes them for samples at the
corners; :func:`vertex_samples` is re-exported from
:mod:`mi_loop.subdiv.tessellation`.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail
from mi_loop.mesh.topology import check_vertices, sharp_topology, validate_faces
from mi_loop.subdiv.hierarchy import build_hierarchy
from mi_loop.subdiv.limit import level_rows, limit_matrix, padded_to_csr, position_masks, vertex_rows
from mi_loop.subdiv.tessellation import tessellate, vertex_samples

__all__ = ["limit_colors", "limit_masks", "limit_mesh", "limit_normals", "limit_positions", "tangent_masks",
           "vertex_samples"]

#: The rows of the hierarchy at the control vertices, under the name the tests compare the closed forms against.
_masks = vertex_rows


def limit_mesh(V, F, level: int = 3, creases=None, *, corners=None, boundary="edge_and_corner",
               crease_method="uniform"):
    """Return a dense, watertight mesh of limit points and unit limit normals.

    The hierarchy is built once for the three row sets (points, d/du, d/dv).

    Parameters
    ----------
    V : (n, 3) float numpy array
        Control points.
    F : (m, 3) int numpy array
        Control faces.
    level : int, optional
        Tessellation level of :func:`~mi_loop.subdiv.tessellation.tessellate` (0 to 8).
    creases, corners, boundary, crease_method : optional
        The crease model, as in :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    P : (k, 3) float64 numpy array
        Limit points.
    F_tess : (m 4**level, 3) int64 numpy array
        Triangles over ``P``, oriented like the control faces.
    N : (k, 3) float64 numpy array
        Unit limit normals.

    Raises
    ------
    ValueError
        Invalid mesh, creases or level, or ``V`` not of shape ``(n, 3)``.

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    >>> P, F_tess, N = limit_mesh(V, F, level=1)
    >>> P.shape, F_tess.shape, bool(np.allclose(np.linalg.norm(N, axis=1), 1))
    ((10, 3), (16, 3), True)
    """
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        fail("limit_mesh", "control points V of shape (n, 3)", f"shape {V.shape}")
    model = dict(creases=creases, corners=corners, boundary=boundary, crease_method=crease_method)
    h = build_hierarchy(F, len(V), func="limit_mesh", **model)
    fid, uv, F_t = tessellate(h.levels[0].F, level, np.flatnonzero(~h.levels[0].hole))   # holes left out
    VL = h.composed() @ V
    P, du, dv = (padded_to_csr(i, w, h.top.n) @ VL
                 for i, w in level_rows(h, fid, uv, (None, "u", "v")))
    N = np.cross(du, dv)
    return P, F_t, N / np.linalg.norm(N, axis=1, keepdims=True)


def limit_colors(colors, F, level: int = 3) -> np.ndarray:
    """Per-control-vertex colours carried to the vertices of :func:`limit_mesh` ``(V, F, level)``.

    The limit operator is linear, so the colour at a limit point is the same
    combination of the control colours as the point is of the control points.

    Parameters
    ----------
    colors : (n, 3) float NumPy array
        One colour per control vertex (e.g. linear albedo in [0, 1]).
    F : (m, 3) int NumPy array
        Control faces.
    level : int, optional
        Tessellation level, as given to :func:`limit_mesh`.

    Returns
    -------
    (k, 3) float64 NumPy array
        Clipped to [0, 1].
    """
    face_ids, uv, _ = tessellate(F, level)
    return np.clip(limit_matrix(F, len(colors), face_ids, uv) @ np.asarray(colors, dtype=np.float64), 0.0, 1.0)


def limit_masks(F, n_vertices, creases=None, *, corners=None, boundary="edge_and_corner", crease_method="uniform"):
    """Return the limit masks at the control vertices as a sparse matrix.

    Row ``i`` gives the limit point of control vertex ``i``: for a smooth
    vertex of valence ``k`` the classic mask ``chi = 1 / (3 / (8 beta) + k)``
    per neighbour and ``1 - k chi`` at the centre, on a crease ``1/6, 2/3,
    1/6``, at a corner the vertex itself; darts and semi-sharp creases from
    the exact local subdivision matrix.

    Parameters
    ----------
    F : (m, 3) int numpy array
        Control faces; every vertex must be used by a face.
    n_vertices : int
        Number of control vertices ``n``.
    creases, corners, boundary, crease_method : optional
        The crease model, as in :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``(n, n)``, float64
        ``M @ V`` are the limit points of the control vertices.

    Raises
    ------
    ValueError
        Invalid mesh or creases, or a vertex used by no face.

    See Also
    --------
    tangent_masks : the two tangent masks at the same vertices.

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> M = limit_masks(F, 4)
    >>> M.toarray()[0].round(6).tolist()             # valence 3: chi = 1 / (3 / (8 beta) + 3) = 1/5
    [0.4, 0.2, 0.2, 0.2]
    """
    model = dict(creases=creases, corners=corners, boundary=boundary, crease_method=crease_method)
    _check_used(F, n_vertices, "limit_masks")
    return position_masks(sharp_topology(F, n_vertices, "limit_masks", **model), "limit_masks", model)


def tangent_masks(F, n_vertices, creases=None, *, corners=None, boundary="edge_and_corner", crease_method="uniform"):
    """Return the tangent masks ``d/du``, ``d/dv`` at the control vertices as sparse matrices.

    Row ``i`` is the parametric derivative of the limit surface at control
    vertex ``i`` in the face that :func:`vertex_samples` picks for it (along
    that face's two edges from the vertex's corner); at an irregular vertex,
    orthonormal rows spanning the tangent plane with ``cross(Mu V, Mv V)``
    along the exact limit normal (see :func:`mi_loop.limit_matrix`).

    Parameters
    ----------
    F : (m, 3) int numpy array
        Control faces; every vertex must be used by a face.
    n_vertices : int
        Number of control vertices ``n``.
    creases, corners, boundary, crease_method : optional
        The crease model, as in :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    Mu : scipy.sparse.csr_matrix, shape ``(n, n)``, float64
    Mv : scipy.sparse.csr_matrix, shape ``(n, n)``, float64

    Raises
    ------
    ValueError
        Invalid mesh or creases, or a vertex used by no face.

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> Mu, Mv = tangent_masks(F, 4)
    >>> bool(abs(Mu.sum(axis=1)).max() < 1e-12 and abs(Mv.sum(axis=1)).max() < 1e-12)   # rows sum to 0
    True
    """
    model = dict(creases=creases, corners=corners, boundary=boundary, crease_method=crease_method)
    _check_used(F, n_vertices, "tangent_masks")
    return vertex_rows(F, n_vertices, model, ("u", "v"), "tangent_masks")


def limit_positions(V, F, creases=None, *, corners=None, boundary="edge_and_corner", crease_method="uniform"):
    """Return the limit points of the control vertices.

    Parameters
    ----------
    V : (n, 3) float numpy array
        Control points, every one used by a face.
    F : (m, 3) int numpy array
        Control faces.
    creases, corners, boundary, crease_method : optional
        The crease model, as in :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    (n, 3) float64 numpy array

    Raises
    ------
    ValueError
        Invalid mesh or creases, or a vertex used by no face.

    Examples
    --------
    >>> import numpy as np, mi_loop
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    >>> np.round(mi_loop.limit_positions(V, F)[0], 6)   # beta(3) = 3/16... chi = 1/(2+3)
    array([0.2, 0.2, 0.2])
    """
    model = dict(creases=creases, corners=corners, boundary=boundary, crease_method=crease_method)
    V, F = _checked(V, F, "limit_positions")
    return position_masks(sharp_topology(F, len(V), "limit_positions", **model), "limit_positions", model) @ V


def limit_normals(V, F, creases=None, *, corners=None, boundary="edge_and_corner", crease_method="uniform"):
    """Return unit limit normals at the control vertices.

    Parameters
    ----------
    V : (n, 3) float numpy array
        Control points, every one used by a face.
    F : (m, 3) int numpy array
        Control faces.
    creases, corners, boundary, crease_method : optional
        The crease model, as in :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    (n, 3) float64 numpy array
        ``cross(d/du, d/dv)`` of the limit surface at each vertex, normalised
        (at an irregular vertex the exact limit normal).

    Raises
    ------
    ValueError
        Invalid mesh or creases, or a vertex used by no face.

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    >>> np.round(limit_normals(V, F)[0] * np.sqrt(3), 6).tolist()   # outward, along the vertex
    [1.0, 1.0, 1.0]
    """
    model = dict(creases=creases, corners=corners, boundary=boundary, crease_method=crease_method)
    V, F = _checked(V, F, "limit_normals")
    Mu, Mv = vertex_rows(F, len(V), model, ("u", "v"), "limit_normals")
    N = np.cross(Mu @ V, Mv @ V)
    return N / np.linalg.norm(N, axis=1, keepdims=True)


def _check_used(F, n_vertices, func):
    """Every vertex must be used by a face (a vertex mask needs a face); returns F, validated first."""
    F = validate_faces(F, n_vertices, func)
    used = np.zeros(int(n_vertices), bool)
    used[F.ravel()] = True
    if not used.all():
        unused = np.flatnonzero(~used)
        fail(func, "every control vertex used by a face (mi_loop.validate_mesh drops the others)",
             f"{len(unused)} unused vertices, the first vertex {unused[0]}")
    return F


def _checked(V, F, func):
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        fail(func, "control points V of shape (n, 3) with n > 0", f"shape {V.shape}")
    F = _check_used(F, len(V), func)
    return check_vertices(V, func), F
