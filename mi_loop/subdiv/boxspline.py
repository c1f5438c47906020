"""The 12 quartic box-spline basis functions of a regular Loop patch.

Stam (1998), "Evaluation of Loop subdivision surfaces", appendix. With
barycentric ``(w_a, w_b, w_c) = (1 - u - v, u, v)`` of the patch triangle
``(a, b, c)``, basis ``i`` belongs to the lattice point ``LATTICE[i]`` in axial
coordinates where ``a = (0, 0)``, ``b = (1, 0)``, ``c = (0, 1)``.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail

__all__ = ["BLOCK", "COEFFICIENTS", "LATTICE", "PRODUCT_ROWS", "box_basis", "box_rows"]

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

#: Box-spline rows as monomials times these: ``(15, 12)`` for the value over the
#: quartic monomials ``wa^i wb^j wc^(4-i-j)`` (``i`` then ``j`` descending), ``(10, 12)``
#: for ``d/du`` and ``d/dv`` over the cubic ones, in the same order.
COEFFICIENTS = {None: _C, "u": _DU, "v": _DV}
#: Points per block of monomials in :func:`box_rows` (its temporaries stay in cache).
BLOCK = 4096
#: Rows per matrix product: small enough for BLAS (OpenBLAS below 2^18
#: multiply-adds) to run it on the calling thread, so these thin products
#: never wait for a thread pool to start or for its threads to be scheduled.
PRODUCT_ROWS = 1024


def _raise_degree(M: np.ndarray, d: int, wa, wb, wc) -> np.ndarray:
    """Monomials of degree ``d + 1`` from those of degree ``d`` (rows (monomial, point), order of :data:`_MONO`).

    Those with a factor ``wa`` come first, in the order of ``M``; then the
    ``d + 2`` without: the last ``d + 1`` rows of ``M`` times ``wb`` and the
    last row times ``wc``.
    """
    n = len(M)
    out = np.empty((n + d + 2, M.shape[1]))
    np.multiply(M, wa, out=out[:n])
    np.multiply(M[n - d - 1:], wb, out=out[n:n + d + 1])
    np.multiply(M[-1], wc, out=out[-1])
    return out


def box_rows(u: np.ndarray, v: np.ndarray, derivatives, width: int = 12, scale=None) -> dict:
    """Evaluate the 12 basis functions and their parametric derivatives into padded rows.

    Parameters
    ----------
    u, v : (k,) float64 numpy arrays
        Patch parameters.
    derivatives : iterable of None, 'u', 'v'
        Which rows: the value (None), ``d/du`` or ``d/dv``.
    width : int
        Columns of the returned arrays (>= 12); columns 12 and up are zero.
    scale : (k,) float64 numpy array, optional
        Factor of every derivative row (not of the value rows).

    Returns
    -------
    dict ``{derivative: (k, width) float64 numpy array}``

    Examples
    --------
    >>> B = box_rows(np.array([0.2]), np.array([0.3]), (None, "u"), width=13)
    >>> B[None].shape, round(float(B[None].sum()), 12), float(B["u"][0, 12])
    ((1, 13), 1.0, 0.0)
    """
    names = list(dict.fromkeys(derivatives))
    k = len(u)
    out = {d: (np.empty if width == 12 else np.zeros)((k, width)) for d in names}
    for a in range(0, k, BLOCK):
        b = min(k, a + BLOCK)
        wb, wc = u[a:b], v[a:b]
        wa = 1.0 - wb - wc
        M3 = _raise_degree(_raise_degree(np.stack([wa, wb, wc]), 1, wa, wb, wc), 2, wa, wb, wc)
        blocks = [(None, _raise_degree(M3, 3, wa, wb, wc))] if None in out else []
        if "u" in out or "v" in out:
            if scale is not None:
                M3 *= scale[a:b]
            blocks += [(d, M3) for d in ("u", "v") if d in out]
        for d, M in blocks:
            C, W = COEFFICIENTS[d], out[d]
            for r in range(0, b - a, PRODUCT_ROWS):
                e = min(b - a, r + PRODUCT_ROWS)
                np.matmul(M[:, r:e].T, C, out=W[a + r:a + e, :12])
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
    if derivative not in COEFFICIENTS:
        fail("box_basis", "derivative None, 'u' or 'v'", repr(derivative))
    uv = np.asarray(uv, dtype=np.float64)
    return box_rows(np.ascontiguousarray(uv[:, 0]), np.ascontiguousarray(uv[:, 1]), (derivative,))[derivative]
