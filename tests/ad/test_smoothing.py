"""The (I + lambda L) parameterisation solved on the device (mi_loop.ad.smoothing)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from mi_loop.ad.smoothing import SmoothParameterisation, smoothing_matrix
from mi_loop.datasets import icosphere

from helpers import exactly


def flat(X):
    import mitsuba as mi

    return mi.Float(np.asarray(X, dtype=np.float32).ravel())


def test_the_matrix_is_i_plus_lambda_l():
    V, F = icosphere(2)
    M = smoothing_matrix(F, len(V), 7.0).toarray()
    degree = np.diag(M) - 1.0
    assert set(np.round(degree / 7.0).astype(int)) == {5, 6}          # valences of an icosphere
    np.testing.assert_allclose(M.sum(axis=1), 1.0)                     # L annihilates constants
    np.testing.assert_allclose(M, M.T)
    assert np.all(M[~np.eye(len(V), dtype=bool)] <= 0)                 # -lambda on edges, 0 elsewhere


def test_solve_matches_a_float64_sparse_solve_and_is_bit_identical_run_to_run():
    V, F = icosphere(3)
    p = SmoothParameterisation(F, len(V), lam=20.0)
    G = np.random.default_rng(0).normal(size=V.shape)
    x = [np.array(p.solve(flat(G))).reshape(-1, 3) for _ in range(3)]
    ref = np.stack([spla.spsolve(p.M.tocsc(), G[:, k]) for k in range(3)], axis=1)
    np.testing.assert_allclose(x[0], ref, atol=1e-6 * np.abs(ref).max())
    assert all(np.array_equal(x[0], other) for other in x[1:])


def test_parameters_and_points_are_inverse():
    V, F = icosphere(2)
    p = SmoothParameterisation(F, len(V), lam=10.0)
    x = flat(V)
    np.testing.assert_allclose(np.array(p.to_points(p.to_parameters(x))), np.array(x), atol=2e-6)
    np.testing.assert_allclose(np.array(p.to_parameters(x)).reshape(-1, 3), p.M @ V.astype(np.float32), atol=1e-5)


def test_to_points_differentiates_as_a_second_solve_in_both_modes():
    """f(u) = <w, M^{-1} u>: df/du = M^{-1} w (reverse), and the forward derivative along d is <w, M^{-1} d>."""
    import drjit as dr

    V, F = icosphere(1)
    p = SmoothParameterisation(F, len(V), lam=3.0)
    rng = np.random.default_rng(1)
    w, u, d = (rng.normal(size=V.shape) for _ in range(3))
    solve = spla.factorized(p.M.tocsc())
    Minv_w = np.stack([solve(w[:, k]) for k in range(3)], axis=1)

    u_dr = flat(u)
    dr.enable_grad(u_dr)
    dr.backward(dr.sum(p.to_points(u_dr) * flat(w)))
    np.testing.assert_allclose(np.array(dr.grad(u_dr)).reshape(-1, 3), Minv_w, atol=1e-5)

    u_dr = flat(u)
    dr.enable_grad(u_dr)
    dr.set_grad(u_dr, flat(d))
    y = dr.sum(p.to_points(u_dr) * flat(w))
    dr.forward_to(y)
    np.testing.assert_allclose(float(dr.grad(y)[0]), float(np.sum(Minv_w * d)), rtol=1e-4)


def test_a_gradient_at_one_vertex_becomes_a_smooth_bump():
    V, F = icosphere(3)
    p = SmoothParameterisation(F, len(V), lam=20.0)
    G = np.zeros_like(V)
    G[0] = V[0]
    step = np.array(p.solve(flat(G)), dtype=np.float64).reshape(-1, 3)
    along = step @ V[0]
    near = V @ V[0] > np.cos(0.3)
    assert along[0] == along.max() and (along[near] > 0.05 * along[0]).all()   # spread over a region
    assert along[0] < 0.2                                                      # not concentrated at one vertex


def test_lambda_zero_is_the_identity():
    V, F = icosphere(1)
    p = SmoothParameterisation(F, len(V), lam=0.0)
    x = flat(V)
    np.testing.assert_array_equal(np.array(p.to_parameters(x)), np.array(x))
    np.testing.assert_array_equal(np.array(p.to_points(x)), np.array(x))
    np.testing.assert_array_equal(np.array(p.solve(x)), np.array(x))


@pytest.mark.parametrize("lam", [-1.0, float("inf"), True])
def test_a_bad_lambda_is_refused(lam):
    V, F = icosphere(1)
    with pytest.raises(ValueError, match=exactly(f"SmoothParameterisation(): expected lam to be a finite "
                                                 f"number >= 0, got {lam}")):
        SmoothParameterisation(F, len(V), lam=lam)
