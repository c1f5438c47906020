"""Distance metrics (mi_loop.metrics) against analytic oracles."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from mi_loop.mesh.sampling import _closest_on_triangles, closest_points, sample_surface, surface_distances
from mi_loop.metrics import nps_metrics, two_sided


def _icosphere(subdivisions, radius=1.0):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices), np.asarray(m.faces)


def _grid(n=20, size=1.0, z=0.0):
    """A flat square ``[0, size]^2`` at height ``z``, ``2 n^2`` triangles, normals +z."""
    x = np.linspace(0, size, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _box(extents=(1.0, 1.0, 1.0)):
    m = trimesh.creation.box(extents=extents)
    return np.asarray(m.vertices), np.asarray(m.faces)


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
    V, F = _icosphere(2)
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
    V, F = _box((1.0, 2.0, 4.0))
    P, N, face = sample_surface(V, F, 20000, seed=1)
    np.testing.assert_allclose(surface_distances(V, F, P), 0, atol=1e-12)
    axis = np.argmax(np.abs(N), 1)
    area = np.array([2 * 4, 1 * 4, 1 * 2]) * 2 / 28.0          # faces normal to x, y, z
    np.testing.assert_allclose(np.bincount(axis, minlength=3) / 20000, area, atol=0.01)
    np.testing.assert_array_equal(sample_surface(V, F, 10, seed=4)[0], sample_surface(V, F, 10, seed=4)[0])


def test_concentric_spheres():
    Vt, Ft = _icosphere(5, 1.0)
    Vf, Ff = _icosphere(5, 1.1)
    diag = np.linalg.norm(np.ptp(Vt, axis=0))
    out = two_sided(Vf, Ff, Vt, Ft, n_samples=20000)
    # Chordal error of a level-5 icosphere is below 3e-4 of the radius.
    for key in ("mean", "rms", "hausdorff", "p2s_mean", "p2s_max", "s2p_mean", "s2p_rms", "s2p_max"):
        np.testing.assert_allclose(out[key], 0.1 / diag, rtol=0.01, err_msg=key)
    assert out["diagonal"] == pytest.approx(diag)
    pts = two_sided(Vf, Ff, Vt)                             # target as a point set (its vertices)
    np.testing.assert_allclose(pts["p2s_mean"], 0.1 / diag, rtol=0.01)
    assert 0.1 / diag < pts["s2p_mean"] < 0.1 / diag * 1.05


def test_mesh_against_itself_is_zero():
    V, F = _icosphere(3)
    out = two_sided(V, F, V, F, n_samples=5000)
    for key in ("mean", "rms", "hausdorff"):
        assert out[key] < 1e-12, key
    nps = nps_metrics((V, F), (V, F), n=5000)
    assert nps["P2S"] < 1e-12 and nps["HD"] < 1e-12
    assert nps["NAE"] < 1e-4 and nps["NAE_oriented"] < 1e-4


def test_translated_box_hausdorff():
    V, F = _box()
    t = 0.05
    out = two_sided(V + [t, 0, 0], F, V, F, n_samples=20000)
    diag = np.sqrt(3.0)
    np.testing.assert_allclose([out["hausdorff"], out["p2s_max"], out["s2p_max"]], t / diag, rtol=1e-9)
    assert out["mean"] < t / diag


def test_plane_patch_at_small_offset():
    Vt, Ft = _grid(20)
    Vf, Ff = _grid(13, z=0.01)                             # different triangulation, same square
    out = two_sided(Vf, Ff, Vt, Ft, n_samples=5000)
    for key in ("mean", "rms", "hausdorff", "p2s_max", "s2p_mean"):
        np.testing.assert_allclose(out[key], 0.01 / np.sqrt(2.0), rtol=1e-9, err_msg=key)
    nps = nps_metrics((Vf, Ff), (Vt, Ft), n=5000)
    # The target's largest extent (1) is scaled to 2.
    assert nps["scale"] == pytest.approx(2.0)
    np.testing.assert_allclose([nps["P2S"], nps["HD"]], 0.02, rtol=1e-9)
    assert nps["NAE"] < 1e-6


@pytest.mark.parametrize("degrees", [5.0, 30.0])
def test_nae_of_a_rotated_plane_is_the_rotation_angle(degrees):
    V, F = _grid(10, z=0.0)
    th = np.radians(degrees)
    R = np.array([[1, 0, 0], [0, np.cos(th), -np.sin(th)], [0, np.sin(th), np.cos(th)]])
    Vr = (V - 0.5) @ R.T + 0.5
    nps = nps_metrics((Vr, F), (V, F), n=3000)
    np.testing.assert_allclose([nps["NAE"], nps["NAE_oriented"]], degrees, rtol=1e-6)
    flipped = nps_metrics((Vr, F[:, ::-1]), (V, F), n=3000)
    np.testing.assert_allclose(flipped["NAE"], degrees, rtol=1e-6)
    np.testing.assert_allclose(flipped["NAE_oriented"], 180 - degrees, rtol=1e-6)


def test_nps_metrics_are_scale_invariant():
    Vt, Ft = _icosphere(3)
    Vf, Ff = _icosphere(2, 1.02)
    a = nps_metrics((Vf, Ff), (Vt, Ft), n=4000)
    b = nps_metrics((Vf * 7 + 3, Ff), (Vt * 7 + 3, Ft), n=4000)
    for key in ("P2S", "HD"):
        np.testing.assert_allclose(a[key], b[key], rtol=1e-9, err_msg=key)
    # Closest points on an edge pick either face's normal; rounding decides ties.
    np.testing.assert_allclose(a["NAE"], b["NAE"], rtol=1e-3)
    assert 0 < a["P2S"] < 0.05 and a["NAE"] > 0


def test_errors():
    V, F = _icosphere(1)
    with pytest.raises(ValueError, match=r"closest_points\(\): expected mesh vertices of shape \(n, 3\) with n > 0, got shape \(42, 2\)"):
        closest_points(V[:, :2], F, V)
    with pytest.raises(ValueError, match=r"closest_points\(\): expected mesh face indices in \[0, 42\), got face 3 = \[.*99"):
        G = F.copy()
        G[3, 1] = 99
        closest_points(V, G, V)
    with pytest.raises(ValueError, match=r"closest_points\(\): expected mesh faces as a non-empty integer array of shape \(m, 3\), got float64"):
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
    with pytest.raises(ValueError, match=r"sample_surface\(\): expected a mesh with a positive surface area, got zero area"):
        sample_surface(np.zeros((3, 3)), np.array([[0, 1, 2]]), 5)
    with pytest.raises(ValueError, match=r"two_sided\(\): expected a target with a bounding box of non-zero diagonal, got zero diagonal"):
        two_sided(V, F, np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"nps_metrics\(\): expected a target of non-zero extent, got zero extent"):
        nps_metrics((V, F), (np.zeros((3, 3)), np.array([[0, 1, 2]])))
    with pytest.raises(ValueError, match=r"two_sided\(\): expected target of shape \(k, 3\) with k > 0, got shape \(0, 3\)"):
        two_sided(V, F, np.zeros((0, 3)), F)
    with pytest.raises(ValueError, match=r"two_sided\(\): expected target face indices in \[0, 2\), got face 0"):
        two_sided(V, F, V[:2], F)
