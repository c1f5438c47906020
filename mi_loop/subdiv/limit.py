"""Exact Loop limit evaluation at arbitrary ``(face, u, v)`` as sparse rows (NumPy/SciPy).

On the :class:`~mi_loop.subdiv.hierarchy.Hierarchy` (the control mesh refined
until every face has at most one irregular corner), regular faces are quartic
box-spline patches (with phantom points along creases and boundaries); faces
with an irregular corner use :mod:`mi_loop.subdiv.irregular`. Rows are kept
factored as ``W_L @ S_L``: ``W_L`` (padded, on the level-``L`` vertices) times
the composed subdivision matrix ``S_L``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mi_loop.errors import fail
from mi_loop.mesh.topology import validate_faces
from mi_loop.subdiv.boxspline import box_basis
from mi_loop.subdiv.hierarchy import Hierarchy, build_hierarchy
from mi_loop.subdiv.irregular import MAX_DEPTH

__all__ = ["check_samples", "level_rows", "limit_matrix", "padded_to_csr"]


def _descend(uv: np.ndarray):
    """Child index and child parameters of points ``uv`` (k, 2) in a parent face."""
    u, v = uv[:, 0], uv[:, 1]
    child = np.where(u >= 0.5, 1, np.where(v >= 0.5, 2, np.where(u + v <= 0.5, 0, 3)))
    uc = np.select([child == 0, child == 1, child == 2], [2 * u, 2 * u - 1, 2 * u], 1 - 2 * u)
    vc = np.select([child == 0, child == 1, child == 2], [2 * v, 2 * v, 2 * v - 1], 1 - 2 * v)
    return child, np.clip(np.stack([uc, vc], 1), 0.0, 1.0)


def _map_to_level(h: Hierarchy, face_ids: np.ndarray, uv: np.ndarray):
    """Face and parameters at level L of control-face points, and the derivative factor."""
    f = face_ids.astype(np.int64)
    sign = np.ones(len(f))
    for _ in range(len(h.S)):
        child, uv = _descend(uv)
        f = 4 * f + child
        sign = np.where(child == 3, -sign, sign)
    return f, uv, sign * 2.0 ** len(h.S)


def _regular_rows(h, faces, uv, derivative):
    b = box_basis(uv, derivative)
    pid = h.reg_pid[faces]
    for p in np.unique(pid):
        if not np.array_equal(h.Phis[p], np.eye(12)):
            sel = pid == p
            b[sel] = b[sel] @ h.Phis[p]
    return h.reg_P[faces], b


def _local_rows(loc, s, t, derivative):
    """Weights over the K patch points (s along v->r_i, t along v->r_j)."""
    st = s + t
    at_vertex = st <= 2.0 ** -MAX_DEPTH
    m = np.floor(-np.log2(np.maximum(st, 2.0 ** -MAX_DEPTH)))
    m = np.where(st * 2.0 ** m > 1.0, m - 1, np.where(st * 2.0 ** m <= 0.5, m + 1, m))
    m = np.clip(m, 0, MAX_DEPTH).astype(np.int64)
    scale = 2.0 ** m
    ss, tt = s * scale, t * scale
    child = np.where(ss >= 0.5, 0, np.where(tt >= 0.5, 1, 2))
    cu = np.select([child == 0, child == 1], [2 * ss - 1, 2 * ss], 1 - 2 * ss)
    cv = np.select([child == 0, child == 1], [2 * tt, 2 * tt - 1], 1 - 2 * tt)
    cuv = np.clip(np.stack([cu, cv], 1), 0.0, 1.0)
    K = len(loc.pi)
    if derivative is None:
        out = np.broadcast_to(loc.pi, (len(s), K)).copy()
        b = box_basis(cuv)
        factor = np.ones(len(s))
    else:
        out = np.zeros((len(s), K))
        b = box_basis(cuv, {"s": "u", "t": "v"}[derivative])
        factor = np.where(child == 2, -2.0, 2.0) * scale
    key = np.where(at_vertex, -1, child * (MAX_DEPTH + 1) + m)
    for k in np.unique(key[key >= 0]):
        sel = key == k
        out[sel] += factor[sel, None] * (b[sel] @ loc.G[k // (MAX_DEPTH + 1), k % (MAX_DEPTH + 1)])
    if derivative is not None:
        out[at_vertex] = loc.T[0 if derivative == "s" else 1]
    return out


def _irregular_rows(h, faces, uv, derivative):
    """Rows for points in faces with an irregular corner; ``(idx, W)`` padded."""
    rot = h.irr_corner[faces]
    r = np.arange(len(faces))
    bary = np.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)
    s, t = bary[r, (rot + 1) % 3], bary[r, (rot + 2) % 3]
    sig = h.irr_sig[faces]
    idx = h.irr_P[faces]
    W = np.zeros(idx.shape)
    if derivative is not None:
        # d/du, d/dv from d/ds, d/dt with (s, t) = barycentrics (rot+1, rot+2).
        dbary = np.zeros((len(faces), 3))
        dbary[:, 0], dbary[:, 1 if derivative == "u" else 2] = -1.0, 1.0
        ds, dt = dbary[r, (rot + 1) % 3][:, None], dbary[r, (rot + 2) % 3][:, None]
    for q in np.unique(sig):
        sel = sig == q
        loc = h.locals[q]
        K = len(loc.pi)
        if derivative is None:
            W[sel, :K] = _local_rows(loc, s[sel], t[sel], None)
        else:
            W[sel, :K] = (ds[sel] * _local_rows(loc, s[sel], t[sel], "s")
                          + dt[sel] * _local_rows(loc, s[sel], t[sel], "t"))
    return idx, W


def level_rows(h: Hierarchy, face_ids, uv, derivatives=(None,)):
    """Return padded limit rows over the level-``L`` vertices, one pair per derivative.

    Parameters
    ----------
    h : Hierarchy
        From :func:`build_hierarchy`.
    face_ids : (k,) int64 numpy array
        Control face of every sample (checked by :func:`check_samples`).
    uv : (k, 2) float64 numpy array
        Parameters in the control faces (checked by :func:`check_samples`).
    derivatives : tuple of None, 'u', 'v'
        Which rows to return: the limit point (None) or a parametric derivative.

    Returns
    -------
    list of tuples ``(idx (k, w) int32 numpy array, W (k, w) float64 numpy array)``
        One pair per entry of ``derivatives``; row ``i`` of the limit matrix
        over level ``L`` is ``sum_j W[i, j] e_{idx[i, j]}``. The index array
        does not depend on the derivative and is the same object in every pair.

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> h = build_hierarchy(F, 4)
    >>> (idx, W), = level_rows(h, np.array([0]), np.array([[0.25, 0.25]]))
    >>> idx.shape == W.shape, round(float(W.sum()), 12)
    (True, 1.0)
    """
    faces, uvL, sign = _map_to_level(h, face_ids, uv)
    reg = h.irr_corner[faces] < 0
    ri, ii = np.flatnonzero(reg), np.flatnonzero(~reg)
    if len(ii) == 0:
        idx = h.reg_P[faces].astype(np.int32)
        return [(idx, np.ascontiguousarray(_regular_rows(h, faces, uvL, d)[1])
                 * (sign[:, None] if d is not None else 1.0)) for d in derivatives]
    K = max(len(h.locals[q].pi) for q in np.unique(h.irr_sig[faces[ii]]))
    width = max(12, K)
    # Regular block then irregular block, padded to one width; one row gather
    # (the inverse permutation) puts them back in sample order.
    inverse = np.empty(len(faces), dtype=np.int64)
    inverse[np.concatenate([ri, ii])] = np.arange(len(faces))
    idx = np.zeros((len(faces), width), dtype=np.int32)
    idx[:len(ri), :12] = h.reg_P[faces[ri]]
    idx[len(ri):, :K] = h.irr_P[faces[ii]][:, :K]
    idx = idx[inverse]
    out = []
    for d in derivatives:
        W = np.zeros((len(faces), width))
        W[:len(ri), :12] = _regular_rows(h, faces[ri], uvL[ri], d)[1]
        W[len(ri):, :K] = _irregular_rows(h, faces[ii], uvL[ii], d)[1][:, :K]
        W = W[inverse]
        if d is not None:
            W *= sign[:, None]
        out.append((idx, W))
    return out


def check_samples(face_ids, uv, m, func):
    """Check limit-sample parameters; return int64 face ids and ``uv`` snapped into the triangle.

    Parameters
    ----------
    face_ids : (k,) int array_like
        Control face of every sample, in ``[0, m)``.
    uv : (k, 2) float array_like
        Parameters with ``u >= 0``, ``v >= 0``, ``u + v <= 1`` (1e-12 slack,
        removed here).
    m : int
        Number of control faces.
    func : str
        Name of the calling public function, for the message.

    Returns
    -------
    face_ids : (k,) int64 numpy array
    uv : (k, 2) float64 numpy array

    Raises
    ------
    ValueError
        Bad shapes or dtype, a face id out of range, ``uv`` outside the
        triangle; the first offending sample is named.

    Examples
    --------
    >>> check_samples([0, 1], [[0.5, 0.5 + 1e-13], [0.0, 0.0]], 2, "f")[1].sum(1).tolist()
    [1.0, 0.0]
    >>> check_samples([0, 2], [[0.2, 0.2], [0.2, 0.2]], 2, "f")
    Traceback (most recent call last):
    ...
    ValueError: f(): expected face ids in [0, 2), got face id 2 at sample 1
    """
    face_ids = np.asarray(face_ids)
    uv = np.asarray(uv, dtype=np.float64)
    if face_ids.ndim != 1 or not np.issubdtype(face_ids.dtype, np.integer):
        fail(func, "face_ids as a 1-D integer array", f"{face_ids.dtype} array of shape {face_ids.shape}")
    if uv.shape != (len(face_ids), 2):
        fail(func, f"uv of shape ({len(face_ids)}, 2) (one row per face id)", f"shape {uv.shape}")
    bad = np.flatnonzero((face_ids < 0) | (face_ids >= m))
    if len(bad):
        fail(func, f"face ids in [0, {m})", f"face id {face_ids[bad[0]]} at sample {bad[0]}")
    tol = 1e-12
    bad = np.flatnonzero(~np.isfinite(uv).all(1) | (uv < -tol).any(1) | (uv.sum(1) > 1 + tol))
    if len(bad):
        fail(func, "uv with u >= 0, v >= 0, u + v <= 1", f"uv = {uv[bad[0]].tolist()} at sample {bad[0]}")
    uv = np.clip(uv, 0.0, 1.0)
    over = uv.sum(1) > 1.0
    uv[over] /= uv[over].sum(1, keepdims=True)
    return face_ids.astype(np.int64), uv


def padded_to_csr(idx, W, n_cols):
    """Return the CSR matrix of padded rows (duplicates summed, zeros dropped).

    Parameters
    ----------
    idx : (k, w) int numpy array
        Column of every entry (padding entries may point anywhere).
    W : (k, w) float64 numpy array
        Weights (zero on padding).
    n_cols : int
        Number of columns.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``(k, n_cols)``, float64

    Examples
    --------
    >>> padded_to_csr(np.array([[0, 2, 0]]), np.array([[0.25, 0.5, 0.25]]), 3).toarray().tolist()
    [[0.5, 0.0, 0.5]]
    """
    k, w = W.shape
    # Copies: sum_duplicates() sorts and compacts the arrays in place.
    M = sp.csr_matrix((W.ravel().copy(), idx.ravel().copy(), np.arange(0, k * w + 1, w)),
                      shape=(k, n_cols))
    M.sum_duplicates()
    M.eliminate_zeros()
    return M


def limit_matrix(F, n_vertices, face_ids, uv, creases=None, derivative=None):
    """Return the sparse matrix of exact limit points (or derivatives) at ``(face, u, v)``.

    Parameters
    ----------
    F : (m, 3) int numpy array
        Control faces (manifold, consistently oriented; boundaries allowed).
    n_vertices : int
        Number of control vertices ``n``.
    face_ids : (k,) int numpy array
        Control face of every sample.
    uv : (k, 2) float numpy array
        Parameters, ``u, v >= 0``, ``u + v <= 1``; the control-face point
        ``(1-u-v) V[F[f,0]] + u V[F[f,1]] + v V[F[f,2]]`` maps to the limit point.
    creases : None, (c, 2) int numpy array, or tuple ``(E, sharpness)``
        See :func:`mi_loop.subdivision_matrix`.
    derivative : None, 'u' or 'v'
        Limit point, or its parametric derivative.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``(k, n)``, float64
        ``W @ V`` gives the ``(k, 3)`` limit points (derivatives).

    Raises
    ------
    ValueError
        Invalid mesh, creases or samples, or an unknown ``derivative``; the
        message names the offending element. Two faces on the same three
        vertices (a closed two-triangle component) are refused, see
        :func:`~mi_loop.mesh.topology.validate_faces`.

    Notes
    -----
    Exact everywhere: box splines on regular patches (with phantom points on
    creases and boundaries), powers of the local subdivision matrix next to
    irregular vertices (Stam 1998, without eigenvectors), the limit mask at the
    vertex itself. At an irregular vertex the parametric derivatives vanish or
    diverge; there the two derivative rows are orthonormal rows spanning the
    limit tangent plane, oriented so that ``cross(du, dv)`` is the exact limit
    normal.

    Examples
    --------
    >>> import numpy as np, mi_loop
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> W = mi_loop.limit_matrix(F, 4, np.array([0]), np.array([[0.25, 0.25]]))
    >>> W.shape, round(float(W.sum()), 12)
    ((1, 4), 1.0)
    """
    if derivative not in (None, "u", "v"):
        fail("limit_matrix", "derivative None, 'u' or 'v'", repr(derivative))
    if derivative is None:             # all samples at control-vertex corners: the vertex masks, no hierarchy
        F = validate_faces(F, n_vertices, "limit_matrix")
        face_ids, uv = check_samples(face_ids, uv, len(F), "limit_matrix")
        corner = np.select([(uv[:, 0] == 0) & (uv[:, 1] == 0), (uv[:, 0] == 1) & (uv[:, 1] == 0),
                            (uv[:, 0] == 0) & (uv[:, 1] == 1)], [0, 1, 2], -1)
        if len(corner) and (corner >= 0).all():
            from mi_loop.subdiv.masks import _position_masks

            return _position_masks(F, n_vertices, creases, "limit_matrix")[F[face_ids, corner]]
    h = build_hierarchy(F, n_vertices, creases)
    face_ids, uv = check_samples(face_ids, uv, len(h.levels[0].F), "limit_matrix")
    (idx, W), = level_rows(h, face_ids, uv, (derivative,))
    return (padded_to_csr(idx, W, h.top.n) @ h.composed()).tocsr()
