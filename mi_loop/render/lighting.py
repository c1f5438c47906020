"""Lighting the photos do not state: low-order spherical harmonics and a gain per photo, estimated.

A diffuse surface under distant lighting ``L(w)`` sends ``albedo / pi * E(n)``
towards every camera, ``E(n)`` the irradiance at its normal. ``E`` of any
environment is, to within a few percent, a quadratic in ``n``: its spherical
harmonics of bands 0-2 (nine per channel) carry all but ~1 % of it
(Ramamoorthi and Hanrahan 2001, "An efficient representation for irradiance
environment maps"). :class:`Lighting` holds those nine *shading* coefficients
per channel,

``s(n) = max(0, sum_j s_j Y_j(n))``,  ``radiance = g_k * albedo * s(n)``

(``Y_j`` the real spherical harmonics of :func:`sh_basis`, ``s_j = A_l L_lm / pi``
with ``L_lm`` the environment's coefficients and ``A_l = pi, 2 pi / 3, pi / 4``),
and per photo ``k`` a gain ``g_k`` (RGB): exposure and white balance. The gains
are stored as logarithms and used relative to their mean over the photos, so
that their product is 1 and the overall level stays with the lighting and the
albedo.

:class:`~mi_loop.render.images.ImageRenderer` renders this model through
Mitsuba: the radiance at each vertex of the tessellated limit surface (its
exact limit normal, the limit of the albedo field) is the shape's emission
(:func:`mi_loop.render.plugin.create` with ``radiance=``), seen through the
projective integrator (silhouettes) at path depth 1, so the gradients of the
render reach the control points (through the normals and the silhouettes), the
albedo, the coefficients and the gains in one reverse pass. Shadows and
interreflections are left out, as in every spherical-harmonic lighting model.

References
----------
R. Ramamoorthi, P. Hanrahan. An efficient representation for irradiance
environment maps. SIGGRAPH 2001.
"""
from __future__ import annotations

import functools

import numpy as np

from mi_loop.errors import fail

__all__ = ["BAND_FACTORS", "N_COEFFS", "Lighting", "sh_basis", "sh_gradient"]

#: Coefficients per channel: bands 0, 1, 2.
N_COEFFS = 9
#: ``A_l`` of the cosine lobe per coefficient (Ramamoorthi and Hanrahan): ``E_lm = A_l L_lm``.
BAND_FACTORS = np.array([np.pi] + [2 * np.pi / 3] * 3 + [np.pi / 4] * 5)
_Y00 = float(0.5 * np.sqrt(1 / np.pi))
# Python floats: a NumPy float64 times a Dr.Jit Float is a Float64
_C1, _C2, _C3 = (float(v) for v in (0.5 * np.sqrt(3 / np.pi), 0.5 * np.sqrt(15 / np.pi),
                                     0.25 * np.sqrt(5 / np.pi)))


def sh_basis(n):
    """Return the nine real spherical harmonics of bands 0-2 at unit vectors.

    Parameters
    ----------
    n : (k, 3) float NumPy array, or a Dr.Jit 3-vector of width k
        Unit directions.

    Returns
    -------
    (k, 9) float64 NumPy array, or list of 9 Dr.Jit Float
        ``Y_00; Y_1-1, Y_10, Y_11; Y_2-2, Y_2-1, Y_20, Y_21, Y_22``, in the
        order of :data:`BAND_FACTORS` (orthonormal on the sphere).

    Examples
    --------
    >>> Y = sh_basis(np.array([[0.0, 0.0, 1.0]]))
    >>> (np.round(Y, 4) + 0.0).tolist()
    [[0.2821, 0.0, 0.4886, 0.0, 0.0, 0.0, 0.6308, 0.0, 0.0]]
    """
    if isinstance(n, np.ndarray):
        x, y, z = (np.asarray(n, dtype=np.float64)[:, i] for i in range(3))
        one = np.ones_like(x)
    else:
        x, y, z = n.x, n.y, n.z
        one = 0.0 * x + 1.0
    c1, c2, c3 = _C1, _C2, _C3
    Y = [_Y00 * one, c1 * y, c1 * z, c1 * x, c2 * x * y, c2 * y * z, c3 * (3 * z * z - 1), c2 * x * z,
         0.5 * c2 * (x * x - y * y)]
    return np.stack(Y, axis=1) if isinstance(n, np.ndarray) else Y


