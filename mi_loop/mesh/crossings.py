"""Where a triangle mesh passes through itself: pairs of triangles sharing no vertex that intersect.

A fast test for the fitting loop's step guard (:class:`~mi_loop.fitting.guard.FoldGuard`),
called at every step: a uniform grid on the triangles' bounding boxes finds the
pairs close enough to meet, and Numba tests each pair exactly, edge by edge. The
metric :func:`mi_loop.metrics.self_intersections` (MeshLab) also counts
neighbours that share one vertex; the guard leaves those to its normal tests.
"""
from __future__ import annotations

import numpy as np

from mi_loop._numba import numba
from mi_loop.mesh.checks import check_triangles

__all__ = ["crossing_among", "crossing_faces", "crossing_pairs", "near_pairs"]


@numba.njit(cache=True, inline="always")
def _orient(a, b, c, d):
    """Six times the signed volume of the tetrahedron (a, b, c, d)."""
    ux, uy, uz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    vx, vy, vz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    wx, wy, wz = d[0] - a[0], d[1] - a[1], d[2] - a[2]
    return ux * (vy * wz - vz * wy) - uy * (vx * wz - vz * wx) + uz * (vx * wy - vy * wx)


@numba.njit(cache=True)
def _edge_crosses(p, q, a, b, c):
    """Does the segment pq pass through the inside of triangle abc (touching and lying in its plane do not count)?"""
    sp, sq = _orient(a, b, c, p), _orient(a, b, c, q)
    if sp * sq >= 0.0:
        return False
    s1, s2, s3 = _orient(p, q, a, b), _orient(p, q, b, c), _orient(p, q, c, a)
    return (s1 > 0.0 and s2 > 0.0 and s3 > 0.0) or (s1 < 0.0 and s2 < 0.0 and s3 < 0.0)


@numba.njit(cache=True)
def _crosses(V, f, g):
    """Do triangles f and g (sharing no vertex) pass through each other: does one's edge cross the other?"""
    for e in range(3):
        if _edge_crosses(V[f[e]], V[f[(e + 1) % 3]], V[g[0]], V[g[1]], V[g[2]]):
            return True
        if _edge_crosses(V[g[e]], V[g[(e + 1) % 3]], V[f[0]], V[f[1]], V[f[2]]):
            return True
    return False


@numba.njit(cache=True)
def _tri_boxes(V, F, pad):
    """Each triangle's bounding box, grown by pad: (lo, hi)."""
    m = len(F)
    lo, hi = np.empty((m, 3)), np.empty((m, 3))
    for i in range(m):
        for d in range(3):
            a, b, c = V[F[i, 0], d], V[F[i, 1], d], V[F[i, 2], d]
            lo[i, d], hi[i, d] = min(a, min(b, c)) - pad, max(a, max(b, c)) + pad
    return lo, hi


@numba.njit(cache=True)
def _cell_entries(lo, hi, h):
    """(cell key, box) for every grid cell (size h) every box covers, sorted by key; the boxes' lowest and
    highest cells (clo, chi); the grid's (ny, nz)."""
    m = len(lo)
    clo, chi = np.empty((m, 3), dtype=np.int64), np.empty((m, 3), dtype=np.int64)
    for d in range(3):
        origin = lo[:, d].min()
        for i in range(m):
            clo[i, d], chi[i, d] = np.int64((lo[i, d] - origin) / h), np.int64((hi[i, d] - origin) / h)
    ny, nz = chi[:, 1].max() + 1, chi[:, 2].max() + 1
    count = 0
    for i in range(m):
        count += (chi[i, 0] - clo[i, 0] + 1) * (chi[i, 1] - clo[i, 1] + 1) * (chi[i, 2] - clo[i, 2] + 1)
    keys, boxes = np.empty(count, dtype=np.int64), np.empty(count, dtype=np.int64)
    k = 0
    for i in range(m):
        for x in range(clo[i, 0], chi[i, 0] + 1):
            for y in range(clo[i, 1], chi[i, 1] + 1):
                for z in range(clo[i, 2], chi[i, 2] + 1):
                    keys[k], boxes[k] = (x * ny + y) * nz + z, i
                    k += 1
    order = np.argsort(keys, kind="mergesort")
    return keys[order], boxes[order], clo, chi, ny, nz


@numba.njit(cache=True, inline="always")
def _overlap(lo, hi, i, j):
    """Do boxes i and j meet?"""
    for d in range(3):
        if lo[i, d] > hi[j, d] or lo[j, d] > hi[i, d]:
            return False
    return True


@numba.njit(cache=True)
def _meet_once(lo, hi, clo, chi, cell, i, j):
    """Do boxes i and j meet, and is this cell the lowest both cover (so that the pair comes once)?"""
    for d in range(3):
        if cell[d] != max(clo[i, d], clo[j, d]):
            return False
    return _overlap(lo, hi, i, j)


