"""Estimated lighting (mi_loop.render.lighting) and its renders through ImageRenderer.

Oracles: the basis is orthonormal on the sphere (quadrature); the shading of an
environment band-limited to band 2 is its irradiance over pi, integrated
numerically over the sphere (the cosine-lobe factors A_l); a render of a sphere
shows ``gain * albedo * s(n)`` at the pixel that sees its pole; the gradients
of the loss with respect to the coefficients and the gains match central
differences (the renders are linear in both). Then highlights left out of the
loss, and every rejected input.
"""
from __future__ import annotations

from dataclasses import replace

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_loop.io.capture import Camera
from mi_loop.render.captures import render_views
from mi_loop.render.images import ImageRenderer
from mi_loop.render.lighting import BAND_FACTORS, N_COEFFS, Lighting, sh_basis

from helpers import exactly, fibonacci_points, flat, sphere_mesh

BACKDROP = [{"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}]


def quadrature(n=200_000):
    """Near-uniform unit directions and their equal solid-angle weights."""
    D = fibonacci_points(n)
    return D / np.linalg.norm(D, axis=1, keepdims=True), 4 * np.pi / n


def test_the_basis_is_orthonormal_on_the_sphere():
    D, w = quadrature()
    Y = sh_basis(D)
    np.testing.assert_allclose(w * Y.T @ Y, np.eye(N_COEFFS), atol=2e-4)


def test_shading_of_a_band_limited_environment_is_its_irradiance_over_pi():
    """s_j = A_l L_lm / pi, checked against E(n) = int L(w) max(0, n . w) dw by quadrature."""
    rng = np.random.default_rng(0)
    env = rng.normal(size=(N_COEFFS, 3))
    env[0] += 3.0                                           # mostly positive radiance; the sign does not matter
    D, w = quadrature()
    radiance = sh_basis(D) @ env                            # (k, 3): the environment L(w)
    normals = fibonacci_points(7)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    irradiance = w * np.maximum(normals @ D.T, 0.0) @ radiance
    coefficients = BAND_FACTORS[:, None] * env / np.pi
    light = Lighting(1, coefficients)
    np.testing.assert_allclose(sh_basis(normals) @ coefficients, irradiance / np.pi, atol=2e-3)
    np.testing.assert_allclose(light.environment(), env, rtol=1e-6, atol=1e-6)


def pole_camera(resolution=33):
    """A camera on +z looking at the origin (OpenGL: it looks down its -z), a narrow view."""
    c2w = np.eye(4)
    c2w[2, 3] = 3.0
    f = 0.5 * resolution / np.tan(np.radians(10.0))
    return Camera(c2w=c2w, fx=f, fy=f, cx=resolution / 2, cy=resolution / 2, width=resolution, height=resolution)


def lit_sphere(coefficients, log_gain, albedo=0.4):
    """An ImageRenderer of a 0.5-sphere control mesh seen from +z (twice, two gains) and the flat control points."""
    V, F = sphere_mesh(0.5, 2)
    cam = pole_camera()
    views = render_views(V, F, [cam, cam], BACKDROP, spp=4)
    light = Lighting(2, coefficients)
    light.log_gain = mi.Float(np.asarray(log_gain, dtype=np.float32))
    r = ImageRenderer(V, F, views, BACKDROP, albedo=np.full(V.shape, albedo), level=3, spp=4, lighting=light)
    return r, flat(V)


def test_a_render_shows_gain_times_albedo_times_shading_at_the_pole():
    """s(n) = a + b z with a = 0.5 / Y00, b = 0.8 / Y10: at the pole (n = z) 1.3 per unit albedo; gains e^+-0.2."""
    S = np.zeros((N_COEFFS, 3))
    S[0], S[2] = 0.5 / sh_basis(np.array([[0.0, 0, 1]]))[0, 0], 0.8 / sh_basis(np.array([[0.0, 0, 1]]))[0, 2]
    S[2, 2] = 0.0                                            # blue has no directional part: 0.5
    r, x = lit_sphere(S, [0.2, 0.0, 0.0, -0.2, 0.0, 0.0])
    for k, red_gain in ((0, np.exp(0.2)), (1, np.exp(-0.2))):
        centre = np.asarray(r.render(x, None, k, seed=0))[16, 16]
        np.testing.assert_allclose(centre, 0.4 * np.array([1.3 * red_gain, 1.3, 0.5]), rtol=0.02)
    corner = np.asarray(r.render(x, None, 0, seed=0))[0, 0]
    np.testing.assert_allclose(corner, [1.0, 1.0, 1.0])      # the backdrop, not lit by anything


def test_gradients_of_coefficients_and_gains_match_central_differences():
    rng = np.random.default_rng(1)
    S = 0.3 * rng.normal(size=(N_COEFFS, 3))
    S[0] = 1.2 / sh_basis(np.array([[0.0, 0, 1]]))[0, 0]
    log_gain = 0.1 * rng.normal(size=6)
    r, x = lit_sphere(S, log_gain)
    # somewhere to go: half the render itself, so that R - T keeps its sign and the L1 loss is linear in both
    r.targets = [mi.TensorXf(0.5 * np.asarray(r.render(x, None, k, seed=3))) for k in (0, 1)]
    light = r.lighting
    light.coefficients, light.log_gain = flat(S, grad=True), mi.Float(log_gain.astype(np.float32))
    dr.enable_grad(light.log_gain)
    r.backward(x, None, [0, 1], seed=3)
    g_s, g_l = np.asarray(dr.grad(light.coefficients)), np.asarray(dr.grad(light.log_gain))

    def loss(S_, l_):
        light.coefficients, light.log_gain = mi.Float(S_.astype(np.float32).ravel()), mi.Float(l_.astype(np.float32))
        return np.mean(r.losses(x, None, [0, 1], seed=3))

    h = 0.1                                                 # the loss is linear in both: no truncation error
    fd_s = [(loss(S.ravel() + h * e, log_gain) - loss(S.ravel() - h * e, log_gain)) / (2 * h) for e in np.eye(27)]
    fd_l = [(loss(S.ravel(), log_gain + h * e) - loss(S.ravel(), log_gain - h * e)) / (2 * h) for e in np.eye(6)]
    # the reverse pass draws its own pixel samples: a few percent of the largest gradient is Monte Carlo noise
    np.testing.assert_allclose(g_s, fd_s, atol=0.03 * np.abs(fd_s).max())
    np.testing.assert_allclose(g_l, fd_l, atol=0.03 * np.abs(fd_l).max())


def test_gains_are_relative_to_their_geometric_mean():
    light = Lighting(3)
    light.log_gain = mi.Float(np.array([0.3, 0, 0, 0.6, 0, 0, 0.9, 0, 0], dtype=np.float32))
    np.testing.assert_allclose(light.numpy()["gains"][:, 0], np.exp([-0.3, 0.0, 0.3]), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(light.gain(2))[0], np.exp(0.3), rtol=1e-6)


def test_highlights_inside_the_mask_are_left_out_of_the_loss():
    """A target equal to the render but for a bright patch (and a dark one), mask all ones: with highlights 1.5
    the bright patch costs nothing, the dark one still does; without, both cost."""
    S = np.zeros((N_COEFFS, 3))
    S[0] = 1.0 / sh_basis(np.array([[0.0, 0, 1]]))[0, 0]
    r, x = lit_sphere(S, np.zeros(6))
    same = np.asarray(r.render(x, None, 0, seed=5))
    mask = np.ones(same.shape[:2], np.float32)                  # the target is the image itself
    bright, dark = same.copy(), same.copy()
    bright[12:15, 12:15] += 0.5
    dark[18:21, 18:21] *= 0.2
    V, F = sphere_mesh(0.5, 2)
    results = {}
    for t in (0.0, 1.5):
        for name, img in (("bright", bright), ("dark", dark)):
            view = replace(r.views[0], rgb=img.astype(np.float32), mask=mask)
            rr = ImageRenderer(V, F, [view, r.views[1]], BACKDROP, albedo=np.full(V.shape, 0.4), level=3, spp=4,
                               lighting=Lighting(2, S), highlights=t)
            results[t, name] = rr.losses(x, None, [0], seed=5)[0]
    assert results[0.0, "bright"] > 1e-3 and results[0.0, "dark"] > 1e-4
    assert results[1.5, "bright"] < 1e-6
    np.testing.assert_allclose(results[1.5, "dark"], results[0.0, "dark"], rtol=1e-5)


def test_rejected_lighting_and_highlights():
    with pytest.raises(ValueError, match=exactly("Lighting(): expected n_views, an integer >= 1, got 0")):
        Lighting(0)
    with pytest.raises(ValueError, match=exactly("Lighting(): expected finite coefficients of shape (9, 3), "
                                                 "got shape (4, 3)")):
        Lighting(2, np.zeros((4, 3)))
    with pytest.raises(ValueError, match=exactly("Lighting(): expected a uniform level > 0, got -1.0")):
        Lighting(2, level=-1.0)
    V, F = sphere_mesh(0.5, 1)
    views = render_views(V, F, [pole_camera(), pole_camera()], BACKDROP, spp=2)
    A = np.full(V.shape, 0.5)
    with pytest.raises(ValueError, match=exactly("ImageRenderer(): expected a lighting of 2 views (one gain per view), "
                                                 "got 3")):
        ImageRenderer(V, F, views, BACKDROP, albedo=A, level=1, spp=1, lighting=Lighting(3))
    with pytest.raises(TypeError, match=exactly("ImageRenderer(): expected lighting to be a "
                                                "mi_loop.render.lighting.Lighting, got dict")):
        ImageRenderer(V, F, views, BACKDROP, albedo=A, level=1, spp=1, lighting={})
    with pytest.raises(ValueError, match=exactly("ImageRenderer(): expected highlights, a factor >= 0 (0: off), "
                                                 "got -1.0")):
        ImageRenderer(V, F, views, BACKDROP, albedo=A, level=1, spp=1, highlights=-1.0)
    with pytest.raises(ValueError, match=exactly("render_views(): expected colors (the emitted radiance) with "
                                                 "emission=True, got none")):
        render_views(V, F, [pole_camera()], BACKDROP, emission=True)


def test_render_geometry_shows_the_side_light_on_a_sphere():
    """At the pixel that sees a sphere's point facing the camera, n = the camera's back axis: the grey is
    0.06 + 0.7 (0.35 / |l|), l = (0.8, 0.5, 0.35) in the camera's (right, up, back); the backdrop is 0.05."""
    from mi_loop.render.captures import render_geometry

    V, F = sphere_mesh(0.5, 4)
    N = V / np.linalg.norm(V, axis=1, keepdims=True)
    a = render_geometry(V, F, N, [pole_camera()])[0]
    expected = 0.06 + 0.7 * 0.35 / np.linalg.norm([0.8, 0.5, 0.35])
    np.testing.assert_allclose(a[16, 16], expected, rtol=0.01)
    np.testing.assert_allclose(a[0, 0], 0.05, rtol=1e-5)
    assert a[16, 24, 0] > a[16, 8, 0]                               # brighter on the camera's right, towards the light
