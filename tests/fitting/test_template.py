"""Automatic templates (mi_loop.fitting.template): sphere oracle, the real bunny scan, slivers, errors."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

import mi_loop
from mi_loop import datasets
from mi_loop.fitting.slivers import angles, remove_slivers
from mi_loop.fitting.template import make_template, mesh_template, poisson_depth
from mi_loop.io.points import load_oriented_points

from helpers import DATA, slotted_torus, sphere_mesh, sphere_points

BUNNY_SCAN = DATA / "scans" / "bunny_rangescans_merged_stride3.ply"


@pytest.fixture(scope="module")
def unit_sphere():
    """20,000 random points on the unit sphere (also their own normals)."""
    return sphere_points(20000)[0]


@pytest.fixture(scope="module")
def bunny_scan():
    P, N, _ = load_oriented_points(BUNNY_SCAN)
    return P, N


def _check_closed_valid(V, F, genus=0, min_angle=10.0):
    with warnings.catch_warnings():
        warnings.simplefilter("error")                    # no unreferenced vertices either
        V2, F2, kept = mi_loop.validate_mesh(V, F)
    assert len(kept) == len(V)
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(E, axis=0, return_counts=True)
    assert (counts == 2).all()                            # closed
    assert len(V) - len(counts) + len(F) == 2 - 2 * genus  # Euler characteristic
    volume = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6
    assert volume > 0                                     # outward
    assert angles(V, F).min() >= min_angle
    labels = trimesh.graph.connected_components(E, nodes=np.arange(len(V)))
    assert len(labels) == 1


@pytest.mark.parametrize("n", [100, 642])
def test_sphere_template(unit_sphere, n):
    P = unit_sphere
    V, F, info = make_template(P, P * 3.0, n)
    assert abs(len(V) - n) <= 0.03 * n and info["vertices"] == len(V)
    _check_closed_valid(V, F)
    np.testing.assert_allclose(np.linalg.norm(V, axis=1), 1.0, atol=0.03)
    assert info["depth"] == 6 and info["genus"] == 0 and info["boundary_edges"] == 0
    assert info["poisson_components"] >= 1
    assert info["poisson_vertices"] > 2 * n and info["min_angle"] >= 10
    for key in ("time_poisson", "time_decimate", "time_cleanup", "time_total"):
        assert info[key] >= 0


def test_orientation_follows_the_normals(unit_sphere):
    V, F, _ = make_template(unit_sphere, -unit_sphere, 200)
    volume = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6
    assert volume < 0                                     # inward normals, inward faces
    _check_closed_valid(V, F[:, ::-1])


def test_open_scan_keeps_its_boundary():
    P, N, _ = load_oriented_points(DATA / "scans" / "demosthenes-low-res.obj", n_samples=50_000)
    V, F, info = make_template(P, N, 800)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mi_loop.validate_mesh(V, F)
    assert info["boundary_edges"] > 0 and info["genus"] is None
    assert abs(len(V) - 800) <= 0.03 * 800 and angles(V, F).min() >= 10
    from scipy.spatial import cKDTree

    normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    agree = np.sum(normals * N[cKDTree(P).query(V[F].mean(1))[1]], axis=1)
    assert np.mean(agree > 0) > 0.9


@pytest.mark.parametrize("n", [314, 1000, pytest.param(4667, marks=pytest.mark.slow)])
def test_bunny_scan_templates(bunny_scan, n):
    P, N = bunny_scan
    V, F, info = make_template(P, N, n)
    assert abs(len(V) - n) <= 0.03 * n and info["depth"] == poisson_depth(n)
    _check_closed_valid(V, F)
    # Template vertices lie near the scan (Poisson closes the unscanned bottom, so not all).
    from scipy.spatial import cKDTree

    d = cKDTree(P).query(V)[0] / np.linalg.norm(np.ptp(P, axis=0))
    assert np.median(d) < 0.01


def test_remove_slivers_fixes_needles_and_caps():
    fine_V, fine_F = sphere_mesh(1.0, 5, builder="trimesh")
    V, F = sphere_mesh(1.0, 3, builder="trimesh")
    V = V.copy()                                          # edited below
    for v in (0, 50, 200):                                # pull vertices onto a neighbour: needles
        w = F[np.flatnonzero((F == v).any(1))[0]]
        w = w[w != v][0]
        V[v] = V[w] + 0.02 * (V[v] - V[w])
    assert angles(V, F).min() < 2
    V2, F2, stats = remove_slivers(V, F, fine_V, fine_F, 10.0)
    _check_closed_valid(V2, F2)
    assert stats["min_angle"] >= 10 and stats["flips"] + stats["collapses"] > 0
    assert len(V2) >= len(V) - 3
    np.testing.assert_allclose(np.linalg.norm(V2, axis=1), 1.0, atol=2e-3)


def test_poisson_depth_rule():
    assert [poisson_depth(n) for n in (4, 2000, 2001, 8000, 8001)] == [6, 6, 7, 7, 8]


def test_errors(unit_sphere):
    P = unit_sphere
    with pytest.raises(ValueError, match="n_vertices must be an integer >= 4, got 3"):
        make_template(P, P, 3)
    with pytest.raises(ValueError, match="n_vertices must be an integer"):
        make_template(P, P, 100.0)
    with pytest.raises(ValueError, match="more than half the 20000 input points"):
        make_template(P, P, 10001)
    with pytest.raises(ValueError, match="half the .* vertices of the depth-4 Poisson surface; pass a larger depth"):
        make_template(P, P, 2000, depth=4)
    with pytest.raises(ValueError, match="must both have shape"):
        make_template(P, P[:-1], 100)
    Q = P.copy()
    Q[17, 1] = np.nan
    with pytest.raises(ValueError, match="point or normal 17 is not finite"):
        make_template(Q, P, 100)
    N = P.copy()
    N[9] = 0
    with pytest.raises(ValueError, match="normal 9 has zero length"):
        make_template(P, N, 100)
    with pytest.raises(ValueError, match="depth must be an integer in \\[4, 10\\]"):
        make_template(P, P, 100, depth=11)
    with pytest.raises(ValueError, match="min_angle must be in"):
        make_template(P, P, 100, min_angle=30)
    with pytest.raises(ValueError, match="max_points must be at least 1000"):
        make_template(P, P, 100, max_points=10)
    with pytest.raises(ValueError, match=r"^make_template\(\): genus must be an integer >= 0 or None, got -1$"):
        make_template(P, P, 100, genus=-1)


def test_a_template_webbed_across_a_slot_is_cut_back_to_the_genus_asked():
    P, N = slotted_torus(0.03)
    _, F, info = make_template(P, N, 300)                       # depth 6: the slot is webbed, a handle
    assert info["genus"] == 1 and info["handles_cut"] == []
    V, F, info = make_template(P, N, 300, genus=0)
    assert info["genus"] == 0 and len(info["handles_cut"]) == 1
    mi_loop.validate_mesh(V, F)
    # the loop cut goes round the tube (girth 2 pi 0.2 = 1.26), not round the ring (2 pi 0.4 at least)
    assert info["handles_cut"][0] < 1.5


# -- templates from a mesh -------------------------------------------------------

FOX = DATA / "sequences" / "fox_walk_24f.npz"


@pytest.mark.parametrize("n", [150, 1200])
def test_mesh_template_of_a_sphere(n):
    """Coarser and finer than the input (642 vertices): closed, genus 0, on the sphere."""
    V, F = datasets.icosphere(3)
    Vt, Ft, info = mesh_template(V, F, n)
    assert abs(len(Vt) - n) <= 0.05 * n and info["vertices"] == len(Vt)
    _check_closed_valid(Vt, Ft)
    np.testing.assert_allclose(np.linalg.norm(Vt, axis=1), 1.0, atol=0.02)
    assert info["input_vertices"] == 642 and info["refined_vertices"] >= 3 * n


def test_mesh_template_keeps_a_torus_genus():
    V, F = datasets.torus(24, 12)
    Vt, Ft, info = mesh_template(V, F, 150)
    _check_closed_valid(Vt, Ft, genus=1)
    assert info["genus"] == 1


def test_mesh_template_reaches_the_thin_parts_poisson_loses():
    """Fox, frame 0: every vertex of the input (feet and ear tips included) lies near the mesh
    template, while the depth-6 Poisson template of the same surface misses some by far more."""
    from mi_loop.mesh.sampling import closest_points, sample_surface

    data = np.load(FOX)
    V, F = data["vertices"][0].astype(np.float64), data["faces"]
    diagonal = np.linalg.norm(V.max(0) - V.min(0))
    Vt, Ft, _ = mesh_template(V, F, 1000)
    _check_closed_valid(Vt, Ft)
    miss_mesh = closest_points(Vt, Ft, V)[0].max() / diagonal
    P, N, _ = sample_surface(V, F, 50_000, seed=0)
    Vp, Fp, _ = make_template(P, N, 1000)
    miss_poisson = closest_points(Vp, Fp, V)[0].max() / diagonal
    assert miss_mesh < 0.02 and miss_poisson > 3 * miss_mesh, (miss_mesh, miss_poisson)


def test_mesh_template_welds_a_triangle_soup():
    """Every face with its own three vertices (as some OBJ exporters write): welded first."""
    V, F = datasets.icosphere(3)
    soup_V, soup_F = V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3)
    Vt, Ft, info = mesh_template(soup_V, soup_F, 150)
    assert info["input_vertices"] == 642
    _check_closed_valid(Vt, Ft)
    np.testing.assert_allclose(np.linalg.norm(Vt, axis=1), 1.0, atol=0.02)


def test_mesh_template_rejects_a_mesh_in_pieces():
    V, F = datasets.icosphere(2)
    two_V, two_F = np.vstack([V, V + [3.0, 0.0, 0.0]]), np.vstack([F, F + len(V)])
    with pytest.raises(ValueError, match=r"^mesh_template\(\): the mesh is in pieces: its largest connected "
                                         r"part holds only 50 % of its area"):
        mesh_template(two_V, two_F, 100)
    small = np.vstack([V, 0.2 * V + [3.0, 0.0, 0.0]])        # a 4 % speck next to the sphere is dropped
    Vt, Ft, _ = mesh_template(small, np.vstack([F, F + len(V)]), 100)
    assert np.linalg.norm(Vt, axis=1).max() < 1.05


def test_mesh_template_errors():
    V, F = datasets.icosphere(1)
    with pytest.raises(ValueError, match="mesh_template\\(\\): n_vertices must be an integer >= 4, got 3"):
        mesh_template(V, F, 3)
    with pytest.raises(ValueError, match="mesh_template\\(\\): min_angle must be in \\[0, 20\\] degrees, got 25"):
        mesh_template(V, F, 100, min_angle=25)
    with pytest.raises(ValueError, match=r"^mesh_template\(\): genus must be an integer >= 0 or None, got 0.5$"):
        mesh_template(V, F, 100, genus=0.5)
    bad = np.vstack([F, [[0, 1, 2]]])                   # one face twice: not a manifold
    with pytest.raises(ValueError, match=r"^mesh_template\(\): expected a manifold mesh \(the faces around each vertex "
                                         r"form one fan\), "
                                         r"got non-manifold vertex 0, whose faces form 2 separate fans"):
        mesh_template(V, bad, 100)
