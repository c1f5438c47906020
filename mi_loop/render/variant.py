"""Choose the Mitsuba variant and make the ``loop_subdiv`` plugin available in it.

Two ways in, both checking the libLLVM that Dr.Jit loaded before any kernel
is compiled (Debian 12's LLVM 15 aborts the process):

- :func:`set_variant` sets the variant and registers the plugin;
- :func:`register` registers the plugin for a variant the caller set with
  ``mi.set_variant`` (``import mi_loop`` does it by itself when a JIT
  autodiff variant is already set).
"""
from __future__ import annotations

__all__ = ["DEFAULT_VARIANT", "JIT_AD_PREFIXES", "VARIANT_ENV", "cuda_available", "default_variant",
           "jit_ad_variants", "register", "set_variant", "usable_variants"]

#: Variant used by the CLI, the examples and the tests unless told otherwise: CPU (LLVM), autodiff, RGB.
DEFAULT_VARIANT = "llvm_ad_rgb"

#: Environment variable naming the command line's default variant (e.g. ``cuda_ad_rgb`` on a GPU machine).
VARIANT_ENV = "MI_LOOP_VARIANT"

#: Prefixes of the variants the plugin works in (JIT, autodiff).
JIT_AD_PREFIXES = ("llvm_ad_", "cuda_ad_")


def default_variant() -> str:
    """The command line's default ``--variant``: ``$MI_LOOP_VARIANT`` if set and not empty, else ``llvm_ad_rgb``.

    Returns
    -------
    str
        Not checked here: ``--variant`` values are checked before any work, whichever way they came.
    """
    import os

    return os.environ.get(VARIANT_ENV, "").strip() or DEFAULT_VARIANT


def jit_ad_variants() -> list:
    """The JIT autodiff variants of the installed Mitsuba (``llvm_ad_*``, ``cuda_ad_*``).

    Returns
    -------
    list of str
    """
    import mitsuba as mi

    return [v for v in mi.variants() if v.startswith(JIT_AD_PREFIXES)]


def cuda_available() -> bool:
    """Whether Dr.Jit found a CUDA driver and device (``cuda_ad_*`` variants can run).

    Returns
    -------
    bool
    """
    import drjit as dr

    return bool(dr.has_backend(dr.JitBackend.CUDA))


def usable_variants(kind: str = "ad_rgb") -> list:
    """The JIT autodiff variants that can run on this machine: LLVM always, CUDA where a GPU is.

    Parameters
    ----------
    kind : str, optional
        Variant suffix after ``llvm_``/``cuda_`` (default ``'ad_rgb'``).

    Returns
    -------
    list of str
        E.g. ``['llvm_ad_rgb']`` here, ``['llvm_ad_rgb', 'cuda_ad_rgb']`` with a GPU.
    """
    names = jit_ad_variants()
    out = [f"llvm_{kind}"] if f"llvm_{kind}" in names else []
    if f"cuda_{kind}" in names and cuda_available():
        out.append(f"cuda_{kind}")
    return out


def _check_backend(name: str, func: str) -> None:
    """Stop with one line before a variant whose backend would crash or is missing."""
    if name.startswith("llvm_"):
        from mi_loop._llvm import check_loaded_llvm

        check_loaded_llvm()
    elif name.startswith("cuda_") and not cuda_available():
        raise RuntimeError(f"{func}(): expected a CUDA device for {name!r}, got none (Dr.Jit found no CUDA "
                           "driver or GPU); use an llvm_ad_* variant such as 'llvm_ad_rgb'")


def set_variant(name: str = DEFAULT_VARIANT) -> None:
    """Set the Mitsuba variant and register the ``loop_subdiv`` shape plugin.

    Parameters
    ----------
    name : str, optional
        A JIT autodiff variant of the installed Mitsuba, ``llvm_ad_*`` or
        ``cuda_ad_*`` (default ``'llvm_ad_rgb'``).

    Raises
    ------
    ValueError
        If ``name`` is not an autodiff JIT variant of the installed Mitsuba.
    RuntimeError
        If ``name`` is an LLVM variant and Dr.Jit loaded a libLLVM older than
        16 (the message names the fix: ``apt-get install libllvm19``).

    Notes
    -----
    :mod:`mi_loop` never sets a variant at import. Users who set it
    themselves with ``mi.set_variant`` call :func:`register` instead.
    """
    import mitsuba as mi

    usable = jit_ad_variants()
    if name not in usable:
        raise ValueError(f"set_variant(): expected one of {usable}, got {name!r}")
    _check_backend(name, "set_variant")
    mi.set_variant(name)
    register()


def register():
    """Register the ``loop_subdiv`` shape plugin for the variant already set.

    For the order of Mitsuba's own tutorials::

        mi.set_variant("llvm_ad_rgb")
        import mi_loop            # registers loop_subdiv (a JIT AD variant is set)
        mi_loop.register()        # or explicitly, e.g. after changing the variant
        scene = mi.load_file("scene.xml")

    Returns
    -------
    type
        The ``mi.Mesh`` subclass implementing the plugin in this variant.

    Raises
    ------
    RuntimeError
        If no variant is set, it is not a JIT autodiff variant, or its libLLVM
        is older than 16.
    """
    import mitsuba as mi

    from mi_loop.render import plugin

    variant = mi.variant()
    if variant is None or not variant.startswith(JIT_AD_PREFIXES):
        raise RuntimeError(f"register(): expected a Mitsuba llvm_ad_* or cuda_ad_* variant to be set, "
                           f"got {variant!r}; call mi_loop.set_variant() or mi.set_variant() first")
    _check_backend(variant, "register")
    return plugin.register()
