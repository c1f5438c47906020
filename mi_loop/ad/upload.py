"""NumPy to Dr.Jit and back, without recompiling kernels.

Arrays uploaded every iteration (IMLS neighbour lists, ARAP targets) must keep
one kernel: the LLVM backend reads NumPy memory in place and writes its
alignment into the kernel, so ordinary NumPy buffers sporadically change the
kernel hash and recompile. :func:`aligned` copies into a 64-byte aligned buffer.
"""
from __future__ import annotations

import numpy as np

__all__ = ["aligned", "to_numpy_points", "upload_float", "upload_uint", "upload_vec"]


def aligned(a, dtype) -> np.ndarray:
    """Contiguous copy of ``a`` in a 64-byte aligned buffer, for upload to Dr.Jit.

    Parameters
    ----------
    a : array_like
    dtype : numpy dtype

    Returns
    -------
    numpy array
        Same shape and values as ``a``, ``dtype``, data pointer a multiple of 64.

    Examples
    --------
    >>> b = aligned(np.arange(5), np.float32)
    >>> b.ctypes.data % 64, b.tolist()
    (0, [0.0, 1.0, 2.0, 3.0, 4.0])
    """
    a = np.ascontiguousarray(a, dtype=dtype)
    buf = np.empty(a.nbytes + 64, dtype=np.uint8)
    start = -buf.ctypes.data % 64
    out = buf[start:start + a.nbytes].view(dtype).reshape(a.shape)
    out[...] = a
    return out


def upload_float(a):
    """Flat ``mi.Float`` of ``a`` (any shape, raveled), from an aligned float32 buffer.

    Parameters
    ----------
    a : float array_like
        Values, any shape.

    Returns
    -------
    mi.Float (a.size)
    """
    import mitsuba as mi

    return mi.Float(aligned(np.ravel(a), np.float32))


def upload_uint(a):
    """Flat ``mi.UInt32`` of ``a`` (any shape, raveled), from an aligned buffer.

    Parameters
    ----------
    a : non-negative int array_like
        Indices, any shape, below 2**32.

    Returns
    -------
    mi.UInt32 (a.size)
    """
    import mitsuba as mi

    return mi.UInt32(aligned(np.ravel(a), np.uint32))


def upload_vec(cls, A):
    """``cls`` (``mi.Point3f``, ``mi.Vector3f``, ``mi.Normal3f``) from a ``(k, 3)`` float array.

    Parameters
    ----------
    cls : type
        A three-component Dr.Jit array type of the current variant.
    A : (k, 3) float array_like
        One row per element.

    Returns
    -------
    cls (k)
    """
    import mitsuba as mi

    A = np.asarray(A)
    return cls(*(mi.Float(aligned(A[:, c], np.float32)) for c in range(3)))


def to_numpy_points(x) -> np.ndarray:
    """``(k, 3)`` float64 NumPy copy of a ``mi.Point3f``/``mi.Vector3f`` (or a flat xyz ``mi.Float``).

    Parameters
    ----------
    x : mi.Point3f (k), mi.Vector3f (k) or mi.Float (3k)
        Device array; gradients are not copied.

    Returns
    -------
    (k, 3) float64 numpy array
    """
    import mitsuba as mi

    if isinstance(x, mi.Float):
        return np.array(x, dtype=np.float64).reshape(-1, 3)
    return np.array(x, dtype=np.float64).T
