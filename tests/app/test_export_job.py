"""``mi-loop export`` (mi_loop.app.export_job) and ``--view-level``: the limit surface of a result directory
as GLB, OBJ or PLY, the same files as the jobs write, and every refusal with its message."""
from __future__ import annotations

import contextlib
import json
import re
from types import SimpleNamespace

import numpy as np
import pytest

from mi_loop import datasets, io
from mi_loop.app import batch_job
from mi_loop.app import cluster as cluster_module
from mi_loop.app.cli import main
from mi_loop.app.parser import build_parser
from mi_loop.io.runs import CSV_HEADER
from mi_loop.subdiv.masks import limit_colors, limit_mesh

from helpers import one_line_error, parse_glb, torus_cloud, write_xyz

WANT = ("export OUT: expected a result directory of mi-loop fit or fit-images (control.ply) or of fit-sequence "
        "(sequence.json, metrics.csv, control/NNNN.ply), got ")


@pytest.fixture(scope="module")
def fit_result(tmp_path_factory):
    """``mi-loop fit`` of a small torus cloud with ``--view-level 1``."""
    root = tmp_path_factory.mktemp("fit")
    out = root / "out"
    assert main(["fit", str(write_xyz(root / "torus.xyz", *torus_cloud(2000))), "-o", str(out), "--vertices", "60",
                 "--iterations", "10", "--view-level", "1", "--quiet"]) == 0
    return out


def write_sequence(out, T=3, fps=10.0, albedo=False, faces=None):
    """A fit-sequence result written by hand: control/NNNN.ply of a moving icosphere(1), metrics.csv, sequence.json."""
    V, F = datasets.icosphere(1)
    (out / "control").mkdir(parents=True)
    rows = []
    for t in range(T):
        colors = np.clip(0.5 + 0.3 * V * (t + 1) / T, 0, 1) if albedo else None
        io.write_ply(out / "control" / f"{t:04d}.ply", V * (1 + 0.1 * t) + [0.2 * t, 0, 0],
                     F if faces is None or t == 0 else faces, colors=colors)
        rows.append(f"{t},walk[{t}],0.001,0.001,0.002,0,,,1.0,0.0,10")
    (out / "metrics.csv").write_text(CSV_HEADER + "\n" + "\n".join(rows) + "\n")
    (out / "sequence.json").write_text(json.dumps({} if fps is None else {"fps": fps}))
    return out


def test_the_fit_writes_limit_glb_at_its_view_level_and_export_rewrites_it(fit_result, tmp_path, capsys):
    V, F = io.read_mesh(fit_result / "control.ply")
    doc, read = parse_glb(fit_result / "limit.glb")
    prim, = doc["meshes"][0]["primitives"]
    P, F_t, N = limit_mesh(V, F, 1)                                        # --view-level 1
    np.testing.assert_allclose(read(prim["attributes"]["POSITION"]), P, rtol=0, atol=1e-6)
    np.testing.assert_allclose(read(prim["attributes"]["NORMAL"]), N, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(read(prim["indices"]).reshape(-1, 3), F_t)
    before = {p.name: p.stat().st_mtime_ns for p in fit_result.iterdir() if p.is_file()}

    capsys.readouterr()
    assert main(["export", str(fit_result), "--level", "1"]) == 0
    captured = capsys.readouterr()
    assert captured.out.split() == [str(fit_result / "export" / "limit.glb")]
    assert "limit surface at level 1: 240 vertices, 480 triangles" in captured.err
    assert (fit_result / "export" / "limit.glb").read_bytes() == (fit_result / "limit.glb").read_bytes()
    # obj and ply default to limit.ply's level (3): the same surface as the fit wrote
    assert main(["export", str(fit_result), "--format", "ply", "--quiet"]) == 0
    assert (fit_result / "export" / "limit.ply").read_bytes() == (fit_result / "limit.ply").read_bytes()
    assert main(["export", str(fit_result), "--format", "obj", "--quiet"]) == 0
    V_obj, F_obj = io.read_mesh(fit_result / "export" / "limit.obj")
    V_lim, F_lim = io.read_mesh(fit_result / "limit.ply")
    np.testing.assert_array_equal(F_obj, F_lim)
    np.testing.assert_array_equal(V_obj, V_lim)                        # 17 digits: float64 exactly
    assert len((fit_result / "export" / "limit.obj").read_text().split("\nvn ")) == len(V_lim) + 1   # normals too
    # -o: any .glb path, its directories created; level 0 is the limit points of the control vertices
    capsys.readouterr()
    target = tmp_path / "new" / "deep" / "coarse.glb"
    assert main(["export", str(fit_result), "--level", "0", "-o", str(target), "--quiet"]) == 0
    assert capsys.readouterr().out.split() == [str(target)]
    doc, read = parse_glb(target)
    assert doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]["count"] == len(V)
    assert {p.name: p.stat().st_mtime_ns for p in fit_result.iterdir() if p.is_file()} == before   # untouched


