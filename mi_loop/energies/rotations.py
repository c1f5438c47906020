"""Best rotations of many 3x3 cross-covariance matrices at once, in closed form (vectorised NumPy).

For ``S = sum_j w_j a_j b_j^T`` the rotation ``R`` maximising ``tr(R S)``
(the ``R`` that best maps the ``a_j`` onto the ``b_j``, as in ARAP's local
step) is found without an SVD, by Horn's quaternion method (Horn 1987) in the
form of Theobald's QCP algorithm (2005):

- ``R(q)`` of the unit quaternion ``q`` maximising ``q^T N q``, ``N`` the
  traceless symmetric 4x4 matrix built from ``S``, so ``R`` is proper by
  construction (no reflection to repair);
- the largest eigenvalue ``lambda`` of ``N`` is the largest root of its
  characteristic quartic ``l^4 + c2 l^2 + c1 l + c0``, with
  ``c2 = -2 |S|_F^2`` and ``c1 = -8 det S``; Newton's method from
  ``sqrt(3) |S|_F``, an upper bound, descends monotonically onto it;
- its eigenvector is the largest column of the adjugate of ``N - lambda I``.

Every step is an elementwise operation on arrays of length ``n``. Where the
best rotation is not unique (rank ``S`` <= 1, or the two smallest singular
values equal after the sign of ``det S``) the adjugate vanishes; those
matrices take the SVD route of :func:`svd_rotations`, whose answer is then
one of the optimal rotations.

:func:`best_rotations` is the one-off NumPy function; :class:`RotationSolver`
runs the same arithmetic as one float64 Dr.Jit LLVM kernel, traced once and
replayed (``dr.freeze``), with Newton's loop running per entry until that
entry converges. It is the one ARAP uses every iteration: one pass over the
``n`` entries instead of a NumPy temporary per arithmetic step, and Newton's
steps only where an entry has not converged yet (timings in BENCHMARKS.md,
section "ARAP rotations as one compiled kernel").

References
----------
Horn (1987), Closed-form solution of absolute orientation using unit
quaternions; Theobald (2005), Rapid calculation of RMSDs using a
quaternion-based characteristic polynomial; Umeyama (1991).
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail

__all__ = ["RotationSolver", "best_rotations", "svd_rotations"]


def svd_rotations(S) -> np.ndarray:
    """The best proper rotations by SVD: ``R = W diag(1, 1, det(W U^T)) U^T`` for ``S = U Sigma W^T``.

    Parameters
    ----------
    S : (n, 3, 3) float array

    Returns
    -------
    (n, 3, 3) float64 NumPy array
    """
    U, _, Wt = np.linalg.svd(np.asarray(S, dtype=np.float64))
    W = np.swapaxes(Wt, 1, 2)
    sign = np.where(np.linalg.det(W @ np.swapaxes(U, 1, 2)) < 0, -1.0, 1.0)
    W[:, :, 2] *= sign[:, None]
    return W @ np.swapaxes(U, 1, 2)


def _det3(a, b, c, d, e, f, g, h, i):
    """Determinant of ``[[a, b, c], [d, e, f], [g, h, i]]``, elementwise."""
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def best_rotations(S, *, tol: float = 1e-9) -> np.ndarray:
    """Return the proper rotations ``R_i`` maximising ``tr(R_i S_i)``, in closed form.

    Parameters
    ----------
    S : (n, 3, 3) float array
        Cross-covariances ``S_i = sum_j w_j a_j b_j^T``; ``R_i`` maps the
        ``a_j`` (rest) onto the ``b_j`` (current).
    tol : float, optional
        Matrices whose adjugate column is below ``tol`` (relative) are
        degenerate and go to :func:`svd_rotations`.

    Returns
    -------
    (n, 3, 3) float64 NumPy array
        Proper rotations; the identity where ``S_i = 0``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> S = rng.normal(size=(1000, 3, 3))
    >>> bool(np.abs(best_rotations(S) - svd_rotations(S)).max() < 1e-9)
    True
    >>> best_rotations(np.zeros((1, 3, 3)))[0].tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    S = _check_covariances(S, "best_rotations")
    n = len(S)
    norm = np.sqrt(np.einsum("kab,kab->k", S, S))
    zero = norm == 0
    S = S / np.where(zero, 1.0, norm)[:, None, None]             # |S|_F = 1: tolerances are relative
    xx, xy, xz, yx, yy, yz, zx, zy, zz = (np.ascontiguousarray(S[:, a, b]) for a in range(3) for b in range(3))
    # Horn's traceless symmetric N, as its ten distinct entries.
    d = [xx + yy + zz, xx - yy - zz, -xx + yy - zz, -xx - yy + zz]
    o = {(0, 1): yz - zy, (0, 2): zx - xz, (0, 3): xy - yx, (1, 2): xy + yx, (1, 3): zx + xz, (2, 3): yz + zy}
    # Characteristic quartic l^4 + c2 l^2 + c1 l + c0 of N (|S|_F = 1: c2 = -2).
    c1 = -8.0 * _det3(xx, xy, xz, yx, yy, yz, zx, zy, zz)
    c0 = _det4(_entries(d, o, 0.0))
    lam = np.full(n, np.sqrt(3.0))                                 # >= sigma1 + sigma2 + sigma3
    for _ in range(60):           # Newton from above: monotone, about 6 steps for ARAP's S, 12 for random ones
        l2 = lam * lam
        df = (4.0 * l2 - 4.0) * lam + c1
        step = (((l2 - 2.0) * l2 + c1 * lam) + c0) / np.where(df > 0, df, np.inf)
        lam -= step
        if np.abs(step).max() < 1e-13:                             # then it oscillates at round-off
            break
    # Adjugate of A = N - lam I: every column is parallel to the eigenvector q, column j as |q_j|.
    C = _cofactors(_entries(d, o, lam))
    best = np.argmax(np.abs(np.stack([C[j][j] for j in range(4)])), axis=0)   # C_jj = -|...| q_j^2
    q = [np.choose(best, [C[j][i] for j in range(4)]) for i in range(4)]
    qn = np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    degenerate = ~zero & (qn < tol)
    w, x, y, z = (c / np.where(qn > 0, qn, 1.0) for c in q)
    R = np.empty((n, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = 2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z
    R[zero] = np.eye(3)
    if degenerate.any():
        R[degenerate] = svd_rotations(S[degenerate])
    return R


def _check_covariances(S, func: str) -> np.ndarray:
    S = np.asarray(S, dtype=np.float64)
    if S.ndim != 3 or S.shape[1:] != (3, 3):
        raise ValueError(f"{func}(): expected S of shape (n, 3, 3), got {S.shape}")
    return S


class RotationSolver:
    """Best rotations as one compiled Dr.Jit kernel: :func:`best_rotations` without its NumPy passes.

    Parameters
    ----------
    tol : float, optional
        As in :func:`best_rotations`.

    Notes
    -----
    The kernel (LLVM backend, float64, whatever Mitsuba variant is set) is
    traced on the first call and replayed by ``dr.freeze`` afterwards, also
    for other ``n``; the recording belongs to this object. Newton's loop is a
    symbolic ``dr.while_loop`` that stops per entry once its step falls below
    ``1e-13``. Degenerate entries take the SVD on the host, as in
    :func:`best_rotations`. Without an LLVM backend the solver calls
    :func:`best_rotations`.

    Examples
    --------
    >>> solve = RotationSolver()
    >>> S = np.random.default_rng(0).normal(size=(1000, 3, 3))
    >>> bool(np.abs(solve(S) - svd_rotations(S)).max() < 1e-9)
    True
    """

    def __init__(self, *, tol: float = 1e-9):
        import drjit as dr

        if not (isinstance(tol, (int, float, np.number)) and np.isfinite(tol) and tol > 0):
            fail("RotationSolver", "a finite tol > 0", repr(tol))
        self.tol = float(tol)
        self._kernel = dr.freeze(_kernel_for(self.tol)) if dr.has_backend(dr.JitBackend.LLVM) else None

    def __call__(self, S) -> np.ndarray:
        """Return the proper rotations ``R_i`` maximising ``tr(R_i S_i)``.

        Parameters
        ----------
        S : (n, 3, 3) float array

        Returns
        -------
        (n, 3, 3) float64 NumPy array
            As :func:`best_rotations` (the same to about 1e-13).
        """
        S = _check_covariances(S, "RotationSolver")
        if self._kernel is None:
            return best_rotations(S, tol=self.tol)
        from drjit.llvm import Float64

        from mi_loop.ad.upload import aligned

        n = len(S)
        T = S.reshape(n, 9).T                          # rows in 64-byte aligned buffers: one recording
        rows, degenerate = self._kernel([Float64(aligned(t, np.float64)) for t in T])
        R = np.empty((n, 9))
        for k in range(9):
            R[:, k] = rows[k].numpy()
        R = R.reshape(n, 3, 3)
        degenerate = degenerate.numpy()
        if degenerate.any():
            R[degenerate] = svd_rotations(S[degenerate])
        return R


def _kernel_for(tol: float):
    """The traced function of :class:`RotationSolver`: nine ``Float64`` rows of ``S`` to nine of ``R``."""
    def kernel(s):
        import drjit as dr
        from drjit.llvm import Bool, UInt32

        norm = dr.sqrt(sum(v * v for v in s))
        zero = norm == 0
        s = [v * dr.select(zero, 0.0, dr.rcp(norm)) for v in s]          # |S|_F = 1
        xx, xy, xz, yx, yy, yz, zx, zy, zz = s
        d = [xx + yy + zz, xx - yy - zz, -xx + yy - zz, -xx - yy + zz]
        o = {(0, 1): yz - zy, (0, 2): zx - xz, (0, 3): xy - yx, (1, 2): xy + yx, (1, 3): zx + xz, (2, 3): yz + zy}
        c1 = -8.0 * _det3(*s)
        c0 = _det4(_entries(d, o, 0.0))

        def step(lam, it, moving):
            l2 = lam * lam
            df = (4.0 * l2 - 4.0) * lam + c1
            delta = dr.select(df > 0, (((l2 - 2.0) * l2 + c1 * lam) + c0) / df, 0.0)
            return lam - delta, it + 1, dr.abs(delta) >= 1e-13

        # loop state: lam (Newton's iterate, from the upper bound sqrt(3)), it (steps taken), moving (not converged)
        lam, _, _ = dr.while_loop((0.0 * norm + np.sqrt(3.0), UInt32(0), Bool(True)),
                                  lambda lam, it, moving: moving & (it < 60), step)
        C = _cofactors(_entries(d, o, lam))
        q, best = list(C[0]), dr.abs(C[0][0])
        for j in (1, 2, 3):
            better = dr.abs(C[j][j]) > best
            best = dr.select(better, dr.abs(C[j][j]), best)
            q = [dr.select(better, C[j][i], q[i]) for i in range(4)]
        qn2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
        w, x, y, z = (c * dr.select(qn2 > 0, dr.rsqrt(qn2), 0.0) for c in q)
        R = [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y),
             2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x),
             2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]
        R = [dr.select(zero, 1.0 if k % 4 == 0 else 0.0, r) for k, r in enumerate(R)]
        return R, ~zero & (qn2 < tol * tol)
    return kernel


