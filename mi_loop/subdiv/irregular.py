"""Exact evaluation next to an irregular vertex by powers of the local subdivision matrix.

Around a face ``g = (v, r_i, r_j)`` whose only irregular corner is ``v`` (true
after one subdivision step), one Loop step maps the patch points ``P(g)`` to
the patch points of the corner child ``P(g')`` by a fixed matrix ``A`` (Stam
1998; the ``N + 6`` points for an interior vertex of valence ``N``; fewer on a
crease or boundary sector). The three other children are regular patches:
``E_k`` maps ``P(g)`` to their 12 box-spline points. A point at depth ``m``
(``2^-(m+1) < s + t <= 2^-m``) in child ``k`` of the ``m``-th corner child is

    x(s, t) = b(s', t') E_k A^m P = pi^T P + b(s', t') E_k B^m P,

with ``pi`` the limit mask (left eigenvector of ``A`` for eigenvalue 1) and
``B = A - 1 pi^T``, whose powers decay, so derivatives keep full relative
precision at any depth. No eigenvectors are needed: valence 3 (defective
``A``), creases, corners and boundaries are all handled the same way. ``A`` and
``E_k`` are read off the subdivision matrix of the next level at one
representative face per local configuration; only the faces around the
representatives are subdivided for that (:func:`build_locals`). Samples in
such faces are grouped by configuration, child and depth, and their rows
written, by :class:`IrregularSamples`.
"""
from __future__ import annotations

import numpy as np

from mi_loop.mesh.halfedge import Topology
from mi_loop.subdiv.boxspline import PRODUCT_ROWS, box_basis, box_rows
from mi_loop.subdiv.patches import irregular_points, phantom_matrices, stam_points
from mi_loop.subdiv.subdivision import subdivide_topology

__all__ = ["MAX_DEPTH", "IrregularSamples", "LocalMatrices", "build_local", "build_locals"]

#: Depth below which a point is taken as the vertex itself (2^-60 ~ 1e-18).
MAX_DEPTH = 60


class LocalMatrices:
    """Matrices of one local configuration (signature).

    Parameters
    ----------
    A : (K, K) float64 numpy array
        One Loop step on the ``K`` patch points: ``P(g') = A P(g)``.
    E : (3, 12, K) float64 numpy array
        The 12 box-spline points of the three regular children (corner
        ``r_i``, corner ``r_j``, middle), phantom points included.
    tangents : bool
        Compute ``T`` now (else the caller sets it, see :func:`build_locals`).

    Attributes
    ----------
    pi : (K,) float64
        Limit mask of the irregular vertex over the ``K`` patch points.
    G : (3, MAX_DEPTH + 1, 12, K) float64
        ``E_k B^m`` for the children ``k`` = corner ``r_i``, corner ``r_j``, middle.
    B : (K, K) float64
        ``A - 1 pi^T``.
    r_st : (2, K) float64
        ``d/ds`` and ``d/dt`` at the vertex, before any step (seeds of ``T``).
    T : (2, K) float64
        Orthonormal rows spanning the limit tangent plane at the vertex, in
        the orientation of ``s x t`` (see :func:`_tangent_pairs`); set by
        :func:`build_locals` when ``tangents`` is False.
    """

    def __init__(self, A: np.ndarray, E: np.ndarray, tangents: bool = True):
        K = len(A)
        w, Vl = np.linalg.eig(A.T)
        i1 = np.argmin(np.abs(w - 1.0))
        pi = np.real(Vl[:, i1])
        pi = pi / pi.sum()
        # Refine pi by power iteration on the stochastic matrix (exact fixed point).
        for _ in range(4):
            pi = pi @ A
        self.pi = pi
        B = A - np.outer(np.ones(K), pi)
        G = np.empty((3, MAX_DEPTH + 1, 12, K))
        Bm = np.eye(K) - np.outer(np.ones(K), pi)
        for m in range(MAX_DEPTH + 1):
            np.matmul(E, Bm, out=G[:, m])
            Bm = Bm @ B
        self.G = G
        self.B = B
        self.r_st = np.stack([_R_S @ E[0], _R_T @ E[1]])
        if tangents:
            self.T = _tangent_pairs([self.r_st], [B])[0]


