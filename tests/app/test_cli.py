"""The ``mi-loop`` command line (mi_loop.app.cli): demo, render and control, --version, --debug, --quiet, --variant.

The parser itself is tested in test_parser.py, the fit, fit-sequence and
compare jobs in test_fit_job.py, test_sequence_job.py and test_compare_job.py.
"""
from __future__ import annotations

import numpy as np
import pytest
from matplotlib import image as mpl_image

import mi_loop
from mi_loop import datasets, io
from mi_loop.app.cli import main

from helpers import one_line_error, run_console, run_python


def test_demo_writes_control_limit_and_render(tmp_path):
    out = tmp_path / "demo"
    result = run_console("demo", "-o", str(out), "--resolution", "32", "--spp", "4", "--level", "1")
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
    result = run_console("demo", "-o", str(tmp_path / "file" / "out"))
    assert result.returncode == 1
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith("mi-loop: error: ensure_writable_dir(): expected a directory that files can "
                                    f"be created in, got '{tmp_path / 'file' / 'out'}'")


def test_render_missing_control_mesh(tmp_path, capsys):
    line = one_line_error(capsys, ["render", str(tmp_path / "nope.ply"), "-o", str(tmp_path / "o.png")])
    assert "nope.ply': no such file" in line
    assert not (tmp_path / "o.png").exists()


def test_render_rejects_non_png_output(tmp_path, capsys):
    line = one_line_error(capsys, ["render", "x.ply", "-o", str(tmp_path / "o.jpg")])
    assert line == f"mi-loop: error: render --output: expected a .png file, got '{tmp_path / 'o.jpg'}'"


def test_render_rejects_bad_creases(tmp_path, capsys):
    io.write_ply(tmp_path / "c.ply", *datasets.blob())
    line = one_line_error(capsys, ["render", str(tmp_path / "c.ply"), "-o", str(tmp_path / "o.png"),
                                   "--creases", "0 1, oops"])
    assert "creases entry 1 is 'oops'" in line


def test_render_rejects_bad_corners(tmp_path, capsys):
    io.write_ply(tmp_path / "c.ply", *datasets.blob())
    line = one_line_error(capsys, ["render", str(tmp_path / "c.ply"), "-o", str(tmp_path / "o.png"),
                                   "--corners", "3, 4 -1"])
    assert "corners entry 1 is '4 -1'" in line
    assert not (tmp_path / "o.png").exists()


def test_render_rejects_unknown_boundary_rule(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["render", "c.ply", "-o", str(tmp_path / "o.png"), "--boundary", "corner"])
    assert exit_info.value.code == 2
    assert "argument --boundary: invalid choice: 'corner'" in capsys.readouterr().err


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


# -- global options: --version, --debug / MI_LOOP_TRACEBACK, --quiet, --variant -------


def test_version_names_mi_loop_mitsuba_and_drjit_without_importing_them():
    from importlib import metadata

    code = ("import sys\nfrom mi_loop.app.cli import main\n"
            "try:\n    main(['--version'])\nexcept SystemExit as e:\n    assert e.code == 0, e.code\n"
            "print('imported' if {'mitsuba', 'drjit'} & set(sys.modules) else 'not imported')\n")
    result = run_python(code, timeout=120)
    assert result.returncode == 0, result.stderr
    first, second = result.stdout.splitlines()
    assert first == (f"mi-loop {mi_loop.__version__} (mitsuba {metadata.version('mitsuba')}, "
                     f"drjit {metadata.version('drjit')})")
    assert second == "not imported"


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_shows_the_traceback_behind_the_one_line_error(tmp_path, capsys, where):
    argv = ["render", str(tmp_path / "nope.ply"), "-o", str(tmp_path / "o.png")]
    assert main(["--debug", *argv] if where == "before" else [*argv, "--debug"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):")
    assert "ValueError: read_mesh(): " in err                               # the exception behind it
    assert err.splitlines()[-1] == (f"mi-loop: error: read_mesh(): expected an existing file, got "
                                    f"'{tmp_path / 'nope.ply'}': no such file")


def test_the_environment_variable_shows_the_traceback_too(tmp_path, capsys, monkeypatch):
    argv = ["render", str(tmp_path / "nope.ply"), "-o", str(tmp_path / "o.png")]
    monkeypatch.setenv("MI_LOOP_TRACEBACK", "1")
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):") and err.splitlines()[-1].startswith("mi-loop: error: ")
    monkeypatch.setenv("MI_LOOP_TRACEBACK", "0")                           # 0 or unset: one line only
    one_line_error(capsys, argv)