def test_a_sequence_exports_as_one_animated_glb_at_its_rate(tmp_path, capsys):
    out = write_sequence(tmp_path / "seq", fps=10.0)
    assert main(["export", str(out), "--quiet"]) == 0
    assert capsys.readouterr().out.split() == [str(out / "export" / "sequence.glb")]
    doc, read = parse_glb(out / "export" / "sequence.glb")
    prim, = doc["meshes"][0]["primitives"]
    assert len(prim["targets"]) == 3 and doc["meshes"][0]["extras"]["targetNames"] == ["walk[0]", "walk[1]", "walk[2]"]
    base = read(prim["attributes"]["POSITION"])
    assert len(base) == 162                                                # the default view level: 1
    for t, target in enumerate(prim["targets"]):
        P, _, _ = limit_mesh(*io.read_mesh(out / "control" / f"{t:04d}.ply"), 1)
        np.testing.assert_allclose(base + read(target["POSITION"]), P, rtol=0, atol=1e-6)
    times = read(doc["animations"][0]["samplers"][0]["input"]).ravel()
    np.testing.assert_array_equal(times, (np.arange(3) / 10.0).astype(np.float32))      # sequence.json's rate
    assert main(["export", str(out), "--fps", "30", "-o", str(tmp_path / "fast.glb"), "--quiet"]) == 0
    doc, read = parse_glb(tmp_path / "fast.glb")
    np.testing.assert_array_equal(read(doc["animations"][0]["samplers"][0]["input"]).ravel(),
                                  (np.arange(3) / 30.0).astype(np.float32))
    older = write_sequence(tmp_path / "older", fps=None)                    # a run from before sequence.json had it
    assert main(["export", str(older), "--quiet"]) == 0
    doc, read = parse_glb(older / "export" / "sequence.glb")
    assert read(doc["animations"][0]["samplers"][0]["input"]).ravel()[1] == np.float32(1 / 24)


def test_frame_names_with_commas_and_older_runs_export(tmp_path, capsys):
    """metrics.csv goes through the csv module: a frame name with a comma is one name; a run from before the
    fold and drift columns (its older header) still exports."""
    from mi_loop.io.runs import OLDER_COLUMNS, MetricsRow, write_metrics

    out = write_sequence(tmp_path / "seq")
    write_metrics(out / "metrics.csv", [MetricsRow(t, f"scan {t}, left", 0.001, 0.001, 0.002, 0.0, None, None, 1.0,
                                                   0.0, 10) for t in range(3)])
    assert main(["export", str(out), "--quiet"]) == 0
    doc, _ = parse_glb(out / "export" / "sequence.glb")
    assert doc["meshes"][0]["extras"]["targetNames"] == ["scan 0, left", "scan 1, left", "scan 2, left"]
    older = write_sequence(tmp_path / "older")
    (older / "metrics.csv").write_text(",".join(OLDER_COLUMNS) + "\n"
                                       + "".join(f"{t},walk[{t}],0.001,0.001,0.002,1.0,0.0,10\n" for t in range(3)))
    assert main(["export", str(older), "--quiet"]) == 0
    doc, _ = parse_glb(older / "export" / "sequence.glb")
    assert doc["meshes"][0]["extras"]["targetNames"] == ["walk[0]", "walk[1]", "walk[2]"]