class Lighting:
    """Spherical-harmonic shading and per-photo gains (module docstring).

    Parameters
    ----------
    n_views : int
        Photos, each with its own gain, >= 1.
    coefficients : (9, 3) float array-like, optional
        Shading coefficients ``s_j`` per RGB channel (default: uniform shading
        of ``level``, the look of a white constant environment of radiance
        ``level`` on a diffuse surface without occlusion).
    level : float, optional
        The uniform shading when no coefficients are given, > 0.

    Attributes
    ----------
    coefficients : mi.Float (27)
        ``s_j`` interleaved by channel (row-major (9, 3)); may carry gradients.
    log_gain : mi.Float (3 n_views)
        Log of each photo's RGB gain before centring; may carry gradients.

    Raises
    ------
    ValueError
        ``n_views < 1``, coefficients not of shape (9, 3) or not finite,
        ``level <= 0``.
    """

    def __init__(self, n_views: int, coefficients=None, *, level: float = 1.0):
        import mitsuba as mi

        if isinstance(n_views, bool) or not isinstance(n_views, (int, np.integer)) or n_views < 1:
            fail("Lighting", "n_views, an integer >= 1", repr(n_views))
        if coefficients is None:
            if not np.isfinite(level) or level <= 0:
                fail("Lighting", "a uniform level > 0", level)
            coefficients = np.zeros((N_COEFFS, 3))
            coefficients[0] = level / _Y00
        S = np.asarray(coefficients, dtype=np.float64)
        if S.shape != (N_COEFFS, 3) or not np.isfinite(S).all():
            fail("Lighting", f"finite coefficients of shape ({N_COEFFS}, 3)", f"shape {S.shape}")
        self.n_views = int(n_views)
        self.coefficients = mi.Float(S.astype(np.float32).ravel())
        self.log_gain = mi.Float(np.zeros(3 * self.n_views, dtype=np.float32))

    def gain(self, view: int):
        """Photo ``view``'s RGB gain ``exp(l_view - mean_k l_k)``: ``mi.Color3f`` of width 1, differentiable."""
        import drjit as dr
        import mitsuba as mi

        every = dr.arange(mi.UInt32, self.n_views) * 3
        first = dr.opaque(mi.UInt32, 3 * int(view))          # one kernel for every view, not one per view
        return mi.Color3f(*(dr.exp(dr.gather(mi.Float, self.log_gain, first + c)
                                   - dr.sum(dr.gather(mi.Float, self.log_gain, every + c)) / self.n_views)
                            for c in range(3)))

    def shading(self, normals):
        """``s(n)`` per channel at unit normals: ``mi.Color3f`` of their width (no gradients)."""
        import drjit as dr

        return _shade(dr.detach(self.coefficients), sh_basis(dr.detach(normals)))[0]

    def radiance(self, albedo, normals, view: int | None):
        """``g_view * albedo * s(n)``: the radiance towards camera ``view`` (no gain if None); ``mi.Color3f``.

        Differentiable with respect to ``albedo``, ``normals``, :attr:`coefficients`
        and :attr:`log_gain` (a custom reverse pass, :func:`_radiance_op`: the
        27 coefficients' gradients are sums over every vertex, done in one pass
        rather than one reduction per coefficient).
        """
        import drjit as dr
        import mitsuba as mi

        gain = mi.Color3f(1.0) if view is None else self.gain(view)
        return dr.custom(_radiance_op(), mi.Color3f(albedo), mi.Vector3f(normals), self.coefficients, gain)

    def numpy(self) -> dict:
        """The estimate as NumPy: ``coefficients`` (9, 3), ``gains`` (n_views, 3) float64."""
        import drjit as dr

        log_gain = np.array(dr.detach(self.log_gain), dtype=np.float64).reshape(self.n_views, 3)
        return {"coefficients": np.array(dr.detach(self.coefficients), dtype=np.float64).reshape(N_COEFFS, 3),
                "gains": np.exp(log_gain - log_gain.mean(axis=0))}

    def shade(self, albedo, normals, view: int | None = None) -> np.ndarray:
        """NumPy twin of :meth:`radiance`: ``(k, 3)`` float64 radiance for ``(k, 3)`` albedo and unit normals."""
        est = self.numpy()
        L = np.asarray(albedo, float) * np.maximum(sh_basis(np.asarray(normals, float)) @ est["coefficients"], 0.0)
        return L if view is None else L * est["gains"][int(view)]

    def environment(self) -> np.ndarray:
        """The environment's own coefficients ``L_lm = pi s_lm / A_l``: (9, 3) float64 (to draw the light)."""
        return np.pi * self.numpy()["coefficients"] / BAND_FACTORS[:, None]


