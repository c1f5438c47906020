"""Large, smooth steps on control points: the ``(I + lambda L)`` parameterisation and a uniform Adam.

Nicolet, Jacobson and Jakob (2021) optimise ``u = (I + lambda L) x`` instead of
the vertex positions ``x`` (``L`` the combinatorial Laplacian of the mesh):
a gradient ``g`` with respect to ``x`` becomes ``(I + lambda L)^{-1} g`` with
respect to ``u``, which spreads each step over the neighbourhood (a
gradient that pulls one silhouette vertex moves a smooth region), and the
"uniform" Adam divides every coordinate's step by one common second moment,
so the smoothing is not undone by per-coordinate normalisation. On a control
mesh the system is small (a few thousand rows) and symmetric positive
definite; it is factorised once per control mesh with SciPy (no extra
dependency), everything in float64 NumPy, in a fixed order (deterministic).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mi_loop.errors import fail
from mi_loop.mesh.geometry import edges

__all__ = ["AdamUniform", "SmoothParameterisation", "adjacency"]


def adjacency(F, n: int) -> sp.csr_matrix:
    """Return the vertex adjacency matrix of a triangle mesh.

    Parameters
    ----------
    F : (m, 3) int NumPy array
        Triangles.
    n : int
        Number of vertices.

    Returns
    -------
    (n, n) scipy.sparse.csr_matrix, float64
        ``A_ij = 1`` where ``i`` and ``j`` share an edge; its row sums are the valences.
    """
    E = edges(np.asarray(F))
    return sp.coo_matrix((np.ones(2 * len(E)), (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                         shape=(n, n)).tocsr()


class SmoothParameterisation:
    """``u = (I + lambda L) x`` for the control points of one control mesh.

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
    M : (n, n) scipy.sparse.csc_matrix, float64
        ``I + lambda L`` with ``L = D - A`` (degree minus adjacency).

    Examples
    --------
    >>> import numpy as np
    >>> from mi_loop.datasets import icosphere
    >>> V, F = icosphere(1)
    >>> p = SmoothParameterisation(F, len(V), lam=10.0)
    >>> bool(np.allclose(p.to_points(p.to_parameters(V)), V))
    True
    """

    def __init__(self, F, n: int, lam: float):
        if not (np.isfinite(lam) and lam >= 0):
            fail("SmoothParameterisation", "lam to be a finite number >= 0", lam)
        A = adjacency(F, n)
        L = sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A
        self.lam = float(lam)
        self.M = (sp.identity(n) + self.lam * L).tocsc()
        self._solve = spla.factorized(self.M)

    def to_parameters(self, V) -> np.ndarray:
        """``u = M x`` of control points ``V (n, 3)``; (n, 3) float64."""
        return np.asarray(self.M @ np.asarray(V, dtype=np.float64))

    def to_points(self, U) -> np.ndarray:
        """``x = M^{-1} u``; (n, 3) float64."""
        U = np.asarray(U, dtype=np.float64)
        return np.stack([self._solve(U[:, k]) for k in range(U.shape[1])], axis=1)

    def gradient(self, G) -> np.ndarray:
        """Gradient with respect to ``u`` of one with respect to ``x``: ``M^{-T} g = M^{-1} g`` (M symmetric)."""
        return self.to_points(G)


class AdamUniform:
    """Adam whose step divides by the largest second moment of all coordinates (Nicolet et al. 2021).

    Parameters
    ----------
    x0 : float NumPy array
        Start value (any shape), copied as float64.
    lr : float
        Step size (the largest step of one coordinate, in ``x0``'s units).
    betas : (float, float)
        Moment decay rates.
    eps : float
        Added to the root of the second moment.
    uniform : bool
        True: one second moment for all (the paper's variant); False: plain Adam.

    Notes
    -----
    ``m = b1 m + (1 - b1) g``, ``v = b2 v + (1 - b2) g^2``, then
    ``x -= lr * m_hat / (eps + max sqrt(v_hat))`` (``sqrt(v_hat)`` per
    coordinate when ``uniform`` is False), with the usual bias corrections.
    """

    def __init__(self, x0, lr: float, betas=(0.9, 0.999), eps: float = 1e-8, uniform: bool = True):
        self.x = np.array(x0, dtype=np.float64)
        self.lr, self.betas, self.eps, self.uniform = float(lr), betas, float(eps), uniform
        self.m = np.zeros_like(self.x)
        self.v = np.zeros_like(self.x)
        self.t = 0

    def step(self, g) -> np.ndarray:
        """Take one step along gradient ``g`` (shape of ``x``); return the new ``x``."""
        b1, b2 = self.betas
        g = np.asarray(g, dtype=np.float64)
        self.t += 1
        self.m = b1 * self.m + (1 - b1) * g
        self.v = b2 * self.v + (1 - b2) * g * g
        m_hat = self.m / (1 - b1 ** self.t)
        root = np.sqrt(self.v / (1 - b2 ** self.t))
        self.x = self.x - self.lr * m_hat / (self.eps + (root.max() if self.uniform else root))
        return self.x
