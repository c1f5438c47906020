"""The multi-view renderer (mi_loop.render.multiview): image-loss gradients, the camera rig, its lighting.

Scenes are tiny on purpose (an icosphere(1) control mesh with 42 vertices,
24x24 images, a few views) so that the file runs in well under a minute.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_loop.ad.operator import LimitOperator
from mi_loop.energies.arap import ARAP
from mi_loop.energies.imls import IMLS
from mi_loop.fitting.options import SequenceOptions
from mi_loop.fitting.static import sample_parameters
from mi_loop.mesh.geometry import vertex_normals
from mi_loop.mesh.sampling import sample_surface
from mi_loop.render.cameras import _direction
from mi_loop.render.multiview import Renderer, rig_views

from helpers import CAMERA_BOX, as_numpy, flat, sphere_mesh


def renderer_and_targets(mode, spp=256, views=3, target_radius=0.45):
    """Renderer of a 0.4-radius icosphere(1) control mesh and renders of a larger sphere."""
    V, F = sphere_mesh(0.4, 1)
    options = SequenceOptions(views=views, resolution=24, spp=spp, target_spp=64, level=1, mode=mode)
    renderer = Renderer(V, F, CAMERA_BOX, options.rig)
    Vt, Ft = sphere_mesh(target_radius)
    return V, F, renderer, renderer.targets(Vt, Ft, vertex_normals(Vt, Ft))


def image_gradient(renderer, V, views, targets, seed):
    """Gradient ``(n, 3)`` of the mean image loss over ``views`` w.r.t. the control points."""
    x = flat(V, grad=True)
    renderer.backward(x, views, targets, seed=seed)
    return as_numpy(dr.grad(x))



# -- the image term's gradient ------------------------------------------------------


@pytest.mark.parametrize("mode", ["shading", "silhouette"])
def test_image_gradient_matches_central_differences(mode):
    """AD directional derivative of the image loss vs central differences.

    A 0.4-radius icosphere(1) control mesh (limit radius ~0.36) against renders
    of a 0.45-radius sphere; three views at 24x24, 256 spp, L1 loss. Both
    differences use the seed of the AD render, so they see the same samples.
    Directions: the unit normals (growth) and a tilted growth ``n (1 + y/2)``;
    step h = 0.02 (about a quarter pixel). The AD gradient is the mean of
    the per-view gradients, each from its own backward pass (as
    ``Renderer.backward`` does; see the next test).
    Measured agreement: 1-6 %. Tolerance 12 %: the boundary term is a Monte
    Carlo estimate with other samples than the primal renders, and the
    differences of a fixed-seed L1 loss carry pixel-quantisation noise.
    """
    V, _F, renderer, targets = renderer_and_targets(mode)
    views, seed, h = [0, 1, 2], 5, 0.02
    g = sum(image_gradient(renderer, V, [k], targets, seed) for k in views) / len(views)

    def loss(W):
        return renderer.loss(flat(W), views, targets, seed=seed)

    n = V / np.linalg.norm(V, axis=1, keepdims=True)
    for d in (n, n * (1.0 + 0.5 * n[:, 1:2])):
        fd = (loss(V + h * d) - loss(V - h * d)) / (2 * h)
        assert fd < -1e-2            # growing towards the larger target lowers the loss
        np.testing.assert_allclose(np.sum(g * d), fd, rtol=0.12)


def test_multi_view_loss_gradient_is_the_mean_of_the_per_view_gradients():
    """loss(x, [0, 1]) = (loss(x, [0]) + loss(x, [1])) / 2 (same seeds), so the gradients must be too."""
    V, _F, renderer, targets = renderer_and_targets("silhouette", spp=8, views=2)
    g0, g1 = (image_gradient(renderer, V, [k], targets, 5) for k in (0, 1))
    both = renderer.loss(flat(V), [0, 1], targets, seed=5)
    single = [renderer.loss(flat(V), [k], targets, seed=5) for k in (0, 1)]
    np.testing.assert_allclose(both, np.mean(single), rtol=1e-5)      # the primal is right
    assert np.linalg.norm(g0 - g1) > 0.1 * np.linalg.norm(g0)          # the views differ
    g01 = image_gradient(renderer, V, [0, 1], targets, 5)
    np.testing.assert_allclose(g01, (g0 + g1) / 2, rtol=0, atol=1e-3 * np.abs(g0 + g1).max())


def test_combined_gradient_is_the_sum_of_the_term_gradients():
    """One backward pass through IMLS + ARAP + image = sum of three separate passes.

    All three terms consume the same control-point variable (the limit
    operator and the renderer's ``loop_subdiv`` gather it, ARAP too); Dr.Jit
    1.5.0 mis-accumulated the z component when one variable fed two gather
    chains (see ``unravel_points``). Float32 atomics reorder sums, hence a
    tolerance of 1e-4 of the largest entry rather than bit equality.
    """
    V, F, renderer, targets = renderer_and_targets("shading", spp=4, views=2)
    rng = np.random.default_rng(0)
    x0 = V + rng.normal(scale=0.01, size=V.shape)
    arap = ARAP(V + rng.normal(scale=0.01, size=V.shape), F)
    R = arap.rotations(x0)
    Vt, Ft = sphere_mesh(0.45, 3)
    P, N, _ = sample_surface(Vt, Ft, 2000, seed=0)
    imls = IMLS(P, N)
    op = LimitOperator(F, len(V), *sample_parameters(F, len(V), "vertices"), derivatives=False)
    imls.update(as_numpy(op.positions(flat(x0))))
    terms = {
        "arap": lambda x: 0.3 * arap.energy(x, R),
        "imls": lambda x: imls.energy(op.positions(x), reduce="mean"),
    }

    def gradient(names):
        x = flat(x0, grad=True)
        geometric = [terms[k](x) for k in names if k != "image"]
        if geometric:
            dr.backward(sum(geometric, mi.Float(0.0)))      # one pass for IMLS + ARAP
        if "image" in names:
            renderer.backward(x, [1], targets, seed=7)       # then the render's own pass
        return as_numpy(dr.grad(x))

    parts = {k: gradient([k]) for k in [*terms, "image"]}
    for k, g in parts.items():
        assert np.abs(g[:, 2]).max() > 1e-6, k          # every term moves z as well
    total = sum(parts.values())
    np.testing.assert_allclose(gradient([*terms, "image"]), total, rtol=0, atol=1e-4 * np.abs(total).max())


# -- the camera rig ----------------------------------------------------------------


def test_rig_views_cover_the_sphere():
    """Every direction is within 40 degrees of one of the 20 cameras (Fibonacci spacing ~30)."""
    views = rig_views(20)
    assert len(views) == 20
    D = np.array([_direction(a, e) for a, e in views])
    elevation = np.array([e for _, e in views])
    assert elevation.min() < -60 and elevation.max() > 60          # both poles are seen
    assert (elevation > 0).sum() == (elevation < 0).sum() == 10     # balanced hemispheres
    assert all(0 <= a < 360 for a, _ in views)
    probes = np.random.default_rng(0).normal(size=(20_000, 3))
    probes /= np.linalg.norm(probes, axis=1, keepdims=True)
    worst = np.degrees(np.arccos(np.clip((probes @ D.T).max(1), -1, 1))).max()
    assert worst < 40, worst
    gap = np.degrees(np.arccos(np.clip(D @ D.T - 2 * np.eye(20), -1, 1))).min()
    assert gap > 20, gap                                             # no two cameras coincide
    (azimuth, elevation), = rig_views(1)
    assert elevation == 0.0 and 0 <= azimuth < 360                  # one view: on the equator


def test_every_view_of_the_rig_sees_the_lit_subject():
    """No camera of a 20-view rig looks at the back of the key light instead of the subject.

    (The key light once sat between the subject and the cameras near its
    direction, so view 0 rendered black for target and fit alike: no loss and
    no gradient.) The centre of every view shows the grey sphere lit at least
    by the environment.
    """
    V, F = sphere_mesh(0.4, 2)
    options = SequenceOptions(views=20, resolution=16, target_spp=8)
    renderer = Renderer(V, F, CAMERA_BOX, options.rig)
    for k, image in enumerate(renderer.targets(V, F, vertex_normals(V, F))):
        centre = np.array(image)[6:10, 6:10].mean()
        assert centre > 0.1, (k, renderer.views[k], centre)


def test_rig_views_rejects_zero_views():
    with pytest.raises(ValueError, match=r"rig_views\(\): expected at least one view, got 0"):
        rig_views(0)
