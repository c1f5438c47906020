"""As-rigid-as-possible (ARAP) regulariser on the control mesh.

Topology, cotangent weights and rest edge vectors are computed once in NumPy;
the best rotations come in closed form every iteration (:mod:`.rotations`:
Horn's quaternion as one compiled float64 kernel, no SVD); the energy
itself is a Dr.Jit expression of the control points with fixed-size device
arrays, so AD gives ``dE/dV`` and the kernels are reused.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mi_loop.ad.control import ControlPoints
from mi_loop.ad.sparse import IndexMap
from mi_loop.ad.upload import upload_float, upload_vec
from mi_loop.energies.rotations import RotationSolver
from mi_loop.errors import fail
from mi_loop.mesh.checks import check_points
from mi_loop.mesh.topology import validate_faces

__all__ = ["ARAP", "cotangent_weights"]

def cotangent_weights(V, F, min_weight: float = 1e-3):
    """Undirected edges and their cotangent weights ``w_ij = (cot a_ij + cot b_ij) / 2``.

    Parameters
    ----------
    V : (n, 3) float numpy array
        Rest positions.
    F : (m, 3) int numpy array
        Faces (validated).
    min_weight : float
        Floor for the edge weights (see Notes).

    Returns
    -------
    E : (e, 2) int64 numpy array
        Edges, ``E[:, 0] < E[:, 1]``.
    w : (e,) float64 numpy array
        Weights, ``>= min_weight``.

    Raises
    ------
    ValueError
        If a face has zero area (its cotangents are infinite).

    Notes
    -----
    ``a_ij``, ``b_ij`` are the angles opposite edge ``ij`` (Meyer et al. 2003);
    a boundary edge has only one, so ``w_ij = cot a_ij / 2``. Cotangent
    weights are dimensionless. Sums of cotangents are negative across edges
    whose opposite angles add up to more than pi (obtuse triangles), and
    zero for the diagonal of a square; a negative weight would reward
    stretching that edge, so weights are clamped to ``min_weight`` (that edge
    then hardly contributes).
    """
    corners = []
    for c in range(3):  # corner c is opposite edge (F[:, c+1], F[:, c+2])
        a, b, o = F[:, (c + 1) % 3], F[:, (c + 2) % 3], F[:, c]
        u, v = V[a] - V[o], V[b] - V[o]
        s = np.linalg.norm(np.cross(u, v), axis=1)
        bad = np.flatnonzero(s <= 1e-12 * np.maximum(np.sum(u * u, 1), np.sum(v * v, 1)))
        if len(bad):
            fail("ARAP", "rest faces of non-zero area (cotangent weights)",
                 f"face {bad[0]} = {F[bad[0]].tolist()} of zero area; remove or fix it")
        corners.append((np.minimum(a, b), np.maximum(a, b), np.sum(u * v, 1) / s))
    i, j, cot = (np.concatenate(t) for t in zip(*corners))
    n = len(V)
    keys, inv = np.unique(i * n + j, return_inverse=True)
    w = 0.5 * np.bincount(inv, weights=cot, minlength=len(keys))
    E = np.stack([keys // n, keys % n], 1)
    return E, np.maximum(w, min_weight)


class ARAP:
    r"""ARAP energy of control points relative to a rest mesh (Sorkine and Alexa 2007).

    Parameters
    ----------
    V_rest : (n, 3) float numpy array
        Rest (template) control points.
    F : (m, 3) int numpy array
        Control faces (manifold, consistently oriented; validated).
    min_weight : float
        Floor of the cotangent weights (see :func:`cotangent_weights`).

    Attributes
    ----------
    I, J : (2e,) int64 numpy arrays
        Directed one-ring edges ``i -> j``, both directions of every edge.
    w : (2e,) float64 numpy array
        ``w_ij`` of each directed edge.

    Notes
    -----
    .. math::
        E(V, R) = \sum_i \sum_{j \in N(i)} w_{ij}
            \| (V_i - V_j) - R_i (\bar V_i - \bar V_j) \|^2

    (thesis eq. 12 with ``R_i`` mapping rest to current edges). For fixed
    ``V`` the energy separates over vertices and ``R_i`` minimises
    ``sum_j w_ij |e'_ij - R e_ij|^2``, i.e. maximises ``tr(R S_i)`` with
    ``S_i = sum_j w_ij e_ij e'_ij^T``: from ``S_i = U Sigma W^T``,
    ``R_i = W diag(1, 1, det(W U^T)) U^T`` (Umeyama 1991; the sign flip on the
    smallest singular value turns a reflection into the best rotation). It is
    computed without the SVD, as Horn's unit quaternion (the same rotation,
    proper by construction; :class:`~mi_loop.energies.rotations.RotationSolver`).

    Why holding ``R`` fixed gives the exact gradient: with
    ``R*(V) = argmin_{R in SO(3)^n} E(V, R)``, the regulariser is
    ``E*(V) = E(V, R*(V))`` and by the chain rule
    ``dE*/dV = dE/dV|_R + <dE/dR, dR*/dV>``. ``dR*/dV`` is tangent to
    ``SO(3)`` and ``dE/dR`` vanishes along every tangent direction at a
    minimiser over ``SO(3)`` (first-order optimality), so the second term is
    zero (envelope theorem). This needs ``R*`` to be a unique, differentiable
    minimiser: it fails only where ``S_i`` is degenerate (e.g. a collapsed
    one-ring, or two smallest singular values equal after the sign flip).

    References
    ----------
    Sorkine, Alexa (2007), As-rigid-as-possible surface modeling; Umeyama
    (1991); Meyer, Desbrun, Schroeder, Barr (2003); Xie (2022), eq. 12-13.

    Examples
    --------
    >>> import numpy as np, drjit as dr, mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> from mi_loop.energies.arap import ARAP
    >>> from mi_loop.datasets import icosphere
    >>> V, F = icosphere(1)
    >>> arap = ARAP(V, F)
    >>> x = mi.Float((1.5 * V).astype(np.float32).ravel())   # scaled: not rigid
    >>> dr.enable_grad(x)
    >>> E = arap.energy(x, arap.rotations(1.5 * V))
    >>> dr.backward(E)
    >>> bool(E[0] > 0), dr.width(dr.grad(x)) == 3 * len(V)
    (True, True)
    """

    def __init__(self, V_rest, F, min_weight: float = 1e-3):
        V = check_points(V_rest, "ARAP", "rest vertices")
        if not (isinstance(min_weight, (int, float, np.number)) and np.isfinite(min_weight) and min_weight > 0):
            fail("ARAP", "a finite min_weight > 0", repr(min_weight))
        F = validate_faces(F, len(V), "ARAP")
        self.V_rest, self.F, self.n = V, F, len(V)
        E, w = cotangent_weights(V, F, min_weight)
        self.I = np.concatenate([E[:, 0], E[:, 1]])
        self.J = np.concatenate([E[:, 1], E[:, 0]])
        self.w = np.concatenate([w, w])
        self.e_rest = V[self.I] - V[self.J]  # (2e, 3) rest edges e_ij
        # S_i = sum_j w_ij e_ij e'_ij^T = sum_j w_ij e_ij (V_i - V_j)^T: one sparse (3n, n) product K V,
        # row 3 i + a holding w_ij e_ij[a] at column i and -w_ij e_ij[a] at column j
        we = (self.w[:, None] * self.e_rest).ravel()
        rows = (3 * self.I[:, None] + np.arange(3)).ravel()
        cols = np.r_[np.repeat(self.I, 3), np.repeat(self.J, 3)]
        self._K = sp.csr_matrix((np.r_[we, -we], (np.r_[rows, rows], cols)), shape=(3 * self.n, self.n))
        self._solve = RotationSolver()
        self._Id = IndexMap(self.I, self.n)
        self._Jd = IndexMap(self.J, self.n)
        self._wd = upload_float(self.w)

    def _numpy_points(self, V, func: str) -> np.ndarray:
        import mitsuba as mi

        if isinstance(V, ControlPoints):
            V = V.numpy()
        elif isinstance(V, mi.Point3f):
            V = np.array(V, dtype=np.float64).T
        elif isinstance(V, mi.Float):
            V = np.array(V, dtype=np.float64).reshape(-1, 3)
        V = np.asarray(V, dtype=np.float64)
        if V.shape != (self.n, 3):
            raise ValueError(f"ARAP.{func}(): expected ({self.n}, 3) control points, got shape {V.shape}")
        if not np.isfinite(V).all():
            bad = np.flatnonzero(~np.isfinite(V).all(1))
            raise ValueError(f"ARAP.{func}(): expected finite control points, got point {bad[0]} = "
                             f"{V[bad[0]].tolist()}")
        return V

    def rotations(self, V) -> np.ndarray:
        """Best rotations ``R_i`` for current control points (NumPy, closed form: :mod:`.rotations`).

        Parameters
        ----------
        V : (n, 3) float numpy array (or mi.Point3f / flat mi.Float, read without gradients)
            Current control points.

        Returns
        -------
        R : (n, 3, 3) float64 numpy array
            Proper rotations (``det = +1``); the identity where a vertex has no edges.
        """
        V = self._numpy_points(V, "rotations")
        return self._solve(self.covariances(V))

    def covariances(self, V) -> np.ndarray:
        """``S_i = sum_j w_ij e_ij e'_ij^T`` for current control points ``V`` ((n, 3) NumPy): (n, 3, 3)."""
        return (self._K @ V).reshape(self.n, 3, 3)

    def energy(self, x, R=None):
        """ARAP energy ``E(V, R)`` with the rotations held constant.

        Parameters
        ----------
        x : ControlPoints, mi.Float (3n, xyz interleaved) or mi.Point3f (n)
            Control points, possibly with gradients enabled; pass the
            :class:`~mi_loop.ad.control.ControlPoints` shared with the other
            terms of the energy.
        R : (n, 3, 3) float numpy array or None
            Rotations from :meth:`rotations`; ``None`` computes them from ``x``
            (one device-to-host copy).

        Returns
        -------
        mi.Float (1)
            Differentiable w.r.t. ``x``; the gradient with ``R = rotations(x)``
            is the exact gradient of ``min_R E`` (see the class Notes).
        """
        import drjit as dr
        import mitsuba as mi

        if isinstance(x, mi.Point3f):
            if dr.width(x) != self.n:
                raise ValueError(f"ARAP.energy(): expected {self.n} control points, got {dr.width(x)}")
            P = x
        else:
            x = ControlPoints.of(x, self.n, "ARAP.energy")
            P = x.points
        if R is None:
            R = self.rotations(x if not isinstance(x, mi.Point3f) else np.array(x, dtype=np.float64).T)
        R = np.asarray(R, dtype=np.float64)
        if R.shape != (self.n, 3, 3):
            raise ValueError(f"ARAP.energy(): expected R of shape ({self.n}, 3, 3), got {R.shape}")
        if not np.isfinite(R).all():
            raise ValueError("ARAP.energy(): expected finite rotations R (compute them with rotations()), "
                             "got non-finite entries")
        # rotated rest edges R_i e_ij: same size every iteration, so no recompilation
        Re = np.einsum("kab,kb->ka", R[self.I], self.e_rest)
        target = upload_vec(mi.Vector3f, Re)
        d = self._Id(P) - self._Jd(P) - target
        return dr.sum(self._wd * dr.squared_norm(d))
