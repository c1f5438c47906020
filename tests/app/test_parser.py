"""The ``mi-loop`` argument parser (mi_loop.app.parser): usage errors, global flags, defaults, help texts.

The option flags are generated from the fields' declarations (mi_loop.fitting.options):
every field's flag, default, type, choices and help are checked against its
declaration in every command that takes it, and every rejected value against its
flag-named message.
"""
from __future__ import annotations

import argparse
import dataclasses
import re

import pytest

from mi_loop.app.cli import main, options_from_args
from mi_loop.app.parser import FLAGS, build_parser, flag
from mi_loop.fitting.declarations import declared, option_flag
from mi_loop.fitting.options import FitOptions, ImageFitOptions, SequenceOptions

from helpers import REPO, one_line_error

#: Each command that takes an option class: its shortest command line and the class.
COMMANDS = {
    "fit": (["fit", "in.xyz", "-o", "{out}"], FitOptions),
    "fit-sequence": (["fit-sequence", "frames.npz", "-o", "{out}"], SequenceOptions),
    "fit-images": (["fit-images", "transforms.json", "-o", "{out}"], ImageFitOptions),
    "fit-batch": (["fit-batch", "a.xyz", "-o", "{out}"], FitOptions),
    "fit-batch --sequences": (["fit-batch", "--sequences", "seq.npz", "-o", "{out}"], SequenceOptions),
}


def command_line(name: str, out="out") -> list:
    return [a.format(out=out) for a in COMMANDS[name][0]]


def command_parser(name: str) -> argparse.ArgumentParser:
    """The sub-parser of a command (``'fit-batch --sequences'``: the one ``--sequences`` switches to)."""
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    parser = sub.choices[name.split()[0]]
    return parser.switch[1] if name.endswith("--sequences") else parser


def help_of(action) -> str:
    """An action's help as ``--help`` prints it (``%(default)s`` expanded), whitespace collapsed."""
    return " ".join((action.help % {**vars(action), "prog": "mi-loop"}).split())


def field_action(parser, f):
    """The action of a field's own flag."""
    action = parser._option_string_actions[option_flag(f)]
    assert action.dest == f.name, (f.name, action.dest)
    return action


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


# -- the option flags, generated from the fields' declarations ---------------------------------------


@pytest.mark.parametrize("name", COMMANDS)
def test_every_field_has_its_flag_default_type_and_choices_in_every_command_that_takes_it(name):
    parser, cls = command_parser(name), COMMANDS[name][1]
    args = build_parser().parse_args(command_line(name))
    for f, declaration in declared(cls):
        action = field_action(parser, f)
        if declaration.capped_by:                          # the default depends on another flag
            assert action.default is None and getattr(args, f.name) is None, f.name
        else:
            assert action.default == f.default and getattr(args, f.name) == f.default, f.name
        if declaration.rule.parse is None:                 # a switch: the flag stores the opposite
            assert action.nargs == 0 and action.const is (not f.default), f.name
        else:
            assert action.type is declaration.rule.parse and action.metavar == declaration.metavar, f.name
            expected = None if declaration.paths else declaration.rule.choices
            assert action.choices == expected, f.name
        assert help_of(action).startswith(" ".join(declaration.help.split()).split("%")[0]), f.name
    assert options_from_args(cls, args, name) == cls()      # the command line's defaults are the options'


