"""Points on triangle meshes (NumPy/SciPy): exact closest points and area-uniform samples.

A :class:`scipy.spatial.cKDTree` only prefilters candidate triangles; the
distances are exact point-to-triangle distances.
"""
from __future__ import annotations

import itertools

import numpy as np

from mi_loop.errors import fail
from mi_loop.mesh.checks import check_points, check_triangles

__all__ = ["closest_points", "sample_surface", "surface_distances"]


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _closest_on_segment(p, a, b):
    ab = b - a
    t = np.clip(_dot(p - a, ab) / np.maximum(_dot(ab, ab), 1e-300), 0.0, 1.0)
    return a + t[:, None] * ab


def _closest_on_triangles(p, a, b, c):
    """Closest points of ``(k, 3)`` points ``p`` on triangles ``(a, b, c)``, row by row.

    Interior projection when its barycentrics are non-negative, otherwise the
    nearest of the three edge points; degenerate triangles reduce to segments.
    """
    n = np.cross(b - a, c - a)
    nn = _dot(n, n)
    ok = nn > 1e-300
    proj = p - (_dot(p - a, n) / np.where(ok, nn, 1.0))[:, None] * n
    u = _dot(np.cross(c - b, proj - b), n)
    v = _dot(np.cross(a - c, proj - c), n)
    w = _dot(np.cross(b - a, proj - a), n)
    inside = ok & (u >= 0) & (v >= 0) & (w >= 0)
    best = proj.copy()
    best_d = np.where(inside, _dot(p - proj, p - proj), np.inf)
    for s, t in ((a, b), (b, c), (c, a)):
        q = _closest_on_segment(p, s, t)
        d = _dot(p - q, p - q)
        take = ~inside & (d < best_d)
        best[take], best_d[take] = q[take], d[take]
    return best, best_d


def closest_points(V, F, Q, chunk: int = 8192):
    """Exact closest points of query points on a triangle mesh.

    The distance to the nearest mesh vertex bounds the answer; a
    :class:`~scipy.spatial.cKDTree` of triangle centroids (one per size class
    of triangles, radii within a factor 2) returns every triangle whose
    bounding sphere reaches within that bound, and the exact point-triangle
    distance is taken over those candidates.

    Parameters
    ----------
    V : (n, 3) float numpy array
        Mesh vertices.
    F : (m, 3) int numpy array
        Triangles (any orientation; degenerate ones are treated as segments).
    Q : (k, 3) float numpy array
        Query points.
    chunk : int
        Queries per batch (bounds memory).

    Returns
    -------
    dist : (k,) float64 numpy array
        Euclidean distances.
    C : (k, 3) float64 numpy array
        Closest points.
    face : (k,) int64 numpy array
        Triangle of each closest point.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> d, C, f = closest_points(V, F, np.array([[0.2, 0.2, 0.5], [2.0, 0, 0]]))
    >>> d.round(6).tolist(), C[1].tolist()
    ([0.5, 1.0], [1.0, 0.0, 0.0])
    """
    from scipy.spatial import cKDTree

    V, F = check_triangles(V, F, "closest_points")
    Q = check_points(Q, "closest_points")
    T = V[F]
    cen = T.mean(1)
    rad = np.linalg.norm(T - cen[:, None], axis=2).max(1)
    d0, _ = cKDTree(V[np.unique(F)]).query(Q)
    level = np.floor(np.log2(np.maximum(rad, rad.max() * 2.0 ** -12 + 1e-300))).astype(int)
    bins = []                                      # (triangle ids, centroid tree, largest radius)
    for L in np.unique(level):
        idx = np.flatnonzero(level == L)
        bins.append((idx, cKDTree(cen[idx]), rad[idx].max()))
    dist, C, face = np.empty(len(Q)), np.empty((len(Q), 3)), np.empty(len(Q), dtype=np.int64)
    for s in range(0, len(Q), chunk):
        q = Q[s:s + chunk]
        qi, fi = [], []
        for idx, tree, r in bins:
            hits = tree.query_ball_point(q, d0[s:s + chunk] * (1 + 1e-9) + r + 1e-12)
            lens = np.fromiter(map(len, hits), dtype=np.int64, count=len(hits))
            qi.append(np.repeat(np.arange(len(q)), lens))
            fi.append(idx[np.fromiter(itertools.chain.from_iterable(hits), dtype=np.int64, count=lens.sum())])
        qi, fi = np.concatenate(qi), np.concatenate(fi)
        cp, d2 = _closest_on_triangles(q[qi], T[fi, 0], T[fi, 1], T[fi, 2])
        order = np.lexsort((d2, qi))
        first = order[np.unique(qi[order], return_index=True)[1]]  # every query has >= 1 candidate
        dist[s:s + chunk] = np.sqrt(d2[first])
        C[s:s + chunk] = cp[first]
        face[s:s + chunk] = fi[first]
    return dist, C, face


def surface_distances(V, F, points):
    """Return the exact distances from points to a triangle mesh (see :func:`closest_points`).

    Parameters
    ----------
    V : (n, 3) float numpy array
        Mesh vertices.
    F : (m, 3) int numpy array
        Triangles.
    points : (k, 3) float numpy array
        Query points.

    Returns
    -------
    (k,) float64 numpy array

    Raises
    ------
    ValueError
        As :func:`closest_points`.

    Examples
    --------
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> surface_distances(V, F, np.array([[0.2, 0.2, -2.0]])).tolist()
    [2.0]
    """
    return closest_points(V, F, points)[0]


def sample_surface(V, F, n: int, seed: int = 0):
    """Draw area-weighted uniform samples with their face normals.

    Parameters
    ----------
    V : (n_v, 3) float numpy array
    F : (m, 3) int numpy array
        Triangles; zero-area ones are never drawn.
    n : int
        Number of samples.
    seed : int
        Seed of :func:`numpy.random.default_rng`.

    Returns
    -------
    P : (n, 3) float64 numpy array
        Samples.
    N : (n, 3) float64 numpy array
        Unit normals of the faces they lie on (right-hand rule on ``F``).
    face : (n,) int64 numpy array
        Face of every sample.

    Raises
    ------
    ValueError
        Bad mesh, zero total area, ``n < 1``.
    """
    V, F = check_triangles(V, F, "sample_surface")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        fail("sample_surface", "a positive integer n", n)
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    area2 = np.linalg.norm(cross, axis=1)
    if not area2.sum() > 0:
        fail("sample_surface", "a mesh with a positive surface area", "zero area")
    rng = np.random.default_rng(seed)
    face = rng.choice(len(F), size=n, p=area2 / area2.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)                               # barycentrics (1 - s, s (1 - r2), s r2) are uniform
    T = V[F[face]]
    P = (1 - s)[:, None] * T[:, 0] + (s * (1 - r2))[:, None] * T[:, 1] + (s * r2)[:, None] * T[:, 2]
    return P, cross[face] / area2[face, None], face
