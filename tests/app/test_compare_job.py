"""The ``mi-loop compare`` job (mi_loop.app.compare_job): analytic distances, what it measures, bad files."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from mi_loop import datasets, io
from mi_loop.app.cli import main

from helpers import limit_surface, one_line_error, torus_cloud, write_xyz


def run_compare(capsys, argv):
    """Run ``mi-loop compare`` in-process, check that it exits 0, return its JSON output."""
    code = main(["compare", *argv])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)


def test_compare_control_mesh_with_its_own_limit_surface_is_zero(tmp_path, capsys):
    V, F = datasets.blob(1)
    io.write_ply(tmp_path / "control.ply", V, F)
    io.write_ply(tmp_path / "target.ply", *limit_surface(V, F))
    result = run_compare(capsys, [str(tmp_path / "control.ply"), str(tmp_path / "target.ply"),
                                  "--json", str(tmp_path / "sub" / "numbers.json")])
    two = result["two_sided"]
    for key in ("p2s_mean", "p2s_rms", "p2s_max", "s2p_mean", "s2p_rms", "s2p_max", "mean", "rms", "hausdorff"):
        assert 0 <= two[key] < 1e-9, (key, two[key])
    V_lim = limit_surface(V, F)[0]
    np.testing.assert_allclose(two["diagonal"], np.linalg.norm(np.ptp(V_lim, axis=0)), rtol=1e-12)
    nps = result["nps"]
    for key in ("P2S", "HD", "p2s_fit_to_target", "p2s_target_to_fit"):
        assert 0 <= nps[key] < 1e-9, (key, nps[key])
    assert 0 <= nps["NAE"] < 1e-3 and 0 <= nps["NAE_oriented"] < 1e-3     # degrees
    assert json.loads((tmp_path / "sub" / "numbers.json").read_text()) == result


def test_compare_plain_meshes_scaled_spheres_matches_the_offset(tmp_path, capsys):
    """A convex polyhedron A and B = (1 + delta) A are between delta * r_in and delta apart everywhere,
    with r_in the smallest distance of A's face planes from the centre and A's vertices on the unit sphere."""
    delta = 0.01
    V, F = datasets.icosphere(3)
    io.write_ply(tmp_path / "a.ply", V, F)
    io.write_ply(tmp_path / "b.ply", (1 + delta) * V, F)
    result = run_compare(capsys, [str(tmp_path / "a.ply"), str(tmp_path / "b.ply"), "--mesh"])
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    r_in = np.min(np.einsum("ij,ij->i", n / np.linalg.norm(n, axis=1, keepdims=True), V[F[:, 0]]))
    lo, hi = delta * r_in * (1 - 1e-9), delta * (1 + 1e-9)

    two = result["two_sided"]
    np.testing.assert_allclose(two["diagonal"], (1 + delta) * np.linalg.norm(np.ptp(V, axis=0)), rtol=1e-12)
    for key in ("p2s_mean", "p2s_max", "s2p_mean", "s2p_max", "mean", "rms", "hausdorff"):
        assert lo <= two[key] * two["diagonal"] <= hi, (key, two[key] * two["diagonal"], lo, hi)
    nps = result["nps"]
    np.testing.assert_allclose(nps["scale"], 2 / ((1 + delta) * np.ptp(V, axis=0).max()), rtol=1e-12)
    for key in ("P2S", "HD", "p2s_fit_to_target", "p2s_target_to_fit"):
        assert lo <= nps[key] / nps["scale"] <= hi, (key, nps[key] / nps["scale"], lo, hi)
    assert 0 <= nps["NAE"] < 1.0 and nps["NAE_oriented"] == pytest.approx(nps["NAE"])   # same orientation


def test_compare_with_a_point_target_has_no_nps(tmp_path, capsys):
    V, F = datasets.icosphere(1)
    V_lim, F_lim = limit_surface(V, F)
    io.write_ply(tmp_path / "control.ply", V, F)
    write_xyz(tmp_path / "points.xyz", V_lim, V_lim)                 # the limit points lie on the surface
    result = run_compare(capsys, [str(tmp_path / "control.ply"), str(tmp_path / "points.xyz")])
    assert set(result) == {"fitted", "two_sided", "definitions"}
    assert set(result["definitions"]) == {"two_sided"}
    two = result["two_sided"]
    assert two["n_target"] == len(V_lim)
    assert 0 <= two["p2s_max"] < 1e-9                                  # target points to the surface
    # surface samples to the nearest target point: positive, at most the longest tessellation edge
    longest = max(np.linalg.norm(V_lim[F_lim[:, i]] - V_lim[F_lim[:, (i + 1) % 3]], axis=1).max()
                  for i in range(3))
    assert 0 < two["s2p_mean"] <= two["s2p_max"] <= longest / two["diagonal"]


def test_compare_rejects_bad_files(tmp_path, capsys):
    io.write_ply(tmp_path / "control.ply", *datasets.icosphere(1))
    write_xyz(tmp_path / "points.xyz", *torus_cloud(100))
    line = one_line_error(capsys, ["compare", str(tmp_path / "nope.ply"), str(tmp_path / "points.xyz")])
    assert re.search(r"read_mesh\(\): expected an existing file, got '.*nope\.ply': no such file$", line), line
    line = one_line_error(capsys, ["compare", str(tmp_path / "control.ply"), str(tmp_path / "nope.xyz")])
    assert re.search(r"load_oriented_points\(\): expected an existing file, got '.*nope\.xyz': no such file$",
                     line), line
    (tmp_path / "nonman.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\n"
                                         "f 1 2 3\nf 1 2 4\nf 2 1 5\n")
    line = one_line_error(capsys, ["compare", str(tmp_path / "nonman.obj"), str(tmp_path / "points.xyz")])
    assert re.search(r"compare: .*nonman\.obj: .*edge \(0, 1\)", line), line


def test_compare_output_defines_its_numbers(tmp_path, capsys):
    V, F = datasets.icosphere(2)
    io.write_ply(tmp_path / "a.ply", V, F)
    io.write_ply(tmp_path / "b.ply", 1.01 * V, F)
    result = run_compare(capsys, [str(tmp_path / "a.ply"), str(tmp_path / "b.ply")])
    assert result["fitted"] == {"path": str(tmp_path / "a.ply"), "n_vertices": 162,
                                "as": "control mesh (its limit surface at level 3)"}
    definitions = result["definitions"]
    assert set(definitions) == {"two_sided", "nps"}
    assert {"P2S", "HD", "NAE", "units"} <= set(definitions["nps"])
    assert "degrees" in definitions["nps"]["NAE"] and "largest extent is 2" in definitions["nps"]["units"]
    assert "bounding-box diagonal" in definitions["two_sided"]["units"]
    for key in result["two_sided"]:                                # every number has its definition
        assert any(key in name.split(", ") for name in definitions["two_sided"]) or key == "diagonal"


@pytest.mark.slow
def test_compare_measures_a_dense_mesh_as_it_is_and_says_so(tmp_path, capsys, monkeypatch):
    from mi_loop.app import compare_job

    monkeypatch.setattr(compare_job, "CONTROL_VERTEX_LIMIT", 100)   # icosphere(2): 162 vertices
    V, F = datasets.icosphere(2)
    io.write_ply(tmp_path / "limit.ply", V, F)
    io.write_ply(tmp_path / "target.ply", V, F)
    code = main(["compare", str(tmp_path / "limit.ply"), str(tmp_path / "target.ply")])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    result = json.loads(captured.out)
    assert result["fitted"]["as"] == "plain triangle mesh"
    assert result["two_sided"]["hausdorff"] < 1e-9                  # the same mesh: measured as it is
    assert ("FITTED 'limit.ply' has 162 vertices (more than 100): measuring it as a plain triangle mesh; "
            "pass --control to evaluate its limit surface") in captured.err
    code = main(["compare", str(tmp_path / "limit.ply"), str(tmp_path / "target.ply"), "--control", "--quiet"])
    captured = capsys.readouterr()
    assert code == 0 and captured.err == ""
    result = json.loads(captured.out)
    assert result["fitted"]["as"] == "control mesh (its limit surface at level 3)"
    assert result["two_sided"]["hausdorff"] > 1e-3                  # the limit surface shrinks inside
