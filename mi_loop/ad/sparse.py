r"""Gathers whose reverse pass is a gather too: no atomics, bit-reproducible gradients.

Dr.Jit turns every ``dr.gather`` of a differentiable array into a scatter-add
in the reverse pass. On the LLVM backend those adds run on several threads in
an order that changes from run to run, so float32 gradients (and everything
an optimiser does with them) differ in their last bits, and a fit that runs
for hundreds of iterations, or a sequence fitted frame after frame, amplifies
that into visible differences. Measured on Dr.Jit 1.5.0 (2 threads): every
``dr.scatter_reduce`` mode (Auto, Direct, Expand, Local) gives different sums
from run to run; ``dr.block_sum(..., mode="evaluated")`` over gathered values
is bit-identical. (``mode="symbolic"`` is a scatter-reduce too: it changed one
gradient entry in the last bit in about one run in six of
``tests/ad/test_sparse.py``, and is not used.)

:class:`IndexMap` is a fixed index table ``y[t] = x[index[t]]`` whose reverse
pass is the transposed table applied by :class:`SegmentSum`: the adjoints of
all ``t`` with ``index[t] = j`` are gathered into padded rows and summed with
``dr.block_sum``, in an order fixed when the table is built. Forward- and
reverse-mode AD both work (a ``dr.CustomOp``).

Notes
-----
:class:`SegmentSum` sums ``v[t]`` over the ``t`` of each segment ``s``:

.. math::
    out_s = \sum_{t : seg_t = s} v_t .

Entries are sorted by segment (stable), cut into chunks of at most ``W``
entries, each chunk padded to ``W`` with inactive slots and reduced with
``dr.block_sum``; chunk sums of a segment are then reduced the same way, until
one value per segment is left. Every level is a gather plus a block sum over
fixed index arrays, so the result does not depend on the thread schedule, and
padding costs at most ``W - 1`` slots per segment and level.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail

__all__ = ["IndexMap", "SegmentSum", "gather"]

#: Largest chunk (``dr.block_sum`` block) of a :class:`SegmentSum` level.
MAX_WIDTH = 32


def _stable_order(seg: np.ndarray, n: int) -> np.ndarray:
    """Stable sort order of segment labels (a radix sort when they fit in 16 bits)."""
    if n <= 1 << 16:
        return np.argsort(seg.astype(np.uint16), kind="stable")
    return np.argsort(seg, kind="stable")


def _levels(seg: np.ndarray, n: int):
    """NumPy tables ``[(positions, active, width)]`` of the chunked reduction of ``seg``."""
    levels = []
    while True:
        counts = np.bincount(seg, minlength=n)
        if len(seg) == n and np.array_equal(seg, np.arange(n)):
            return levels
        width = int(min(max(counts.max(initial=1), 1), MAX_WIDTH))
        order = _stable_order(seg, n)
        chunks = np.maximum(1, -(-counts // width))              # ceil, an empty segment keeps one chunk
        first_slot = width * np.concatenate([[0], np.cumsum(chunks)[:-1]])
        first_entry = np.concatenate([[0], np.cumsum(counts)[:-1]])
        # a segment's sorted entries fill consecutive slots from its first chunk on
        slot = np.arange(len(seg)) + np.repeat(first_slot - first_entry, counts)
        positions = np.zeros(int(chunks.sum()) * width, dtype=np.uint32)
        active = np.zeros(len(positions), dtype=bool)
        positions[slot], active[slot] = order, True
        levels.append((positions, active, width))
        seg = np.repeat(np.arange(n), chunks)


class SegmentSum:
    """Deterministic segmented sum ``out[s] = sum of v[t] over seg[t] == s`` in Dr.Jit.

    Parameters
    ----------
    segments : (m,) int numpy array
        Segment of every entry, in ``[0, n)``; segments may be empty.
    n : int
        Number of segments.

    Examples
    --------
    >>> import mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> s = SegmentSum(np.array([2, 0, 2, 2]), 4)
    >>> s(mi.Float([1.0, 2.0, 3.0, 4.0])).numpy().tolist()
    [2.0, 0.0, 8.0, 0.0]
    """

    def __init__(self, segments, n: int):
        from mi_loop.ad.upload import upload_uint

        seg = np.asarray(segments)
        if seg.ndim != 1 or not np.issubdtype(seg.dtype, np.integer):
            fail("SegmentSum", "a 1-D integer array of segments", f"{seg.dtype} array of shape {seg.shape}")
        if len(seg) and (seg.min() < 0 or seg.max() >= n):
            bad = int(np.flatnonzero((seg < 0) | (seg >= n))[0])
            fail("SegmentSum", f"segments in [0, {n})", f"segment {seg[bad]} at entry {bad}")
        self.m, self.n = len(seg), int(n)
        self._levels = []
        for positions, active, width in _levels(seg.astype(np.int64), self.n):
            import mitsuba as mi

            self._levels.append((upload_uint(positions), mi.Bool(active), width))

    @property
    def depth(self) -> int:
        """Number of gather + block-sum levels (0 when every segment holds one entry, in order)."""
        return len(self._levels)

    def __call__(self, v):
        """Apply to ``v`` (``mi.Float (m)`` or a 3-vector type of width ``m``); same type, width ``n``.

        Parameters
        ----------
        v : mi.Float (m), or mi.Point3f / mi.Vector3f (m)
            Values; derivatives flow through (gathers and block sums only).

        Returns
        -------
        Same type as ``v``, width ``n``.
        """
        import drjit as dr

        if self.m == 0:
            return dr.zeros(type(v), self.n)
        for positions, active, width in self._levels:
            dr.eval(v)   # all components of the source in one kernel (a gather would evaluate them one by one)
            v = dr.block_sum(dr.gather(type(v), v, positions, active), width, mode="evaluated")
        return v


class IndexMap:
    """A fixed index table ``y[t] = x[index[t]]`` with a deterministic reverse pass.

    Parameters
    ----------
    index : (m,) int numpy array
        Source element of every output element, in ``[0, n_source)``.
    n_source : int
        Width of the arrays it is applied to.

    Notes
    -----
    The transposed table (:class:`SegmentSum` over ``index``) is built on the
    first reverse pass and kept, so tables rebuilt every few iterations (IMLS
    neighbour lists) pay for it only when gradients are needed.

    Examples
    --------
    >>> import drjit as dr, mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> g = IndexMap(np.array([1, 1, 0]), 2)
    >>> x = mi.Float([10.0, 20.0]); dr.enable_grad(x)
    >>> y = g(x); y.numpy().tolist()
    [20.0, 20.0, 10.0]
    >>> dr.backward(y * mi.Float([1.0, 2.0, 4.0])); dr.grad(x).numpy().tolist()
    [4.0, 3.0]
    """

    def __init__(self, index, n_source: int):
        from mi_loop.ad.upload import upload_uint

        idx = np.asarray(index)
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
            fail("IndexMap", "a 1-D integer index array", f"{idx.dtype} array of shape {idx.shape}")
        if len(idx) and (idx.min() < 0 or idx.max() >= n_source):
            bad = int(np.flatnonzero((idx < 0) | (idx >= n_source))[0])
            fail("IndexMap", f"indices in [0, {n_source})", f"index {idx[bad]} at entry {bad}")
        self.index_np = idx.astype(np.int64)
        self.index = upload_uint(self.index_np)
        self.m, self.n_source = len(idx), int(n_source)
        self._transpose = None

    @property
    def transpose(self) -> SegmentSum:
        """The transposed table, built on first use."""
        if self._transpose is None:
            self._transpose = SegmentSum(self.index_np, self.n_source)
        return self._transpose

    def __call__(self, x):
        """Gather ``x[index]``; ``x`` of type ``mi.Float`` or a 3-vector type, width ``n_source``."""
        import drjit as dr

        if dr.width(x) != self.n_source:
            fail("IndexMap", f"an array of width {self.n_source}", f"width {dr.width(x)}")
        if not dr.grad_enabled(x):
            return dr.gather(type(x), x, self.index)
        return dr.custom(_gather_op(), self, x)


def gather(cls, x, table: IndexMap):
    """``dr.gather(cls, x, table.index)`` with a deterministic reverse pass (see :class:`IndexMap`).

    Parameters
    ----------
    cls : type
        Result type, the type of ``x`` (kept for symmetry with ``dr.gather``).
    x : cls (n_source)
        Source, possibly with gradients.
    table : IndexMap

    Returns
    -------
    cls (m)
    """
    if not isinstance(x, cls):
        x = cls(x)
    return table(x)


def _gather_op():
    """The ``dr.CustomOp`` behind :class:`IndexMap` (defined on first use: drjit is imported lazily)."""
    global _GATHER_OP
    if _GATHER_OP is None:
        import drjit as dr

        class Gather(dr.CustomOp):
            def eval(self, table, x):
                self.table, self.cls = table, type(x)
                return dr.gather(type(x), x, table.index)

            def forward(self):
                self.set_grad_out(dr.gather(self.cls, self.grad_in("x"), self.table.index))

            def backward(self):
                self.set_grad_in("x", self.table.transpose(self.grad_out()))

            def name(self):
                return "IndexMap"

        _GATHER_OP = Gather
    return _GATHER_OP


_GATHER_OP = None
