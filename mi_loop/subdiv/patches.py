"""Patch control points around faces, with creases treated as cuts (NumPy).

An infinitely sharp crease separates the surface on its two sides, so ring
walks stop at sharp edges: a walk around a vertex never crosses a sharp edge.
Points that a regular boundary or crease patch lacks are phantom points,
extrapolated by the parallelogram rule ``x = p + q - r`` (the reflection that
turns the interior Loop rules into the boundary rules).
"""
from __future__ import annotations

import numpy as np

from mi_loop.mesh.halfedge import Topology
from mi_loop.subdiv.boxspline import LATTICE

__all__ = ["corner_regular", "irregular_points", "phantom_matrices", "stam_points"]


def _corners(h: np.ndarray):
    """Next and previous half-edges of the faces of half-edges ``h`` (``3 f + c``)."""
    c = h % 3
    return h - c + (c + 1) % 3, h - c + (c + 2) % 3


def _ring6(topo: Topology, h0: np.ndarray) -> np.ndarray:
    """Walk the one-ring of the tails of half-edges ``h0`` counter-clockwise from their heads.

    The first step goes through the face of ``h0``; later steps cross edges
    and stop at sharp ones; the rest is filled clockwise from the head.
    Returns ``(k, 6)`` int64, -1 where the sector ends.
    """
    T = topo.walk_tables()
    R = np.full((len(h0), 6), -1, dtype=np.int64)
    start = T.head[h0]
    R[:, 0] = start
    R[:, 1] = T.prev_vertex[h0]
    g = np.where(T.prev_sharp[h0], -1, T.ccw[h0])   # tail -> R[:, j - 1], -1 once the walk has stopped
    for j in range(2, 6):
        nxt = T.prev_vertex[g]
        nxt[nxt == start] = -1
        R[:, j] = nxt
        g = np.where(T.prev_sharp[g] | (nxt < 0), -1, T.ccw[g])
        if (g < 0).all():
            break
    g = h0.copy()                                    # tail -> last point filled clockwise
    active = ~T.sharp[h0]
    for j in range(5, 1, -1):
        active &= R[:, j] < 0
        if not active.any():
            break
        g_next = np.where(active, T.cw[g], -1)
        nxt = T.head[g_next]
        active &= (nxt >= 0) & ~(R == nxt[:, None]).any(1)
        R[:, j] = np.where(active, nxt, R[:, j])
        g = np.where(active, g_next, g)
        active &= ~T.sharp[g]
    return R


def stam_points(topo: Topology, h) -> np.ndarray:
    """Return the 12 regular-patch points of the faces of half-edges ``h`` in Stam's order.

    Parameters
    ----------
    topo : Topology
        Mesh connectivity.
    h : (k,) int numpy array
        Half-edge ``a -> b`` (flat corner index ``3 f + c``) of each face
        ``(a, b, c)``, in the face's orientation.

    Returns
    -------
    (k, 12) int64 numpy array
        Vertex ids at the lattice points :data:`~mi_loop.subdiv.boxspline.LATTICE`,
        -1 where the patch lacks the point (a boundary or crease: a phantom
        point, see :func:`phantom_matrices`).

    Examples
    --------
    >>> from mi_loop.mesh.halfedge import Topology
    >>> topo = Topology.build(np.array([[0, 1, 2]]), 3)
    >>> stam_points(topo, np.array([0])).tolist()
    [[-1, -1, -1, 0, -1, -1, 1, 2, -1, -1, -1, -1]]
    """
    h = np.asarray(h, dtype=np.int64)
    h_bc, h_ca = _corners(h)
    ra, rb, rc = _ring6(topo, h), _ring6(topo, h_bc), _ring6(topo, h_ca)
    return np.stack([ra[:, 4], ra[:, 3], ra[:, 5], rc[:, 0], ra[:, 2], rb[:, 3],
                     ra[:, 0], rb[:, 0], rc[:, 4], rb[:, 4], rb[:, 5], rc[:, 3]], axis=1)


