"""Tests of ``mi-loop fit`` and ``mi-loop compare`` (mi_loop.app.cli, mi_loop.app.fit_job)."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib import image as mpl_image

from mi_loop import datasets, io
from mi_loop.app.cli import main
from mi_loop.subdiv.limit import limit_matrix
from mi_loop.subdiv.tessellation import tessellate
from mi_loop.mesh.topology import validate_mesh
from helpers import one_line_error

MI_LOOP = Path(sys.executable).with_name("mi-loop")



def torus_error(V, R=1.0, r=0.4):
    """Analytic distance of points to the torus of radii (R, r) around the z axis."""
    return np.abs(np.hypot(np.hypot(V[:, 0], V[:, 1]) - R, V[:, 2]) - r)


def limit_surface(V, F, level=3):
    fid, uv, F_t = tessellate(F, level)
    return limit_matrix(F, len(V), fid, uv) @ V, F_t


def write_xyz(path, P, N):
    np.savetxt(path, np.hstack([P, N]))
    return path


def torus_cloud(n=2000, seed=3):
    P, N, _ = datasets.noisy_torus_points(n, outliers=0.0, seed=seed)
    return P, N


# -- a successful run ----------------------------------------------------------------


def test_fit_demo_writes_control_limit_report_and_pictures(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["fit", "--demo", "-o", str(out), "--vertices", "100", "--iterations", "60", "--quiet"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    names = ["control.ply", "limit.ply", "report.json", "loss.png", "render.png"]
    assert captured.out.split() == [str(out / n) for n in names]
    assert "error" not in captured.err and "[mi-loop" in captured.err        # progress on stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(names)            # and nothing else

    report = json.loads((out / "report.json").read_text())
    assert report["input"] == "built-in noisy torus"
    assert report["input_info"]["n_points"] == 20200                         # 20000 + 1 % outliers
    params = report["params"]
    assert params["max_iterations"] == 60 and 1 <= params["iterations"] <= 60
    assert params["samples"] == "level1" and params["alpha"] == 0.001 and params["seed"] == 0
    assert abs(params["n_vertices"] - 100) <= 10
    assert set(report["timings_s"]) >= {"template", "operator", "energies", "optimisation", "total",
                                         "metrics", "pictures"}
    assert all(np.isfinite(t) and t >= 0 for t in report["timings_s"].values())
    metrics = report["metrics"]
    keys = {f"{d}_{s}" for d in ("p2s", "s2p") for s in ("mean", "rms", "max")} | {"mean", "rms", "hausdorff"}
    assert set(metrics) >= keys and all(np.isfinite(metrics[k]) and metrics[k] >= 0 for k in keys)
    assert metrics["mean"] < 0.01                                              # 1 % of the bbox diagonal
    assert report["template"]["genus"] == 1
    assert all(np.isfinite(v) for v in report["final_energy"].values())

    V, F = io.read_mesh(out / "control.ply")
    V_checked, F_checked, _ = validate_mesh(V, F)                              # a valid control mesh
    assert len(V_checked) == len(V) == params["n_vertices"] and len(F) == params["n_faces"]
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), 1), axis=0)
    assert len(V) - len(E) + len(F) == 0                                       # closed genus-1 surface

    V_lim, F_lim = io.read_mesh(out / "limit.ply")
    V_ref, F_ref = limit_surface(V, F)
    np.testing.assert_array_equal(F_lim, F_ref)
    np.testing.assert_allclose(V_lim, V_ref, rtol=0, atol=1e-9)              # limit.ply is control.ply's limit
    assert torus_error(V_lim).mean() < 0.01                                    # and it lies on the torus

    loss = mpl_image.imread(out / "loss.png")
    render = mpl_image.imread(out / "render.png")
    assert loss.shape[:2] == (400, 640) and render.shape[:2] == (320, 640)
    assert loss[..., :3].std() > 0.02 and render[..., :3].std() > 0.02       # not blank pictures


def test_console_script_reports_bad_input_without_traceback(tmp_path):
    out = tmp_path / "out"
    result = subprocess.run([str(MI_LOOP), "fit", str(tmp_path / "missing.xyz"), "-o", str(out), "--quiet"],
                            capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr and result.stderr.count("\n") == 1, result.stderr
    assert re.match(r"mi-loop: error: load_oriented_points: '.*missing\.xyz': no such file$", result.stderr)
    assert result.stdout == "" and not out.exists()


# -- bad input: exit 1, one line, nothing in OUTDIR ----------------------------------


def nan_cloud(tmp_path):
    P, N = torus_cloud()
    P[7, 1] = np.nan
    return [str(write_xyz(tmp_path / "nan.xyz", P, N))]


def zero_normal_xyz(tmp_path):
    P, N = torus_cloud()
    N[11] = 0.0
    return [str(write_xyz(tmp_path / "zero.xyz", P, N))]


def zero_normal_ply(tmp_path):
    P, N = torus_cloud()
    N[5] = 0.0
    return [str(io.write_ply(tmp_path / "zero.ply", P, np.zeros((0, 3), dtype=np.int64), normals=N))]


def empty_file(tmp_path):
    (tmp_path / "empty.xyz").write_text("")
    return [str(tmp_path / "empty.xyz")]


def few_points(tmp_path):
    P, N = torus_cloud()
    return [str(write_xyz(tmp_path / "few.xyz", P[:30], N[:30]))]           # default --vertices 1000


def non_manifold_template(tmp_path):
    P, N = torus_cloud()
    (tmp_path / "nonman.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\n"
                                         "f 1 2 3\nf 1 2 4\nf 2 1 5\n")    # three faces on edge (0, 1)
    return [str(write_xyz(tmp_path / "ok.xyz", P, N)), "--template", str(tmp_path / "nonman.obj")]


def missing_template(tmp_path):
    P, N = torus_cloud()
    return [str(write_xyz(tmp_path / "ok.xyz", P, N)), "--template", str(tmp_path / "nope.ply")]


def template_with_too_few_points(tmp_path):
    P, N = torus_cloud()
    io.write_ply(tmp_path / "ico.ply", *datasets.icosphere(1))
    return [str(write_xyz(tmp_path / "tiny.xyz", P[:8], N[:8])), "--template", str(tmp_path / "ico.ply")]


def vertices(count):
    def build(tmp_path):
        P, N = torus_cloud()
        return [str(write_xyz(tmp_path / "ok.xyz", P, N)), "--vertices", str(count)]
    return build


def negative_h0(tmp_path):
    P, N = torus_cloud()
    return [str(write_xyz(tmp_path / "ok.xyz", P, N)), "--vertices", "60", "--h0", "-1"]


def input_and_demo(tmp_path):
    P, N = torus_cloud()
    return [str(write_xyz(tmp_path / "ok.xyz", P, N)), "--demo"]


BAD_INPUTS = {
    "missing file": (lambda tmp_path: [str(tmp_path / "missing.xyz")],
                     r"load_oriented_points: '.*missing\.xyz': no such file$"),
    "empty file": (empty_file, r"load_oriented_points: '.*empty\.xyz': the file holds no points$"),
    "NaN point": (nan_cloud, r"'.*nan\.xyz': point 7 has a non-finite coordinate \[.*nan.*\]"),
    "zero normal xyz": (zero_normal_xyz,
                        r"'.*zero\.xyz': normal 11 is zero-length or non-finite \[0\.0, 0\.0, 0\.0\]"),
    "zero normal ply": (zero_normal_ply,
                        r"'.*zero\.ply': normal 5 is zero-length or non-finite \[0\.0, 0\.0, 0\.0\]"),
    "too few points": (few_points, r"make_template\(\): n_vertices=1000 is more than half the 30 input points"),
    "non-manifold template": (non_manifold_template,
                              r"--template .*nonman\.obj: edge \(0, 1\) is used twice in the same direction"),
    "missing template": (missing_template, r"read_mesh: '.*nope\.ply': no such file$"),
    "template, too few points": (template_with_too_few_points,
                                 r"IMLS\(\): expected at least min_neighbors = 12 points, got 8"),
    "--vertices 3": (vertices(3), r"fit: --vertices must be at least 4, got 3$"),
    "--vertices 10**6": (vertices(10**6),
                         r"make_template\(\): n_vertices=1000000 is more than half the 2000 input points"),
    "--h0 -1": (negative_h0, r"IMLS\(\): expected a finite h0 > 0 .*got -1\.0$"),
    "INPUT and --demo": (input_and_demo, r"fit: give either an INPUT file or --demo$"),
    "neither INPUT nor --demo": (lambda tmp_path: [], r"fit: give either an INPUT file or --demo$"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_fit_rejects_bad_input_and_writes_nothing(case, tmp_path, capsys):
    build, message = BAD_INPUTS[case]
    out = tmp_path / "out"
    line = one_line_error(capsys, ["fit", *build(tmp_path), "-o", str(out), "--quiet"])
    assert re.search(message, line), line
    assert not out.exists()


def test_fit_failure_leaves_an_existing_output_directory_empty(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    line = one_line_error(capsys, ["fit", *few_points(tmp_path), "-o", str(out), "--quiet"])
    assert "is more than half the 30 input points" in line
    assert out.is_dir() and list(out.iterdir()) == []


def test_fit_failure_removes_the_parents_it_created(tmp_path, capsys):
    one_line_error(capsys, ["fit", *few_points(tmp_path), "-o", str(tmp_path / "new" / "deep" / "out")])
    assert not (tmp_path / "new").exists()


def test_fit_rejects_an_output_path_under_a_regular_file(tmp_path, capsys):
    P, N = torus_cloud()
    (tmp_path / "file").write_text("x")
    line = one_line_error(capsys, ["fit", str(write_xyz(tmp_path / "ok.xyz", P, N)),
                                   "-o", str(tmp_path / "file" / "out"), "--quiet"])
    assert re.search(r"cannot write to directory '.*file/out': Not a directory$", line), line
    assert (tmp_path / "file").read_text() == "x"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "ok.xyz"]


@pytest.mark.parametrize("argv, message", [
    (["--iterations", "0"], r"argument --iterations: expected a positive integer, got 0"),
    (["--vertices", "50", "--template", "t.ply"], r"argument --template: not allowed with argument --vertices"),
    (["--samples", "grid"], r"argument --samples: invalid choice: 'grid'"),
])
def test_fit_usage_errors_exit_2(argv, message, tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as info:
        main(["fit", "--demo", "-o", str(out), *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mi-loop fit: error: "), err
    assert re.search(message, err), err
    assert not out.exists()


# -- atomic writes ---------------------------------------------------------------------


def test_a_failing_writer_leaves_no_temporary_or_partial_file(tmp_path, capsys, monkeypatch):
    import matplotlib.image
    import mi_loop.app.report

    def full_disk(f, *args, **kwargs):
        f.write(b"\x89PNG half an image")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(matplotlib.image, "imsave", full_disk)        # the PNG writers fail midway
    monkeypatch.setattr(mi_loop.app.report, "side_by_side", lambda *a, **k: np.zeros((8, 16, 3)))  # skip rendering
    P, N = torus_cloud(3000)
    out = tmp_path / "out"
    line = one_line_error(capsys, ["fit", str(write_xyz(tmp_path / "in.xyz", P, N)), "-o", str(out),
                                   "--vertices", "60", "--iterations", "40", "--quiet"])
    assert line == "mi-loop: error: [Errno 28] No space left on device"
    # outputs are staged and moved together: a failed run leaves nothing, not even OUTDIR
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.xyz"]


def test_a_failing_writer_keeps_an_existing_outdir_as_it_was(tmp_path, capsys, monkeypatch):
    import matplotlib.image
    import mi_loop.app.report

    def full_disk(f, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(matplotlib.image, "imsave", full_disk)
    monkeypatch.setattr(mi_loop.app.report, "side_by_side", lambda *a, **k: np.zeros((8, 16, 3)))
    P, N = torus_cloud(3000)
    out = tmp_path / "out"
    out.mkdir()
    (out / "control.ply").write_text("from an earlier run")
    one_line_error(capsys, ["fit", str(write_xyz(tmp_path / "in.xyz", P, N)), "-o", str(out),
                            "--vertices", "60", "--iterations", "40", "--quiet"])
    assert sorted(p.name for p in out.iterdir()) == ["control.ply"]   # no staging dir, no .tmp
    assert (out / "control.ply").read_text() == "from an earlier run"


# -- mi-loop compare -------------------------------------------------------------------


def run_compare(capsys, argv):
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
    assert set(result) == {"two_sided"}
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
    assert re.search(r"read_mesh: '.*nope\.ply': no such file$", line), line
    line = one_line_error(capsys, ["compare", str(tmp_path / "control.ply"), str(tmp_path / "nope.xyz")])
    assert re.search(r"load_oriented_points: '.*nope\.xyz': no such file$", line), line
    (tmp_path / "nonman.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\n"
                                         "f 1 2 3\nf 1 2 4\nf 2 1 5\n")
    line = one_line_error(capsys, ["compare", str(tmp_path / "nonman.obj"), str(tmp_path / "points.xyz")])
    assert re.search(r"compare: .*nonman\.obj: edge \(0, 1\) is used twice", line), line
