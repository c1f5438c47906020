"""The ``mi-loop fit`` job (mi_loop.app.fit_job): outputs, report, bad input, atomic writes, templates."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from matplotlib import image as mpl_image

from mi_loop import datasets, io
from mi_loop.app.cli import main
from mi_loop.mesh.topology import validate_mesh

from helpers import (
    DATA,
    bunny_in_the_scans_frame,
    limit_surface,
    one_line_error,
    run_console,
    slot_template_runs,
    torus_cloud,
    torus_error,
    write_xyz,
)

# -- a successful run ----------------------------------------------------------------


def test_fit_demo_writes_control_limit_report_and_pictures(tmp_path, capsys, jit_variant):
    out = tmp_path / "out"
    code = main(["fit", "--demo", "-o", str(out), "--vertices", "100", "--iterations", "60"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    names = ["control.ply", "limit.ply", "limit.glb", "report.json", "report.html", "loss.png", "render.png"]
    assert captured.out.split() == [str(out / n) for n in names]
    assert "error" not in captured.err and "[mi-loop" in captured.err        # progress on stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(names)            # and nothing else

    report = json.loads((out / "report.json").read_text())
    assert report["input"] == "built-in noisy torus"
    assert report["input_info"]["n_points"] == 20200                         # 20000 + 1 % outliers
    params = report["params"]
    assert params["iterations"] == 60 and 1 <= params["iterations_run"] <= 60
    assert params["samples"] == "level1" and params["seed"] == 0
    # the demo's noise is known (sigma 0.5 % of the diagonal): estimated, and the ARAP weight follows it
    noise = report["noise"]
    assert noise["estimated"] and abs(noise["sigma_diagonal"] / 0.005 - 1) < 0.2, noise
    held = re.fullmatch(r"selected on (\d+) held-out points", noise["alpha"])
    assert held and abs(int(held.group(1)) - 2020) < 150, noise["alpha"]                # a tenth of the points
    selection = noise["selection"]
    assert selection["alphas"] == [0.001, 0.01, 0.1, 1.0][:len(selection["alphas"])]
    best = int(np.argmin(selection["held_out_mean"]))
    assert params["alpha"] == selection["alphas"][best] > 0.001                          # not the clean weight
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
    assert report["variant"] == jit_variant

    # the stage line names the terms that are on; the end says whether the fit converged
    err = captured.err
    assert ("fitting: template, limit operator, then Adam on IMLS + 3 x coverage + ARAP (weight chosen for the "
            "noise) + 0.01 x fold") in err
    assert re.search(r"noise: \d\.\d\de-03 of the diagonal, 0\.\d\d x the point spacing; ARAP weight \S+ "
                     r"\(selected on \d+ held-out points\)", err), err
    # folds: measured and written to report.json, and a warning line whenever one is non-zero
    assert 0 <= metrics["flipped_area_pct"] <= 100 and 0 <= metrics["self_intersecting_pct"] <= 100
    assert metrics["self_intersecting_faces"] == round(metrics["self_intersecting_pct"] / 100 * 64 * params["n_faces"])
    assert "input_self_intersecting_pct" not in metrics                      # points: no input mesh to test
    assert re.search(r"folds: \S+ % of the limit surface's area faces against the data, \d+ of \d+ limit faces", err)
    assert ("faces against the nearest data normal" in err) is (metrics["flipped_area_pct"] > 0)
    assert ("intersect another part of the surface" in err) is (metrics["self_intersecting_faces"] > 0)
    n = params["iterations_run"]
    assert report["converged"] is (n < 60)
    assert (f"converged after {n} iterations" if n < 60 else "stopped at the iteration cap (60)") in err

    # the demo knows the clean torus: distances to it too, next to those to the noisy points
    clean = report["metrics_clean"]
    assert set(clean) >= keys and all(np.isfinite(clean[k]) and clean[k] >= 0 for k in keys)
    assert clean["mean"] < metrics["mean"]               # noise and outliers are not on the clean surface
    assert clean["n_target"] == 20000 and metrics["n_target"] == 20200
    assert re.search(r"distance to the clean torus .*: mean \d\.\d\de-\d\d, RMS", err), err

    V, F = io.read_mesh(out / "control.ply")
    V_checked, _F_checked, _ = validate_mesh(V, F)                              # a valid control mesh
    assert len(V_checked) == len(V) == params["n_vertices"] and len(F) == params["n_faces"]
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), 1), axis=0)
    assert len(V) - len(E) + len(F) == 0                                       # closed genus-1 surface

    V_lim, F_lim = io.read_mesh(out / "limit.ply")
    V_ref, F_ref = limit_surface(V, F)
    np.testing.assert_array_equal(F_lim, F_ref)
    np.testing.assert_allclose(V_lim, V_ref, rtol=0, atol=1e-9)              # limit.ply is control.ply's limit
    assert torus_error(V_lim).mean() < 0.01                                    # and it lies on the torus
    import trimesh

    viewer = trimesh.load(out / "limit.glb", force="mesh", process=False)     # the viewer's: level 2 by default
    V_view, F_view = limit_surface(V, F, level=2)
    np.testing.assert_array_equal(viewer.faces, F_view)
    np.testing.assert_allclose(viewer.vertices, V_view, rtol=0, atol=1e-6)

    loss = mpl_image.imread(out / "loss.png")
    render = mpl_image.imread(out / "render.png")
    assert loss.shape[:2] == (400, 640) and render.shape[:2] == (320, 640)
    assert loss[..., :3].std() > 0.02 and render[..., :3].std() > 0.02       # not blank pictures


def test_console_script_reports_bad_input_without_traceback(tmp_path):
    out = tmp_path / "out"
    result = run_console("fit", str(tmp_path / "missing.xyz"), "-o", str(out), "--quiet", timeout=120)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr and result.stderr.count("\n") == 1, result.stderr
    assert re.match(r"mi-loop: error: load_oriented_points\(\): expected an existing file, got '.*missing\.xyz': "
                    r"no such file$", result.stderr)
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
                     r"load_oriented_points\(\): expected an existing file, got '.*missing\.xyz': no such file$"),
    "empty file": (empty_file, r"load_oriented_points\(\): expected points in '.*empty\.xyz', got none"),
    "NaN point": (nan_cloud, r"expected finite points in '.*nan\.xyz', got point 7 = \[.*nan.*\]"),
    "zero normal xyz": (zero_normal_xyz,
                        r"non-zero normals in '.*zero\.xyz', got normal 11 = \[0\.0, 0\.0, 0\.0\]"),
    "zero normal ply": (zero_normal_ply,
                        r"non-zero normals in '.*zero\.ply', got normal 5 = \[0\.0, 0\.0, 0\.0\]"),
    "too few points": (few_points, r"make_template\(\): n_vertices=1000 is more than half the 30 input points"),
    "non-manifold template": (non_manifold_template,
                              r"fit --template '.*nonman\.obj': .*edge \(0, 1\)"),
    "missing template": (missing_template, r"expected an existing file, got '.*nope\.ply': no such file$"),
    "template, too few points": (template_with_too_few_points,
                                 r"IMLS\(\): expected at least min_neighbors = 12 points, got 8"),
    "--vertices 3": (vertices(3), r"fit --vertices: expected an integer >= 4, got 3$"),
    "--vertices 10**6": (vertices(10**6),
                         r"make_template\(\): n_vertices=1000000 is more than half the 2000 input points"),
    "--h0 -1": (negative_h0, r"fit --h0: expected a finite number > 0 \(or None: automatic\), got -1\.0$"),
    "INPUT and --demo": (input_and_demo, r"fit INPUT: expected an input file or --demo \(one of them\), got both$"),
    "neither INPUT nor --demo": (lambda tmp_path: [],
                                 r"fit INPUT: expected an input file or --demo \(one of them\), got neither$"),
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
    assert re.search(r"ensure_writable_dir\(\): expected a directory that files can be created in, got "
                     r"'.*file/out': Not a directory$", line), line
    assert (tmp_path / "file").read_text() == "x"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "ok.xyz"]


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


# -- options are checked before any input is read ---------------------------------------


@pytest.mark.parametrize("argv, message", [
    (["--alpha", "-1"], r"fit --alpha: expected a finite number >= 0, got -1\.0$"),
    (["--cover", "nan"], r"fit --cover: expected a finite number >= 0, got nan$"),
    (["--fold", "-0.5"], r"fit --fold: expected a finite number >= 0, got -0\.5$"),
    (["--iterations", "0"], r"fit --iterations: expected an integer >= 1, got 0$"),
    (["--tolerance=-1e-3"], r"fit --tolerance: expected a finite number >= 0, got -0\.001$"),
    (["--seed", "-1"], r"fit --seed: expected an integer >= 0, got -1$"),
    (["--h0", "0"], r"fit --h0: expected a finite number > 0 \(or None: automatic\), got 0\.0$"),
    (["--vertices", "2"], r"fit --vertices: expected an integer >= 4, got 2$"),
])
def test_a_bad_option_fails_before_the_input_is_read(argv, message, tmp_path, capsys):
    """The input does not exist: an error about the option proves it came first."""
    out = tmp_path / "out"
    line = one_line_error(capsys, ["fit", str(tmp_path / "nonexistent" / "huge_scan.ply"), "-o", str(out),
                                   *argv])
    assert re.search(message, line), line
    assert list(tmp_path.iterdir()) == []                          # nothing written, not even OUTDIR


# -- --template: in the data's frame, polygons split --------------------------------------


#: The merged bunny range scans (points with normals).
SCAN = DATA / "scans" / "bunny_rangescans_merged_stride3.ply"


def test_a_template_in_another_frame_is_refused(tmp_path, capsys):
    """control/bunny_4667.ply is the remeshed bunny at about 10x the range scans' size, centred elsewhere."""
    out = tmp_path / "out"
    template = DATA / "control" / "bunny_4667.ply"
    line = one_line_error(capsys, ["fit", str(SCAN), "-o", str(out), "--template", str(template), "--quiet"])
    assert line.startswith(f"mi-loop: error: fit --template '{template}': expected a control mesh in the "
                           "data's frame (bounding-box diagonal within a factor 2 of the data's, centre within "
                           "0.25 of its diagonal), got a template 9.")
    assert line.endswith("scale and translate the template onto the data")
    assert not out.exists()


