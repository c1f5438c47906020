"""One declaration per option field: its rule, help, flag and command-line form (for :mod:`mi_loop.fitting.options`).

:func:`option` declares a dataclass field: its default, the :class:`Rule` its
values obey (which also says how the command line reads one), its help text
and, where they are not the plain ``--`` + name with dashes, its flag,
metavar, deprecated spellings and special command-line forms (:class:`Option`).
:func:`check_fields` checks an instance against its fields' rules (the option
classes' ``__post_init__``); :func:`declared` and :func:`option_flag` are what
the command-line parser (:mod:`mi_loop.app.parser`) is generated from. A
rejected value raises :class:`OptionError` (a :class:`ValueError`).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import Field, dataclass, field, fields

import numpy as np

from mi_loop.errors import expected

__all__ = ["COUNT", "FLAG", "POSITIVE", "SEED", "WEIGHT", "Option", "OptionError", "Rule", "at_least",
           "check_fields", "declared", "integers", "interval", "one_of", "option", "option_flag"]


class OptionError(ValueError):
    """A rejected option value.

    Parameters
    ----------
    owner : str
        The class or function that rejects it (``'FitOptions'``, ``'fit'``).
    name : str
        The field.
    what : str
        What the value should have been (``'a finite number >= 0'``).
    got : object
        The value.
    """

    def __init__(self, owner: str, name: str, what: str, got):
        self.owner, self.name, self.what, self.got = owner, name, what, got
        super().__init__(expected(owner, f"{name} to be {what}", self.shown))

    @property
    def shown(self):
        """The value as the message shows it (strings quoted), for :func:`mi_loop.errors.expected`."""
        return repr(self.got) if isinstance(self.got, str) else self.got

    def renamed(self, owner: str) -> OptionError:
        """The same error, reported by ``owner`` (a public function that built the options)."""
        return OptionError(owner, self.name, self.what, self.got)


# -- rules: what a field accepts -------------------------------------------------------


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_real(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


@dataclass(frozen=True)
class Rule:
    """What an option field accepts, said once for the class's check and for the command line.

    Parameters
    ----------
    ok : callable
        ``ok(value) -> bool``.
    what : str
        The accepted values, as :class:`OptionError` words them (``'a finite number >= 0'``).
    parse : callable or None
        How the command line reads one value (``float``, ``int``, ``str``); None: a
        switch, the field a bool whose flag stores the opposite of its default.
    choices : tuple, optional
        The only values (the command line offers them as choices).

    Examples
    --------
    >>> WEIGHT.ok(0.5), WEIGHT.ok(-1.0), WEIGHT.what
    (True, False, 'a finite number >= 0')
    >>> at_least(16).or_none("the photos' size").what
    "an integer >= 16 (or None: the photos' size)"
    """

    ok: Callable[[object], bool]
    what: str
    parse: Callable[[str], object] | None = None
    choices: tuple | None = None

    def or_none(self, meaning: str | None = None) -> Rule:
        """The same rule that also accepts None (``meaning``, if given, says what None does)."""
        what = self.what if meaning is None else f"{self.what} (or None: {meaning})"
        return Rule(lambda v: v is None or self.ok(v), what, self.parse, self.choices)


def at_least(low: int) -> Rule:
    """The rule of an integer ``>= low``.

    Parameters
    ----------
    low : int
        Smallest accepted value.
    """
    return Rule(lambda v: _is_int(v) and v >= low, f"an integer >= {low}", int)


def integers(low: int, high: int) -> Rule:
    """The rule of an integer in ``low..high``.

    Parameters
    ----------
    low, high : int
        Smallest and largest accepted values.
    """
    return Rule(lambda v: _is_int(v) and low <= v <= high, f"an integer in {low}..{high}", int)


def interval(low: float, high: float, open_low: bool = False) -> Rule:
    """The rule of a number in ``[low, high]`` (``(low, high]`` when ``open_low``).

    Parameters
    ----------
    low, high : float
        The interval's ends.
    open_low : bool
        Exclude ``low``.
    """
    above = (lambda v: v > low) if open_low else (lambda v: v >= low)
    return Rule(lambda v: _is_real(v) and above(v) and v <= high,
                f"a number in {'(' if open_low else '['}{low:g}, {high:g}]", float)


def one_of(choices: tuple, what: str | None = None) -> Rule:
    """The rule of one of ``choices`` (strings).

    Parameters
    ----------
    choices : tuple of str
        The accepted values.
    what : str, optional
        How the error message names them (default ``one of (...)``).
    """
    return Rule(lambda v: v in choices, what or f"one of {choices}", str, tuple(choices))


WEIGHT = Rule(lambda v: _is_real(v) and math.isfinite(v) and v >= 0, "a finite number >= 0", float)
POSITIVE = Rule(lambda v: _is_real(v) and math.isfinite(v) and v > 0, "a finite number > 0", float)
COUNT = at_least(1)
SEED = at_least(0)
FLAG = Rule(lambda v: isinstance(v, (bool, np.bool_)), "True or False")


# -- the declaration of one field ------------------------------------------------------


@dataclass(frozen=True)
class Option:
    """How an option field is checked and spelled on the command line (a field's ``metadata['option']``).

    Parameters
    ----------
    rule : Rule
        The accepted values and how the command line reads one.
    help : str
        The command line's help text (``%(default)s``: the field's default).
    flag : str, optional
        The flag, where it is not ``--`` + the name with dashes (``--vertices``).
    metavar : str, optional
        The value's name in the help (default: argparse's).
    deprecated : tuple of str
        Old spellings of the flag (of a field that takes a value), accepted
        for one release with a warning and hidden from the help.
    exclusive : str, optional
        Name of a mutually exclusive group of flags (``'template'``: ``--vertices``
        or ``--template``; ``'terms'``: ``--no-image`` or ``--image-only``).
    presets : tuple of (flag, value, help)
        More flags that store a fixed value in the field (``--fixed-albedo``: 0),
        exclusive with the flag.
    capped_by : str, optional
        Another field; the command line's default is the field's default, but
        never more than that field's value (``views_per_iteration`` by ``views``).
    paths : bool
        The flag also takes a file, which the command passes on beside the
        options; the field then keeps its default (``fit-images --init MESH``).
    """

    rule: Rule
    help: str
    flag: str | None = None
    metavar: str | None = None
    deprecated: tuple = ()
    exclusive: str | None = None
    presets: tuple = ()
    capped_by: str | None = None
    paths: bool = False


def option(default, *, rule: Rule, help: str, flag: str | None = None, metavar: str | None = None,
           deprecated: tuple = (), exclusive: str | None = None, presets: tuple = (), capped_by: str | None = None,
           paths: bool = False):
    """Declare an option field: its default, rule, help and command-line spelling.

    Parameters
    ----------
    default : object
        The default (immutable).
    rule : Rule
        The accepted values.
    help : str
        The command line's help text.
    flag, metavar, deprecated, exclusive, presets, capped_by, paths
        As in :class:`Option`.

    Returns
    -------
    dataclasses.Field
        With the :class:`Option` as ``metadata['option']``.
    """
    declaration = Option(rule, help, flag, metavar, tuple(deprecated), exclusive, tuple(presets), capped_by, paths)
    return field(default=default, metadata={"option": declaration})


def declared(cls) -> list[tuple[Field, Option]]:
    """Return every field of an option class with its declaration, in the class's order.

    Parameters
    ----------
    cls : type
        :class:`FitOptions`, :class:`SequenceOptions`, :class:`ImageFitOptions` (or a subclass).

    Returns
    -------
    list of (dataclasses.Field, Option)
    """
    return [(f, f.metadata["option"]) for f in fields(cls)]


def option_flag(f: Field) -> str:
    """Return the command-line flag of an option field.

    Parameters
    ----------
    f : dataclasses.Field
        A field of an option class.

    Returns
    -------
    str
        Its declared flag, else ``--`` and its name with dashes.

    Examples
    --------
    >>> from mi_loop.fitting.options import FitOptions
    >>> [option_flag(f) for f in fields(FitOptions)][:2]
    ['--vertices', '--alpha']
    """
    return f.metadata["option"].flag or "--" + f.name.replace("_", "-")


def check_fields(options) -> None:
    """Check every field of an option object against its rule.

    Parameters
    ----------
    options : dataclass instance
        Whose fields were declared with :func:`option`.

    Raises
    ------
    OptionError
        For the first field whose value its rule rejects.
    """
    for f, declaration in declared(type(options)):
        value = getattr(options, f.name)
        if not declaration.rule.ok(value):
            raise OptionError(type(options).__name__, f.name, declaration.rule.what, value)
