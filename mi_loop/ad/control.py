"""The control points of one iteration, unravelled once and shared by every consumer.

An optimiser holds the control points as one flat ``mi.Float`` of length
``3 n`` (xyz interleaved), the form Mitsuba's ``mi.traverse`` exposes. The
limit operators, ARAP and the ``loop_subdiv`` plugin need them as an
``mi.Point3f`` of width ``n``. :class:`ControlPoints` does that conversion once
per iteration; hand the same object to every term of one energy.

Sharing is more than a saving. In Dr.Jit 1.5.0, when one AD variable is
gathered into two separate intermediate arrays that are gathered again, the
reverse pass mis-accumulates the third component (pinned in
``tests/ad/test_operator.py``). One :class:`ControlPoints` per iteration
means one intermediate.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail

__all__ = ["ControlPoints"]


class ControlPoints:
    """Control points as ``mi.Point3f``, unravelled from a flat ``mi.Float`` (differentiably).

    Parameters
    ----------
    x : mi.Float (3n), mi.TensorXf (n, 3) or (n, 3) float numpy array
        Control points, xyz interleaved when flat; gradients, if enabled on
        ``x``, flow back to it.
    n : int, optional
        Expected number of points (checked when given).
    func : str, optional
        Name of the public function receiving ``x``, for error messages.

    Attributes
    ----------
    flat : mi.Float (3n)
        The variable itself (gradients accumulate here).
    points : mi.Point3f (n)
        The unravelled points.
    n : int

    Examples
    --------
    >>> import numpy as np, drjit as dr, mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> x = mi.Float([0.0, 1, 2, 3, 4, 5]); dr.enable_grad(x)
    >>> cp = ControlPoints(x, 2)
    >>> cp.numpy().tolist()
    [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]
    >>> dr.backward(dr.sum(cp.points.y)); dr.grad(x).numpy().tolist()
    [0.0, 1.0, 0.0, 0.0, 1.0, 0.0]
    """

    def __init__(self, x, n: int | None = None, func: str = "ControlPoints"):
        import drjit as dr
        import mitsuba as mi

        if isinstance(x, np.ndarray):
            x = np.asarray(x, dtype=np.float32)
            if x.ndim != 2 or x.shape[1] != 3:
                fail(func, "control points of shape (n, 3)", f"shape {x.shape}")
            x = mi.Float(x.ravel())
        if isinstance(x, mi.TensorXf):
            if x.ndim != 2 or x.shape[1] != 3:
                fail(func, "a (n, 3) tensor of control points", f"shape {tuple(x.shape)}")
            x = x.array
        if not isinstance(x, mi.Float):
            fail(func, "control points as mi.Float (3n), mi.TensorXf (n, 3), a NumPy array or "
                 "ControlPoints", type(x).__name__, TypeError)
        width = dr.width(x)
        if width % 3 or (n is not None and width != 3 * n):
            want = f"{3 * n} control coordinates ({n} points, xyz interleaved)" if n is not None \
                else "a multiple of 3 control coordinates (xyz interleaved)"
            fail(func, want, f"{width}")
        self.flat, self.n = x, width // 3
        self.points = dr.gather(mi.Point3f, x, dr.arange(mi.UInt32, self.n))

    @classmethod
    def of(cls, x, n: int | None = None, func: str = "ControlPoints") -> ControlPoints:
        """``x`` itself if it is a :class:`ControlPoints` (of ``n`` points), else ``ControlPoints(x, n)``."""
        if isinstance(x, cls):
            if n is not None and x.n != n:
                fail(func, f"{n} control points", f"{x.n}")
            return x
        return cls(x, n, func)

    def numpy(self) -> np.ndarray:
        """``(n, 3)`` float64 NumPy copy of the points (no gradients)."""
        return np.array(self.flat, dtype=np.float64).reshape(-1, 3)
