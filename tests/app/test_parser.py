"""The ``mi-loop`` argument parser (mi_loop.app.parser): usage errors, global flags, defaults, help texts."""
from __future__ import annotations

import re

import pytest

from mi_loop.app.cli import main
from mi_loop.app.parser import build_parser
from mi_loop.fitting.options import SequenceOptions


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


@pytest.mark.parametrize("argv, message", [
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


@pytest.mark.parametrize("command", [["demo", "-o", "x"], ["render", "c.ply", "-o", "x.png"],
                                     ["fit", "--demo", "-o", "x"], ["fit-sequence", "f.npz", "-o", "x"],
                                     ["compare", "a.ply", "b.ply"], ["control", "blob", "-o", "x.ply"]])
def test_every_command_accepts_quiet_and_debug_before_or_after_it(command):
    parser = build_parser()
    for argv in ([*command, "--quiet"], ["--quiet", *command], [*command, "-q"], ["-q", *command]):
        args = parser.parse_args(argv)
        assert args.quiet is True and args.debug is False
    assert parser.parse_args(command).quiet is False


def test_the_default_variant_is_the_package_default():
    from mi_loop.render.variant import DEFAULT_VARIANT

    parser = build_parser()
    for argv in (["demo", "-o", "x"], ["render", "c.ply", "-o", "x.png"], ["fit", "--demo", "-o", "x"],
                 ["fit-sequence", "f.npz", "-o", "x"]):
        assert parser.parse_args(argv).variant == DEFAULT_VARIANT


def test_the_command_line_defaults_are_the_options_defaults():
    import dataclasses
    import inspect

    from mi_loop.app.cli import fit_options
    from mi_loop.fitting.options import FitOptions
    from mi_loop.fitting.static import fit

    assert fit_options(build_parser().parse_args(["fit", "--demo", "-o", "x"])) == FitOptions()
    signature = inspect.signature(fit).parameters                  # fit()'s keywords read them too
    for field in dataclasses.fields(FitOptions):
        assert signature[field.name].default == field.default, field.name


def test_fewer_views_than_the_default_views_per_iteration_render_them_all():
    from mi_loop.app.cli import sequence_options
    options = sequence_options(build_parser().parse_args(["fit-sequence", "f.npz", "-o", "x", "--views", "1"]))
    assert options.views == options.views_per_iteration == 1
    defaults = sequence_options(build_parser().parse_args(["fit-sequence", "f.npz", "-o", "x"]))
    assert defaults == SequenceOptions()                            # the command line's defaults are the options'


def test_every_option_has_help_and_seed_loss_points_random_are_explained(capsys):
    import argparse

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    for name, sub in commands.items():
        for action in sub._actions:
            if action.option_strings and action.dest not in ("help", "shape", "name"):
                assert action.help, (name, action.option_strings)
    texts = {}
    for command in ("fit", "fit-sequence"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        texts[command] = " ".join(capsys.readouterr().out.split())
        assert "'random' four uniformly random points per control face, drawn once from --seed" in texts[command]
        assert "--seed SEED random seed: of the automatic template's sampling and of --samples random" in texts[command]
    assert "--loss {l1,l2} pixel loss of the rendered rig: mean absolute (l1, default)" in texts["fit-sequence"]
    assert "--points N points sampled on every mesh frame" in texts["fit-sequence"]
    assert ("--deterministic bit-reproducible image term: the reverse render runs on one thread (slower)"
            in texts["fit-sequence"])


def test_compare_help_defines_the_metrics(capsys):
    with pytest.raises(SystemExit) as info:
        main(["compare", "--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for phrase in ("P2S: point-to-surface distance", "HD: Hausdorff distance", "NAE: normal angle error in degrees",
                   "fractions of the target's bounding-box diagonal", "--control", "--mesh"):
        assert phrase in text, phrase
