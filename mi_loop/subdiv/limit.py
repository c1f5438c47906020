"""Exact Loop limit evaluation at arbitrary ``(face, u, v)`` as sparse rows (NumPy/SciPy).

The control mesh is subdivided ``L`` times (once, or until semi-sharp creases
have expired) so that every face has at most one irregular corner. Regular
faces are quartic box-spline patches (with phantom points along creases and
boundaries); faces with an irregular corner use :mod:`mi_loop.subdiv.irregular`.
Rows are kept factored as ``W_L @ S_L``: ``W_L`` (padded, on the level-``L``
vertices) times the composed subdivision matrix ``S_L``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from mi_loop.subdiv.boxspline import box_basis
from mi_loop.subdiv.irregular import MAX_DEPTH, build_local
from mi_loop.subdiv.patches import corner_regular, irregular_points, phantom_matrices, stam_points
from mi_loop.subdiv.subdivision import subdivide_topology
from mi_loop.mesh.topology import Topology, check_creases, validate_faces


def descend(uv: np.ndarray):
    """Child index and child parameters of points ``uv`` (k, 2) in a parent face."""
    u, v = uv[:, 0], uv[:, 1]
    child = np.where(u >= 0.5, 1, np.where(v >= 0.5, 2, np.where(u + v <= 0.5, 0, 3)))
    uc = np.select([child == 0, child == 1, child == 2], [2 * u, 2 * u - 1, 2 * u], 1 - 2 * u)
    vc = np.select([child == 0, child == 1, child == 2], [2 * v, 2 * v, 2 * v - 1], 1 - 2 * v)
    return child, np.clip(np.stack([uc, vc], 1), 0.0, 1.0)


@dataclass
class Hierarchy:
    """Control mesh refined until every face has one irregular corner at most.

    Per-face patch tables at the finest level are built once: regular faces
    keep their 12 box-spline points and phantom pattern, irregular faces their
    rotation, local-configuration id and patch points.
    """

    levels: list          # Topology per level 0..L
    S: list               # S[l] maps level l -> l + 1
    max_valence: int

    def __post_init__(self):
        topo = self.top
        F = topo.F
        kind = topo.vertex_kind()
        val = topo.valence()
        reg = np.stack([corner_regular(topo, kind, val, F[:, c], F[:, (c + 1) % 3])
                        for c in range(3)], 1)
        n_irr = (~reg).sum(1)
        if (n_irr > 1).any():
            raise RuntimeError("Hierarchy: a face has two irregular corners after subdivision")
        self.irr_corner = np.where(n_irr == 0, -1, np.argmax(~reg, axis=1))
        m = len(F)
        self.reg_P = np.zeros((m, 12), dtype=np.int64)
        self.reg_pid = np.zeros(m, dtype=np.int64)
        r = np.flatnonzero(self.irr_corner < 0)
        P = stam_points(topo, F[r, 0], F[r, 1], F[r, 2])
        self.reg_pid[r], self.Phis = phantom_matrices(P)
        self.reg_P[r] = np.maximum(P, 0)
        self._irregular_tables(kind)

    def _irregular_tables(self, kind):
        topo, mv = self.top, self.max_valence
        g = np.flatnonzero(self.irr_corner >= 0)
        rot = self.irr_corner[g]
        F = topo.F[g]
        r = np.arange(len(g))
        v, ri, rj = F[r, rot], F[r, (rot + 1) % 3], F[r, (rot + 2) % 3]
        P = irregular_points(topo, v, ri, rj, mv)
        ok = P >= 0
        sector = ok.copy()
        sector[:, 0] = False
        sector[:, 1 + 2 * mv:] = False
        sharp = np.zeros_like(ok)
        sharp[sector] = topo.edge_sharp(np.broadcast_to(v[:, None], P.shape)[sector], P[sector])
        sig_arr = np.concatenate([ok, sharp, kind[v][:, None] == np.arange(3)], 1)
        _, first, sig = np.unique(np.packbits(sig_arr, axis=1), axis=0,
                                  return_index=True, return_inverse=True)
        self.irr_sig = np.full(len(topo.F), -1, dtype=np.int64)
        self.irr_sig[g] = sig
        order = np.argsort(~ok, axis=1, kind="stable")  # present slots first, in order
        self.irr_P = np.zeros((len(topo.F), P.shape[1]), dtype=np.int64)
        self.irr_P[g] = np.maximum(np.take_along_axis(P, order, 1), 0)
        self.locals = []
        if len(g):
            S_next, fine = subdivide_topology(topo)
            self.locals = [build_local(topo, fine, S_next, g[i], rot[i], mv) for i in first]

    @property
    def top(self) -> Topology:
        return self.levels[-1]

    def composed(self) -> sp.csr_matrix:
        """``S_L = S[L-1] @ ... @ S[0]`` of shape ``(n_L, n_0)``."""
        M = self.S[0]
        for S in self.S[1:]:
            M = S @ M
        return M.tocsr()


def build_hierarchy(F, n_vertices, creases=None, func="limit_matrix") -> Hierarchy:
    """Validate and refine the control mesh (see :class:`Hierarchy`)."""
    F = validate_faces(F, n_vertices, func)
    cr = check_creases(creases, F, int(n_vertices), func)
    topo = Topology.build(F, int(n_vertices), cr)
    finite = topo.sharpness[np.isfinite(topo.sharpness)]
    n_levels = max(1, int(finite.max()) if len(finite) else 1)
    levels, Ss = [topo], []
    for _ in range(n_levels):
        S, topo = subdivide_topology(topo)
        Ss.append(S)
        levels.append(topo)
    return Hierarchy(levels, Ss, int(topo.valence().max()))


def map_to_level(h: Hierarchy, face_ids: np.ndarray, uv: np.ndarray):
    """Face and parameters at level L of control-face points; derivative factor."""
    f = face_ids.astype(np.int64)
    sign = np.ones(len(f))
    for _ in range(len(h.S)):
        child, uv = descend(uv)
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
    """Padded rows ``[(idx (k, w), W (k, w)), ...]`` over level-L vertices, one per derivative.

    The index array does not depend on the derivative and is shared by all
    returned pairs.
    """
    faces, uvL, sign = map_to_level(h, face_ids, uv)
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
        Bad shapes or dtype, a face id out of range, ``uv`` outside the triangle.
    """
    face_ids = np.asarray(face_ids)
    uv = np.asarray(uv, dtype=np.float64)
    if face_ids.ndim != 1 or not np.issubdtype(face_ids.dtype, np.integer):
        raise ValueError(f"{func}(): face_ids must be a 1-D integer array, got {face_ids.dtype} "
                         f"array of shape {face_ids.shape}")
    if uv.shape != (len(face_ids), 2):
        raise ValueError(f"{func}(): uv must have shape ({len(face_ids)}, 2), got {uv.shape}")
    bad = np.flatnonzero((face_ids < 0) | (face_ids >= m))
    if len(bad):
        raise ValueError(f"{func}(): sample {bad[0]} has face id {face_ids[bad[0]]} outside [0, {m})")
    tol = 1e-12
    bad = np.flatnonzero(~np.isfinite(uv).all(1) | (uv < -tol).any(1) | (uv.sum(1) > 1 + tol))
    if len(bad):
        raise ValueError(f"{func}(): sample {bad[0]} has uv = {uv[bad[0]].tolist()}; "
                         "expected u >= 0, v >= 0, u + v <= 1")
    uv = np.clip(uv, 0.0, 1.0)
    over = uv.sum(1) > 1.0
    uv[over] /= uv[over].sum(1, keepdims=True)
    return face_ids.astype(np.int64), uv


def padded_to_csr(idx, W, n_cols):
    """CSR matrix ``(k, n_cols)`` from padded rows (duplicates summed, zeros dropped)."""
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
        Invalid mesh, creases or samples; the message names the offending element.

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
        raise ValueError(f"limit_matrix(): derivative must be None, 'u' or 'v', got {derivative!r}")
    h = build_hierarchy(F, n_vertices, creases)
    face_ids, uv = check_samples(face_ids, uv, len(h.levels[0].F), "limit_matrix")
    (idx, W), = level_rows(h, face_ids, uv, (derivative,))
    return (padded_to_csr(idx, W, h.top.n) @ h.composed()).tocsr()
