"""The limit operator in Dr.Jit: control points -> limit points, tangents, normals.

Built once per control mesh and sample set; index and weight arrays live on
the device and are reused, so repeated calls launch the same kernels. The
operator is kept factored, ``W = W_L S_L``: ``S_L`` (subdivision to the level
where every face has one irregular corner at most) and ``W_L`` (padded rows of
at most ``N + 6`` weights). Both are padded gathers plus block sums whose
reverse pass is the transposed gather (:mod:`mi_loop.ad.sparse`): forward- and
reverse-mode AD, no atomics, bit-reproducible gradients.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mi_loop.ad.control import ControlPoints
from mi_loop.subdiv.hierarchy import build_hierarchy
from mi_loop.subdiv.limit import check_samples, level_rows, padded_to_csr

__all__ = ["DERIVATIVES", "LimitOperator"]

DERIVATIVES = (None, "u", "v")


#: Columns of the base table of a :class:`_Stage` (a regular patch has 12 control points).
BASE_WIDTH = 12
#: Entries per chunk of a stage's transposed table.
CHUNK = 16


def _csr_to_padded(M: sp.csr_matrix):
    """Padded ``(idx, W)`` of a CSR matrix (rows with fewer entries padded with zeros)."""
    counts = np.diff(M.indptr)
    width = int(counts.max()) if len(counts) else 1
    rows = np.repeat(np.arange(M.shape[0]), counts)
    slot = np.arange(len(M.indices)) - np.repeat(M.indptr[:-1], counts)
    idx = np.zeros((M.shape[0], width), dtype=np.int64)
    W = np.zeros((M.shape[0], width))
    idx[rows, slot], W[rows, slot] = M.indices, M.data
    return idx, W


class _Stage:
    """Padded sparse rows ``y_d[i] = sum_j W_d[i, j] x[idx[i, j]]`` on the device, one index table for all ``d``.

    Forward: one fused kernel over the rows, unrolled over the table's columns
    (each a gather from ``x`` and a multiply-add per weight table), reading the
    indices and weights once. Rows with more than :data:`BASE_WIDTH` entries
    (patches next to an irregular vertex of high valence) keep their extra
    columns in a second, smaller table, added in by a masked gather.

    Reverse: the transposed table, each column's entries cut into chunks of
    :data:`CHUNK` (unrolled the same way, gathering the output adjoints of
    nearby rows) and the chunk sums reduced per column by a
    :class:`~mi_loop.ad.sparse.SegmentSum`. Gathers and fixed-order sums only:
    no atomics, so gradients are bit-reproducible.
    """

    def __init__(self, idx: np.ndarray, weights: dict, n_cols: int):
        import mitsuba as mi

        from mi_loop.ad.sparse import SegmentSum
        from mi_loop.ad.upload import upload_float, upload_uint

        idx = np.asarray(idx, dtype=np.int64)
        self.rows, self.n_cols, self.names = len(idx), int(n_cols), tuple(weights)
        Ws = [np.asarray(weights[d], dtype=np.float64) for d in self.names]
        base = min(BASE_WIDTH, idx.shape[1])
        self.idx = [upload_uint(np.ascontiguousarray(idx[:, j])) for j in range(base)]
        self.w = [[upload_float(np.ascontiguousarray(W[:, j])) for j in range(base)] for W in Ws]
        used = np.zeros(idx.shape, bool)
        for W in Ws:
            used |= W != 0
        wide = np.flatnonzero(used[:, base:].any(axis=1)) if idx.shape[1] > base else np.zeros(0, np.int64)
        self.wide = None
        if len(wide):
            extra = int(np.flatnonzero(used[wide][:, base:].any(axis=0)).max()) + 1
            slot = np.zeros(self.rows, dtype=np.int64)
            slot[wide] = np.arange(len(wide))
            is_wide = np.zeros(self.rows, bool)
            is_wide[wide] = True
            self.wide = (upload_uint(slot), mi.Bool(is_wide),
                         [upload_uint(np.ascontiguousarray(idx[wide, base + j])) for j in range(extra)],
                         [[upload_float(np.ascontiguousarray(W[wide, base + j])) for j in range(extra)]
                          for W in Ws])
        # Transposed table: every used entry, grouped by column, chunked.
        r, c = np.nonzero(used)
        col = idx[r, c]
        order = np.argsort(col, kind="stable")          # within a column: rows in increasing order
        r, c, col = r[order], c[order], col[order]
        counts = np.bincount(col, minlength=self.n_cols)
        chunks = np.maximum(1, -(-counts // CHUNK))
        pos = np.arange(len(col)) - np.repeat(np.cumsum(counts) - counts, counts)
        chunk = np.repeat(np.cumsum(chunks) - chunks, counts) + pos // CHUNK
        t_idx = np.zeros((CHUNK, int(chunks.sum())), dtype=np.int64)
        t_idx[pos % CHUNK, chunk] = r
        self.t_idx = [upload_uint(a) for a in t_idx]
        self.t_w = []
        for W in Ws:
            t_w = np.zeros((CHUNK, int(chunks.sum())))
            t_w[pos % CHUNK, chunk] = W[r, c]
            self.t_w.append([upload_float(a) for a in t_w])
        self.t_sum = SegmentSum(np.repeat(np.arange(self.n_cols), chunks), self.n_cols)

    def forward(self, x, names):
        """Rows ``names`` applied to ``x`` (3-vector type of width ``n_cols``): a list of ``mi.Point3f``."""
        import drjit as dr
        import mitsuba as mi

        x = mi.Point3f(x)
        ks = [self.names.index(d) for d in names]
        acc = [None] * len(ks)
        for j, i in enumerate(self.idx):
            g = dr.gather(mi.Point3f, x, i)
            acc = [g * self.w[k][j] if a is None else dr.fma(g, self.w[k][j], a) for a, k in zip(acc, ks)]
        if self.wide is not None:
            slot, is_wide, idx, w = self.wide
            extra = [None] * len(ks)
            for j, i in enumerate(idx):
                g = dr.gather(mi.Point3f, x, i)
                extra = [g * w[k][j] if e is None else dr.fma(g, w[k][j], e) for e, k in zip(extra, ks)]
            dr.eval(extra)
            acc = [a + dr.gather(mi.Point3f, e, slot, is_wide) for a, e in zip(acc, extra)]
        return acc

    def backward(self, grads, names):
        """``sum_d W_d^T grads[d]`` for the rows ``names``: ``mi.Point3f`` of width ``n_cols``."""
        import drjit as dr
        import mitsuba as mi

        grads = [mi.Point3f(g) for g in grads]
        dr.eval(grads)
        ks = [self.names.index(d) for d in names]
        acc = None
        for j, i in enumerate(self.t_idx):
            for g, k in zip(grads, ks):
                term = dr.gather(mi.Point3f, g, i)
                acc = term * self.t_w[k][j] if acc is None else dr.fma(term, self.t_w[k][j], acc)
        return self.t_sum(acc)


def _apply_op():
    """The ``dr.CustomOp`` of :meth:`LimitOperator._apply` (defined on first use: drjit is imported lazily)."""
    global _APPLY_OP
    if _APPLY_OP is None:
        import drjit as dr

        class Apply(dr.CustomOp):
            """Control points -> the rows ``names`` of ``stage_rows @ stage_S``; reverse by the transposed tables."""

            def eval(self, stages, x, names):
                self.stages, self.names = stages, names
                return tuple(_forward(stages, x, names))

            def forward(self):
                self.set_grad_out(tuple(_forward(self.stages, self.grad_in("x"), self.names)))

            def backward(self):
                S, rows = self.stages
                g = self.grad_out()
                self.set_grad_in("x", S.backward([rows.backward(list(g), self.names)], (None,)))

            def name(self):
                return "LimitOperator"

        _APPLY_OP = Apply
    return _APPLY_OP


def _forward(stages, x, names):
    S, rows = stages
    return rows.forward(S.forward(x, (None,))[0], names)


_APPLY_OP = None


class LimitOperator:
    """Exact Loop limit positions and derivatives at fixed samples, in Dr.Jit.

    Parameters
    ----------
    F : (m, 3) int numpy array
        Control faces.
    n_vertices : int
        Number of control vertices ``n``.
    face_ids : (k,) int numpy array
        Control face of every sample.
    uv : (k, 2) float numpy array
        Sample parameters (see :func:`mi_loop.limit_matrix`).
    creases : optional
        As in :func:`mi_loop.subdivision_matrix`.
    derivatives : bool
        Also build the ``d/du`` and ``d/dv`` rows (needed for tangents and normals).

    Examples
    --------
    >>> import numpy as np, mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    >>> op = mi_loop.LimitOperator(F, 4, np.array([0, 1]), np.array([[0.2, 0.3], [0.5, 0.5]]))
    >>> P = op.positions(mi.Float(V.ravel()))
    >>> np.allclose(np.array(P).T, (op.matrix() @ V), atol=1e-6)
    True
    """

    def __init__(self, F, n_vertices, face_ids, uv, creases=None, derivatives: bool = True):
        h = build_hierarchy(F, n_vertices, creases, "LimitOperator")
        self.face_ids, self.uv = check_samples(face_ids, uv, len(h.levels[0].F), "LimitOperator")
        self.n = int(n_vertices)
        self.n_samples = len(self.face_ids)
        self.derivatives = bool(derivatives)
        names = DERIVATIVES if derivatives else (None,)
        self._rows = dict(zip(names, level_rows(h, self.face_ids, self.uv, names)))
        self._S = h.composed()
        self._n_level = h.top.n
        self._device = None

    # -- SciPy views --------------------------------------------------------
    def matrix(self, derivative=None) -> sp.csr_matrix:
        """The composed ``(k, n)`` CSR matrix of positions (or ``'u'``/``'v'`` derivatives)."""
        idx, W = self._rows[derivative]
        return (padded_to_csr(idx, W, self._n_level) @ self._S).tocsr()

    # -- Dr.Jit ---------------------------------------------------------------
    def _dev(self):
        if self._device is None:
            S_idx, S_w = _csr_to_padded(self._S)
            idx = self._rows[None][0]          # level_rows gives every derivative the same index table
            if any(i is not idx for i, _ in self._rows.values()):
                raise RuntimeError("LimitOperator: internal error: derivative rows with their own index tables")
            self._device = (_Stage(S_idx, {None: S_w}, self.n),
                            _Stage(idx, {d: W for d, (_, W) in self._rows.items()}, self._n_level))
        return self._device

    def _points(self, x):
        return ControlPoints.of(x, self.n, "LimitOperator").points

    def _apply(self, x, names):
        """The rows ``names`` at control points ``x``: gradients through one custom operation."""
        import drjit as dr

        P = self._points(x)
        if not dr.grad_enabled(P):
            return _forward(self._dev(), P, names)
        return list(dr.custom(_apply_op(), self._dev(), P, names))

    def evaluate(self, x):
        """Limit points and parametric derivatives.

        Parameters
        ----------
        x : ControlPoints, mi.Float (3n, xyz interleaved), mi.TensorXf (n, 3) or (n, 3) numpy array
            Control points, possibly with gradients enabled. Pass the same
            :class:`~mi_loop.ad.control.ControlPoints` to every term of one
            energy (see its notes).

        Returns
        -------
        P : mi.Point3f (k)
        du, dv : mi.Vector3f (k)
            ``dP/du`` and ``dP/dv`` (unit tangent directions at irregular vertices).
        """
        import mitsuba as mi

        if "u" not in self._rows:
            raise ValueError("LimitOperator.evaluate(): built with derivatives=False")
        P, du, dv = self._apply(x, DERIVATIVES)
        return P, mi.Vector3f(du), mi.Vector3f(dv)

    def positions(self, x):
        """Limit points ``mi.Point3f (k)`` of control points ``x`` (see :meth:`evaluate`)."""
        return self._apply(x, (None,))[0]

    def positions_normals(self, x):
        """Limit points and unit limit normals from one evaluation: ``(mi.Point3f, mi.Normal3f)``."""
        import drjit as dr
        import mitsuba as mi

        P, du, dv = self.evaluate(x)
        return P, mi.Normal3f(dr.normalize(dr.cross(du, dv)))

    def normals(self, x):
        """Unit limit normals ``mi.Normal3f (k)``, ``normalize(cross(du, dv))``."""
        return self.positions_normals(x)[1]
