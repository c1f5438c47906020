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
from mi_loop.mesh.topology import sharp_topology

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


def _decremented(s: np.ndarray) -> np.ndarray:
    """OpenSubdiv's uniform decay of edge or vertex sharpness: ``s - 1``, 0 once at or below 1, ``inf`` kept."""
    return np.where(s > 1.0, s - 1.0, 0.0)


def _rule(vertex_sharpness: np.ndarray, sharp_edges: np.ndarray) -> np.ndarray:
    """OpenSubdiv's vertex rule: 0 smooth, 1 dart, 2 crease, 3 corner (vertex sharpness > 0 or 3+ sharp edges)."""
    return np.where((vertex_sharpness > 0) | (sharp_edges > 2), 3, sharp_edges)


def child_edge_sharpness(topo: Topology) -> np.ndarray:
    """Sharpness of the two children of every edge: ``(e, 2)``, column ``a`` the child at ``E[:, a]``.

    ``'uniform'``: ``s - 1`` (0 at or below 1). ``'chaikin'`` (OpenSubdiv's
    ``SubdivideEdgeSharpnessAtVertex``): at an end vertex with other
    semi-sharp edges, ``3/4 s + 1/4`` their mean sharpness, minus 1.
    Infinitely sharp edges stay infinitely sharp; smooth edges stay smooth.
    """
    s, E = topo.sharpness, topo.E
    out = np.repeat(_decremented(s)[:, None], 2, axis=1)
    if topo.crease_method != "chaikin":
        return out
    semi = np.isfinite(s) & (s > 0)
    ends = E.T.ravel()                                      # end a of every edge, a = 0 then 1
    count = np.bincount(ends, weights=np.tile(semi, 2), minlength=topo.n)
    s_semi = np.where(semi, s, 0.0)
    total = np.bincount(ends, weights=np.tile(s_semi, 2), minlength=topo.n)
    for a in (0, 1):
        v = E[:, a]
        others = count[v] - 1
        mean = (total[v] - s_semi) / np.maximum(others, 1)
        blended = 0.75 * s_semi + 0.25 * mean - 1.0
        chaikin = semi & (others > 0)
        out[chaikin, a] = np.maximum(blended[chaikin], 0.0)
    return out


def _vertex_masks(topo: Topology, child: np.ndarray):
    """Vertex-point rows ``(centre weight (n,), neighbour weight of every edge end (2, e))`` (OpenSubdiv's rules).

    The parent rule's mask (smooth for smooth and dart vertices, crease
    ``3/4, 1/8, 1/8``, corner ``1``); where the child's rule differs (a
    semi-sharp vertex or edge decayed), blended with the child rule's mask
    by OpenSubdiv's ``ComputeFractionalWeightAtVertex``: the mean parent
    sharpness of the vertex and edges that become smooth, at most 1.
    """
    n, E, s = topo.n, topo.E, topo.sharpness
    ends = E.T.ravel()
    val = np.bincount(ends, minlength=n)
    beta = np.where(val > 0, loop_beta(np.maximum(val, 1)), 0.0)
    vs = topo.vertex_sharpness
    vs_child = _decremented(vs)
    s_end = np.concatenate([s, s])                          # parent sharpness at each edge end
    c_end = child.T.ravel()                                 # child sharpness at each edge end
    p_rule = _rule(vs, np.bincount(ends, weights=s_end > 0, minlength=n).astype(np.int64))
    c_rule = _rule(vs_child, np.bincount(ends, weights=c_end > 0, minlength=n).astype(np.int64))

    def mask(rule, sharp_end):
        smooth = rule <= 1
        centre = np.where(smooth, 1.0 - val * beta, np.where(rule == 2, 0.75, 1.0))
        nb = np.where(smooth[ends], beta[ends], 0.0) + np.where((rule[ends] == 2) & sharp_end, 0.125, 0.0)
        return centre, nb

    centre, nb = mask(p_rule, s_end > 0)
    blend = (p_rule >= 2) & (c_rule != p_rule)
    if blend.any():
        if topo.crease_method == "chaikin":
            goes = (s_end > 0) & (c_end <= 0)
        else:
            goes = (s_end > 0) & (s_end <= 1.0)
        v_goes = (vs > 0) & (vs_child <= 0)
        count = np.bincount(ends, weights=goes, minlength=n) + v_goes
        total = np.bincount(ends, weights=np.where(goes, s_end, 0.0), minlength=n) + np.where(v_goes, vs, 0.0)
        w = np.where(blend, np.minimum(total / np.maximum(count, 1), 1.0), 1.0)
        w[blend & (count == 0)] = 0.0
        c_centre, c_nb = mask(c_rule, c_end > 0)
        centre = w * centre + (1.0 - w) * c_centre
        nb = w[ends] * nb + (1.0 - w[ends]) * c_nb
    return centre, nb


