"""Deterministic gathers (mi_loop.ad.sparse): exact sums, bit-identical reverse passes, forward mode."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mi_loop
from mi_loop.ad.control import ControlPoints
from mi_loop.ad.sparse import MAX_WIDTH, IndexMap, SegmentSum
from mi_loop.datasets import icosphere
from mi_loop.subdiv.tessellation import tessellate

from helpers import flat, point3f


def grad_of(f, x0, weights):
    """Gradient of ``sum(weights * f(x))`` at ``x0`` (NumPy float64)."""
    x = mi.Float(x0)
    dr.enable_grad(x)
    dr.backward(dr.sum(f(x) * weights))
    return np.array(dr.grad(x), dtype=np.float64)


@pytest.mark.parametrize("n, m", [(7, 0), (1, 5), (50, 40), (300, 100_000), (3, 40_000)])
def test_segment_sum_matches_float64_sums(n, m):
    """Random segments, empty segments, one segment of 40,000 entries (three levels of chunks)."""
    rng = np.random.default_rng(n + m)
    seg = rng.integers(0, n, m)
    v = rng.standard_normal(m).astype(np.float32)
    out = SegmentSum(seg, n)(mi.Float(v)).numpy()
    ref = np.bincount(seg, weights=v.astype(np.float64), minlength=n)
    scale = max(np.sqrt(np.bincount(seg, minlength=n).max(initial=1)), 1.0)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5 * scale)
    assert out.shape == (n,)


def test_segment_sum_depth_follows_the_largest_segment():
    assert SegmentSum(np.arange(5), 5).depth == 0                              # identity: no level
    assert SegmentSum(np.repeat(np.arange(4), 3), 4).depth == 1                # one block sum of width 3
    assert SegmentSum(np.zeros(MAX_WIDTH ** 2 + 1, dtype=int), 1).depth == 3   # 32 -> 32 -> 2 -> 1


def test_index_map_gradient_equals_the_transpose_and_is_bit_identical():
    """2M entries into 1000 sources: plain ``dr.gather`` differs run to run here (scatter-add
    atomics on several threads); the IndexMap reverse pass must not, and must be the transpose."""
    rng = np.random.default_rng(0)
    n, m = 1000, 2_000_000
    idx = rng.integers(0, n, m)
    w = rng.random(m).astype(np.float32)
    table = IndexMap(idx, n)
    x0 = rng.random(n).astype(np.float32)
    grads = [grad_of(table, x0, mi.Float(w)) for _ in range(5)]
    for g in grads[1:]:
        np.testing.assert_array_equal(g, grads[0])
    ref = np.bincount(idx, weights=w.astype(np.float64), minlength=n)
    np.testing.assert_allclose(grads[0], ref, rtol=2e-6)


def test_index_map_forward_mode_and_vectors():
    """Forward-mode derivative is the gather of the tangent; 3-vector types gather per component."""
    rng = np.random.default_rng(1)
    idx = rng.integers(0, 20, 500)
    table = IndexMap(idx, 20)
    P0 = rng.standard_normal((20, 3)).astype(np.float32)
    x = point3f(P0)
    dr.enable_grad(x)
    y = table(x)
    tangent = rng.standard_normal((20, 3)).astype(np.float32)
    dr.set_grad(x, point3f(tangent))
    dr.forward_to(y)
    np.testing.assert_array_equal(np.array(dr.grad(y)).T, tangent[idx])
    np.testing.assert_array_equal(np.array(y).T, P0[idx])


def test_separate_control_point_views_still_add_up():
    """Two IndexMap chains from two separate ControlPoints of one variable: gradients add.

    (The plain ``dr.gather`` version of this loses the z component in Dr.Jit
    1.5.0: ``tests/ad/test_operator.py`` pins that down.)
    """
    rng = np.random.default_rng(0)
    n = 50
    V = rng.standard_normal((n, 3)).astype(np.float32)
    maps = [IndexMap(rng.integers(0, n, k), n) for k in (200, 300)]

    def grad(branches):
        x = mi.Float(V.ravel())
        dr.enable_grad(x)
        E = mi.Float(0.0)
        for b in branches:
            E = E + (b + 1) * dr.sum(dr.squared_norm(maps[b](ControlPoints(x).points)))
        dr.backward(E)
        return np.array(dr.grad(x), dtype=np.float64)

    both, first, second = grad([0, 1]), grad([0]), grad([1])
    np.testing.assert_allclose(both, first + second, rtol=1e-5, atol=1e-4)


def test_limit_operator_backward_is_bit_identical():
    """Positions, d/du and d/dv at 40,960 samples of an icosphere(2) cage, reverse pass 12 times."""
    V, F = icosphere(2)
    fid, uv, _ = tessellate(F, 3)
    op = mi_loop.LimitOperator(F, len(V), fid, uv)
    rng = np.random.default_rng(2)
    w = [mi.Vector3f(*rng.standard_normal((3, len(fid))).astype(np.float32)) for _ in range(3)]

    def grad():
        x = flat(V, grad=True)
        P, du, dv = op.evaluate(x)
        dr.backward(dr.sum(dr.dot(P, w[0]) + dr.dot(du, w[1]) + dr.dot(dv, w[2])))
        return np.array(dr.grad(x))

    g = [grad() for _ in range(12)]     # the atomic block sums this replaced differed about one run in six
    for other in g[1:]:
        np.testing.assert_array_equal(other, g[0])
    M = [op.matrix(d) for d in (None, "u", "v")]
    ref = sum(Md.T @ np.array(wd).T for Md, wd in zip(M, w)).ravel()
    np.testing.assert_allclose(g[0], ref, rtol=0, atol=1e-4 * np.abs(ref).max())


def test_bad_tables_are_named():
    with pytest.raises(ValueError, match=r"IndexMap\(\): expected indices in \[0, 4\), got index 4 at entry 2"):
        IndexMap(np.array([0, 1, 4]), 4)
    with pytest.raises(ValueError, match=r"IndexMap\(\): expected a 1-D integer index array, got float64"):
        IndexMap(np.array([0.0, 1.0]), 4)
    with pytest.raises(ValueError, match=r"SegmentSum\(\): expected segments in \[0, 2\), got segment -1 at entry 0"):
        SegmentSum(np.array([-1, 0]), 2)
    with pytest.raises(ValueError, match=r"SegmentSum\(\): expected a 1-D integer array of segments, got int64 "
                                         r"array of shape \(2, 2\)"):
        SegmentSum(np.zeros((2, 2), dtype=np.int64), 2)
    with pytest.raises(ValueError, match=r"IndexMap\(\): expected an array of width 4, got width 3"):
        IndexMap(np.array([0, 1]), 4)(mi.Float([1.0, 2.0, 3.0]))
