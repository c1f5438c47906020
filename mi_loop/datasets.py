"""Procedural control meshes: deterministic, closed, manifold triangle meshes.

Each generator returns ``(V, F)`` as NumPy arrays and depends on nothing but
its arguments, so a demo, a scene file and a test built from the same call
see the same control points in the same order.

==============  ==========================================================
``icosphere``   unit icosphere: 12 valence-5 vertices, the rest valence 6
``blob``        icosphere pushed in and out along smooth radial bumps
``torus``       regular torus: every vertex has valence 6
==============  ==========================================================
"""
from __future__ import annotations

import numpy as np

__all__ = ["CONTROL_MESHES", "blob", "control_mesh", "icosphere", "noisy_torus_points", "torus", "torus_distance"]


def icosphere(subdivisions: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Return a unit icosphere: an icosahedron split ``subdivisions`` times.

    Parameters
    ----------
    subdivisions : int, optional
        Number of 1-to-4 midpoint splits (0 gives the icosahedron).

    Returns
    -------
    V : (10 * 4**s + 2, 3) float64 NumPy array
        Vertices on the unit sphere.
    F : (20 * 4**s, 3) int64 NumPy array
        Outward-oriented (counter-clockwise seen from outside) triangles.

    Raises
    ------
    ValueError
        If ``subdivisions`` is negative or not an integer.

    Examples
    --------
    >>> V, F = icosphere(1)
    >>> V.shape, F.shape
    ((42, 3), (80, 3))
    """
    if not isinstance(subdivisions, (int, np.integer)) or subdivisions < 0:
        raise ValueError(f"icosphere: expected an integer subdivisions >= 0, got {subdivisions!r}")
    t = (1 + 5 ** 0.5) / 2
    V = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0],
                  [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    F = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
                  [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
                  [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
                  [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    for _ in range(int(subdivisions)):
        V, F = _split_midpoints(V, F)
    return V / np.linalg.norm(V, axis=1, keepdims=True), F


def _split_midpoints(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into four at its edge midpoints (shared midpoints merged)."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    unique, inverse = np.unique(E, axis=0, return_inverse=True)
    mid = len(V) + inverse.reshape(3, len(F)).T          # (m, 3) midpoints of edges 01, 12, 20
    V = np.vstack([V, 0.5 * (V[unique[:, 0]] + V[unique[:, 1]])])
    a, b, c = F.T
    ab, bc, ca = mid.T
    F = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                        np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
    return V, F


def blob(subdivisions: int = 1, amplitude: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Return an icosphere displaced along smooth radial bumps.

    Parameters
    ----------
    subdivisions : int, optional
        Icosphere level (1 gives 42 vertices and 80 faces).
    amplitude : float, optional
        Bump height relative to the unit radius; ``|amplitude| < 0.5`` keeps
        the shape star-shaped.

    Returns
    -------
    V : (n, 3) float64 NumPy array
    F : (m, 3) int64 NumPy array

    Raises
    ------
    ValueError
        If ``amplitude`` is not in (-0.5, 0.5).

    Notes
    -----
    The radius along unit direction ``d`` is
    ``1 + amplitude * (sin(3 d_x) cos(2 d_y) + d_z**2 - 1/3)``.
    """
    if not -0.5 < amplitude < 0.5:
        raise ValueError(f"blob: expected amplitude in (-0.5, 0.5), got {amplitude!r}")
    D, F = icosphere(subdivisions)
    r = 1 + amplitude * (np.sin(3 * D[:, 0]) * np.cos(2 * D[:, 1]) + D[:, 2] ** 2 - 1 / 3)
    return D * r[:, None], F


def torus(n_major: int = 12, n_minor: int = 8, major_radius: float = 1.0,
          minor_radius: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    """Return a torus around the z axis triangulated so every vertex has valence 6.

    Parameters
    ----------
    n_major, n_minor : int, optional
        Vertices around the main ring and around the tube (each >= 3).
    major_radius, minor_radius : float, optional
        Ring and tube radii, ``0 < minor_radius < major_radius``.

    Returns
    -------
    V : (n_major * n_minor, 3) float64 NumPy array
        Vertex ``i * n_minor + j`` sits at ring angle ``2 pi i / n_major``
        and tube angle ``2 pi j / n_minor``.
    F : (2 * n_major * n_minor, 3) int64 NumPy array
        Outward-oriented triangles.

    Raises
    ------
    ValueError
        If a count is below 3 or the radii are not ``0 < minor < major``.
    """
    if min(n_major, n_minor) < 3:
        raise ValueError(f"torus: expected n_major, n_minor >= 3, got {n_major}, {n_minor}")
    if not 0 < minor_radius < major_radius:
        raise ValueError(f"torus: expected 0 < minor_radius < major_radius, got {minor_radius}, {major_radius}")
    u = 2 * np.pi * np.arange(n_major)[:, None] / n_major
    v = 2 * np.pi * np.arange(n_minor)[None, :] / n_minor
    ring = major_radius + minor_radius * np.cos(v)
    V = np.stack(np.broadcast_arrays(ring * np.cos(u), ring * np.sin(u), minor_radius * np.sin(v)), -1)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return V.reshape(-1, 3), F.astype(np.int64)


def torus_distance(X, major_radius: float = 1.0, minor_radius: float = 0.4) -> np.ndarray:
    """Exact distance of points to the torus around the z axis (the surface of :func:`noisy_torus_points`).

    Parameters
    ----------
    X : (k, 3) float array
        Points.
    major_radius, minor_radius : float, optional
        Ring and tube radii.

    Returns
    -------
    (k,) float64 NumPy array
        ``| |(rho - R, z)| - r |`` with ``rho`` the distance from the z axis.

    Examples
    --------
    >>> torus_distance([[1.4, 0, 0], [1.0, 0, 0.5], [0, 0, 0]]).round(12).tolist()
    [0.0, 0.1, 0.6]
    """
    X = np.asarray(X, dtype=np.float64)
    rho = np.hypot(X[:, 0], X[:, 1])
    return np.abs(np.hypot(rho - major_radius, X[:, 2]) - minor_radius)


#: Generators by name, as offered by ``mi-loop control NAME``.
CONTROL_MESHES = {"blob": blob, "icosphere": icosphere, "torus": torus}


def control_mesh(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Return the named procedural control mesh with default parameters.

    Parameters
    ----------
    name : str
        One of ``CONTROL_MESHES``: ``'blob'``, ``'icosphere'``, ``'torus'``.

    Returns
    -------
    V : (n, 3) float64 NumPy array
    F : (m, 3) int64 NumPy array

    Raises
    ------
    ValueError
        If the name is unknown.
    """
    if name not in CONTROL_MESHES:
        raise ValueError(f"control_mesh: unknown mesh '{name}', expected one of {sorted(CONTROL_MESHES)}")
    return CONTROL_MESHES[name]()


def noisy_torus_points(n_points: int = 20_000, noise: float = 0.005, outliers: float = 0.01,
                       major_radius: float = 1.0, minor_radius: float = 0.4, seed: int = 0):
    """Return an oriented point cloud sampled on a torus, with noise and outliers.

    Points are uniform in area (rejection on the tube angle), displaced along
    the analytic normal by Gaussian noise, plus a fraction of uniformly random
    outliers in the bounding box (with random unit normals).

    Parameters
    ----------
    n_points : int
        Points on the surface.
    noise : float
        Standard deviation of the normal displacement, relative to the bbox diagonal.
    outliers : float
        Outliers as a fraction of ``n_points``.
    major_radius, minor_radius : float
        Torus radii (axis z).
    seed : int

    Returns
    -------
    P : (k, 3) float64 NumPy array
    N : (k, 3) float64 NumPy array
        Analytic outward unit normals (random for outliers).
    clean : (n_points, 3) float64 NumPy array
        The noise-free surface points, for measuring a fit.

    Examples
    --------
    >>> P, N, clean = noisy_torus_points(1000, outliers=0.0)
    >>> P.shape, bool(abs(np.linalg.norm(N, axis=1) - 1).max() < 1e-12)
    ((1000, 3), True)
    """
    if n_points < 1 or noise < 0 or outliers < 0 or not 0 < minor_radius < major_radius:
        raise ValueError("noisy_torus_points: expected n_points >= 1, noise >= 0, outliers >= 0 "
                         f"and 0 < minor < major radius, got {n_points}, {noise}, {outliers}, "
                         f"{minor_radius}, {major_radius}")
    rng = np.random.default_rng(seed)
    R, r = major_radius, minor_radius
    u = rng.uniform(0, 2 * np.pi, 4 * n_points)
    v = rng.uniform(0, 2 * np.pi, 4 * n_points)
    keep = rng.uniform(0, R + r, 4 * n_points) < R + r * np.cos(v)  # area element ~ R + r cos v
    u, v = u[keep][:n_points], v[keep][:n_points]
    N = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], 1)
    clean = np.stack([(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u), r * np.sin(v)], 1)
    diag = np.linalg.norm([2 * (R + r), 2 * (R + r), 2 * r])
    P = clean + N * rng.normal(0, noise * diag, (len(clean), 1))
    n_out = int(round(outliers * n_points))
    lo, hi = clean.min(0), clean.max(0)
    P_out = rng.uniform(lo, hi, (n_out, 3))
    N_out = rng.standard_normal((n_out, 3))
    N_out /= np.linalg.norm(N_out, axis=1, keepdims=True)
    return np.concatenate([P, P_out]), np.concatenate([N, N_out]), clean