def test_a_sequence_exports_as_one_file_per_frame_with_its_colours(tmp_path, capsys):
    out = write_sequence(tmp_path / "seq", albedo=True)
    assert main(["export", str(out), "--format", "ply", "--quiet"]) == 0
    assert capsys.readouterr().out.split() == [str(out / "export" / f"{t:04d}.ply") for t in range(3)]
    for t in range(3):
        V, F = io.read_mesh(out / "control" / f"{t:04d}.ply")
        P, F_t, _ = limit_mesh(V, F, 2)                                     # as limit/NNNN.ply
        V_ply, F_ply = io.read_mesh(out / "export" / f"{t:04d}.ply")
        np.testing.assert_array_equal(V_ply, P)
        np.testing.assert_array_equal(F_ply, F_t)
        albedo = io.read_vertex_colors(out / "control" / f"{t:04d}.ply")
        np.testing.assert_allclose(io.read_vertex_colors(out / "export" / f"{t:04d}.ply"),
                                   limit_colors(albedo, F, 2), atol=1e-6)      # each frame's own albedo
    assert main(["export", str(out), "--format", "obj", "--level", "1", "-o", str(tmp_path / "frames"), "--quiet"]) == 0
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["0000.obj", "0001.obj", "0002.obj"]
    assert len(io.read_mesh(tmp_path / "frames" / "0002.obj")[0]) == 162
    assert main(["export", str(out), "--quiet"]) == 0                      # glb: the last frame's albedo
    doc, read = parse_glb(out / "export" / "sequence.glb")
    albedo = io.read_vertex_colors(out / "control" / "0002.ply")
    np.testing.assert_allclose(read(doc["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"]),
                               limit_colors(albedo, datasets.icosphere(1)[1], 1), atol=1e-6)


# -- refused: one line, exit 1, nothing written ------------------------------------------


def not_a_ply(tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "control.ply").write_text("not a ply\n")
    return [str(tmp_path / "r")]


def other_faces(tmp_path):
    F = datasets.icosphere(1)[1].copy()
    F[0] = F[0, ::-1]
    write_sequence(tmp_path / "r", faces=F)
    return [str(tmp_path / "r")]


def only(*names):
    """A directory holding just these files (empty or a CSV header)."""
    def build(tmp_path):
        (tmp_path / "r").mkdir()
        for name in names:
            (tmp_path / "r" / name).write_text(CSV_HEADER + "\n" if name == "metrics.csv" else "{}")
        return [str(tmp_path / "r")]
    return build


def without_frame(tmp_path):
    (write_sequence(tmp_path / "r") / "control" / "0001.ply").unlink()
    return [str(tmp_path / "r")]


def with_output(name, kind="fit"):
    def build(tmp_path):
        if kind == "fit":
            (tmp_path / "r").mkdir()
            io.write_ply(tmp_path / "r" / "control.ply", *datasets.icosphere(1))
        else:
            write_sequence(tmp_path / "r")
        (tmp_path / "taken.ply").write_text("a file")
        (tmp_path / "taken").write_text("a file")
        (tmp_path / "dir.glb").mkdir()
        return [str(tmp_path / "r"), *name]
    return build


