"""The 12 quartic box-spline basis functions of a regular Loop patch.

Stam (1998), "Evaluation of Loop subdivision surfaces", appendix. With
barycentric ``(w_a, w_b, w_c) = (1 - u - v, u, v)`` of the patch triangle
``(a, b, c)``, basis ``i`` belongs to the lattice point ``LATTICE[i]`` in axial
coordinates where ``a = (0, 0)``, ``b = (1, 0)``, ``c = (0, 1)``.
"""
from __future__ import annotations

import numpy as np

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
    C = np.zeros((15, 12))
    for b, terms in enumerate(_TERMS):
        for mono, c in terms.items():
            C[_MONO.index(mono), b] = c / 12.0
    return C


_C = _coefficients()
_EXP = np.array(_MONO)


def _monomials(wa, wb, wc, d=(0, 0, 0)):
    """Derivative ``d`` (orders in wa, wb, wc) of every monomial, shape ``(k, 15)``."""
    out = np.empty((len(wa), 15))
    for m, (i, j, k) in enumerate(_MONO):
        coef = 1.0
        e = []
        for p, q in zip((i, j, k), d):
            for r in range(q):
                coef *= p - r
            e.append(p - q)
        if coef == 0 or min(e) < 0:
            out[:, m] = 0.0
        else:
            out[:, m] = coef * wa ** e[0] * wb ** e[1] * wc ** e[2]
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
    """
    u, v = uv[:, 0], uv[:, 1]
    wa = 1.0 - u - v
    if derivative is None:
        M = _monomials(wa, u, v)
    elif derivative == "u":
        M = _monomials(wa, u, v, (0, 1, 0)) - _monomials(wa, u, v, (1, 0, 0))
    elif derivative == "v":
        M = _monomials(wa, u, v, (0, 0, 1)) - _monomials(wa, u, v, (1, 0, 0))
    else:
        raise ValueError(f"box_basis(): derivative must be None, 'u' or 'v', got {derivative!r}")
    return M @ _C
