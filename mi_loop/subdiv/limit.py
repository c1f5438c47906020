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
from mi_loop.mesh.topology import sharp_topology
from mi_loop.subdiv.boxspline import PRODUCT_ROWS, box_rows
from mi_loop.subdiv.hierarchy import Hierarchy, build_hierarchy
from mi_loop.subdiv.irregular import MAX_DEPTH

__all__ = ["check_samples", "level_rows", "limit_matrix", "padded_to_csr"]


def _map_to_level(h: Hierarchy, face_ids: np.ndarray, uv: np.ndarray):
    """Face and parameters ``(u, v)`` at level L of control-face points, and the derivative factor.

    Child 0, 1, 2 of a face holds its corner 0, 1, 2 and child 3 is the middle
    face, turned by half a turn (its parameters and derivatives change sign).
    """
    f = face_ids.astype(np.int64)
    u, v = np.array(uv[:, 0]), np.array(uv[:, 1])
    sign = np.ones(len(f))
    for _ in range(len(h.S)):
        c1 = u >= 0.5
        c2 = v >= 0.5
        c2 &= ~c1
        mid = u + v > 0.5
        mid &= ~(c1 | c2)
        f *= 4
        f += c1
        f += 2 * c2
        f += 3 * mid
        u *= 2
        u -= c1
        v *= 2
        v -= c2
        np.subtract(1.0, u, out=u, where=mid)
        np.subtract(1.0, v, out=v, where=mid)
        np.negative(sign, out=sign, where=mid)
        np.clip(u, 0.0, 1.0, out=u)
        np.clip(v, 0.0, 1.0, out=v)
    return f, u, v, sign * 2.0 ** len(h.S)


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


