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

from mi_loop.subdiv.boxspline import box_basis
from mi_loop.subdiv.patches import irregular_points, phantom_matrices, stam_points

__all__ = ["MAX_DEPTH", "LocalMatrices", "build_local"]

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

    Attributes
    ----------
    pi : (K,) float64
        Limit mask of the irregular vertex over the ``K`` patch points.
    G : (3, MAX_DEPTH + 1, 12, K) float64
        ``E_k B^m`` for the children ``k`` = corner ``r_i``, corner ``r_j``, middle.
    T : (2, K) float64
        Orthonormal rows spanning the limit tangent plane at the vertex, in
        the orientation of ``s x t`` (see :func:`_tangent_pair`).
    """

    def __init__(self, A: np.ndarray, E: np.ndarray):
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
        self.T = _tangent_pair(box_basis(np.zeros((1, 2)), "u")[0] @ E[0],
                               box_basis(np.zeros((1, 2)), "v")[0] @ E[1], B)


def _tangent_pair(r_s: np.ndarray, r_t: np.ndarray, B: np.ndarray, steps: int = 240) -> np.ndarray:
    """Rows spanning the limit tangent plane at the vertex, with the orientation of ``s x t``.

    The derivative rows at depth ``m`` are ``r B^m``; their cross product is
    dominated by the pair of slowest-decaying modes they excite (which need not
    be the two edge directions: at a dart or crease vertex both rows can tend
    to the same dominant mode). Subspace iteration on the pair with an
    orientation-preserving Gram-Schmidt step (positive triangular factor)
    converges to that plane at rate ``|lambda_3 / lambda_2|`` and keeps the sign
    of the normal ``cross(T_s V, T_t V)``.
    """
    Y = np.stack([r_s, r_t]).astype(np.float64)
    for _ in range(steps):
        Y = Y @ B
        Y[0] /= np.linalg.norm(Y[0])
        Y[1] -= (Y[1] @ Y[0]) * Y[0]
        Y[1] /= np.linalg.norm(Y[1])
    return Y


def build_local(topo, fine_topo, S_next, g: int, rot: int, max_valence: int):
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
        raise RuntimeError(f"build_local(): internal error: the corner child of face {g} is not self-similar")
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
    return LocalMatrices(A, np.stack(E))


def _rows(S, idx, col):
    """Dense rows ``S[idx]`` over the columns listed in ``col`` (all others must be zero)."""
    sub = S[idx].tocoo()
    out = np.zeros((len(idx), len(col)))
    for r, c, x in zip(sub.row, sub.col, sub.data):
        if int(c) not in col:
            raise RuntimeError("build_local(): internal error: a subdivision row leaves the patch")
        out[r, col[int(c)]] += x
    return out
