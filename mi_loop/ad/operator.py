"""The limit operator in Dr.Jit: control points -> limit points, tangents, normals.

Built once per control mesh and sample set; index and weight arrays live on
the device and are reused, so repeated calls launch the same kernels. The
operator is kept factored, ``W = W_L S_L``: ``S_L`` (subdivision to the level
where every face has one irregular corner at most) and ``W_L`` (padded rows of
at most ``N + 6`` weights). Both are linear maps written with ``dr.gather``,
so forward- and reverse-mode AD come from Dr.Jit.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mi_loop.subdiv.limit import check_samples, build_hierarchy, level_rows, padded_to_csr

DERIVATIVES = (None, "u", "v")


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


_UNRAVELLED: list = [None, None, None]  # [(index, index_ad), handle, Point3f]: last variable


def unravel_points(x):
    """``mi.Point3f (n)`` from a flat ``mi.Float (3n)`` (xyz interleaved), differentiably.

    Every consumer of the same variable (limit operators, ARAP, the
    ``loop_subdiv`` plugin) receives the same unravelled array: in Dr.Jit
    1.5.0, when one AD variable is gathered into two separate intermediate
    arrays that are gathered again, the reverse pass mis-accumulates the third
    component (reproduced in ``tests/test_operator.py``). Sharing one
    intermediate avoids it. The cached variable is held, so its index cannot be
    reused by another array while cached (a separate handle is held: the
    caller's Python object may later be assigned new contents in place).
    """
    import drjit as dr
    import mitsuba as mi

    key = (x.index, x.index_ad)
    if _UNRAVELLED[0] == key:
        return _UNRAVELLED[2]
    points = dr.gather(mi.Point3f, x, dr.arange(mi.UInt32, dr.width(x) // 3))
    _UNRAVELLED[:] = [key, type(x)(x), points]
    return points


def forget_unravelled() -> None:
    """Drop the cached unravelled array (before building a new graph from the same variable)."""
    _UNRAVELLED[:] = [None, None, None]


class _Padded:
    """A padded sparse matrix on the device: ``y_i = sum_j W[i, j] x[idx[i, j]]``.

    One gather of all ``rows * width`` entries, then a block sum over each row.
    """

    def __init__(self, idx: np.ndarray, W: np.ndarray):
        import mitsuba as mi

        self.shape = idx.shape
        self.idx = mi.UInt32(np.ascontiguousarray(idx, dtype=np.uint32).ravel())
        self.w = mi.Float(np.ascontiguousarray(W, dtype=np.float32).ravel())

    def apply(self, x, expand: bool = False):
        """``x``: ``mi.Point3f`` or ``mi.Vector3f``; returns the same type, length ``rows``.

        ``expand``: the reverse pass accumulates into per-thread copies of ``x``
        (``dr.ReduceMode.Expand``) instead of atomics; for a small ``x`` that
        only this operator gathers from (Dr.Jit forbids mixing reduction modes
        on one target).
        """
        import drjit as dr

        cls = type(x)
        mode = dr.ReduceMode.Expand if expand else dr.ReduceMode.Auto
        terms = self.w * dr.gather(cls, x, self.idx, mode=mode)
        return cls(*(dr.block_sum(terms[c], self.shape[1]) for c in range(3)))


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
            self._device = {"S": _Padded(*_csr_to_padded(self._S))}
            for d, (idx, W) in self._rows.items():
                self._device[d] = _Padded(idx, W)
        return self._device

    def _points(self, x):
        import drjit as dr
        import mitsuba as mi

        if isinstance(x, np.ndarray):
            x = mi.Float(np.asarray(x, dtype=np.float32).ravel())
        if isinstance(x, mi.TensorXf):
            if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] != self.n:
                raise ValueError(f"LimitOperator: expected a ({self.n}, 3) tensor of control "
                                 f"points, got shape {tuple(x.shape)}")
            x = x.array
        if not isinstance(x, mi.Float):
            raise TypeError(f"LimitOperator: control points must be mi.Float (3n), mi.TensorXf "
                            f"(n, 3) or a NumPy array, got {type(x).__name__}")
        if dr.width(x) != 3 * self.n:
            raise ValueError(f"LimitOperator: expected {3 * self.n} control coordinates "
                             f"({self.n} points, xyz interleaved), got {dr.width(x)}")
        return unravel_points(x)

    def evaluate(self, x):
        """Limit points and parametric derivatives.

        Parameters
        ----------
        x : mi.Float (3n, xyz interleaved), mi.TensorXf (n, 3) or (n, 3) numpy array
            Control points, possibly with gradients enabled.

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
        xL = dev["S"].apply(self._points(x))
        P = dev[None].apply(xL, expand=True)
        du = dev["u"].apply(mi.Vector3f(xL), expand=True)
        dv = dev["v"].apply(mi.Vector3f(xL), expand=True)
        return P, du, dv

    def positions(self, x):
        """Limit points ``mi.Point3f (k)`` of control points ``x`` (see :meth:`evaluate`)."""
        dev = self._dev()
        return dev[None].apply(dev["S"].apply(self._points(x)), expand=True)

    def positions_normals(self, x):
        """Limit points and unit limit normals from one evaluation: ``(mi.Point3f, mi.Normal3f)``."""
        import drjit as dr
        import mitsuba as mi

        P, du, dv = self.evaluate(x)
        return P, mi.Normal3f(dr.normalize(dr.cross(du, dv)))

    def normals(self, x):
        """Unit limit normals ``mi.Normal3f (k)``, ``normalize(cross(du, dv))``."""
        return self.positions_normals(x)[1]