#: d/ds and d/dt of the box-spline basis at the corner (0, 0) of a child patch.
_R_S, _R_T = box_basis(np.zeros((1, 2)), "u")[0], box_basis(np.zeros((1, 2)), "v")[0]


def _tangent_pairs(R: list, Bs: list, steps: int = 240) -> list:
    """Rows spanning the limit tangent plane at the vertex, with the orientation of ``s x t``.

    The derivative rows at depth ``m`` are ``r B^m``; their cross product is
    dominated by the pair of slowest-decaying modes they excite (which need not
    be the two edge directions: at a dart or crease vertex both rows can tend
    to the same dominant mode). Subspace iteration on the pair with an
    orientation-preserving Gram-Schmidt step (positive triangular factor)
    converges to that plane at rate ``|lambda_3 / lambda_2|`` and keeps the sign
    of the normal ``cross(T_s V, T_t V)``.

    ``R[i]`` (2, K_i) holds the rows ``(r_s, r_t)`` of configuration ``i`` and
    ``Bs[i]`` its ``B``; all configurations iterate together (zero-padded to
    the largest ``K``, which changes no value). Returns the ``(2, K_i)`` pairs.
    """
    K = max(len(B) for B in Bs)
    Y = np.zeros((len(Bs), 2, K))
    Bp = np.zeros((len(Bs), K, K))
    for i, (r, B) in enumerate(zip(R, Bs)):
        Y[i, :, :len(B)] = r
        Bp[i, :len(B), :len(B)] = B
    for _ in range(steps):
        Y = Y @ Bp
        Y[:, 0] /= np.sqrt(np.einsum("ij,ij->i", Y[:, 0], Y[:, 0]))[:, None]
        Y[:, 1] -= np.einsum("ij,ij->i", Y[:, 1], Y[:, 0])[:, None] * Y[:, 0]
        Y[:, 1] /= np.sqrt(np.einsum("ij,ij->i", Y[:, 1], Y[:, 1]))[:, None]
    return [Y[i, :, :len(B)].copy() for i, B in enumerate(Bs)]


def build_locals(topo, faces, rots, max_valence: int) -> list:
    """Build the :class:`LocalMatrices` of faces ``faces[i]``, rotated so that ``v = F[faces[i], rots[i]]``.

    The next level is subdivided only around these faces: every row that
    :func:`build_local` reads depends on the faces incident to the vertices
    next to ``(v, r_i, r_j)``, and those are all kept (see :func:`_neighbourhood`).

    Parameters
    ----------
    topo : Topology
        Connectivity of the level that holds the faces.
    faces, rots : (c,) int numpy arrays
        Faces with exactly one irregular corner, and which corner (0, 1, 2).
    max_valence : int
        Largest valence in ``topo``.

    Returns
    -------
    list of LocalMatrices
        One per face, in order.
    """
    if len(faces) == 0:
        return []
    sub, sub_faces = _neighbourhood(topo, np.asarray(faces, dtype=np.int64))
    S_next, fine = subdivide_topology(sub)
    locs = [build_local(sub, fine, S_next, int(g), int(r), max_valence, tangents=False)
            for g, r in zip(sub_faces, rots)]
    for loc, T in zip(locs, _tangent_pairs([loc.r_st for loc in locs], [loc.B for loc in locs])):
        loc.T = T
    return locs