REFUSED = {
    "no such directory": (lambda t: [str(t / "nope")], WANT + "'{t}/nope': no such directory"),
    "a file": (lambda t: [str(io.write_ply(t / "c.ply", *datasets.icosphere(1)))], WANT + "'{t}/c.ply': a file"),
    "an empty directory": (only(), WANT + "'{t}/r' without control.ply or sequence.json"),
    "a fit-batch OUTDIR": (only("summary.csv"), WANT + "'{t}/r' without control.ply or sequence.json (a fit-batch "
                                                       "OUTDIR: export each OUTDIR/<name>)"),
    "no metrics.csv": (only("sequence.json"), "export OUT: expected a fit-sequence directory with its metrics.csv "
                                              "(the finished frames), got no '{t}/r/metrics.csv'"),
    "no finished frame": (only("sequence.json", "metrics.csv"),
                          "export OUT: expected a fit-sequence directory with at least one finished frame (a row of "
                          "metrics.csv), got none in '{t}/r/metrics.csv'"),
    "a frame's control mesh missing": (without_frame, "export OUT: expected the control mesh of every finished "
                                                      "frame, got no '{t}/r/control/0001.ply'"),
    "frames of other faces": (other_faces, "export OUT: expected one connectivity in every frame of "
                                           "'{t}/r/control', got other faces in '0001.ply'"),
    "control.ply not a PLY": (not_a_ply, r"read_mesh(): expected a PLY file (a header from 'ply' to 'end_header') "
                                         "in '{t}/r/control.ply', got "),
    "-o of another suffix": (with_output(["-o", "x.obj"]),
                             "export -o: expected a .glb file (--format glb), got 'x.obj'"),
    "-o a directory": (with_output(["-o", "{t}/dir.glb"]), "export -o: expected a .glb file (--format glb), got "
                                                            "'{t}/dir.glb': a directory"),
    "-o a file for frames": (with_output(["--format", "ply", "-o", "{t}/frames.ply"], "sequence"),
                             "export -o: expected a directory for the frames of a sequence (one NNNN.ply per "
                             "frame), got '{t}/frames.ply'"),
    "-o an existing file for frames": (with_output(["--format", "obj", "-o", "{t}/taken"], "sequence"),
                                       "export -o: expected a directory for the frames of a sequence (one NNNN.obj "
                                       "per frame), got '{t}/taken': a file"),
    "-o under a file": (with_output(["-o", "{t}/taken.ply/x.glb"]),
                        "ensure_writable_dir(): expected a directory that files can be created in, got "
                        "'{t}/taken.ply': "),
    "--fps for a fit": (with_output(["--fps", "30"]), "export --fps: expected a fit-sequence result exported as glb "
                                                      "(the frame rate of its animation), got --fps 30 for a fit "
                                                      "result"),
    "--fps with obj": (with_output(["--fps", "30", "--format", "obj"], "sequence"),
                       "export --fps: expected a fit-sequence result exported as glb (the frame rate of its "
                       "animation), got --fps 30 for --format obj"),
    "--fps 0": (with_output(["--fps", "0"], "sequence"), "export --fps: expected a finite number > 0, got 0.0"),
    "--fps nan": (with_output(["--fps", "nan"], "sequence"), "export --fps: expected a finite number > 0, got nan"),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_export_refuses(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    build, message = REFUSED[case]
    args = [a.format(t=tmp_path) for a in build(tmp_path)]
    made = sorted(tmp_path.rglob("*"))
    line = one_line_error(capsys, ["export", *args])
    assert line.startswith("mi-loop: error: " + message.format(t=tmp_path)), line
    assert sorted(tmp_path.rglob("*")) == made                              # nothing written, nothing created


@pytest.mark.parametrize("argv, message", [
    (["--format", "stl"], "argument --format: invalid choice: 'stl' (choose from 'glb', 'obj', 'ply')"),
    (["--level", "7"], "argument --level: expected a level in 0..6, got 7"),
    (["--level", "two"], "argument --level: invalid level value: 'two'"),
])
def test_bad_usage_is_exit_2(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["export", str(tmp_path), *argv])
    assert info.value.code == 2
    assert capsys.readouterr().err == f"mi-loop export: error: {message}\n"
    assert list(tmp_path.iterdir()) == []


# -- --view-level on every fitting command ----------------------------------------------


@pytest.mark.parametrize("argv, default", [
    (["fit", "--demo", "-o", "x"], 2), (["fit-images", "t.json", "-o", "x"], 2),
    (["fit-sequence", "f.npz", "-o", "x"], 1), (["fit-batch", "a.xyz", "-o", "x"], 2),
    (["fit-batch", "--sequences", "s.npz", "-o", "x"], 1),
])
def test_every_fitting_command_takes_a_view_level(argv, default, capsys):
    parser = build_parser()
    assert parser.parse_args(argv).view_level == default
    assert parser.parse_args([*argv, "--view-level", "4"]).view_level == 4
    with pytest.raises(SystemExit) as info:
        parser.parse_args([*argv, "--view-level", "7"])
    assert info.value.code == 2
    assert capsys.readouterr().err.endswith("error: argument --view-level: expected a level in 0..6, got 7\n")


@pytest.mark.parametrize("extra, settings", [
    ([], {"view_level": 2}), (["--view-level", "0"], {"view_level": 0}), (["--sequences"], {"view_level": 1}),
    (["--sequences", "--view-level", "3"], {"view_level": 3}),
])
def test_fit_batch_hands_the_view_level_to_every_job(extra, settings, tmp_path, capsys, monkeypatch):
    tasks = []
    client = SimpleNamespace(register_plugin=lambda plugin: None)
    monkeypatch.setattr(cluster_module, "connect", lambda *args: contextlib.nullcontext(client))
    monkeypatch.setattr(batch_job, "_collect", lambda client, todo, *args: tasks.extend(todo))
    write_xyz(tmp_path / "a.xyz", *torus_cloud(200))
    np.savez(tmp_path / "s.npz", vertices=np.zeros((1, 4, 3)), faces=np.zeros((1, 3), dtype=int))
    inputs = [str(tmp_path / ("s.npz" if "--sequences" in extra else "a.xyz"))]
    assert main(["fit-batch", *inputs, "-o", str(tmp_path / "out"), *extra, "--quiet"]) == 0
    task, = tasks
    assert {k: v for k, v in task.settings.items() if k == "view_level"} == settings
    assert re.fullmatch(r".*/out/(a|s)", str(task.output))
