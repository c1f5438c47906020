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
from mi_loop.subdiv.limit import check_samples, level_rows, requested_derivatives

__all__ = ["DERIVATIVES", "LimitOperator"]

DERIVATIVES = (None, "u", "v")

#: Slots per chunk of the rows' transposed table: one array is read per slot, and more streams than
#: this thrash the prefetchers (655k shuffled samples, 2 cores, reverse pass of positions: 12.8 ms at
#: 12 slots, 13.6 at 8, 14.1 at 16, 20.5 at 32).
TRANSPOSED_WIDTH = 12


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


class _Padded:
    """Padded sparse rows on the device sharing one index table: ``y_d,i = sum_j W_d[i, j] x[idx[i, j]]``.

    One gather of all ``rows * width`` entries (an :class:`~mi_loop.ad.sparse.IndexMap`,
    whose reverse pass is the transposed gather), then a block sum over each
    row per weight table: no atomics in either direction, so gradients are
    bit-reproducible. Positions and both derivatives of a sample set have the
    same index table, so :meth:`apply` gathers once for all three.
    """

    def __init__(self, idx: np.ndarray, weights: dict, n_cols: int):
        from mi_loop.ad.sparse import IndexMap
        from mi_loop.ad.upload import upload_float

        self.width = idx.shape[1]
        self.gather = IndexMap(np.ascontiguousarray(idx, dtype=np.int64).ravel(), n_cols)
        self.w = {d: upload_float(W) for d, W in weights.items()}

    def apply(self, x, names=(None,)):
        """Rows ``names`` applied to ``x`` (``mi.Point3f``/``mi.Vector3f`` of width ``n_cols``): a list."""
        import drjit as dr

        cls = type(x)
        gathered = self.gather(x)
        out = []
        for d in names:
            terms = self.w[d] * gathered
            out.append(cls(*(dr.block_sum(terms[c], self.width, mode="evaluated") for c in range(3))))
        return out


class _Rows:
    """The sample rows over the level-``L`` points as one kernel per direction, with a transposed table.

    Forward: ``y_d,i = sum_j W_d[i, j] x[idx[i, j]]``, the ``w`` slots
    unrolled (one array per slot, read contiguously; ``x`` gathered once per
    slot for every ``d``), so no ``rows * w`` temporary is written. Reverse:
    the entries sorted by column (stable) and cut into chunks of at most
    :data:`TRANSPOSED_WIDTH` per column, stored slot by slot as (sample,
    weights); one kernel sums each
    chunk's ``W_d * adjoint_d[sample]`` in slot order, and a
    :class:`~mi_loop.ad.sparse.SegmentSum` adds the chunks of every column.
    Both directions gather only: no atomics, bit-reproducible gradients.
    The transposed table is built with the forward one.

    The transposed table takes the samples in the order ``order`` (grouped by
    level-``L`` face), whatever their own order, and the adjoints are
    permuted into it by one gather: each chunk then reads the adjoints of
    neighbouring samples (on 655k shuffled samples, 2 cores, in 32-slot
    chunks, the reverse pass of positions took 18 ms without it and 12 ms
    with it, gather included).
    """

    def __init__(self, idx: np.ndarray, weights: dict, n_cols: int, order: np.ndarray):
        from mi_loop.ad.sparse import SegmentSum
        from mi_loop.ad.tables import forward_tables, transposed_tables
        from mi_loop.ad.upload import upload_float, upload_uint

        self.k, self.n_cols, names = idx.shape[0], int(n_cols), list(weights)
        W = tuple(weights[d] for d in names)
        idx_t, w_t = forward_tables(idx, W)
        self.idx = [upload_uint(a) for a in idx_t]
        self.w = {d: [upload_float(a) for a in w_t[q]] for q, d in enumerate(names)}
        sample, weights_t, chunk_col = transposed_tables(idx, W, order, self.n_cols, TRANSPOSED_WIDTH)
        self.order = upload_uint(order)
        self.t_sample = [upload_uint(a) for a in sample]
        self.t_w = {d: [upload_float(a) for a in weights_t[q]] for q, d in enumerate(names)}
        self.t_sum = SegmentSum(chunk_col, self.n_cols)

    def forward(self, x, names):
        """``[y_d for d in names]`` of points ``x`` (a 3-vector type, width ``n_cols``), no AD."""
        import drjit as dr

        cls = type(x)
        acc = {d: dr.zeros(cls, self.k) for d in names}
        for j, idx in enumerate(self.idx):
            p = dr.gather(cls, x, idx)
            for d in names:
                acc[d] = dr.fma(self.w[d][j], p, acc[d])
        return [acc[d] for d in names]

    def backward(self, grad, derivative):
        """Adjoint at the ``n_cols`` points of ``grad`` (3-vector type, width ``k``), that of rows ``derivative``."""
        import drjit as dr

        cls = type(grad)
        dr.eval(grad)       # every component in one kernel (gathers would evaluate them one by one)
        grad = dr.gather(cls, grad, self.order)     # in the table's row order
        dr.eval(grad)
        acc = dr.zeros(cls, dr.width(self.t_sample[0]))
        for weights, sample in zip(self.t_w[derivative], self.t_sample):
            acc = dr.fma(weights, dr.gather(cls, grad, sample, sample < self.k), acc)
        return self.t_sum(acc)

    def apply(self, x, names=(None,)):
        """Rows ``names`` applied to ``x`` (``mi.Point3f``/``mi.Vector3f`` of width ``n_cols``): a list."""
        import drjit as dr

        if not dr.grad_enabled(x):
            return self.forward(x, names)
        # One custom operation per output: under Mitsuba's nested traversals (mi.render's reverse pass
        # reaching limit normals through an emitter's radiance), an operation with three outputs was
        # handed adjoints of outputs it had already propagated (test_sequence_photos' exposure test).
        return [dr.custom(_rows_op(), self, x, d) for d in names]


