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


def _ring6(topo: Topology, centre: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Walk the one-ring of ``centre`` counter-clockwise from ``start``.

    The first step goes through the face ``(centre, start, x)``; later steps
    cross edges and stop at sharp ones; the rest is filled clockwise from
    ``start``. Returns ``(k, 6)`` int64, -1 where the sector ends.
    """
    k = len(centre)
    R = np.full((k, 6), -1, dtype=np.int64)
    R[:, 0] = start
    R[:, 1] = topo.next_ccw(centre, start)
    for j in range(2, 6):
        prev = R[:, j - 1]
        ok = (prev >= 0) & ~topo.edge_sharp(centre, np.maximum(prev, 0))
        nxt = np.where(ok, topo.next_ccw(centre, np.maximum(prev, 0)), -1)
        R[:, j] = np.where(nxt == start, -1, nxt)
    cur = start.copy()
    active = ~topo.edge_sharp(centre, start)
    for j in range(5, 1, -1):
        active &= R[:, j] < 0
        nxt = np.where(active, topo.next_cw(centre, cur), -1)
        active &= nxt >= 0
        seen = (R == nxt[:, None]).any(1)
        active &= ~seen
        R[:, j] = np.where(active, nxt, R[:, j])
        cur = np.where(active, nxt, cur)
        active &= ~topo.edge_sharp(centre, np.maximum(cur, 0))
    return R


def stam_points(topo: Topology, a, b, c) -> np.ndarray:
    """Return the 12 regular-patch points of faces ``(a, b, c)`` in Stam's order.

    Parameters
    ----------
    topo : Topology
        Mesh connectivity.
    a, b, c : (k,) int numpy arrays
        Corners of each face, in the face's orientation.

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
    >>> stam_points(topo, np.array([0]), np.array([1]), np.array([2])).tolist()
    [[-1, -1, -1, 0, -1, -1, 1, 2, -1, -1, -1, -1]]
    """
    ra, rb, rc = _ring6(topo, a, b), _ring6(topo, b, c), _ring6(topo, c, a)
    P = np.stack([ra[:, 4], ra[:, 3], ra[:, 5], a, ra[:, 2], rb[:, 3],
                  b, c, rc[:, 4], rb[:, 4], rb[:, 5], rc[:, 3]], axis=1)
    return P


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


def corner_regular(topo: Topology, kind: np.ndarray, valence: np.ndarray,
                   corner: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    """Whether ``corner`` is regular for the face whose next corner is ``nxt``.

    Regular: smooth with valence 6 and no sharp edge, or a crease vertex
    (exactly two sharp edges) whose sector containing the face has 3 faces.

    Parameters
    ----------
    topo : Topology
        Mesh connectivity.
    kind : (n,) int numpy array
        :meth:`Topology.vertex_kind` of every vertex.
    valence : (n,) int numpy array
        :meth:`Topology.valence` of every vertex.
    corner, nxt : (k,) int numpy arrays
        A face corner and the next corner of the same face.

    Returns
    -------
    (k,) bool numpy array
    """
    sc = topo.sharp_count()[corner]
    smooth_reg = (sc == 0) & (valence[corner] == 6)
    R = _ring6(topo, corner, nxt)
    sector_pts = (R >= 0).sum(1)
    # A crease sector of 3 faces has 4 points and both ends on sharp edges.
    crease_reg = (kind[corner] == 1) & (sector_pts == 4)
    return smooth_reg | crease_reg


def _vertex_sector(topo: Topology, v: np.ndarray, start: np.ndarray, max_valence: int):
    """Neighbours of ``v`` reachable without crossing sharp edges, from ``start``.

    Counter-clockwise first (the first step through face ``(v, start, x)``),
    then clockwise. Returns ``(k, 2 max_valence)`` int64 padded with -1 and the
    number of counter-clockwise entries ``(k,)``.
    """
    k = len(v)
    L = np.full((k, 2 * max_valence), -1, dtype=np.int64)
    L[:, 0] = start
    cur = start.copy()
    active = np.ones(k, bool)
    n_ccw = np.ones(k, dtype=np.int64)
    for j in range(1, max_valence):
        nxt = np.where(active, topo.next_ccw(v, cur), -1)
        active &= (nxt >= 0) & (nxt != start)
        L[:, j] = np.where(active, nxt, -1)
        n_ccw += active
        cur = np.where(active, nxt, cur)
        active &= ~topo.edge_sharp(v, cur)
    last_ccw = L[np.arange(k), n_ccw - 1]
    cur = start.copy()
    active = ~topo.edge_sharp(v, start)
    for j in range(max_valence, 2 * max_valence):
        nxt = np.where(active, topo.next_cw(v, cur), -1)
        active &= (nxt >= 0) & (nxt != last_ccw) & (nxt != start)
        L[:, j] = np.where(active, nxt, -1)
        cur = np.where(active, nxt, cur)
        active &= ~topo.edge_sharp(v, cur)
    return L, n_ccw


def irregular_points(topo: Topology, v, ri, rj, max_valence: int) -> np.ndarray:
    """Return the patch points of faces ``(v, ri, rj)`` whose corner ``v`` is irregular.

    Parameters
    ----------
    topo : Topology
        Mesh connectivity.
    v, ri, rj : (k,) int numpy arrays
        The irregular corner and the two others, in the face's orientation.
    max_valence : int
        Largest valence in the mesh (pads the sector).

    Returns
    -------
    (k, 1 + 2 max_valence + 5) int64 numpy array
        ``[v, sector of v from ri (counter-clockwise, then clockwise, padded),
        3 outer points of ri, 2 outer points of rj]``, -1 where absent.
    """
    L, _ = _vertex_sector(topo, v, ri, max_valence)
    Ri = _ring6(topo, ri, rj)
    Rj = _ring6(topo, rj, v)
    return np.concatenate([v[:, None], L, Ri[:, 3:6], Rj[:, 3:5]], axis=1)
