"""Limit positions and normals at the control vertices (NumPy/SciPy)."""
from __future__ import annotations

import numpy as np

from mi_loop.subdiv.limit import build_hierarchy, level_rows, padded_to_csr
from mi_loop.subdiv.tessellation import tessellate
from mi_loop.mesh.topology import validate_mesh

_CORNER_UV = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


def vertex_samples(F, n_vertices: int):
    """``(face_ids, uv)`` of one corner sample per control vertex (its limit point)."""
    F = np.asarray(F)
    face = np.zeros(int(n_vertices), dtype=np.int64)
    corner = np.zeros(int(n_vertices), dtype=np.int64)
    for c in range(3):
        face[F[:, c]] = np.arange(len(F))
        corner[F[:, c]] = c
    return face, _CORNER_UV[corner].copy()


def limit_mesh(V, F, level: int = 3, creases=None):
    """Dense limit mesh of a control mesh: ``(P (k, 3), F_tess (t, 3), N (k, 3))`` (NumPy).

    Limit points and unit limit normals at a watertight level-``level``
    tessellation; the mesh hierarchy is built once for all three row sets.
    """
    V = np.asarray(V, dtype=np.float64)
    h = build_hierarchy(F, len(V), creases, "limit_mesh")
    fid, uv, F_t = tessellate(h.levels[0].F, level)
    VL = h.composed() @ V
    P, du, dv = (padded_to_csr(i, w, h.top.n) @ VL
                 for i, w in level_rows(h, fid, uv, (None, "u", "v")))
    N = np.cross(du, dv)
    return P, F_t, N / np.linalg.norm(N, axis=1, keepdims=True)


def limit_masks(F, n_vertices, creases=None, derivatives=False):
    """Return the limit masks at the control vertices as sparse matrices.

    Row ``i`` of the position mask gives the limit point of control vertex
    ``i``: for a smooth vertex of valence ``k`` the classic mask ``chi =
    1 / (3 / (8 beta) + k)`` per neighbour and ``1 - k chi`` at the centre, on a
    crease ``1/6, 2/3, 1/6``, at a corner the vertex itself; darts and
    semi-sharp creases from the exact local subdivision matrix.

    Parameters
    ----------
    F : (m, 3) int numpy array
    n_vertices : int
    creases : optional
        As in :func:`mi_loop.subdivision_matrix`.
    derivatives : bool
        Also return the tangent masks along the two edges of one incident face.

    Returns
    -------
    M : scipy.sparse.csr_matrix ``(n, n)``
        Position masks; with ``derivatives`` also ``(Mu, Mv)`` of the same shape.
    """
    h = build_hierarchy(F, n_vertices, creases, "limit_masks")
    face, uv = vertex_samples(h.levels[0].F, n_vertices)
    names = (None, "u", "v") if derivatives else (None,)
    S = h.composed()
    rows = level_rows(h, face, uv, names)
    Ms = [(padded_to_csr(i, w, h.top.n) @ S).tocsr() for i, w in rows]
    return tuple(Ms) if derivatives else Ms[0]


def limit_positions(V, F, creases=None):
    """Return the limit points of the control vertices.

    Parameters
    ----------
    V : (n, 3) float numpy array
    F : (m, 3) int numpy array
    creases : optional

    Returns
    -------
    (n, 3) float64 numpy array

    Examples
    --------
    >>> import numpy as np, mi_loop
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    >>> np.round(mi_loop.limit_positions(V, F)[0], 6)   # beta(3) = 3/16... chi = 1/(2+3)
    array([0.2, 0.2, 0.2])
    """
    V, F, _ = _checked(V, F)
    return limit_masks(F, len(V), creases) @ V


def limit_normals(V, F, creases=None):
    """Return unit limit normals at the control vertices, ``(n, 3)`` float64."""
    V, F, _ = _checked(V, F)
    _, Mu, Mv = limit_masks(F, len(V), creases, derivatives=True)
    N = np.cross(Mu @ V, Mv @ V)
    return N / np.linalg.norm(N, axis=1, keepdims=True)


def _checked(V, F):
    V = np.asarray(V, dtype=np.float64)
    used = np.zeros(len(V), bool)
    used[np.asarray(F).ravel()] = True
    if not used.all():
        raise ValueError(f"limit_positions(): {int((~used).sum())} control vertices are not used by "
                         "any face; drop them first (mi_loop.validate_mesh does)")
    return validate_mesh(V, F, "limit_positions")
