"""The image loss (mi_loop.render.images) and the views it fits (mi_loop.render.captures).

Oracles first: a target rendered from the control mesh's own limit surface
costs no more than the noise of two renders, and Mitsuba's film holds the
background in the RGB of partly covered pixels (so rendered targets need no
compositing). Then the backward pass against single-view passes and central
differences, one reverse pass shared with geometric terms, and every rejected
input. Scenes are tiny (24x24, a few views).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_loop import datasets
from mi_loop.mesh.geometry import vertex_normals
from mi_loop.render.cameras import rig_cameras
from mi_loop.render.captures import render_targets, render_views
from mi_loop.render.images import ImageRenderer
from mi_loop.render.scene import rig_emitters
from mi_loop.subdiv.masks import limit_mesh

from helpers import CAMERA_BOX, as_numpy, exactly, flat, sphere_mesh

#: The rig's albedo per mode: grey shading under the key light, black silhouettes.
GREY = {"shading": 0.6, "silhouette": 0.0}


def rig(mode, n_views=3, resolution=24):
    """Cameras and emitters of a rig around CAMERA_BOX."""
    return rig_cameras(n_views, CAMERA_BOX, resolution), rig_emitters(CAMERA_BOX, mode)


def sphere_targets(mode, spp=64, radius=0.45):
    """A 0.4-radius icosphere(1) control mesh and rig targets of a larger sphere (3 views, 24x24)."""
    V, F = sphere_mesh(0.4, 1)
    cameras, emitters = rig(mode)
    Vt, Ft = sphere_mesh(radius, 3)
    targets = render_targets(Vt, Ft, cameras, emitters, albedo=np.full(Vt.shape, GREY[mode]),
                             normals=vertex_normals(Vt, Ft), spp=spp)
    return V, F, targets, emitters


def gradients(renderer, V, c, view_ids, seed, weight=1.0, albedo_grad=True):
    """``(dL/dx, dL/dc, losses)`` of one ``backward`` call, as (n, 3) arrays."""
    x, a = flat(V, grad=True), flat(c, grad=albedo_grad)
    losses = renderer.backward(x, a, view_ids, seed=seed, weight=weight)
    return as_numpy(dr.grad(x)), as_numpy(dr.grad(a)), losses


# -- oracles -----------------------------------------------------------------------


def test_the_film_holds_the_background_in_partly_covered_pixels():
    """A black sphere in a 0.25 environment: RGB = (1 - alpha) 0.25 at every pixel, edges included.

    This is why a target rendered in the fit's own emitters is compared as it
    is (mask of ones): compositing it over the background again would count
    the background twice at the silhouette.
    """
    V, F = sphere_mesh(0.3, 3)
    cameras, emitters = rig("silhouette", n_views=2, resolution=16)
    views = render_views(V, F, cameras, emitters, colors=np.zeros(V.shape), spp=64)
    for view in views:
        edge = (view.mask > 0.05) & (view.mask < 0.95)
        assert edge.sum() >= 8, edge.sum()
        np.testing.assert_allclose(view.rgb, np.repeat(0.25 * (1 - view.mask)[..., None], 3, axis=2), atol=1e-6)
    targets = render_targets(V, F, cameras, emitters, albedo=np.zeros(V.shape), spp=64, seed=0)
    for view, target in zip(views, targets):
        np.testing.assert_array_equal(target.mask, 1.0)
        np.testing.assert_allclose(target.rgb, view.rgb, atol=0.06)   # the same picture, other samples


@pytest.mark.parametrize("mode", ["shading", "silhouette"])
@pytest.mark.parametrize("loss", ["l1", "l2"])
def test_a_render_of_the_own_limit_surface_costs_only_the_noise(mode, loss):
    """Target: the blob's limit surface tessellated at level 2 (limit normals); renderer: the blob at level 2.

    Both at 256 spp, so the loss is the difference of two noisy renders of one
    picture: its expectation is that of two target renders with other seeds.
    One pair of seeds is a noisy statistic (the ratio ranged 0.85-1.57 over six
    pairs for L2, whose sum is dominated by a few edge pixels), so the sums over
    six independent pairs are compared: the own loss no more than 1.25 times
    the floor (measured 0.97-1.10), and far below that of the blob grown by 5 %.
    """
    V, F = datasets.blob()
    V = 0.5 * V / np.abs(V).max()
    P, Ft, N = limit_mesh(V, F, 2)
    cameras, emitters = rig(mode)
    albedo = GREY[mode]
    power = 1 if loss == "l1" else 2
    own = floor = grown = 0.0
    for pair in range(6):
        T0, T1 = (render_targets(P, Ft, cameras, emitters, albedo=np.full(P.shape, albedo), normals=N, spp=256,
                                 seed=s) for s in (2 * pair, 2 * pair + 1))
        r = ImageRenderer(V, F, T0, emitters, albedo=np.full(V.shape, albedo), level=2, spp=256, loss=loss)
        for k, view in enumerate(T0):
            np.testing.assert_array_equal(np.asarray(r.targets[k]), view.rgb)      # no compositing
        floor += sum(np.mean(np.abs(a.rgb - b.rgb) ** power) for a, b in zip(T0, T1))
        own += sum(r.losses(flat(V), None, seed=100 + pair))
        grown += sum(r.losses(flat(1.05 * V), None, seed=100 + pair))
    assert own <= 1.25 * floor, (own, floor)
    assert grown > 1.8 * own, (grown, own)


# -- the backward pass -------------------------------------------------------------


def test_backward_over_several_views_is_the_weighted_mean_of_single_views():
    """Each view rebuilds the geometry from x (Mitsuba frees its graph in every reverse render).

    backward(x, c, [0, 1], weight=w) = w (g_0 + g_1) / 2 for the points and the
    albedo, and returns the single views' losses. (A renderer that sets the same
    x again without marking it dirty would return g_0 / 2 here.)
    """
    V, F, targets, emitters = sphere_targets("shading", spp=16)
    c = np.full(V.shape, 0.6)
    r = ImageRenderer(V, F, targets, emitters, albedo=c, level=1, spp=8, deterministic=True)
    g0, c0, (l0,) = gradients(r, V, c, [0], seed=5)
    g1, c1, (l1,) = gradients(r, V, c, [1], seed=5)
    assert np.linalg.norm(g0 - g1) > 0.1 * np.linalg.norm(g0)                 # the views differ
    g01, c01, losses = gradients(r, V, c, [0, 1], seed=5, weight=2.5)
    np.testing.assert_allclose(losses, [l0, l1], rtol=1e-6)
    np.testing.assert_allclose(g01, 2.5 * (g0 + g1) / 2, rtol=0, atol=1e-5 * np.abs(g01).max())
    np.testing.assert_allclose(c01, 2.5 * (c0 + c1) / 2, rtol=0, atol=1e-5 * np.abs(c01).max())


def test_a_reverse_pass_shared_with_geometric_terms_adds_their_gradients():
    """IMLS + ARAP in one reverse pass, then the render's own passes into the same x: the sum of the three.

    All three consume the same control-point variable (the limit operator and the
    renderer's ``loop_subdiv`` gather it, ARAP too); Dr.Jit 1.5.0 once
    mis-accumulated the z component when one variable fed two gather chains.
    One thread per reverse render; the geometric terms' sums are deterministic,
    so only float32 summation order separates the parts from the whole.
    """
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.imls import IMLS
    from mi_loop.fitting.static import sample_parameters
    from mi_loop.mesh.sampling import sample_surface

    V, F, targets, emitters = sphere_targets("shading", spp=16)
    r = ImageRenderer(V, F, targets, emitters, albedo=np.full(V.shape, 0.6), level=1, spp=4, deterministic=True)
    rng = np.random.default_rng(0)
    x0 = V + rng.normal(scale=0.01, size=V.shape)
    arap = ARAP(V + rng.normal(scale=0.01, size=V.shape), F)
    R = arap.rotations(x0)
    P, N, _ = sample_surface(*sphere_mesh(0.45, 3), 2000, seed=0)
    imls = IMLS(P, N)
    op = LimitOperator(F, len(V), *sample_parameters(F, len(V), "vertices"), derivatives=False)
    imls.update(as_numpy(op.positions(flat(x0))))
    terms = {"arap": lambda x: 0.3 * arap.energy(x, R), "imls": lambda x: imls.energy(op.positions(x), reduce="mean")}

    def gradient(names):
        x = flat(x0, grad=True)
        geometric = [terms[k](x) for k in names if k != "image"]
        if geometric:
            dr.backward(sum(geometric, mi.Float(0.0)))      # one pass for IMLS + ARAP
        if "image" in names:
            r.backward(x, None, [1], seed=7)                 # then the render's own pass
        return as_numpy(dr.grad(x))

    parts = {k: gradient([k]) for k in [*terms, "image"]}
    for k, g in parts.items():
        assert np.abs(g[:, 2]).max() > 1e-6, k          # every term moves z as well
    total = sum(parts.values())
    np.testing.assert_allclose(gradient([*terms, "image"]), total, rtol=0, atol=1e-4 * np.abs(total).max())


def test_backward_with_gradients_on_the_points_only():
    """c without gradients, or None (the albedo last set), gives the same point gradient as c with them."""
    V, F, targets, emitters = sphere_targets("shading", spp=16)
    c = np.full(V.shape, 0.6)
    r = ImageRenderer(V, F, targets, emitters, albedo=c, level=1, spp=8, deterministic=True)
    g, _, losses = gradients(r, V, c, [0, 2], seed=7)
    g_plain, gc_plain, losses_plain = gradients(r, V, c, [0, 2], seed=7, albedo_grad=False)
    np.testing.assert_array_equal(gc_plain, 0.0)
    x = flat(V, grad=True)
    losses_none = r.backward(x, None, [0, 2], seed=7)
    for other, other_losses in ((g_plain, losses_plain), (as_numpy(dr.grad(x)), losses_none)):
        np.testing.assert_allclose(other_losses, losses, rtol=1e-6)
        np.testing.assert_allclose(other, g, rtol=0, atol=1e-5 * np.abs(g).max())


@pytest.mark.parametrize("mode", ["shading", "silhouette"])
def test_point_gradient_matches_central_differences(mode):
    """AD directional derivative of the mean L1 loss over 3 views vs central differences (256 spp, h = 0.02).

    A 0.4-radius icosphere(1) control mesh (limit radius about 0.36) against
    renders of a 0.45-radius sphere; directions: the unit normals (growth) and
    a tilted growth n (1 + y / 2). The differences use the seeds of the AD
    renders (losses and backward share view_seed). Tolerance 12 %: the boundary
    term is a Monte Carlo estimate with other samples than the primal, and a
    fixed-seed L1 loss is quantised by pixels.
    """
    V, F, targets, emitters = sphere_targets(mode)
    r = ImageRenderer(V, F, targets, emitters, albedo=np.full(V.shape, GREY[mode]), level=1, spp=256)
    views, seed, h = [0, 1, 2], 5, 0.02
    g = gradients(r, V, np.full(V.shape, GREY[mode]), views, seed, albedo_grad=False)[0]

    def loss(W):
        return np.mean(r.losses(flat(W), None, views, seed=seed))

    n = V / np.linalg.norm(V, axis=1, keepdims=True)
    for d in (n, n * (1.0 + 0.5 * n[:, 1:2])):
        fd = (loss(V + h * d) - loss(V - h * d)) / (2 * h)
        assert fd < -1e-2                          # growing towards the larger target lowers the loss
        np.testing.assert_allclose(np.sum(g * d), fd, rtol=0.12)


def test_albedo_gradient_matches_central_differences():
    """d loss / d c along a uniform brightening and a red-only change, L2 loss (quadratic in c), h = 0.05.

    The differences are exact for a quadratic; what separates them from the AD
    derivative is that the reverse pass draws other samples than the primal.
    At 64 spp that relative error ranged -1 % to +7.5 % over six seeds, at 256
    spp -2 % to +2 %, at 1024 spp -0.3 % to +0.3 %: 1024 spp and 2 %.
    """
    V, F, targets, emitters = sphere_targets("shading", spp=64)
    c = np.full(V.shape, 0.5)
    r = ImageRenderer(V, F, targets, emitters, albedo=c, level=1, spp=1024, loss="l2")
    _, gc, _ = gradients(r, V, c, [0, 1], seed=3)

    def loss(a):
        return np.mean(r.losses(flat(V), flat(a), [0, 1], seed=3))

    for d in (np.ones(V.shape), np.array([1.0, 0.0, 0.0]) * np.ones(V.shape)):
        fd = (loss(c + 0.05 * d) - loss(c - 0.05 * d)) / 0.1
        assert fd < -1e-4                          # the target's albedo is 0.6: brightening helps
        np.testing.assert_allclose(np.sum(gc * d), fd, rtol=0.02)


# -- targets from the same cameras -------------------------------------------------


def test_set_photos_keeps_the_scene_for_the_same_cameras_only():
    V, F, targets, emitters = sphere_targets("silhouette", spp=8)
    r = ImageRenderer(V, F, targets, emitters, albedo=np.zeros(V.shape), level=1, spp=4)
    scene = r.scene
    Vt, Ft = sphere_mesh(0.2, 2)           # further from the control mesh's limit (radius 0.36) than 0.45
    smaller = render_targets(Vt, Ft, r.cameras, emitters, albedo=np.zeros(Vt.shape), spp=8)
    before = r.losses(flat(V), None, seed=1)
    assert r.set_photos(smaller) is True and r.scene is scene
    np.testing.assert_array_equal(np.asarray(r.targets[2]), smaller[2].rgb)
    assert all(a > b for a, b in zip(r.losses(flat(V), None, seed=1), before))
    other = rig_cameras(3, (np.full(3, -0.7), np.full(3, 0.7)), 24)
    moved = render_targets(Vt, Ft, other, emitters, albedo=np.zeros(Vt.shape), spp=8)
    assert r.set_photos(moved) is False
    assert r.views[0] is smaller[0] and r.cameras == [v.camera for v in smaller]


def test_every_view_of_a_rig_sees_the_lit_subject():
    """No camera of a 20-view rig looks at the back of the key light instead of the subject.

    The centre of every view (the box centre's image) shows the grey sphere,
    lit at least by the environment (radiance 0.25, albedo 0.6).
    """
    V, F = sphere_mesh(0.4, 2)
    cameras, emitters = rig("shading", n_views=20, resolution=16)
    for k, view in enumerate(render_targets(V, F, cameras, emitters, albedo=np.full(V.shape, 0.6),
                                            normals=vertex_normals(V, F), spp=8)):
        centre = view.rgb[6:10, 6:10].mean()
        assert centre > 0.1, (k, centre)


# -- rejected input ----------------------------------------------------------------


@pytest.fixture(scope="module")
def small():
    """A renderer on 2 views of 8x8 and its arguments."""
    V, F = sphere_mesh(0.4, 0)
    cameras, emitters = rig("silhouette", n_views=2, resolution=8)
    views = render_targets(V, F, cameras, emitters, albedo=np.zeros(V.shape), spp=1)
    args = {"V": V, "F": F, "views": views, "emitters": emitters, "albedo": np.zeros(V.shape), "level": 0,
            "spp": 1}
    return ImageRenderer(**args), args


@pytest.mark.parametrize("change, exc, message", [
    ({"V": np.zeros(12)}, ValueError, "ImageRenderer(): expected control points V of shape (n, 3), got shape (12,)"),
    ({"albedo": np.zeros((12, 4))}, ValueError,
     "ImageRenderer(): expected albedo of shape (n, 3) = (12, 3), one linear RGB per vertex, got shape (12, 4)"),
    ({"albedo": np.r_[np.zeros((5, 3)), [[0.2, 1.5, 0.0]], np.zeros((6, 3))]}, ValueError,
     "ImageRenderer(): expected albedo in [0, 1], got [0.2, 1.5, 0.0] at vertex 5"),
    ({"views": []}, ValueError, "ImageRenderer(): expected at least one view, got none"),
    ({"views": ["photos"]}, TypeError,
     "ImageRenderer(): expected views that are mi_loop.io.View objects, got str at views[0]"),
    ({"integrator": "prb"}, ValueError,
     "ImageRenderer(): expected integrator to be one of ('direct_projective', 'prb_projective'), got 'prb'"),
    ({"loss": "l3"}, ValueError, "ImageRenderer(): expected loss to be one of ('l1', 'l2'), got 'l3'"),
    ({"level": -1}, ValueError, "ImageRenderer(): expected an integer level >= 0, got -1"),
    ({"spp": 0}, ValueError, "ImageRenderer(): expected an integer spp >= 1, got 0"),
])
def test_image_renderer_refuses_bad_input(small, change, exc, message):
    args = {**small[1], **change}
    with pytest.raises(exc, match=exactly(message)):
        ImageRenderer(**args)


def test_image_renderer_methods_refuse_bad_views_and_spp(small):
    r, args = small
    x = flat(args["V"])
    with pytest.raises(ValueError, match=exactly("ImageRenderer.render(): expected a view index in [0, 2), got 2")):
        r.render(x, None, 2, seed=0)
    with pytest.raises(ValueError, match=exactly("ImageRenderer.render(): expected an integer spp >= 1, got 0")):
        r.render(x, None, 0, seed=0, spp=0)
    with pytest.raises(ValueError, match=exactly("ImageRenderer.backward(): expected at least one view id, got none")):
        r.backward(x, None, [], seed=0)
    with pytest.raises(ValueError, match=exactly("ImageRenderer.backward(): expected a view index in [0, 2), "
                                                 "got -1")):
        r.backward(x, None, [0, -1], seed=0)
    with pytest.raises(ValueError, match=exactly("ImageRenderer.losses(): expected a view index in [0, 2), got 5")):
        r.losses(x, None, [5], seed=0)
    with pytest.raises(ValueError, match=exactly("ImageRenderer.set_photos(): expected at least one view, got none")):
        r.set_photos([])
    with pytest.raises(TypeError, match=exactly("ImageRenderer.set_photos(): expected views that are "
                                                "mi_loop.io.View objects, got ndarray at views[1]")):
        r.set_photos([args["views"][0], np.zeros((8, 8, 3))])


@pytest.mark.parametrize("change, message", [
    ({"albedo": np.zeros(3)}, "render_targets(): expected albedo of shape (n, 3) = (12, 3), one linear RGB per "
                              "vertex, got shape (3,)"),
    ({"albedo": np.full((12, 3), -0.1)}, "render_targets(): expected albedo in [0, 1], got [-0.1, -0.1, -0.1] "
                                         "at vertex 0"),
    ({"spp": 0}, "render_targets(): expected an integer spp >= 1, got 0"),
])
def test_render_targets_refuses_bad_input(small, change, message):
    args = small[1]
    kwargs = {"albedo": np.zeros((12, 3)), "spp": 1, **change}
    with pytest.raises(ValueError, match=exactly(message)):
        render_targets(args["V"], args["F"], [v.camera for v in args["views"]], args["emitters"], **kwargs)
