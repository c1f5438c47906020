"""Limit rows over the control vertices in one pass per sample (NumPy + Numba).

:func:`~mi_loop.subdiv.limit.level_rows` gives each sample's row over the
level-``L`` vertices of the :class:`~mi_loop.subdiv.hierarchy.Hierarchy`; the
limit matrix over the control vertices is that row times the composed
subdivision matrix ``S_L``. A sparse-times-sparse product would rediscover,
sample by sample, a pattern that only depends on the level-``L`` face. Here it
is found once per face instead:

- ``D_f`` (:func:`face_tables`, for the faces that hold samples only): the
  face's patch points' rows of ``S_L``, dense over the sorted control
  columns they reach (12-20 on a closed mesh);
- regular faces: the box-spline polynomial (:mod:`~mi_loop.subdiv.boxspline`),
  the face's phantom matrix and ``D_f`` multiplied once per face that holds a
  sample, ``Q_f = C Phi_f D_f`` (15 quartic monomials, 10 cubic ones for
  each derivative). A sample's row is then its monomials times ``Q_f``: one
  short dot product per control column, with no sparse index arithmetic;
- faces with an irregular corner: the rows of
  :class:`~mi_loop.subdiv.irregular.IrregularSamples` over the patch points
  times ``D_f``.

The CSR arrays are written in place, one row per sample, in parallel
(each row by one thread, in a fixed order: bit-identical results whatever the
thread count). Exact zeros are dropped, so the matrices equal the sparse
products up to rounding (about 1e-16; an entry the product rounds to zero may
be kept as a value of order 1e-17, and the other way round).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mi_loop._numba import numba as nb
from mi_loop.subdiv.boxspline import COEFFICIENTS
from mi_loop.subdiv.irregular import IrregularSamples

__all__ = ["composed_rows", "face_tables", "level_params"]


@nb.njit(parallel=True, cache=True)
def _map_to_level(face_ids, uv, levels, faces, u_out, v_out, scale):       # pragma: no cover (compiled)
    """Face and ``(u, v)`` at level ``L`` of control-face points, and the derivative factor (:func:`level_params`)."""
    for i in nb.prange(len(face_ids)):
        f, u, v, sign = face_ids[i], uv[i, 0], uv[i, 1], 1.0
        for _ in range(levels):
            c1 = u >= 0.5
            c2 = (v >= 0.5) and not c1
            mid = (u + v > 0.5) and not (c1 or c2)
            f = 4 * f + c1 + 2 * c2 + 3 * mid
            u = 2.0 * u - c1
            v = 2.0 * v - c2
            if mid:
                u, v, sign = 1.0 - u, 1.0 - v, -sign
            u, v = min(max(u, 0.0), 1.0), min(max(v, 0.0), 1.0)
        faces[i], u_out[i], v_out[i], scale[i] = f, u, v, sign * 2.0 ** levels


@nb.njit(parallel=True, cache=True)
def _face_columns(face_P, active, indptr, indices, cols, ncols):            # pragma: no cover (compiled)
    """Sorted union of the ``S_L`` columns of every face's active patch points."""
    for f in nb.prange(face_P.shape[0]):
        n = 0
        for j in range(face_P.shape[1]):
            if not active[f, j]:
                continue
            r = face_P[f, j]
            for p in range(indptr[r], indptr[r + 1]):
                c = indices[p]
                q = 0
                while q < n and cols[f, q] < c:
                    q += 1
                if q < n and cols[f, q] == c:
                    continue
                for s in range(n, q, -1):
                    cols[f, s] = cols[f, s - 1]
                cols[f, q] = c
                n += 1
        ncols[f] = n


@nb.njit(parallel=True, cache=True)
def _face_dense(face_P, active, indptr, indices, data, cols, ncols, D):    # pragma: no cover (compiled)
    """``D[f, j, q] = S_L[face_P[f, j], cols[f, q]]`` over the active patch points."""
    for f in nb.prange(face_P.shape[0]):
        for j in range(face_P.shape[1]):
            if not active[f, j]:
                continue
            r = face_P[f, j]
            for p in range(indptr[r], indptr[r + 1]):
                c = indices[p]
                lo, hi = 0, ncols[f]
                while lo < hi:
                    mid = (lo + hi) // 2
                    if cols[f, mid] < c:
                        lo = mid + 1
                    else:
                        hi = mid
                D[f, j, lo] += data[p]