_LATTICE_KEY = {tuple(p): i for i, p in enumerate(LATTICE)}
_NEIGH = [(1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1)]


def _phantom_matrix(missing: np.ndarray) -> np.ndarray:
    """``(12, 12)`` matrix ``Phi``: Stam points ``X = Phi @ Y`` from the present slots ``Y``.

    A missing slot ``x`` becomes ``p + q - r`` with ``p, q`` present neighbours
    of ``x`` adjacent to each other and ``r = p + q - x`` present.
    """
    Phi = np.eye(12)
    present = ~missing
    for x in np.flatnonzero(missing):
        Phi[x, x] = 0.0
        X = LATTICE[x]
        found = False
        for d0, d1 in zip(_NEIGH, _NEIGH[1:] + _NEIGH[:1]):
            p = _LATTICE_KEY.get((X[0] + d0[0], X[1] + d0[1]))
            q = _LATTICE_KEY.get((X[0] + d1[0], X[1] + d1[1]))
            r = _LATTICE_KEY.get((X[0] + d0[0] + d1[0], X[1] + d0[1] + d1[1]))
            if None not in (p, q, r) and present[p] and present[q] and present[r]:
                Phi[x, [p, q, r]] += (1.0, 1.0, -1.0)
                found = True
                break
        if not found:
            raise RuntimeError(f"phantom_matrices(): internal error: no phantom rule for slot {x} with missing "
                               f"{missing.tolist()}")
    return Phi


_PHI_CACHE: dict[bytes, np.ndarray] = {}


def phantom_matrices(P: np.ndarray):
    """Group patches by their missing-slot pattern and return each pattern's phantom matrix.

    A missing slot ``x`` becomes ``p + q - r`` with ``p, q`` present neighbours
    of ``x`` adjacent to each other and ``r = p + q - x`` present (the
    parallelogram rule), so the Stam points are ``X = Phi @ Y`` with ``Y`` the
    present slots.

    Parameters
    ----------
    P : (k, 12) int numpy array
        Patch points from :func:`stam_points`, -1 where missing.

    Returns
    -------
    pattern_id : (k,) int64 numpy array
        Pattern of every patch, an index into ``Phis``.
    Phis : (p, 12, 12) float64 numpy array
        The matrix of each pattern (identity for a complete patch).

    Raises
    ------
    RuntimeError
        If a missing slot has no parallelogram rule (never for the patches of
        a mesh that :func:`~mi_loop.mesh.topology.validate_faces` accepts).

    Examples
    --------
    >>> pid, Phis = phantom_matrices(np.array([np.arange(12), [-1] + list(range(11))]))
    >>> pid.tolist(), Phis.shape, bool(np.allclose(Phis[0], np.eye(12)))
    ([0, 1], (2, 12, 12), True)
    """
    missing = P < 0
    codes = missing @ (1 << np.arange(12))
    uniq, pattern_id = np.unique(codes, return_inverse=True)
    Phis = []
    for code in uniq:
        key = int(code).to_bytes(2, "little")
        if key not in _PHI_CACHE:
            _PHI_CACHE[key] = _phantom_matrix((int(code) >> np.arange(12)) & 1 == 1)
        Phis.append(_PHI_CACHE[key])
    return pattern_id, np.stack(Phis)


