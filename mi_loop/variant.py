"""Choose the Mitsuba variant and make the ``loop_subdiv`` plugin available in it."""
from __future__ import annotations

__all__ = ["DEFAULT_VARIANT", "set_variant"]

#: Variant used by the CLI, the examples and the tests: CPU (LLVM), autodiff, RGB.
DEFAULT_VARIANT = "llvm_ad_rgb"


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

    Notes
    -----
    :mod:`mi_loop` never sets a variant at import; call this (or
    ``mi.set_variant`` followed by :func:`mi_loop.plugin.register`) first.
    """
    import mitsuba as mi

    from . import plugin

    if name not in mi.variants() or not name.startswith(("llvm_ad_", "cuda_ad_")):
        usable = [v for v in mi.variants() if v.startswith(("llvm_ad_", "cuda_ad_"))]
        raise ValueError(f"set_variant: expected one of {usable}, got {name!r}")
    mi.set_variant(name)
    plugin.register()
