"""The ``mi-loop fit-sequence`` job (mi_loop.app.sequence_job): outputs, resume, Ctrl-C, bad input, reports.

Runs are tiny on purpose (a 3-frame icosphere(2) sequence, an icosphere(1)
template with 42 vertices, :data:`FAST` options). fit_frame itself is tested in
tests/fitting/test_sequence.py.
"""
from __future__ import annotations

import csv
import json
import re
import shutil

import mitsuba as mi
import numpy as np
import pytest

import mi_loop.fitting.sequence
import mi_loop.io.files
from mi_loop import datasets, io
from mi_loop.app.cli import main
from mi_loop.fitting.options import SequenceOptions

from helpers import REPO, interrupt_at_frame, one_line_error, parse_glb, slot_template_runs, sphere_mesh

#: Options of a quick run: 4 views of 24x24 pixels, 2 spp, 20 iterations per frame (30 for the first),
#: an image refresh every 10, 2000 points.
FAST = ["--views", "4", "--res", "24", "--spp", "2", "--iterations", "20", "--first-iterations", "30",
        "--image-every", "10", "--points", "2000"]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A 3-frame NPZ of a growing, moving, rough icosphere(2) and an icosphere(1) template file.

    Rough (radial noise of 3 %): with ``--seen 1`` the renders of the frames count (a clean mesh
    frame's renders are skipped: see mi_loop.fitting.sequence.MIN_IMAGE_WEIGHT).
    """
    root = tmp_path_factory.mktemp("inputs")
    V, F = datasets.icosphere(2)
    V = V * (1 + 0.03 * np.random.default_rng(0).standard_normal((len(V), 1)))
    frames = np.stack([V * (1 + 0.1 * t) + [0.05 * t, 0.0, 0.0] for t in range(3)])
    np.savez(root / "seq.npz", vertices=frames, faces=F)
    Vc, Fc = datasets.icosphere(1)
    io.write_ply(root / "control.ply", Vc, Fc)
    return root / "seq.npz", root / "control.ply"


def argv(inputs, out, *extra):
    """``fit-sequence`` command line for the ``inputs`` fixture, written to ``out``, with :data:`FAST`."""
    npz, template = inputs
    return ["fit-sequence", str(npz), "-o", str(out), "--template", str(template), *FAST, *extra]


def run_ok(args):
    """Run ``mi-loop`` in-process and check that it exits 0."""
    code = main(args)
    assert code == 0
    return code


@pytest.fixture(scope="module")
def image_run(inputs, tmp_path_factory):
    """Output directory of one run with the image term (``--seen 1``: the rough frames' renders count),
    its sequence.glb at the level of limit/ (2) and 12.5 fps."""
    out = tmp_path_factory.mktemp("image_run") / "out"
    run_ok(argv(inputs, out, "--seen", "1", "--view-level", "2", "--fps", "12.5"))
    return out


@pytest.fixture(scope="module")
def geometric_run(inputs, tmp_path_factory):
    """Output directory of one run without the image term (the reference of the resume tests)."""
    out = tmp_path_factory.mktemp("geometric_run") / "out"
    run_ok(argv(inputs, out, "--no-image"))
    return out


def read_rows(out):
    """Rows of ``out/metrics.csv`` as dicts."""
    with open(out / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def no_temporary_files(out):
    """True when ``out`` holds no hidden staging file and no ``.tmp`` file."""
    return [p for p in out.rglob("*") if p.name.startswith(".") or p.suffix == ".tmp"] == []


def test_fit_sequence_writes_every_frame_with_the_templates_faces(inputs, image_run):
    _, template = inputs
    _, F_template = io.read_mesh(template)
    V_frames = np.load(inputs[0])["vertices"]
    for t in range(3):
        V, F = io.read_mesh(image_run / "control" / f"{t:04d}.ply")
        np.testing.assert_array_equal(F, F_template)
        assert V.shape == (42, 3) and np.isfinite(V).all()
        V_lim, F_lim = io.read_mesh(image_run / "limit" / f"{t:04d}.ply")
        assert len(F_lim) == 16 * len(F_template)                     # level-2 tessellation
        centre = V_frames[t].mean(0)                                     # follows the motion
        radius = np.linalg.norm(V_frames[t] - centre, axis=1).mean()
        r_fit = np.linalg.norm(V_lim - centre, axis=1)
        np.testing.assert_allclose(r_fit.mean(), radius, rtol=0.03)
    rows = read_rows(image_run)
    assert [int(r["frame"]) for r in rows] == [0, 1, 2]
    assert [r["name"] for r in rows] == ["seq[0]", "seq[1]", "seq[2]"]
    for r in rows:
        values = [float(r[k]) for k in ("mean", "rms", "hausdorff", "seconds", "time_render")]
        assert np.isfinite(values).all() and min(values) >= 0
        assert float(r["mean"]) <= float(r["rms"]) <= float(r["hausdorff"]) < 0.05
        assert float(r["time_render"]) > 0
        assert 0 <= float(r["flipped_pct"]) <= 100
        # an NPZ is in correspondence; a sphere holds nothing in place tangentially: bounded, not small
        assert 0 <= float(r["drift_mean"]) <= float(r["drift_p95"]) < 0.1
    assert [int(r["iterations"]) for r in rows] == [30, 20, 20]                 # --first-iterations, --iterations
    for name in ("drift.png", "strip.png"):
        assert (image_run / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert no_temporary_files(image_run)
    assert not (image_run / "limit" / "0003.ply").exists()
    # sequence.glb at --view-level 2: frame k (base + target k) is limit/000k.ply, shown from k / 12.5 s
    doc, read = parse_glb(image_run / "sequence.glb")
    prim, = doc["meshes"][0]["primitives"]
    base = read(prim["attributes"]["POSITION"])
    assert len(prim["targets"]) == 3 and doc["meshes"][0]["extras"]["targetNames"] == [r["name"] for r in rows]
    for t, target in enumerate(prim["targets"]):
        V_lim, F_lim = io.read_mesh(image_run / "limit" / f"{t:04d}.ply")
        assert len(base) == len(V_lim)
        np.testing.assert_allclose(base + read(target["POSITION"]), V_lim, rtol=0, atol=2e-6)
    np.testing.assert_array_equal(read(prim["indices"]).reshape(-1, 3), F_lim)
    sampler, = doc["animations"][0]["samplers"]
    np.testing.assert_array_equal(read(sampler["input"]).ravel(), (np.arange(3) / 12.5).astype(np.float32))
    assert json.loads((image_run / "sequence.json").read_text())["fps"] == 12.5


def test_resume_without_images_equals_the_uninterrupted_run(inputs, geometric_run, tmp_path,
                                                            monkeypatch, capsys):
    """IMLS + ARAP only: the resumed run reproduces the uninterrupted one bit for bit. Frame 2
    starts from state/0001.npz (the exact float64 control points in the unit box), with the
    normalisation, step size and options of sequence.json; the fitting loops are deterministic."""
    out = tmp_path / "out"
    interrupt_at_frame(monkeypatch, 2)
    assert main(argv(inputs, out, "--no-image")) == 130
    assert capsys.readouterr().err.splitlines()[-1] == "mi-loop: error: interrupted"
    assert len(read_rows(out)) == 2 and not (out / "control" / "0002.ply").exists()
    monkeypatch.undo()
    run_ok(argv(inputs, out, "--no-image", "--resume", "--alpha", "0.02"))   # kept from sequence.json
    err = capsys.readouterr().err
    assert "resuming after frame 1 (2 frames done)" in err
    assert "mi-loop: warning: --resume keeps the options of sequence.json: alpha 0.01 (this command line: 0.02)" in err
    assert [int(r["frame"]) for r in read_rows(out)] == [0, 1, 2]
    for t in range(3):
        V, F = io.read_mesh(out / "control" / f"{t:04d}.ply")
        V_ref, F_ref = io.read_mesh(geometric_run / "control" / f"{t:04d}.ply")
        np.testing.assert_array_equal(F, F_ref)
        np.testing.assert_array_equal(V, V_ref)
        with np.load(out / "state" / f"{t:04d}.npz") as a, np.load(geometric_run / "state" / f"{t:04d}.npz") as b:
            np.testing.assert_array_equal(a["x"], b["x"])
    assert (out / "sequence.glb").read_bytes() == (geometric_run / "sequence.glb").read_bytes()


def spy_on_camera_boxes(monkeypatch, boxes):
    """Record the camera box of every camera rig the job builds."""
    class Spy(mi_loop.fitting.sequence.Rig):
        def __init__(self, options, box):
            boxes.append(np.array(box, dtype=np.float64))
            super().__init__(options, box)
    monkeypatch.setattr(mi_loop.fitting.sequence, "Rig", Spy)


@pytest.mark.slow
def test_resume_with_images_matches_the_uninterrupted_run(inputs, tmp_path, monkeypatch):
    """The cameras are fixed for the whole sequence, so a resumed run must use the same ones, and
    with --deterministic (the reverse render on one thread) the resumed frames equal the
    uninterrupted run's bit for bit."""
    reference, out, boxes = tmp_path / "reference", tmp_path / "out", []
    run_ok(argv(inputs, reference, "--deterministic"))
    interrupt_at_frame(monkeypatch, 2)
    spy_on_camera_boxes(monkeypatch, boxes)
    assert main(argv(inputs, out, "--deterministic")) == 130
    monkeypatch.undo()
    spy_on_camera_boxes(monkeypatch, boxes)
    run_ok(argv(inputs, out, "--resume"))                 # --deterministic comes from sequence.json
    assert len(boxes) == 2
    np.testing.assert_array_equal(boxes[1], boxes[0])     # same cameras
    for t in range(3):
        V, _ = io.read_mesh(out / "control" / f"{t:04d}.ply")
        V_ref, _ = io.read_mesh(reference / "control" / f"{t:04d}.ply")
        np.testing.assert_array_equal(V, V_ref, err_msg=f"frame {t}")


def test_ctrl_c_while_writing_a_frame_leaves_only_complete_files(inputs, geometric_run, tmp_path,
                                                                 monkeypatch, capsys):
    """Ctrl-C in the middle of writing control/0001.ply: no partial or temporary file remains,
    the CSV lists exactly the frames whose control mesh is on disk, and --resume completes."""
    out = tmp_path / "out"
    real_fdopen = mi_loop.io.files.os.fdopen

    class Interrupted:                     # writes the first chunk (the header), then Ctrl-C
        def __init__(self, f):
            self.f, self.writes = f, 0

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            self.writes += 1
            if self.writes == 2:
                raise KeyboardInterrupt
            return self.f.write(data)

    paths = {}
    real_mkstemp = mi_loop.io.files.tempfile.mkstemp

    def mkstemp(*args, **kwargs):          # remember the name of every temporary file
        fd, name = real_mkstemp(*args, **kwargs)
        paths[fd] = name
        return fd, name
    monkeypatch.setattr(mi_loop.io.files.tempfile, "mkstemp", mkstemp)

    def fdopen_by_name(fd, *args, **kwargs):
        f = real_fdopen(fd, *args, **kwargs)
        return Interrupted(f) if "0001.ply" in paths.get(fd, "") and "/control/" in paths[fd] else f
    monkeypatch.setattr(mi_loop.io.files.os, "fdopen", fdopen_by_name)

    assert main(argv(inputs, out, "--no-image")) == 130
    assert capsys.readouterr().err.splitlines()[-1] == "mi-loop: error: interrupted"
    monkeypatch.undo()
    assert any("control" in p and "0001.ply" in p for p in paths.values())   # it was interrupted there
    assert no_temporary_files(out)
    assert sorted(p.name for p in (out / "control").iterdir()) == ["0000.ply"]
    assert sorted(p.name for p in (out / "state").iterdir()) == ["0000.npz"]
    V, _F = io.read_mesh(out / "control" / "0000.ply")
    assert V.shape == (42, 3)
    assert [int(r["frame"]) for r in read_rows(out)] == [0]
    for p in (out / "limit").iterdir():                  # whatever is there is complete
        io.read_mesh(p)
    run_ok(argv(inputs, out, "--no-image", "--resume"))
    V, _ = io.read_mesh(out / "control" / "0002.ply")
    V_ref, _ = io.read_mesh(geometric_run / "control" / "0002.ply")
    np.testing.assert_array_equal(V, V_ref)                             # as in the resume test


def test_sequence_glb_plays_every_frame_and_export_writes_the_same_file(geometric_run, tmp_path, capsys):
    """The default view level (1) and rate (24 fps); mi_loop's glTF baker plays it back as the limit
    surfaces of control/; ``mi-loop export`` of the directory gives the same bytes."""
    from mi_loop.io.animation import bake_animation
    from mi_loop.subdiv.masks import limit_mesh

    doc, read = parse_glb(geometric_run / "sequence.glb")
    prim, = doc["meshes"][0]["primitives"]
    assert doc["accessors"][prim["attributes"]["POSITION"]]["count"] == 42 + 120   # icosphere(1) at level 1
    assert len(prim["targets"]) == 3
    baked = bake_animation(geometric_run / "sequence.glb", "sequence", fps=24.0)
    np.testing.assert_allclose(baked.times, np.arange(3) / 24.0)
    for t in range(3):
        P, F_t, _ = limit_mesh(*io.read_mesh(geometric_run / "control" / f"{t:04d}.ply"), 1)
        np.testing.assert_allclose(baked.vertices[t], P, rtol=0, atol=2e-6)
    np.testing.assert_array_equal(baked.faces, F_t)
    out = tmp_path / "copy"
    shutil.copytree(geometric_run, out)
    assert main(["export", str(out), "-o", str(tmp_path / "again.glb"), "--quiet"]) == 0
    assert capsys.readouterr().out.split() == [str(tmp_path / "again.glb")]
    assert (tmp_path / "again.glb").read_bytes() == (geometric_run / "sequence.glb").read_bytes()


def test_a_failure_while_writing_sequence_glb_leaves_no_part_of_it(inputs, geometric_run, tmp_path, capsys,
                                                                  monkeypatch):
    """The disk fills up in the middle of sequence.glb: no sequence.glb, no temporary file, every frame
    kept; --resume (nothing left to fit) writes it whole."""
    import contextlib

    import mi_loop.io.glb

    real_open = mi_loop.io.glb.atomic_open

    class Full:
        def __init__(self, f):
            self.f, self.writes = f, 0

        def write(self, data):
            self.writes += 1
            if self.writes == 2:                          # after the header: a half-written file
                raise OSError(28, "No space left on device")
            return self.f.write(data)

    @contextlib.contextmanager
    def full_disk(path):
        with real_open(path) as f:
            yield Full(f)

    out = tmp_path / "out"
    shutil.copytree(geometric_run, out)
    (out / "sequence.glb").unlink()
    monkeypatch.setattr(mi_loop.io.glb, "atomic_open", full_disk)
    line = one_line_error(capsys, argv(inputs, out, "--no-image", "--resume"))
    assert line == "mi-loop: error: [Errno 28] No space left on device"
    monkeypatch.undo()
    assert not (out / "sequence.glb").exists() and no_temporary_files(out)
    assert [int(r["frame"]) for r in read_rows(out)] == [0, 1, 2]
    run_ok(argv(inputs, out, "--no-image", "--resume"))
    assert (out / "sequence.glb").read_bytes() == (geometric_run / "sequence.glb").read_bytes()


# -- bad input ---------------------------------------------------------------------


def test_an_unreadable_frame_stops_the_run_and_keeps_the_finished_frames(inputs, tmp_path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    for t in range(2):
        io.write_ply(frames / f"{t:04d}.ply", *sphere_mesh(1.0 + 0.1 * t))
    (frames / "0002.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\ngarbage\n")
    out = tmp_path / "out"
    line = one_line_error(capsys, ["fit-sequence", str(frames), "-o", str(out), "--template",
                                   str(inputs[1]), "--no-image", "--iterations", "5",
                                   "--points", "1000"])
    assert "0002.ply" in line
    assert [int(r["frame"]) for r in read_rows(out)] == [0, 1]
    for t in range(2):
        V, _F = io.read_mesh(out / "control" / f"{t:04d}.ply")
        assert V.shape == (42, 3)
    assert no_temporary_files(out)


def test_a_frame_with_nan_coordinates_is_rejected(tmp_path, capsys):
    V, F = datasets.icosphere(2)
    frames = np.stack([V, V])
    frames[0, 7, 1] = np.nan
    np.savez(tmp_path / "seq.npz", vertices=frames, faces=F)
    line = one_line_error(capsys, ["fit-sequence", str(tmp_path / "seq.npz"), "-o",
                                   str(tmp_path / "out"), "--vertices", "42"])
    assert re.fullmatch(r"mi-loop: error: fit-sequence FRAMES: expected finite coordinates in frame seq\[0\], got "
                        r"vertex 7 = \[.*, nan, .*\]", line), line
    assert not (tmp_path / "out").exists()


def test_an_empty_directory_is_an_empty_sequence(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    line = one_line_error(capsys, ["fit-sequence", str(tmp_path / "empty"), "-o", str(tmp_path / "out")])
    assert line == ("mi-loop: error: read_frames(): expected at least one frame file, got none in "
                    f"['{tmp_path / 'empty'}']")


def test_a_missing_frame_path_is_named(tmp_path, capsys):
    missing = tmp_path / "nope.npz"
    line = one_line_error(capsys, ["fit-sequence", str(missing), "-o", str(tmp_path / "out")])
    assert line == ("mi-loop: error: read_frames(): expected an existing file, directory or glob pattern, "
                    f"got '{missing}': no such file or directory")


def test_a_non_manifold_template_is_rejected(inputs, tmp_path, capsys):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    F = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])                  # edge 0-1 shared by 3 faces
    io.write_ply(tmp_path / "bad.ply", V, F)
    line = one_line_error(capsys, ["fit-sequence", str(inputs[0]), "-o", str(tmp_path / "out"),
                                   "--template", str(tmp_path / "bad.ply"), *FAST])
    assert line.startswith(f"mi-loop: error: fit-sequence --template '{tmp_path / 'bad.ply'}': ")
    assert "edge" in line and "0" in line and "1" in line


def test_an_output_directory_under_a_regular_file_is_rejected(inputs, tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    line = one_line_error(capsys, ["fit-sequence", str(inputs[0]), "-o", str(tmp_path / "file" / "out")])
    assert line == ("mi-loop: error: ensure_writable_dir(): expected a directory that files can be created in, "
                    f"got '{tmp_path / 'file' / 'out'}': Not a directory")


def test_fewer_than_four_template_vertices_are_rejected(inputs, tmp_path, capsys):
    line = one_line_error(capsys, ["fit-sequence", str(inputs[0]), "-o", str(tmp_path / "out"),
                                   "--vertices", "3"])
    assert line == "mi-loop: error: fit-sequence --vertices: expected an integer >= 4, got 3"
    assert not (tmp_path / "out").exists()


def test_a_quoted_glob_selects_frames_in_name_order(tmp_path, capsys):
    for t in (2, 0, 1, 3):
        io.write_ply(tmp_path / f"f_{t:02d}.ply", *sphere_mesh(1.0 + 0.1 * t))
    (tmp_path / "f_notes.txt").write_text("not a frame\n")
    frames = io.read_frames([str(tmp_path / "f_0[0-2].ply")])
    assert [frame().name for frame in frames] == ["f_00.ply", "f_01.ply", "f_02.ply"]
    line = one_line_error(capsys, ["fit-sequence", str(tmp_path / "g_*.ply"), "-o", str(tmp_path / "out")])
    assert line == ("mi-loop: error: read_frames(): expected frame files matching the pattern, got none for "
                    f"'{tmp_path / 'g_*.ply'}'")


def test_the_automatic_template_of_mesh_frames_comes_from_the_first_mesh(tmp_path, capsys):
    V, F = datasets.icosphere(3)
    np.savez(tmp_path / "seq.npz", vertices=np.stack([V, 1.1 * V]), faces=F)
    out = tmp_path / "out"
    run_ok(["fit-sequence", str(tmp_path / "seq.npz"), "-o", str(out), "--vertices", "120",
            "--no-image", "--iterations", "30", "--points", "3000"])
    assert "template: first frame's mesh decimated to" in capsys.readouterr().err
    Vc, _Fc = io.read_mesh(out / "control" / "0000.ply")
    assert abs(len(Vc) - 120) <= 6
    rows = read_rows(out)
    assert max(float(r["mean"]) for r in rows) < 2e-3


def test_a_non_manifold_first_frame_falls_back_to_poisson(tmp_path, capsys):
    V, F = datasets.icosphere(3)
    F_bad = np.vstack([F, F[:1]])                        # one face twice
    np.savez(tmp_path / "seq.npz", vertices=V[None], faces=F_bad)
    run_ok(["fit-sequence", str(tmp_path / "seq.npz"), "-o", str(tmp_path / "out"), "--vertices", "120",
            "--no-image", "--iterations", "5", "--points", "3000"])
    err = capsys.readouterr().err
    assert "template: first frame's mesh cannot be used (mesh_template(): expected a manifold mesh" in err
    assert "template: screened Poisson + decimation to 120 vertices" in err


@pytest.mark.parametrize("flag", [["--poisson-template"], ["--template-depth", "8"], ["--template-genus", "0"]])
def test_poisson_template_and_template_exclude_each_other(inputs, tmp_path, capsys, flag):
    line = one_line_error(capsys, ["fit-sequence", str(inputs[0]), "-o", str(tmp_path / "out"),
                                   "--template", str(inputs[1]), *flag])
    assert line == (f"mi-loop: error: fit-sequence {flag[0]}: expected no --template (it builds the "
                    f"template), got --template '{inputs[1]}'")


def test_template_depth_opens_a_narrow_slot_that_the_default_depth_webs_and_template_genus_cuts_it(tmp_path, capsys):
    def run(data, out, flags):
        run_ok(["fit-sequence", str(data), "-o", str(out), "--vertices", "300", "--no-image",
                "--first-iterations", "5", *flags])

    found = slot_template_runs(tmp_path, capsys, run, "control/0000.ply")
    assert {name: g for name, (g, _) in found.items()} == {"default": 1, "depth 8": 0, "genus 0": 0}
    for name, (_, err) in found.items():
        assert f"template: screened Poisson{' at depth 8' if name == 'depth 8' else ''} + decimation" in err
    cut = {name: "template: 1 handle cut to genus 0 (loops" in err for name, (_, err) in found.items()}
    assert cut == {"default": False, "depth 8": False, "genus 0": True}


@pytest.mark.parametrize("flag, value, message", [
    ("--alpha", "-1", "expected a finite number >= 0, got -1.0"),
    ("--beta", "nan", "expected a finite number >= 0, got nan"),
    ("--cover", "-0.5", "expected a finite number >= 0 (or None: 3 on mesh frames and with --images, 0.3 on point "
                        "clouds without), got -0.5"),
    ("--views", "0", "expected an integer >= 1, got 0"),
    ("--res", "0", "expected an integer >= 1, got 0"),
    ("--spp", "-2", "expected an integer >= 1, got -2"),
    ("--iterations", "0", "expected an integer >= 1, got 0"),
    ("--image-every", "0", "expected an integer >= 1, got 0"),
    ("--points", "0", "expected an integer >= 1, got 0"),
    ("--seed", "-3", "expected an integer >= 0, got -3"),
    ("--views-per-iteration", "5", "expected an integer in [1, views=4], got 5"),    # FAST has --views 4
    ("--gn-iterations", "0", "expected an integer >= 1, got 0"),
])
def test_bad_options_are_rejected_before_the_frames_are_read(tmp_path, capsys, flag, value, message):
    """The frames do not exist: an error about the option proves it came first; nothing is written."""
    out = tmp_path / "out"
    line = one_line_error(capsys, ["fit-sequence", str(tmp_path / "nonexistent.npz"), "-o", str(out),
                                   *FAST, flag, value])
    assert line == f"mi-loop: error: fit-sequence {flag}: {message}"
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_solver_is_refused_with_the_choices(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["fit-sequence", str(tmp_path / "x.npz"), "-o", str(tmp_path / "out"), "--solver", "lbfgs"])
    assert ("mi-loop fit-sequence: error: argument --solver: invalid choice: 'lbfgs' (choose from 'gauss-newton', "
            "'adam')") in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def point_frames(tmp_path, n=2):
    """``n`` XYZ frames (points and normals) of a growing unit sphere."""
    frames = tmp_path / "points"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for t in range(n):
        N = rng.normal(size=(4000, 3))
        N /= np.linalg.norm(N, axis=1, keepdims=True)
        np.savetxt(frames / f"{t:04d}.xyz", np.hstack([(1.0 + 0.05 * t) * N, N]))
    return frames


def test_point_cloud_frames_are_fitted_without_the_image_term(inputs, tmp_path, capsys):
    out = tmp_path / "out"
    run_ok(["fit-sequence", str(point_frames(tmp_path)), "-o", str(out), "--template", str(inputs[1]),
            "--iterations", "60", "--points", "2000"])
    err = capsys.readouterr().err
    assert "point-cloud frames without --images: no surface to render, so the image term is off" in err
    assert ("terms: IMLS + coverage (3 x on mesh frames, 0.3 x on point clouds) + ARAP + 0.01 x ARAP to the template + "
            "fold barrier (0.01 x on mesh frames, 1 x on point clouds)\n") in err       # the defaults by kind
    rows = read_rows(out)
    assert [int(r["frame"]) for r in rows] == [0, 1]
    assert all(float(r["time_render"]) == 0 for r in rows)
    for t, r in enumerate(rows):                  # the limit surface follows the growing sphere
        V_lim, _ = io.read_mesh(out / "limit" / f"{t:04d}.ply")
        np.testing.assert_allclose(np.linalg.norm(V_lim, axis=1).mean(), 1.0 + 0.05 * t, rtol=0.02)
        assert float(r["mean"]) < 0.01


def test_the_log_names_the_weights_given(inputs, tmp_path, capsys):
    run_ok(["fit-sequence", str(point_frames(tmp_path)), "-o", str(tmp_path / "out"), "--template", str(inputs[1]),
            "--frames", "0:1", "--first-iterations", "2", "--cover", "2", "--fold", "0", "--alpha-rest", "0"])
    assert "terms: IMLS + 2 x coverage + ARAP\n" in capsys.readouterr().err


def test_sequence_json_records_the_options_the_run_used(inputs, tmp_path, capsys, monkeypatch):
    """Point-cloud frames without --images: the image term is off, decided before sequence.json records the
    options; every frame is fitted with exactly the recorded options, the caller's are left as given, and a
    --resume of the run (nothing left to fit) finds no difference to warn about."""
    from dataclasses import asdict

    from mi_loop.app import sequence_job
    from mi_loop.app.progress import Reporter

    used = []
    real = mi_loop.fitting.sequence.fit_frame

    def spy(*args, **kwargs):
        used.append(asdict(args[6]))                  # fit_frame(x0, F, points, normals, op, image, options, ...)
        return real(*args, **kwargs)
    monkeypatch.setattr(mi_loop.fitting.sequence, "fit_frame", spy)
    given = SequenceOptions(iterations=5, first_iterations=5, n_points=1000)
    out, frames = tmp_path / "out", point_frames(tmp_path)
    sequence_job.run([frames], out, given, template=inputs[1], log=Reporter(quiet=True))
    recorded = json.loads((out / "sequence.json").read_text())["options"]
    assert recorded["image"] is False and given.image is True          # the caller's options are not changed
    assert used == [recorded, recorded]                                # what both frames ran with
    assert recorded == asdict(SequenceOptions(iterations=5, first_iterations=5, n_points=1000, image=False))
    capsys.readouterr()
    sequence_job.run([frames], out, given, template=inputs[1], resume=True, log=Reporter())
    err = capsys.readouterr().err
    assert "resuming after frame 1 (2 frames done)" in err and "warning" not in err
    assert len(used) == 2                                              # nothing left to fit


def test_image_only_needs_mesh_frames(inputs, tmp_path, capsys):
    line = one_line_error(capsys, ["fit-sequence", str(point_frames(tmp_path, 1)), "-o", str(tmp_path / "out"),
                                   "--template", str(inputs[1]), "--image-only"])
    assert line == ("mi-loop: error: fit-sequence --image-only: expected mesh frames (a surface to render) or "
                    "--images, got point-cloud frames")
    assert not (tmp_path / "out").exists()                       # nothing left behind


def test_a_run_stopped_before_its_first_frame_leaves_an_existing_directory_as_it_was(
        inputs, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    interrupt_at_frame(monkeypatch, 0)
    assert main(argv(inputs, out, "--no-image")) == 130
    assert capsys.readouterr().err.splitlines()[-1] == "mi-loop: error: interrupted"
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


# -- what fit-sequence prints and records ----------------------------------------------


def test_fit_sequence_prints_every_written_path_and_records_its_options(inputs, tmp_path, capsys, jit_variant):
    from dataclasses import asdict

    import mi_loop.app.sequence_job
    from mi_loop.io.runs import RunRecord

    out = tmp_path / "out"
    run_ok(argv(inputs, out, "--no-image", "--deterministic", "--quiet"))
    captured = capsys.readouterr()
    assert captured.err == ""                                          # --quiet: no progress at all
    expected = []
    for t in range(3):
        expected += [out / "control" / f"{t:04d}.ply", out / "limit" / f"{t:04d}.ply", out / "state" / f"{t:04d}.npz"]
        if t == 0:
            expected += [out / "sequence.json", out / "metrics.csv"]
    expected += [out / "drift.png", out / "strip.png", out / "sequence.glb", out / "report.html"]
    assert captured.out.splitlines() == [str(p) for p in expected]
    written = sorted(p for p in out.rglob("*") if p.is_file())
    assert written == sorted(expected)                                 # and nothing else was written

    state = json.loads((out / "sequence.json").read_text())
    assert state["options"] == asdict(SequenceOptions(views=4, resolution=24, spp=2, iterations=20,
                                                      first_iterations=30, image_every=10, n_points=2000,
                                                      views_per_iteration=2,
                                                      image=False, deterministic=True))
    assert state["template"]["source"] == "file" and state["template"]["n_vertices"] == 42
    assert state["normals_estimated"] is False and state["variant"] == jit_variant and state["n_frames"] == 3
    readme = (REPO / "README.md").read_text()
    assert list(state) == list(RunRecord.__dataclass_fields__)        # one writer: RunRecord's keys, in order
    for key in state:                                                  # every key is documented
        assert f"{key} :" in RunRecord.__doc__, key
        assert f"`{key}`" in readme, key
    assert "mi_loop.io.runs.RunRecord" in mi_loop.app.sequence_job.__doc__


def test_fit_sequence_draws_a_progress_bar_on_a_terminal(inputs, tmp_path, monkeypatch):
    import io as stdio
    import sys

    class Terminal(stdio.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    run_ok(argv(inputs, tmp_path / "out", "--no-image"))
    text = terminal.getvalue()
    assert "fit-sequence:" in text and "frame 3/3" in text and "/70 [" in text   # 30 + 20 + 20 iterations
    assert "[mi-loop" in text


def test_a_diverging_frame_is_a_fit_error_naming_frame_and_iteration(inputs, tmp_path, capsys, monkeypatch):
    """A NaN in frame 1's energy: one line naming the frame and iteration; frame 0 stays written."""
    from mi_loop.energies.imls import IMLS
    from mi_loop.errors import FitError

    real_fit, real_energy = mi_loop.fitting.sequence.fit_frame, IMLS.energy
    frame = []

    def fit_frame(*args, **kwargs):
        frame.append(args[7])
        return real_fit(*args, **kwargs)

    def energy(self, Q, reduce="sum"):
        E = real_energy(self, Q, reduce)
        return E + mi.Float(float("nan")) if frame[-1] == 1 else E

    monkeypatch.setattr(mi_loop.fitting.sequence, "fit_frame", fit_frame)
    monkeypatch.setattr(IMLS, "energy", energy)
    out = tmp_path / "out"
    line = one_line_error(capsys, argv(inputs, out, "--no-image"))
    assert re.fullmatch(r"mi-loop: error: fit_frame\(\): expected a finite energy, got imls nan "
                        r"at frame 1, iteration \d+ \(the optimisation diverged\)", line), line
    assert [int(r["frame"]) for r in read_rows(out)] == [0]
    frame.clear()
    assert main(argv(inputs, tmp_path / "again", "--no-image", "--debug")) == 1
    err = capsys.readouterr().err                                      # the one exception type of a failed fit
    assert f"{FitError.__module__}.FitError: fit_frame(): expected a finite energy" in err


def write_point_frames(root, n=3, points=3000):
    """``n`` PLY frames of points only (no normals, no faces) on a growing unit sphere."""
    frames = root / "bare"
    frames.mkdir()
    rng = np.random.default_rng(1)
    for t in range(n):
        D = rng.normal(size=(points, 3))
        D /= np.linalg.norm(D, axis=1, keepdims=True)
        io.write_ply(frames / f"{t:04d}.ply", (1.0 + 0.05 * t) * D, np.zeros((0, 3), dtype=np.int64))
    return frames


def test_point_frames_without_normals_get_estimated_normals(inputs, tmp_path, capsys):
    out = tmp_path / "out"
    run_ok(["fit-sequence", str(write_point_frames(tmp_path)), "-o", str(out), "--template", str(inputs[1]),
            "--iterations", "60"])
    err = capsys.readouterr().err
    assert err.count("point-cloud frames without normals: estimating and orienting normals in every frame") == 1
    rows = read_rows(out)
    assert [int(r["frame"]) for r in rows] == [0, 1, 2]
    for t, r in enumerate(rows):                  # outward normals: the surface grows with the sphere
        V_lim, _ = io.read_mesh(out / "limit" / f"{t:04d}.ply")
        np.testing.assert_allclose(np.linalg.norm(V_lim, axis=1).mean(), 1.0 + 0.05 * t, rtol=0.02)
        assert float(r["mean"]) < 0.01
    assert json.loads((out / "sequence.json").read_text())["normals_estimated"] is True


def test_a_template_in_another_frame_is_refused(inputs, tmp_path, capsys):
    V, F = datasets.icosphere(1)
    io.write_ply(tmp_path / "big.ply", 10.0 * V + 30.0, F)
    out = tmp_path / "out"
    line = one_line_error(capsys, ["fit-sequence", str(inputs[0]), "-o", str(out), "--template",
                                   str(tmp_path / "big.ply"), *FAST])
    assert line.startswith(f"mi-loop: error: fit-sequence --template '{tmp_path / 'big.ply'}': expected a control "
                           "mesh in the data's frame")
    assert line.endswith("scale and translate the template onto the data")
    assert not out.exists()


def test_resume_without_the_exact_state_falls_back_to_the_control_mesh(inputs, geometric_run, tmp_path,
                                                                       monkeypatch, capsys):
    """A run written before state/ existed: resumed from control/NNNN.ply, with a warning, nearly equal."""
    out = tmp_path / "out"
    interrupt_at_frame(monkeypatch, 2)
    assert main(argv(inputs, out, "--no-image")) == 130
    monkeypatch.undo()
    (out / "state" / "0001.npz").unlink()
    capsys.readouterr()
    run_ok(argv(inputs, out, "--no-image", "--resume"))
    assert (f"mi-loop: warning: {out / 'state' / '0001.npz'} is missing (an older run?): resuming from "
            "control/0001.ply, which is not bit-exact") in capsys.readouterr().err
    V, _ = io.read_mesh(out / "control" / "0002.ply")
    V_ref, _ = io.read_mesh(geometric_run / "control" / "0002.ply")
    extent = np.ptp(np.load(inputs[0])["vertices"].reshape(-1, 3), axis=0).max()
    np.testing.assert_allclose(V, V_ref, rtol=0, atol=1e-6 * extent)


def test_a_quad_template_is_split_with_a_warning_and_recorded(inputs, tmp_path, capsys):
    (tmp_path / "cube.obj").write_text("v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\n"
                                       "v 1 1 1\nv -1 1 1\nf 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\n"
                                       "f 3 4 8 7\nf 4 1 5 8\n")          # a cube of six quads
    out = tmp_path / "out"
    run_ok(["fit-sequence", str(inputs[0]), "-o", str(out), "--template", str(tmp_path / "cube.obj"), *FAST,
            "--no-image", "--quiet"])
    assert capsys.readouterr().err.splitlines() == [
        (f"mi-loop: warning: fit-sequence --template '{tmp_path / 'cube.obj'}': 6 faces with more than three "
         "corners were split into triangles (12 triangles); the Loop surface of the triangulated mesh is fitted")]
    template = json.loads((out / "sequence.json").read_text())["template"]
    assert template["split_polygons"] == 6 and template["n_faces"] == 12


def test_resume_without_sequence_json_is_refused(inputs, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    interrupt_at_frame(monkeypatch, 1)
    assert main(argv(inputs, out, "--no-image")) == 130
    monkeypatch.undo()
    (out / "sequence.json").unlink()
    capsys.readouterr()
    line = one_line_error(capsys, argv(inputs, out, "--no-image", "--resume"))
    assert line == ("mi-loop: error: fit-sequence --resume: expected the run's sequence.json next to its "
                    f"metrics.csv, got no '{out / 'sequence.json'}'")
    assert [int(r["frame"]) for r in read_rows(out)] == [0]              # the finished frame is kept


def test_resume_of_an_older_runs_metrics_is_refused_with_the_fix(inputs, tmp_path, capsys):
    """A metrics.csv of the columns before flipped_pct and drift: --resume names the fix; nothing is changed."""
    from mi_loop.io.runs import CSV_HEADER, OLDER_COLUMNS

    out = tmp_path / "out"
    (out / "control").mkdir(parents=True)
    text = ",".join(OLDER_COLUMNS) + "\n0,seq[0],0.001,0.002,0.01,3.5,0.4,30\n"
    (out / "metrics.csv").write_text(text)
    line = one_line_error(capsys, argv(inputs, out, "--no-image", "--resume"))
    assert line == (f"mi-loop: error: fit-sequence --resume: expected a metrics.csv with the columns {CSV_HEADER}, "
                    f"got '{','.join(OLDER_COLUMNS)}' in '{out / 'metrics.csv'}' (a run of an older version: start "
                    "it again without --resume)")
    assert (out / "metrics.csv").read_text() == text
    assert sorted(p.name for p in out.iterdir()) == ["control", "metrics.csv"]


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    """3 frames of 4000 points on an ellipsoid moving by (0.1, 0.05, 0) per frame, in correspondence, as
    ``points (T, N, 3)``; and an icosphere(1) template on the ellipsoid."""
    root = tmp_path_factory.mktemp("clouds")
    rng = np.random.default_rng(0)
    P = rng.normal(size=(4000, 3))
    P /= np.linalg.norm(P, axis=1, keepdims=True)
    axes = np.array([1.0, 0.7, 0.5])
    np.savez(root / "clouds.npz", points=np.stack([P * axes + [0.1 * t, 0.05 * t, 0.0] for t in range(3)]))
    Vc, Fc = datasets.icosphere(2)
    io.write_ply(root / "control.ply", Vc * axes, Fc)
    return root / "clouds.npz", root / "control.ply"


def test_points_in_correspondence_fill_the_drift_columns_and_a_translation_does_not_drift(clouds, tmp_path, capsys):
    """The frames are their own reference (points in correspondence). Under a translation of 3.6 % of the
    diagonal per frame, Gauss-Newton with a stiff ARAP keeps the control vertices' limit points on their
    material points: the drift grows by less than 0.05 % of the diagonal over the frames (0.016 % measured;
    the 0.4 % at frame 0 is the coarse template's fit error)."""
    npz, template = clouds
    out = tmp_path / "out"
    run_ok(["fit-sequence", str(npz), "-o", str(out), "--template", str(template), "--solver", "gauss-newton",
            "--gn-iterations", "6", "--alpha", "1"])
    assert "frames in correspondence: the correspondence drift is measured against them" in capsys.readouterr().err
    with open(out / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    drift = [float(r["drift_mean"]) for r in rows]
    assert len(rows) == 3 and all(d < 0.005 for d in drift) and drift[2] - drift[0] < 0.0005, drift
    assert all(float(r["mean"]) < 0.01 for r in rows)


def test_a_reference_of_points_measures_the_drift_of_other_frames(clouds, tmp_path):
    """--reference with points (T, N, 3): the frames (here written as XYZ files, not in correspondence)
    get their drift from it; a reference of another length is refused."""
    npz, template = clouds
    frames = tmp_path / "frames"
    frames.mkdir()
    P = np.load(npz)["points"]
    for t in range(3):
        np.savetxt(frames / f"{t:04d}.xyz", P[t][::2])
    out = tmp_path / "out"
    run_ok(["-q", "fit-sequence", str(frames), "-o", str(out), "--template", str(template), "--reference", str(npz),
            "--solver", "gauss-newton", "--gn-iterations", "4", "--frames", "0:2"])
    with open(out / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and all(0 < float(r["drift_mean"]) < 0.01 for r in rows)


def test_track_carries_a_translation_so_that_adam_does_not_drift(clouds, tmp_path):
    """``--track``: the embedded deformation graph carries each frame's start along the translation (3.6 % of
    the diagonal per frame) and the tangential term holds it there: the drift grows by less than 0.1 % over
    the frames (0.052 % measured; 0.050 % without ``--track``: on this smooth motion Adam alone holds too,
    the D-FAUST bench is where the two differ), the fit stays on the points, and the options are recorded."""
    npz, template = clouds
    out = tmp_path / "out"
    run_ok(["fit-sequence", str(npz), "-o", str(out), "--template", str(template), "--track", "8"])
    with open(out / "metrics.csv") as f:
        drift = [float(r["drift_mean"]) for r in csv.DictReader(f)]
    assert len(drift) == 3 and drift[2] - drift[0] < 0.001, drift
    with open(out / "metrics.csv") as f:
        assert all(float(r["mean"]) < 0.01 for r in csv.DictReader(f))
    options = json.loads((out / "sequence.json").read_text())["options"]
    assert options["track"] == 8 and options["tangential"] == 1.0
