"""The smooth parameterisation (I + lambda L) and the uniform Adam (mi_loop.fitting.largesteps)."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop.datasets import icosphere
from mi_loop.fitting.largesteps import AdamUniform, SmoothParameterisation

from helpers import exactly


def test_parameters_and_points_are_inverse_and_the_matrix_is_i_plus_lambda_l():
    V, F = icosphere(2)
    p = SmoothParameterisation(F, len(V), lam=7.0)
    M = p.M.toarray()
    degree = np.diag(M) - 1.0
    assert set(np.round(degree / 7.0).astype(int)) == {5, 6}          # valences of an icosphere
    np.testing.assert_allclose(M.sum(axis=1), 1.0)                     # L annihilates constants
    np.testing.assert_allclose(M, M.T)
    np.testing.assert_allclose(p.to_points(p.to_parameters(V)), V, atol=1e-12)


def test_the_gradient_is_the_chain_rule_through_the_solve():
    """f(u) = <w, M^{-1} u>: df/du = M^{-1} w, against central differences."""
    V, F = icosphere(1)
    p = SmoothParameterisation(F, len(V), lam=3.0)
    rng = np.random.default_rng(0)
    w, u, d = (rng.normal(size=V.shape) for _ in range(3))
    g = p.gradient(w)
    eps = 1e-6
    fd = (np.sum(w * p.to_points(u + eps * d)) - np.sum(w * p.to_points(u - eps * d))) / (2 * eps)
    np.testing.assert_allclose(np.sum(g * d), fd, rtol=1e-7)


def test_a_gradient_at_one_vertex_becomes_a_smooth_bump():
    V, F = icosphere(3)
    p = SmoothParameterisation(F, len(V), lam=20.0)
    G = np.zeros_like(V)
    G[0] = V[0]
    step = p.gradient(G)
    along = step @ V[0]
    near = V @ V[0] > np.cos(0.3)
    assert along[0] == along.max() and (along[near] > 0.05 * along[0]).all()   # spread over a region
    assert along[0] < 0.2                                                      # not concentrated at one vertex


def test_lambda_zero_is_the_identity():
    V, F = icosphere(1)
    p = SmoothParameterisation(F, len(V), lam=0.0)
    np.testing.assert_array_equal(p.to_parameters(V), V)


def test_negative_lambda_is_refused():
    V, F = icosphere(1)
    with pytest.raises(ValueError, match=exactly("SmoothParameterisation(): expected lam to be a finite "
                                                 "number >= 0, got -1.0")):
        SmoothParameterisation(F, len(V), lam=-1.0)


def test_uniform_adam_steps_every_coordinate_by_one_scale():
    """First step: m_hat = g, sqrt(v_hat) = |g|; uniform divides all by max |g|, plain Adam by each |g|."""
    g = np.array([[1.0, -0.5], [0.25, 0.0]])
    uniform = AdamUniform(np.zeros((2, 2)), lr=0.1, eps=0.0)
    np.testing.assert_allclose(uniform.step(g), -0.1 * g / 1.0)
    plain = AdamUniform(np.zeros((2, 2)), lr=0.1, eps=1e-12, uniform=False)
    np.testing.assert_allclose(plain.step(g), -0.1 * np.sign(g), atol=1e-9)


def test_uniform_adam_minimises_a_quadratic():
    target = np.array([1.0, -2.0, 0.5])
    opt = AdamUniform(np.zeros(3), lr=0.05)
    for _ in range(400):
        opt.step(2 * (opt.x - target))
    np.testing.assert_allclose(opt.x, target, atol=0.02)
