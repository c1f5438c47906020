"""Tests of static fitting (mi_loop.fitting.static): analytic distance oracles, invariances, every rejected input."""
from __future__ import annotations

import re

import numpy as np
import pytest

from mi_loop import datasets
from mi_loop.errors import FitError
from mi_loop.fitting.options import FitOptions
from mi_loop.fitting.static import SAMPLE_MODES, FitResult, fit, sample_parameters
from mi_loop.metrics import two_sided
from mi_loop.subdiv.limit import limit_matrix
from mi_loop.subdiv.tessellation import tessellate

from helpers import limit_surface, sphere_points, torus_error

SPHERE_R = 2.0


def sphere_error(V):
    """Analytic distance of points to the sphere of radius SPHERE_R at the origin."""
    return np.abs(np.linalg.norm(V, axis=1) - SPHERE_R)


def small_template():
    """Icosphere(2) control mesh (162 vertices) well inside the noisy sphere."""
    V, F = datasets.icosphere(2)
    return 0.7 * SPHERE_R * V, F


# -- fitting works ------------------------------------------------------------------


def test_fit_torus_with_automatic_template_approaches_the_clean_surface():
    P, N, clean = datasets.noisy_torus_points(4000, seed=1)
    result = fit(P, N, FitOptions(n_vertices=120, iterations=150))
    assert isinstance(result, FitResult)
    assert result.V.shape == result.V_template.shape and result.F.shape[1] == 3
    assert abs(len(result.V) - 120) <= 12                     # "within a few percent" of the request
    assert result.info["template"]["genus"] == 1

    V_fit, F_fit = limit_surface(result.V, result.F)
    V_tpl, F_tpl = limit_surface(result.V_template, result.F)
    e_fit, e_tpl = torus_error(V_fit), torus_error(V_tpl)
    assert e_fit.mean() < 0.5 * e_tpl.mean(), (e_fit.mean(), e_tpl.mean())
    assert e_fit.mean() < 0.01                                  # 1 % of the major radius
    d_fit, d_tpl = two_sided(V_fit, F_fit, clean), two_sided(V_tpl, F_tpl, clean)
    assert d_fit["mean"] < d_tpl["mean"] and d_fit["rms"] < d_tpl["rms"], (d_fit, d_tpl)

    total = result.history["total"]
    assert total[-1] < total[0]
    n_it = result.params["iterations_run"]
    assert 1 <= n_it < 150                                      # stopped by the schedule, not the cap
    assert all(len(result.history[k]) == n_it for k in ("imls", "cover", "arap", "fold", "total", "lr"))
    parts = np.sum([result.history[k] for k in ("imls", "cover", "arap", "fold")], axis=0)
    np.testing.assert_allclose(parts, total, rtol=1e-5)
    assert min(result.history["cover"]) > 0                          # the default weight is on
    lr = np.asarray(result.history["lr"])
    assert (lr > 0).all() and (np.diff(lr) <= 0).all()        # the schedule only ever shrinks the step
    assert set(result.timings) >= {"template", "operator", "energies", "optimisation", "total"}
    assert all(np.isfinite(v) and v >= 0 for v in result.timings.values())


def test_fit_keeps_a_user_templates_connectivity_and_reports_progress():
    P, N = sphere_points(3000, radius=SPHERE_R, noise=0.01)
    V0, F0 = small_template()
    calls = []
    result = fit(P, N, FitOptions(iterations=80), template=(V0, F0),
                 progress=lambda i, total, energy: calls.append((i, total, energy)))
    np.testing.assert_array_equal(result.F, F0)
    assert result.V.shape == V0.shape
    np.testing.assert_allclose(result.V_template, V0, rtol=1e-12, atol=1e-12)
    assert result.info["template"] == {"source": "user"}
    assert result.params["n_vertices"] == len(V0) and result.params["n_faces"] == len(F0)
    n_level1 = len(tessellate(F0, 1)[1])  # default samples: the level-1 tessellation points
    assert result.params["samples"] == "level1" and result.params["n_samples"] == n_level1
    assert result.params["alpha"] == 0.001

    e_fit = sphere_error(limit_surface(result.V, F0)[0])
    e_tpl = sphere_error(limit_surface(V0, F0)[0])
    assert e_tpl.mean() > 0.5                                   # the template starts far inside
    assert e_fit.mean() < 0.05 * e_tpl.mean(), (e_fit.mean(), e_tpl.mean())
    assert result.history["total"][-1] < 0.1 * result.history["total"][0]

    # progress(i, iterations, energy) once per recorded iteration, energies as in the history
    assert [c[0] for c in calls] == list(range(1, result.params["iterations_run"] + 1))
    assert {c[1] for c in calls} == {80}
    np.testing.assert_allclose([c[2] for c in calls], result.history["total"], rtol=0)


