"""The option classes (mi_loop.fitting.options): one declaration per field, every nonsense value refused."""
from __future__ import annotations

from dataclasses import fields

import pytest

from mi_loop.fitting.declarations import Option, OptionError, Rule, option_flag
from mi_loop.fitting.options import FitOptions, ImageFitOptions, SequenceOptions

from helpers import exactly


def test_sequence_options_reject_nonsense():
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected views_per_iteration to be an integer "
                                         r"in \[1, views=4\], got 5$"):
        SequenceOptions(views=4, views_per_iteration=5)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected loss to be one of \('l1', 'l2'\), "
                                         r"got 'l3'$"):
        SequenceOptions(loss="l3")
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected mode to be one of"):
        SequenceOptions(mode="depth")
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected seen to be a number in \[0, 1\], "
                                         r"got 1.5$"):
        SequenceOptions(seen=1.5)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected reach to be an integer in 0..10, "
                                         r"got 11$"):
        SequenceOptions(reach=11)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected image_every to be an integer >= 1, "
                                         r"got 0$"):
        SequenceOptions(image_every=0)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected geometric or image to be True "
                                         r"\(both terms are off: nothing to fit\), got False$"):
        SequenceOptions(geometric=False, image=False)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected deterministic to be True or False, "
                                         r"got 'yes'$"):
        SequenceOptions(deterministic="yes")
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected level to be an integer in 0\.\.6, "
                                         r"got 7$"):
        SequenceOptions(level=7)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected every key to be one of the fields "
                                         r"\[.*\], got \['colour'\]$"):
        SequenceOptions.from_dict({"colour": "red"})
    assert SequenceOptions.from_dict({"alpha": 0.5}) == SequenceOptions(alpha=0.5)   # older files: defaults
    assert SequenceOptions.from_dict({"alpha": 0.5, "joint_iterations": 8}) == SequenceOptions(alpha=0.5)  # retired


# -- one declaration per field: default, rule, flag and help ------------------------------------------

CLASSES = [FitOptions, SequenceOptions, ImageFitOptions]


def every_field():
    return [pytest.param(cls, f, id=f"{cls.__name__}.{f.name}") for cls in CLASSES for f in fields(cls)]


@pytest.mark.parametrize("cls, f", every_field())
def test_every_field_declares_a_rule_its_default_obeys_and_a_help_text(cls, f):
    declaration = f.metadata["option"]
    assert isinstance(declaration, Option) and isinstance(declaration.rule, Rule)
    assert declaration.rule.ok(f.default), f.name
    assert declaration.help and declaration.help == " ".join(declaration.help.split())
    assert option_flag(f).startswith("--") and all(old.startswith("--") for old in declaration.deprecated)
    if declaration.rule.parse is None:                  # a switch
        assert isinstance(f.default, bool)
    else:
        assert f.default is None or declaration.rule.parse(str(f.default)) == f.default


@pytest.mark.parametrize("cls, f", every_field())
def test_every_field_refuses_a_value_of_the_wrong_kind_with_its_rules_words(cls, f):
    what = f.metadata["option"].rule.what
    with pytest.raises(OptionError, match=exactly(f"{cls.__name__}(): expected {f.name} to be {what}, got 'nosuch'")):
        cls(**{f.name: "nosuch"})


@pytest.mark.parametrize("cls, name, value, what", [
    (FitOptions, "alpha", -1.0, "a finite number >= 0"),
    (FitOptions, "h0", 0.0, "a finite number > 0 (or None: automatic)"),
    (FitOptions, "n_vertices", 3, "an integer >= 4"),
    (FitOptions, "iterations", True, "an integer >= 1"),          # a bool is no count
    (SequenceOptions, "tolerance", -1e-3, "a finite number >= 0"),
    (SequenceOptions, "albedo_lr", -0.5, "a finite number >= 0"),
    (SequenceOptions, "views_per_iteration", 0, "an integer >= 1"),
    (SequenceOptions, "track", -1, "an integer >= 0"),
    (SequenceOptions, "tangential", -1.0, "a finite number >= 0"),
    (SequenceOptions, "cover", -1.0, "a finite number >= 0 (or None: 3 on mesh frames and with --images, "
                                     "0.3 on point clouds without)"),
    (SequenceOptions, "fold", -1.0, "a finite number >= 0 (or None: 0.01 on mesh frames, 1 on point clouds)"),
    (ImageFitOptions, "albedo_lr", float("nan"), "a finite number >= 0"),
    (ImageFitOptions, "lr_decay", 0.0, "a number in (0, 1]"),
    (ImageFitOptions, "tolerance", float("inf"), "a finite number >= 0"),
    (ImageFitOptions, "holdout", 1, "0 (off) or an integer >= 2"),
    (ImageFitOptions, "holdout", -3, "0 (off) or an integer >= 2"),
])
def test_rejected_values_name_the_class_the_field_and_the_rule(cls, name, value, what):
    with pytest.raises(OptionError, match=exactly(f"{cls.__name__}(): expected {name} to be {what}, got {value}")):
        cls(**{name: value})


def test_renamed_fields_and_the_new_sequence_tolerance():
    assert SequenceOptions().tolerance == 0.0 and SequenceOptions(tolerance=0.01).tolerance == 0.01
    assert SequenceOptions(albedo_lr=0.0).albedo_lr == ImageFitOptions(albedo_lr=0.0).albedo_lr == 0.0
    for cls in CLASSES:
        assert "iterations" in {f.name for f in fields(cls)} and "tolerance" in {f.name for f in fields(cls)}
    names = {f.name for cls in CLASSES for f in fields(cls)}
    assert not names & {"max_iterations", "geo_iterations", "image_smooth", "smooth", "stall", "fit_albedo"}
    old = SequenceOptions.from_dict({"geo_iterations": 9, "image_smooth": 2.0})        # sequence.json of older runs
    assert (old.iterations, old.lam) == (9, 2.0)


def test_the_rules_say_what_they_accept():
    from mi_loop.fitting.declarations import at_least, integers, interval, one_of

    assert at_least(16).or_none("the photos' size").what == "an integer >= 16 (or None: the photos' size)"
    assert at_least(16).or_none().ok(None) and not at_least(16).ok(None) and not at_least(16).ok(16.0)
    assert integers(0, 6).what == "an integer in 0..6" and not integers(0, 6).ok(7)
    assert interval(0, 1, open_low=True).what == "a number in (0, 1]" and not interval(0, 1, open_low=True).ok(0)
    assert interval(0, 1).what == "a number in [0, 1]" and interval(0, 1).ok(0)
    assert one_of(("a", "b")).what == "one of ('a', 'b')" and one_of(("a", "b")).choices == ("a", "b")
    assert [option_flag(f) for f in fields(SequenceOptions) if f.name in ("resolution", "n_points", "image")] == [
        "--res", "--no-image", "--points"]