def _neighbourhood(topo: Topology, faces: np.ndarray):
    """The faces incident to vertices within one edge of ``faces``, as a mesh of their own.

    Vertex rules need every face at the vertex and edge rules both faces at
    the edge, so the subdivision rows of the vertices of ``faces``, of their
    edge points and of the edge points of the faces around them are those of
    ``topo``, and so are the sharp edges that the ring walks stop at.
    Returns the sub-mesh :class:`Topology` (creases kept) and the ids of
    ``faces`` in it.
    """
    F, n = topo.F, topo.n
    near = np.zeros(n, dtype=bool)
    near[F[faces].ravel()] = True
    near[F[near[F].any(1)].ravel()] = True
    keep = np.flatnonzero(near[F].any(1))
    vid = np.full(n, -1, dtype=np.int64)
    used = np.unique(F[keep].ravel())
    vid[used] = np.arange(len(used))
    edges = np.unique(topo.face_edge[keep].ravel())
    edges = edges[(topo.sharpness[edges] > 0) & ~topo.boundary[edges]]
    creases = (vid[topo.E[edges]], topo.sharpness[edges]) if len(edges) else None
    vs = topo.vertex_sharpness[used]
    sharp_v = np.flatnonzero(vs > 0)
    corners = (sharp_v, vs[sharp_v]) if len(sharp_v) else None
    # the vertex sharpness as given: the sub-mesh's own boundary vertices of one face are not corners
    sub = Topology.build(vid[F[keep]], len(used), creases, corners, "edge_only", topo.crease_method)
    return sub, np.searchsorted(keep, faces)


def build_local(topo, fine_topo, S_next, g: int, rot: int, max_valence: int, tangents: bool = True):
    """Build the :class:`LocalMatrices` of face ``g``, rotated so that ``v = F[g, rot]``.

    Parameters
    ----------
    topo : Topology
        Connectivity of the level that holds face ``g``.
    fine_topo : Topology
        Connectivity of the next level.
    S_next : scipy.sparse.csr_matrix, shape ``(fine_topo.n, topo.n)``
        The subdivision step between them.
    g : int
        A face with exactly one irregular corner.
    rot : int
        Which corner of ``g`` (0, 1 or 2) is irregular.
    max_valence : int
        Largest valence in ``topo``.
    tangents : bool
        Also compute :attr:`LocalMatrices.T` (:func:`build_locals` computes
        them for all configurations at once).

    Returns
    -------
    LocalMatrices

    Raises
    ------
    RuntimeError
        If the corner child's patch does not repeat the parent's (an internal
        error: never for a mesh that :func:`~mi_loop.mesh.topology.validate_faces`
        accepts).
    """
    n = topo.n
    P = irregular_points(topo, np.array([3 * g + rot]), max_valence)[0][0]
    present = P[P >= 0]
    # Children of the rotated face in the fine mesh (ids of the new vertices).
    v, ri, rj = (topo.F[g, (rot + c) % 3] for c in range(3))
    m_vi, m_ij, m_jv = (n + topo.face_edge[g, (rot + c) % 3] for c in range(3))
    Pc = irregular_points(fine_topo, np.array([_child_half_edge(fine_topo, g, v, m_vi)]), max_valence)[0][0]
    if not np.array_equal(Pc >= 0, P >= 0):
        raise RuntimeError(f"build_local(): internal error: the corner child of face {g} is not self-similar")
    col = np.full(topo.n, -1, dtype=np.int64)
    col[present] = np.arange(len(present))
    A = _rows(S_next, Pc[Pc >= 0], col)
    kids = [(m_vi, ri), (m_jv, m_ij), (m_ij, m_jv)]  # first edge of the children at ri, at rj, middle
    E = []
    for a, b in kids:
        Q = stam_points(fine_topo, np.array([_child_half_edge(fine_topo, g, a, b)]))
        pid, Phis = phantom_matrices(Q)
        T = np.zeros((12, len(present)))
        ok = Q[0] >= 0
        T[ok] = _rows(S_next, Q[0][ok], col)
        E.append(Phis[pid[0]] @ T)
    return LocalMatrices(A, np.stack(E), tangents)