@pytest.mark.parametrize("mode", ["level1", "random"])
def test_fit_with_other_sample_modes(mode):
    P, N = sphere_points(3000, radius=SPHERE_R, noise=0.01, seed=2)
    V0, F0 = small_template()
    result = fit(P, N, FitOptions(samples=mode, iterations=50, seed=3), template=(V0, F0))
    expected = {"level1": len(tessellate(F0, 1)[0]), "random": 4 * len(F0)}[mode]
    assert result.params["samples"] == mode and result.params["n_samples"] == expected
    np.testing.assert_array_equal(result.F, F0)
    assert np.isfinite(result.V).all()
    e_fit = sphere_error(limit_surface(result.V, F0)[0])
    e_tpl = sphere_error(limit_surface(V0, F0)[0])
    assert e_fit.mean() < 0.1 * e_tpl.mean(), (e_fit.mean(), e_tpl.mean())
    assert result.history["total"][-1] < result.history["total"][0]


def test_fit_is_in_the_inputs_units_and_ignores_normal_length():
    """Scaling by 100 and translating the data scales and translates the fit (normals x7 change nothing)."""
    P, N, _ = datasets.noisy_torus_points(3000, seed=2)
    shift = np.array([5.0, -3.0, 12.0])
    a = fit(P, N, FitOptions(n_vertices=80, iterations=60))
    b = fit(100.0 * P + shift, 7.0 * N, FitOptions(n_vertices=80, iterations=60))
    np.testing.assert_array_equal(b.F, a.F)
    np.testing.assert_allclose(b.V_template, 100.0 * a.V_template + shift, rtol=0, atol=1e-6)
    # Adam runs in float32 in the unit box: agreement to ~1e-6 of the object's size (~290 units)
    np.testing.assert_allclose(b.V, 100.0 * a.V + shift, rtol=0, atol=1e-3)
    np.testing.assert_allclose(b.params["normalisation_scale"], 100.0 * a.params["normalisation_scale"])
    np.testing.assert_allclose(b.params["h0"], a.params["h0"], rtol=1e-9)   # h0 lives in the unit box
    # float32 sums over the data in a nondeterministic order: ~1e-5 drift after 60 iterations
    np.testing.assert_allclose(b.history["total"], a.history["total"], rtol=1e-4)
    assert np.ptp(b.V, axis=0).max() > 50 * np.ptp(P, axis=0).max()         # not left in the unit box


# -- sample_parameters ---------------------------------------------------------------


def loop_limit_weights(n):
    """Loop's limit-position mask of a valence-n vertex: (centre weight, weight per neighbour)."""
    beta = (5 / 8 - (3 / 8 + np.cos(2 * np.pi / n) / 4) ** 2) / n
    chi = 1 / (3 / (8 * beta) + n)
    return 1 - n * chi, chi


def test_vertex_samples_are_the_limit_positions_of_the_control_vertices():
    V, F = datasets.icosphere(1)                                # valences 5 and 6
    fid, uv = sample_parameters(F, len(V), "vertices")
    assert fid.shape == (len(V),) and uv.shape == (len(V), 2)
    W = limit_matrix(F, len(V), fid, uv).toarray()
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), 1), axis=0)
    for v in range(len(V)):
        ring = np.unique(E[(E == v).any(1)])
        ring = ring[ring != v]
        centre, chi = loop_limit_weights(len(ring))
        expected = np.zeros(len(V))
        expected[v], expected[ring] = centre, chi
        np.testing.assert_allclose(W[v], expected, atol=1e-12, err_msg=f"vertex {v}")


def test_level1_and_random_sample_parameters():
    V, F = datasets.icosphere(1)
    fid, uv = sample_parameters(F, len(V), "level1")
    ref_fid, ref_uv, _ = tessellate(F, 1)
    np.testing.assert_array_equal(fid, ref_fid)
    np.testing.assert_array_equal(uv, ref_uv)

    fid, uv = sample_parameters(F, len(V), "random", seed=5)
    np.testing.assert_array_equal(fid, np.repeat(np.arange(len(F)), 4))
    assert (uv >= 0).all() and (uv.sum(1) <= 1).all()          # inside the parameter triangle
    fid2, uv2 = sample_parameters(F, len(V), "random", seed=5)
    np.testing.assert_array_equal(uv2, uv)                      # seeded
    assert not np.allclose(sample_parameters(F, len(V), "random", seed=6)[1], uv)


