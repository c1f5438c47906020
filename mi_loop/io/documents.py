"""Small files read whole: JSON documents, and text files shipped inside the package.

- :func:`read_json`: a JSON file (a Dask scheduler file, ``sequence.json``, ``report.json``), every failure
  as one line that names the file;
- :func:`read_package_text`: a text file installed with a package (the report viewer's scripts and styles).
"""
from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from mi_loop.errors import fail

__all__ = ["read_json", "read_package_text"]


def read_json(path, where: str, want: str):
    """Read a JSON file.

    Parameters
    ----------
    path : str or os.PathLike
        The file; messages quote it as given.
    where : str
        Who reads it, for the message (``"fit-batch --scheduler"``).
    want : str
        What the file should be, for the message.

    Returns
    -------
    object
        The parsed document (a dict, a list, ...).

    Raises
    ------
    ValueError
        ``where: expected want, got 'path': no such file``, or ``...: not a JSON file (reason)``
        when it cannot be read or parsed.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     _ = open(os.path.join(d, "a.json"), "w").write('{"address": "tcp://h:1"}')
    ...     read_json(os.path.join(d, "a.json"), "example", "a JSON file")
    {'address': 'tcp://h:1'}
    """
    if not Path(path).is_file():
        fail(where, want, f"'{path}': no such file")
    try:
        return json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        fail(where, want, f"'{path}': not a JSON file ({exc})")


def read_package_text(package: str, *parts: str) -> str:
    """Read a UTF-8 text file installed with a package (:mod:`importlib.resources`).

    Parameters
    ----------
    package : str
        The package that holds it (``"mi_loop.app"``).
    parts : str
        Its path inside the package, one name per argument (``"viewer", "report.js"``).

    Returns
    -------
    str

    Examples
    --------
    >>> read_package_text("mi_loop.app", "viewer", "three.LICENSE").startswith("The MIT License")
    True
    """
    resource = resources.files(package)
    for part in parts:
        resource = resource / part
    return resource.read_text(encoding="utf-8")