def test_quiet_silences_progress_but_not_the_written_paths(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "--resolution", "16", "--spp", "1", "--level", "1", "--quiet"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    assert captured.out.split() == [str(out / n) for n in ("control.ply", "limit.ply", "render.png")]


@pytest.mark.parametrize("command", [["demo", "-o", "{out}"], ["render", "{out}.ply", "-o", "{out}.png"],
                                     ["fit", "--demo", "-o", "{out}"], ["fit-sequence", "{out}.npz", "-o", "{out}"]])
def test_an_unknown_variant_is_refused_with_the_usable_ones(tmp_path, capsys, command):
    from mi_loop.render.variant import jit_ad_variants

    out = str(tmp_path / "out")
    line = one_line_error(capsys, [c.format(out=out) for c in command] + ["--variant", "scalar_rgb"])
    name = command[0]
    assert line == (f"mi-loop: error: {name} --variant: expected one of {', '.join(jit_ad_variants())}, "
                    "got 'scalar_rgb'")
    assert "llvm_ad_rgb" in line
    assert list(tmp_path.iterdir()) == []                                   # refused before any work


def test_the_default_variant_comes_from_the_environment(tmp_path, capsys, monkeypatch):
    """MI_LOOP_VARIANT is --variant's default (checked like a given one); unset or empty: llvm_ad_rgb."""
    from mi_loop.app.parser import build_parser
    from mi_loop.render.variant import jit_ad_variants

    monkeypatch.setenv("MI_LOOP_VARIANT", "scalar_rgb")
    line = one_line_error(capsys, ["fit", "--demo", "-o", str(tmp_path / "out")])
    assert line == f"mi-loop: error: fit --variant: expected one of {', '.join(jit_ad_variants())}, got 'scalar_rgb'"
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setenv("MI_LOOP_VARIANT", "")
    assert build_parser().parse_args(["fit", "--demo", "-o", "x"]).variant == "llvm_ad_rgb"
    monkeypatch.delenv("MI_LOOP_VARIANT")
    assert build_parser().parse_args(["fit-sequence", "a.npz", "-o", "x"]).variant == "llvm_ad_rgb"


# -- options_from_args: the special forms the fields' declarations ask for ----------------------------


def parsed(*argv):
    from mi_loop.app.parser import build_parser

    return build_parser().parse_args(list(argv))


def test_fixed_albedo_is_albedo_lr_zero_and_excludes_albedo_lr(capsys):
    from mi_loop.app.cli import options_from_args
    from mi_loop.fitting.options import ImageFitOptions

    base = ["fit-images", "t.json", "-o", "o"]
    assert options_from_args(ImageFitOptions, parsed(*base, "--fixed-albedo"), "fit-images").albedo_lr == 0.0
    assert options_from_args(ImageFitOptions, parsed(*base, "--albedo-lr", "0.3"), "fit-images").albedo_lr == 0.3
    assert options_from_args(ImageFitOptions, parsed(*base), "fit-images").albedo_lr == ImageFitOptions.albedo_lr
    with pytest.raises(SystemExit) as info:
        main([*base, "--albedo-lr", "0.3", "--fixed-albedo"])
    assert info.value.code == 2
    assert capsys.readouterr().err.endswith("error: argument --fixed-albedo: not allowed with argument --albedo-lr\n")


@pytest.mark.parametrize("command", [["fit-sequence", "f.npz"], ["fit-batch", "--sequences", "s.npz"]])
def test_no_image_and_image_only_turn_one_term_off_and_exclude_each_other(command, capsys):
    from mi_loop.app.cli import options_from_args
    from mi_loop.fitting.options import SequenceOptions

    def terms(*extra):
        options = options_from_args(SequenceOptions, parsed(*command, "-o", "o", *extra), command[0])
        return options.geometric, options.image

    assert (terms(), terms("--no-image"), terms("--image-only")) == ((True, True), (True, False), (False, True))
    with pytest.raises(SystemExit) as info:
        main([*command, "-o", "o", "--no-image", "--image-only"])
    assert info.value.code == 2
    assert capsys.readouterr().err.endswith("error: argument --image-only: not allowed with argument --no-image\n")


@pytest.mark.parametrize("command", [["fit", "a.xyz"], ["fit-sequence", "f.npz"], ["fit-batch", "a.xyz"],
                                     ["fit-batch", "--sequences", "s.npz"]])
def test_vertices_and_template_exclude_each_other(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([*command, "-o", "o", "--vertices", "50", "--template", "t.ply"])
    assert info.value.code == 2
    assert capsys.readouterr().err.endswith("error: argument --template: not allowed with argument --vertices\n")
    assert parsed(*command, "-o", "o", "--template", "t.ply").n_vertices == 1000      # the default, ignored


def test_poisson_template_and_template_exclude_each_other_in_fit_batch_sequences(tmp_path, capsys):
    line = one_line_error(capsys, ["fit-batch", "--sequences", str(tmp_path / "s.npz"), "-o", str(tmp_path / "o"),
                                   "--template", "t.ply", "--poisson-template"])
    assert line == ("mi-loop: error: fit-batch --poisson-template: expected no --template (it builds the template), "
                    "got --template 't.ply'")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["fit", "a.xyz"], ["fit-batch", "a.xyz"], ["fit-batch", "--sequences", "s.npz"]])
@pytest.mark.parametrize("flag", [["--template-depth", "8"], ["--template-genus", "0"]])
def test_template_depth_and_genus_are_refused_with_a_template(command, flag, tmp_path, capsys):
    line = one_line_error(capsys, [*command, "-o", str(tmp_path / "o"), "--template", "t.ply", *flag])
    assert line == (f"mi-loop: error: {command[0]} {flag[0]}: expected no --template (it builds the template), "
                    "got --template 't.ply'")
    assert list(tmp_path.iterdir()) == []


def test_init_takes_a_shape_or_a_mesh_file_which_leaves_the_option_at_its_default(tmp_path, capsys):
    from mi_loop.app.cli import options_from_args
    from mi_loop.fitting.options import ImageFitOptions

    def init(value):
        return options_from_args(ImageFitOptions, parsed("fit-images", "t.json", "-o", "o", "--init", value),
                                 "fit-images").init

    assert (init("sphere"), init("hull"), init("start.ply")) == ("sphere", "hull", ImageFitOptions.init)
    line = one_line_error(capsys, ["fit-images", str(tmp_path / "t.json"), "-o", str(tmp_path / "o"),
                                   "--init", str(tmp_path / "nosuch.ply")])
    assert line == ("mi-loop: error: fit-images --init: expected sphere, hull or an existing control mesh file, "
                    f"got '{tmp_path / 'nosuch.ply'}'")