def test_sample_parameters_rejects_an_unknown_mode():
    V, F = datasets.icosphere(0)
    with pytest.raises(ValueError, match=r"samples must be one of \('vertices', 'level1', 'random'\), "
                                         r"got 'grid'"):
        sample_parameters(F, len(V), "grid")
    assert SAMPLE_MODES == ("vertices", "level1", "random")


# -- rejected input ------------------------------------------------------------------


@pytest.fixture(scope="module")
def cloud():
    """500 exact points and normals on the sphere (no fitting happens in the error tests)."""
    return sphere_points(500, radius=SPHERE_R, seed=4)


@pytest.mark.parametrize("shape, message", [
    ((10, 2), r"fit\(\): expected points of shape \(k, 3\) with k > 0, got shape \(10, 2\)"),
    ((0, 3), r"fit\(\): expected points of shape \(k, 3\) with k > 0, got shape \(0, 3\)"),
    ((30,), r"fit\(\): expected points of shape \(k, 3\) with k > 0, got shape \(30,\)"),
])
def test_fit_rejects_points_of_the_wrong_shape(shape, message):
    with pytest.raises(ValueError, match=message):
        fit(np.ones(shape), np.ones(shape))


def test_fit_rejects_normals_of_another_shape(cloud):
    P, N = cloud
    with pytest.raises(ValueError, match=r"fit\(\): expected normals of the points' shape \(500, 3\), "
                                         r"got shape \(499, 3\)"):
        fit(P, N[:-1])


def test_fit_rejects_a_nan_point_and_an_infinite_normal(cloud):
    P, N = cloud[0].copy(), cloud[1].copy()
    P[4, 1] = np.nan
    with pytest.raises(ValueError, match=r"fit\(\): expected finite points, got row 4 = \[.*, nan, .*\]"):
        fit(P, N)
    P, N = cloud[0], cloud[1].copy()
    N[2, 0] = np.inf
    with pytest.raises(ValueError, match=r"fit\(\): expected finite normals, got normal 2 = \[inf, "):
        fit(P, N)


def test_fit_rejects_a_zero_length_normal(cloud):
    P, N = cloud[0], cloud[1].copy()
    N[6] = 0.0
    with pytest.raises(ValueError, match=r"fit\(\): expected non-zero normals, got normal 6 = \[0.0, 0.0, 0.0\]"):
        fit(P, N)


def test_fit_rejects_an_invalid_samples_mode(cloud):
    with pytest.raises(ValueError, match=r"FitOptions\(\): expected samples to be one of .*got 'faces'"):
        FitOptions(samples="faces")


def test_fit_rejects_a_non_manifold_template(cloud):
    # two tetrahedra sharing only vertex 0: a bow-tie vertex
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3], [0, 5, 4], [0, 4, 6], [0, 6, 5], [4, 5, 6]])
    with pytest.raises(ValueError, match=r"fit\(\): expected a manifold mesh \(the faces around each vertex form one "
                                         r"fan\), got non-manifold "
                                         r"vertex 0, whose faces form 2 separate fans"):
        fit(*cloud, template=(V, F))
    # a third face on edge (0, 1) of a tetrahedron
    F = np.vstack([F[:4], [[0, 1, 4]]])
    with pytest.raises(ValueError, match=r"fit\(\): expected a manifold mesh \(at most two faces per edge\), got "
                                         r"non-manifold edge \(0, 1\) "
                                         r"shared by 3 faces \(0, 1, 4\)"):
        fit(*cloud, template=(V[:5], F))


def test_fit_rejects_degenerate_templates(cloud):
    V, F = datasets.icosphere(1)
    F_rep = F.copy()
    F_rep[3] = [F[3, 0], F[3, 0], F[3, 1]]
    with pytest.raises(ValueError, match=re.escape(f"fit(): expected faces with three distinct vertices, got face 3 = "
                                                   f"{F_rep[3].tolist()} (degenerate)")):
        fit(*cloud, template=(V, F_rep))
    V_flat = V.copy()
    V_flat[F[0, 2]] = (V[F[0, 0]] + V[F[0, 1]]) / 2             # face 0 collapses onto its edge
    with pytest.raises(ValueError, match=re.escape(f"ARAP(): expected rest faces of non-zero area (cotangent weights), "
                                                   f"got face 0 = {F[0].tolist()} of zero area")):
        fit(*cloud, template=(V_flat, F))
    V_nan = V.copy()
    V_nan[7, 2] = np.nan
    with pytest.raises(ValueError, match=r"fit\(\): expected finite vertex coordinates, got vertex 7 = \[.*nan\]"):
        fit(*cloud, template=(V_nan, F))


