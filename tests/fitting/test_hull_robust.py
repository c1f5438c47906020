"""The visual hull and its template on masks as real captures have them (mi_loop.fitting.hull, fitting.images).

Oracles: an analytic sphere and torus, pinhole cameras, and masks computed by
casting each pixel's centre ray at the surface (a pixel is foreground if its
ray hits). Against them: subjects that overflow a frame, wrong masks, JPEG
masks, a torus's genus, hulls cut by the grid, lone voxels and thin plates.
"""
from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from mi_loop.fitting.hull import Carving, carve, hull_points, visual_hull
from mi_loop.fitting.images import _start_mesh, start_mesh
from mi_loop.fitting.options import ImageFitOptions
from mi_loop.fitting.template import make_template
from mi_loop.io.views import Camera, View
from mi_loop.mesh.geometry import euler_characteristic
from mi_loop.render.cameras import fibonacci_cameras, look_at

from helpers import exactly, sphere_points


def pixel_rays(camera: Camera):
    """Origin ``(3,)`` and unit directions ``(h, w, 3)`` of the rays through the pixel centres."""
    j, i = np.mgrid[0:camera.height, 0:camera.width] + 0.5
    d = np.stack([(i - camera.cx) / camera.fx, -(j - camera.cy) / camera.fy, -np.ones_like(i)], axis=-1)
    d = d @ camera.c2w[:3, :3].T
    return camera.c2w[:3, 3], d / np.linalg.norm(d, axis=-1, keepdims=True)


def sphere_mask(camera: Camera, centre, radius: float) -> np.ndarray:
    """1 where the pixel's centre ray hits the sphere (ahead of the camera), else 0."""
    o, d = pixel_rays(camera)
    oc = o - np.asarray(centre, dtype=np.float64)
    b = d @ oc
    disc = b ** 2 - (oc @ oc - radius ** 2)
    far = -b + np.sqrt(np.maximum(disc, 0.0))
    return ((disc >= 0) & (far > 0)).astype(np.float32)


def torus_sdf(X, R: float, r: float):
    """Signed distance to the torus about the z axis (tube radius ``r`` at distance ``R``)."""
    return np.hypot(np.hypot(X[..., 0], X[..., 1]) - R, X[..., 2]) - r


def torus_mask(camera: Camera, R: float, r: float) -> np.ndarray:
    """1 where the pixel's centre ray hits the torus: sphere tracing of its distance, 300 steps."""
    o, d = pixel_rays(camera)
    t = np.zeros(d.shape[:2])
    for _ in range(300):
        t += np.maximum(torus_sdf(o + t[..., None] * d, R, r), 0.0)
    return (torus_sdf(o + t[..., None] * d, R, r) < 1e-3).astype(np.float32)


def views_of(cameras, mask_of) -> list:
    return [View(cam, np.zeros((cam.height, cam.width, 3)), mask_of(cam), f"v{k}") for k, cam in enumerate(cameras)]


def ring_cameras(n=20):
    return fibonacci_cameras(n, [0, 0, 0], 4.0, fov_x_deg=40, width=64, height=64)


def sphere_iou(carving: Carving, radius=1.0):
    """``(contained, iou, volume ratio)``: every voxel a voxel deep inside kept; IoU and volume against the ball."""
    d = np.linalg.norm(carving.centres, axis=-1)
    truth, hull = d <= radius, carving.occupied
    contained = bool(hull[d < radius - carving.voxel].all())
    return contained, (hull & truth).sum() / (hull | truth).sum(), hull.sum() / truth.sum()


# -------------------------------------------------------------------------- the sphere's hull


def test_a_ball_seen_whole_gives_a_tight_hull():
    carving = carve(views_of(ring_cameras(), lambda c: sphere_mask(c, [0, 0, 0], 1.0)), resolution=48)
    contained, iou, ratio = sphere_iou(carving)
    assert contained and iou > 0.85 and ratio < 1.2, (iou, ratio)