def _entries(d, o, lam):
    """The 4x4 symmetric ``N - lam I`` as a nested list of arrays."""
    return [[d[i] - lam if i == j else o[(min(i, j), max(i, j))] for j in range(4)] for i in range(4)]


_PAIRS = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]


def _minors2(A, r0, r1):
    """The six 2x2 minors of rows ``r0, r1`` of ``A``, keyed by column pair."""
    return {(a, b): A[r0][a] * A[r1][b] - A[r0][b] * A[r1][a] for a, b in _PAIRS}


def _det4(A):
    """Determinant of a 4x4 (nested list of arrays), by Laplace expansion over the first two rows."""
    top, bottom = _minors2(A, 0, 1), _minors2(A, 2, 3)
    return (top[(0, 1)] * bottom[(2, 3)] - top[(0, 2)] * bottom[(1, 3)] + top[(0, 3)] * bottom[(1, 2)]
            + top[(1, 2)] * bottom[(0, 3)] - top[(1, 3)] * bottom[(0, 2)] + top[(2, 3)] * bottom[(0, 1)])


def _cofactors(A):
    """Cofactors ``C[j][i]`` of a symmetric 4x4 ``A`` (column j of its adjugate), sharing the 2x2 minors."""
    low, high = _minors2(A, 2, 3), _minors2(A, 0, 1)     # for deleted rows 0, 1 and rows 2, 3
    C = [[None] * 4 for _ in range(4)]
    for i in range(4):                                  # the deleted row
        keep = [r for r in range(4) if r != i]
        first, minors = (keep[0], low) if i < 2 else (keep[2], high)   # the row expanded, the other two's minors
        for j in range(4):                              # the deleted column
            cols = [c for c in range(4) if c != j]
            a, b, c = cols
            det = A[first][a] * minors[(b, c)] - A[first][b] * minors[(a, c)] + A[first][c] * minors[(a, b)]
            C[j][i] = det if (i + j) % 2 == 0 else -det
    return C
