"""IMLS distance to an oriented point cloud, and the fitting energy ``sum_j f(Q_j)^2``.

Neighbour search runs in NumPy/SciPy (``cKDTree``) whenever the samples have
moved enough to call :meth:`IMLS.update`; the evaluation of ``f`` runs in Dr.Jit
on fixed-width padded neighbour lists, so every iteration launches the same
kernels and reverse-mode AD gives ``dE/dQ``.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from mi_loop.ad.sparse import IndexMap
from mi_loop.ad.upload import to_numpy_points, upload_float, upload_uint, upload_vec
from mi_loop.errors import fail
from mi_loop.mesh.checks import check_oriented_points, check_points

__all__ = ["IMLS"]


class IMLS:
    r"""Implicit moving least-squares surface of oriented points (Oeztireli et al. 2009).

    Parameters
    ----------
    points : (N, 3) float numpy array
        Data points ``p_i``, in whatever units the caller uses (the thesis
        scales the cloud to the unit box first; that is the caller's job).
    normals : (N, 3) float numpy array
        Normals ``n_i``; normalised here. Zero-length normals are an error.
    h0 : float or None
        Starting support radius. ``None`` picks ``H0_FACTOR * median_i d_m(p_i)``
        where ``d_m(p_i)`` is the distance from ``p_i`` to its ``m``-th nearest
        other data point, ``m = min_neighbors``: on a uniformly sampled surface a
        ball of that radius holds about ``1.5^2 m`` points. Noisy data wants a
        larger ``h0`` (smoother ``f``), clean detailed data a smaller one.
    min_neighbors : int
        A sample's radius grows until at least this many points lie within it.
    max_neighbors : int
        ``K``, width of the padded neighbour lists (must be ``>= min_neighbors``).
    growth : float
        Factor by which a sample's radius grows (``> 1``).
    max_growths : int
        Largest number of growths, so ``h_j <= h0 * growth ** max_growths``.

    Notes
    -----
    The surface is the zero set of (thesis eq. 9-11)

    .. math::
        f(x) = \frac{\sum_i n_i^T (x - p_i)\, \phi_i(x)}{\sum_i \phi_i(x)}, \quad
        \phi_i(x) = (1 - |x - p_i|^2 / h^2)^4 \ (|x - p_i| < h), \quad
        E = \sum_j f(Q_j)^2.

    Radius rule, per sample ``Q_j`` (:meth:`update`): ``h_j = h0 * growth^g``
    with the smallest ``g in [0, max_growths]`` for which at least
    ``min_neighbors`` points lie strictly within ``h_j``. If more than ``K``
    points lie within ``h_j``, ``h_j`` shrinks to the distance of the
    ``(K+1)``-th nearest point, so no point with non-zero weight is ever
    dropped from a list (``f`` is the exact IMLS with radius ``h_j``). Because
    ``f`` is normalised by ``sum phi``, uneven density only changes ``h_j``, not
    the scale of ``f``. A sample far from all data gets the largest radius
    ``h0 * growth^max_growths`` (with the defaults, 1024 ``h0``), and is pulled
    towards whatever points that radius reaches; if it reaches none,
    ``f = 0`` there (no pull; counted in :attr:`n_isolated`).

    Outliers: IMLS is an average, not a robust estimator. A stray point within
    ``h_j`` of a sample on the surface shifts ``f`` by its share
    ``phi / sum phi`` of the weight, which is small when the surface around it
    is densely sampled (``h_j`` stays small and most weight goes to close
    points). Isolated outliers far from the surface are only reached by
    samples that are far away themselves. Dense clusters of outliers create a
    spurious surface: remove them before fitting.

    Gradients are taken with the neighbour lists and ``h_j`` held fixed
    between calls to :meth:`update`; the weight ``phi`` and its derivative
    vanish smoothly at ``r = h_j``, so ``f`` is C^3 in ``Q`` between updates.

    References
    ----------
    Oeztireli, Guennebaud, Gross (2009), Feature preserving point set surfaces
    based on non-linear kernel regression; Xie (2022), thesis eq. 9-11.

    Examples
    --------
    >>> import numpy as np, mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> from mi_loop.energies.imls import IMLS
    >>> g = np.linspace(-1, 1, 21)
    >>> P = np.stack(np.meshgrid(g, g, [0.0]), -1).reshape(-1, 3)   # the plane z = 0
    >>> imls = IMLS(P, np.tile([0.0, 0.0, 1.0], (len(P), 1)))
    >>> Q = np.array([[0.1, 0.2, 0.05], [-0.3, 0.0, -0.02]])
    >>> imls.update(Q)
    >>> f = imls.values(mi.Point3f(Q.T.astype(np.float32)))
    >>> np.allclose(np.array(f), [0.05, -0.02], atol=1e-6)
    True
    """

    #: Multiple of the median ``min_neighbors``-th neighbour distance used for ``h0=None``.
    H0_FACTOR = 1.5

    def __init__(self, points, normals, h0=None, min_neighbors: int = 12,
                 max_neighbors: int = 32, growth: float = 2.0, max_growths: int = 10):
        import mitsuba as mi

        P, N = check_oriented_points(points, normals, "IMLS")
        if int(min_neighbors) != min_neighbors or min_neighbors < 1:
            fail("IMLS", "a positive integer min_neighbors", min_neighbors)
        if int(max_neighbors) != max_neighbors or max_neighbors < min_neighbors:
            fail("IMLS", f"an integer max_neighbors >= min_neighbors = {min_neighbors}", max_neighbors)
        if len(P) < min_neighbors:
            fail("IMLS", f"at least min_neighbors = {min_neighbors} points", f"{len(P)}; "
                 "lower min_neighbors or give more points")
        if not (isinstance(growth, (int, float, np.number)) and np.isfinite(growth) and growth > 1):
            fail("IMLS", "a finite growth > 1", repr(growth))
        if int(max_growths) != max_growths or max_growths < 0:
            fail("IMLS", "a non-negative integer max_growths", max_growths)
        self.min_neighbors, self.max_neighbors = int(min_neighbors), int(max_neighbors)
        self.growth, self.max_growths = float(growth), int(max_growths)
        self.points, self.normals = P, N
        self.tree = cKDTree(P)
        if h0 is None:
            d, _ = self.tree.query(P, k=min(self.min_neighbors + 1, len(P)), workers=-1)
            h0 = self.H0_FACTOR * float(np.median(d[:, -1]))
            if not h0 > 0:
                fail("IMLS", "points that do not all coincide (h0 is chosen from their spacing)",
                     "coinciding points; pass h0 explicitly")
        if not (isinstance(h0, (int, float, np.number)) and np.isfinite(h0) and h0 > 0):
            fail("IMLS", "a finite h0 > 0 (or None for automatic)", repr(h0))
        self.h0 = float(h0)
        self._p = upload_vec(mi.Point3f, self.points)
        self._n = upload_vec(mi.Vector3f, self.normals)
        self.n_samples = None

    def update(self, Q, normals=None):
        """Recompute each sample's radius and neighbour list (NumPy/SciPy), upload them.

        Parameters
        ----------
        Q : (k, 3) float numpy array or mi.Point3f (k)
            Current sample positions (gradients, if any, are ignored).
        normals : (k, 3) float numpy array, optional
            The surface's normals at the samples. Given, a data point counts
            for a sample only if its normal is within 90 degrees of the
            sample's: the near side of a thin part does not pull the far side
            onto itself (partial scans, where the far side has no points).

        Notes
        -----
        Sets :attr:`radius` ``(k,)``, :attr:`neighbors` ``(k, K)`` int64 (padded
        with 0), :attr:`valid` ``(k, K)`` bool, :attr:`n_isolated`. Device arrays
        keep their sizes as long as ``k`` does, so kernels are reused.
        """
        import mitsuba as mi

        if isinstance(Q, mi.Point3f):
            Q = to_numpy_points(Q)
        Q = check_points(Q, "IMLS.update", "samples")
        K, m = self.max_neighbors, self.min_neighbors
        d, idx = self.tree.query(Q, k=K + 1, workers=-1)  # inf / len(P) where too few points
        d_m = d[:, m - 1]
        g = np.zeros(len(Q), dtype=np.int64)
        h = np.full(len(Q), self.h0)
        for _ in range(self.max_growths):  # smallest g with d_m < h0 * growth^g
            short = h <= d_m
            if not short.any():
                break
            g[short] += 1
            h[short] = self.h0 * self.growth ** g[short]
        shrink = (d[:, K] < h) & (d[:, K] > d_m)
        h[shrink] = d[shrink, K]
        valid = (d[:, :K] < h[:, None]) & (idx[:, :K] < len(self.points))
        if normals is not None:
            normals = check_points(normals, "IMLS.update", "sample normals")
            if len(normals) != len(Q):
                fail("IMLS.update", f"one normal per sample ({len(Q)})", f"{len(normals)}")
            facing = np.einsum("kjd,kd->kj", self.normals[np.minimum(idx[:, :K], len(self.points) - 1)], normals)
            valid &= facing > 0
        self.radius, self.growths = h, g
        self.neighbors, self.valid = np.where(valid, idx[:, :K], 0), valid
        self.n_isolated = int((~valid.any(1)).sum())
        self.n_samples = len(Q)
        self._idx = upload_uint(self.neighbors.ravel())
        self._mask = upload_float(valid.ravel())
        self._inv_h2 = upload_float(np.repeat(1.0 / h ** 2, K))
        self._rep = IndexMap(np.repeat(np.arange(len(Q)), K), len(Q))   # deterministic reverse pass

    def values(self, Q):
        """IMLS function ``f(Q_j)`` at every sample.

        Parameters
        ----------
        Q : mi.Point3f (k)
            Samples, same count as at the last :meth:`update`; may carry gradients.

        Returns
        -------
        mi.Float (k)
            ``f(Q_j)``, differentiable w.r.t. ``Q`` (lists and ``h_j`` held fixed).
        """
        import drjit as dr
        import mitsuba as mi

        if self.n_samples is None:
            raise ValueError("IMLS.values: call update(Q) first to build the neighbour lists")
        if not isinstance(Q, mi.Point3f):
            raise TypeError(f"IMLS.values: samples must be mi.Point3f, got {type(Q).__name__}")
        if dr.width(Q) != self.n_samples:
            raise ValueError(f"IMLS.values: expected {self.n_samples} samples (as at the last "
                             f"update), got {dr.width(Q)}; call update(Q) after resampling")
        K = self.max_neighbors
        x = self._rep(Q)                                  # sample of each slot (k K)
        p = dr.gather(mi.Point3f, self._p, self._idx)     # neighbour point
        nrm = dr.gather(mi.Vector3f, self._n, self._idx)  # neighbour normal
        d = x - p
        t = dr.maximum(1.0 - dr.squared_norm(d) * self._inv_h2, 0.0)
        phi = self._mask * dr.square(dr.square(t))        # (1 - r^2/h^2)^4, 0 outside h
        term = phi * dr.dot(nrm, d)
        dr.eval(phi, term)                                # one kernel for both sums
        num, den = dr.block_sum(term, K), dr.block_sum(phi, K)
        return dr.select(den > 0, num / dr.select(den > 0, den, 1.0), 0.0)

    def gradients(self, Q) -> np.ndarray:
        """``grad f(Q_j)`` at every sample (lists and radii of the last :meth:`update` held), ``(k, 3)`` NumPy.

        Parameters
        ----------
        Q : (k, 3) float NumPy array
            Samples, as many as at the last update.

        Returns
        -------
        (k, 3) float64 NumPy array
            Zero where a sample has no neighbour.
        """
        import drjit as dr
        import mitsuba as mi

        q = upload_vec(mi.Point3f, np.asarray(Q, dtype=np.float64))
        dr.enable_grad(q)
        dr.backward(dr.sum(self.values(q)))          # f_j depends on Q_j alone
        return np.array(dr.grad(q), dtype=np.float64).T

    def energy(self, Q, reduce: str = "sum"):
        """Fitting energy ``E = sum_j f(Q_j)^2`` (thesis eq. 11), or its mean over samples.

        Parameters
        ----------
        Q : mi.Point3f (k)
            Samples (see :meth:`values`).
        reduce : {'sum', 'mean'}
            ``'mean'`` divides by ``k``, so step sizes do not depend on the sample count.

        Returns
        -------
        mi.Float (1)
            Differentiable w.r.t. ``Q``.
        """
        import drjit as dr

        if reduce not in ("sum", "mean"):
            raise ValueError(f"IMLS.energy: reduce must be 'sum' or 'mean', got {reduce!r}")
        E = dr.sum(dr.square(self.values(Q)))
        return E / self.n_samples if reduce == "mean" else E
