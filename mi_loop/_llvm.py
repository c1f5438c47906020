"""Point Dr.Jit's LLVM backend at a libLLVM that works (version 16 or newer).

Dr.Jit loads libLLVM when ``drjit`` is first imported and reads the
``DRJIT_LIBLLVM_PATH`` environment variable to decide which library to load.
Debian 12's default libLLVM 15 crashes while compiling Mitsuba kernels
(``LLVM ERROR: Cannot select: ... fminimum``); libLLVM 19 from the
``libllvm19`` package works. :func:`configure_llvm` runs once when
:mod:`mi_loop` is imported (it sets the variable, never raises);
:func:`check_loaded_llvm` runs when a variant is set and stops with one line
naming the fix before a crashing library is used.

This module uses the standard library only, so ``setup.sh`` can run it as a
script (``python3 mi_loop/_llvm.py``) to ask whether a usable libLLVM exists
before the virtual environment is built: exit status 0 if so, 1 otherwise.
"""
from __future__ import annotations

import glob
import os
import re
import sys

__all__ = ["MIN_LLVM_VERSION", "check_loaded_llvm", "configure_llvm", "find_libllvm", "libllvm_version"]

#: Oldest LLVM major version whose code generation handles Mitsuba's kernels.
MIN_LLVM_VERSION = 16

#: Glob patterns (relative to the file-system root) searched for libLLVM.
SEARCH_PATTERNS = (
    "usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "usr/lib/llvm-*/lib/libLLVM*.so*",
    "usr/lib64/libLLVM*.so*",
    "usr/lib/libLLVM*.so*",
)

# libLLVM-19.so, libLLVM-19.so.1, libLLVM-14.0.6.so.1, libLLVM.so.19.1, libLLVM.so
_NAME = re.compile(r"^libLLVM(?:-(?P<pre>\d+)[\d.]*)?\.so(?:\.(?P<post>\d+)[\d.]*)?$")
_DIR = re.compile(r"(?:^|/)llvm-(?P<dir>\d+)/lib/[^/]+$")


def _error(found: str) -> RuntimeError:
    return RuntimeError(
        f"mi_loop needs libLLVM >= {MIN_LLVM_VERSION} for Dr.Jit's LLVM backend "
        f"({found}): run `apt-get install libllvm19` or set DRJIT_LIBLLVM_PATH "
        "to a newer libLLVM"
    )


def libllvm_version(path: str) -> int | None:
    """Return the LLVM major version encoded in a libLLVM file path.

    Parameters
    ----------
    path : str
        Path of a shared library, e.g. ``/usr/lib/x86_64-linux-gnu/libLLVM-19.so``,
        ``/usr/lib/llvm-15/lib/libLLVM.so`` or ``libLLVM.so.19.1``.

    Returns
    -------
    int or None
        The major version, or None if the name is not a libLLVM shared library
        (static archives and component libraries such as ``libLLVMCore.a`` are
        not) or carries no version.

    Examples
    --------
    >>> libllvm_version("/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    19
    >>> libllvm_version("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    19
    >>> libllvm_version("/usr/lib/llvm-15/lib/libLLVM.so")
    15
    >>> libllvm_version("/usr/lib/llvm-14/lib/libLLVMCore.a") is None
    True
    """
    match = _NAME.match(os.path.basename(path))
    if match is None:
        return None
    version = match.group("pre") or match.group("post")
    if version is None:
        in_dir = _DIR.search(path.replace(os.sep, "/"))
        version = in_dir.group("dir") if in_dir else None
    return int(version) if version is not None else None


