"""Coverage energy: every data point pulls its nearest limit sample towards it.

The IMLS energy (:mod:`mi_loop.energies.imls`) measures the surface's distance to the
data, one-sided: a part of the data that no sample is near (an ear tip, the end
of a thin leg) costs nothing, so the fit can leave it uncovered. The coverage
term is the other direction, an ICP-style point-to-plane energy

    E_cover = mean_i ( n_i . (Q_{j(i)} - p_i) )^2,

``j(i)`` the limit sample nearest to data point ``p_i`` (found with a k-d tree
in :meth:`Coverage.update`, held fixed in between) and ``n_i`` the data
normal. Measuring along the data normal leaves samples free to slide along the
surface, so the term does not bunch them up where data points are dense.

Isolated data points are left out: a point whose ``m``-th nearest other data
point (``m = 8``) is more than ``isolation`` times farther than that of the
median point is an outlier (a stray point in the air), not a part of the
surface to cover, and the term would drag the surface to it.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from mi_loop.ad.sparse import IndexMap
from mi_loop.ad.upload import upload_float, upload_vec
from mi_loop.mesh.checks import check_oriented_points, check_points

__all__ = ["Coverage"]


class Coverage:
    """Point-to-plane energy from data points to their nearest samples.

    Parameters
    ----------
    points : (N, 3) float NumPy array
        Data points ``p_i``.
    normals : (N, 3) float NumPy array
        Data normals ``n_i``, any non-zero length (normalised here).
    isolation : float
        Points whose 8th-nearest-neighbour distance exceeds this multiple
        of the median one get weight 0 (see the module notes).
    tree : scipy.spatial.cKDTree, optional
        A k-d tree of the same points to reuse (``IMLS.tree`` when both terms
        are built on one point set); built here otherwise.

    Examples
    --------
    A unit square of data points and a sample set shifted by 0.1 along the normal:

    >>> import mitsuba as mi, numpy as np
    >>> _ = mi.set_variant("llvm_ad_rgb")
    >>> g = np.linspace(0, 1, 5)
    >>> P = np.array([(x, y, 0.0) for x in g for y in g])
    >>> cover = Coverage(P, np.tile([0.0, 0.0, 1.0], (len(P), 1)))
    >>> Q = P[::2] + [0.0, 0.0, 0.1]
    >>> cover.update(Q)
    >>> round(float(cover.energy(mi.Point3f(*Q.T.astype(np.float32)))[0]), 6)
    0.01
    """

    def __init__(self, points, normals, isolation: float = 3.0, tree=None):
        import mitsuba as mi

        P, N = check_oriented_points(points, normals, "Coverage")
        if not isolation > 1:
            raise ValueError(f"Coverage: isolation must be a number > 1, got {isolation!r}")
        if tree is not None and not (tree.n == len(P) and np.array_equal(tree.data, P)):
            raise ValueError("Coverage: tree must be a k-d tree of these points (e.g. IMLS(points, ...).tree)")
        self.points, self.normals = P, N
        self.weight = _not_isolated(P, isolation, tree).astype(np.float64)
        self._w = upload_float(self.weight / self.weight.sum())
        self._p = upload_vec(mi.Point3f, self.points)
        self._n = upload_vec(mi.Vector3f, self.normals)
        self.nearest = None

    def update(self, Q, normals=None):
        """Find each data point's nearest sample (NumPy/SciPy) and upload the indices.

        Parameters
        ----------
        Q : (k, 3) float NumPy array
            Current sample positions.
        normals : (k, 3) float NumPy array, optional
            The surface's normals at the samples. Given, a data point takes the
            nearest of its 8 nearest samples whose normal is within 90 degrees
            of its own (the nearest one when none is): a point on the near
            side of a thin part does not pull the far side.

        Notes
        -----
        Sets :attr:`nearest` ``(N,)``, the sample index of every data point.
        """

        Q = check_points(Q, "Coverage.update", "samples")
        if normals is None:
            self.nearest = cKDTree(Q).query(self.points, workers=-1)[1]
        else:
            k = min(8, len(Q))
            idx = cKDTree(Q).query(self.points, k=k, workers=-1)[1].reshape(len(self.points), k)
            facing = np.einsum("ijd,id->ij", np.asarray(normals, dtype=np.float64)[idx], self.normals) > 0
            first = np.where(facing.any(1), facing.argmax(1), 0)
            self.nearest = idx[np.arange(len(idx)), first]
        self.n_samples = len(Q)
        self._idx = IndexMap(self.nearest, len(Q))   # deterministic reverse pass

    def energy(self, Q):
        """``mean_i (n_i . (Q_{j(i)} - p_i))^2`` over the kept points, ``mi.Float (1)``, differentiable."""
        import drjit as dr

        if self.nearest is None:
            raise ValueError("Coverage.energy: call update(Q) first to find the nearest samples")
        if dr.width(Q) != self.n_samples:
            raise ValueError(f"Coverage.energy: expected {self.n_samples} samples (as at the last "
                             f"update), got {dr.width(Q)}")
        q = self._idx(Q)
        return dr.sum(self._w * dr.square(dr.dot(self._n, q - self._p)))


def _not_isolated(P, isolation: float, tree=None, m: int = 8):
    """Mask of points whose ``m``-th nearest other point lies within ``isolation`` x the median's."""
    if len(P) <= m:
        return np.ones(len(P), dtype=bool)
    d = (cKDTree(P) if tree is None else tree).query(P, k=m + 1, workers=-1)[0][:, m]
    return d <= isolation * np.median(d)