@numba.njit(cache=True)
def _box_pairs(lo, hi, h):
    """Pairs (i, j), i < j, of boxes that meet, over a uniform grid of cell size h."""
    keys, boxes, clo, chi, ny, nz = _cell_entries(lo, hi, h)
    out = []
    start = 0
    while start < len(keys):
        stop = start
        while stop < len(keys) and keys[stop] == keys[start]:
            stop += 1
        key = keys[start]
        cell = (key // (ny * nz), (key // nz) % ny, key % nz)
        for a in range(start, stop):
            for b in range(a + 1, stop):
                i, j = boxes[a], boxes[b]
                if _meet_once(lo, hi, clo, chi, cell, i, j):
                    out.append((min(i, j), max(i, j)))
        start = stop
    pairs = np.empty((len(out), 2), dtype=np.int64)
    for k in range(len(out)):
        pairs[k, 0], pairs[k, 1] = out[k]
    return pairs


@numba.njit(cache=True, inline="always")
def _share_corner(F, i, j):
    for a in range(3):
        for b in range(3):
            if F[i, a] == F[j, b]:
                return True
    return False


@numba.njit(cache=True)
def _apart(F, pairs):
    """The pairs of triangles that share no corner."""
    keep = np.empty(len(pairs), dtype=np.bool_)
    for k in range(len(pairs)):
        keep[k] = not _share_corner(F, pairs[k, 0], pairs[k, 1])
    return pairs[keep]


@numba.njit(cache=True)
def _group_boxes(lo, hi, group, n_groups):
    """The bounding box of each group's boxes (empty groups: lo +inf, hi -inf)."""
    glo, ghi = np.full((n_groups, 3), np.inf), np.full((n_groups, 3), -np.inf)
    for i in range(len(group)):
        for d in range(3):
            glo[group[i], d] = min(glo[group[i], d], lo[i, d])
            ghi[group[i], d] = max(ghi[group[i], d], hi[i, d])
    return glo, ghi


@numba.njit(cache=True)
def _member_pairs(F, lo, hi, gpairs, members, starts):
    """The pairs of triangles, one of each group of a pair of groups, whose boxes meet and that share no corner."""
    out = []
    for k in range(len(gpairs)):
        ga, gb = gpairs[k, 0], gpairs[k, 1]
        for a in range(starts[ga], starts[ga + 1]):
            for b in range(starts[gb], starts[gb + 1]):
                i, j = members[a], members[b]
                if _overlap(lo, hi, i, j) and not _share_corner(F, i, j):
                    out.append((min(i, j), max(i, j)))
    pairs = np.empty((len(out), 2), dtype=np.int64)
    for k in range(len(out)):
        pairs[k, 0], pairs[k, 1] = out[k]
    return pairs


@numba.njit(cache=True)
def _boxes_meet(V, f, g):
    for d in range(3):
        lo_f = min(V[f[0], d], min(V[f[1], d], V[f[2], d]))
        hi_g = max(V[g[0], d], max(V[g[1], d], V[g[2], d]))
        if lo_f > hi_g:
            return False
        hi_f = max(V[f[0], d], max(V[f[1], d], V[f[2], d]))
        lo_g = min(V[g[0], d], min(V[g[1], d], V[g[2], d]))
        if lo_g > hi_f:
            return False
    return True


@numba.njit(cache=True, parallel=True)
def _cross_list(V, F, pairs, out):
    for k in numba.prange(len(pairs)):
        f, g = F[pairs[k, 0]], F[pairs[k, 1]]
        out[k] = _boxes_meet(V, f, g) and _crosses(V, f, g)


def _cell(lo, hi) -> float:
    """Grid cell: twice the median box's largest side (not below 1e-12 of the whole)."""
    extent = (hi - lo).max(axis=1)
    return max(2.0 * float(np.median(extent)), 1e-12 * max(float((hi.max(axis=0) - lo.min(axis=0)).max()), 1.0))


def _sorted(pairs):
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def crossing_pairs(V, F) -> np.ndarray:
    """Return the pairs of triangles that share no vertex and pass through each other.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Vertices.
    F : (m, 3) int NumPy array
        Triangles.

    Returns
    -------
    (p, 2) int64 NumPy array
        Pairs ``i < j`` of triangle indices, sorted: an edge of one passes
        through the inside of the other. Triangles that only touch, or lie in
        one plane, do not count.

    Raises
    ------
    ValueError
        If ``V`` or ``F`` is malformed (:func:`mi_loop.mesh.checks.check_triangles`).

    Notes
    -----
    Broad phase (:func:`near_pairs` at reach 0): a uniform grid of cells
    twice the median triangle's bounding-box side; each pair whose boxes
    meet is found once, in the lowest cell both boxes cover. Narrow phase:
    two triangles that are not coplanar intersect iff one of their six
    edges crosses the other triangle, which two signs of tetrahedron volumes
    and three of the edge against the triangle's sides decide.

    Examples
    --------
    >>> V = np.array([[0., 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [1.5, 1.5, 0]])
    >>> crossing_pairs(V, np.array([[0, 1, 2], [3, 4, 5]])).tolist()
    [[0, 1]]
    """
    V, F = check_triangles(V, F, "crossing_pairs")
    return _sorted(crossing_among(V, F, _near(V, F, 0.0)))


def near_pairs(V, F, reach: float, groups=None) -> np.ndarray:
    """Return the pairs of triangles that share no vertex and whose bounding boxes come within ``reach``.

    The broad phase of :func:`crossing_pairs`, kept for a while: triangles that
    each move less than ``reach / 2`` can only cross among these pairs.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Vertices.
    F : (m, 3) int NumPy array
        Triangles.
    reach : float
        Largest gap between the bounding boxes of a pair (>= 0).
    groups : tuple ``(group, G)``, optional
        ``group`` ((m,) int) puts every triangle in a face of ``G`` ((g, 3)
        int): pairs whose faces share a corner are left out (the limit
        triangles of neighbouring control faces: a fold there turns normals,
        which other tests watch).

    Returns
    -------
    (p, 2) int64 NumPy array
        Pairs ``i < j``, sorted.

    Raises
    ------
    ValueError
        If the mesh is malformed, ``reach`` is negative or not finite, or ``group`` does not fit.

    Examples
    --------
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0.5], [1, 0, 0.5], [0, 1, 0.5]])
    >>> F = np.array([[0, 1, 2], [3, 4, 5]])
    >>> near_pairs(V, F, 0.6).tolist(), near_pairs(V, F, 0.4).tolist()
    ([[0, 1]], [])
    """
    V, F = check_triangles(V, F, "near_pairs")
    if not (np.isfinite(reach) and reach >= 0):
        raise ValueError(f"near_pairs(): expected a finite reach >= 0, got {reach!r}")
    if groups is not None:
        group, G = np.asarray(groups[0], dtype=np.int64), np.ascontiguousarray(groups[1], dtype=np.int64)
        groups = (group, G)
        if group.shape != (len(F),) or G.ndim != 2 or G.shape[1] != 3 or (len(group) and not (
                0 <= group.min() and group.max() < len(G))):
            raise ValueError(f"near_pairs(): expected groups (group, G): group of shape ({len(F)},) indexing the "
                             f"faces G (g, 3), got group of shape {group.shape} and G of shape {G.shape}")
    return _near(V, F, reach, groups)


def _near(V, F, reach: float, groups=None) -> np.ndarray:
    """:func:`near_pairs` of a checked mesh."""
    if len(F) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    lo, hi = _tri_boxes(V, F, 0.5 * reach)
    if groups is None:
        return _sorted(_apart(F, _box_pairs(lo, hi, _cell(lo, hi))))
    # two levels: the groups' boxes first (a control face's limit triangles), then their triangles
    group, G = groups
    glo, ghi = _group_boxes(lo, hi, group, len(G))
    used = np.flatnonzero(np.isfinite(glo[:, 0]))
    gpairs = _apart(G, used[_box_pairs(glo[used], ghi[used], _cell(glo[used], ghi[used]))])
    members = np.argsort(group, kind="stable")
    starts = np.searchsorted(group[members], np.arange(len(G) + 1))
    return _sorted(_member_pairs(F, lo, hi, gpairs, members, starts))


def crossing_among(V, F, pairs) -> np.ndarray:
    """Return those of ``pairs`` (of triangles sharing no vertex; :func:`near_pairs`) that pass through each other.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Vertices (unchecked: the caller's, at every step).
    F : (m, 3) int64 NumPy array
        Triangles.
    pairs : (p, 2) int64 NumPy array
        Candidate pairs.

    Returns
    -------
    (q, 2) int64 NumPy array
        The crossing ones, in the order of ``pairs``.
    """
    hit = np.zeros(len(pairs), dtype=np.bool_)
    _cross_list(np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(F, dtype=np.int64),
                np.ascontiguousarray(pairs, dtype=np.int64), hit)
    return pairs[hit]


def crossing_faces(V, F) -> np.ndarray:
    """Mark the triangles that another triangle, sharing no vertex with it, passes through (:func:`crossing_pairs`).

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Vertices.
    F : (m, 3) int NumPy array
        Triangles.

    Returns
    -------
    (m,) bool NumPy array

    Examples
    --------
    >>> V = np.array([[0., 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [1.5, 1.5, 0]])
    >>> crossing_faces(V, np.array([[0, 1, 2], [3, 4, 5]])).tolist()
    [True, True]
    """
    pairs = crossing_pairs(V, F)
    out = np.zeros(len(F), dtype=bool)
    out[pairs.ravel()] = True
    return out
