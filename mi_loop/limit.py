"""Exact Loop limit evaluation at arbitrary ``(face, u, v)`` as sparse rows (NumPy/SciPy).

The control mesh is subdivided ``L`` times (once, or until semi-sharp creases
have expired) so that every face has at most one irregular corner. Regular
faces are quartic box-spline patches (with phantom points along creases and
boundaries); faces with an irregular corner use :mod:`mi_loop.irregular`.
Rows are kept factored as ``W_L @ S_L``: ``W_L`` (padded, on the level-``L``
vertices) times the composed subdivision matrix ``S_L``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .boxspline import box_basis
from .irregular import MAX_DEPTH, build_local
from .patches import corner_regular, irregular_points, phantom_matrices, stam_points
from .subdivision import subdivide_topology
from .topology import Topology, parse_creases, validate_faces


def children_of(a, b, c, ab, bc, ca):
    """The four children of face ``(a, b, c)`` in :func:`subdivision_matrix` order."""
    return [(a, ab, ca), (ab, b, bc), (ca, bc, c), (bc, ca, ab)]


def descend(uv: np.ndarray):
    """Child index and child parameters of points ``uv`` (k, 2) in a parent face."""
    u, v = uv[:, 0], uv[:, 1]
    child = np.where(u >= 0.5, 1, np.where(v >= 0.5, 2, np.where(u + v <= 0.5, 0, 3)))
    uc = np.select([child == 0, child == 1, child == 2], [2 * u, 2 * u - 1, 2 * u], 1 - 2 * u)
    vc = np.select([child == 0, child == 1, child == 2], [2 * v, 2 * v, 2 * v - 1], 1 - 2 * v)
    return child, np.clip(np.stack([uc, vc], 1), 0.0, 1.0)


@dataclass
class Hierarchy:
    """Topology of the control mesh refined until faces have one irregular corner at most."""

    levels: list       # Topology per level 0..L
    S: list            # subdivision matrices, S[l] maps level l -> l + 1
    kind: np.ndarray   # vertex rule at level L
    irregular: np.ndarray  # (n_L,) bool, irregular vertices at level L (for all faces)
    max_valence: int
    _local: dict = None
    _next: tuple = None

    @property
    def top(self) -> Topology:
        return self.levels[-1]

    def composed(self) -> sp.csr_matrix:
        """``S_L = S[L-1] @ ... @ S[0]`` of shape ``(n_L, n_0)``."""
        M = self.S[0]
        for S in self.S[1:]:
            M = S @ M
        return M.tocsr()

    def next_level(self):
        if self._next is None:
            self._next = subdivide_topology(self.top)
        return self._next

    def local(self, signature, g, rot):
        if self._local is None:
            self._local = {}
        if signature not in self._local:
            S_next, fine = self.next_level()
            self._local[signature] = build_local(self.top, fine, S_next, g, rot, self.max_valence)
        return self._local[signature]


def build_hierarchy(F, n_vertices, creases=None, func="limit_matrix") -> Hierarchy:
    """Validate and refine the control mesh (see :class:`Hierarchy`)."""
    F = validate_faces(F, n_vertices, func)
    cr = parse_creases(creases, F, int(n_vertices), func)
    topo = Topology.build(F, int(n_vertices), cr)
    finite = topo.sharpness[np.isfinite(topo.sharpness)]
    n_levels = max(1, int(finite.max()) if len(finite) else 1)
    levels, Ss = [topo], []
    for _ in range(n_levels):
        S, topo = subdivide_topology(topo)
        Ss.append(S)
        levels.append(topo)
    kind = topo.vertex_kind()
    val = topo.valence()
    # A vertex is irregular for a face unless it is corner-regular for it;
    # evaluated per face corner in `classify`.
    return Hierarchy(levels, Ss, kind, np.zeros(topo.n, bool), int(val.max()))


def classify(h: Hierarchy):
    """Per face at level L: index (0..2) of its irregular corner, or -1."""
    topo = h.top
    F = topo.F
    val = topo.valence()
    reg = np.stack([corner_regular(topo, h.kind, val, F[:, c], F[:, (c + 1) % 3])
                    for c in range(3)], 1)
    n_irr = (~reg).sum(1)
    if (n_irr > 1).any():
        raise RuntimeError("classify(): a face has two irregular corners after subdivision")
    return np.where(n_irr == 0, -1, np.argmax(~reg, axis=1))


def map_to_level(h: Hierarchy, face_ids: np.ndarray, uv: np.ndarray):
    """Face and parameters at level L of control-face points; derivative sign."""
    f = face_ids.astype(np.int64)
    sign = np.ones(len(f))
    for _ in range(len(h.S)):
        child, uv = descend(uv)
        f = 4 * f + child
        sign = np.where(child == 3, -sign, sign)
    return f, uv, sign * 2.0 ** len(h.S)


def _regular_rows(topo, faces, uv, derivative):
    F = topo.F[faces]
    P = stam_points(topo, F[:, 0], F[:, 1], F[:, 2])
    pid, Phis = phantom_matrices(P)
    b = box_basis(uv, derivative)
    W = np.einsum("ki,kij->kj", b, Phis[pid]) if len(Phis) > 1 else b @ Phis[0]
    return np.maximum(P, 0), W


def _irregular_rows(h, faces, rot, uv, derivative):
    """Rows for points in faces whose corner ``rot`` is irregular; ``(idx, W)`` padded."""
    topo = h.top
    F = topo.F[faces]
    r = np.arange(len(faces))
    v, ri, rj = F[r, rot], F[r, (rot + 1) % 3], F[r, (rot + 2) % 3]
    P = irregular_points(topo, v, ri, rj, h.max_valence)
    ok = P >= 0
    sector = ok.copy()
    sector[:, 0] = False
    sector[:, 1 + 2 * h.max_valence:] = False
    sharp = np.zeros_like(P, dtype=bool)
    sharp[sector] = topo.edge_sharp(np.broadcast_to(v[:, None], P.shape)[sector], P[sector])
    sig_arr = np.concatenate([ok, sharp, h.kind[v][:, None] == np.arange(3)], 1)
    sigs, sig_id = np.unique(np.packbits(sig_arr, axis=1), axis=0, return_inverse=True)
    bary = np.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)
    s, t = bary[r, (rot + 1) % 3], bary[r, (rot + 2) % 3]
    idx = np.zeros(P.shape, dtype=np.int64)
    W = np.zeros(P.shape)
    for k_sig in range(len(sigs)):
        sel = np.flatnonzero(sig_id == k_sig)
        first = sel[0]
        loc = h.local(sigs[k_sig].tobytes(), faces[first], rot[first])
        Ps = P[sel]
        K = len(loc.pi)
        cols = np.argsort(Ps < 0, axis=1, kind="stable")[:, :K]  # present slots, in order
        idx[sel, :K] = np.take_along_axis(Ps, cols, 1)
        W[sel, :K] = _local_rows(loc, s[sel], t[sel], derivative)
    return idx, W


def _local_rows(loc, s, t, derivative):
    """Weights over the K patch points (s along v->r_i, t along v->r_j)."""
    st = s + t
    at_vertex = st <= 2.0 ** -MAX_DEPTH
    m = np.where(at_vertex, 0, np.floor(-np.log2(np.maximum(st, 1e-300)))).astype(np.int64)
    m = np.clip(m, 0, MAX_DEPTH)
    # Guard floor() rounding: the scaled sum must lie in (1/2, 1].
    scale = 2.0 ** m
    m = np.where(st * scale > 1.0, m - 1, np.where(st * scale <= 0.5, m + 1, m))
    m = np.clip(m, 0, MAX_DEPTH)
    scale = 2.0 ** m
    ss, tt = s * scale, t * scale
    child = np.where(ss >= 0.5, 0, np.where(tt >= 0.5, 1, 2))
    cu = np.select([child == 0, child == 1], [2 * ss - 1, 2 * ss], 1 - 2 * ss)
    cv = np.select([child == 0, child == 1], [2 * tt, 2 * tt - 1], 1 - 2 * tt)
    cuv = np.clip(np.stack([cu, cv], 1), 0.0, 1.0)
    K = len(loc.pi)
    out = np.zeros((len(s), K))
    factor = np.where(child == 2, -2.0, 2.0) * scale
    if derivative is None:
        b = box_basis(cuv)
        out[:] = loc.pi
        for k in range(3):
            sel = (child == k) & ~at_vertex
            out[sel] += np.einsum("ki,kij->kj", b[sel], loc.G[k][m[sel]])
        return out
    name = {"s": "u", "t": "v"}[derivative]
    b = box_basis(cuv, name)
    for k in range(3):
        sel = (child == k) & ~at_vertex
        out[sel] = factor[sel, None] * np.einsum("ki,kij->kj", b[sel], loc.G[k][m[sel]])
    out[at_vertex] = loc.T[0 if derivative == "s" else 1]
    return out


def level_rows(h: Hierarchy, face_ids, uv, derivative=None):
    """Padded rows ``(idx (k, w), W (k, w))`` over level-L vertices."""
    faces, uvL, sign = map_to_level(h, face_ids, uv)
    irr = classify(h)[faces]
    width = max(12, h.max_valence * 2 + 6 + 1)
    idx = np.zeros((len(faces), width), dtype=np.int64)
    W = np.zeros((len(faces), width))
    reg = irr < 0
    if reg.any():
        i, w = _regular_rows(h.top, faces[reg], uvL[reg], derivative)
        idx[reg, :12], W[reg, :12] = i, w * (sign[reg, None] if derivative else 1.0)
    if (~reg).any():
        sel = np.flatnonzero(~reg)
        rot = irr[sel]
        if derivative is None:
            i, w = _irregular_rows(h, faces[sel], rot, uvL[sel], None)
        else:
            # d/du, d/dv from d/ds, d/dt: (s, t) = barycentrics (rot+1, rot+2).
            i, ws = _irregular_rows(h, faces[sel], rot, uvL[sel], "s")
            _, wt = _irregular_rows(h, faces[sel], rot, uvL[sel], "t")
            col = 1 if derivative == "u" else 2
            dbary = np.zeros((len(sel), 3))
            dbary[:, 0], dbary[:, col] = -1.0, 1.0
            r = np.arange(len(sel))
            ds = dbary[r, (rot + 1) % 3][:, None]
            dt = dbary[r, (rot + 2) % 3][:, None]
            w = (ds * ws + dt * wt) * sign[sel, None]
        idx[sel, :i.shape[1]], W[sel, :i.shape[1]] = i, w
    used = int((W != 0).any(0).nonzero()[0].max()) + 1 if W.size else 0
    return idx[:, :used], W[:, :used]


def _check_samples(face_ids, uv, m, func):
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
    M = sp.csr_matrix((W.ravel(), idx.ravel(), np.arange(0, k * w + 1, w)), shape=(k, n_cols))
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
    diverge; there the rows are unit-norm tangent directions along the two face
    edges, whose cross product is the exact limit normal.

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
    face_ids, uv = _check_samples(face_ids, uv, len(h.levels[0].F), "limit_matrix")
    idx, W = level_rows(h, face_ids, uv, derivative)
    return (padded_to_csr(idx, W, h.top.n) @ h.composed()).tocsr()
