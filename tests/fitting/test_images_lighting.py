"""fit_images under lighting it is not told (mi_loop.render.lighting): photos of a known surface lit by a known
low-order light, each photo with its own exposure and white balance.

Oracle: the photos are rendered from the blob's limit surface with the emission
model itself (``render_views(emission=True)``: radiance ``g_k * albedo * s(n)``),
a light from above and to the side, and gains that differ by up to 2x between
photos. The fit that estimates the lighting must find the gains (relative to
their geometric mean) and the light's direction, explain the shading (a lower
image loss) and reach the surface (within 0.005 of the diagonal; the fit told a
uniform white light lands as close, within the renders' run-to-run spread).
"""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop import datasets
from mi_loop.fitting.images import fit_images
from mi_loop.fitting.options import ImageFitOptions
from mi_loop.io.emitters import DEFAULT_EMITTERS
from mi_loop.metrics import two_sided
from mi_loop.render.cameras import fibonacci_cameras
from mi_loop.render.captures import render_views
from mi_loop.render.lighting import N_COEFFS, Lighting, sh_basis
from mi_loop.subdiv.masks import limit_mesh

LIGHT = [dict(e) for e in DEFAULT_EMITTERS]
#: The light's direction: above and to the side.
KEY = np.array([0.6, 0.7, 0.38]) / np.linalg.norm([0.6, 0.7, 0.38])
#: Each photo's true RGB gain.
GAINS = np.exp(np.random.default_rng(4).uniform(-0.35, 0.35, size=(8, 3)))


def key_light():
    """Shading 0.35 + 0.8 max(0, n . KEY)-like: band 0 and band 1 along KEY, and white."""
    S = np.zeros((N_COEFFS, 3))
    y0, y1 = sh_basis(np.array([[0.0, 0, 1]]))[0, [0, 2]]
    S[0] = 0.7 / y0
    S[[3, 1, 2]] = (0.6 / y1) * KEY[:, None]          # Y_11 ~ x, Y_1-1 ~ y, Y_10 ~ z
    return S


@pytest.fixture(scope="module")
def lit_photos():
    P, F, N = limit_mesh(*datasets.blob(), 3)
    lo, hi = P.min(0), P.max(0)
    P = (P - 0.5 * (lo + hi)) / np.linalg.norm(hi - lo)
    cams = fibonacci_cameras(len(GAINS), [0, 0, 0], 1.9, fov_x_deg=35, width=48, height=48)
    light = Lighting(1, key_light())
    albedo = np.full(P.shape, 0.5)
    views = [render_views(P, F, [cam], LIGHT, colors=np.clip(light.shade(albedo, N) * g, 0, None), normals=N,
                          spp=16, emission=True, seed=k)[0] for k, (cam, g) in enumerate(zip(cams, GAINS))]
    return P, F, views


@pytest.mark.slow
def test_the_lighting_and_the_gains_are_found_and_the_surface_is_reached(lit_photos):
    P, F, views = lit_photos
    distance, results = {}, {}
    for lighting in ("given", "sh"):
        options = ImageFitOptions(n_vertices=300, refinements=1, iterations=120, spp=4, seed=0, lighting=lighting,
                                  light_lr=0.03)
        results[lighting] = result = fit_images(views, LIGHT, options)
        distance[lighting] = two_sided(*limit_mesh(result.V, result.F, 3)[:2], P, F, n_samples=20_000)["mean"]
    est = results["sh"].lighting.numpy()
    truth = GAINS / np.exp(np.log(GAINS).mean(axis=0))
    np.testing.assert_allclose(est["gains"], truth, rtol=0.08)
    direction = est["coefficients"][[3, 1, 2]].mean(axis=1)
    assert direction @ KEY > 0.9 * np.linalg.norm(direction), direction
    # the photos' shading is explained (the image loss falls well below the uniform light's), and the surface is
    # reached: the distance is not compared with the given light's, because the renders' run-to-run spread is
    # larger than the difference (three runs, sh / given: 0.00346 / 0.00379, 0.00365 / 0.00357, 0.00391 / 0.00330)
    loss = {k: np.mean([h["loss"] for h in r.history[-10:]]) for k, r in results.items()}
    assert loss["sh"] < 0.7 * loss["given"], loss
    assert distance["sh"] < 0.005, distance
