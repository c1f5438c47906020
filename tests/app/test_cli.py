"""Tests of the ``mi-loop`` command line (mi_loop.app.cli)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib import image as mpl_image

import mi_loop
from mi_loop import datasets, io
from mi_loop.app.cli import main

MI_LOOP = Path(sys.executable).with_name("mi-loop")


def run(*args, timeout=300):
    return subprocess.run([str(MI_LOOP), *args], capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def test_demo_writes_control_limit_and_render(tmp_path):
    out = tmp_path / "demo"
    result = run("demo", "-o", str(out), "--resolution", "32", "--spp", "4", "--level", "1")
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr and "[mi-loop" in result.stderr      # progress on stderr
    assert result.stdout.split() == [str(out / n) for n in ("control.ply", "limit.ply", "render.png")]

    V, F = io.read_mesh(out / "control.ply")
    V_ds, F_ds = datasets.blob()
    np.testing.assert_array_equal(V, V_ds)
    np.testing.assert_array_equal(F, F_ds)

    P, F_tess = io.read_mesh(out / "limit.ply")
    _, uv, F_ref = mi_loop.tessellate(F, 1)
    assert P.shape == (len(uv), 3)
    np.testing.assert_array_equal(F_tess, F_ref)
    r = np.linalg.norm(P, axis=1)
    assert 0.6 < r.min() and r.max() < 1.3                # the limit surface lies inside the blob's hull

    image = mpl_image.imread(out / "render.png")
    assert image.shape[:2] == (32, 32)
    assert image[..., :3].std() > 0.02                      # not a blank picture


def test_console_script_error_is_one_line(tmp_path):
    (tmp_path / "file").write_text("x")
    result = run("demo", "-o", str(tmp_path / "file" / "out"))
    assert result.returncode == 1
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith("mi-loop: error: cannot write to directory")


def one_line_error(capsys, argv, status=1):
    code = main(argv)
    captured = capsys.readouterr()
    assert code == status
    lines = [line for line in captured.err.splitlines() if not line.startswith("[mi-loop")]
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("mi-loop: error: ")
    return lines[0]


def test_render_missing_control_mesh(tmp_path, capsys):
    line = one_line_error(capsys, ["render", str(tmp_path / "nope.ply"), "-o", str(tmp_path / "o.png")])
    assert "nope.ply': no such file" in line
    assert not (tmp_path / "o.png").exists()


def test_render_rejects_non_png_output(tmp_path, capsys):
    line = one_line_error(capsys, ["render", "x.ply", "-o", str(tmp_path / "o.jpg")])
    assert "output must be a .png file" in line


def test_render_rejects_bad_creases(tmp_path, capsys):
    io.write_ply(tmp_path / "c.ply", *datasets.blob())
    line = one_line_error(capsys, ["render", str(tmp_path / "c.ply"), "-o", str(tmp_path / "o.png"),
                                   "--creases", "0 1, oops"])
    assert "creases entry 1 is 'oops'" in line


def test_render_rejects_invalid_control_mesh(tmp_path, capsys):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    io.write_ply(tmp_path / "bad.ply", V, np.array([[0, 1, 1]]))        # degenerate face
    line = one_line_error(capsys, ["render", str(tmp_path / "bad.ply"), "-o", str(tmp_path / "o.png")])
    assert "face 0" in line or "degenerate" in line


def test_render_writes_png(tmp_path, capsys):
    io.write_ply(tmp_path / "t.ply", *datasets.torus())
    assert main(["render", str(tmp_path / "t.ply"), "-o", str(tmp_path / "t.png"),
                 "--level", "1", "--resolution", "24", "--spp", "2"]) == 0
    assert capsys.readouterr().out.strip() == str(tmp_path / "t.png")
    assert mpl_image.imread(tmp_path / "t.png").shape[:2] == (24, 24)


def test_control_writes_dataset(tmp_path, capsys):
    assert main(["control", "torus", "-o", str(tmp_path / "t.ply")]) == 0
    V, F = io.read_mesh(tmp_path / "t.ply")
    np.testing.assert_array_equal(V, datasets.torus()[0])
    np.testing.assert_array_equal(F, datasets.torus()[1])


@pytest.mark.parametrize("argv, message", [
    (["demo"], "the following arguments are required: -o/--output"),
    (["demo", "-o", "x", "--level", "9"], "expected a level in 0..6, got 9"),
    (["demo", "-o", "x", "--spp", "0"], "expected a positive integer, got 0"),
    (["control", "cube", "-o", "x.ply"], "invalid choice: 'cube'"),
    ([], "the following arguments are required: command"),
])
def test_usage_errors_are_one_line(capsys, argv, message):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and err.startswith("mi-loop")
