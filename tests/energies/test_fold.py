"""The fold barrier (mi_loop.energies.fold): analytic values, its gradient, reference normals; and in a fit."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from mi_loop import datasets
from mi_loop.energies.fold import FOLD_COSINE, fold_energy, nearest_data_normals
from mi_loop.metrics import flipped_fraction, self_intersections

from helpers import limit_surface, sphere_points


def normals_at(angles):
    """``mi.Normal3f`` of unit normals turned by ``angles`` (radians) from +z in the xz-plane."""
    import mitsuba as mi

    a = np.asarray(angles, dtype=np.float64)
    return mi.Normal3f(np.sin(a).astype(np.float32), np.zeros(len(a), np.float32), np.cos(a).astype(np.float32))


def test_the_barrier_is_zero_within_60_degrees_and_grows_quadratically_beyond():
    import mitsuba as mi

    angles = np.radians([0.0, 30.0, 59.0, 90.0, 120.0, 180.0])
    up = mi.Normal3f(np.zeros(6), np.zeros(6), np.ones(6))
    expected = np.maximum(FOLD_COSINE - np.cos(angles), 0.0) ** 2
    assert expected[:3].sum() == 0 and expected[-1] == 2.25
    for k in range(6):        # one sample at a time: the value itself, not only the mean
        E = fold_energy(normals_at(angles[k:k + 1]), mi.Normal3f(0, 0, 1))
        np.testing.assert_allclose(E[0], expected[k], atol=1e-6)
    np.testing.assert_allclose(fold_energy(normals_at(angles), up)[0], expected.mean(), rtol=1e-6)
    # a reference half as long (neighbours that disagree) halves the free cosine and the pull
    half = mi.Normal3f(np.zeros(6), np.zeros(6), np.full(6, 0.5))
    np.testing.assert_allclose(fold_energy(normals_at(angles), half)[0],
                               np.mean(np.maximum(0.25 - 0.5 * np.cos(angles), 0.0) ** 2), rtol=1e-6)


def test_the_barriers_gradient_turns_a_flipped_normal_back():
    """d/dn of (c - n.r)^2 is -2 (c - n.r) r: against the reference, for a turned normal only."""
    import drjit as dr
    import mitsuba as mi

    n = normals_at(np.radians([150.0, 10.0]))
    dr.enable_grad(n)
    dr.backward(fold_energy(n, mi.Normal3f([0, 0], [0, 0], [1, 1])))
    g = np.array(dr.grad(n)).T
    c = FOLD_COSINE - np.cos(np.radians(150.0))
    np.testing.assert_allclose(g[0], [0, 0, -2 * c / 2], rtol=1e-5)          # mean over 2 samples
    np.testing.assert_array_equal(g[1], [0, 0, 0])


def test_reference_normals_average_the_nearest_data_normals():
    P = np.array([[0.0, 0, 0.1], [0, 0, -0.1], [0, 0, 0.3], [5, 0, 0]])
    N = np.array([[0.0, 0, 1], [0, 0, -1], [0, 0, 1], [1, 0, 0]])
    tree = cKDTree(P)
    np.testing.assert_array_equal(nearest_data_normals(tree, N, [[0, 0, 0.12], [4.9, 0, 0]]), [[0, 0, 1], [1, 0, 0]])
    # inside a thin sheet both sides are near: the mean is short, and zero when they balance
    np.testing.assert_allclose(nearest_data_normals(tree, N, [[0, 0, 0.0]], k=2), [[0, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(nearest_data_normals(tree, N, [[0, 0, 0.0]], k=3), [[0, 0, 1 / 3]], rtol=1e-12)


def z_folded_sphere(R=2.0):
    """An icosphere(3) of radius R with a latitude band pushed over itself: a Z-fold lying on the sphere.

    The polar angle of every control vertex moves to ``t + 0.8 exp(-((t - 1.2) / 0.3)^2)``; that
    map decreases on a band (its slope reaches 1 - 0.8 sqrt(2/e) / 0.3 < 0), so the band's
    triangles are turned over while every control vertex stays on the sphere.
    """
    V, F = datasets.icosphere(3)
    t = np.arccos(np.clip(V[:, 2], -1, 1))
    p = np.arctan2(V[:, 1], V[:, 0])
    t = t + 0.8 * np.exp(-((t - 1.2) / 0.3) ** 2)
    return R * np.c_[np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], F


def test_the_fold_term_unfolds_a_fold_that_lies_on_the_data():
    """The distance terms see nothing wrong with a fold on the sphere; the barrier removes it.

    Measured: flipped area 9.4 % of the template, 8.8 % after a fit without the barrier and 0 with
    the default weight; self-intersecting limit faces 5226 / 9559 / 31 of 40,960.
    """
    from mi_loop.fitting.options import FitOptions
    from mi_loop.fitting.static import fit

    R = 2.0
    P, N = sphere_points(6000, radius=R, seed=0)[:2]
    Vs, Fs = datasets.icosphere(4)
    V0, F = z_folded_sphere(R)
    V_tpl, F_tpl = limit_surface(V0, F)
    assert flipped_fraction(V_tpl, F_tpl, R * Vs, Fs) > 0.05
    folded = fit(P, N, FitOptions(fold=0.0, iterations=150), template=(V0, F))
    unfolded = fit(P, N, FitOptions(iterations=150), template=(V0, F))
    assert unfolded.params["fold"] == 0.01 and folded.history["fold"] == [0.0] * len(folded.history["fold"])
    V1, F1 = limit_surface(folded.V, folded.F)
    V2, F2 = limit_surface(unfolded.V, unfolded.F)
    assert flipped_fraction(V1, F1, R * Vs, Fs) > 0.05                # without it the fold stays
    assert flipped_fraction(V2, F2, R * Vs, Fs) < 1e-3
    assert self_intersections(V2, F2).sum() < 0.1 * self_intersections(V1, F1).sum()
    err = np.abs(np.linalg.norm(V2, axis=1) - R) / R
    assert err.mean() < 0.01 and err.max() < 0.1     # still the sphere: measured 0.3 % mean, 6.8 % max (the seam)
