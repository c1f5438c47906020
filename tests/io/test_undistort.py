"""Photos read as ideal pinholes (mi_loop.io.capture, mi_loop.io.undistort): lenses undone, pixels squared, JPEGs
decoded reduced.

The oracle is written out here, independent of OpenCV: known 3D points are
projected through OpenCV's lens formulas (radial-tangential with the rational
terms, and the equidistant fisheye), in mi_loop's pixel convention (corner
origin), and drawn as small Gaussian dots into a synthetic photo. After
:func:`read_capture` the dots' centroids must sit where the view's pinhole
camera projects the points (:func:`mi_loop.render.cameras.project`).
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from mi_loop.io.capture import read_capture
from mi_loop.io.pixels import read_pixels
from mi_loop.io.srgb import linear_to_srgb
from mi_loop.io.undistort import Lens, area_resize, ideal_camera, scale_camera
from mi_loop.io.views import Camera, View
from mi_loop.render.cameras import look_at, project

from helpers import exactly

C2W = look_at([0.4, 0.9, 3.0], [0.0, 0.1, 0.0])
#: Intrinsics of the synthetic photos: 480 x 360, principal point off centre.
FX, FY, CX, CY, W, H = 400.0, 400.0, 243.7, 176.2, 480, 360


def distort(model: str, k: dict, x, y):
    """OpenCV's lens models by hand: undistorted normalised ``(x, y)`` (y down) -> distorted."""
    if model == "OPENCV_FISHEYE":
        r = np.hypot(x, y)
        t = np.arctan(r)
        td = t * (1 + k.get("k1", 0) * t**2 + k.get("k2", 0) * t**4 + k.get("k3", 0) * t**6 + k.get("k4", 0) * t**8)
        return x * td / r, y * td / r
    r2 = x * x + y * y
    g = (1 + k.get("k1", 0) * r2 + k.get("k2", 0) * r2**2 + k.get("k3", 0) * r2**3) \
        / (1 + k.get("k4", 0) * r2 + k.get("k5", 0) * r2**2 + k.get("k6", 0) * r2**3)
    p1, p2 = k.get("p1", 0), k.get("p2", 0)
    return (x * g + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * g + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def scene_points(spacing=0.09, extent=(0.5, 0.38)):
    """World points on a grid of undistorted normalised coordinates, at depths 2 to 4; and those coordinates."""
    gx = np.arange(-extent[0], extent[0] + 1e-9, spacing)
    gy = np.arange(-extent[1], extent[1] + 1e-9, spacing)
    x, y = (a.ravel() for a in np.meshgrid(gx, gy))
    depth = np.random.default_rng(3).uniform(2.0, 4.0, len(x))
    cam = np.stack([x * depth, -y * depth, -depth], axis=1)          # OpenGL camera axes: y up, looking down -z
    return cam @ C2W[:3, :3].T + C2W[:3, 3], x, y


def dots(shape, centres, sigma):
    """Linear intensity: a Gaussian dot of peak 1 at each ``(u, v)`` (corner convention), pixel centres sampled."""
    h, w = shape
    img = np.zeros(shape)
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    for u, v in centres:
        y0, y1, x0, x1 = int(max(0, v - 5 * sigma)), int(min(h, v + 5 * sigma + 1)), \
            int(max(0, u - 5 * sigma)), int(min(w, u + 5 * sigma + 1))
        img[y0:y1, x0:x1] += np.exp(-((xs[y0:y1, x0:x1] - u) ** 2 + (ys[y0:y1, x0:x1] - v) ** 2) / (2 * sigma**2))
    return np.clip(img, 0, 1)


def write_photo(tmp_path, img, mask=None, suffix=".png", quality=95, **intrinsics):
    """Write the photo (sRGB-encoded, grey as RGB) and a transforms.json with ``intrinsics``."""
    pixels = np.round(linear_to_srgb(img) * 255).astype(np.uint8)
    Image.fromarray(np.dstack([pixels] * 3)).save(tmp_path / f"photo{suffix}", quality=quality)
    frame = {"file_path": f"photo{suffix}", "transform_matrix": C2W.tolist(), **intrinsics}
    if mask is not None:
        Image.fromarray(np.round(mask * 255).astype(np.uint8)).save(tmp_path / f"mask{suffix}", quality=quality)
        frame["mask_path"] = f"mask{suffix}"
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps({"frames": [frame]}))
    return path


