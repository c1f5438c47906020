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
``E_k`` are read off the global subdivision matrix of the next level at one
representative face per local configuration.
"""
from __future__ import annotations

import numpy as np

from .boxspline import box_basis
from .patches import irregular_points, phantom_matrices, stam_points

#: Depth below which a point is taken as the vertex itself (2^-60 ~ 1e-18).
MAX_DEPTH = 60


class LocalMatrices:
    """Matrices of one local configuration (signature).

    Attributes
    ----------
    pi : (K,) float64
        Limit mask of the irregular vertex over the ``K`` patch points.
    G : (3, MAX_DEPTH + 1, 12, K) float64
        ``E_k B^m`` for the children ``k`` = corner ``r_i``, corner ``r_j``, middle.
    T : (2, K) float64
        Unit tangent directions at the vertex along ``s`` and ``t``.
    """

    def __init__(self, A: np.ndarray, E: np.ndarray, crease_tangents=(None, None)):
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
            for k in range(3):
                G[k, m] = E[k] @ Bm
            Bm = Bm @ B
        self.G = G
        ts = _dominant_direction(box_basis(np.zeros((1, 2)), "u")[0] @ E[0], B)
        tt = _dominant_direction(box_basis(np.zeros((1, 2)), "v")[0] @ E[1], B)
        # Along a crease edge the limit is a cubic B-spline curve (or its
        # end at a corner): its tangent is exact and finite; elsewhere the
        # dominant decaying mode gives the direction.
        ts = ts if crease_tangents[0] is None else crease_tangents[0]
        tt = tt if crease_tangents[1] is None else crease_tangents[1]
        self.T = np.stack([ts / np.linalg.norm(ts), tt / np.linalg.norm(tt)])


def _dominant_direction(r: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Direction of ``lim r B^m`` (normalised): the slowest-decaying mode that ``r`` excites.

    A high power of ``B`` (repeated squaring) is a multiple of the spectral
    projector on its dominant modes; when ``r`` does not excite them (e.g. by
    symmetry) they are deflated and the next group is tried.
    """
    Bk = B.copy()
    for _ in range(8):
        X = Bk / np.abs(Bk).max()
        for _ in range(12):
            X = X @ X
            X /= np.abs(X).max()
        y = r @ X
        if np.linalg.norm(y) > 1e-8 * np.linalg.norm(r):
            return y / np.linalg.norm(y)
        rank = np.linalg.matrix_rank(X, tol=1e-8)
        P = X * rank / np.trace(X)
        Bk = Bk - Bk @ P
    raise RuntimeError("_dominant_direction(): no decaying mode is excited")


def build_local(topo, fine_topo, S_next, g: int, rot: int, max_valence: int):
    """Build :class:`LocalMatrices` at face ``g`` (rotated so ``v = F[g, rot]``)."""
    n = topo.n
    f = topo.F[g]
    v, ri, rj = f[rot], f[(rot + 1) % 3], f[(rot + 2) % 3]
    P = irregular_points(topo, np.array([v]), np.array([ri]), np.array([rj]), max_valence)[0]
    present = P[P >= 0]
    # Children of the rotated face in the fine mesh (ids of the new vertices).
    m_vi = n + topo.edge_id(np.array([v]), np.array([ri]))[0]
    m_ij = n + topo.edge_id(np.array([ri]), np.array([rj]))[0]
    m_jv = n + topo.edge_id(np.array([rj]), np.array([v]))[0]
    Pc = irregular_points(fine_topo, np.array([v]), np.array([m_vi]), np.array([m_jv]),
                          max_valence)[0]
    if not np.array_equal(Pc >= 0, P >= 0):
        raise RuntimeError("build_local(): corner child is not self-similar")
    col = {int(p): i for i, p in enumerate(present)}
    A = _rows(S_next, Pc[Pc >= 0], col)
    kids = [(m_vi, ri, m_ij), (m_jv, m_ij, rj), (m_ij, m_jv, m_vi)]  # corner ri, corner rj, middle
    E = []
    for a, b, c in kids:
        Q = stam_points(fine_topo, np.array([a]), np.array([b]), np.array([c]))
        pid, Phis = phantom_matrices(Q)
        T = np.zeros((12, len(present)))
        ok = Q[0] >= 0
        T[ok] = _rows(S_next, Q[0][ok], col)
        E.append(Phis[pid[0]] @ T)
    return LocalMatrices(A, np.stack(E), _crease_tangents(topo, P, v, (ri, rj), col, max_valence))


def _crease_tangents(topo, P, v, ends, col, max_valence):
    """Exact tangent rows along sharp face edges at a crease or corner vertex."""
    kind = topo.vertex_kind()[v]
    sector = P[1:1 + 2 * max_valence]
    sector = sector[sector >= 0]
    sharp_nb = sector[topo.edge_sharp(np.full(len(sector), v), sector)]
    out = []
    for r in ends:
        if kind == 0 or not topo.edge_sharp(np.array([v]), np.array([r]))[0]:
            out.append(None)
            continue
        t = np.zeros(len(col))
        t[col[int(r)]] += 1.0
        if kind == 1:  # B-spline through the two sharp neighbours
            other = [x for x in sharp_nb if x != r]
            if len(other) != 1:
                out.append(None)
                continue
            t[col[int(other[0])]] -= 1.0
        else:  # corner: the curve starts at v
            t[col[int(v)]] -= 1.0
        out.append(t)
    return out


def _rows(S, idx, col):
    """Dense rows ``S[idx]`` over the columns listed in ``col`` (all others must be zero)."""
    sub = S[idx].tocoo()
    out = np.zeros((len(idx), len(col)))
    for r, c, x in zip(sub.row, sub.col, sub.data):
        if int(c) not in col:
            raise RuntimeError("build_local(): subdivision row leaves the patch")
        out[r, col[int(c)]] += x
    return out