def find_libllvm(root: str = "/") -> tuple[str, int] | None:
    """Find the newest libLLVM shared library in the usual Debian locations.

    Parameters
    ----------
    root : str, optional
        Directory that stands for the file-system root (tests pass a fake tree).

    Returns
    -------
    (str, int) or None
        Path and major version of the newest library found, or None if there
        is none. Among files of one version the shortest name is taken
        (``libLLVM-19.so`` before ``libLLVM-19.so.1``).
    """
    found = []
    for pattern in SEARCH_PATTERNS:
        for path in glob.glob(os.path.join(root, pattern)):
            version = libllvm_version(path)
            if version is not None and os.path.isfile(path):
                found.append((-version, len(path), path))
    if not found:
        return None
    neg_version, _, path = min(found)
    return path, -neg_version


def configure_llvm(environ=None, modules=None, root: str = "/") -> str | None:
    """Point Dr.Jit at the newest libLLVM >= 16 before ``drjit`` is imported; never raise.

    Parameters
    ----------
    environ : mapping, optional
        Environment to read and update (default ``os.environ``).
    modules : mapping, optional
        Loaded modules (default ``sys.modules``); decides whether ``drjit``
        was imported already.
    root : str, optional
        File-system root to search under (tests pass a fake tree).

    Returns
    -------
    str or None
        The libLLVM path now in ``DRJIT_LIBLLVM_PATH``, or None when nothing
        was set: the variable was set by the user, ``drjit`` was imported
        already, or no libLLVM >= 16 was found.

    Notes
    -----
    Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` once, when ``drjit`` is imported, so
    the variable only helps before that. ``import mi_loop`` calls this and
    must not fail on a machine without a usable libLLVM (the NumPy limit
    evaluation works there); :func:`check_loaded_llvm`, called by
    :func:`mi_loop.set_variant` and :func:`mi_loop.register`, stops before an
    LLVM variant is used with a library that would crash.
    """
    environ = os.environ if environ is None else environ
    modules = sys.modules if modules is None else modules
    if "drjit" in modules or environ.get("DRJIT_LIBLLVM_PATH"):
        return None
    best = find_libllvm(root)
    if best is None or best[1] < MIN_LLVM_VERSION:
        return None
    environ["DRJIT_LIBLLVM_PATH"] = best[0]
    return best[0]


def check_loaded_llvm(modules=None, environ=None, root: str = "/") -> int:
    """Check that the libLLVM Dr.Jit loaded is version 16 or newer; return its major version.

    Parameters
    ----------
    modules : mapping, optional
        Loaded modules (default ``sys.modules``); ``drjit`` is imported if absent.
    environ : mapping, optional
        Environment, for the message (default ``os.environ``).
    root : str, optional
        File-system root searched for a better library, for the message.

    Returns
    -------
    int
        The loaded LLVM major version.

    Raises
    ------
    RuntimeError
        One line naming the fix, if no libLLVM is loaded or it is older than 16
        (Debian 12's LLVM 15 aborts the process while compiling Mitsuba's kernels).
    """
    modules = sys.modules if modules is None else modules
    environ = os.environ if environ is None else environ
    if "drjit" not in modules:
        import drjit  # noqa: F401  (loads libLLVM, reading DRJIT_LIBLLVM_PATH)
        modules = sys.modules
    version = modules["drjit"].detail.llvm_version()[0]
    if version >= MIN_LLVM_VERSION:
        return version
    loaded = f"loaded LLVM {version}" if version > 0 else "no libLLVM loaded"
    if environ.get("DRJIT_LIBLLVM_PATH"):
        loaded += f" from DRJIT_LIBLLVM_PATH={environ['DRJIT_LIBLLVM_PATH']}"
    else:
        best = find_libllvm(root)
        if best is not None and best[1] >= MIN_LLVM_VERSION:
            loaded += f"; {best[0]} would work: import mi_loop before drjit and mitsuba"
        elif best is not None:
            loaded += f"; newest found is LLVM {best[1]}: {best[0]}"
    raise _error(loaded)


if __name__ == "__main__":  # used by setup.sh before the venv exists
    best = find_libllvm()
    ok = best is not None and best[1] >= MIN_LLVM_VERSION
    print(f"libLLVM: {best[0] if best else 'none'}" + ("" if ok else " (too old)"))
    sys.exit(0 if ok else 1)
