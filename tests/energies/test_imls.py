"""IMLS distance and energy: analytic oracles, gradients, neighbour search, errors."""
from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

from mi_loop.energies.imls import IMLS

from helpers import as_numpy, fibonacci_points, point3f


def _plane(n_points=3000, seed=0):
    """Random points on the plane through c with unit normal nu, and a frame of it."""
    rng = np.random.default_rng(seed)
    nu = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    t1 = np.cross(nu, [1.0, 0, 0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(nu, t1)
    c = np.array([0.1, 0.2, -0.3])
    ab = rng.uniform(-1, 1, (n_points, 2))
    return c + ab[:, :1] * t1 + ab[:, 1:] * t2, nu, c, (t1, t2)


def _f_reference(im, Q):
    """float64 NumPy f(Q) with the object's neighbour lists and radii held fixed."""
    p, nrm = im.points[im.neighbors], im.normals[im.neighbors]     # (k, K, 3)
    d = Q[:, None, :] - p
    t = np.maximum(1 - np.sum(d * d, 2) / im.radius[:, None] ** 2, 0)
    phi = im.valid * t ** 4
    return np.sum(phi * np.sum(nrm * d, 2), 1) / np.sum(phi, 1)


def test_plane_gives_signed_distance():
    P, nu, c, (t1, t2) = _plane()
    im = IMLS(P, np.tile(2.5 * nu, (len(P), 1)))       # normals get normalised
    rng = np.random.default_rng(1)
    delta = rng.uniform(-0.1, 0.1, 200)
    ab = rng.uniform(-0.8, 0.8, (200, 2))
    Q = c + ab[:, :1] * t1 + ab[:, 1:] * t2 + delta[:, None] * nu
    im.update(Q)
    f = np.array(im.values(point3f(Q)))
    # every term n.(x - p_i) equals the signed distance, so f does exactly (float32 rounding)
    np.testing.assert_allclose(f, delta, atol=2e-6)
    E_sum, E_mean = im.energy(point3f(Q)), im.energy(point3f(Q), reduce="mean")
    np.testing.assert_allclose(E_sum[0], np.sum(delta ** 2), rtol=1e-4)
    np.testing.assert_allclose(E_mean[0], np.mean(delta ** 2), rtol=1e-4)


def test_sphere_within_curvature_bound():
    P = fibonacci_points(4000)
    im = IMLS(P, P)
    rng = np.random.default_rng(2)
    dirs = rng.standard_normal((300, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    delta = rng.uniform(-0.05, 0.05, 300)
    Q = (1 + delta)[:, None] * dirs
    im.update(Q)
    f = np.array(im.values(point3f(Q)), dtype=np.float64)
    # n_i.(x - p_i) = |x| cos(theta_i) - 1, so f - delta = -|x| (1 - <cos theta>)_phi, and a
    # neighbour within h of x has 1 - cos(theta) < (h^2 - delta^2) / (2 |x|):
    # -h^2 / 2 <= f - delta <= 0 (up to float32 rounding). h ~ 0.16 here, so |f - delta| < 0.013.
    err = f - delta
    assert np.all(err <= 1e-6)
    assert np.all(err >= -(im.radius ** 2 - delta ** 2) / 2 - 1e-6)
    assert np.abs(err).max() < 0.02


def test_gradient_matches_float64_central_differences():
    P = fibonacci_points(2000)
    im = IMLS(P, P)
    rng = np.random.default_rng(3)
    Q = fibonacci_points(2000)[::50] * rng.uniform(0.95, 1.05, (40, 1)) + 0.01 * rng.standard_normal((40, 3))
    im.update(Q)
    Qd = point3f(Q)
    dr.enable_grad(Qd)
    E = im.energy(Qd)
    dr.backward(E)
    g = as_numpy(dr.grad(Qd))
    np.testing.assert_allclose(E[0], np.sum(_f_reference(im, Q) ** 2), rtol=1e-4)
    # float64 reference with fixed lists; step 1e-6 -> truncation ~1e-12, rounding ~1e-10
    eps, fd = 1e-6, np.zeros_like(Q)
    for j in range(len(Q)):
        for a in range(3):
            Qp, Qm = Q.copy(), Q.copy()
            Qp[j, a] += eps
            Qm[j, a] -= eps
            Ep, Em = (np.sum(_f_reference(im, Qx) ** 2) for Qx in (Qp, Qm))
            fd[j, a] = (Ep - Em) / (2 * eps)
    # AD runs in float32: relative error ~1e-6 of the largest component
    np.testing.assert_allclose(g, fd, atol=1e-4 * np.abs(fd).max())


def test_gradient_matches_float32_central_differences():
    P = fibonacci_points(2000)
    im = IMLS(P, P)
    rng = np.random.default_rng(4)
    Q = 1.03 * fibonacci_points(500)[::10] + 0.01 * rng.standard_normal((50, 3))
    im.update(Q)
    Qd = point3f(Q)
    dr.enable_grad(Qd)
    dr.backward(im.energy(Qd))
    g = as_numpy(dr.grad(Qd))
    # Directional derivative of the float32 energy itself. E ~ 0.05, float32 rounding of E
    # ~ 1e-8; step 1e-3 keeps that below 1e-5 of the slope while the O(step^2) truncation
    # (f is smooth on the scale h ~ 0.2) stays ~1e-5: tolerance 1e-3 relative.
    u = rng.standard_normal(Q.shape)
    step = 1e-3
    Ep, Em = (im.energy(point3f(Q + s * step * u))[0] for s in (1, -1))
    np.testing.assert_allclose((Ep - Em) / (2 * step), np.sum(g * u), rtol=1e-3)


def test_radius_grows_where_points_are_sparse():
    rng = np.random.default_rng(5)
    dense = np.c_[rng.uniform(-1, 0, 4000), rng.uniform(-1, 1, 4000), np.zeros(4000)]  # spacing ~0.02
    sparse = np.c_[rng.uniform(0, 1, 200), rng.uniform(-1, 1, 200), np.zeros(200)]    # spacing ~0.1
    P = np.vstack([dense, sparse])
    im = IMLS(P, np.tile([0, 0, 1.0], (len(P), 1)), h0=0.05, min_neighbors=8)
    Q = np.array([[-0.5, 0.3, 0.01], [-0.5, -0.5, -0.02], [0.5, 0.5, 0.02], [0.6, -0.4, -0.03],
                  [500.0, 0, 0]])
    im.update(Q)
    assert np.all(im.growths[:2] == 0) and np.all(im.radius[:2] <= 0.05)
    assert np.all(im.growths[2:4] >= 1) and np.all(im.radius[2:4] > 0.05)
    assert np.all(im.valid[:4].sum(1) >= 8)
    # the sample far from all data hits the cap, finds nothing, and gets f = 0
    assert im.growths[4] == im.max_growths and im.radius[4] == 0.05 * 2.0 ** im.max_growths
    assert im.n_isolated == 1
    f = np.array(im.values(point3f(Q)))
    np.testing.assert_allclose(f, [0.01, -0.02, 0.02, -0.03, 0.0], atol=2e-6)


def test_radius_shrinks_to_keep_every_weighted_point():
    P, nu, c, _ = _plane(3000)
    im = IMLS(P, np.tile(nu, (len(P), 1)), h0=1.0, max_neighbors=16)   # ~2400 points within h0
    Q = c + 0.05 * nu + np.zeros((3, 3))
    im.update(Q)
    d = np.sort(np.linalg.norm(P - Q[0], axis=1))
    np.testing.assert_allclose(im.radius, d[16])                    # (K+1)-th neighbour
    assert np.all(im.valid.sum(1) == 16)
    np.testing.assert_allclose(np.array(im.values(point3f(Q))), 0.05, atol=2e-6)


def test_lists_keep_their_shape_and_kernels_are_reused():
    P = fibonacci_points(3000)
    im = IMLS(P, P)
    rng = np.random.default_rng(6)
    Q = 1.02 * fibonacci_points(300)

    def step(Q):
        im.update(Q)
        Qd = point3f(Q)
        dr.enable_grad(Qd)
        E = im.energy(Qd, reduce="mean")
        dr.backward(E)
        dr.eval(dr.grad(Qd))
        return im.neighbors.shape

    shape = step(Q)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()                                    # clear
        Q2 = 0.95 * Q + 0.05 * rng.standard_normal(Q.shape)   # different neighbours and radii
        assert step(Q2) == shape == (300, im.max_neighbors)
        jit = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert jit and all(k["cache_hit"] for k in jit)


def test_automatic_h0_follows_the_spacing():
    XY = np.stack(np.meshgrid(np.arange(40), np.arange(40)), -1).reshape(-1, 2) * 0.01
    P = np.c_[XY, np.zeros(len(XY))]
    im = IMLS(P, np.tile([0, 0, 1.0], (len(P), 1)), min_neighbors=8)
    # on a square lattice of spacing s the 8th neighbour (diagonal) is at s sqrt(2)
    np.testing.assert_allclose(im.h0, IMLS.H0_FACTOR * 0.01 * np.sqrt(2), rtol=1e-9)


@pytest.mark.parametrize("points, normals, kwargs, match", [
    (np.zeros((20, 2)), np.zeros((20, 2)), {}, r"IMLS\(\): expected points of shape \(k, 3\) with k > 0, got shape "
                                               r"\(20, 2\)"),
    (np.zeros((0, 3)), np.zeros((0, 3)), {}, r"IMLS\(\): expected points of shape \(k, 3\) with k > 0, got shape \(0, "
                                             r"3\)"),
    (np.ones((20, 3)), np.ones((19, 3)), {}, r"IMLS\(\): expected normals of the points' shape \(20, 3\), got shape "
                                             r"\(19, 3\)"),
    (np.r_[np.ones((5, 3)), [[np.nan, 0, 0]], np.ones((14, 3))], np.ones((20, 3)), {},
     r"IMLS\(\): expected finite points, got row 5 = \[nan, 0.0, 0.0\]"),
    (np.ones((20, 3)), np.r_[np.ones((7, 3)), np.zeros((1, 3)), np.ones((12, 3))], {},
     r"IMLS\(\): expected non-zero normals, got normal 7 = \[0.0, 0.0, 0.0\]"),
    (np.random.default_rng(0).random((20, 3)), np.ones((20, 3)), {"h0": 0.0},
     r"IMLS\(\): expected a finite h0 > 0 \(or None for automatic\), got 0.0"),
    (np.random.default_rng(0).random((20, 3)), np.ones((20, 3)), {"h0": -1.0},
     r"expected a finite h0 > 0 .*, got -1.0"),
    (np.random.default_rng(0).random((20, 3)), np.ones((20, 3)), {"h0": np.inf},
     r"expected a finite h0 > 0 .*, got inf"),
    (np.random.default_rng(0).random((20, 3)), np.ones((20, 3)), {"h0": "0.1"}, r"expected a finite h0 > 0 .*, got "
                                                                                r"'0.1'"),
    (np.random.default_rng(0).random((5, 3)), np.ones((5, 3)), {}, r"IMLS\(\): expected at least min_neighbors = 12 "
                                                                   r"points, got 5"),
    (np.random.default_rng(0).random((20, 3)), np.ones((20, 3)), {"max_neighbors": 4},
     r"IMLS\(\): expected an integer max_neighbors >= min_neighbors = 12, got 4"),
    (np.random.default_rng(0).random((20, 3)), np.ones((20, 3)), {"growth": 1.0}, r"IMLS\(\): expected a finite growth "
                                                                                  r"> 1, got 1.0"),
    (np.random.default_rng(0).random((20, 3)), np.ones((20, 3)), {"max_growths": -1},
     r"IMLS\(\): expected a non-negative integer max_growths, got -1"),
    (np.ones((20, 3)), np.ones((20, 3)), {},
     r"IMLS\(\): expected points that do not all coincide .*pass h0 explicitly"),
])
def test_constructor_errors(points, normals, kwargs, match):
    with pytest.raises(ValueError, match=match):
        IMLS(points, normals, **kwargs)


def test_update_and_energy_errors():
    P = fibonacci_points(200)
    im = IMLS(P, P)
    with pytest.raises(ValueError, match="call update"):
        im.values(point3f(P[:4]))
    with pytest.raises(ValueError, match=r"IMLS.update\(\): expected samples of shape \(k, 3\) with k > 0, got shape "
                                         r"\(4, 2\)"):
        im.update(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"IMLS.update\(\): expected finite samples, got row 1 = \[nan, 0.0, 0.0\]"):
        im.update(np.array([[0, 0, 0], [np.nan, 0, 0]]))
    im.update(P[:4])
    with pytest.raises(ValueError, match="expected 4 samples"):
        im.energy(point3f(P[:5]))
    with pytest.raises(TypeError, match="must be mi.Point3f"):
        im.values(P[:4])
    with pytest.raises(ValueError, match="reduce must be"):
        im.energy(point3f(P[:4]), reduce="max")
