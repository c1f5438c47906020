"""Optimisers with state and step-size schedules for the fitting loop (:mod:`mi_loop.fitting.loop`).

An optimiser owns the state of one flat Dr.Jit parameter (moments, step
count) and nothing else: the loop hands it the current value and gradient and
takes the new value back. Its state is saved with :meth:`Adam.state_dict` and
restored with :meth:`Adam.load_state_dict`, so a run resumed from a saved
state continues bit for bit. The step size is not the optimiser's business
either: a :class:`Schedule` gives it per iteration (and the loop's
convergence test may halve it).

:class:`GaussNewton` is the second solver and plugs in the same way (an
object with ``step(value, grad, lr)``, ``reset()``, ``state_dict()`` and
``load_state_dict()``); it also says ``needs_hessian``, and the loop hands it
the terms' Gauss-Newton matrix at every refresh (:meth:`GaussNewton.set_hessian`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mi_loop.errors import fail

__all__ = ["Adam", "Constant", "Exponential", "GaussNewton", "Schedule"]


class Adam:
    r"""Adam on one flat Dr.Jit array, optionally "uniform" (Nicolet et al. 2021).

    Parameters
    ----------
    beta_1, beta_2 : float
        Decay rates of the first and second moments, in [0, 1).
    epsilon : float
        Added to the root of the second moment, >= 0.
    uniform : bool
        Divide every coordinate's step by the largest second moment of all
        coordinates instead of its own (the variant of "Large steps in inverse
        rendering of geometry"): the direction of a smoothed gradient is kept.

    Notes
    -----
    With ``g`` the gradient and ``t`` the step count after this step:

    .. math::
        m_t = \beta_1 m_{t-1} + (1 - \beta_1) g, \quad
        v_t = \beta_2 v_{t-1} + (1 - \beta_2) g^2, \quad
        x_t = x_{t-1} - \eta \frac{\sqrt{1 - \beta_2^t}}{1 - \beta_1^t} \frac{m_t}{\sqrt{v_t + \varepsilon^2}}

    (``v_t`` replaced by ``max v_t`` when ``uniform``). The arithmetic is that of
    ``drjit.opt.Adam`` operation for operation, so the two give the same
    iterates bit for bit (``tests/fitting/test_optimisers.py``); unlike it,
    this one keeps no parameter, its state can be saved and restored, and its
    step size comes with each step (no kernel is recompiled when it changes).

    Examples
    --------
    >>> import mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> opt = Adam()
    >>> x = opt.step(mi.Float([1.0, 2.0]), mi.Float([1.0, -1.0]), lr=0.1)
    >>> [round(v, 4) for v in x.numpy().tolist()], opt.state_dict()["t"]
    ([0.9, 2.1], 1)
    """

    def __init__(self, *, beta_1: float = 0.9, beta_2: float = 0.999, epsilon: float = 1e-8,
                 uniform: bool = False):
        for name, value in (("beta_1", beta_1), ("beta_2", beta_2)):
            if not (isinstance(value, (int, float)) and 0 <= value < 1):
                fail("Adam", f"{name} in [0, 1)", value)
        if not (isinstance(epsilon, (int, float)) and math.isfinite(epsilon) and epsilon >= 0):
            fail("Adam", "a finite epsilon >= 0", epsilon)
        self.beta_1, self.beta_2, self.epsilon = float(beta_1), float(beta_2), float(epsilon)
        self.uniform = bool(uniform)
        self.reset()

    def reset(self) -> None:
        """Forget the moments and the step count (the next step is a first step)."""
        self.t, self.m, self.v = 0, None, None

    def step(self, value, grad, lr: float):
        """Return the value after one step along ``grad`` with step size ``lr`` (detached, evaluated).

        Parameters
        ----------
        value, grad : mi.Float (k)
            Current value and its gradient (same width).
        lr : float
            Step size, > 0.

        Returns
        -------
        mi.Float (k)
        """
        import drjit as dr

        value, grad = dr.detach(value), dr.detach(grad)
        tp = type(value)
        if dr.width(value) != dr.width(grad):
            fail("Adam.step", f"a gradient of width {dr.width(value)}", dr.width(grad))
        if self.m is None:
            self.m, self.v = dr.opaque(tp, 0, dr.width(value)), dr.opaque(tp, 0, dr.width(value))
        elif dr.width(self.m) != dr.width(value):
            fail("Adam.step", f"a value of width {dr.width(self.m)} (the width of its state)", dr.width(value))
        UInt = dr.uint32_array_t(tp)
        Wide = dr.float64_array_t(tp)
        t = UInt(self.t) + 1
        m_t = dr.lerp(grad, self.m, self.beta_1)
        v_t = dr.lerp(dr.square(grad), self.v, self.beta_2)
        ema = tp(-dr.sqrt(1 - Wide(self.beta_2) ** t) / (1 - Wide(self.beta_1) ** t))
        dr.make_opaque(ema)
        scale = dr.opaque(tp, float(lr)) * ema
        v_m = dr.max(v_t) if self.uniform else v_t
        if self.epsilon <= 1e-6:
            direction = m_t * dr.rsqrt(v_m + self.epsilon ** 2)
        else:
            direction = m_t / (dr.sqrt(v_m) + self.epsilon)
        new = dr.fma(direction, scale, value)
        dr.eval(new, m_t, v_t)
        self.t, self.m, self.v = self.t + 1, m_t, v_t
        return new

    def state_dict(self) -> dict:
        """The state as plain values: ``t`` (int) and, after a first step, ``m`` and ``v`` (float32 NumPy)."""
        state = {"t": int(self.t)}
        if self.m is not None:
            state["m"] = np.array(self.m, dtype=np.float32)
            state["v"] = np.array(self.v, dtype=np.float32)
        return state

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` (the next step continues as the saved optimiser would have).

        Raises
        ------
        ValueError
            A state without ``t``, or with only one of ``m`` and ``v``.
        """
        import mitsuba as mi

        if "t" not in state or (("m" in state) != ("v" in state)):
            fail("Adam.load_state_dict", "a state with 't' and, after a first step, both 'm' and 'v'",
                 sorted(state))
        self.t = int(np.asarray(state["t"]))
        if "m" in state:
            self.m = mi.Float(np.asarray(state["m"], dtype=np.float32).ravel())
            self.v = mi.Float(np.asarray(state["v"], dtype=np.float32).ravel())
        else:
            self.m = self.v = None


class GaussNewton:
    r"""Gauss-Newton steps ``x - lr (H + mu D)^-1 g`` on the control points, ``H`` from the terms.

    ``H`` is the sum of the energy terms' Gauss-Newton matrices (``2 J^T J``
    of their residuals, :meth:`mi_loop.fitting.terms.Term.hessian`) at the
    loop's last refresh, with the neighbour lists of that refresh: the steps
    follow the energy's curvature. A direction that no term's residual moves
    (sliding along the surface where only ARAP holds the points) is as stiff
    as ARAP makes it, so a small gradient there gives a small step; Adam,
    which divides each coordinate's step by its own gradient's size, gives it
    a full one. Terms without a matrix (barriers, renders) have their
    gradients preconditioned by the others' (a Sobolev step through ``H``).

    Parameters
    ----------
    damping : float
        ``mu`` relative to the mean diagonal of ``H`` (Levenberg's damping:
        ``H`` is only positive semi-definite), > 0.
    metric : SciPy sparse matrix, optional
        ``D`` of the damping ``mu D`` instead of the identity, symmetric
        positive definite (e.g. ``(I + L) (x) I_3``: rough steps damped more than smooth ones).
    max_step : float, optional
        Trust region: the step of each point (3 consecutive coordinates) is
        shortened to this length where longer. Gradients of terms without a
        matrix (renders) where the others are flat would otherwise take
        steps of any length.

    Notes
    -----
    ``H`` is factorised once per refresh (Cholesky in float64, cholespy, on
    the host) and each step is two triangular solves in a fixed order, so
    steps are bit-identical run to run. The optimiser keeps no moments: its
    state is the step count alone.

    Examples
    --------
    >>> import mitsuba as mi, mi_loop, scipy.sparse as sp
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> opt = GaussNewton(damping=1e-12)
    >>> opt.set_hessian(sp.diags([2.0, 2.0, 2.0, 8.0, 8.0, 8.0]))    # E = |x|^2 + 4 |y|^2
    >>> x = opt.step(mi.Float([1, 1, 1, 1, 1, 1]), mi.Float([2, 2, 2, 8, 8, 8]), lr=1.0)
    >>> [round(v, 6) for v in x.numpy().tolist()]
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    """

    needs_hessian = True

    def __init__(self, *, damping: float = 1e-4, metric=None, max_step: float | None = None):
        import scipy.sparse as sp

        if not (isinstance(damping, (int, float)) and math.isfinite(damping) and damping > 0):
            fail("GaussNewton", "a finite damping > 0", damping)
        self.damping = float(damping)
        self.metric = None if metric is None else sp.csr_matrix(metric, dtype=np.float64)
        if max_step is not None and not (isinstance(max_step, (int, float)) and math.isfinite(max_step)
                                         and max_step > 0):
            fail("GaussNewton", "a finite max_step > 0 (or None)", max_step)
        self.max_step = None if max_step is None else float(max_step)
        self.H, self._solver, self.t = None, None, 0

    def reset(self) -> None:
        """Nothing to forget but the step count (the matrix stays until the next refresh)."""
        self.t = 0

    def set_hessian(self, H) -> None:
        """The matrix of the next steps: ``(3n, 3n)`` SciPy sparse, symmetric positive semi-definite."""
        import scipy.sparse as sp

        H = sp.csr_matrix(H, dtype=np.float64)
        if H.shape[0] != H.shape[1] or not np.isfinite(H.data).all():
            fail("GaussNewton.set_hessian", "a finite square matrix", f"shape {H.shape}")
        self.H, self._solver = H, None

    def _factor(self):
        import scipy.sparse as sp
        from cholespy import CholeskySolverD, MatrixType

        d = self.H.diagonal()
        mu = self.damping * max(float(d.mean()), 1e-30)
        D = sp.identity(self.H.shape[0]) if self.metric is None else self.metric
        M = (self.H + D * mu).tocoo()
        self._solver = CholeskySolverD(M.shape[0], M.row.astype(np.int32), M.col.astype(np.int32),
                                       M.data.astype(np.float64), MatrixType.COO)

    def step(self, value, grad, lr: float):
        """Return ``value - lr (H + mu D)^-1 grad`` (detached, evaluated).

        Parameters
        ----------
        value, grad : mi.Float (k)
            Current value and its gradient, ``k`` the size of the matrix.
        lr : float
            Step size, > 0 (1: the full Gauss-Newton step).

        Returns
        -------
        mi.Float (k)

        Raises
        ------
        ValueError
            No matrix yet (the loop sets one at its first refresh), or another width than the matrix's.
        """
        import drjit as dr

        if self.H is None:
            fail("GaussNewton.step", "a matrix (set_hessian) before the first step", "none")
        g = np.array(dr.detach(grad), dtype=np.float64)
        if len(g) != self.H.shape[0] or dr.width(value) != len(g):
            fail("GaussNewton.step", f"a value and a gradient of width {self.H.shape[0]}",
                 f"{dr.width(value)} and {len(g)}")
        if self._solver is None:
            self._factor()
        d = np.zeros_like(g)
        self._solver.solve(g, d)
        d *= float(lr)
        if self.max_step is not None:         # trust region: no point moves farther than max_step in one step
            D = d.reshape(-1, 3)
            length = np.linalg.norm(D, axis=1)
            D *= np.minimum(1.0, self.max_step / np.maximum(length, 1e-300))[:, None]
        x = np.array(dr.detach(value), dtype=np.float64) - d
        self.t += 1
        out = type(value)(x.astype(np.float32))
        dr.eval(out)
        return out

    def state_dict(self) -> dict:
        """``{'t': steps}``: the matrix is rebuilt from the iterate at the next refresh."""
        return {"t": int(self.t)}

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict`."""
        if "t" not in state:
            fail("GaussNewton.load_state_dict", "a state with 't'", sorted(state))
        self.t = int(np.asarray(state["t"]))


class Schedule:
    """Step size per iteration (the base class: ``lr`` at every iteration).

    Parameters
    ----------
    lr : float
        Step size, finite and > 0.
    """

    def __init__(self, lr: float):
        if not (isinstance(lr, (int, float, np.floating)) and math.isfinite(lr) and lr > 0):
            fail(type(self).__name__, "a finite step size lr > 0", lr)
        self.lr = float(lr)

    def __call__(self, it: int) -> float:
        return self.lr


class Constant(Schedule):
    """The same step size ``lr`` at every iteration.

    Parameters
    ----------
    lr : float
        Step size, finite and > 0.
    """


@dataclass
class Exponential(Schedule):
    """``lr * decay ** (it / (length - 1))``: from ``lr`` at the first iteration to ``lr * decay`` at the last.

    Attributes
    ----------
    lr : float
        Step size at the first iteration, finite and > 0.
    decay : float
        Ratio of the last step size to the first, in (0, 1].
    length : int
        Iterations the decay spans.

    Examples
    --------
    >>> s = Exponential(0.1, 0.5, 3)
    >>> [round(s(i), 4) for i in range(3)]
    [0.1, 0.0707, 0.05]
    """

    lr: float
    decay: float
    length: int

    def __post_init__(self):
        Schedule.__init__(self, self.lr)
        if not (isinstance(self.decay, (int, float)) and 0 < self.decay <= 1):
            fail("Exponential", "decay in (0, 1]", self.decay)

    def __call__(self, it: int) -> float:
        return self.lr * self.decay ** (it / max(1, self.length - 1))