def centroid_errors(view, points, radius):
    """Distance of each dot's intensity centroid from :func:`project` of its point, for dots well inside."""
    uv = project(view.camera, points)
    img = view.rgb[..., 0]
    errors = []
    for u, v in uv:
        x0, x1, y0, y1 = int(u - radius), int(u + radius) + 1, int(v - radius), int(v + radius) + 1
        if x0 < 1 or y0 < 1 or x1 > view.camera.width - 1 or y1 > view.camera.height - 1:
            continue
        win = img[y0:y1, x0:x1].astype(np.float64)
        if view.valid is not None and view.valid[y0:y1, x0:x1].min() < 1:
            continue
        ys, xs = np.mgrid[y0:y1, x0:x1] + 0.5
        errors.append(np.hypot((win * xs).sum() / win.sum() - u, (win * ys).sum() / win.sum() - v))
    return np.array(errors)


LENSES = {
    "OPENCV": {"k1": -0.25, "k2": 0.08, "p1": 0.002, "p2": -0.003, "k3": -0.01},
    "SIMPLE_RADIAL": {"k1": 0.12},
    "RADIAL": {"k1": -0.1, "k2": 0.03},
    "FULL_OPENCV": {"k1": -0.2, "k2": 0.05, "p1": -0.001, "p2": 0.002, "k3": 0.01, "k4": 0.05, "k5": -0.02,
                    "k6": 0.005},
    "OPENCV_FISHEYE": {"k1": 0.05, "k2": -0.01, "k3": 0.003, "k4": -0.001},
}


@pytest.mark.parametrize("model", LENSES)
@pytest.mark.parametrize("resolution", [None, 300])
def test_undistorted_dots_sit_where_the_pinhole_projects_them(tmp_path, model, resolution):
    k = LENSES[model]
    points, x, y = scene_points()
    xd, yd = distort(model, k, x, y)
    centres = np.stack([FX * xd + CX, FY * yd + CY], axis=1)
    inside = (centres[:, 0] > 8) & (centres[:, 0] < W - 8) & (centres[:, 1] > 8) & (centres[:, 1] < H - 8)
    path = write_photo(tmp_path, dots((H, W), centres[inside], 1.5), camera_model=model, fl_x=FX, fl_y=FY,
                       cx=CX, cy=CY, **k)
    view = read_capture(path, resolution=resolution).views[0]
    cam = view.camera
    assert cam.fx == cam.fy and np.array_equal(cam.c2w, C2W)
    if resolution is not None:
        assert max(cam.width, cam.height) == resolution
    scale = cam.fx / FX
    errors = centroid_errors(view, points[inside], radius=max(3, 6 * scale))
    assert len(errors) >= 0.8 * inside.sum()
    assert errors.max() < 0.1, (errors.max(), np.median(errors))


