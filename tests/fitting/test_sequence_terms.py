"""Pieces of the capture-grade sequence fit: data support, facing-only IMLS and coverage, renderers, pixel widths."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from mi_loop.energies.coverage import Coverage
from mi_loop.energies.imls import IMLS
from mi_loop.fitting.sequence import Rig, pixel_size, support


def slab(n=21, gap=0.1):
    """Points on the plane z = 0 with normals +z (the near side of a slab whose far side z = -gap is unseen)."""
    g = np.linspace(-1, 1, n)
    P = np.stack(np.meshgrid(g, g, [0.0]), -1).reshape(-1, 3)
    return P, np.tile([0.0, 0.0, 1.0], (len(P), 1))


def test_support_is_one_near_facing_points_and_zero_on_the_far_side():
    P, N = slab()
    tree = cKDTree(P)
    Q = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -0.1], [0.0, 0.0, -0.1], [0.0, 0.0, 2.0]])
    Nq = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    s = support(Q, tree, 0.1, Nq, N)
    assert s.tolist() == [1.0, 1.0, 0.0, 0.0]               # the far side faces away: unsupported
    assert support(Q, tree, 0.1)[2] == 1.0                  # without normals it would count as seen


def test_imls_with_sample_normals_ignores_points_facing_the_other_way():
    P, N = slab()
    imls = IMLS(P, N, h0=0.3)
    Q = np.array([[0.0, 0.0, -0.1], [0.0, 0.0, 0.05]])
    imls.update(Q)
    assert imls.valid[0].any()                              # the far side is pulled onto the near one ...
    imls.update(Q, normals=np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]))
    assert not imls.valid[0].any() and imls.valid[1].any()  # ... unless it faces away from the points
    assert imls.n_isolated == 1


def test_coverage_with_sample_normals_pulls_the_nearest_facing_sample():
    P, N = slab(5)
    Q = np.array([[0.0, 0.0, -0.01], [0.0, 0.0, 0.2]])     # a far-side sample nearer than the near-side one
    cover = Coverage(P, N)
    cover.update(Q)
    assert set(cover.nearest.tolist()) == {0}
    cover.update(Q, normals=np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]))
    assert set(cover.nearest.tolist()) == {1}


def test_the_photo_renderer_takes_new_photos_from_the_same_cameras_only():
    from mi_loop import datasets
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.render.cameras import fibonacci_cameras
    from mi_loop.render.captures import render_views
    from mi_loop.render.images import ImageRenderer

    V, F = datasets.icosphere(1)
    lights = [dict(e) for e in DEFAULT_EMITTERS]
    cams = fibonacci_cameras(2, [0, 0, 0], 3.0, fov_x_deg=40, width=16, height=16)
    a = render_views(0.5 * V, F, cams, lights, spp=4)
    b = render_views(0.7 * V, F, cams, lights, spp=4)
    r = ImageRenderer(V, F, a, lights, albedo=np.full(V.shape, 0.5), level=0, spp=2)
    before = np.array(r.targets[0])
    assert r.set_photos(b)
    assert not np.allclose(np.array(r.targets[0]), before)
    other = render_views(0.7 * V, F, fibonacci_cameras(2, [0, 0, 0], 4.0, fov_x_deg=40, width=16, height=16),
                         lights, spp=4)
    assert not r.set_photos(other)


# --- pixel widths and the noise-aware image weight --------------------------------------------

def test_the_rig_pixel_width_is_what_mitsubas_own_sensor_sees_at_the_subject():
    """Rays through two neighbouring pixels of the rig's sensor, cut by the plane through the box centre."""
    import mitsuba as mi

    from mi_loop.fitting.options import SequenceOptions

    from helpers import CAMERA_BOX, sphere_mesh

    V, F = sphere_mesh(0.4, 1)
    options = SequenceOptions(views=3, resolution=40)
    rig = Rig(options, CAMERA_BOX)
    images = rig.images(V, F, sphere_mesh(0.45, 2), 0)
    renderer = images.renderer()
    centre = 0.5 * (CAMERA_BOX[0] + CAMERA_BOX[1])
    for sensor in renderer.scene.sensors():
        hits = []
        for px in (19.5, 20.5):        # neighbouring pixel centres on the middle row
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(px / 40, 0.5), mi.Point2f(0.5, 0.5))
            o, d = np.array(ray.o).ravel(), np.array(ray.d).ravel()
            axis = (centre - o) / np.linalg.norm(centre - o)
            hits.append(o + d * ((centre - o) @ axis) / (d @ axis))
        width = float(np.linalg.norm(hits[1] - hits[0]))
        assert abs(images.pixel / width - 1) < 1e-3, width


def test_the_photo_pixel_width_projects_to_one_pixel_at_the_subject():
    from mi_loop.render.cameras import fibonacci_cameras, project

    centre, scale = np.array([1.0, 2.0, -1.0]), 4.0
    cams = fibonacci_cameras(5, centre, 10.0, fov_x_deg=40, width=64, height=48)
    p = pixel_size(cams, centre, scale) * scale             # unit box -> capture units
    for c in cams:
        right = c.c2w[:3, 0]
        x = project(c, np.stack([centre, centre + p * right]))
        assert abs(np.linalg.norm(x[1] - x[0]) - 1.0) < 1e-9