def _child_half_edge(fine_topo, g: int, a: int, b: int) -> int:
    """Half-edge ``a -> b`` of a child of face ``g`` (children are fine faces ``4 g .. 4 g + 3``)."""
    F = fine_topo.F[4 * g:4 * g + 4]
    f, c = np.nonzero((F == a) & (np.roll(F, -1, axis=1) == b))
    return 3 * (4 * g + int(f[0])) + int(c[0])


def _rows(S, idx, col):
    """Dense rows ``S[idx]`` over the columns ``col`` (``(n,)`` int, -1 outside the patch; all others must be zero)."""
    starts, stops = S.indptr[idx], S.indptr[np.asarray(idx) + 1]
    counts = stops - starts
    entry = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts - starts, counts)
    c = col[S.indices[entry]]
    if (c < 0).any():
        raise RuntimeError("build_local(): internal error: a subdivision row leaves the patch")
    out = np.zeros((len(idx), int(col.max()) + 1))
    out[np.repeat(np.arange(len(idx)), counts), c] = S.data[entry]
    return out


def _corner_child(s, t):
    """Depth ``m``, child (0 at ``r_i``, 1 at ``r_j``, 2 middle) and its parameters, near the irregular vertex.

    ``m`` is the depth with ``2^-(m+1) < s + t <= 2^-m``, read off the binary
    exponent; ``at_vertex`` marks ``s + t <= 2^-MAX_DEPTH``. Returns
    ``at_vertex, m, child, cu, cv, factor`` with ``factor`` the derivative
    factor of the child's parameters.
    """
    st = s + t
    at_vertex = st <= 2.0 ** -MAX_DEPTH
    mant, e = np.frexp(np.maximum(st, 2.0 ** -MAX_DEPTH))
    m = np.clip((mant == 0.5) - e, 0, MAX_DEPTH)
    cu, cv = np.ldexp(s, m + 1), np.ldexp(t, m + 1)     # 2 s 2^m, 2 t 2^m: exact
    c0 = cu >= 1.0
    c1 = cv >= 1.0
    c1 &= ~c0
    c2 = ~(c0 | c1)
    cu -= c0
    cv -= c1
    np.subtract(1.0, cu, out=cu, where=c2)
    np.subtract(1.0, cv, out=cv, where=c2)
    child = c1 + 2 * c2
    factor = np.ldexp(np.where(c2, -2.0, 2.0), m)
    return at_vertex, m, child, np.clip(cu, 0.0, 1.0, out=cu), np.clip(cv, 0.0, 1.0, out=cv), factor


#: d/du and d/dv in terms of d/ds and d/dt, by the irregular corner: (s, t) are
#: the barycentrics (rot + 1, rot + 2) of (1 - u - v, u, v).
_DS = {"u": (1.0, 0.0, -1.0), "v": (0.0, 1.0, -1.0)}
_DT = {"u": (0.0, -1.0, 1.0), "v": (1.0, -1.0, 0.0)}
_N_LOCAL = 3 * (MAX_DEPTH + 1) + 1      # (child, depth) pairs and the vertex itself


