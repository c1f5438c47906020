"""One Loop subdivision step as a sparse matrix (NumPy/SciPy).

Rules (Loop 1987; boundary and crease rules of Hoppe et al. 1994):

* edge point: ``3/8 (a + b) + 1/8 (c + d)``; on a sharp edge (boundary, or
  crease with sharpness > 0) the midpoint;
* vertex point, by the number of incident sharp edges: 0 or 1 (smooth, dart)
  ``(1 - k beta) v + beta sum(neighbours)`` with Loop's original
  ``beta(k) = (5/8 - (3/8 + cos(2 pi / k) / 4)^2) / k``; 2 (crease or boundary)
  ``3/4 v + 1/8`` each sharp neighbour; 3 or more, or a boundary vertex with a
  single face (corner): the vertex stays.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mi_loop.mesh.halfedge import Topology
from mi_loop.mesh.topology import check_creases, validate_faces

__all__ = ["loop_beta", "subdivide_topology", "subdivision_matrix"]


def loop_beta(k):
    """Return Loop's original vertex weight ``beta(k) = (5/8 - (3/8 + cos(2 pi / k) / 4)^2) / k``.

    Parameters
    ----------
    k : int or int numpy array
        Valence (> 0).

    Returns
    -------
    float64 numpy array of the shape of ``k``

    Examples
    --------
    >>> float(loop_beta(6)) == 1 / 16, float(loop_beta(3)) == 3 / 16
    (True, True)
    """
    k = np.asarray(k, dtype=np.float64)
    return (5.0 / 8.0 - (3.0 / 8.0 + np.cos(2.0 * np.pi / k) / 4.0) ** 2) / k


def subdivide_topology(topo: Topology):
    """Subdivide a validated mesh once.

    Parameters
    ----------
    topo : Topology
        Connectivity and crease sharpness of the coarse mesh.

    Returns
    -------
    S : scipy.sparse.csr_matrix, shape ``(n + e, n)``, float64
        ``V_fine = S @ V``; fine vertex ``n + i`` is the new vertex of edge ``i``.
    fine : Topology
        Topology of the fine mesh, sharpness of child edges decremented.

    Examples
    --------
    >>> from mi_loop.mesh.halfedge import Topology
    >>> S, fine = subdivide_topology(Topology.build(np.array([[0, 1, 2]]), 3))
    >>> S.shape, fine.F.shape
    ((6, 3), (4, 3))
    """
    F, n, E = topo.F, topo.n, topo.E
    e = len(E)
    kind = topo.vertex_kind()
    sharp_edge = topo.sharpness > 0

    rows, cols, vals = [], [], []

    # Vertex points.
    val = topo.valence()
    beta = np.where(val > 0, loop_beta(np.maximum(val, 1)), 0.0)
    smooth = kind == 0
    crease = kind == 1
    vidx = np.arange(n)
    centre = np.where(smooth, 1.0 - val * beta, np.where(crease, 0.75, 1.0))
    rows.append(vidx)
    cols.append(vidx)
    vals.append(centre)
    for a, b in ((0, 1), (1, 0)):
        v, w = E[:, a], E[:, b]
        w_smooth = np.where(smooth[v], beta[v], 0.0)
        w_crease = np.where(crease[v] & sharp_edge, 0.125, 0.0)
        wt = w_smooth + w_crease
        keep = wt != 0
        rows.append(v[keep])
        cols.append(w[keep])
        vals.append(wt[keep])

    # Edge points: opposite vertices from the two incident faces.
    opp = np.full((e, 2), -1, dtype=np.int64)
    fe = topo.face_edge
    for c in range(3):
        eid = fe[:, c]
        o = F[:, (c + 2) % 3]
        forward = F[:, c] < F[:, (c + 1) % 3]
        opp[eid[forward], 0] = o[forward]
        opp[eid[~forward], 1] = o[~forward]
    new = n + np.arange(e)
    smooth_e = ~sharp_edge
    end_w = np.where(smooth_e, 0.375, 0.5)
    for a in (0, 1):
        rows.append(new)
        cols.append(E[:, a])
        vals.append(end_w)
    for a in (0, 1):
        rows.append(new[smooth_e])
        cols.append(opp[smooth_e, a])
        vals.append(np.full(smooth_e.sum(), 0.125))

    S = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n + e, n))

    a, b, c = F[:, 0], F[:, 1], F[:, 2]
    ab, bc, ca = n + fe[:, 0], n + fe[:, 1], n + fe[:, 2]
    F_fine = np.stack([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                       np.stack([ca, bc, c], 1), np.stack([bc, ca, ab], 1)], 1).reshape(-1, 3)

    s_child = np.where(np.isfinite(topo.sharpness), topo.sharpness - 1.0, np.inf)
    s_child = np.maximum(s_child, 0.0)
    s_child[topo.boundary] = 0.0  # boundaries are re-detected from the fine faces
    keep = s_child > 0
    E_c = np.concatenate([np.stack([E[keep, 0], new[keep]], 1), np.stack([new[keep], E[keep, 1]], 1)])
    s_c = np.concatenate([s_child[keep], s_child[keep]])
    fine = Topology.build(F_fine, n + e, (E_c, s_c) if len(E_c) else None)
    return S, fine


def subdivision_matrix(F, n_vertices: int, creases=None):
    """Return the matrix of one Loop subdivision step and the fine faces.

    Parameters
    ----------
    F : (m, 3) int numpy array
        Triangle faces of a manifold, consistently oriented mesh (boundaries allowed).
    n_vertices : int
        Number of control vertices ``n``.
    creases : None, (c, 2) int numpy array, or tuple ``(E, sharpness)``
        Crease edges given by vertex pairs; without sharpness they are
        infinitely sharp, otherwise sharpness is a positive integer or ``inf``.

    Returns
    -------
    S : scipy.sparse.csr_matrix, shape ``(n + e, n)``, float64
        ``V_fine = S @ V``; the first ``n`` fine vertices are the old ones, then
        one new vertex per undirected edge.
    F_fine : (4 m, 3) int64 numpy array
        Children of face ``f = (a, b, c)`` are rows ``4 f .. 4 f + 3``:
        ``(a, ab, ca), (ab, b, bc), (ca, bc, c), (bc, ca, ab)``.

    Raises
    ------
    ValueError
        For an invalid mesh or crease specification.

    Examples
    --------
    >>> import numpy as np, mi_loop
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> S, F_fine = mi_loop.subdivision_matrix(F, 4)
    >>> S.shape, F_fine.shape
    ((10, 4), (16, 3))
    >>> np.allclose(S.sum(axis=1), 1.0)
    True
    """
    F = validate_faces(F, n_vertices, "subdivision_matrix")
    cr = check_creases(creases, F, int(n_vertices), "subdivision_matrix")
    S, fine = subdivide_topology(Topology.build(F, int(n_vertices), cr))
    return S, fine.F
