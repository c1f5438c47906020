"""Distance metrics (mi_loop.metrics) against analytic oracles; closest points are in tests/mesh/test_sampling.py."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop.metrics import nps_metrics, two_sided

from helpers import box_mesh, sphere_mesh


def _grid(n=20, size=1.0, z=0.0):
    """A flat square ``[0, size]^2`` at height ``z``, ``2 n^2`` triangles, normals +z."""
    x = np.linspace(0, size, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def test_concentric_spheres():
    Vt, Ft = sphere_mesh(1.0, 5, builder="trimesh")
    Vf, Ff = sphere_mesh(1.1, 5, builder="trimesh")
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
    V, F = sphere_mesh(1.0, 3, builder="trimesh")
    out = two_sided(V, F, V, F, n_samples=5000)
    for key in ("mean", "rms", "hausdorff"):
        assert out[key] < 1e-12, key
    nps = nps_metrics((V, F), (V, F), n=5000)
    assert nps["P2S"] < 1e-12 and nps["HD"] < 1e-12
    assert nps["NAE"] < 1e-4 and nps["NAE_oriented"] < 1e-4


def test_translated_box_hausdorff():
    V, F = box_mesh()
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
    Vt, Ft = sphere_mesh(1.0, 3, builder="trimesh")
    Vf, Ff = sphere_mesh(1.02, 2, builder="trimesh")
    a = nps_metrics((Vf, Ff), (Vt, Ft), n=4000)
    b = nps_metrics((Vf * 7 + 3, Ff), (Vt * 7 + 3, Ft), n=4000)
    for key in ("P2S", "HD"):
        np.testing.assert_allclose(a[key], b[key], rtol=1e-9, err_msg=key)
    # Closest points on an edge pick either face's normal; rounding decides ties.
    np.testing.assert_allclose(a["NAE"], b["NAE"], rtol=1e-3)
    assert 0 < a["P2S"] < 0.05 and a["NAE"] > 0


def test_errors():
    V, F = sphere_mesh(1.0, 1, builder="trimesh")
    with pytest.raises(ValueError, match=r"two_sided\(\): expected a target with a bounding box of non-zero diagonal, "
                                         r"got zero diagonal"):
        two_sided(V, F, np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"nps_metrics\(\): expected a target of non-zero extent, got zero extent"):
        nps_metrics((V, F), (np.zeros((3, 3)), np.array([[0, 1, 2]])))
    with pytest.raises(ValueError, match=r"two_sided\(\): expected target of shape \(k, 3\) with k > 0, got shape \(0, "
                                         r"3\)"):
        two_sided(V, F, np.zeros((0, 3)), F)
    with pytest.raises(ValueError, match=r"two_sided\(\): expected target face indices in \[0, 2\), got face 0"):
        two_sided(V, F, V[:2], F)


# ---------------------------------------------------------------- folds and correspondence drift
def test_flipped_fraction_is_the_area_of_the_reversed_part():
    """A grid with the faces over x < 0.25 reversed: a quarter of the area faces the wrong way."""
    from mi_loop.metrics import flipped_fraction

    V, F = _grid(20)
    left = V[F].mean(1)[:, 0] < 0.25
    G = F.copy()
    G[left] = G[left][:, ::-1]
    assert flipped_fraction(V, G, V, F) == pytest.approx(0.25, abs=1e-9)
    fine, _ = _grid(100)
    P = fine[fine[:, 0] > 0.5] + [0.0, 0.0, 0.005]        # points over the right half only, normals +z
    N = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    assert flipped_fraction(V, G, P, N_target=N) == 0.0     # the reversed part is not where the points are
    assert flipped_fraction(V, F[:, ::-1], P, N_target=N) == pytest.approx(0.5, abs=0.06)


def test_flipped_fraction_needs_faces_or_normals():
    from mi_loop.metrics import flipped_fraction

    V, F = _grid(2)
    with pytest.raises(ValueError, match=r"^flipped_fraction\(\): expected target faces F_target or target "
                                         r"normals N_target, got neither$"):
        flipped_fraction(V, F, V)


def test_flipped_fraction_of_a_sphere_with_an_inverted_cap_is_the_caps_area_share():
    """An icosphere whose faces above z = 0.6 are reversed, against the sphere itself: their area over the total."""
    from mi_loop.metrics import flipped_fraction

    V, F = sphere_mesh(1.0, 3)
    cap = V[F].mean(1)[:, 2] > 0.6
    G = F.copy()
    G[cap] = G[cap][:, ::-1]
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    share = area[cap].sum() / area.sum()
    assert 0.15 < share < 0.25                               # a cap of height 0.4: 20 % of a sphere's area
    np.testing.assert_allclose(flipped_fraction(V, G, V, F), share, rtol=1e-12)
    assert flipped_fraction(V, F, V, F) == 0.0


def test_self_intersections_of_crossing_triangles_and_of_closed_convex_meshes():
    from mi_loop.metrics import self_intersections

    V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [1.5, 1.5, 0]])
    np.testing.assert_array_equal(self_intersections(V, [[0, 1, 2], [3, 4, 5]]), [True, True])
    V_apart = V + np.array([[0, 0, 0]] * 3 + [[0, 0, 5]] * 3)            # the second one moved clear above
    np.testing.assert_array_equal(self_intersections(V_apart, [[0, 1, 2], [3, 4, 5]]), [False, False])
    for V, F in (sphere_mesh(1.0, 3), box_mesh((1.0, 2.0, 3.0))):      # closed and convex: none
        assert not self_intersections(V, F).any()
    V, F = sphere_mesh(1.0, 3)
    top = int(np.argmax(V[:, 2]))
    V[top] = [0.0, 0.0, -1.5]                       # the top vertex pushed through the bottom: its fan crosses it
    crossed = self_intersections(V, F)
    fan = (F == top).any(1)
    assert crossed[fan].all() and 0 < crossed[~fan].sum() < 20, (crossed[fan].sum(), crossed[~fan].sum())


def test_self_intersections_rejects_bad_meshes():
    from mi_loop.metrics import self_intersections

    with pytest.raises(ValueError, match=r"^self_intersections\(\): expected mesh vertices of shape \(n, 3\) with "
                                         r"n > 0, got shape \(4, 2\)$"):
        self_intersections(np.zeros((4, 2)), [[0, 1, 2]])
    with pytest.raises(ValueError, match=r"^self_intersections\(\): expected mesh face indices in \[0, 3\), "):
        self_intersections(np.eye(3), [[0, 1, 3]])


def test_drift_follows_the_barycentric_point_of_a_deforming_mesh():
    """Attached points follow an affine motion exactly (drift 0); moved points drift by what they moved."""
    from mi_loop.metrics import attach, drift

    V, F = sphere_mesh(1.0, 3)
    rng = np.random.default_rng(0)
    Q = V[F[:40]].mean(1) * 1.001                            # near the surface, off the vertices
    a = attach(Q, V, F)
    A = np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.2], [0.1, 0.0, 1.1]])
    Vt = V @ A.T + [0.3, -0.1, 0.2]
    on = a.points(V)
    assert np.linalg.norm(on - Q, axis=1).max() < 2e-3      # the nearest points
    assert drift(on @ A.T + [0.3, -0.1, 0.2], a, Vt)["max"] < 1e-12
    shift = rng.normal(size=(len(Q), 3))
    shift *= 0.05 / np.linalg.norm(shift, axis=1, keepdims=True)
    d = drift(on @ A.T + [0.3, -0.1, 0.2] + shift, a, Vt)
    diag = np.linalg.norm(np.ptp(Vt, axis=0))
    assert d["mean"] == pytest.approx(0.05 / diag, rel=1e-9) and d["p95"] == pytest.approx(0.05 / diag, rel=1e-9)
    with pytest.raises(ValueError, match=r"^drift\(\): expected 40 points \(as attached\), got 39$"):
        drift(on[:39], a, Vt)


def test_drift_against_points_in_correspondence_is_zero_for_a_rigid_motion():
    """Points attached to the triangles of their 3 nearest cloud points follow a rigid motion of the
    cloud exactly; points moved off it drift by what they moved; the diagonal is the whole cloud's."""
    from scipy.spatial.transform import Rotation

    from mi_loop.metrics import attach_points, drift

    rng = np.random.default_rng(1)
    P = rng.normal(size=(3000, 3))
    P /= np.linalg.norm(P, axis=1, keepdims=True)
    Q = rng.normal(size=(200, 3))
    Q *= 1.002 / np.linalg.norm(Q, axis=1, keepdims=True)
    a = attach_points(Q, P)
    assert a.cloud and np.all(a.bary >= 0) and np.allclose(a.bary.sum(1), 1.0)
    third = np.linalg.norm(P[a.F] - Q[:, None], axis=2).max(1)          # a point of the triangle: no farther
    assert np.all(np.linalg.norm(a.points(P) - Q, axis=1) <= third + 1e-12)
    R, t = Rotation.from_rotvec([0.3, -1.1, 0.4]).as_matrix(), np.array([0.5, -2.0, 1.0])
    Pt = P @ R.T + t
    on = a.points(P) @ R.T + t
    assert drift(on, a, Pt)["max"] < 1e-12
    d = drift(on + [0.0, 0.03, 0.0], a, Pt)
    diag = np.linalg.norm(np.ptp(Pt, axis=0))
    assert d["mean"] == pytest.approx(0.03 / diag, rel=1e-9) and d["max"] == pytest.approx(0.03 / diag, rel=1e-9)
    with pytest.raises(ValueError, match=r"^attach_points\(\): expected a cloud of at least 3 points, got 2$"):
        attach_points(Q, P[:2])


def test_two_sided_exact_measures_the_surface_not_the_spacing_of_its_points():
    from mi_loop import datasets

    V, F = datasets.torus(256, 96)         # vertices on the torus; sags 1.4 (1 - cos pi/256) + 0.4 (1 - cos pi/96)
    clean = datasets.noisy_torus_points(2000, noise=0.0, outliers=0.0)[2]
    by_points = two_sided(V, F, clean, n_samples=20_000)
    exact = two_sided(V, F, clean, n_samples=20_000, exact=datasets.torus_distance)
    assert exact["p2s_mean"] == by_points["p2s_mean"]                  # the other direction is unchanged
    assert exact["s2p_max"] * exact["diagonal"] < 3.2e-4                # at most the two chord sags
    assert by_points["s2p_mean"] > 20 * exact["s2p_mean"]               # 2000 points: spacing dominates
    R, r = 1.0, 0.4
    X = np.array([[R + r, 0, 0], [0, R - r, 0], [0, 0, 0], [0, 2.0, 1.0]])
    np.testing.assert_allclose(datasets.torus_distance(X), [0, 0, R - r, np.hypot(1.0, 1.0) - r], atol=1e-15)
