"""The 12 quartic box-spline basis functions of a regular Loop patch.

Stam (1998), "Evaluation of Loop subdivision surfaces", appendix. With
barycentric ``(w_a, w_b, w_c) = (1 - u - v, u, v)`` of the patch triangle
``(a, b, c)``, basis ``i`` belongs to the lattice point ``LATTICE[i]`` in axial
coordinates where ``a = (0, 0)``, ``b = (1, 0)``, ``c = (0, 1)``.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail

__all__ = ["LATTICE", "box_basis"]

#: Axial lattice coordinates of the 12 patch points (Stam's order 1..12).
LATTICE = np.array([(0, -1), (-1, 0), (1, -1), (0, 0), (-1, 1), (2, -1),
                    (1, 0), (0, 1), (-1, 2), (2, 0), (1, 1), (0, 2)])

# Monomials wa^i wb^j wc^k with i + j + k = 4; Stam's u, v, w = wa, wb, wc.
_MONO = [(i, j, 4 - i - j) for i in range(4, -1, -1) for j in range(4 - i, -1, -1)]
_TERMS = [  # basis -> {(i, j, k): coefficient * 12}
    {(4, 0, 0): 1, (3, 1, 0): 2},
    {(4, 0, 0): 1, (3, 0, 1): 2},
    {(4, 0, 0): 1, (3, 0, 1): 2, (3, 1, 0): 6, (2, 1, 1): 6, (2, 2, 0): 12, (1, 2, 1): 6,
     (1, 3, 0): 6, (0, 3, 1): 2, (0, 4, 0): 1},
    {(4, 0, 0): 6, (3, 0, 1): 24, (2, 0, 2): 24, (1, 0, 3): 8, (0, 0, 4): 1, (3, 1, 0): 24,
     (2, 1, 1): 60, (1, 1, 2): 36, (0, 1, 3): 6, (2, 2, 0): 24, (1, 2, 1): 36, (0, 2, 2): 12,
     (1, 3, 0): 8, (0, 3, 1): 6, (0, 4, 0): 1},
    {(4, 0, 0): 1, (3, 0, 1): 6, (2, 0, 2): 12, (1, 0, 3): 6, (0, 0, 4): 1, (3, 1, 0): 2,
     (2, 1, 1): 6, (1, 1, 2): 6, (0, 1, 3): 2},
    {(1, 3, 0): 2, (0, 4, 0): 1},
    {(4, 0, 0): 1, (3, 0, 1): 6, (2, 0, 2): 12, (1, 0, 3): 6, (0, 0, 4): 1, (3, 1, 0): 8,
     (2, 1, 1): 36, (1, 1, 2): 36, (0, 1, 3): 8, (2, 2, 0): 24, (1, 2, 1): 60, (0, 2, 2): 24,
     (1, 3, 0): 24, (0, 3, 1): 24, (0, 4, 0): 6},
    {(4, 0, 0): 1, (3, 0, 1): 8, (2, 0, 2): 24, (1, 0, 3): 24, (0, 0, 4): 6, (3, 1, 0): 6,
     (2, 1, 1): 36, (1, 1, 2): 60, (0, 1, 3): 24, (2, 2, 0): 12, (1, 2, 1): 36, (0, 2, 2): 24,
     (1, 3, 0): 6, (0, 3, 1): 8, (0, 4, 0): 1},
    {(1, 0, 3): 2, (0, 0, 4): 1},
    {(0, 3, 1): 2, (0, 4, 0): 1},
    {(1, 0, 3): 2, (0, 0, 4): 1, (1, 1, 2): 6, (0, 1, 3): 6, (1, 2, 1): 6, (0, 2, 2): 12,
     (1, 3, 0): 2, (0, 3, 1): 6, (0, 4, 0): 1},
    {(0, 0, 4): 1, (0, 1, 3): 2},
]


def _coefficients():
    """Quartic coefficients (15, 12) and d/du, d/dv over cubic monomials (10, 12)."""
    C = np.zeros((15, 12))
    for b, terms in enumerate(_TERMS):
        for mono, c in terms.items():
            C[_MONO.index(mono), b] = c / 12.0
    Du, Dv = np.zeros((10, 12)), np.zeros((10, 12))
    for m, (i, j, k) in enumerate(_MONO):
        # d/du = d/dwb - d/dwa, d/dv = d/dwc - d/dwa  (wa = 1 - u - v)
        if j:
            Du[_MONO3.index((i, j - 1, k))] += j * C[m]
        if k:
            Dv[_MONO3.index((i, j, k - 1))] += k * C[m]
        if i:
            Du[_MONO3.index((i - 1, j, k))] -= i * C[m]
            Dv[_MONO3.index((i - 1, j, k))] -= i * C[m]
    return C, Du, Dv


_MONO3 = [(i, j, 3 - i - j) for i in range(3, -1, -1) for j in range(3 - i, -1, -1)]
_C, _DU, _DV = _coefficients()


def _monomials(wa, wb, wc, degree):
    pa, pb, pc = [np.ones_like(wa)], [np.ones_like(wb)], [np.ones_like(wc)]
    for _ in range(degree):
        pa.append(pa[-1] * wa)
        pb.append(pb[-1] * wb)
        pc.append(pc[-1] * wc)
    monos = _MONO if degree == 4 else _MONO3
    out = np.empty((len(monos), len(wa)))
    for m, (i, j, k) in enumerate(monos):
        np.multiply(pa[i], pb[j], out=out[m])
        out[m] *= pc[k]
    return out


def box_basis(uv: np.ndarray, derivative: str | None = None) -> np.ndarray:
    """Evaluate the 12 basis functions or their parametric derivative.

    Parameters
    ----------
    uv : (k, 2) float64 numpy array
        Patch parameters ``(u, v)``.
    derivative : None, 'u' or 'v'
        Value, ``d/du`` or ``d/dv`` (with ``w_a = 1 - u - v`` held dependent).

    Returns
    -------
    (k, 12) float64 numpy array

    Raises
    ------
    ValueError
        For another ``derivative``.

    Examples
    --------
    >>> uv = np.array([[0.2, 0.3], [0.0, 0.0]])
    >>> np.round(box_basis(uv).sum(1), 12).tolist()      # a partition of unity
    [1.0, 1.0]
    >>> bool(np.abs(box_basis(uv, "u").sum(1)).max() < 1e-12)
    True
    """
    u, v = uv[:, 0], uv[:, 1]
    wa = 1.0 - u - v
    # Monomials are built row-major (monomial, point): much faster for large k.
    if derivative is None:
        return (_C.T @ _monomials(wa, u, v, 4)).T
    if derivative == "u":
        return (_DU.T @ _monomials(wa, u, v, 3)).T
    if derivative == "v":
        return (_DV.T @ _monomials(wa, u, v, 3)).T
    fail("box_basis", "derivative None, 'u' or 'v'", repr(derivative))