@pytest.mark.parametrize("name", COMMANDS)
def test_help_shows_every_options_default(name, capsys):
    parser, cls = command_parser(name), COMMANDS[name][1]
    for f, declaration in declared(cls):
        if declaration.rule.parse is None:
            continue                                        # a switch: off unless given
        text = help_of(field_action(parser, f))
        if f.default is None:
            assert "(default: " in text, (f.name, text)     # said in words
        elif declaration.rule.choices:
            assert str(f.default) in text and "default" in text, (f.name, text)
        else:
            assert f"default {f.default}" in text, (f.name, text)
    with pytest.raises(SystemExit):
        main([*name.split(), "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert all(option_flag(f) in shown for f in dataclasses.fields(cls))


def test_a_field_added_to_an_option_class_appears_in_the_parser(monkeypatch):
    from mi_loop.app import parser as parser_module
    from mi_loop.fitting.declarations import COUNT, option

    @dataclasses.dataclass
    class Grown(FitOptions):
        knots: int = option(7, rule=COUNT, metavar="K", help="knots per edge (default %(default)s)")

    monkeypatch.setattr(parser_module, "FitOptions", Grown)
    grown = command_parser("fit")
    assert help_of(grown._option_string_actions["--knots"]) == "knots per edge (default 7)"
    args = build_parser().parse_args(["fit", "in.xyz", "-o", "out", "--knots", "9", "--iterations", "5"])
    assert options_from_args(Grown, args, "fit") == Grown(knots=9, iterations=5)
    with pytest.raises(ValueError, match=r"^fit --knots: expected an integer >= 1, got 0$"):
        options_from_args(Grown, build_parser().parse_args(["fit", "x", "-o", "o", "--knots", "0"]), "fit")


def test_flags_come_from_the_declarations_and_one_name_has_one_flag_in_every_command():
    seen = {}
    for name in COMMANDS:
        parser, cls = command_parser(name), COMMANDS[name][1]
        for f in dataclasses.fields(cls):
            action = field_action(parser, f)
            assert seen.setdefault(f.name, action.option_strings[0]) == action.option_strings[0], f.name
            assert flag(f.name) == FLAGS[f.name] == option_flag(f), f.name
    assert (flag("n_vertices"), flag("resolution"), flag("n_points")) == ("--vertices", "--res", "--points")
    assert (flag("image"), flag("geometric")) == ("--no-image", "--image-only")
    assert flag("geometric or image") == "geometric or image"          # a check of two fields, as it is


#: Rejected values of each rule (by its description): (command-line text, the value as the message shows it).
BAD_VALUES = {
    "a finite number >= 0": [("-1", "-1.0"), ("nan", "nan"), ("inf", "inf")],
    "a finite number > 0": [("0", "0.0"), ("-2", "-2.0")],
    "a finite number > 0 (or None: automatic)": [("0", "0.0"), ("nan", "nan")],
    ("a finite number >= 0 (or None: 3 on mesh frames and with --images, "
     "0.3 on point clouds without)"): [("-0.5", "-0.5"), ("inf", "inf")],
    "a finite number >= 0 (or None: 0.01 on mesh frames, 1 on point clouds)": [("-1", "-1.0"), ("nan", "nan")],
    "a finite number >= 0 (or None: 0.01, or 0.3 with --images)": [("-0.1", "-0.1"), ("inf", "inf")],
    "an integer >= 0": [("-1", "-1")],
    "an integer >= 1": [("0", "0"), ("-3", "-3")],
    "an integer >= 4": [("3", "3")],
    "an integer >= 16 (or None: the photos' size)": [("8", "8")],
    "an integer in 0..4": [("5", "5"), ("-1", "-1")],
    "an integer in 0..6": [("7", "7")],
    "an integer in 4..10 (or None: from --vertices)": [("3", "3"), ("11", "11")],
    "an integer >= 0 (or None: as built)": [("-1", "-1")],
    "an integer in 0..10": [("11", "11")],
    "a number in [0, 1]": [("1.5", "1.5"), ("-0.1", "-0.1")],
    "a number in (0, 1]": [("0", "0.0"), ("1.5", "1.5")],
    "0 (off) or an integer >= 2": [("1", "1"), ("-2", "-2")],
}


def rejected_values():
    """(command, flag, text, message) for every valued, choice-free field of every command and its bad values."""
    cases = []
    for name, (_, cls) in COMMANDS.items():
        for f, declaration in declared(cls):
            rule = declaration.rule
            if rule.parse is None or rule.choices:
                continue                                    # switches; choices are argparse's (below)
            assert rule.what in BAD_VALUES, f"no bad values for the rule {rule.what!r} of {cls.__name__}.{f.name}"
            command = name.split()[0]
            cases += [pytest.param(name, option_flag(f), text, f"{command} {option_flag(f)}: expected {rule.what}, "
                                   f"got {shown}", id=f"{name}{option_flag(f)}={text}")
                      for text, shown in BAD_VALUES[rule.what]]
    return cases


@pytest.mark.parametrize("name, option, text, message", rejected_values())
def test_every_rejected_value_is_named_by_its_flag(name, option, text, message, tmp_path, capsys):
    """The inputs do not exist: an error about the option proves it came first; nothing is written."""
    line = one_line_error(capsys, [*command_line(name, tmp_path / "out"), f"{option}={text}"])
    assert line == f"mi-loop: error: {message}"
    assert list(tmp_path.iterdir()) == []


def choice_fields():
    return [pytest.param(name, option_flag(f), f.metadata["option"].rule.choices, id=f"{name}{option_flag(f)}")
            for name, (_, cls) in COMMANDS.items() for f, d in declared(cls) if d.rule.choices and not d.paths]


@pytest.mark.parametrize("name, option, choices", choice_fields())
def test_a_value_outside_the_choices_is_a_usage_error(name, option, choices, capsys):
    with pytest.raises(SystemExit) as info:
        main([*command_line(name), option, "nosuch"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    choices = ", ".join(repr(c) for c in choices)
    assert err.endswith(f"error: argument {option}: invalid choice: 'nosuch' (choose from {choices})\n"), err


@pytest.mark.parametrize("name, old, new, field", [
    ("fit-sequence", "--image-smooth", "--lam", "lam"),
    ("fit-batch --sequences", "--image-smooth", "--lam", "lam"),
    ("fit-images", "--smooth", "--laplacian", "laplacian"),
    ("fit-images", "--stall", "--tolerance", "tolerance"),
])
def test_a_deprecated_spelling_works_and_warns_once(name, old, new, field, capsys):
    args = build_parser().parse_args([*command_line(name), old, "0.25"])
    assert capsys.readouterr().err == f"mi-loop: warning: {old} is deprecated; use {new}\n"
    assert getattr(options_from_args(COMMANDS[name][1], args, name), field) == 0.25
    build_parser().parse_args([*command_line(name), new, "0.25"])
    assert capsys.readouterr().err == ""                            # the current spelling: no warning
    parser = command_parser(name)
    assert parser._option_string_actions[old].help == argparse.SUPPRESS       # hidden from the help,
    assert f"deprecated spelling: {old}" in help_of(parser._option_string_actions[new])   # named by the new flag
    declaration = next(d for f, d in declared(COMMANDS[name][1]) if f.name == field)
    assert declaration.deprecated == (old,)


def test_a_rejected_value_under_a_deprecated_spelling_names_the_current_flag(tmp_path, capsys):
    code = main([*command_line("fit-images", tmp_path / "o"), "--smooth", "-1"])
    err = capsys.readouterr().err.splitlines()
    assert code == 1 and err == ["mi-loop: warning: --smooth is deprecated; use --laplacian",
                                 "mi-loop: error: fit-images --laplacian: expected a finite number >= 0, got -1.0"]


@pytest.mark.parametrize("name", COMMANDS)
def test_iterations_and_tolerance_reach_the_same_fields_in_every_command(name):
    cls = COMMANDS[name][1]
    args = build_parser().parse_args([*command_line(name), "--iterations", "7", "--tolerance", "0.25"])
    options = options_from_args(cls, args, name)
    assert (options.iterations, options.tolerance) == (7, 0.25)
    assert dataclasses.replace(options, iterations=cls.iterations, tolerance=cls.tolerance) == cls()


def test_sequence_options_have_a_tolerance_that_is_off_by_default():
    assert SequenceOptions().tolerance == 0.0
    args = build_parser().parse_args([*command_line("fit-sequence"), "--tolerance", "1e-3"])
    assert options_from_args(SequenceOptions, args, "fit-sequence").tolerance == 1e-3


@pytest.mark.parametrize("name, other", [("fit-batch", SequenceOptions), ("fit-batch --sequences", FitOptions)])
def test_fit_batch_takes_fits_options_and_with_sequences_fit_sequences(name, other, capsys):
    parser, cls = command_parser(name), COMMANDS[name][1]
    dests = {a.dest for a in parser._actions if a.option_strings} - {"help", "quiet", "debug"}
    own = {f.name for f in dataclasses.fields(cls)}
    hand_written = {"scheduler", "workers", "sequences", "template", "view_level", "variant", "output"}
    assert dests == own | hand_written | ({"frame_range"} if cls is SequenceOptions else set())
    foreign = next(f for f in dataclasses.fields(other) if f.name not in own)     # --views or --h0
    with pytest.raises(SystemExit) as info:
        main([*command_line(name), option_flag(foreign), "1"])
    assert info.value.code == 2
    assert f"unrecognized arguments: {option_flag(foreign)} 1" in capsys.readouterr().err


#: Flags that several commands take, and the words each command's help says them with.
SAME_WORDS = {
    "--iterations": "most iterations of ",
    "--tolerance": "below which",
    "--seed": "random seed: of ",
    "--spp": "samples per pixel",
    "--level": "4**L triangles per control face",
    "--view-level": "4**L triangles per control face",
    "--res": "in pixels",
    "--resolution": "in pixels",
    "--lam": "lambda of the (I + lambda L)^-1 smoothing over the cage",
    "--cover": "weight of the coverage term: data points pull their nearest limit samples",
    "--fold": "weight of the fold barrier on limit normals turned by more than 60 degrees",
    "--emitters": "the photos' lighting: a Mitsuba XML file holding only emitters",
    "--vertices": "control vertices",
    "--albedo-lr": "Adam step of the per-control-vertex albedo",
    "--deterministic": "bit-reproducible",
    "--alpha": "ARAP weight",
    "--samples": "limit samples of the distance terms",
}


@pytest.mark.parametrize("option, words", SAME_WORDS.items())
def test_a_flag_says_the_same_thing_the_same_way_in_every_command(option, words):
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    parsers = {**sub.choices, "fit-batch --sequences": sub.choices["fit-batch"].switch[1]}
    helps = {name: help_of(p._option_string_actions[option]) for name, p in parsers.items()
             if option in p._option_string_actions}
    assert len(helps) >= 2, helps                                       # a flag of several commands
    assert all(words in text for text in helps.values()), helps


# -- the README's synopsis is the generated help -------------------------------------------------------


def readme_synopsis() -> list:
    """(command, bracketed alternatives) of each ``mi-loop`` command in the README's Command line block."""
    text = (REPO / "README.md").read_text()
    block = re.search(r"^## Command line\n+```text\n(.*?)```", text, re.S | re.M).group(1)
    commands = []
    for line in block.splitlines():
        line = line.split("  #")[0]
        if line.startswith("mi-loop "):
            commands.append([line])
        else:
            commands[-1].append(line)
    return [" ".join(lines) for lines in commands]


@pytest.mark.parametrize("synopsis", readme_synopsis(), ids=lambda s: " ".join(s.split()[:2]))
def test_the_readme_synopsis_names_each_flag_with_its_metavar_or_choices(synopsis):
    words = synopsis.split()
    if words[1].startswith("--"):
        return                                              # mi-loop --version
    name = "fit-batch --sequences" if words[1] == "fit-batch" and "--sequences" in words else words[1]
    parser = command_parser(name)
    for group in re.findall(r"\[([^\]]+)\]", synopsis):
        for item in group.split(" | "):
            option, *value = item.split()
            if not option.startswith("--"):
                continue                                    # [fit options]
            action = parser._option_string_actions.get(option)
            assert action is not None and action.help != argparse.SUPPRESS, (name, option)
            if value and (value[0].isupper() or "|" in value[0]):           # a metavar or the choices
                shown = action.metavar or "|".join(action.choices or ()) or action.dest.upper()
                assert value[0].rstrip(".") == shown, (name, option, value[0], shown)