def test_a_subject_that_overflows_some_frames_is_not_cut_there():
    """Two cameras so close that the ball fills their frames, one aimed past it (the ball leaves its frame
    on one side), one inside the grid (voxels behind it): the hull is as tight as without them."""
    cams = ring_cameras()
    f = 32 / np.tan(np.radians(20))
    cams += [Camera(look_at([0, 0, 1.8], [0, 0, 0]), f, f, 32, 32, 64, 64),
             Camera(look_at([1.3, 0.2, 0.0], [0, 0, 0]), f, f, 32, 32, 64, 64),
             Camera(look_at([0, -2.5, 0.0], [0.9, 0, 0], up=(0, 0, 1)), f, f, 32, 32, 64, 64)]
    views = views_of(cams, lambda c: sphere_mask(c, [0, 0, 0], 1.0))
    assert views[20].mask.all() and views[21].mask.all()                  # the ball overflows the frame
    assert 0.2 < views[22].mask.mean() < 0.8 and views[22].mask[:, 0].all()    # it runs off one side
    carving = carve(views, resolution=48)
    contained, iou, ratio = sphere_iou(carving)
    assert contained and iou > 0.85 and ratio < 1.2, (iou, ratio)


def test_two_wrong_masks_of_twenty_are_outvoted():
    """A hole punched through one silhouette, half of another missing: the hull still holds the ball."""
    views = views_of(ring_cameras(), lambda c: sphere_mask(c, [0, 0, 0], 1.0))
    holed, halved = views[3].mask.copy(), views[7].mask.copy()
    yy, xx = np.mgrid[0:64, 0:64]
    holed[(yy - 32) ** 2 + (xx - 32) ** 2 < 8 ** 2] = 0.0
    halved[:, :32] = 0.0
    views[3], views[7] = (View(v.camera, v.rgb, m, v.name) for v, m in ((views[3], holed), (views[7], halved)))
    carving = carve(views, resolution=48)
    contained, iou, ratio = sphere_iou(carving)
    assert contained and iou > 0.8 and ratio < 1.25, (iou, ratio)
    assert carving.info["outvoted"] > 0
    classic = carve(views, resolution=48, outvote=0.0)                    # every background vote carves
    assert not sphere_iou(classic)[0]


def jpeg(mask: np.ndarray, quality: int = 60) -> np.ndarray:
    buffer = io.BytesIO()
    Image.fromarray(np.round(255 * mask).astype(np.uint8), "L").save(buffer, "JPEG", quality=quality)
    return np.asarray(Image.open(io.BytesIO(buffer.getvalue())), dtype=np.float32) / 255


def test_jpeg_masks_at_quality_60_give_the_same_hull():
    views = views_of(ring_cameras(), lambda c: jpeg(sphere_mask(c, [0, 0, 0], 1.0)))
    values = np.concatenate([v.mask.ravel() for v in views])
    assert ((values > 0.2) & (values < 0.8)).sum() > 100                  # the masks ring ...
    assert ((values > 0.02) & (values <= 0.2)).sum() > 100               # ... into the background too
    contained, iou, ratio = sphere_iou(carve(views, resolution=48))
    assert contained and iou > 0.85 and ratio < 1.2, (iou, ratio)


def test_uncertain_pixels_abstain():
    """Masks of 0.5 everywhere say nothing: the whole seen grid is kept, and nothing is voted."""
    views = views_of(ring_cameras(), lambda c: np.full((64, 64), 0.5, np.float32))
    carving = carve(views, resolution=16)
    assert carving.inside.sum() == carving.outside.sum() == 0
    assert carving.occupied[carving.seen >= 5].all()


# -------------------------------------------------------------------------- genus, cut hulls, thin parts


@pytest.fixture(scope="module")
def torus_views():
    cams = fibonacci_cameras(40, [0, 0, 0], 4.5, fov_x_deg=45, width=64, height=64)
    return views_of(cams, lambda c: torus_mask(c, 1.0, 0.4))


def test_a_torus_seen_from_many_directions_gives_a_genus_one_template(torus_views):
    V, F, bbox, info = _start_mesh(torus_views, ImageFitOptions(n_vertices=400, refinements=0))
    chi, n_boundary = euler_characteristic(len(V), F)
    assert (chi, n_boundary) == (0, 0) and info["template"]["genus"] == 1
    np.testing.assert_allclose(bbox[1], [1.4, 1.4, 0.4], atol=0.12)     # a tight box
    assert np.abs(torus_sdf(V, 1.0, 0.4)).max() < 0.15                   # control points near the torus


