"""fit_images (mi_loop.fitting.images): shape and albedo from synthetic photos of known surfaces."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop import datasets
from mi_loop.fitting.declarations import OptionError
from mi_loop.fitting.hull import capture_bounds, in_mask, visual_hull
from mi_loop.fitting.images import fit_images, stage_plan, start_mesh
from mi_loop.fitting.options import ImageFitOptions
from mi_loop.io.emitters import DEFAULT_EMITTERS
from mi_loop.io.views import Camera, View
from mi_loop.metrics import two_sided
from mi_loop.render.cameras import fibonacci_cameras
from mi_loop.render.captures import render_views
from mi_loop.subdiv.limit import limit_matrix
from mi_loop.subdiv.masks import limit_mesh
from mi_loop.subdiv.tessellation import tessellate

from helpers import exactly

LIGHT = [dict(e) for e in DEFAULT_EMITTERS]


def blob_target():
    """The blob's limit surface, centred, bbox diagonal 1: ``(P, F, N)``."""
    P, F, N = limit_mesh(*datasets.blob(), 3)
    lo, hi = P.min(0), P.max(0)
    return (P - 0.5 * (lo + hi)) / np.linalg.norm(hi - lo), F, N


def two_tone(P):
    """A smooth albedo: warm on +x, cool on -x."""
    t = 0.5 + 0.5 * np.tanh(6 * P[:, :1])
    return t * np.array([0.8, 0.5, 0.2]) + (1 - t) * np.array([0.2, 0.4, 0.8])


@pytest.fixture(scope="module")
def photos():
    P, F, N = blob_target()
    cams = fibonacci_cameras(10, [0, 0, 0], 1.9, fov_x_deg=35, width=48, height=48)
    return P, F, render_views(P, F, cams, LIGHT, normals=N, colors=two_tone(P), spp=16)


def limit_albedo(result, level=3):
    face_ids, uv, _ = tessellate(result.F, level)
    return limit_matrix(result.F, len(result.V), face_ids, uv) @ result.albedo


def test_capture_bounds_find_the_point_the_cameras_look_at():
    cams = fibonacci_cameras(6, [0.3, -0.2, 0.1], 2.0, fov_x_deg=40, width=32, height=32)
    centre, radius = capture_bounds(cams)
    np.testing.assert_allclose(centre, [0.3, -0.2, 0.1], atol=1e-9)
    np.testing.assert_allclose(radius, 2.0 * np.sin(np.radians(20)), rtol=1e-9)


def test_capture_bounds_refuse_a_single_camera():
    cams = fibonacci_cameras(1, [0, 0, 0], 2.0, fov_x_deg=40, width=32, height=32)
    with pytest.raises(ValueError, match=exactly("capture_bounds(): expected cameras whose optical axes meet near "
                                                 "one point (two or more, not parallel), got 1 camera(s)")):
        capture_bounds(cams)


def test_the_visual_hull_holds_the_subject_and_its_box_is_close(photos):
    P, F, views = photos
    H, N, (lo, hi) = visual_hull(views, resolution=48)
    voxel = 2 * 1.9 * np.sin(np.radians(17.5)) / 47
    assert (lo <= P.min(0) + voxel).all() and (hi >= P.max(0) - voxel).all()   # nothing of the subject carved
    assert np.linalg.norm(hi - lo) < 1.25                                       # 10 views: a tight box
    outward = np.einsum("ij,ij->i", N, H - 0.5 * (lo + hi)) > 0
    assert outward.mean() > 0.9                                                 # normals point out


def test_in_mask_treats_the_unseen_pixels_of_an_undistorted_photo_as_outside_it():
    """Pixels whose valid is below 0.5 are outside the frame: they neither carve nor count as seeing."""
    camera = Camera(np.eye(4), 4.0, 4.0, 2.0, 2.0, 4, 4)
    X = np.array([[x, 0.1, -1.0] for x in (-0.375, -0.125, 0.125, 0.375)])     # pixels (0..3, 1) of the image
    valid = np.ones((4, 4))
    valid[:, 0], valid[:, 1] = 0.0, 0.4
    view = View(camera, np.zeros((4, 4, 3)), np.zeros((4, 4)), "v")
    inside, fg = in_mask(view, X)
    assert inside.tolist() == [True] * 4 and fg.tolist() == [False] * 4
    inside, fg = in_mask(View(camera, view.rgb, view.mask, "v", valid), X)
    assert inside.tolist() == [False, False, True, True] and fg.tolist() == [False, False]


def test_the_stage_plan_halves_the_images_and_keeps_the_triangle_count():
    plan = stage_plan(ImageFitOptions(refinements=2, iterations=100, triangles=20_000), (256, 256), 320)
    assert [p["scale"] for p in plan] == [0.25, 0.5, 1.0]
    assert [320 * 4 ** k * 4 ** p["level"] for k, p in enumerate(plan)] == [20480, 20480, 20480]
    assert sum(p["iterations"] for p in plan) == 100


