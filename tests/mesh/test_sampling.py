"""Closest points and surface samples (mi_loop.mesh.sampling) against analytic oracles and brute force."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop.mesh.sampling import _closest_on_triangles, closest_points, sample_surface, surface_distances

from helpers import box_mesh, sphere_mesh


def test_closest_point_regions_of_one_triangle():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    F = np.array([[0, 1, 2]])
    Q = np.array([[0.25, 0.25, 2.0],    # above the interior
                  [0.5, -1.0, 0.0],     # beside edge 01
                  [1.0, 1.0, 1.0],      # beside edge 12
                  [-1.0, -2.0, 0.0],    # vertex 0 region
                  [3.0, -0.5, 0.0]])    # vertex 1 region
    d, C, f = closest_points(V, F, Q)
    C_expected = np.array([[0.25, 0.25, 0], [0.5, 0, 0], [0.5, 0.5, 0], [0, 0, 0], [1, 0, 0]])
    np.testing.assert_allclose(C, C_expected, atol=1e-15)
    np.testing.assert_allclose(d, np.linalg.norm(Q - C_expected, axis=1), atol=1e-15)
    np.testing.assert_array_equal(f, 0)


def test_degenerate_triangle_is_a_segment():
    a, b, c = np.array([[0.0, 0, 0]]), np.array([[2.0, 0, 0]]), np.array([[1.0, 0, 0]])
    C, d2 = _closest_on_triangles(np.array([[1.5, 1.0, 0.0]]), a, b, c)
    np.testing.assert_allclose(C, [[1.5, 0, 0]])
    np.testing.assert_allclose(d2, [1.0])


def test_closest_points_match_brute_force():
    V, F = sphere_mesh(1.0, 2, builder="trimesh")
    V = V * [1.0, 0.6, 1.3]                                  # triangles of varied size
    Q = np.random.default_rng(0).normal(size=(500, 3)) * 1.2
    d, C, f = closest_points(V, F, Q, chunk=128)
    T = V[F]
    brute = np.array([np.sqrt(_closest_on_triangles(np.repeat(q[None], len(F), 0),
                                                    T[:, 0], T[:, 1], T[:, 2])[1].min()) for q in Q])
    np.testing.assert_allclose(d, brute, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(C - Q, axis=1), d, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(_closest_on_triangles(Q, *T[f].transpose(1, 0, 2))[0] - C,
                                              axis=1), 0, atol=1e-14)


def test_sample_surface_is_area_weighted_on_the_surface():
    V, F = box_mesh((1.0, 2.0, 4.0))
    P, N, face = sample_surface(V, F, 20000, seed=1)
    np.testing.assert_allclose(surface_distances(V, F, P), 0, atol=1e-12)
    axis = np.argmax(np.abs(N), 1)
    area = np.array([2 * 4, 1 * 4, 1 * 2]) * 2 / 28.0          # faces normal to x, y, z
    np.testing.assert_allclose(np.bincount(axis, minlength=3) / 20000, area, atol=0.01)
    np.testing.assert_array_equal(sample_surface(V, F, 10, seed=4)[0], sample_surface(V, F, 10, seed=4)[0])


def test_errors():
    V, F = sphere_mesh(1.0, 1, builder="trimesh")
    with pytest.raises(ValueError, match=r"closest_points\(\): expected mesh vertices of shape \(n, 3\) with n > 0, "
                                         r"got shape \(42, 2\)"):
        closest_points(V[:, :2], F, V)
    with pytest.raises(ValueError, match=r"closest_points\(\): expected mesh face indices in \[0, 42\), got face 3 = "
                                         r"\[.*99"):
        G = F.copy()
        G[3, 1] = 99
        closest_points(V, G, V)
    with pytest.raises(ValueError, match=r"closest_points\(\): expected mesh faces as a non-empty integer array of "
                                         r"shape \(m, 3\), got float64"):
        closest_points(V, F.astype(float), V)
    Q = V.copy()
    Q[2, 0] = np.nan
    with pytest.raises(ValueError, match=r"closest_points\(\): expected finite points, got row 2 = \[nan"):
        surface_distances(V, F, Q)
    W = V.copy()
    W[4, 1] = np.inf
    with pytest.raises(ValueError, match=r"closest_points\(\): expected finite mesh vertices, got vertex 4 = \[.*inf"):
        closest_points(W, F, V)
    with pytest.raises(ValueError, match=r"sample_surface\(\): expected a positive integer n, got 0"):
        sample_surface(V, F, 0)
    with pytest.raises(ValueError, match=r"sample_surface\(\): expected a mesh with a positive surface area, got zero "
                                         r"area"):
        sample_surface(np.zeros((3, 3)), np.array([[0, 1, 2]]), 5)
