"""mi_loop: exact, differentiable Loop subdivision surfaces for Mitsuba 3 / Dr.Jit."""
from __future__ import annotations

from .limit import limit_matrix
from .subdivision import subdivision_matrix
from .topology import validate_mesh

__all__ = ["limit_matrix", "subdivision_matrix", "validate_mesh"]