def sh_gradient(n) -> list:
    """Return the gradients of :func:`sh_basis` with respect to the direction.

    Parameters
    ----------
    n : Dr.Jit 3-vector of width k
        Directions (the gradient of the polynomials, not projected onto the sphere).

    Returns
    -------
    list of 9 mi.Vector3f
        ``d Y_j / d n`` in the order of :func:`sh_basis`.
    """
    import mitsuba as mi

    x, y, z = n.x, n.y, n.z
    c1, c2, c3 = _C1, _C2, _C3
    zero = 0.0 * x
    return [mi.Vector3f(zero, zero, zero), mi.Vector3f(zero, c1 + zero, zero), mi.Vector3f(zero, zero, c1 + zero),
            mi.Vector3f(c1 + zero, zero, zero), mi.Vector3f(c2 * y, c2 * x, zero), mi.Vector3f(zero, c2 * z, c2 * y),
            mi.Vector3f(zero, zero, 6 * c3 * z), mi.Vector3f(c2 * z, zero, c2 * x), mi.Vector3f(c2 * x, -c2 * y, zero)]


def _shade(S, Y):
    """``(max(0, s), s)``, ``s_c = sum_j S_jc Y_j``: two ``mi.Color3f`` (``S`` a detached ``mi.Float (27)``)."""
    import drjit as dr
    import mitsuba as mi

    s = [sum(dr.gather(mi.Float, S, 3 * j + c) * y for j, y in enumerate(Y)) for c in range(3)]
    return mi.Color3f(*(dr.maximum(v, 0.0) for v in s)), mi.Color3f(*s)


@functools.cache
def _radiance_op():
    """The ``dr.CustomOp`` of :meth:`Lighting.radiance` (built once a variant is set)."""
    import drjit as dr
    import mitsuba as mi

    class Radiance(dr.CustomOp):
        """``R = g * a * max(0, S^T Y(n))`` and its reverse pass."""

        def eval(self, albedo, normals, coefficients, gain):
            dr.eval(albedo, normals)     # once: the reverse pass must not trace the limit evaluation again
            self.a, self.n, self.S, self.g = albedo, normals, coefficients, gain
            self.Y = sh_basis(normals)
            self.shade, self.s = _shade(coefficients, self.Y)
            return gain * albedo * self.shade

        def backward(self):
            gR = self.grad_out()
            w = dr.select(self.s > 0, gR * self.g * self.a, 0.0)              # dL/ds per channel
            dY = sh_gradient(self.n)
            grad_n = mi.Vector3f(0.0)
            for c in range(3):
                grad_n += w[c] * sum(dr.gather(mi.Float, self.S, 3 * j + c) * d for j, d in enumerate(dY))
            self.set_grad_in("albedo", gR * self.g * self.shade)
            self.set_grad_in("normals", grad_n)
            # the coefficients' and the gains' gradients are sums over every vertex: scatter-adds that Dr.Jit
            # reduces within each SIMD packet first (ReduceMode.Local), queued with the rest of the reverse pass
            grad_S, grad_g = dr.zeros(mi.Float, 3 * N_COEFFS), dr.zeros(mi.Float, 3)
            P = gR * self.a * self.shade
            for c in range(3):
                for j, y in enumerate(self.Y):
                    dr.scatter_reduce(dr.ReduceOp.Add, grad_S, w[c] * y, mi.UInt32(3 * j + c),
                                      mode=dr.ReduceMode.Local)
                dr.scatter_reduce(dr.ReduceOp.Add, grad_g, P[c], mi.UInt32(c), mode=dr.ReduceMode.Local)
            self.set_grad_in("coefficients", grad_S)
            self.set_grad_in("gain", mi.Color3f(*(dr.gather(mi.Float, grad_g, c) for c in range(3))))

        def name(self):
            return "Lighting.radiance"

    return Radiance