@nb.njit(parallel=True, cache=True)
def _face_polynomials(C4, C3u, C3v, Phis, pid, phantom, D, ncols, Q):    # pragma: no cover (compiled)
    """``Q[f] = C Phi_f D_f`` of regular faces: ``(35, C)`` each.

    Rows 0-14: the quartic's monomial coefficients of each control column;
    15-24 and 25-34: those of the cubic d/du and d/dv (``C``:
    :data:`~mi_loop.subdiv.boxspline.COEFFICIENTS`).
    """
    for f in nb.prange(len(ncols)):
        nc = ncols[f]
        P = D[f, :12, :nc].copy()
        if phantom[f]:
            P = Phis[pid[f]] @ P
        Q[f] = 0.0
        for j in range(12):
            for c in range(nc):
                x = P[j, c]
                if x == 0.0:
                    continue
                for q in range(15):
                    Q[f, q, c] += C4[q, j] * x
                for q in range(10):
                    Q[f, 15 + q, c] += C3u[q, j] * x
                    Q[f, 25 + q, c] += C3v[q, j] * x


@nb.njit(parallel=True, cache=True)
def _regular_rows(regular, slot, u, v, scale, Q, cols, ncols, offsets, out, indices):    # pragma: no cover
    """Rows of the samples in regular faces: monomials of ``(1 - u - v, u, v)`` times ``Q[slot[i]]``.

    In sample order, so that the rows are written one after the other (a
    row-by-row scatter in face order costs twice the time on shuffled
    samples); ``Q`` is read per sample. ``out`` and ``indices`` hold the
    arrays of the positions, d/du and d/dv; an empty array is a matrix not
    wanted. The dot products run over ``q`` outside, control columns inside
    (vectorised, each entry summed in a fixed order).
    """
    block, width = 4096, Q.shape[2]
    for first in nb.prange((len(slot) + block - 1) // block):
        m3, m4 = np.empty(10), np.empty(15)
        acc = np.empty(width)
        for i in range(first * block, min(len(slot), (first + 1) * block)):
            if not regular[i]:
                continue
            f, wb, wc = slot[i], u[i], v[i]
            _monomials(1.0 - wb - wc, wb, wc, m3, m4)
            base, nc = offsets[i], ncols[f]
            for which in range(3):                   # positions, d/du (Q rows 15-24), d/dv (25-34)
                data, index = out[which], indices[which]
                if len(data) == 0:
                    continue
                mono, q0, factor = (m4, 0, 1.0) if which == 0 else (m3, 5 + 10 * which, scale[i])
                acc[:] = 0.0
                for q in range(len(mono)):
                    for c in range(width):
                        acc[c] += mono[q] * Q[f, q0 + q, c]
                for c in range(nc):
                    data[base + c] = factor * acc[c]
                    index[base + c] = cols[f, c]


@nb.njit(inline="always")
def _monomials(wa, wb, wc, m3, m4):                                          # pragma: no cover (compiled)
    """Cubic and quartic monomials ``wa^i wb^j wc^(d-i-j)``, ``i`` then ``j`` descending (boxspline's order)."""
    _degree_monomials(wa, wb, wc, 3, m3)
    _degree_monomials(wa, wb, wc, 4, m4)


@nb.njit(inline="always")
def _degree_monomials(wa, wb, wc, degree, out):                             # pragma: no cover (compiled)
    q = 0
    for i in range(degree, -1, -1):
        for j in range(degree - i, -1, -1):
            x = 1.0
            for _ in range(i):
                x *= wa
            for _ in range(j):
                x *= wb
            for _ in range(degree - i - j):
                x *= wc
            out[q] = x
            q += 1


@nb.njit(parallel=True, cache=True)
def _patch_rows(rows, slot, W, dest, D, cols, ncols, offsets, out, indices):    # pragma: no cover (compiled)
    """Rows over the patch points ``W[d, t]`` (sample ``rows[t]``) times its face's ``D``, into ``out[dest[d]]``.

    ``slot[i]``: the entry of sample ``i``'s face in ``D``, ``cols`` and ``ncols``.
    """
    for t in nb.prange(len(rows)):
        i = rows[t]
        f = slot[i]
        base = offsets[i]
        for c in range(ncols[f]):
            for d in range(W.shape[0]):
                acc = 0.0
                for j in range(W.shape[2]):
                    acc += W[d, t, j] * D[f, j, c]
                out[dest[d]][base + c] = acc
                indices[dest[d]][base + c] = cols[f, c]


def face_tables(h, faces, width: int):
    """Return the control columns and dense ``S_L`` rows of some level-``L`` faces.

    Parameters
    ----------
    h : Hierarchy
    faces : (f,) int numpy array
        Level-``L`` faces.
    width : int
        Patch points per face to take (12 for regular faces; at least the
        ``irr_K`` of faces with an irregular corner).

    Returns
    -------
    cols : (f, C) int32 numpy array
        Sorted control vertices that face ``faces[i]``'s patch points depend
        on, in its first ``ncols[i]`` entries.
    ncols : (f,) int64 numpy array
    D : (f, width, C) float64 numpy array
        ``D[i, j, q]``: weight of control vertex ``cols[i, q]`` in patch
        point ``j`` of face ``faces[i]`` (zero for padding and phantom slots).
    """
    S = h.composed()
    S.sort_indices()
    face_P = np.ascontiguousarray(h.face_P[faces, :width])
    irr = h.irr_corner[faces] >= 0
    active = np.zeros(face_P.shape, dtype=bool)
    active[irr] = np.arange(width) < h.irr_K[faces[irr], None]
    reg = np.flatnonzero(~irr)
    active[reg, :12] = (h.Phis != 0).any(axis=1)[h.reg_pid[faces[reg]]]   # phantom slots have zero columns
    bound = int(np.diff(S.indptr).max(initial=1)) * width
    cols = np.zeros((len(faces), bound), dtype=np.int32)
    ncols = np.zeros(len(faces), dtype=np.int64)
    _face_columns(face_P, active, S.indptr, S.indices, cols, ncols)
    cols = np.ascontiguousarray(cols[:, :max(1, int(ncols.max(initial=1)))])
    D = np.zeros((len(faces), width, cols.shape[1]))
    _face_dense(face_P, active, S.indptr, S.indices, S.data, cols, ncols, D)
    return cols, ncols, D


def composed_rows(h, face_ids, uv, derivatives):
    """Return the limit matrices over the control vertices, one per derivative, sharing one pass.

    Parameters
    ----------
    h : Hierarchy
        From :func:`~mi_loop.subdiv.hierarchy.build_hierarchy`.
    face_ids : (k,) int64 numpy array
    uv : (k, 2) float64 numpy array
        Samples, checked by :func:`~mi_loop.subdiv.limit.check_samples`.
    derivatives : tuple of None, 'u', 'v'
        Which matrices, in order (repeats allowed).

    Returns
    -------
    list of scipy.sparse.csr_matrix, shape ``(k, n)``, float64
        Sorted indices, no explicit zeros.
    """
    k, n = len(face_ids), h.levels[0].n
    faces, u, v, scale = level_params(h, face_ids, uv)
    # Tables of the faces that hold samples only, regular and irregular apart (memory: at most
    # 35 + 12 doubles per control column of a regular face, w of an irregular one).
    regular = h.irr_corner[faces] < 0
    used = np.zeros(len(h.face_P), dtype=bool)
    used[faces] = True
    slot = np.zeros(len(h.face_P), dtype=np.int64)
    reg_faces = np.flatnonzero(used & (h.irr_corner < 0))
    irr_faces = np.flatnonzero(used & (h.irr_corner >= 0))
    slot[reg_faces], slot[irr_faces] = np.arange(len(reg_faces)), np.arange(len(irr_faces))
    slot = slot[faces]
    cols_r, ncols_r, D_r = face_tables(h, reg_faces, 12)
    cols_i, ncols_i, D_i = face_tables(h, irr_faces, int(h.irr_K[irr_faces].max(initial=12)))
    counts = np.empty(k, dtype=np.int64)
    counts[regular], counts[~regular] = ncols_r[slot[regular]], ncols_i[slot[~regular]]
    itype = np.int32 if counts.sum() < 2 ** 31 else np.int64      # one dtype for indices and indptr: no copies
    offsets = np.zeros(k + 1, dtype=itype)
    np.cumsum(counts, out=offsets[1:])
    names = [d for d in (None, "u", "v") if d in derivatives]
    dest = np.array([0 if None in names else -1, 1 if "u" in names else -1, 2 if "v" in names else -1])
    # One array per matrix (not rows of one buffer: SciPy copies arrays that are views of a much larger one).
    nnz = int(offsets[-1])
    out = tuple(np.empty(nnz if d in names else 0) for d in (None, "u", "v"))
    indices = tuple(np.empty(nnz if d in names else 0, dtype=itype) for d in (None, "u", "v"))
    Q = np.empty((len(reg_faces), 35, cols_r.shape[1]))
    _face_polynomials(COEFFICIENTS[None], COEFFICIENTS["u"], COEFFICIENTS["v"], h.Phis, h.reg_pid[reg_faces],
                      h.phantom[reg_faces], D_r, ncols_r, Q)
    _regular_rows(regular, slot, u, v, scale, Q, cols_r, ncols_r, offsets, out, indices)
    ii = np.flatnonzero(~regular)
    if len(ii):
        W = _irregular_level_rows(h, faces[ii], u[ii], v[ii], scale[ii], names, D_i.shape[1])
        _patch_rows(ii, slot, W, dest[dest >= 0], D_i, cols_i, ncols_i, offsets, out, indices)
    matrices = {d: _csr(out[a], indices[a], offsets.copy(), (k, n)) for a, d in enumerate((None, "u", "v"))
                if d in names}
    return [matrices[d] if derivatives.index(d) == a else matrices[d].copy() for a, d in enumerate(derivatives)]


def level_params(h, face_ids, uv):
    """Return the level-``L`` face and parameters of every sample, and its derivative factor.

    Child 0, 1, 2 of a face holds its corner 0, 1, 2 and child 3 is the
    middle face, turned by half a turn (its parameters and derivatives
    change sign).

    Parameters
    ----------
    h : Hierarchy
    face_ids : (k,) int numpy array
    uv : (k, 2) float64 numpy array
        Samples, checked by :func:`~mi_loop.subdiv.limit.check_samples`.

    Returns
    -------
    faces : (k,) int64 numpy array
    u, v : (k,) float64 numpy arrays
    scale : (k,) float64 numpy array
        ``+-2^L``: d/du and d/dv at level ``L`` times this are those in the control face.
    """
    k = len(face_ids)
    faces, u, v, scale = np.empty(k, np.int64), np.empty(k), np.empty(k), np.empty(k)
    _map_to_level(np.ascontiguousarray(face_ids, dtype=np.int64), np.ascontiguousarray(uv, dtype=np.float64),
                  len(h.S), faces, u, v, scale)
    return faces, u, v, scale


def _irregular_level_rows(h, faces, u, v, scale, names, width):
    """Rows over the patch points of samples in faces with an irregular corner: ``(len(names), k, width)``."""
    patch = IrregularSamples(h, np.arange(len(faces)), faces, u, v, scale)
    W = {d: np.empty((len(faces), width)) for d in names}
    patch.apply(h, W)
    return np.stack([W[d] for d in names])


def _csr(data, indices, indptr, shape):
    """CSR matrix of rows with sorted columns, exact zeros dropped (in place: the arrays are its own)."""
    M = sp.csr_matrix((data, indices, indptr), shape=shape)
    M.has_sorted_indices = True
    if not data.all():
        M.eliminate_zeros()
    return M
