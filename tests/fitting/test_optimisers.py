"""Optimisers with state and step schedules (mi_loop.fitting.optimisers)."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop.fitting.optimisers import Adam, Constant, Exponential

from helpers import exactly


def _gradients(steps: int, width: int, seed: int = 0) -> list:
    rng = np.random.default_rng(seed)
    return [rng.normal(size=width).astype(np.float32) for _ in range(steps)]


@pytest.mark.parametrize("uniform", [False, True])
def test_adam_gives_the_iterates_of_drjits_adam_bit_for_bit(uniform):
    """Same value, same gradients, same step size: the same float32 iterates as drjit.opt.Adam."""
    import drjit as dr
    import mitsuba as mi

    x0 = np.random.default_rng(1).normal(size=300).astype(np.float32)
    ref = dr.opt.Adam(lr=0.01, params={"x": mi.Float(x0)}, uniform=uniform)
    ours, x = Adam(uniform=uniform), mi.Float(x0)
    for g in _gradients(25, 300):
        dr.set_grad(ref["x"], mi.Float(g))
        ref.step()
        x = ours.step(x, mi.Float(g), 0.01)
        np.testing.assert_array_equal(np.array(x), np.array(ref["x"]))


def test_adam_first_steps_move_each_coordinate_by_the_step_size_or_by_one_scale():
    """First step: m_hat = g and sqrt(v_hat) = |g|: plain Adam moves every coordinate by lr, the uniform
    variant by lr |g| / max |g| (one common scale keeps the direction of g)."""
    import mitsuba as mi

    g = np.array([1.0, -0.5, 0.25, 0.0], dtype=np.float32)
    plain = Adam().step(mi.Float(np.zeros(4, np.float32)), mi.Float(g), 0.1)
    uniform = Adam(uniform=True).step(mi.Float(np.zeros(4, np.float32)), mi.Float(g), 0.1)
    np.testing.assert_allclose(np.array(plain), -0.1 * np.sign(g), atol=1e-6)
    np.testing.assert_allclose(np.array(uniform), -0.1 * g / np.abs(g).max(), atol=1e-6)


def test_a_restored_state_continues_bit_for_bit():
    """Ten steps, save, ten more; a fresh optimiser loaded with the saved state takes the same ten."""
    import mitsuba as mi

    gs = _gradients(20, 50, seed=2)
    first, x = Adam(), mi.Float(np.linspace(-1, 1, 50, dtype=np.float32))
    for g in gs[:10]:
        x = first.step(x, mi.Float(g), 0.05)
    saved, x_saved = first.state_dict(), np.array(x)
    for g in gs[10:]:
        x = first.step(x, mi.Float(g), 0.05)
    second, y = Adam(), mi.Float(x_saved)
    second.load_state_dict({k: np.copy(v) for k, v in saved.items()})
    for g in gs[10:]:
        y = second.step(y, mi.Float(g), 0.05)
    np.testing.assert_array_equal(np.array(y), np.array(x))
    assert saved["t"] == 10 and second.state_dict()["t"] == 20


def test_reset_forgets_the_moments():
    import mitsuba as mi

    opt = Adam()
    x = opt.step(mi.Float([0.0, 0.0]), mi.Float([1.0, -2.0]), 0.1)
    opt.reset()
    assert opt.state_dict() == {"t": 0}
    np.testing.assert_allclose(np.array(opt.step(x, mi.Float([1.0, -2.0]), 0.1)), [-0.2, 0.2], rtol=1e-5)


def test_adam_minimises_a_quadratic():
    import mitsuba as mi

    target = np.array([1.0, -2.0, 0.5], dtype=np.float32)
    opt, x = Adam(uniform=True), mi.Float(np.zeros(3, np.float32))
    for _ in range(400):
        x = opt.step(x, 2 * (x - mi.Float(target)), 0.05)
    np.testing.assert_allclose(np.array(x), target, atol=0.02)


@pytest.mark.parametrize("kwargs, message", [
    ({"beta_1": 1.0}, "Adam(): expected beta_1 in [0, 1), got 1.0"),
    ({"beta_2": -0.1}, "Adam(): expected beta_2 in [0, 1), got -0.1"),
    ({"epsilon": float("nan")}, "Adam(): expected a finite epsilon >= 0, got nan"),
])
def test_adam_rejects_bad_settings(kwargs, message):
    with pytest.raises(ValueError, match=exactly(message)):
        Adam(**kwargs)


def test_adam_rejects_mismatched_widths_and_bad_states():
    import mitsuba as mi

    opt = Adam()
    with pytest.raises(ValueError, match=exactly("Adam.step(): expected a gradient of width 2, got 3")):
        opt.step(mi.Float([0.0, 0.0]), mi.Float([1.0, 1.0, 1.0]), 0.1)
    opt.step(mi.Float([0.0, 0.0]), mi.Float([1.0, 1.0]), 0.1)
    with pytest.raises(ValueError, match=exactly("Adam.step(): expected a value of width 2 (the width of its "
                                                 "state), got 3")):
        opt.step(mi.Float([0.0, 0.0, 0.0]), mi.Float([1.0, 1.0, 1.0]), 0.1)
    with pytest.raises(ValueError, match=exactly("Adam.load_state_dict(): expected a state with 't' and, after a "
                                                 "first step, both 'm' and 'v', got ['m', 't']")):
        opt.load_state_dict({"t": 3, "m": np.zeros(2)})


def test_schedules():
    assert [Constant(0.3)(i) for i in (0, 5)] == [0.3, 0.3]
    s = Exponential(0.2, 0.25, 5)
    np.testing.assert_allclose([s(0), s(2), s(4)], [0.2, 0.1, 0.05])
    assert Exponential(0.2, 0.5, 1)(0) == 0.2                     # one iteration: no decay to spread
    with pytest.raises(ValueError, match=exactly("Constant(): expected a finite step size lr > 0, got 0.0")):
        Constant(0.0)
    with pytest.raises(ValueError, match=exactly("Exponential(): expected decay in (0, 1], got 1.5")):
        Exponential(0.1, 1.5, 10)