def test_the_sphere_start_has_few_enough_vertices_for_the_refinements(photos):
    V, F, _ = start_mesh(photos[2], ImageFitOptions(n_vertices=700, init="sphere", refinements=2))
    assert len(V) == 42                                    # 42 -> 162 -> 642 <= 700


def test_the_hull_start_is_closer_to_a_waisted_shape_than_the_sphere():
    """A peanut (waist radius 0.3 of its ends'): the hull sees the waist, the box's ellipsoid cannot.

    Measured: hull 0.023, sphere 0.034 of the diagonal (a 45-vertex template of a 96^3 hull
    from 10 views of 48^2). On the near-spherical blob both starts are equally far (0.025, 0.024).
    """
    V, F = datasets.icosphere(3)
    V = V * np.c_[0.3 + 0.7 * V[:, 1] ** 2, 1.6 * np.ones(len(V)), 0.3 + 0.7 * V[:, 1] ** 2]
    V = V / np.linalg.norm(V.max(0) - V.min(0))
    cams = fibonacci_cameras(10, [0, 0, 0], 1.9, fov_x_deg=35, width=48, height=48)
    views = render_views(V, F, cams, LIGHT, spp=4)
    distance = {}
    for init in ("hull", "sphere"):
        V0, F0, _ = start_mesh(views, ImageFitOptions(n_vertices=700, init=init, refinements=2))
        distance[init] = two_sided(*limit_mesh(V0, F0, 3)[:2], V, F, n_samples=20_000)["mean"]
    assert distance["hull"] < 0.8 * distance["sphere"], distance


@pytest.mark.slow
def test_photos_bring_a_sphere_onto_the_shape_and_recover_its_albedo(photos):
    """Measured: mean distance 0.030 -> 0.0033 of the diagonal, albedo error 0.135 -> 0.022 (10 views of 48^2)."""
    P, F, views = photos
    options = ImageFitOptions(n_vertices=700, init="sphere", refinements=2, iterations=150, spp=4, seed=0)
    result = fit_images(views, LIGHT, options)
    assert [s["n_vertices"] for s in result.stages] == [42, 162, 642]
    start = two_sided(*limit_mesh(result.V0, result.F0, 3)[:2], P, F, n_samples=20_000)["mean"]
    end = two_sided(*limit_mesh(result.V, result.F, 3)[:2], P, F, n_samples=20_000)["mean"]
    assert end < 0.25 * start and end < 0.01
    from scipy.spatial import cKDTree

    Q = limit_mesh(result.V, result.F, 3)[0]
    truth = two_tone(P)[cKDTree(P).query(Q)[1]]
    error = np.abs(limit_albedo(result) - truth).mean()
    assert error < 0.3 * np.abs(0.5 - truth).mean()
    assert result.albedo.min() >= 0 and result.albedo.max() <= 1


def test_the_same_seed_gives_the_same_fit_with_deterministic_renders(photos):
    options = ImageFitOptions(n_vertices=200, init="sphere", refinements=1, iterations=6, spp=2,
                              deterministic=True)
    a, b = (fit_images(photos[2], LIGHT, options) for _ in range(2))
    np.testing.assert_array_equal(a.V, b.V)
    np.testing.assert_array_equal(a.albedo, b.albedo)


def test_fixed_albedo_stays_grey(photos):
    options = ImageFitOptions(n_vertices=50, init="sphere", refinements=0, iterations=4, spp=2,
                              albedo_lr=0.0, albedo=0.3)
    result = fit_images(photos[2], LIGHT, options)
    np.testing.assert_array_equal(result.albedo, 0.3)


def test_fit_images_needs_two_photos(photos):
    with pytest.raises(ValueError, match=exactly("fit_images(): expected at least two photos, got 1")):
        fit_images(photos[2][:1], LIGHT, ImageFitOptions())


@pytest.mark.parametrize("field, value, what", [
    ("init", "cube", "one of ('hull', 'sphere')"),
    ("refinements", 7, "an integer in 0..4"),
    ("resolution", 8, "an integer >= 16 (or None: the photos' size)"),
    ("lr", 0.0, "a finite number > 0"),
    ("albedo", 1.5, "a number in [0, 1]"),
    ("integrator", "prb", "one of ('direct_projective', 'prb_projective')"),
])
def test_bad_image_options_are_refused(field, value, what):
    with pytest.raises(OptionError, match=exactly(f"ImageFitOptions(): expected {field} to be {what}, "
                                                  f"got {value!r}")):
        ImageFitOptions(**{field: value})