@pytest.mark.slow
def test_a_template_in_the_datas_frame_fits_the_scan(tmp_path, capsys):
    _P, V, F = bunny_in_the_scans_frame()
    io.write_ply(tmp_path / "bunny_314_scan.ply", V, F)
    out = tmp_path / "out"
    code = main(["fit", str(SCAN), "-o", str(out), "--template", str(tmp_path / "bunny_314_scan.ply"),
                 "--iterations", "40", "--quiet"])
    assert code == 0, capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert report["template"]["source"] == "file" and report["template"]["size_ratio"] == pytest.approx(1.0)
    assert report["metrics"]["mean"] < 0.01


def test_template_depth_and_genus_reach_the_static_fits_template(tmp_path, capsys):
    """A torus cut by a narrow slot: the default depth webs it (genus 1); depth 8 or genus 0 does not."""
    def run(data, out, flags):
        assert main(["fit", str(data), "-o", str(out), "--vertices", "300", "--iterations", "5", *flags]) == 0

    found = slot_template_runs(tmp_path, capsys, run, "control.ply")
    assert {name: g for name, (g, _) in found.items()} == {"default": 1, "depth 8": 0, "genus 0": 0}
    cut = {name: "template: 1 handle cut to genus 0 (loops" in err for name, (_, err) in found.items()}
    assert cut == {"default": False, "depth 8": False, "genus 0": True}