def _rows_op():
    """The ``dr.CustomOp`` behind :class:`_Rows` (defined on first use: drjit is imported lazily)."""
    global _ROWS_OP
    if _ROWS_OP is None:
        import drjit as dr

        class RowsOp(dr.CustomOp):
            def eval(self, rows, x, derivative):
                self.rows, self.cls, self.derivative = rows, type(x), derivative
                return rows.forward(x, (derivative,))[0]

            def forward(self):
                self.set_grad_out(self.rows.forward(self.grad_in("x"), (self.derivative,))[0])

            def backward(self):
                self.set_grad_in("x", self.cls(self.rows.backward(self.cls(self.grad_out()), self.derivative)))

            def name(self):
                return "LimitRows"

        _ROWS_OP = RowsOp
    return _ROWS_OP


_ROWS_OP = None


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
    corners, boundary, crease_method : optional
        The rest of the crease model, as in :func:`mi_loop.subdivision_matrix`.

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

    def __init__(self, F, n_vertices, face_ids, uv, creases=None, derivatives: bool = True, *, corners=None,
                 boundary="edge_and_corner", crease_method="uniform"):
        h = build_hierarchy(F, n_vertices, creases, "LimitOperator", corners=corners, boundary=boundary,
                            crease_method=crease_method)
        self.face_ids, self.uv = check_samples(face_ids, uv, len(h.levels[0].F), "LimitOperator",
                                               h.levels[0].hole)
        self.n = int(n_vertices)
        self.n_samples = len(self.face_ids)
        self.derivatives = bool(derivatives)
        names = DERIVATIVES if derivatives else (None,)
        self._rows = dict(zip(names, level_rows(h, self.face_ids, self.uv, names)))
        self._h = h
        self._S = h.composed()
        self._n_level = h.top.n
        self._device = None
        self._positions_csr = None

    # -- SciPy views --------------------------------------------------------
    def matrix(self, derivative=None):
        """The ``(k, n)`` CSR matrix of positions (``'u'``/``'v'``: derivatives; a tuple: one matrix each).

        The same matrices as :func:`mi_loop.limit_matrix` (sorted indices, no
        explicit zeros); a tuple such as ``(None, 'u', 'v')`` builds them in
        one pass.
        """
        from mi_loop.subdiv.compose import composed_rows  # Numba: imported on first use

        several, wanted = requested_derivatives(
            derivative, "LimitOperator.matrix", ("u", "v") if self.derivatives else (),
            "None, 'u' or 'v'" if self.derivatives else "None (built with derivatives=False)")
        matrices = composed_rows(self._h, self.face_ids, self.uv, wanted)
        return tuple(matrices) if several else matrices[0]

    def positions_matrix(self) -> sp.csr_matrix:
        """:meth:`matrix` of positions, built at the first call and kept (Gauss-Newton matrices, step guards)."""
        if self._positions_csr is None:
            self._positions_csr = self.matrix()
        return self._positions_csr

    # -- Dr.Jit ---------------------------------------------------------------
    def _dev(self):
        if self._device is None:
            S_idx, S_w = _csr_to_padded(self._S)
            idx = self._rows[None][0]          # level_rows gives every derivative the same index table
            if any(i is not idx for i, _ in self._rows.values()):
                raise RuntimeError("LimitOperator: internal error: derivative rows with their own index tables")
            from mi_loop.subdiv.compose import level_params  # Numba: imported on first use

            faces = level_params(self._h, self.face_ids, self.uv)[0]
            self._device = {"S": _Padded(S_idx, {None: S_w}, self.n),
                            "rows": _Rows(idx, {d: W for d, (_, W) in self._rows.items()}, self._n_level,
                                          np.argsort(faces, kind="stable"))}
        return self._device

    def _points(self, x):
        return ControlPoints.of(x, self.n, "LimitOperator").points

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
        dev = self._dev()
        xL = dev["S"].apply(self._points(x))[0]
        P, du, dv = dev["rows"].apply(xL, DERIVATIVES)
        return P, mi.Vector3f(du), mi.Vector3f(dv)

    def positions(self, x):
        """Limit points ``mi.Point3f (k)`` of control points ``x`` (see :meth:`evaluate`)."""
        dev = self._dev()
        return dev["rows"].apply(dev["S"].apply(self._points(x))[0])[0]

    def positions_normals(self, x):
        """Limit points and unit limit normals from one evaluation: ``(mi.Point3f, mi.Normal3f)``."""
        import drjit as dr
        import mitsuba as mi

        P, du, dv = self.evaluate(x)
        return P, mi.Normal3f(dr.normalize(dr.cross(du, dv)))

    def normals(self, x):
        """Unit limit normals ``mi.Normal3f (k)``, ``normalize(cross(du, dv))``."""
        return self.positions_normals(x)[1]