class _IrregularSamples:
    """Samples in faces with an irregular corner, sorted by (configuration, corner, child, depth).

    ``rows`` are their sample indices in that order and ``groups`` the runs
    ``(signature, rot, child or -1 at the vertex, depth, factor, start, stop)``
    that share one matrix and one derivative factor; ``cu, cv`` are the
    parameters in the regular child patch and ``scale`` the sample's own
    derivative factor (from :func:`_map_to_level`).
    """

    def __init__(self, h: Hierarchy, rows, faces, u, v, scale):
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

    def apply(self, h: Hierarchy, W: dict):
        """Overwrite the rows of these samples in the padded weights ``W`` (box-spline rows at ``(cu, cv)``)."""
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
                B = {d: np.take(W[d], rows, axis=0)[:, :12] if d in W else
                     box_rows(self.cu[a0:e0], self.cv[a0:e0], (d,), 12, self.scale[a0:e0])[d] for d in need}
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

    Notes
    -----
    Every sample's box-spline rows are evaluated once, at the parameters of
    its regular patch (the level-``L`` face, or the regular child next to an
    irregular vertex), blocked so that temporaries stay in cache; phantom
    patterns and irregular configurations are then applied group by group.

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> h = build_hierarchy(F, 4)
    >>> (idx, W), = level_rows(h, np.array([0]), np.array([[0.25, 0.25]]))
    >>> idx.shape == W.shape, round(float(W.sum()), 12)
    (True, 1.0)
    """
    faces, u, v, scale = _map_to_level(h, face_ids, uv)
    ii = np.flatnonzero(h.irr_corner[faces] >= 0)
    width = max(12, int(h.irr_K[faces[ii]].max())) if len(ii) else 12
    idx = np.take(np.ascontiguousarray(h.face_P[:, :width]), faces, axis=0)
    irr = _IrregularSamples(h, ii, faces[ii], u[ii], v[ii], scale[ii]) if len(ii) else None
    if irr is not None:
        u[irr.rows], v[irr.rows] = irr.cu, irr.cv
    W = box_rows(u, v, derivatives, width, scale)
    pr = np.flatnonzero(h.phantom[faces]) if h.phantom.any() else ()
    if len(pr):
        pid = h.reg_pid[faces[pr]]
        for p in np.unique(pid):
            rows_p = pr[pid == p]
            for a in range(0, len(rows_p), PRODUCT_ROWS):
                rows = rows_p[a:a + PRODUCT_ROWS]
                for Wd in W.values():
                    Wd[rows, :12] = np.take(Wd, rows, axis=0)[:, :12] @ h.Phis[p]
    if irr is not None:
        irr.apply(h, W)
    return [(idx, W[d]) for d in derivatives]


def check_samples(face_ids, uv, m, func, hole=None):
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
    hole : (m,) bool numpy array, optional
        Faces that are holes (:attr:`~mi_loop.mesh.halfedge.Topology.hole`).

    Returns
    -------
    face_ids : (k,) int64 numpy array
    uv : (k, 2) float64 numpy array

    Raises
    ------
    ValueError
        Bad shapes or dtype, a face id out of range or on a hole, ``uv``
        outside the triangle; the first offending sample is named.

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
    if hole is not None and hole[face_ids].any():
        bad = np.flatnonzero(hole[face_ids])
        fail(func, "samples on faces of the limit surface",
             f"face {face_ids[bad[0]]} at sample {bad[0]}, a hole under boundary='none' (a vertex of it is "
             f"on a boundary that is not an infinitely sharp crease); {int(hole.sum())} of {m} faces are holes")
    tol = 1e-12
    u, v = uv[:, 0], uv[:, 1]
    ok = u >= -tol                      # also False for NaN and -inf; u + v catches +inf
    ok &= v >= -tol
    ok &= u + v <= 1 + tol
    if not ok.all():
        bad = np.flatnonzero(~ok)
        fail(func, "uv with u >= 0, v >= 0, u + v <= 1", f"uv = {uv[bad[0]].tolist()} at sample {bad[0]}")
    uv = np.clip(uv, 0.0, 1.0)
    over = np.flatnonzero(uv[:, 0] + uv[:, 1] > 1.0)
    if len(over):
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


def _all_corners(uv) -> bool:
    """Whether ``uv`` is a non-empty (k, 2) array of face corners ``(0, 0)``, ``(1, 0)``, ``(0, 1)`` only."""
    uv = np.asarray(uv)
    if uv.ndim != 2 or uv.shape[1] != 2 or len(uv) == 0 or not np.issubdtype(uv.dtype, np.number):
        return False
    u, v = uv[:, 0], uv[:, 1]
    return bool((((u == 0) | (u == 1)) & ((v == 0) | (v == 1)) & (u + v <= 1)).all())


def limit_matrix(F, n_vertices, face_ids, uv, creases=None, derivative=None, *, corners=None,
                 boundary="edge_and_corner", crease_method="uniform"):
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
    corners, boundary, crease_method : optional
        The rest of OpenSubdiv's crease model, see :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``(k, n)``, float64
        ``W @ V`` gives the ``(k, 3)`` limit points (derivatives).

    Raises
    ------
    ValueError
        Invalid mesh, crease model or samples, a sample on a hole (boundary
        ``'none'``), or an unknown ``derivative``; the message names the
        offending element. Two faces on the same three
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
    model = dict(creases=creases, corners=corners, boundary=boundary, crease_method=crease_method)
    if derivative is None and _all_corners(uv):   # the vertex masks, no hierarchy
        from mi_loop.subdiv.masks import _position_masks

        topo = sharp_topology(F, n_vertices, "limit_matrix", **model)
        face_ids, uv = check_samples(face_ids, uv, len(topo.F), "limit_matrix", topo.hole)
        corner = np.where(uv[:, 0] == 1, 1, np.where(uv[:, 1] == 1, 2, 0))
        return _position_masks(topo, "limit_matrix", model)[topo.F[face_ids, corner]]
    h = build_hierarchy(F, n_vertices, func="limit_matrix", **model)
    face_ids, uv = check_samples(face_ids, uv, len(h.levels[0].F), "limit_matrix", h.levels[0].hole)
    (idx, W), = level_rows(h, face_ids, uv, (derivative,))
    return (padded_to_csr(idx, W, h.top.n) @ h.composed()).tocsr()
