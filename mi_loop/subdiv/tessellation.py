"""Uniform, watertight tessellation of control faces in parameter space, and corner samples (NumPy)."""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail
from mi_loop.mesh.halfedge import Topology
from mi_loop.mesh.topology import validate_faces

__all__ = ["tessellate", "vertex_samples"]

_CORNER_UV = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


def vertex_samples(F, n_vertices: int):
    """Return one face-corner sample per control vertex, whose limit point is the vertex's.

    Parameters
    ----------
    F : (m, 3) int numpy array
        Validated faces; every vertex must be used by a face.
    n_vertices : int
        Number of vertices ``n``.

    Returns
    -------
    face_ids : (n,) int64 numpy array
        A face of every vertex.
    uv : (n, 2) float64 numpy array
        The vertex's corner in that face: ``(0, 0)``, ``(1, 0)`` or ``(0, 1)``.

    Examples
    --------
    >>> face_ids, uv = vertex_samples(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> face_ids.tolist(), uv.tolist()
    ([1, 0, 0, 1], [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 1.0]])
    """
    F = np.asarray(F)
    face = np.zeros(int(n_vertices), dtype=np.int64)
    corner = np.zeros(int(n_vertices), dtype=np.int64)
    for c in range(3):
        face[F[:, c]] = np.arange(len(F))
        corner[F[:, c]] = c
    return face, _CORNER_UV[corner].copy()


def tessellate(F, level: int = 3, faces=None):
    """Split every control face into ``4**level`` triangles in ``(u, v)``.

    Points shared by neighbouring faces (control vertices and points on
    control edges) appear once, so the limit mesh is watertight.

    Parameters
    ----------
    F : (m, 3) int numpy array
        Control faces.
    level : int
        Every control edge is cut into ``2**level`` segments (0 to 8).
    faces : (m',) int numpy array, optional
        Tessellate only these control faces (e.g. all but the holes of
        boundary ``'none'``); all by default.

    Returns
    -------
    face_ids : (k,) int64 numpy array
        Control face of every tessellation point (one of ``faces``).
    uv : (k, 2) float64 numpy array
        Its parameters in that face.
    F_tess : (m' * 4**level, 3) int64 numpy array
        Triangles over the ``k`` points, oriented like the control faces,
        ``4**level`` per face in the order of ``faces``.

    Raises
    ------
    ValueError
        For an invalid level or faces.

    Examples
    --------
    >>> import numpy as np, mi_loop
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> face_ids, uv, F_tess = mi_loop.tessellate(F, 1)
    >>> len(uv), len(F_tess)   # 4 vertices + 6 edge midpoints; 16 triangles
    (10, 16)
    """
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 0 <= level <= 8:
        fail("tessellate", "an integer level in [0, 8]", repr(level))
    F = np.asarray(F)
    n = int(F.max()) + 1 if F.size else 0
    F = validate_faces(F, n, "tessellate")
    topo = Topology.build(F, n)
    m, R = len(F), 2 ** level
    i, j = np.meshgrid(np.arange(R + 1), np.arange(R + 1), indexing="ij")
    keep = i + j <= R
    i, j = i[keep], j[keep]                       # local grid points, (g,)
    local = np.full((R + 1, R + 1), -1)
    local[i, j] = np.arange(len(i))
    # Global key of every (face, grid point).
    e_len = R - 1
    n_edge_pts = len(topo.E) * e_len
    interior = (i > 0) & (j > 0) & (i + j < R)
    n_int = int(interior.sum())
    int_rank = np.cumsum(interior) - 1
    key = np.empty((m, len(i)), dtype=np.int64)
    # interior points
    key[:, interior] = (n + n_edge_pts + np.arange(m)[:, None] * n_int
                        + int_rank[interior][None, :])
    # corners
    for (ci, cj), c in (((0, 0), 0), ((R, 0), 1), ((0, R), 2)):
        key[:, local[ci, cj]] = F[:, c]
    # edge points: edge c from corner c to corner c+1, parameter t = s / R
    s = np.arange(1, R)
    edge_local = [local[s, 0], local[R - s, s], local[0, R - s]]
    for c in range(3):
        a, b = F[:, c], F[:, (c + 1) % 3]
        eid = topo.face_edge[:, c]
        forward = (a < b)[:, None]
        pos = np.where(forward, s[None, :], R - s[None, :]) - 1
        key[:, edge_local[c]] = n + eid[:, None] * e_len + pos
    chosen = np.arange(m) if faces is None else np.asarray(faces, dtype=np.int64)
    key = key[chosen]
    _, first, inverse = np.unique(key.ravel(), return_index=True, return_inverse=True)
    inverse = inverse.reshape(len(chosen), -1)
    f_first, g_first = np.divmod(first, len(i))
    f_first = chosen[f_first]
    uv = np.stack([i[g_first], j[g_first]], 1) / R
    # Triangles of the grid: up (i,j),(i+1,j),(i,j+1) and down (i+1,j),(i+1,j+1),(i,j+1).
    ui, uj = np.meshgrid(np.arange(R), np.arange(R), indexing="ij")
    up = ui + uj < R
    tris = [np.stack([local[ui[up], uj[up]], local[ui[up] + 1, uj[up]], local[ui[up], uj[up] + 1]], 1)]
    dn = ui + uj < R - 1
    tris.append(np.stack([local[ui[dn] + 1, uj[dn]], local[ui[dn] + 1, uj[dn] + 1],
                          local[ui[dn], uj[dn] + 1]], 1))
    tris = np.concatenate(tris)
    F_tess = inverse[:, tris].reshape(-1, 3)
    return f_first.astype(np.int64), uv, F_tess
