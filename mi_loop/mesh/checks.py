"""Shape and finiteness checks of vertex, face, point and normal arrays (NumPy).

Each public function of mi_loop validates its array arguments once, through
these checks, so that the same mistake gets the same message everywhere:
``function(): expected ..., got ...``, naming the first offending row.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail

__all__ = ["check_oriented_points", "check_points", "check_triangles"]


def check_points(P, func: str, what: str = "points", allow_empty: bool = False) -> np.ndarray:
    """Return ``P`` as a float64 ``(k, 3)`` array of finite rows.

    Parameters
    ----------
    P : (k, 3) array_like
        Points (or vertices).
    func : str
        Name of the calling public function, for the message.
    what : str, optional
        What the rows are called in the message (``'points'``, ``'samples'``).
    allow_empty : bool, optional
        Accept ``k = 0``.

    Returns
    -------
    (k, 3) float64 numpy array

    Raises
    ------
    ValueError
        Wrong shape, no rows, or a non-finite row (the first one is named).

    Examples
    --------
    >>> check_points([[0, 0, 0], [1, 2, 3]], "f").shape
    (2, 3)
    >>> check_points([[0, 0, float("nan")]], "f")
    Traceback (most recent call last):
    ...
    ValueError: f(): expected finite points, got row 0 = [0.0, 0.0, nan] (1 such rows)
    """
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or (len(P) == 0 and not allow_empty):
        fail(func, f"{what} of shape (k, 3) with k > 0", f"shape {P.shape}")
    bad = np.flatnonzero(~np.isfinite(P).all(1))
    if len(bad):
        fail(func, f"finite {what}", f"row {bad[0]} = {P[bad[0]].tolist()} ({len(bad)} such rows)")
    return P


def check_oriented_points(P, N, func: str) -> tuple[np.ndarray, np.ndarray]:
    """Return float64 points and unit normals after checking them.

    Parameters
    ----------
    P : (k, 3) array_like
        Points.
    N : (k, 3) array_like
        Normals, any non-zero length.
    func : str
        Name of the calling public function, for the message.

    Returns
    -------
    P : (k, 3) float64 numpy array
    N : (k, 3) float64 numpy array
        Unit normals.

    Raises
    ------
    ValueError
        Bad shapes, non-finite rows, a zero-length normal (the first is named).

    Examples
    --------
    >>> P, N = check_oriented_points([[0, 0, 0]], [[0, 0, 2]], "f")
    >>> N.tolist()
    [[0.0, 0.0, 1.0]]
    >>> check_oriented_points([[0, 0, 0]], [[0, 0, 0]], "f")
    Traceback (most recent call last):
    ...
    ValueError: f(): expected non-zero normals, got normal 0 = [0.0, 0.0, 0.0] (1 such normals); estimate normals (mi_loop.mesh.points.estimate_normals) or drop those points
    """  # noqa: E501 (a doctest's exception line cannot be wrapped)
    P = check_points(P, func)
    if N is None:
        fail(func, f"normals of shape {P.shape}", "None; estimate them with mi_loop.mesh.points.estimate_normals")
    N = np.asarray(N, dtype=np.float64)
    if N.shape != P.shape:
        fail(func, f"normals of the points' shape {P.shape}", f"shape {N.shape}")
    bad = np.flatnonzero(~np.isfinite(N).all(1))
    if len(bad):
        fail(func, "finite normals", f"normal {bad[0]} = {N[bad[0]].tolist()} ({len(bad)} such normals)")
    length = np.linalg.norm(N, axis=1)
    bad = np.flatnonzero(~(length > 1e-12))
    if len(bad):
        fail(func, "non-zero normals", f"normal {bad[0]} = {N[bad[0]].tolist()} ({len(bad)} such normals); "
             "estimate normals (mi_loop.mesh.points.estimate_normals) or drop those points")
    return P, N / length[:, None]


def check_triangles(V, F, func: str, what: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Return float64 vertices and int64 faces of a triangle mesh after checking them.

    Only shapes, index ranges and finiteness are checked; a Loop control mesh
    needs :func:`mi_loop.mesh.topology.validate_mesh` as well (manifold, oriented).

    Parameters
    ----------
    V : (n, 3) array_like
        Vertices.
    F : (m, 3) integer array_like
        Triangles.
    func : str
        Name of the calling public function, for the message.
    what : str, optional
        What the mesh is called in the message.

    Returns
    -------
    V : (n, 3) float64 numpy array
    F : (m, 3) int64 numpy array

    Raises
    ------
    ValueError
        Bad shapes or dtype, a face index outside ``[0, n)``, a non-finite vertex.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        fail(func, f"{what} vertices of shape (n, 3) with n > 0", f"shape {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0 or not np.issubdtype(F.dtype, np.integer):
        fail(func, f"{what} faces as a non-empty integer array of shape (m, 3)", f"{F.dtype} {F.shape}")
    bad = np.flatnonzero((F < 0).any(1) | (F >= len(V)).any(1))
    if len(bad):
        fail(func, f"{what} face indices in [0, {len(V)})", f"face {bad[0]} = {F[bad[0]].tolist()}")
    bad = np.flatnonzero(~np.isfinite(V).all(1))
    if len(bad):
        fail(func, f"finite {what} vertices", f"vertex {bad[0]} = {V[bad[0]].tolist()}")
    return V, F.astype(np.int64)