def test_fit_rejects_fewer_than_four_template_vertices(cloud):
    with pytest.raises(ValueError, match=r"FitOptions\(\): expected n_vertices to be an integer >= 4, got 3"):
        FitOptions(n_vertices=3)


def test_fit_rejects_more_vertices_than_the_data_supports(cloud):
    with pytest.raises(ValueError, match=r"make_template\(\): n_vertices=251 is more than half the 500 "
                                         r"input points; the data cannot support it"):
        fit(*cloud, FitOptions(n_vertices=251))


def test_fit_rejects_too_few_points_for_the_distance_term(cloud):
    P, N = cloud
    with pytest.raises(ValueError, match=r"IMLS\(\): expected at least min_neighbors = 12 points, got 8"):
        fit(P[:8], N[:8], template=small_template())


def test_fit_rejects_a_non_positive_h0(cloud):
    with pytest.raises(ValueError, match=r"FitOptions\(\): expected h0 to be a finite number > 0 .*, got -0.5"):
        FitOptions(h0=-0.5)


@pytest.mark.parametrize("cover", [-1.0, float("inf")])
def test_fit_rejects_a_bad_cover_weight(cloud, cover):
    with pytest.raises(ValueError, match=rf"FitOptions\(\): expected cover to be a finite number >= 0, got {cover}"):
        FitOptions(cover=cover, iterations=5)


@pytest.mark.parametrize("fold", [-0.1, float("nan")])
def test_fit_rejects_a_bad_fold_weight(cloud, fold):
    with pytest.raises(ValueError, match=rf"^FitOptions\(\): expected fold to be a finite number >= 0, got {fold}$"):
        FitOptions(fold=fold, iterations=5)


def test_fit_rejects_a_nan_alpha(cloud):
    with pytest.raises(ValueError, match=r"FitOptions\(\): expected alpha to be a finite number >= 0, got nan"):
        FitOptions(alpha=float("nan"), iterations=5)


def test_fit_reports_divergence_as_fit_error(cloud, monkeypatch):
    """An energy that turns non-finite (here: forced) is retried with smaller steps, then reported."""
    import mitsuba as mi

    from mi_loop.energies.imls import IMLS

    energy = IMLS.energy
    calls = []

    def poisoned(self, Q, reduce="sum"):
        calls.append(1)
        E = energy(self, Q, reduce)
        return E if len(calls) < 3 else E + mi.Float(float("nan"))

    monkeypatch.setattr(IMLS, "energy", poisoned)
    with pytest.raises(FitError, match=r"^fit\(\): expected a finite energy, got imls nan at iteration \d+ "
                                       r"\(the optimisation diverged; try a smaller --alpha or another template\)$"):
        fit(*cloud, FitOptions(iterations=50), template=small_template())
    assert len(calls) > 5   # it retried before giving up


def test_fit_rejects_options_that_are_not_fit_options(cloud):
    with pytest.raises(TypeError, match=r"^fit\(\): expected options to be a FitOptions, got dict$"):
        fit(*cloud, {"n_vertices": 100})


def test_fit_options_reject_a_negative_alpha_and_zero_iterations():
    with pytest.raises(ValueError, match=r"^FitOptions\(\): expected alpha to be a finite number >= 0, got -1.0$"):
        FitOptions(alpha=-1.0, iterations=2)
    with pytest.raises(ValueError, match=r"^FitOptions\(\): expected iterations to be an integer >= 1, got 0$"):
        FitOptions(iterations=0)


def test_fit_rejects_a_template_that_is_not_a_pair(cloud):
    with pytest.raises(ValueError, match=r"fit\(\).*template"):
        fit(*cloud, template=small_template()[0])


def test_fit_says_whether_it_converged(cloud):
    """A stopping rule ends a normal fit early (converged); a cap of 5 iterations does not."""
    done = fit(*cloud, FitOptions(iterations=400), template=small_template())
    assert done.converged and done.params["iterations_run"] < 400
    capped = fit(*cloud, FitOptions(iterations=5), template=small_template())
    assert not capped.converged and capped.params["iterations_run"] == 5


def test_tolerance_zero_runs_every_iteration_at_the_first_step(cloud):
    """0 turns the convergence test off, as in the sequence and image fits: no halving, no early stop."""
    result = fit(*cloud, FitOptions(iterations=150, tolerance=0.0), template=small_template())
    assert not result.converged and result.params["iterations_run"] == 150
    assert len(set(result.history["lr"])) == 1