def _weights_after_one_step(noise_sigma, *, half=False, complete=False):
    """``info`` of a one-iteration fit to sphere points with noise (``half``: the z > 0 half only)."""
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.fitting.options import SequenceOptions
    from mi_loop.fitting.sequence import fit_frame
    from mi_loop.fitting.static import sample_parameters
    from mi_loop.mesh.sampling import sample_surface

    from helpers import CAMERA_BOX, sphere_mesh

    V0, F = sphere_mesh(0.45, 1)
    Vt, Ft = sphere_mesh(0.45, 4)
    P, N, _ = sample_surface(Vt, Ft, 20_000, seed=0)
    P = P + noise_sigma * np.random.default_rng(1).normal(size=(len(P), 1)) * N
    if half:
        P, N = P[P[:, 2] > 0], N[P[:, 2] > 0]
    options = SequenceOptions(views=2, views_per_iteration=1, resolution=128, spp=1, target_spp=2, level=0,
                              iterations=1, image_every=1)
    images = Rig(options, CAMERA_BOX).images(V0, F, (Vt, Ft), 0)
    op = LimitOperator(F, len(V0), *sample_parameters(F, len(V0), "vertices"), derivatives=True)
    _, info = fit_frame(V0, F, P, N, op, images, options, frame=0, lr=1e-3, complete=complete)
    return info, images.pixel


def test_renders_of_a_mesh_frame_count_only_as_much_as_its_roughness_warrants():
    """Complete (mesh) frames: w = seen min(1, (2 sigma / p)^2), ~0 for a clean mesh; point clouds: w = seen."""
    clean, p = _weights_after_one_step(0.0, complete=True)
    assert clean["noise"] < 0.02 * p and clean["seen_weight"] < 1e-3 * 0.1, clean
    assert clean["time_render"] == 0.0                            # beta w below MIN_IMAGE_WEIGHT: no renders
    sigma = 0.15 * p                                              # (2 sigma / p)^2 = 0.09
    noisy, _ = _weights_after_one_step(sigma, complete=True)
    assert abs(noisy["noise"] / sigma - 1) < 0.15, (noisy["noise"], sigma)
    assert abs(noisy["seen_weight"] / (0.1 * (2 * noisy["noise"] / p) ** 2) - 1) < 1e-9
    assert noisy["time_render"] > 0.0
    loud, _ = _weights_after_one_step(3 * p, complete=True)
    assert loud["seen_weight"] == 0.1                             # capped at options.seen
    points, _ = _weights_after_one_step(0.0)
    assert points["noise"] is None and points["seen_weight"] == 0.1


def test_partial_data_leaves_the_unseen_half_to_the_images_but_a_complete_frame_does_not():
    partial, _ = _weights_after_one_step(0.0, half=True)
    assert 0.5 < partial["seen"] < 0.9, partial["seen"]   # the far half, beyond a control edge, unsupported
    complete, _ = _weights_after_one_step(0.0, half=True, complete=True)
    assert complete["seen"] == 1.0


def test_a_frame_returns_the_albedo_it_fitted_for_the_next_frame():
    """Photos of a red sphere, albedo started grey: the albedo fit_frame returns is the stepped one (redder),
    not the one it started from (the next frame starts from it)."""
    from mi_loop import datasets
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.fitting.optimisers import Adam
    from mi_loop.fitting.options import SequenceOptions
    from mi_loop.fitting.sequence import FrameImages, fit_frame
    from mi_loop.fitting.static import sample_parameters
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.render.cameras import fibonacci_cameras
    from mi_loop.render.captures import render_views
    from mi_loop.render.images import ImageRenderer

    V, F = datasets.icosphere(1)
    V = 0.4 * V
    lights = [dict(e) for e in DEFAULT_EMITTERS]
    cams = fibonacci_cameras(4, [0, 0, 0], 2.5, fov_x_deg=40, width=24, height=24)
    photos = render_views(V, F, cams, lights, colors=np.tile([0.9, 0.1, 0.1], (len(V), 1)), spp=8)
    grey = np.full(V.shape, 0.5)
    renderer = ImageRenderer(V, F, photos, lights, albedo=grey, level=0, spp=2)
    options = SequenceOptions(views_per_iteration=2, spp=2, level=0, iterations=6, image_every=1, geometric=False)
    images = FrameImages(renderer, grey, albedo_lr=0.05, albedo_optimiser=Adam())
    op = LimitOperator(F, len(V), *sample_parameters(F, len(V), "vertices"), derivatives=True)
    _, info = fit_frame(V, F, None, None, op, images, options, frame=0, lr=1e-3)
    albedo = np.asarray(info["albedo"])
    assert albedo.shape == V.shape
    assert albedo[:, 0].mean() > 0.6 and albedo[:, 1].mean() < 0.4, albedo.mean(axis=0)
