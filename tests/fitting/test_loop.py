"""The one optimisation loop (mi_loop.fitting.loop): seeds, refresh, convergence, terms, recovery."""
from __future__ import annotations

import math

import numpy as np
import pytest

from mi_loop.errors import FitError
from mi_loop.fitting.loop import Parameter, State, optimise
from mi_loop.fitting.optimisers import Adam, Constant
from mi_loop.fitting.rules import Convergence, Failure, Refresh, Seeds
from mi_loop.fitting.terms import Term

from helpers import exactly

TARGET = np.array([1.0, -2.0, 0.5, 3.0, 0.0, -1.0])


class Quadratic(Term):
    """``|x - target|^2``, refreshed on the loop's rule (the calls are counted)."""

    name = "quad"

    def __init__(self, target=TARGET, poison_from=None):
        import mitsuba as mi

        self.target, self.refreshed, self.poison_from = mi.Float(target.astype(np.float32)), [], poison_from

    def refresh(self, state):
        self.refreshed.append(state.it)

    def energy(self, state):
        import drjit as dr
        import mitsuba as mi

        E = dr.sum(dr.square(state.values["x"] - self.target))
        if self.poison_from is not None and state.it >= self.poison_from:
            E = E + mi.Float(math.nan)
        return E


class FakeRender:
    """A render term: a constant pull of ``x`` and ``albedo`` every ``every`` iterations."""

    kind, name, reuse = "render", "image", ("x",)

    def __init__(self, every):
        self.every, self.calls = every, []

    def refresh(self, state):
        pass

    def gradient(self, state):
        import mitsuba as mi

        self.calls.append(state.it)
        return {"x": mi.Float(np.full(6, 0.5, np.float32)), "albedo": mi.Float(np.ones(3, np.float32))}, 1.0


def param(x0=None, lr=0.05):
    import mitsuba as mi

    x0 = np.zeros(6, np.float32) if x0 is None else np.asarray(x0, np.float32)
    return Parameter(mi.Float(x0), Adam(), Constant(lr))


def test_seeds_are_reproducible_and_distinct_per_key():
    s = Seeds(7)
    assert s.integer(1, 2) == Seeds(7).integer(1, 2) == Seeds(7, 1).integer(2)
    values = {s.child(frame).integer(1, it) for frame in range(40) for it in range(1000)}
    assert len(values) == 40 * 1000                                   # no frame * 1000 + it collisions
    assert s.integer(0) != Seeds(8).integer(0)
    np.testing.assert_array_equal(s.generator(0).permutation(10), Seeds(7).generator(0).permutation(10))
    with pytest.raises(ValueError, match=exactly("Seeds(): expected an integer seed >= 0, got -1")):
        Seeds(-1)


def test_convergence_halves_after_a_plateau_and_stops_after_the_last_halving():
    rule = Convergence(tolerance=0.01, patience=2, halvings=1, window=0)
    values = [10.0, 5.0, 5.0, 5.0, 5.0, 5.0, 5.0, 5.0]
    actions = [rule.update(it, v) for it, v in enumerate(values)]
    # improvement at 0 and 1; 2, 3 flat; the third flat iteration (4) exceeds the patience: halve;
    # the counter restarts there, and three more flat iterations later it stops
    assert actions == ["go", "go", "go", "go", "halve", "go", "go", "stop"]


def test_convergence_window_rule_and_blocks_and_start():
    window = Convergence(tolerance=0.1, patience=100, window=3)
    values = [10.0, 9.0, 8.95, 8.9, 8.85, 8.8]
    assert [window.update(it, v) for it, v in enumerate(values)] == ["go"] * 4 + ["stop", "stop"]
    blocks = Convergence(tolerance=0.1, patience=0, halvings=0, window=0, block=2, start=7)
    values = [4.0, 2.0, 3.0, 3.0, 3.0, 2.9, 3.0, 2.95]
    # block means 3.0, 3.0, 2.95, 2.975: the second and third are flat (not 10 % lower than 3.0), but end
    # before the 7th iteration; the fourth stops
    assert [blocks.update(it, v) for it, v in enumerate(values)] == ["go"] * 7 + ["stop"]
    assert all(Convergence(0.0).update(it, 1.0) == "go" for it in range(50))


def test_refresh_every_n_and_on_movement():
    import mitsuba as mi

    class Probe:                       # a LimitOperator stand-in: the samples are the points themselves
        def positions(self, x):
            return x.points

    refresh = Refresh(every=5, move=0.25, probe=Probe())
    x = param().value
    due = []
    for it, shift in enumerate([0.0, 0.1, 0.2, 0.3, 0.35, 0.4, 0.45, 0.7]):
        p = Parameter(x + mi.Float(shift), Adam(), Constant(0.1))
        state = State(it, {"x": p}, Seeds(0))
        due.append(refresh.due(state))
        if due[-1]:
            refresh.done(state)
    assert due == [True, False, False, True, False, True, False, True]   # 0, moved, every 5, moved


