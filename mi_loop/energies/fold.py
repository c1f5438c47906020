"""Fold barrier on limit normals: a penalty on normals turned away from reference normals.

A fold (the limit surface turned over on itself) can lie on the data: the
distance terms (:mod:`.imls`, :mod:`.coverage`) measure positions only, so an
inside-out strip costs them nothing. The barrier

    E_fold = mean_j max(0, c |r_j| - n_j . r_j)^2,   c = cos 60 deg = 1/2,

``n_j`` the unit limit normal at sample ``j`` and ``r_j`` a reference normal
there, is zero while every normal stays within 60 degrees of its reference
(sharp features of the data and ordinary fitting stay free) and grows
quadratically as a normal turns over. The sequence fit takes as ``r_j`` the
previous frame's unit limit normals. The static fit takes the mean of the
normals of the data points nearest to the sample (:func:`nearest_data_normals`):
where they disagree (a thin part the control mesh cannot resolve, whose two
sides are equally near) the mean is short and the barrier weak, so it does not
push the surface to one side of a part it cannot follow.
"""
from __future__ import annotations

import numpy as np

__all__ = ["FOLD_COSINE", "fold_energy", "nearest_data_normals"]

#: Normals within this cosine of their reference (60 degrees) cost nothing.
FOLD_COSINE = 0.5


def fold_energy(normals, reference, cosine: float = FOLD_COSINE):
    """Return the fold barrier ``mean_j max(0, cosine |r_j| - n_j . r_j)^2``.

    Parameters
    ----------
    normals : mi.Normal3f (k), possibly with gradients
        Unit limit normals at the samples (e.g. ``LimitOperator.normals``).
    reference : mi.Normal3f (k)
        Reference normals of length at most 1 (unit: the plain angle test),
        held constant.
    cosine : float, optional
        Cosine of the free angle (default 60 degrees).

    Returns
    -------
    mi.Float (1)
        Differentiable with respect to ``normals``.

    Examples
    --------
    >>> import mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> up = mi.Normal3f([0, 0, 0], [0, 0, 0], [1, 1, 1])
    >>> print(fold_energy(mi.Normal3f([0, 0, 0], [0, 0, 0], [1, -1, 1]), up))   # (1.5^2 + 0 + 0) / 3
    [0.75]
    """
    import drjit as dr

    turned = dr.maximum(cosine * dr.norm(reference) - dr.dot(normals, reference), 0.0)
    return dr.mean(dr.square(turned))


def nearest_data_normals(tree, data_normals, Q, k: int = 1) -> np.ndarray:
    """The mean normal of the ``k`` data points nearest to each sample: the static fit's reference normals.

    Parameters
    ----------
    tree : scipy.spatial.cKDTree
        Of the data points (e.g. ``IMLS.tree``).
    data_normals : (N, 3) float NumPy array
        Unit data normals, in the tree's order.
    Q : (s, 3) float NumPy array
        Samples (limit points).
    k : int, optional
        Data points per sample; their normals are averaged, not renormalised.

    Returns
    -------
    (s, 3) float64 NumPy array
        Of length 1 where the ``k`` normals agree, shorter where they do not.

    Examples
    --------
    >>> from scipy.spatial import cKDTree
    >>> P = np.array([[0.0, 0, 0.1], [0, 0, -0.1], [5, 0, 0]]); N = np.array([[0.0, 0, 1], [0, 0, -1], [1, 0, 0]])
    >>> nearest_data_normals(cKDTree(P), N, [[0.0, 0, 0.05], [0, 0, 0]], k=2).round(3).tolist()
    [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    >>> nearest_data_normals(cKDTree(P), N, [[0.0, 0, 0.05]]).tolist()
    [[0.0, 0.0, 1.0]]
    """
    _, idx = tree.query(np.asarray(Q, dtype=np.float64), k=k)
    N = np.asarray(data_normals, dtype=np.float64)[idx]
    return N if k == 1 else N.mean(1)