def test_barrel_distortion_keeps_every_photo_pixel_and_marks_the_corners_unseen(tmp_path):
    img = np.full((H, W), 0.5)
    path = write_photo(tmp_path, img, camera_model="OPENCV", fl_x=FX, cx=CX, cy=CY, k1=-0.25, k2=0.08)
    view = read_capture(path).views[0]
    assert view.camera.width > W and view.camera.height > H          # the undistorted border bulges outwards
    valid = view.valid
    assert valid is not None and valid.shape == (view.camera.height, view.camera.width)
    assert valid[0, 0] == 0 and valid[-1, -1] == 0 and valid[view.camera.height // 2, view.camera.width // 2] == 1
    centre = view.rgb[view.camera.height // 2, view.camera.width // 2, 0]
    np.testing.assert_allclose(view.rgb[valid > 0], centre, rtol=1e-5)   # means over the seen part only
    assert (view.rgb[valid == 0] == 0).all() and (view.mask[valid == 0] == 0).all()
    assert (view.mask[valid > 0] == 1).all()


def test_anisotropic_pixels_are_resampled_to_square_ones(tmp_path):
    fy = 1.1 * FX
    points, x, y = scene_points()
    centres = np.stack([FX * x + CX, fy * y + CY], axis=1)
    inside = (centres[:, 0] > 8) & (centres[:, 0] < W - 8) & (centres[:, 1] > 8) & (centres[:, 1] < H - 8)
    path = write_photo(tmp_path, dots((H, W), centres[inside], 1.5), camera_model="PINHOLE", fl_x=FX, fl_y=fy,
                       cx=CX, cy=CY)
    view = read_capture(path).views[0]
    cam = view.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (fy, fy, CX * 1.1, CY) and (cam.width, cam.height) == (528, H)
    assert view.valid is None                                  # the stretched photo fills its image
    assert centroid_errors(view, points[inside], radius=6).max() < 0.1
    raw = read_capture(path, undistort=False).views[0]
    assert (raw.camera.fx, raw.camera.fy, raw.camera.width) == (FX, fy, W)


def test_jpeg_decoded_reduced_keeps_the_dots_in_place(tmp_path):
    """1024 x 768 read at 128: decoded at 1/8 by libjpeg, intrinsics divided by 8 exactly."""
    fx, cx, cy, w, h = 800.0, 517.3, 380.9, 1024, 768
    points, x, y = scene_points(spacing=0.16)
    centres = np.stack([fx * x + cx, fx * y + cy], axis=1)
    inside = (centres[:, 0] > 40) & (centres[:, 0] < w - 40) & (centres[:, 1] > 40) & (centres[:, 1] < h - 40)
    img = dots((h, w), centres[inside], 8.0)
    path = write_photo(tmp_path, img, mask=np.clip(2 * img, 0, 1), suffix=".jpg", fl_x=fx, cx=cx, cy=cy)
    assert read_pixels(tmp_path / "photo.jpg", 8).data.shape == (96, 128, 3)
    view = read_capture(path, resolution=128).views[0]
    cam = view.camera
    assert (cam.fx, cam.cx, cam.cy, cam.width, cam.height) == (100.0, cx / 8, cy / 8, 128, 96)
    assert centroid_errors(view, points[inside], radius=4).max() < 0.1
    assert ((view.mask > 0) & (view.mask < 1)).any()            # a JPEG mask stays soft
    assert view.mask.max() <= 1
    # with distortion: reduced at decode, then undistorted
    k = LENSES["OPENCV"]
    xd, yd = distort("OPENCV", k, x, y)
    centres = np.stack([fx * xd + cx, fx * yd + cy], axis=1)
    inside = (centres[:, 0] > 40) & (centres[:, 0] < w - 40) & (centres[:, 1] > 40) & (centres[:, 1] < h - 40)
    path = write_photo(tmp_path, dots((h, w), centres[inside], 8.0), suffix=".jpg", fl_x=fx, cx=cx, cy=cy, **k)
    view = read_capture(path, resolution=160).views[0]
    assert max(view.camera.width, view.camera.height) == 160
    assert centroid_errors(view, points[inside], radius=4).max() < 0.1


def test_a_jpeg_is_decoded_reduced_to_oversample_times_the_target(tmp_path, monkeypatch):
    from mi_loop.io import capture

    assert capture.OVERSAMPLE == 2
    done = []

    def spy(path, reduction=1):
        px = read_pixels(path, reduction)
        done.append((path.suffix, px.reduction, px.data.shape[:2]))
        return px

    monkeypatch.setattr(capture, "read_pixels", spy)
    img = np.full((768, 1024), 0.3)
    for suffix in (".jpg", ".png"):
        path = write_photo(tmp_path, img, mask=img, suffix=suffix, fl_x=800.0)
        for resolution in (128, 64, 600):
            assert read_capture(path, resolution=resolution).views[0].camera.width == resolution
    assert done == [(".jpg", r, (768 // r, 1024 // r)) for r in (4, 4, 8, 8, 1, 1)] + [(".png", 1, (768, 1024))] * 6


def test_factor_scales_pixel_coordinates_exactly_and_crops_the_last_part_pixel(tmp_path):
    path = write_photo(tmp_path, np.full((H, W), 0.25), fl_x=FX, cx=CX, cy=CY)
    view = read_capture(path, factor=0.3).views[0]
    cam = view.camera
    assert (cam.width, cam.height) == (144, 108)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (FX * 0.3, FY * 0.3, CX * 0.3, CY * 0.3)
    np.testing.assert_allclose(view.rgb, view.rgb[0, 0, 0], rtol=1e-6)
    odd = write_photo(tmp_path, np.full((H + 1, W + 3), 0.25), fl_x=FX)
    view = read_capture(odd, resolution=100).views[0]
    s = 100 / (W + 3)
    assert view.camera.fx == view.camera.fy == FX * s and (view.camera.width, view.camera.height) == (100, 74)


def test_scale_camera_and_area_resize():
    cam = Camera(np.eye(4), 10.0, 10.0, 5.0, 3.0, 10, 7)
    assert scale_camera(cam, 0.5) == Camera(np.eye(4), 5.0, 5.0, 2.5, 1.5, 5, 3)
    ramp = np.arange(7, dtype=np.float32)[None, :]
    # [0, 3.5] and [3.5, 7] of pixels 0..6 (centres 0..6): means 1.5 + 0.25 ... exact area weights
    np.testing.assert_allclose(area_resize(ramp, (1, 2)), [[(0 + 1 + 2 + 0.5 * 3) / 3.5, (0.5 * 3 + 4 + 5 + 6) / 3.5]],
                               rtol=1e-6)
    np.testing.assert_allclose(area_resize(ramp, (1, 2), extent=(1, 6)), [[1.0, 4.0]], rtol=1e-6)


def test_ideal_camera_of_a_pinhole_with_square_pixels_is_itself():
    cam = Camera(C2W, FX, FX, CX, CY, W, H)
    assert ideal_camera(cam, Lens()) == cam


def test_view_valid_is_checked_and_resized_as_a_weight():
    cam = Camera(np.eye(4), 4.0, 4.0, 2.0, 1.0, 4, 2)
    rgb = np.stack([np.full((2, 4), 0.8)] * 3, axis=-1)
    rgb[:, 1] = 0.0                                              # an unseen column holds zeros
    valid = np.ones((2, 4))
    valid[:, 1] = 0.0
    half = View(cam, rgb, np.ones((2, 4)), "v", valid).resized(0.5)
    np.testing.assert_allclose(half.rgb[..., 0], [[0.8, 0.8]], rtol=1e-6)
    np.testing.assert_allclose(half.valid, [[0.5, 1.0]])
    for bad, message in [(np.ones((2, 3)), "View(): expected valid of shape (h, w) = (2, 4) as the camera, or None, "
                                           "got shape (2, 3)"),
                         (np.full((2, 4), 1.5), "View(): expected valid values in [0, 1], got 1.5 at pixel [0, 0]")]:
        with pytest.raises(ValueError, match=exactly(message)):
            View(cam, rgb, np.ones((2, 4)), "v", bad)


def test_refusals_of_resolution_factor_and_distortion_read_as_stored(tmp_path):
    path = write_photo(tmp_path, np.full((8, 12), 0.5), fl_x=10.0, k1=0.1)
    for kwargs, message in [
            ({"resolution": 0}, "read_capture(): expected an integer resolution >= 1 or None, got 0"),
            ({"resolution": 64.0}, "read_capture(): expected an integer resolution >= 1 or None, got 64.0"),
            ({"resolution": 4, "factor": 0.5},
             "read_capture(): expected factor or resolution, not both, got factor = 0.5, resolution = 4"),
            ({"undistort": False}, f"read_capture(): expected a pinhole without distortion (read with undistort=True "
                                   f"to undistort) for frames[0].k1 in '{path}', got 0.1")]:
        with pytest.raises(ValueError, match=exactly(message)):
            read_capture(path, **kwargs)
    fisheye = write_photo(tmp_path, np.full((8, 12), 0.5), fl_x=10.0, is_fisheye=True)
    with pytest.raises(ValueError, match=exactly(
            "read_capture(): expected a pinhole without distortion (read with undistort=True to undistort) for "
            f"frames[0].is_fisheye in '{fisheye}', got True")):
        read_capture(fisheye, undistort=False)


def test_lens_and_resampling_functions_refuse_bad_input():
    cam = Camera(np.eye(4), 10.0, 10.0, 5.0, 3.0, 10, 6)
    from mi_loop.io.undistort import undistort

    for make, message in [
            (lambda: Lens("equirectangular"), "Lens(): expected a model in ('opencv', 'fisheye'), got "
                                              "'equirectangular'"),
            (lambda: Lens("fisheye", (0.1,) * 5), "Lens(): expected at most 4 finite coefficients for model "
                                                  "'fisheye', got (0.1, 0.1, 0.1, 0.1, 0.1)"),
            (lambda: Lens("opencv", (np.nan,)), "Lens(): expected at most 8 finite coefficients for model 'opencv', "
                                                "got (nan,)"),
            (lambda: scale_camera(cam, 0.0), "scale_camera(): expected a finite factor > 0, got 0.0"),
            (lambda: area_resize(np.zeros((6, 10)), (3, 5), extent=(7, 10)),
             "area_resize(): expected a size >= 1 and an extent in (0, 6] x (0, 10], got size (3, 5), extent (7, 10)"),
            (lambda: area_resize(np.zeros((6, 10)), (0, 5)),
             "area_resize(): expected a size >= 1 and an extent in (0, 6] x (0, 10], got size (0, 5), extent (6, 10)"),
            (lambda: undistort(np.zeros((6, 10, 3), np.float32), cam, Lens(), Camera(np.eye(4), 5.0, 6.0, 2.5, 1.5,
                                                                                      5, 3)),
             "undistort(): expected a target with square pixels (fx == fy), got fx = 5.0, fy = 6.0"),
            (lambda: undistort(np.zeros((5, 10, 3), np.float32), cam, Lens(), scale_camera(cam, 0.5)),
             "undistort(): expected an image of the camera's size 10 x 6, got 10 x 5"),
            (lambda: read_pixels("any.png", 0), "read_pixels(): expected an integer reduction >= 1, got 0")]:
        with pytest.raises(ValueError, match=exactly(message)):
            make()


def test_photos_of_one_camera_share_the_remap_tables():
    """Two photos through the same camera and lens build OpenCV's tables once (a capture's photos usually share
    one camera); another lens builds its own; the results do not depend on the cache."""
    from mi_loop.io import undistort as module

    camera = Camera(C2W, FX, FY, CX, CY, W, H)
    lens, other = Lens("opencv", (-0.25, 0.08, 0.002, -0.003)), Lens("opencv", (0.1, 0.0, 0.0, 0.0))
    target = scale_camera(ideal_camera(camera, lens), 0.4)
    rng = np.random.default_rng(0)
    a, b = rng.uniform(size=(H, W, 3)), rng.uniform(size=(H, W, 3))
    module._maps.cache_clear()
    first = module.undistort(a, camera, lens, target)
    module.undistort(b, camera, lens, target)
    assert module._maps.cache_info().misses == 1 and module._maps.cache_info().hits == 1
    module.undistort(a, camera, other, scale_camera(ideal_camera(camera, other), 0.4))
    assert module._maps.cache_info().misses == 2
    module._maps.cache_clear()
    again = module.undistort(a, camera, lens, target)
    np.testing.assert_array_equal(first[0], again[0])
    np.testing.assert_array_equal(first[1], again[1])
