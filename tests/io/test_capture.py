"""Calibrated captures (mi_loop.io.capture): transforms.json in its dialects, images, masks, refusals.

Images are written here by Pillow (8-bit PNG, JPEG), by a few lines of zlib
(16-bit PNG, independent of the reader's decoder) and by ``mitsuba.Bitmap`` (EXR).
"""
from __future__ import annotations

import json
import math
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from mi_loop.io.capture import Camera, View, read_capture, write_capture
from mi_loop.io.srgb import linear_to_srgb, srgb_to_linear
from mi_loop.render.cameras import fibonacci_cameras, look_at, project, sensor_dict

from helpers import exactly

POSE = look_at([0.5, 1.0, 3.0], [0.0, 0.0, 0.0]).tolist()


def png(path, pixels):
    """Write ``pixels`` (h, w[, c]) uint8 as a PNG with Pillow."""
    Image.fromarray(np.asarray(pixels, dtype=np.uint8)).save(path)
    return path


def png16(path, pixels):
    """Write ``pixels`` (h, w, c) uint16, c = 1..4, as a 16-bit PNG (filter 0, one IDAT)."""
    h, w, c = pixels.shape
    raw = b"".join(b"\x00" + pixels[y].astype(">u2").tobytes() for y in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", w, h, 16, {1: 0, 2: 4, 3: 2, 4: 6}[c], 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))
    return path


def transforms(directory, frames, **top):
    """Write ``directory/transforms.json`` with ``frames`` (dicts; transform_matrix POSE unless given)."""
    meta = {**top, "frames": [{"transform_matrix": POSE, **f} for f in frames]}
    path = directory / "transforms.json"
    path.write_text(json.dumps(meta))
    return path


def read_error(path) -> str:
    """The one-line ValueError of read_capture(path)."""
    with pytest.raises(ValueError) as info:
        read_capture(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith("read_capture(): expected "), message
    return message


# ---------------------------------------------------------------- writing and reading back


def random_views(n=3, width=24, height=16, seed=0):
    rng = np.random.default_rng(seed)
    cams = fibonacci_cameras(n, [0.1, 0.0, -0.2], 3.0, fov_x_deg=50.0, width=width, height=height)
    cams[1] = Camera(cams[1].c2w, 30.5, 31.25, 10.3, 9.1, width, height)        # off-centre, anisotropic
    return [View(c, rng.random((height, width, 3)), rng.random((height, width)), f"view {k}")
            for k, c in enumerate(cams)]


def test_write_then_read_gives_cameras_exactly_and_images_to_8_bits(tmp_path):
    views = random_views()
    path = write_capture(tmp_path / "out", views)
    assert path == tmp_path / "out" / "transforms.json"
    assert sorted(p.name for p in (tmp_path / "out" / "images").iterdir()) == ["000.png", "001.png", "002.png"]
    capture = read_capture(path, undistort=False)          # as stored: view 1 keeps fx != fy
    assert capture.path == path and len(capture.views) == 3
    for k, (wrote, read) in enumerate(zip(views, capture.views)):
        assert read.camera == wrote.camera                 # every float exact
        assert read.name == f"images/{k:03d}.png"
        assert read.rgb.dtype == np.float32 and read.mask.dtype == np.float32
        np.testing.assert_allclose(linear_to_srgb(read.rgb), linear_to_srgb(wrote.rgb), atol=0.5 / 255 + 1e-6)
        np.testing.assert_allclose(read.mask, wrote.mask, atol=0.5 / 255 + 1e-6)
    square = read_capture(path).views                        # by default view 1 is resampled to square pixels
    assert [square[k].camera for k in (0, 2)] == [views[k].camera for k in (0, 2)]
    cam = square[1].camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (31.25, 31.25, 10.3 * 31.25 / 30.5, 9.1, 24, 16)
    meta = json.loads(path.read_text())
    assert "camera_angle_x" not in meta                      # the views' intrinsics differ
    assert set(meta["frames"][0]) == {"file_path", "fl_x", "fl_y", "cx", "cy", "w", "h", "transform_matrix"}


def test_shared_centred_cameras_also_get_camera_angle_x(tmp_path):
    views = [v for k, v in enumerate(random_views()) if k != 1]
    meta = json.loads(write_capture(tmp_path, views).read_text())
    assert meta["camera_angle_x"] == pytest.approx(2 * math.atan(12 / views[0].camera.fx), rel=1e-15)


def test_write_is_all_or_nothing(tmp_path, monkeypatch):
    """A bad third view, then a disk error at the second image: nothing appears, an old capture stays."""
    views = random_views()
    bad = View(views[2].camera, views[2].rgb + 1.5, views[2].mask, "hdr")
    with pytest.raises(ValueError, match=exactly(
            "write_capture(): expected rgb in [0, 1] for an 8-bit PNG at views[2] (clip it first), got "
            f"{bad.rgb[0, 0, 0]} at pixel [0, 0]")):
        write_capture(tmp_path / "new" / "capture", [*views[:2], bad])
    assert not (tmp_path / "new").exists()
    old = write_capture(tmp_path / "old", views[:1])
    before = {p.relative_to(tmp_path): p.read_bytes() for p in (tmp_path / "old").rglob("*") if p.is_file()}
    calls = []

    def failing_save(self, fp, *args, **kwargs):
        calls.append(fp)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        return original_save(self, fp, *args, **kwargs)

    original_save = Image.Image.save
    monkeypatch.setattr(Image.Image, "save", failing_save)
    with pytest.raises(OSError, match="No space left"):
        write_capture(tmp_path / "old", views)
    after = {p.relative_to(tmp_path): p.read_bytes() for p in (tmp_path / "old").rglob("*") if p.is_file()}
    assert after == before and old.exists()
    with pytest.raises(ValueError, match=exactly("write_capture(): expected at least one View, got none")):
        write_capture(tmp_path / "none", [])
    with pytest.raises(TypeError, match=exactly("write_capture(): expected a View at views[0], got Camera")):
        write_capture(tmp_path / "none", [views[0].camera])


# ---------------------------------------------------------------- the JSON dialects


def test_blender_file_path_without_suffix_tries_png_jpg_jpeg_exr(tmp_path):
    (tmp_path / "train").mkdir()
    png(tmp_path / "train" / "r_0.png", np.full((8, 8, 3), 200))
    png(tmp_path / "train" / "r_1.jpg", np.full((8, 8, 3), 10))       # Pillow writes JPEG by the suffix
    png(tmp_path / "train" / "r_1.png", np.full((8, 8, 3), 100))      # .png is tried first
    path = transforms(tmp_path, [{"file_path": "./train/r_0"}, {"file_path": "./train/r_1"}], camera_angle_x=0.7)
    views = read_capture(path).views
    assert [v.name for v in views] == ["./train/r_0", "./train/r_1"]
    np.testing.assert_allclose(views[1].rgb, srgb_to_linear(100 / 255), rtol=1e-6)


def test_camera_angle_x_equals_the_equivalent_fl_x(tmp_path):
    png(tmp_path / "a.png", np.zeros((30, 40, 3)))
    angle = transforms(tmp_path, [{"file_path": "a.png"}], camera_angle_x=0.8)
    by_angle = read_capture(angle).views[0].camera
    fx = 20 / math.tan(0.4)
    focal = transforms(tmp_path, [{"file_path": "a.png"}], fl_x=fx, fl_y=fx, cx=20, cy=15, w=40, h=30)
    assert read_capture(focal).views[0].camera == by_angle
    both = transforms(tmp_path, [{"file_path": "a.png"}], camera_angle_x=0.8, camera_angle_y=0.7)
    assert read_capture(both, undistort=False).views[0].camera.fy == pytest.approx(15 / math.tan(0.35), rel=1e-15)
    only_fl_x = transforms(tmp_path, [{"file_path": "a.png"}], fl_x=33.0)
    camera = read_capture(only_fl_x).views[0].camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (33.0, 33.0, 20.0, 15.0)


def test_frame_intrinsics_override_the_top_level(tmp_path):
    png(tmp_path / "wide.png", np.zeros((20, 48, 3)))
    png(tmp_path / "tall.png", np.zeros((48, 20, 3)))
    path = transforms(tmp_path, [
        {"file_path": "wide.png"},
        {"file_path": "tall.png", "fl_x": 60.0, "cx": 4.0, "w": 20, "h": 48},
        {"file_path": "wide.png", "fl_y": 51.0, "cy": 19.5},
    ], fl_x=50.0, cx=24.0, cy=10.0)
    cams = [v.camera for v in read_capture(path, undistort=False).views]
    assert [(c.fx, c.fy, c.cx, c.cy, c.width, c.height) for c in cams] == [
        (50.0, 50.0, 24.0, 10.0, 48, 20), (60.0, 60.0, 4.0, 10.0, 20, 48), (50.0, 51.0, 24.0, 19.5, 48, 20)]


# ---------------------------------------------------------------- images and masks


def test_srgb_decoding_follows_the_formula(tmp_path):
    values = np.array([0, 5, 10, 11, 64, 128, 200, 255], dtype=np.uint8)       # 10/255 < 0.04045 < 11/255
    png(tmp_path / "ramp.png", np.broadcast_to(values[None, :, None], (2, 8, 3)))
    rgb = read_capture(transforms(tmp_path, [{"file_path": "ramp.png"}], fl_x=8.0)).views[0].rgb
    x = values / 255.0
    expected = [x[0] / 12.92, x[1] / 12.92, x[2] / 12.92, ((x[3] + 0.055) / 1.055) ** 2.4,
                ((x[4] + 0.055) / 1.055) ** 2.4, ((x[5] + 0.055) / 1.055) ** 2.4, ((x[6] + 0.055) / 1.055) ** 2.4, 1.0]
    np.testing.assert_allclose(rgb[0, :, 1], expected, rtol=1e-6)


def test_sixteen_bit_png_rgb_rgba_and_grey(tmp_path):
    rng = np.random.default_rng(1)
    rgba = rng.integers(0, 65536, (5, 7, 4)).astype(np.uint16)
    rgba[..., 3] = np.maximum(rgba[..., 3], 1)
    png16(tmp_path / "rgb.png", rgba[..., :3])
    png16(tmp_path / "rgba.png", rgba)
    png16(tmp_path / "grey.png", rgba[..., :1])
    path = transforms(tmp_path, [{"file_path": n} for n in ("rgb.png", "rgba.png", "grey.png")], fl_x=7.0)
    rgb, with_alpha, grey = read_capture(path).views
    np.testing.assert_allclose(rgb.rgb, srgb_to_linear(rgba[..., :3] / 65535), rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(rgb.mask, 1.0)
    np.testing.assert_allclose(with_alpha.mask, rgba[..., 3] / 65535, rtol=1e-6)
    np.testing.assert_allclose(grey.rgb, np.repeat(srgb_to_linear(rgba[..., :1] / 65535), 3, axis=2),
                               rtol=1e-5, atol=1e-7)


def test_jpeg_and_grey_images(tmp_path):
    png(tmp_path / "flat.jpg", np.full((16, 16, 3), (40, 120, 220)))
    png(tmp_path / "grey.png", np.full((16, 16), 77))
    path = transforms(tmp_path, [{"file_path": "flat.jpg"}, {"file_path": "grey.png"}], camera_angle_x=1.0)
    jpeg, grey = read_capture(path).views
    np.testing.assert_allclose(linear_to_srgb(jpeg.rgb.reshape(-1, 3)), np.tile([40, 120, 220], (256, 1)) / 255,
                               atol=2.5 / 255)
    np.testing.assert_array_equal(jpeg.mask, 1.0)
    assert grey.rgb.shape == (16, 16, 3)
    np.testing.assert_allclose(grey.rgb, srgb_to_linear(77 / 255), rtol=1e-6)


def test_alpha_is_the_mask_and_mask_path_overrides_it(tmp_path):
    rgba = np.zeros((6, 8, 4), np.uint8)
    rgba[..., :3] = 90
    rgba[1:4, 2:6, 3] = 255
    rgba[0, 0, 3] = 51
    png(tmp_path / "cut.png", rgba)
    grey_mask = np.zeros((6, 8), np.uint8)
    grey_mask[:, :4] = 255
    png(tmp_path / "mask_grey.png", grey_mask)
    rgba_mask = np.full((6, 8, 4), 255, np.uint8)
    rgba_mask[..., 3] = 0
    rgba_mask[5, 7, 3] = 102                            # alpha wins over the (white) colour
    png(tmp_path / "mask_rgba.png", rgba_mask)
    path = transforms(tmp_path, [{"file_path": "cut.png"}, {"file_path": "cut.png", "mask_path": "mask_grey.png"},
                                 {"file_path": "cut.png", "mask_path": "mask_rgba"}], fl_x=8.0)
    alpha, grey, by_alpha = read_capture(path).views
    np.testing.assert_allclose(alpha.mask, rgba[..., 3] / 255)
    np.testing.assert_allclose(alpha.rgb, srgb_to_linear(90 / 255), rtol=1e-6)    # straight colours, not composited
    np.testing.assert_array_equal(grey.mask, grey_mask / 255)
    expected = np.zeros((6, 8))
    expected[5, 7] = 0.4
    np.testing.assert_allclose(by_alpha.mask, expected, rtol=1e-6)


def test_exr_is_read_linear_as_stored(tmp_path):
    import mitsuba as mi

    rng = np.random.default_rng(2)
    pixels = rng.uniform(0, 4, (6, 5, 4)).astype(np.float32)
    pixels[..., 3] = rng.uniform(0.1, 1, (6, 5))
    mi.Bitmap(pixels).write(str(tmp_path / "hdr.exr"))
    mi.Bitmap(pixels[..., :3]).write(str(tmp_path / "rgb.exr"))
    path = transforms(tmp_path, [{"file_path": "hdr"}, {"file_path": "rgb.exr"}], fl_x=5.0)
    with_alpha, rgb = read_capture(path).views
    np.testing.assert_array_equal(with_alpha.rgb, pixels[..., :3])
    np.testing.assert_array_equal(with_alpha.mask, pixels[..., 3])
    np.testing.assert_array_equal(rgb.rgb, pixels[..., :3])
    np.testing.assert_array_equal(rgb.mask, 1.0)


# ---------------------------------------------------------------- resizing


def test_resized_halves_cleanly():
    rng = np.random.default_rng(4)
    camera = Camera(np.array(POSE), 70.0, 70.0, 20.5, 30.25, 64, 48)
    view = View(camera, rng.random((48, 64, 3)), rng.random((48, 64)), "v")
    half = view.resized(0.5)
    assert (half.camera.width, half.camera.height) == (32, 24)
    assert half.rgb.shape == (24, 32, 3) and half.mask.shape == (24, 32)
    np.testing.assert_allclose(half.rgb, view.rgb.reshape(24, 2, 32, 2, 3).mean(axis=(1, 3)), rtol=1e-6)
    np.testing.assert_allclose(half.mask, view.mask.reshape(24, 2, 32, 2).mean(axis=(1, 3)), rtol=1e-6)
    points = rng.normal(size=(10, 3)) * 0.5
    np.testing.assert_allclose(project(half.camera, points), 0.5 * project(camera, points), rtol=1e-12)
    assert view.resized(1.0) is view


def test_resized_by_a_fraction_weights_partial_pixels():
    """64 -> 24 columns: every new pixel averages 8/3 old ones (as 8 of the old pixels split in three)."""
    camera = Camera(np.eye(4), 40.0, 40.0, 32.0, 4.5, 64, 9)
    ramp = np.broadcast_to((np.arange(64) + 0.5)[None, :, None], (9, 64, 3))
    view = View(camera, ramp, np.ones((9, 64)), "ramp")
    small = view.resized(0.375)
    assert (small.camera.width, small.camera.height) == (24, 3)
    thirds = np.repeat(np.arange(64) + 0.5, 3)
    np.testing.assert_allclose(small.rgb[0, :, 0], thirds.reshape(24, 8).mean(axis=1), rtol=1e-6)
    np.testing.assert_allclose(small.mask, 1.0, rtol=1e-6)
    assert (small.camera.fx, small.camera.cx) == (15.0, 12.0)
    assert (small.camera.fy, small.camera.cy) == (15.0, 4.5 * 0.375)     # 3 rows of 8/3: the last old row cropped


def test_resized_keeps_pixels_square_where_the_size_does_not_divide():
    """601 rows halve to 300 rows of exactly 2 (the last old row cropped), not to 301 rows of 601/301: Mitsuba's
    sensor refuses fx != fy, which is what a DTU capture read at 800 x 601 met in fit-images' coarse stages."""
    rng = np.random.default_rng(5)
    camera = Camera(np.array(POSE), 723.0, 723.0, 400.5, 300.25, 800, 601)
    view = View(camera, rng.random((601, 800, 3)), rng.random((601, 800)), "v")
    for factor in (0.5, 0.25):
        small = view.resized(factor)
        k = round(1 / factor)
        h, w = 601 // k, 800 // k
        assert (small.camera.width, small.camera.height) == (w, h)
        assert small.camera.fx == small.camera.fy == 723.0 * factor
        np.testing.assert_allclose(small.rgb, view.rgb[:h * k].reshape(h, k, w, k, 3).mean(axis=(1, 3)), rtol=1e-5)
        points = rng.normal(size=(10, 3)) * 0.5
        np.testing.assert_allclose(project(small.camera, points), factor * project(camera, points), rtol=1e-12)
        sensor_dict(small.camera)                                          # square pixels: accepted


def test_read_capture_downsamples_as_it_reads(tmp_path):
    png(tmp_path / "a.png", np.full((8, 12, 3), 128))
    path = transforms(tmp_path, [{"file_path": "a.png"}], fl_x=10.0)
    view = read_capture(path, factor=0.5).views[0]
    assert (view.camera.width, view.camera.height, view.camera.fx, view.camera.cx) == (6, 4, 5.0, 3.0)
    with pytest.raises(ValueError, match=exactly("read_capture(): expected a factor in (0, 1] (downsampling only), "
                                                 "got 2.0")):
        read_capture(path, factor=2.0)


# ---------------------------------------------------------------- refusals


def test_refuses_missing_unreadable_or_frameless_json(tmp_path):
    missing = tmp_path / "nope.json"
    assert read_error(missing) == (f"read_capture(): expected a readable JSON file '{missing}', got "
                                   "FileNotFoundError: No such file or directory")
    broken = tmp_path / "broken.json"
    broken.write_text("{frames: [}")
    assert read_error(broken).startswith(f"read_capture(): expected a JSON file '{broken}', got JSONDecodeError: ")
    for text, got in [("[]", "list"), ('{"camera_angle_x": 1}', None), ('{"frames": []}', "[]")]:
        broken.write_text(text)
        what = "a JSON object" if got == "list" else "a non-empty list 'frames'"
        assert read_error(broken) == f"read_capture(): expected {what} in '{broken}', got {got or 'none'}"


@pytest.mark.parametrize("frame, top, message", [
    ({"file_path": "absent"}, {},
     "an existing image file for frames[0].file_path in '{json}', got none of '{dir}/absent.png', "
     "'{dir}/absent.jpg', '{dir}/absent.jpeg', '{dir}/absent.exr'"),
    ({"file_path": "absent.png"}, {},
     "an existing image file for frames[0].file_path in '{json}', got no file '{dir}/absent.png'"),
    ({"file_path": "notes.txt"}, {},
     "a .png, .jpg, .jpeg, .exr image for frames[0].file_path in '{json}', got '{dir}/notes.txt'"),
    ({}, {}, "a file name for frames[0].file_path in '{json}', got none"),
    ({"file_path": "garbage.png"}, {},
     "a readable image for frames[0].file_path in '{json}', got '{dir}/garbage.png': UnidentifiedImageError: "
     "cannot identify image file '{dir}/garbage.png'"),
    ({"file_path": "ok.png", "w": 9}, {},
     "the size of the image (8 x 6) for frames[0].w in '{json}', got 9"),
    ({"file_path": "ok.png"}, {"h": 5},
     "the size of the image (8 x 6) for h (top level, for frames[0]) in '{json}', got 5"),
    ({"file_path": "ok.png", "transform_matrix": [[1, 0, 0, 0]] * 3}, {},
     "a 4 x 4 matrix for frames[0].transform_matrix in '{json}', got shape (3, 4)"),
    ({"file_path": "ok.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, None], [0, 0, 0, 1]]}, {},
     "a finite matrix for frames[0].transform_matrix in '{json}', got nan at row 2, column 3"),
    ({"file_path": "ok.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 0], [0, 0, 0, 1]]}, {},
     "an invertible matrix for frames[0].transform_matrix in '{json}', got a singular 3 x 3 block "
     "(determinant 0)"),
    ({"file_path": "ok.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}, {},
     "a last row (0, 0, 0, 1) for frames[0].transform_matrix in '{json}', got [0.0, 0.0, 1.0, 1.0]"),
    ({"file_path": "ok.png", "transform_matrix": [[1, 0, 0, "x"]] * 4}, {},
     "a 4 x 4 matrix of numbers for frames[0].transform_matrix in '{json}', got [[1, 0, 0, 'x'], [1, 0, 0, 'x'], "
     "[1, 0, 0, 'x'], [1, 0, 0, 'x']]"),
    ({"file_path": "ok.png", "w": 8.5}, {}, "a positive integer for frames[0].w in '{json}', got 8.5"),
    ({"file_path": "ok.png", "fl_x": 5.0, "mask_path": "gone.png"}, {},
     "an existing image file for frames[0].mask_path in '{json}', got no file '{dir}/gone.png'"),
    ({"file_path": "ok.png", "transform_matrix": None}, {},
     "a camera-to-world 4 x 4 matrix for frames[0].transform_matrix in '{json}', got none"),
    ({"file_path": "ok.png"}, {"camera_angle_x": None},
     "intrinsics fl_x or camera_angle_x (per frame or at the top level) for frames[0] in '{json}', got neither"),
    ({"file_path": "ok.png", "fl_x": 0.0}, {}, "a focal length > 0 for frames[0].fl_x in '{json}', got 0.0"),
    ({"file_path": "ok.png"}, {"fl_x": 5.0, "fl_y": -5.0},
     "a focal length > 0 for fl_y (top level, for frames[0]) in '{json}', got -5.0"),
    ({"file_path": "ok.png", "fl_x": "5"}, {}, "a focal length > 0 for frames[0].fl_x in '{json}', got '5'"),
    ({"file_path": "ok.png"}, {"camera_angle_x": 3.5},
     "an angle in (0, pi) radians for camera_angle_x (top level, for frames[0]) in '{json}', got 3.5"),
    ({"file_path": "ok.png", "fl_x": 5.0}, {"camera_model": "EQUIRECTANGULAR"},
     "a camera model mi_loop reads (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, "
     "OPENCV_FISHEYE) for camera_model (top level, for frames[0]) in '{json}', got 'EQUIRECTANGULAR'"),
    ({"file_path": "ok.png", "fl_x": 5.0, "camera_model": "OPENCV_FISHEYE", "p1": 0.01}, {},
     "0 (camera_model OPENCV_FISHEYE has no p1) for frames[0].p1 in '{json}', got 0.01"),
    ({"file_path": "ok.png", "fl_x": 5.0, "camera_model": "SIMPLE_RADIAL", "k2": -0.1}, {},
     "0 (camera_model SIMPLE_RADIAL has no k2) for frames[0].k2 in '{json}', got -0.1"),
    ({"file_path": "ok.png", "fl_x": 5.0, "k4": 0.01}, {},
     "0 (camera_model OPENCV (the default) has no k4) for frames[0].k4 in '{json}', got 0.01"),
    ({"file_path": "ok.png", "fl_x": 5.0, "is_fisheye": True, "camera_model": "OPENCV"}, {},
     "false for camera_model OPENCV for frames[0].is_fisheye in '{json}', got True"),
    ({"file_path": "ok.png", "fl_x": 5.0, "k1": "0.1"}, {}, "a finite number for frames[0].k1 in '{json}', got '0.1'"),
    ({"file_path": "clear.png", "fl_x": 5.0}, {},
     "a mask with some foreground for frames[0].file_path in '{json}', got an image whose alpha is zero "
     "everywhere (an empty mask)"),
    ({"file_path": "ok.png", "fl_x": 5.0, "mask_path": "black.png"}, {},
     "a mask with some foreground for frames[0].mask_path in '{json}', got an empty mask (all zero)"),
    ({"file_path": "ok.png", "fl_x": 5.0, "mask_path": "small.png"}, {},
     "a mask of the image's size 8 x 6 for frames[0].mask_path in '{json}', got 4 x 3 in '{dir}/small.png'"),
])
def test_refuses_bad_frames_naming_file_frame_and_field(tmp_path, frame, top, message):
    png(tmp_path / "ok.png", np.full((6, 8, 3), 50))
    png(tmp_path / "clear.png", np.zeros((6, 8, 4)))
    png(tmp_path / "black.png", np.zeros((6, 8)))
    png(tmp_path / "small.png", np.full((3, 4), 255))
    (tmp_path / "garbage.png").write_bytes(b"not a png")
    (tmp_path / "notes.txt").write_text("x")
    top_level = bool(top)
    top = {"camera_angle_x": 0.9, **top}
    top = {k: v for k, v in top.items() if v is not None}
    good = {"file_path": "ok.png"}
    path = transforms(tmp_path, [good, frame], **top)
    if not top_level:                                          # else the good frame fails first
        message = message.replace("frames[0]", "frames[1]")
    expected = message.format(json=path, dir=tmp_path)
    assert read_error(path) == "read_capture(): expected " + expected


def test_refuses_non_finite_exr_pixels_odd_channels_and_masks_outside_0_1(tmp_path):
    import mitsuba as mi

    pixels = np.ones((4, 4, 3), np.float32)
    pixels[2, 1, 0] = np.nan
    mi.Bitmap(pixels).write(str(tmp_path / "nan.exr"))
    mi.Bitmap(np.ones((4, 4, 5), np.float32)).write(str(tmp_path / "five.exr"))
    mi.Bitmap(np.full((4, 4, 1), 2.0, np.float32)).write(str(tmp_path / "bright.exr"))
    mi.Bitmap(np.ones((4, 4, 3), np.float32)).write(str(tmp_path / "ok.exr"))
    for frame, message in [
            ({"file_path": "nan.exr"}, "finite pixels for frames[0].file_path in '{json}', got nan at pixel [2, 1] "
             "of '{dir}/nan.exr'"),
            ({"file_path": "five.exr"}, "a grey, grey + alpha, RGB or RGBA image for frames[0].file_path in "
             "'{json}', got PixelFormat.MultiChannel in '{dir}/five.exr'"),
            ({"file_path": "ok.exr", "mask_path": "bright.exr"}, "mask values in [0, 1] for frames[0].mask_path in "
             "'{json}', got 2.0 at pixel [0, 0]")]:
        path = transforms(tmp_path, [frame], fl_x=4.0)
        assert read_error(path) == "read_capture(): expected " + message.format(json=path, dir=tmp_path)


def test_refuses_a_frame_that_is_not_an_object(tmp_path):
    path = transforms(tmp_path, [], camera_angle_x=1.0)
    path.write_text(json.dumps({"camera_angle_x": 1.0, "frames": ["r_0.png"]}))
    assert read_error(path) == f"read_capture(): expected a JSON object for frames[0] in '{path}', got 'r_0.png'"


def test_camera_and_view_refuse_bad_fields():
    eye = np.eye(4)
    cases = [
        (lambda: Camera(eye[:3], 1.0, 1.0, 0.0, 0.0, 4, 4), "Camera(): expected c2w: a 4 x 4 matrix, got shape (3, 4)"),
        (lambda: Camera(eye, 0.0, 1.0, 0.0, 0.0, 4, 4), "Camera(): expected a finite fx > 0, got 0.0"),
        (lambda: Camera(eye, 1.0, 1.0, math.nan, 0.0, 4, 4), "Camera(): expected a finite cx, got nan"),
        (lambda: Camera(eye, 1.0, 1.0, 0.0, 0.0, 4.0, 4), "Camera(): expected an integer width >= 1, got 4.0"),
        (lambda: Camera(eye, 1.0, 1.0, 0.0, 0.0, 4, 4).scaled(0.1),
         "Camera.scaled(): expected a factor that leaves at least one of 4 pixels, got 0.1"),
        (lambda: Camera(eye, 1.0, 1.0, 0.0, 0.0, 4, 4).scaled(-1.0),
         "Camera.scaled(): expected a finite factor > 0, got -1.0"),
    ]
    camera = Camera(eye, 1.0, 1.0, 0.0, 0.0, 4, 2)
    cases += [
        (lambda: View(camera, np.zeros((4, 2, 3)), np.ones((2, 4)), "v"),
         "View(): expected rgb of shape (h, w, 3) = (2, 4, 3) as the camera, got shape (4, 2, 3)"),
        (lambda: View(camera, np.zeros((2, 4, 3)), np.ones((2, 4, 1)), "v"),
         "View(): expected a mask of shape (h, w) = (2, 4) as the camera, got shape (2, 4, 1)"),
        (lambda: View(camera, np.full((2, 4, 3), np.inf), np.ones((2, 4)), "v"),
         "View(): expected finite rgb, got inf at pixel [0, 0]"),
        (lambda: View(camera, np.zeros((2, 4, 3)), np.full((2, 4), 1.5), "v"),
         "View(): expected mask values in [0, 1], got 1.5 at pixel [0, 0]"),
        (lambda: View(camera, np.zeros((2, 4, 3)), np.ones((2, 4)), "v").resized(1.5),
         "View.resized(): expected a factor in (0, 1] (downsampling only), got 1.5"),
    ]
    for make, message in cases:
        with pytest.raises(ValueError, match=exactly(message)):
            make()
    with pytest.raises(TypeError, match=exactly("View(): expected a Camera, got NoneType")):
        View(None, np.zeros((2, 4, 3)), np.ones((2, 4)), "v")


def test_cameras_compare_and_hash_by_value():
    a = Camera(np.eye(4), 1.0, 1.0, 2.0, 2.0, 4, 4)
    b = Camera(np.eye(4).tolist(), 1, 1, 2, 2, 4, 4)
    assert a == b and hash(a) == hash(b) and a != a.scaled(0.5)
    assert not a.c2w.flags.writeable
