"""Sharp features: detection on meshes (mi_loop.mesh.features), feature templates, fits and control.ply with creases.

Oracles: a cube's twelve edges are its only features (dihedral 90 degrees), a
sphere has none; a fitted cube keeps its edges sharp only with the creases
(the limit normals on either side of an edge stay 90 degrees apart).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from mi_loop import io
from mi_loop.app.cli import main
from mi_loop.datasets import icosphere
from mi_loop.mesh.features import crease_edges, feature_curves
from mi_loop.mesh.geometry import weld

from helpers import exactly


def cube_mesh(k: int = 8, size: float = 1.0):
    """A closed cube ``[0, size]^3``, each face a ``k x k`` grid of right triangles, outward oriented."""
    t = np.linspace(0.0, size, k + 1)
    V, F = [], []
    for axis in range(3):
        for side in (0.0, size):
            a, b = [c for c in range(3) if c != axis]
            i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
            P = np.zeros(((k + 1) ** 2, 3))
            P[:, axis], P[:, a], P[:, b] = side, t[i.ravel()], t[j.ravel()]
            base = sum(len(v) for v in V)
            q = (i[:-1, :-1] * (k + 1) + j[:-1, :-1]).ravel() + base
            tris = np.r_[np.c_[q, q + k + 1, q + 1], np.c_[q + 1, q + k + 1, q + k + 2]]
            normal = np.zeros(3)
            normal[axis] = 1.0 if side > 0 else -1.0
            e1, e2 = np.zeros(3), np.zeros(3)
            e1[a], e2[b] = 1.0, 1.0
            if np.dot(np.cross(e1, e2), normal) < 0:
                tris = tris[:, ::-1]
            V.append(P)
            F.append(tris)
    return weld(np.vstack(V), np.vstack(F))


def test_cube_features_are_its_twelve_edges_and_a_sphere_has_none():
    V, F = cube_mesh(6)
    curves = feature_curves(V, F, 40.0)
    assert len(curves.E) == 12 * 6 and curves.n_curves == 1
    np.testing.assert_allclose(curves.angle, 90.0, atol=1e-9)
    assert curves.length == pytest.approx(12.0)
    on_edge = np.sum(np.isclose(V[curves.E.ravel()], 0.0) | np.isclose(V[curves.E.ravel()], 1.0), axis=1)
    assert (on_edge >= 2).all()                                  # every feature vertex lies on a cube edge
    Vs, Fs = icosphere(3)
    assert feature_curves(Vs, Fs, 40.0).n_curves == 0
    assert feature_curves(V, F, 95.0).n_curves == 0              # no edge sharper than 90 degrees


def test_short_feature_chains_are_dropped():
    """A spike on a sphere (one chain of sharp edges around it) is dropped when shorter than min_length."""
    Vs, Fs = icosphere(3)
    Vs = Vs.copy()
    Vs[0] *= 1.6                                                  # a spike: its fan edges are sharp
    spike = feature_curves(Vs, Fs, 40.0)
    assert spike.n_curves == 1 and 0 < spike.length < 6.0
    assert feature_curves(Vs, Fs, 40.0, min_length=spike.length * 0.99).n_curves == 1
    assert feature_curves(Vs, Fs, 40.0, min_length=spike.length * 1.01).n_curves == 0


def test_crease_edges_of_a_coarse_cube_follow_the_fine_cube_edges():
    V, F = cube_mesh(8)
    curves = feature_curves(V, F, 40.0)
    Vc, Fc = cube_mesh(2)
    E = crease_edges(Vc, Fc, curves)
    assert len(E) == 12 * 2                                       # every coarse edge on a cube edge
    mid = 0.5 * (Vc[E[:, 0]] + Vc[E[:, 1]])
    assert (np.sum(np.isclose(mid, 0.0) | np.isclose(mid, 1.0), axis=1) >= 2).all()
    Vs, Fs = icosphere(2)
    assert len(crease_edges(Vs, Fs, curves)) == 0


def test_feature_template_of_a_cube_has_creases_and_of_a_sphere_none():
    from mi_loop.fitting.template import feature_template

    V, F = cube_mesh(10)
    Vt, Ft, E, info = feature_template(V, F, 150)
    assert abs(len(Vt) - 150) <= 8 and info["feature_curves"] == 1 and info["creases"] == len(E) > 0
    mid = 0.5 * (Vt[E[:, 0]] + Vt[E[:, 1]])
    assert (np.sum(np.isclose(mid, 0.0, atol=2e-3) | np.isclose(mid, 1.0, atol=2e-3), axis=1) >= 2).all()
    assert feature_template(*icosphere(3), 150) is None
    rough = V + 0.01 * np.random.default_rng(0).standard_normal(V.shape)     # a scan of a cube: its faces bend
    assert feature_curves(rough, F, 40.0, 0.5).n_curves >= 1                  # still sharp chains ...
    assert feature_template(rough, F, 150) is None                            # ... but not a fair surface


def _worst_normal_deviation(result):
    """Largest angle (degrees) between a limit normal and the nearest cube face normal (the 6 axes)."""
    _, _, N_lim = result.limit_mesh(3)
    return float(np.degrees(np.arccos(np.clip(np.abs(N_lim).max(1), 0.0, 1.0))).max())


def test_fit_keeps_a_cubes_edges_sharp_only_with_features(jit_variant):
    from mi_loop.fitting import FitOptions, fit
    from mi_loop.mesh.sampling import sample_surface

    V, F = cube_mesh(12)
    P, N = sample_surface(V, F, 20000, seed=0)[:2]
    sharp = fit(P, N, FitOptions(n_vertices=200, iterations=60), mesh=(V, F))
    smooth = fit(P, N, FitOptions(n_vertices=200, features="off", iterations=60), mesh=(V, F))
    assert sharp.params["n_creases"] > 0 and smooth.params["n_creases"] == 0 and smooth.creases is None
    assert sharp.info["template"]["feature_curves"] == 1
    worst_sharp, worst_smooth = _worst_normal_deviation(sharp), _worst_normal_deviation(smooth)
    assert worst_sharp < 20.0 and worst_smooth > 35.0, (worst_sharp, worst_smooth)   # a rounded edge reaches 45


def test_fit_cli_writes_the_creases_into_control_ply(tmp_path, capsys):
    V, F = cube_mesh(10)
    io.write_ply(tmp_path / "cube.ply", V, F)
    out = tmp_path / "out"
    assert main(["fit", str(tmp_path / "cube.ply"), "-o", str(out), "--vertices", "120",
                 "--iterations", "20"]) == 0
    err = capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    n = report["params"]["n_creases"]
    assert n > 0 and report["template"]["feature_curves"] == 1 and report["params"]["features"] == "auto"
    assert "sharp features: 1 feature curves (" in err and f"{n} crease edges on the control mesh" in err
    E, s = io.read_creases(out / "control.ply")
    assert len(E) == n and np.isinf(s).all()
    assert main(["fit", str(tmp_path / "cube.ply"), "-o", str(tmp_path / "off"), "--vertices", "120",
                 "--iterations", "5", "--features", "off"]) == 0
    assert io.read_creases(tmp_path / "off" / "control.ply") is None


def test_features_option_rejected(tmp_path, capsys):
    from mi_loop.fitting import FitOptions

    with pytest.raises(ValueError, match=exactly("FitOptions(): expected features to be 'auto' or 'off', got 'on'")):
        FitOptions(features="on")
    with pytest.raises(SystemExit):
        main(["fit", "--demo", "-o", str(tmp_path / "o"), "--features", "on"])
    assert "argument --features: invalid choice: 'on'" in capsys.readouterr().err