def test_a_hull_cut_by_the_grid_gives_a_closed_template():
    """A ball larger than the grid fills every frame: the hull is the grid's cube (less what few views see),
    whose boundary voxels on the cube's faces had zero normals (the template step failed on them)."""
    views = views_of(ring_cameras(), lambda c: sphere_mask(c, [0, 0, 0], 2.0))
    carving = carve(views, resolution=32)
    assert carving.occupied[0].any() and carving.occupied[-1].any()      # cut by the grid's faces
    P, N, unoriented = hull_points(carving)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, rtol=1e-12)
    on_face = P[:, 0] == carving.centres[-1, 0, 0, 0]
    assert on_face.any() and (N[on_face, 0] > 0.5).all()                 # the cut's normals point out
    V, F, _ = start_mesh(views, ImageFitOptions(n_vertices=200, refinements=0))
    assert euler_characteristic(len(V), F) == (2, 0)


def test_lone_voxels_and_thin_plates_give_no_points_without_normals():
    occupied = np.zeros((12, 12, 12), dtype=bool)
    occupied[2:6, 2:6, 2:6] = True                  # a block
    occupied[8, 8, 8] = True                        # a lone voxel
    occupied[2:10, 8, 1:6] = True                   # a plate one voxel thick
    axis = np.arange(12.0)
    centres = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1)
    zeros = np.zeros(occupied.shape, dtype=np.int64)
    P, N, unoriented = hull_points(Carving(occupied, centres, zeros, zeros, zeros, 1.0))
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, rtol=1e-12)
    assert unoriented >= 1 and not (P == [8, 8, 8]).all(axis=1).any()    # the lone voxel is left out
    assert len(P) + unoriented == occupied.sum() - 2 * 2 * 2             # every boundary voxel is one or other
    V, F, info = make_template(P, N, 40, zero_normals="drop")             # the template step takes them
    assert len(F) and info["dropped_normals"] == 0


def test_the_template_drops_zero_normals_when_asked_and_counts_them():
    P = sphere_points(4000)[0]
    N = P.copy()
    N[::400] = 0.0
    V, F, info = make_template(P, N, 100, zero_normals="drop")
    assert info["dropped_normals"] == 10 and info["n_points"] == 3990 and info["genus"] == 0
    with pytest.raises(ValueError, match=exactly("make_template(): normal 0 has zero length; estimate normals "
                                                 "first (mi_loop.mesh.points.estimate_normals)")):
        make_template(P, N, 100)
    with pytest.raises(ValueError, match=exactly("make_template(): zero_normals must be 'raise' or 'drop', "
                                                 "got 'keep'")):
        make_template(P, N, 100, zero_normals="keep")


# -------------------------------------------------------------------------- errors


@pytest.mark.parametrize("kwargs, message", [
    ({"resolution": 4}, "carve(): expected an integer resolution >= 8, got 4"),
    ({"band": (0.6, 0.8)}, "carve(): expected a mask band (lo, hi) with 0 < lo <= 0.5 <= hi <= 1, got (0.6, 0.8)"),
    ({"band": 0.5}, "carve(): expected a mask band (lo, hi) with 0 < lo <= 0.5 <= hi <= 1, got 0.5"),
    ({"min_share": 1.0}, "carve(): expected min_share in [0, 1), got 1.0"),
    ({"outvote": -0.1}, "carve(): expected outvote in [0, 1), got -0.1"),
])
def test_bad_carving_parameters_are_refused(kwargs, message):
    views = views_of(ring_cameras(4), lambda c: sphere_mask(c, [0, 0, 0], 1.0))
    with pytest.raises(ValueError, match=exactly(message)):
        carve(views, **kwargs)


def test_a_hull_of_one_voxel_is_refused_with_what_to_do():
    """A ball smaller than a voxel, at a voxel centre: one voxel kept, and it has no normal."""
    views = views_of(ring_cameras(), lambda c: sphere_mask(c, [0, 0, 0], 0.05))
    with pytest.raises(ValueError, match=exactly("visual_hull(): expected a hull thicker than one voxel, got no "
                                                 "oriented boundary point (raise the resolution)")):
        visual_hull(views, resolution=9)
    away = views_of(ring_cameras(), lambda c: sphere_mask(c, [0.07, 0.07, 0.07], 0.03))
    with pytest.raises(ValueError, match=exactly("visual_hull(): expected masks whose foregrounds overlap in "
                                                 "space, got nothing left after carving")):
        visual_hull(away, resolution=9)
