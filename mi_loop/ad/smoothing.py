r"""Large, smooth steps on control points: ``u = (I + lambda L) x``, solved on the device.

Nicolet, Jacobson and Jakob (2021) optimise ``u = (I + lambda L) x`` instead
of the vertex positions ``x`` (``L`` the combinatorial Laplacian of the mesh):
a gradient ``g`` with respect to ``x`` becomes ``(I + lambda L)^{-1} g`` with
respect to ``u``, which spreads each step over the neighbourhood (a gradient
that pulls one silhouette vertex moves a smooth region). The same solve turns
a noisy gradient into a Sobolev gradient.

The matrix is factorised once per control mesh (Cholesky, `cholespy
<https://github.com/rgl-epfl/cholespy>`_, as Mitsuba's own ``ad/largesteps.py``
does) with the factor where the variant runs: on the CPU for ``llvm_*``, on
the GPU for ``cuda_*``. Every solve then reads and writes Dr.Jit arrays in
place, with no copy to the host, and :meth:`SmoothParameterisation.to_points`
is a ``dr.CustomOp`` whose reverse pass is a second solve (the matrix is
symmetric). The triangular solves run in a fixed order, so results are
bit-identical run to run.
"""
from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp

from mi_loop.errors import fail
from mi_loop.mesh.geometry import adjacency

__all__ = ["SmoothParameterisation", "smoothing_matrix"]


def smoothing_matrix(F, n: int, lam: float) -> sp.csr_matrix:
    r"""Return ``I + lambda L`` of a triangle mesh, ``L = D - A`` (degree minus adjacency).

    Parameters
    ----------
    F : (m, 3) int NumPy array
        Triangles.
    n : int
        Number of vertices.
    lam : float
        ``lambda >= 0``.

    Returns
    -------
    (n, n) scipy.sparse.csr_matrix, float64
        Symmetric positive definite; its rows sum to 1 (``L`` annihilates constants).

    Raises
    ------
    ValueError
        ``lam`` negative or not finite.
    """
    if isinstance(lam, bool) or not (isinstance(lam, (int, float, np.number)) and np.isfinite(lam) and lam >= 0):
        fail("SmoothParameterisation", "lam to be a finite number >= 0", lam)
    A = adjacency(F, n)
    L = sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A
    return (sp.identity(n) + float(lam) * L).tocsr()


class SmoothParameterisation:
    """``u = (I + lambda L) x`` for the control points of one control mesh, its inverse a device solve.

    Parameters
    ----------
    F : (m, 3) int NumPy array
        Control faces.
    n : int
        Number of control vertices.
    lam : float
        ``lambda >= 0``; 0 is the identity (plain vertex optimisation).

    Attributes
    ----------
    M : (n, n) scipy.sparse.csr_matrix, float64
        ``I + lambda L`` (:func:`smoothing_matrix`).

    Notes
    -----
    Needs a Mitsuba variant (:func:`mi_loop.set_variant`): the factor is built
    for it; build a new object after switching variants. Double-precision
    variants get a float64 factor, the others float32.

    Examples
    --------
    >>> import numpy as np, mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> from mi_loop.datasets import icosphere
    >>> V, F = icosphere(1)
    >>> p = SmoothParameterisation(F, len(V), lam=10.0)
    >>> x = mi.Float(V.astype(np.float32).ravel())
    >>> bool(np.allclose(p.to_points(p.to_parameters(x)).numpy(), x.numpy(), atol=1e-5))
    True
    """

    def __init__(self, F, n: int, lam: float):
        self.M = smoothing_matrix(F, n, lam)
        self.n, self.lam = int(n), float(lam)
        self._solver = None if self.lam == 0 else _factor(self.M)

    def to_parameters(self, x):
        """``u = M x`` of control points ``x`` (``mi.Float (3n)``, xyz interleaved); no gradients."""
        import mitsuba as mi

        X = np.array(x, dtype=np.float64).reshape(self.n, 3)
        return mi.Float(np.asarray(self.M @ X, dtype=np.float32).ravel())

    def to_points(self, u):
        """``x = M^{-1} u`` (``mi.Float (3n)``); differentiable, its reverse pass a second solve."""
        import drjit as dr

        if self._solver is None:
            return u
        return dr.custom(_solve_op(), self, u)

    def solve(self, g):
        """``M^{-1} g`` of a flat ``mi.Float (3n)`` without gradients (a gradient with respect to ``x``
        becomes one with respect to ``u``: ``M`` is symmetric)."""
        import drjit as dr
        import mitsuba as mi

        if self._solver is None:
            return dr.detach(g)
        b = mi.TensorXf(dr.detach(g), (self.n, 3))
        out = dr.empty(mi.TensorXf, shape=b.shape)
        self._solver.solve(b, out)
        return mi.Float(out.array)


def _factor(M: sp.csr_matrix):
    """The Cholesky factor of ``M`` for the current variant (cholespy), from device index and value tensors."""
    import mitsuba as mi
    from cholespy import MatrixType

    if mi.variant() is None:
        raise RuntimeError("SmoothParameterisation(): expected a Mitsuba variant to be set (mi_loop.set_variant), "
                           "got none")
    if "double" in mi.variant():
        from cholespy import CholeskySolverD as Solver
    else:
        from cholespy import CholeskySolverF as Solver
    C = M.tocoo()
    return Solver(M.shape[0], mi.TensorXi(C.row.astype(np.int32)), mi.TensorXi(C.col.astype(np.int32)),
                  mi.TensorXd(C.data), MatrixType.COO)


@functools.cache
def _solve_op():
    import drjit as dr

    class Solve(dr.CustomOp):
        """``x = M^{-1} u`` with the forward and reverse derivatives as solves."""

        def eval(self, param, u):
            self.param = param
            return param.solve(u)

        def forward(self):
            self.set_grad_out(self.param.solve(self.grad_in("u")))

        def backward(self):
            self.set_grad_in("u", self.param.solve(self.grad_out()))

        def name(self):
            return "SmoothParameterisation.to_points"

    return Solve