class IrregularSamples:
    """Samples in faces with an irregular corner, sorted by (configuration, corner, child, depth).

    Parameters
    ----------
    h : Hierarchy
        The :class:`~mi_loop.subdiv.hierarchy.Hierarchy` that holds the level-``L`` faces.
    rows : (k,) int numpy array
        Index of every sample among all samples (its row in the padded weights).
    faces : (k,) int64 numpy array
        Level-``L`` face of every sample; each has an irregular corner.
    u, v : (k,) float64 numpy arrays
        Parameters in those faces.
    scale : (k,) float64 numpy array
        Derivative factor of every sample's level-``L`` parameters.

    Attributes
    ----------
    rows : (k,) int numpy array
        The sample indices, sorted by (configuration, corner, child, depth).
    cu, cv : (k,) float64 numpy arrays
        Parameters in the regular child patch, in that order.
    scale : (k,) float64 numpy array
        The samples' own derivative factors, in that order.
    groups : list of tuples
        The runs ``(signature, rot, child or -1 at the vertex, depth, factor,
        start, stop)`` that share one matrix and one derivative factor.
    """

    def __init__(self, h, rows, faces, u, v, scale):
        rot = h.irr_corner[faces]
        w = 1 - u - v
        r1, r2 = rot == 1, rot == 2                 # (s, t) = (u, v), (v, w), (w, u)
        s = np.where(r1, v, np.where(r2, w, u))
        t = np.where(r1, w, np.where(r2, u, v))
        at_vertex, m, child, cu, cv, factor = _corner_child(s, t)
        key = (h.irr_sig[faces] * 3 + rot) * _N_LOCAL + np.where(at_vertex, _N_LOCAL - 1,
                                                                   child * (MAX_DEPTH + 1) + m)
        used = np.zeros(len(h.locals) * 3 * _N_LOCAL, dtype=bool)
        used[key] = True
        rank = (np.cumsum(used) - 1).astype(np.int16 if used.sum() < 2 ** 15 else np.int64)[key]
        order = np.argsort(rank, kind="stable")
        self.rows, self.cu, self.cv, self.scale = rows[order], cu[order], cv[order], scale[order]
        factor = factor[order]
        counts = np.bincount(rank)
        stops = np.cumsum(counts)
        self.groups = []
        for k, start, stop in zip(np.flatnonzero(used), stops - counts, stops):
            qr, local = divmod(int(k), _N_LOCAL)
            c, d = divmod(local, MAX_DEPTH + 1) if local < _N_LOCAL - 1 else (-1, 0)
            self.groups.append((qr // 3, qr % 3, c, d, float(factor[start]), int(start), int(stop)))

    def apply(self, h, W: dict):
        """Write the rows of these samples into the padded weights ``W`` (``{derivative: (k, width)}``)."""
        names = list(W)
        width = W[names[0]].shape[1]
        derivs = [d for d in names if d is not None]
        need = ([None] if None in W else []) + (["u", "v"] if derivs else [])
        buf = np.empty((PRODUCT_ROWS, width))
        for q, rot, c, depth, f, a, e in self.groups:
            loc = h.locals[q]
            K = len(loc.pi)
            if c < 0:                      # at the vertex: the limit mask and the tangent-plane rows
                rows = self.rows[a:e]
                for d in names:
                    W[d][rows, K:] = 0.0
                    W[d][rows, :K] = loc.pi if d is None else \
                        self.scale[a:e, None] * (_DS[d][rot] * loc.T[0] + _DT[d][rot] * loc.T[1])
                continue
            G = loc.G[c, depth]
            for a0 in range(a, e, PRODUCT_ROWS):
                e0 = min(e, a0 + PRODUCT_ROWS)
                rows = self.rows[a0:e0]
                # Evaluated here, block by block, whatever W holds: the rows are then the same bits
                # whichever derivatives are asked for (box_rows' products depend on the batch).
                B = box_rows(self.cu[a0:e0], self.cv[a0:e0], need, 12, self.scale[a0:e0])
                out = buf[:e0 - a0]
                out[:, K:] = 0.0
                if None in W:
                    np.add(B[None] @ G, loc.pi, out=out[:, :K])
                    W[None][rows] = out
                if derivs:
                    X, Y = B["u"] @ G, B["v"] @ G     # d/ds and d/dt, up to the factor
                    for d in derivs:
                        ds, dt = f * _DS[d][rot], f * _DT[d][rot]
                        if dt == 0:
                            np.multiply(X, ds, out=out[:, :K])
                        elif ds == 0:
                            np.multiply(Y, dt, out=out[:, :K])
                        else:
                            np.add(ds * X, dt * Y, out=out[:, :K])
                        W[d][rows] = out