def subdivide_topology(topo: Topology):
    """Subdivide a validated mesh once, with OpenSubdiv's crease model.

    Parameters
    ----------
    topo : Topology
        Connectivity and crease model of the coarse mesh.

    Returns
    -------
    S : scipy.sparse.csr_matrix, shape ``(n + e, n)``, float64
        ``V_fine = S @ V``; fine vertex ``n + i`` is the new vertex of edge ``i``.
    fine : Topology
        Topology of the fine mesh: child edges with their decayed sharpness
        (:func:`child_edge_sharpness`), vertex sharpness decremented, holes inherited.

    Notes
    -----
    Edge point: smooth ``3/8 (a + b) + 1/8 (c + d)``; midpoint where the edge
    is infinitely sharp or both children stay sharp; a semi-sharp edge whose
    child point is not a crease blends the two with weight ``s`` on the
    midpoint (OpenSubdiv's ``ComputeEdgeVertexMask``). Vertex points: see
    :func:`_vertex_masks`.

    Examples
    --------
    >>> from mi_loop.mesh.halfedge import Topology
    >>> S, fine = subdivide_topology(Topology.build(np.array([[0, 1, 2]]), 3))
    >>> S.shape, fine.F.shape
    ((6, 3), (4, 3))
    """
    F, n, E = topo.F, topo.n, topo.E
    e = len(E)
    s = topo.sharpness
    child = child_edge_sharpness(topo)

    centre, nb = _vertex_masks(topo, child)
    vidx = np.arange(n)
    rows, cols, vals = [vidx], [vidx], [centre]
    ends, other = E.T.ravel(), E[:, ::-1].T.ravel()
    keep = nb != 0
    rows.append(ends[keep])
    cols.append(other[keep])
    vals.append(nb[keep])

    # Edge points: opposite vertices from the two incident faces.
    opp = np.full((e, 2), -1, dtype=np.int64)
    fe = topo.face_edge
    for c in range(3):
        eid = fe[:, c]
        o = F[:, (c + 2) % 3]
        forward = F[:, c] < F[:, (c + 1) % 3]
        opp[eid[forward], 0] = o[forward]
        opp[eid[~forward], 1] = o[~forward]
    crease_child = np.isinf(s) | (child > 0).all(1)
    w_mid = np.where(s <= 0, 0.0, np.where(crease_child, 1.0, s))   # OpenSubdiv: unclamped s
    new = n + np.arange(e)
    for a in (0, 1):
        rows.append(new)
        cols.append(E[:, a])
        vals.append(0.5 * w_mid + 0.375 * (1.0 - w_mid))
    face_w = 0.125 * (1.0 - w_mid)
    on = face_w != 0
    for a in (0, 1):
        rows.append(new[on])
        cols.append(opp[on, a])
        vals.append(face_w[on])

    S = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n + e, n))

    a, b, c = F[:, 0], F[:, 1], F[:, 2]
    ab, bc, ca = n + fe[:, 0], n + fe[:, 1], n + fe[:, 2]
    F_fine = np.stack([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                       np.stack([ca, bc, c], 1), np.stack([bc, ca, ab], 1)], 1).reshape(-1, 3)

    child[topo.boundary] = 0.0      # boundaries are re-detected from the fine faces
    k0, k1 = child[:, 0] > 0, child[:, 1] > 0
    E_c = np.concatenate([np.stack([E[k0, 0], new[k0]], 1), np.stack([new[k1], E[k1, 1]], 1)])
    s_c = np.concatenate([child[k0, 0], child[k1, 1]])
    vs = _decremented(topo.vertex_sharpness)
    sharp_v = np.flatnonzero(vs > 0)
    fine = Topology.build(F_fine, n + e, (E_c, s_c) if len(E_c) else None,
                          (sharp_v, vs[sharp_v]) if len(sharp_v) else None, "edge_only", topo.crease_method)
    fine.hole = np.repeat(topo.hole, 4)
    return S, fine


def subdivision_matrix(F, n_vertices: int, creases=None, *, corners=None, boundary: str = "edge_and_corner",
                       crease_method: str = "uniform"):
    """Return the matrix of one Loop subdivision step and the fine faces (OpenSubdiv's crease model).

    Parameters
    ----------
    F : (m, 3) int numpy array
        Triangle faces of a manifold, consistently oriented mesh (boundaries allowed).
    n_vertices : int
        Number of control vertices ``n``.
    creases : None, (c, 2) int numpy array, or tuple ``(E, sharpness)``
        Crease edges given by vertex pairs; without sharpness they are
        infinitely sharp, otherwise any sharpness ``>= 0`` as OpenSubdiv
        defines it: semi-sharp rules while it lasts, a fractional part blends
        the sharp and smooth rules at the last step, 10 or more (or ``inf``)
        is infinitely sharp.
    corners : None, (c,) int numpy array, or tuple ``(vertex_ids, sharpness)``
        Vertex sharpness (OpenSubdiv's corner tags): the corner rule while it
        lasts, decremented by one a step; without sharpness infinitely sharp.
    boundary : {'edge_and_corner', 'edge_only', 'none'}
        OpenSubdiv's boundary interpolation: boundary edges are always
        infinitely sharp; ``'edge_and_corner'`` (default) also pins boundary
        vertices of one face; under ``'none'`` the faces at a boundary vertex
        whose boundary edges are not given as infinitely sharp creases are
        holes of the limit surface (still subdivided here, but
        :func:`mi_loop.limit_matrix` refuses samples on them).
    crease_method : {'uniform', 'chaikin'}
        How semi-sharp creases decay: ``s - 1`` a step, or OpenSubdiv's
        Chaikin rule (``3/4 s + 1/4`` the mean of the other semi-sharp edges
        at the end vertex, minus 1).

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
        For an invalid mesh or crease model (the message names the offending element).

    Examples
    --------
    >>> import numpy as np, mi_loop
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> S, F_fine = mi_loop.subdivision_matrix(F, 4)
    >>> S.shape, F_fine.shape
    ((10, 4), (16, 3))
    >>> np.allclose(S.sum(axis=1), 1.0)
    True
    >>> S, _ = mi_loop.subdivision_matrix(F, 4, corners=[0])   # an infinitely sharp corner stays put
    >>> S[0].toarray().round(6).tolist()
    [[1.0, 0.0, 0.0, 0.0]]
    """
    topo = sharp_topology(F, n_vertices, "subdivision_matrix", creases, corners, boundary, crease_method)
    S, fine = subdivide_topology(topo)
    return S, fine.F
