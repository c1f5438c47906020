"""The exceptions mi_loop raises and the one form of their messages.

Every rejected input raises :class:`ValueError` (or :class:`TypeError`) whose
message reads ``function(): expected ..., got ...``; :func:`expected` writes
it. A fit that cannot produce a finite result raises :class:`FitError`, in the
static loop and in the sequence loop alike. The command line prints either as
one line ``mi-loop: error: ...``.
"""
from __future__ import annotations

from typing import NoReturn

__all__ = ["FitError", "expected", "fail"]


class FitError(RuntimeError):
    """The optimisation could not produce a finite result (it diverged and did not recover)."""


def expected(func: str, what: str, got) -> str:
    """Format an input error: ``func(): expected what, got got``.

    Parameters
    ----------
    func : str
        The public function or class that rejects the input, without
        parentheses (``'limit_matrix'``, ``'IMLS'``, ``'fit-sequence --views'``).
    what : str
        What the input should have been.
    got : object
        What it was; strings are inserted as they are, anything else with ``repr``.

    Returns
    -------
    str

    Examples
    --------
    >>> expected("limit_matrix", "uv of shape (k, 2)", "shape (4, 3)")
    'limit_matrix(): expected uv of shape (k, 2), got shape (4, 3)'
    >>> expected("IMLS", "h0 > 0", -1.0)
    'IMLS(): expected h0 > 0, got -1.0'
    """
    head = func if func.endswith(")") or " " in func else f"{func}()"
    return f"{head}: expected {what}, got {got if isinstance(got, str) else repr(got)}"


def fail(func: str, what: str, got, exc: type[Exception] = ValueError) -> NoReturn:
    """Raise ``exc(expected(func, what, got))``.

    Parameters
    ----------
    func, what, got
        As in :func:`expected`.
    exc : type, optional
        Exception class (default :class:`ValueError`).

    Raises
    ------
    ValueError
        Always (or ``exc``).
    """
    raise exc(expected(func, what, got))
