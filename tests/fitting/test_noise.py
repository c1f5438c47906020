"""Noise-aware defaults (mi_loop.fitting.noise, .selection): the estimate against noise we add, the template
rule, the held-out selection of the ARAP weight, and its effect on fits."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop import datasets
from mi_loop.fitting.noise import ALPHA_CLEAN, RATIO_CLEAN, RATIO_NOISY, noise_estimate, template_options
from mi_loop.fitting.options import FitOptions
from mi_loop.fitting.selection import ALPHAS, held_out_split, select_alpha
from mi_loop.fitting.static import fit
from mi_loop.metrics import two_sided


def sphere(n, sigma, seed=0):
    rng = np.random.default_rng(seed)
    U = rng.normal(size=(n, 3))
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    return U * (1 + sigma * rng.normal(size=(n, 1))), U


@pytest.mark.parametrize("sigma", [0.003, 0.01])
def test_the_estimate_recovers_the_noise_we_added_and_its_ratio_to_the_spacing(sigma):
    P, _ = sphere(20_000, sigma)
    est = noise_estimate(P)
    assert est["estimated"] and abs(est["sigma"] / sigma - 1) < 0.15, est
    # spacing: the 12th neighbour of 20,000 uniform points on the unit sphere, sqrt(12 / (pi density))
    expected = np.sqrt(12 / (np.pi * 20_000 / (4 * np.pi)))
    assert abs(est["spacing"] / expected - 1) < 0.15, (est, expected)
    assert est["ratio"] == pytest.approx(est["sigma"] / est["spacing"])
    assert est["sigma_diagonal"] == pytest.approx(est["sigma"] / np.linalg.norm(np.ptp(P, axis=0)))


def test_the_ratio_does_not_depend_on_units_but_on_density():
    P, _ = sphere(20_000, 0.01)
    a, b = noise_estimate(P), noise_estimate(1000 * P)
    assert b["ratio"] == pytest.approx(a["ratio"], rel=1e-9) and b["sigma"] == pytest.approx(1000 * a["sigma"])
    sparse = noise_estimate(P[:5000])           # same noise, a quarter of the points: twice the spacing, half the ratio
    assert 0.4 < sparse["ratio"] / a["ratio"] < 0.6 and abs(sparse["sigma"] / a["sigma"] - 1) < 0.2
    assert noise_estimate(sphere(20_000, 0.0)[0])["ratio"] < 1e-3


def test_too_few_points_estimate_nothing():
    est = noise_estimate(np.random.default_rng(0).normal(size=(24, 3)))
    assert est == {"sigma": 0.0, "spacing": 0.0, "ratio": 0.0, "sigma_diagonal": 0.0, "estimated": False}


def test_the_template_rule_keeps_pymeshlab_defaults_on_clean_data_and_smooths_monotonically():
    ratios = np.linspace(0, 0.6, 61)
    assert all(template_options(r) == {"point_weight": 4.0, "samples_per_node": 1.5} for r in ratios[ratios <= 0.1])
    weights = [template_options(r)["point_weight"] for r in ratios]
    nodes = [template_options(r)["samples_per_node"] for r in ratios]
    assert (np.diff(weights) <= 0).all() and (np.diff(nodes) >= 0).all()
    assert template_options(RATIO_NOISY) == template_options(1.0) == {"point_weight": 0.0, "samples_per_node": 10.0}


def test_selection_keeps_the_candidate_closest_to_the_held_out_points_and_stops_when_it_gets_worse():
    errors = {0.001: 3.0, 0.01: 2.0, 0.1: 2.5, 1.0: 0.5}        # 1.0 would be best, but the search stops at 0.1
    ran, seen = [], []

    def fit_with(alpha, step):
        ran.append(alpha)
        for i in range(1, 11):
            step(i, 10, 1.0)
        return np.full((4, 3), alpha), {"total": [alpha]}, True

    alpha, (V, history, converged), tried = select_alpha(fit_with, lambda V: errors[V[0, 0]],
                                                         progress=lambda i, n, E: seen.append((i, n)))
    assert alpha == 0.01 and V[0, 0] == 0.01 and history == {"total": [0.01]} and converged
    assert ran == [0.001, 0.01, 0.1] and tried == {"alphas": ran, "held_out_mean": [3.0, 2.0, 2.5]}
    assert [i for i, _ in seen] == list(range(1, 31)) and {n for _, n in seen} == {40}     # one bar, four fits
    assert ALPHAS == tuple(sorted(ALPHAS))
    mask = held_out_split(20_000, 3)
    assert abs(mask.mean() - 0.1) < 0.01 and (mask == held_out_split(20_000, 3)).all()
    assert not (mask == held_out_split(20_000, 4)).all()


def test_the_split_does_not_follow_samples_drawn_from_the_same_seed():
    """Area samples drawn with default_rng(seed) and a split from default_rng(seed).random share their words."""
    from mi_loop.mesh.sampling import sample_surface

    V, F = datasets.icosphere(3)                                   # 1280 faces
    face = sample_surface(V, F, 100_000, 0)[2]
    naive = np.random.default_rng(0).random(100_000) < 0.1
    assert np.unique(face[naive]).size < 0.2 * len(F)             # the trap: a tenth of the sphere held out whole
    mask = held_out_split(100_000, 0)
    assert np.unique(face[mask]).size > 0.99 * len(F) and np.unique(face[~mask]).size == len(F)


def test_clean_data_fits_with_the_clean_defaults():
    P, N, _ = datasets.noisy_torus_points(4000, noise=0.0, outliers=0.0, seed=1)
    result = fit(P, N, FitOptions(n_vertices=120, iterations=5))
    assert result.params["alpha"] == ALPHA_CLEAN and result.info["noise"]["ratio"] < RATIO_CLEAN
    assert result.info["noise"]["alpha"] == "clean data" and "selection" not in result.info["noise"]
    assert result.info["template"]["point_weight"] == 4.0 and result.info["template"]["samples_per_node"] == 1.5
    given = fit(P, N, FitOptions(n_vertices=120, iterations=5, alpha=0.5))
    assert given.params["alpha"] == 0.5 and given.info["noise"]["alpha"] == "given"


@pytest.mark.slow
def test_on_the_demo_torus_the_noise_aware_fit_is_closer_to_the_clean_surface():
    """The README demo's data: the automatic defaults against the clean-data ones, measured on the exact torus."""
    P, N, clean = datasets.noisy_torus_points()
    auto = fit(P, N)
    fixed = fit(P, N, FitOptions(alpha=ALPHA_CLEAN))
    assert auto.info["noise"]["ratio"] > RATIO_NOISY * 0.9 and auto.params["alpha"] > 100 * ALPHA_CLEAN
    assert auto.info["template"]["point_weight"] < 0.5 and np.array_equal(fixed.V_template, auto.V_template)
    d = {}
    for name, r in (("auto", auto), ("fixed", fixed)):
        V, F, _ = r.limit_mesh(3)
        d[name] = two_sided(V, F, clean, exact=datasets.torus_distance)["mean"]
    assert d["auto"] < 0.6 * d["fixed"], d                    # BENCHMARKS: 0.39x on this seed