CUBE_OBJ = ("v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n"
            "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n")   # six outward quads


def test_a_quad_template_is_split_with_a_warning_and_recorded(tmp_path, capsys):
    P, N = torus_cloud(3000)
    (tmp_path / "cube.obj").write_text(CUBE_OBJ)
    out = tmp_path / "out"
    code = main(["fit", str(write_xyz(tmp_path / "in.xyz", P, N)), "-o", str(out), "--template",
                 str(tmp_path / "cube.obj"), "--iterations", "5", "--quiet"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert captured.err.splitlines() == [
        (f"mi-loop: warning: fit --template '{tmp_path / 'cube.obj'}': 6 faces with more than three corners "
         "were split into triangles (12 triangles); the Loop surface of the triangulated mesh is fitted")]
    template = json.loads((out / "report.json").read_text())["template"]
    assert template["split_polygons"] == 6 and template["n_faces"] == 12 and template["source"] == "file"


# -- pictures, divergence, progress ------------------------------------------------------


def test_a_fit_leaves_the_callers_matplotlib_backend_alone(tmp_path, capsys, monkeypatch):
    import matplotlib

    import mi_loop.app.report

    monkeypatch.setattr(mi_loop.app.report, "side_by_side", lambda *a, **k: np.zeros((8, 16, 3)))
    before = matplotlib.get_backend()
    matplotlib.use("svg")                                          # a program drawing SVG with pyplot
    try:
        P, N = torus_cloud(2000)
        code = main(["fit", str(write_xyz(tmp_path / "in.xyz", P, N)), "-o", str(tmp_path / "out"),
                     "--vertices", "60", "--iterations", "10", "--quiet"])
        assert code == 0, capsys.readouterr().err
        assert matplotlib.get_backend() == "svg"
    finally:
        matplotlib.use(before)


def test_a_diverging_fit_is_one_line(tmp_path, capsys, monkeypatch):
    import mitsuba as mi

    from mi_loop.energies.imls import IMLS

    energy = IMLS.energy
    monkeypatch.setattr(IMLS, "energy", lambda self, Q, reduce="sum": energy(self, Q, reduce) + mi.Float(float("nan")))
    P, N = torus_cloud(2000)
    out = tmp_path / "out"
    line = one_line_error(capsys, ["fit", str(write_xyz(tmp_path / "in.xyz", P, N)), "-o", str(out),
                                   "--vertices", "60", "--iterations", "10", "--quiet"])
    assert line == ("mi-loop: error: fit(): expected a finite energy, got imls nan at iteration 0 (the optimisation "
                    "diverged; try a smaller --alpha or another template)")
    assert not out.exists()


def test_the_stage_line_names_the_terms_that_are_on():
    from mi_loop.app.fit_job import _stage_line
    from mi_loop.fitting.options import FitOptions

    head = "fitting: template, limit operator, then Adam on "
    assert _stage_line(FitOptions()) == head + "IMLS + 3 x coverage + ARAP (weight chosen for the noise) + 0.01 x fold"
    assert _stage_line(FitOptions(alpha=0.001)) == head + "IMLS + 3 x coverage + 0.001 x ARAP + 0.01 x fold"
    assert _stage_line(FitOptions(alpha=0.001, fold=0.0)) == head + "IMLS + 3 x coverage + 0.001 x ARAP"
    assert _stage_line(FitOptions(alpha=0.5, cover=0.0, fold=0.0)) == head + "IMLS + 0.5 x ARAP"
    assert _stage_line(FitOptions(alpha=0.0, cover=1.5, fold=0.1)) == head + "IMLS + 1.5 x coverage + 0.1 x fold"
    assert _stage_line(FitOptions(alpha=0.0, cover=0.0, fold=0.0, no_crossing=True)) == (
        head + "IMLS; no step crosses the surface (--no-crossing)")


class _Log:
    """Collects what :mod:`mi_loop.app.fit_job` says and warns."""

    def __init__(self):
        self.said, self.warned = [], []

    def say(self, message):
        self.said.append(message)

    def warning(self, message):
        self.warned.append(message)


def test_folds_are_measured_reported_and_warned_about():
    """An inverted cap (faces reversed, 20.8 % of the area) and a vertex pushed through the far side."""
    from mi_loop.app.fit_job import _folds

    V, F = datasets.icosphere(3)
    log = _Log()
    assert _folds(V, F, ("mesh", V, F), log) == {"flipped_area_pct": 0.0, "self_intersecting_pct": 0.0,
                                                  "self_intersecting_faces": 0, "input_self_intersecting_pct": 0.0}
    assert log.warned == [] and log.said == ["folds: 0 % of the limit surface's area faces against the data, "
                                             "0 of 1280 limit faces intersect the surface elsewhere"]
    G = F.copy()
    cap = V[F].mean(1)[:, 2] > 0.6
    G[cap] = G[cap][:, ::-1]
    W = V.copy()
    W[int(np.argmax(V[:, 2]))] = [0.0, 0.0, -1.5]
    out = _folds(W, G, ("mesh", V, F), log)
    assert 10 < out["flipped_area_pct"] < 30 and out["self_intersecting_faces"] >= 6
    assert out["self_intersecting_pct"] == pytest.approx(100 * out["self_intersecting_faces"] / 1280)
    flipped, crossed = log.warned
    assert flipped == (f"{out['flipped_area_pct']:.3g} % of the limit surface's area faces against the nearest data "
                       "normal (a fold, or a part too thin for the control mesh): see render.png; more --vertices "
                       "or a larger --fold may remove it")
    assert crossed == (f"{out['self_intersecting_faces']} of 1280 limit faces ({out['self_intersecting_pct']:.3g} %) "
                       "intersect another part of the surface; the input has 0 %; more --vertices, a larger --fold "
                       "or --no-crossing may remove them")
    log = _Log()
    _folds(W, G, ("mesh", V, F), log, guarded=True)          # a fit that ran with --no-crossing: what is left
    assert log.warned[1] == (f"{out['self_intersecting_faces']} of 1280 limit faces "
                             f"({out['self_intersecting_pct']:.3g} %) intersect another part of the surface; the "
                             "input has 0 %; more --vertices or a larger --fold may remove them (--no-crossing keeps "
                             "apart only limit triangles whose control faces share no corner)")
    # against oriented points (no input mesh): the normals decide, and there is no input share
    P, N = V[::2], V[::2]
    log = _Log()
    out = _folds(V, G, ("points", P, N), log)
    assert 10 < out["flipped_area_pct"] < 30 and "input_self_intersecting_pct" not in out
    assert len(log.warned) == 1 and "faces against the nearest data normal" in log.warned[0]