def test_optimise_minimises_an_energy_term_and_keeps_the_best_or_the_last():
    quad = Quadratic()
    result = optimise({"x": param()}, [quad], iterations=300, seeds=Seeds(0), refresh=Refresh(every=50))
    np.testing.assert_allclose(result.values["x"].ravel(), TARGET, atol=0.05)
    assert quad.refreshed == [0, 50, 100, 150, 200, 250]
    assert result.iterations == 300 and not result.converged
    assert set(result.history) == {"quad", "total", "lr", "time"} and len(result.history["time"]) == 300
    best = optimise({"x": param(lr=0.5)}, [Quadratic()], iterations=60, seeds=Seeds(0), keep="best")
    assert best.history["total"][-1] >= min(best.history["total"])
    E = np.sum((best.values["x"].ravel() - TARGET) ** 2)
    assert E == pytest.approx(min(best.history["total"]), rel=1e-5)     # the kept iterate is the best one


def test_optimise_stops_on_convergence():
    result = optimise({"x": param(lr=0.2)}, [Quadratic()], iterations=2000, seeds=Seeds(0),
                      convergence=Convergence(tolerance=1e-3, patience=12, halvings=3, window=40), keep="best")
    assert result.converged and result.iterations < 2000
    lr = np.array(result.history["lr"])
    assert (np.diff(lr) <= 0).all() and lr[-1] < lr[0]                  # the step only ever halved


def test_render_gradients_are_reused_for_points_and_fresh_only_for_the_rest():
    """A render term due every 3 iterations: its x pull acts every iteration, its albedo pull only when fresh."""
    import mitsuba as mi

    render = FakeRender(every=3)
    albedo = Parameter(mi.Float(np.zeros(3, np.float32)), Adam(), Constant(0.01))
    result = optimise({"x": param(TARGET, lr=0.01), "albedo": albedo}, [Quadratic(), render], iterations=9,
                      seeds=Seeds(0))
    assert render.calls == [0, 3, 6]
    # from the minimum of the quadratic, x moves against the reused pull at every step: 9 steps of Adam
    assert np.all(result.values["x"].ravel() < TARGET - 0.05)
    assert albedo.optimiser.state_dict()["t"] == 3                      # stepped on the 3 fresh iterations only
    np.testing.assert_allclose(result.values["albedo"].ravel(), -0.03, rtol=1e-3)
    image = np.array(result.history["image"])
    assert np.isnan(image[[1, 2, 4, 5, 7, 8]]).all() and (image[[0, 3, 6]] == 1.0).all()


def test_a_non_finite_energy_is_reported_with_where_and_when():
    with pytest.raises(FitError, match=exactly("fit_frame(): expected a finite energy, got quad nan at frame 2, "
                                               "iteration 4 (the optimisation diverged)")):
        optimise({"x": param()}, [Quadratic(poison_from=4)], iterations=10, seeds=Seeds(0),
                 failure=Failure("fit_frame", context="frame 2, "))


def test_recoveries_restore_the_best_iterate_with_a_smaller_step_then_give_up():
    class Flaky(Quadratic):
        calls = 0

        def energy(self, state):
            import mitsuba as mi

            Flaky.calls += 1
            E = super().energy(state)
            return E + mi.Float(math.nan) if Flaky.calls in (5, 6) else E

    result = optimise({"x": param()}, [Flaky()], iterations=20, seeds=Seeds(0), failure=Failure(recoveries=2))
    assert result.iterations == 18                                      # two iterations lost to recoveries
    assert result.history["lr"][-1] == pytest.approx(0.05 / 16)         # each recovery quarters the step
    with pytest.raises(FitError, match=r"^fit\(\): expected a finite energy, got quad nan at iteration 3 "
                                       r"\(the optimisation diverged; try again\)$"):
        optimise({"x": param()}, [Quadratic(poison_from=0)], iterations=20, seeds=Seeds(0),
                 failure=Failure("fit", recoveries=3, hint="try again"))


def test_optimise_rejects_an_unknown_keep():
    with pytest.raises(ValueError, match=exactly("optimise(): expected keep to be 'last' or 'best', got 'first'")):
        optimise({"x": param()}, [Quadratic()], iterations=1, seeds=Seeds(0), keep="first")


def test_a_loop_of_render_terms_only_steps_on_their_gradients():
    render = FakeRender(every=1)
    result = optimise({"x": param(lr=0.01)}, [render], iterations=4, seeds=Seeds(0))
    assert render.calls == [0, 1, 2, 3] and result.history["total"] == [0.0] * 4
    np.testing.assert_allclose(result.values["x"].ravel(), -0.04, rtol=1e-3)   # 4 Adam steps against the pull


def test_the_cage_laplacian_of_the_albedo_is_its_numpy_value_and_moves_only_the_albedo():
    """``w |L c|^2`` with ``L = I - D^-1 A`` on a tetrahedron's cage, against NumPy; the points get no gradient."""
    import drjit as dr

    from mi_loop.fitting.terms import CageLaplacian

    F = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    V = np.random.default_rng(0).normal(size=(4, 3))
    c = np.random.default_rng(1).uniform(size=(4, 3))
    L = np.eye(4) - (np.ones((4, 4)) - np.eye(4)) / 3                       # every vertex has the three others
    term = CageLaplacian(F, 4, 2.0, of="albedo")
    state = State(0, {"x": param(V.ravel()), "albedo": param(c.ravel())}, Seeds(0))
    E = term.energy(state)
    dr.backward(E)
    assert term.name == "albedo_laplacian" and term.wrt == ("albedo",)
    np.testing.assert_allclose(E[0], 2.0 * np.sum((L @ c) ** 2), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(dr.grad(state.values["albedo"])).reshape(4, 3), 4.0 * L.T @ L @ c,
                               rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(dr.grad(state.values["x"])), 0.0)
