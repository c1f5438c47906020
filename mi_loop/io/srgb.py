"""The sRGB transfer function (IEC 61966-2-1): 8-bit images and vertex colours are sRGB-encoded, renders linear."""
from __future__ import annotations

import numpy as np

__all__ = ["linear_to_srgb", "srgb_to_linear"]


def srgb_to_linear(c) -> np.ndarray:
    """Decode sRGB values in [0, 1] to linear ones (the exact piecewise curve).

    Parameters
    ----------
    c : float array-like
        Encoded values in [0, 1] (an 8-bit value ``b`` is ``b / 255``).

    Returns
    -------
    float32 NumPy array, same shape
        Linear values: ``c / 12.92`` up to 0.04045, ``((c + 0.055) / 1.055) ** 2.4`` above.

    Examples
    --------
    >>> [round(float(v), 6) for v in srgb_to_linear([0.0, 0.04045, 1.0])]
    [0.0, 0.003131, 1.0]
    """
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, np.power((np.maximum(c, 0.04045) + 0.055) / 1.055, 2.4)).astype(np.float32)


def linear_to_srgb(x) -> np.ndarray:
    """Encode linear values as sRGB in [0, 1] (clipped to [0, 1] first; NaN becomes 0).

    Parameters
    ----------
    x : float array-like
        Linear values (radiance or albedo).

    Returns
    -------
    float32 NumPy array, same shape
        ``12.92 x`` up to 0.0031308, ``1.055 x ** (1 / 2.4) - 0.055`` above.

    Examples
    --------
    >>> round(float(srgb_to_linear(linear_to_srgb(0.2))), 6)
    0.2
    """
    x = np.clip(np.nan_to_num(np.asarray(x, dtype=np.float64)), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)
