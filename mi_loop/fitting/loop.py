"""The one optimisation loop of mi_loop: parameters, terms, a refresh rule, a convergence test, seeds.

The static fit (:func:`mi_loop.fitting.static.fit`), every stage of the image
fit (:func:`mi_loop.fitting.images.fit_images`) and every frame of a sequence
(:func:`mi_loop.fitting.sequence.fit_frame`) are configurations of
:func:`optimise`; they differ in their :class:`Parameter` list, their terms
(:mod:`mi_loop.fitting.terms`) and the rules below, never in the loop.

One iteration:

1. each parameter's point-space value (``x`` = ``P(u)`` for a smooth
   parameterisation) becomes a leaf with gradients (:class:`State`);
2. when the :class:`Refresh` rule says so, every term rebuilds what depends on
   the iterate (neighbour lists, reference normals, image weights), and an
   optimiser that steps by a matrix gets the terms' Gauss-Newton matrix;
3. the energy terms' values are summed into one Dr.Jit expression and
   differentiated in one reverse pass;
4. the render terms that are due compute their gradients by their own reverse
   passes (one per view); a render term's control-point gradient is reused
   until it is due again;
5. the :class:`Convergence` test may stop the loop, or halve the step and go
   back to the best iterate;
6. each parameter's optimiser steps along its gradient, pulled back through
   its parameterisation, with the step size of its schedule; a guard may
   shorten the step (one that would fold the surface).

No file I/O, no host copies of gradients: gradients stay Dr.Jit arrays from
the reverse pass to the optimiser.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mi_loop.errors import fail
from mi_loop.fitting.optimisers import Adam, Schedule
from mi_loop.fitting.rules import Convergence, Failure, Refresh, Seeds

__all__ = ["LoopResult", "Parameter", "State", "optimise"]


@dataclass
class Parameter:
    """One optimised variable.

    Attributes
    ----------
    value : mi.Float (k)
        The optimiser's coordinates: the points themselves, or ``u`` of a
        smooth parameterisation (:class:`~mi_loop.ad.smoothing.SmoothParameterisation`).
    optimiser : Adam
        Its state persists across calls of :func:`optimise` (a sequence's albedo).
    schedule : Schedule
        Step size per iteration.
    parameterisation : SmoothParameterisation or None
        ``points = parameterisation.to_points(value)``; None: the identity.
    bounds : (float, float) or None
        Each step is clipped to these (an albedo in [0, 1]).
    guard : callable or None
        ``guard(old, new)`` returns the step actually taken, possibly shortened
        (:class:`~mi_loop.fitting.guard.FoldGuard`: no step folds the surface);
        only without a parameterisation.
    """

    value: object
    optimiser: Adam
    schedule: Schedule
    parameterisation: object = None
    bounds: tuple | None = None
    guard: object = None

    def points(self):
        """The point-space value (detached)."""
        import drjit as dr

        if self.parameterisation is None:
            return dr.detach(self.value)
        return self.parameterisation.solve(self.value)

    def step(self, grad, factor: float, it: int) -> None:
        """One optimiser step along ``grad`` (point space), the schedule's step size times ``factor``."""
        import drjit as dr

        if self.parameterisation is not None:
            grad = self.parameterisation.solve(grad)
        value = self.optimiser.step(self.value, grad, self.schedule(it) * factor)
        if self.bounds is not None:
            value = dr.clip(value, *self.bounds)
            dr.eval(value)
        if self.guard is not None and self.parameterisation is None:
            value = self.guard(dr.detach(self.value), value)
        self.value = value


class State:
    """What the terms see of one iteration: the iterate with gradients, evaluations shared between terms.

    Parameters
    ----------
    it : int
        Iteration.
    params : dict of str to Parameter
        The loop's parameters; their point-space values become :attr:`values`.
    seeds : Seeds
        The loop's seeds.

    Attributes
    ----------
    values : dict of str to mi.Float
        Point-space value of each parameter, gradients enabled.
    grads : dict of str to mi.Float
        After the energy terms' reverse pass: their gradient for each parameter
        they differentiate (their ``wrt``). A parameter that no term gave a
        gradient in an iteration is not stepped in it.
    """

    def __init__(self, it: int, params: dict, seeds: Seeds):
        import drjit as dr

        self.it, self.seeds, self.grads = it, seeds, {}
        self.values = {}
        for name, p in params.items():
            v = p.points()
            dr.enable_grad(v)
            self.values[name] = v
        self._cache = {}

    @property
    def x(self):
        """The control points as :class:`~mi_loop.ad.control.ControlPoints` (one per iteration, shared)."""
        if "x" not in self._cache:
            from mi_loop.ad.control import ControlPoints

            self._cache["x"] = ControlPoints(self.values["x"])
        return self._cache["x"]

    def numpy(self, name: str = "x") -> np.ndarray:
        """``(n, 3)`` float64 NumPy copy of a parameter (once per iteration)."""
        key = ("numpy", name)
        if key not in self._cache:
            self._cache[key] = np.array(self.values[name], dtype=np.float64).reshape(-1, 3)
        return self._cache[key]

    def finite(self) -> bool:
        """Whether the host copies made this iteration (:meth:`numpy`) are finite; the parameters
        without one show in the energies, which all depend on the control points."""
        return all(np.isfinite(v).all() for k, v in self._cache.items() if k[0] == "numpy")

    def host(self, op, what: str = "positions") -> np.ndarray:
        """``(k, 3)`` float64 NumPy copy of ``op.positions`` or ``op.normals`` of :attr:`x`, once per iteration.

        Positions are the very variable the energies use (:meth:`evaluate`), read
        back; normals are evaluated apart, without gradients, so that reading them
        does not materialise a variable the energies differentiate (a fused kernel
        and a materialised one may round the last bit differently).
        """
        key = ("host", id(op), what)
        if key not in self._cache:
            if what == "positions":
                value = self.evaluate(op, what)
            else:
                import drjit as dr

                with dr.suspend_grad():
                    value = getattr(op, what)(dr.detach(self.values["x"]))
            self._cache[key] = np.array(value, dtype=np.float64).T
        return self._cache[key]

    def evaluate(self, op, what: str = "positions"):
        """``op.positions``, ``op.normals`` or ``op.positions_normals`` of :attr:`x`, once per iteration."""
        key = (id(op), what)
        if key not in self._cache:
            self._cache[key] = getattr(op, what)(self.x)
        return self._cache[key]


@dataclass
class LoopResult:
    """What :func:`optimise` returns.

    Attributes
    ----------
    values : dict of str to (k, 3) float64 NumPy arrays
        Each parameter's point-space value: at the best monitored value
        (``keep='best'``) or after the last step (``keep='last'``).
    history : dict of lists
        Per iteration: each energy term's (weighted) value, each render term's
        loss (NaN where it was not due), ``total`` (the energy terms' sum),
        ``lr`` (of the first parameter) and ``time`` (seconds since the start).
    iterations : int
        Iterations run.
    converged : bool
        The convergence test stopped the loop (False: it ran all its iterations).
    seconds : dict
        Time in each render term (its renders and reverse passes).
    """

    values: dict
    history: dict
    iterations: int
    converged: bool
    seconds: dict = field(default_factory=dict)


def optimise(params: dict, terms: list, *, iterations: int, seeds: Seeds, refresh: Refresh | None = None,
             convergence: Convergence | None = None, failure: Failure | None = None, keep: str = "last",
             progress=None) -> LoopResult:
    """Run the optimisation loop (module docstring).

    Parameters
    ----------
    params : dict of str to Parameter
        The optimised variables; ``'x'``, the control points, first.
    terms : list of Term
        Energy and render terms (:mod:`mi_loop.fitting.terms`), summed in this order.
    iterations : int
        Most iterations.
    seeds : Seeds
        Seeds of this optimisation (render terms draw theirs from it).
    refresh : Refresh, optional
        When terms refresh (default: every 20 iterations).
    convergence : Convergence, optional
        Stopping rule (default: none, all iterations run).
    failure : Failure, optional
        How non-finite energies are reported (default: at once, as ``optimise()``).
    keep : {'last', 'best'}
        Return the values after the last step, or at the best monitored value.
    progress : callable, optional
        ``progress(done, iterations, value)`` after every iteration.

    Returns
    -------
    LoopResult

    Raises
    ------
    FitError
        A non-finite energy after ``failure.recoveries`` recoveries.
    """
    if keep not in ("last", "best"):
        fail("optimise", "keep to be 'last' or 'best'", repr(keep))
    run = _Run(params, terms, refresh or Refresh(), failure or Failure())
    convergence = convergence or Convergence()
    factor, converged = 1.0, False
    for it in range(iterations):
        state = State(it, params, seeds)
        values = run.evaluate(state)
        if values is None:                        # not finite: recovered at the best iterate, a quarter of the step
            factor *= 0.25
            continue
        grads = run.gradients(state)
        watched = run.record(state, values, factor, convergence.monitor)
        if progress is not None:
            progress(it + 1, iterations, watched)
        action = convergence.update(it, watched)
        if action == "stop":
            converged = True
            break
        if action == "halve":
            factor *= 0.5
            _restore(params, run.best[1])
            continue
        for name, p in params.items():
            if name in grads:
                p.step(grads[name], factor, it)
    return run.result(keep, converged)


class _Run:
    """The loop's bookkeeping: terms by kind, cached render gradients, history, the best iterate."""

    def __init__(self, params, terms, refresh, failure):
        import time

        self.params, self.terms, self.refresh, self.failure = params, terms, refresh, failure
        self.energy_terms = [t for t in terms if t.kind == "energy"]
        self.render_terms = [t for t in terms if t.kind == "render"]
        self.wrt = sorted({k for t in self.energy_terms for k in t.wrt} & set(params))
        self.history = {t.name: [] for t in terms} | {"total": [], "lr": [], "time": []}
        self.seconds = {t.name: 0.0 for t in self.render_terms}
        self.cached = {t.name: {} for t in self.render_terms}       # each render term's reusable gradients
        self.best = (math.inf, self._snapshot())
        self.recoveries, self.t0, self.losses = 0, time.perf_counter(), {}

    def _snapshot(self) -> dict:
        import drjit as dr

        return {k: dr.detach(p.value) for k, p in self.params.items()}

    def evaluate(self, state):
        """Refresh when due, sum the energy terms and differentiate them; their values (None: not finite)."""
        import drjit as dr
        import mitsuba as mi

        due = self.refresh.due(state)
        contributions = []
        for t in self.energy_terms:          # each term refreshes just before it is built (AD nodes in term order)
            if due:
                t.refresh(state)
            contributions.append(t.energy(state))
        if due:
            for t in self.render_terms:
                t.refresh(state)
            self._hessians(state)
            self.refresh.done(state)
        E = contributions[0] if contributions else mi.Float(0.0)
        for c in contributions[1:]:
            E = E + c
        dr.eval(*contributions, E)
        values = {t.name: float(c[0]) for t, c in zip(self.energy_terms, contributions)} | {"total": float(E[0])}
        if not all(np.isfinite(v) for v in values.values()) or not state.finite():
            self.recoveries += 1
            if self.recoveries > self.failure.recoveries:
                raise self.failure.error(state.it, values)
            _restore(self.params, self.best[1])
            return None
        if contributions:
            dr.backward(E)
        state.grads = {k: dr.grad(state.values[k]) for k in self.wrt}
        return values

    def _hessians(self, state) -> None:
        """Hand each optimiser that steps by a matrix (:class:`~mi_loop.fitting.optimisers.GaussNewton`)
        the sum of the energy terms' Gauss-Newton matrices at this iterate."""
        for name, p in self.params.items():
            if not getattr(p.optimiser, "needs_hessian", False):
                continue
            H = None
            for t in self.energy_terms:
                h = t.hessian(state) if name in t.wrt else None
                if h is not None:
                    H = h if H is None else H + h
            if H is None:
                fail("optimise", f"a term with a Gauss-Newton matrix for '{name}' (its optimiser needs one)", "none")
            p.optimiser.set_hessian(H)

    def gradients(self, state) -> dict:
        """The energy gradients plus the render terms' (fresh where due, reused otherwise)."""
        import time

        grads, self.losses = dict(state.grads), {}
        for t in self.render_terms:
            if state.it % t.every == 0:
                t0 = time.perf_counter()
                fresh, self.losses[t.name] = t.gradient(state)
                self.seconds[t.name] += time.perf_counter() - t0
                if not np.isfinite(self.losses[t.name]):
                    raise self.failure.error(state.it, {t.name: self.losses[t.name]})
                self.cached[t.name] = {k: g for k, g in fresh.items() if k in t.reuse}
                _add(grads, fresh)
            else:
                _add(grads, self.cached[t.name])
        return grads

    def record(self, state, values, factor: float, monitor) -> float:
        """Append the iteration to the history, track the best iterate; the monitored value."""
        import time

        for t in self.render_terms:
            self.history[t.name].append(self.losses.get(t.name, math.nan))
        for name, v in values.items():
            self.history[name].append(v)
        first = next(iter(self.params.values()))
        self.history["lr"].append(first.schedule(state.it) * factor)
        self.history["time"].append(time.perf_counter() - self.t0)
        watched = values["total"] if monitor is None else self.history[monitor][-1]
        if watched < self.best[0]:
            self.best = (watched, self._snapshot())
        return watched

    def result(self, keep: str, converged: bool) -> LoopResult:
        chosen = self.best[1] if keep == "best" else {k: p.value for k, p in self.params.items()}
        out = {}
        for k, p in self.params.items():
            v = chosen[k] if p.parameterisation is None else p.parameterisation.solve(chosen[k])
            out[k] = np.array(v, dtype=np.float64).reshape(-1, 3)
        return LoopResult(out, self.history, len(self.history["total"]), converged, self.seconds)


def _restore(params, values) -> None:
    """Go back to ``values`` with fresh optimiser state (the moments belong to the abandoned path)."""
    for k, p in params.items():
        p.value = values[k]
        p.optimiser.reset()


def _add(grads: dict, extra: dict) -> None:
    for k, g in extra.items():
        grads[k] = grads[k] + g if k in grads else g
