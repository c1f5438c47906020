"""mi_loop: exact, differentiable Loop subdivision surfaces for Mitsuba 3 / Dr.Jit.

Modules: :mod:`topology` (validation, half-edges), :mod:`subdivision` (one Loop
step), :mod:`limit` / :mod:`irregular` / :mod:`patches` / :mod:`boxspline`
(exact limit evaluation), :mod:`masks` (limit at control vertices),
:mod:`tessellation`, :mod:`operator` (Dr.Jit), :mod:`plugin` (Mitsuba shape
``loop_subdiv``), :mod:`io`, :mod:`render`, :mod:`cli`.
"""
from __future__ import annotations

from ._llvm import configure_llvm

configure_llvm()

from .limit import limit_matrix  # noqa: E402
from .masks import limit_masks, limit_normals, limit_positions  # noqa: E402
from .operator import LimitOperator  # noqa: E402
from .subdivision import subdivision_matrix  # noqa: E402
from .tessellation import tessellate  # noqa: E402
from .topology import validate_mesh  # noqa: E402
from .variant import set_variant  # noqa: E402

__all__ = ["LimitOperator", "configure_llvm", "limit_masks", "limit_matrix", "limit_normals",
           "limit_positions", "set_variant", "subdivision_matrix", "tessellate", "validate_mesh"]