def corner_regular(topo: Topology, kind: np.ndarray, valence: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Whether the tail of half-edge ``h`` is a regular corner of the face of ``h``.

    Regular: smooth with valence 6, no sharp edge and no vertex sharpness, or a crease vertex
    (exactly two sharp edges) whose sector containing the face has 3 faces.

    Parameters
    ----------
    topo : Topology
        Mesh connectivity.
    kind : (n,) int numpy array
        :meth:`Topology.vertex_kind` of every vertex.
    valence : (n,) int numpy array
        :meth:`Topology.valence` of every vertex.
    h : (k,) int numpy array
        Half-edges (flat corner indices ``3 f + c``): corner ``F[f, c]`` of face ``f``.

    Returns
    -------
    (k,) bool numpy array
    """
    h = np.asarray(h, dtype=np.int64)
    corner = topo.F.ravel()[h]
    regular = (kind[corner] == 0) & (topo.sharp_count()[corner] == 0) & (valence[corner] == 6)
    # A crease sector of 3 faces has 4 points and both ends on sharp edges.
    crease = np.flatnonzero(kind[corner] == 1)
    if len(crease):
        regular[crease] = (_ring6(topo, h[crease]) >= 0).sum(1) == 4
    return regular


def _vertex_sector(topo: Topology, h0: np.ndarray, max_valence: int):
    """Neighbours of the tails of ``h0`` reachable without crossing sharp edges, from the heads.

    Counter-clockwise first (the first step through the face of ``h0``), then
    clockwise. Returns ``(k, 2 max_valence)`` int64 padded with -1, whether the
    edge to each of them is sharp (bool, same shape) and the number of
    counter-clockwise entries ``(k,)``.
    """
    T = topo.walk_tables()
    k = len(h0)
    L = np.full((k, 2 * max_valence), -1, dtype=np.int64)
    sharp = np.zeros(L.shape, dtype=bool)
    start = T.head[h0]
    L[:, 0], sharp[:, 0] = start, T.sharp[h0]
    g = h0.copy()                                    # tail -> L[:, j - 1], -1 once the walk has stopped
    n_ccw = np.ones(k, dtype=np.int64)
    for j in range(1, max_valence):
        nxt = T.prev_vertex[g]
        active = (nxt >= 0) & (nxt != start)
        if not active.any():
            break
        L[:, j] = np.where(active, nxt, -1)
        n_ccw += active
        sharp[:, j] = active & T.prev_sharp[g]
        g = np.where(active & ~T.prev_sharp[g], T.ccw[g], -1)
    last_ccw = L[np.arange(k), n_ccw - 1]
    g = h0.copy()                                    # tail -> L[:, j - 1] (clockwise)
    active = ~T.sharp[h0]
    for j in range(max_valence, 2 * max_valence):
        if not active.any():
            break
        g_next = np.where(active, T.cw[g], -1)
        nxt = T.head[g_next]
        active &= (nxt >= 0) & (nxt != last_ccw) & (nxt != start)
        L[:, j] = np.where(active, nxt, -1)
        g = np.where(active, g_next, g)
        sharp[:, j] = active & T.sharp[g]
        active &= ~T.sharp[g]
    return L, sharp, n_ccw


def irregular_points(topo: Topology, h, max_valence: int):
    """Return the patch points of the faces of half-edges ``h = v -> r_i`` whose corner ``v`` is irregular.

    Parameters
    ----------
    topo : Topology
        Mesh connectivity.
    h : (k,) int numpy array
        Half-edge from the irregular corner ``v`` to the next corner ``r_i``
        of each face ``(v, r_i, r_j)`` (flat corner index ``3 f + c``).
    max_valence : int
        Largest valence in the mesh (pads the sector).

    Returns
    -------
    P : (k, 1 + 2 max_valence + 5) int64 numpy array
        ``[v, sector of v from r_i (counter-clockwise, then clockwise, padded),
        3 outer points of r_i, 2 outer points of r_j]``, -1 where absent.
    sharp : (k, 1 + 2 max_valence + 5) bool numpy array
        Whether the edge from ``v`` to the sector point is sharp (False outside the sector).
    """
    h = np.asarray(h, dtype=np.int64)
    h_ij, h_jv = _corners(h)
    L, L_sharp, _ = _vertex_sector(topo, h, max_valence)
    Ri, Rj = _ring6(topo, h_ij), _ring6(topo, h_jv)
    P = np.concatenate([topo.F.ravel()[h][:, None], L, Ri[:, 3:6], Rj[:, 3:5]], axis=1)
    sharp = np.zeros(P.shape, dtype=bool)
    sharp[:, 1:1 + 2 * max_valence] = L_sharp
    return P, sharp
