"""mi_loop: exact, differentiable Loop subdivision surfaces for Mitsuba 3 / Dr.Jit.

Layers, each importing only from those before it:

- :mod:`mi_loop.mesh` (NumPy): validation, topology, geometry, sampling, point normals;
- :mod:`mi_loop.io`: mesh and point-cloud files, atomic writes;
- :mod:`mi_loop.subdiv` (NumPy/SciPy): Loop subdivision and the exact limit, :func:`limit_matrix`;
- :mod:`mi_loop.ad` (Dr.Jit): :class:`LimitOperator`, deterministic sparse gathers;
- :mod:`mi_loop.energies` (Dr.Jit): IMLS, coverage, ARAP;
- :mod:`mi_loop.render` (Mitsuba): variant, the ``loop_subdiv`` plugin, cameras, multi-view losses;
- :mod:`mi_loop.fitting`: templates, static and sequence fitting loops (no file I/O);
- :mod:`mi_loop.app`: jobs, reports and the ``mi-loop`` command line.

``import mi_loop`` imports neither Dr.Jit nor Mitsuba and never fails for lack
of a libLLVM: the public names below load their modules on first use. If
``DRJIT_LIBLLVM_PATH`` is unset and ``drjit`` is not imported yet, it is set to
the newest libLLVM >= 16 found (Dr.Jit's CPU backend crashes with LLVM 15);
:func:`set_variant` and :func:`register` check the library actually loaded.
If Mitsuba is already imported with a JIT autodiff variant set, the
``loop_subdiv`` plugin is registered for it at import.
"""
from __future__ import annotations

import importlib
import sys

from mi_loop._llvm import configure_llvm

__version__ = "0.2.0"

configure_llvm()

#: Public name -> module that defines it (loaded on first access).
_LAZY = {
    "LimitOperator": "mi_loop.ad.operator",
    "limit_matrix": "mi_loop.subdiv.limit",
    "limit_masks": "mi_loop.subdiv.masks",
    "limit_normals": "mi_loop.subdiv.masks",
    "limit_positions": "mi_loop.subdiv.masks",
    "subdivision_matrix": "mi_loop.subdiv.subdivision",
    "tessellate": "mi_loop.subdiv.tessellation",
    "validate_mesh": "mi_loop.mesh.topology",
    "set_variant": "mi_loop.render.variant",
    "register": "mi_loop.render.variant",
    "fit": "mi_loop.fitting.static",
    "FitError": "mi_loop.errors",
}
#: Sub-modules reachable as attributes of the package (``from mi_loop import plugin``).
_MODULES = {
    "plugin": "mi_loop.render.plugin",
    "datasets": "mi_loop.datasets",
    "metrics": "mi_loop.metrics",
    "io": "mi_loop.io",
}

__all__ = sorted([*_LAZY, "__version__", "configure_llvm"])


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif name in _MODULES:
        value = importlib.import_module(_MODULES[name])
    else:
        raise AttributeError(f"module 'mi_loop' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted([*globals(), *_LAZY, *_MODULES])


def _register_if_variant_set() -> None:
    """Register ``loop_subdiv`` when Mitsuba is loaded with a JIT AD variant (never imports it)."""
    mi = sys.modules.get("mitsuba")
    variant = getattr(mi, "variant", lambda: None)() if mi is not None else None
    if variant is not None and variant.startswith(("llvm_ad_", "cuda_ad_")):
        from mi_loop.render.variant import register

        try:
            register()
        except RuntimeError as exc:   # an unusable libLLVM: say so, but let the import succeed
            import warnings

            warnings.warn(f"mi_loop: loop_subdiv not registered: {exc}", RuntimeWarning, stacklevel=3)


_register_if_variant_set()
