"""Camera formats of real captures (mi_loop.io.camera_formats): IDR / NeuS, LLFF, COLMAP text and binary.

Each format is checked against an independent oracle: a scene of known
OpenCV cameras ``x_cam = R X + t`` with ``K`` (``fx != fy``) and known points is
written in the format's own convention (IDR: ``P = s K [R | t]``, pixel centres
at integer coordinates; COLMAP: world-to-camera quaternions, pixel centres at
half-integers; LLFF: [down, right, back] columns and ``(h, w, focal)``), read by
:func:`load_meta`, and :func:`mi_loop.render.cameras.project` must put the points
where the format's own projection does, in the corner convention.
"""
from __future__ import annotations

import struct

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from mi_loop.io.camera_formats import FORMATS, detect, load_meta
from mi_loop.io.colmap import ColmapImage, colmap_model_kind, read_colmap_model
from mi_loop.io.views import Camera
from mi_loop.render.cameras import project

from helpers import DATA, exactly, value_error

W, H = 64, 48
POINTS = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [-0.25, 0.15, -0.3], [0.1, 0.35, 0.2], [-0.2, -0.3, 0.25]])
EYES = np.array([[2.5, 0.4, 0.6], [-0.8, 2.2, -0.5], [0.3, -1.1, 2.4]])
#: Intrinsics (fx, fy, cx, cy) of the three cameras, fx != fy.
INTRINSICS = [(60.0, 60.3, 31.7, 24.2), (55.5, 55.0, 30.1, 25.9), (70.2, 70.9, 33.3, 22.4)]


def opencv_pose(eye, target=(0.05, -0.02, 0.03)):
    """``R`` (rows: camera x right, y down, z forward in world coordinates) and ``t`` of a camera at ``eye``."""
    z = np.subtract(target, eye) / np.linalg.norm(np.subtract(target, eye))
    x = np.cross([0.0, 0.0, -1.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ eye


def K_matrix(fx, fy, cx, cy, skew=0.0):
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def pinhole_pixels(K, R, t, points=POINTS):
    """``K (R X + t)`` divided by depth: pixels in the format's own convention."""
    x = (points @ R.T + t) @ K.T
    return x[:, :2] / x[:, 2:]


def camera(frame) -> Camera:
    """The camera of a frame, built as read_capture builds it."""
    return Camera(np.asarray(frame["transform_matrix"]), frame["fl_x"], frame["fl_y"], frame["cx"], frame["cy"],
                  frame["w"], frame["h"])


def images(directory, names, size=(W, H), mode="RGB"):
    directory.mkdir(parents=True, exist_ok=True)
    for name in names:
        Image.new(mode, size, 128).save(directory / name)
    return directory


def error(path, **kwargs) -> str:
    return value_error(load_meta, path, function="load_meta", **kwargs)


# ------------------------------------------------------------------------------------------------ IDR / NeuS


def write_idr(root, scales=(1.0, -2.5, 0.01), K_of=K_matrix, n_masks=3, drop=()):
    """An IDR scene: world_mat_i = s_i K [R | t] (4 x 4), scale_mat_i, camera_mat_i, image/, mask/."""
    root.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for i, (eye, intr, s) in enumerate(zip(EYES, INTRINSICS, scales)):
        R, t = opencv_pose(eye)
        world = np.eye(4)
        world[:3] = s * K_of(*intr) @ np.hstack([R, t[:, None]])
        arrays[f"world_mat_{i}"] = world
        arrays[f"scale_mat_{i}"] = np.diag([0.6, 0.6, 0.6, 1.0])
        arrays[f"camera_mat_{i}"] = np.eye(4)
    for key in drop:
        arrays.pop(key)
    np.savez(root / "cameras_sphere.npz", **arrays)
    images(root / "image", [f"{i:06d}.png" for i in range(3)])
    images(root / "mask", [f"{i:03d}.png" for i in range(n_masks)], mode="L")
    return root


def test_idr_projects_as_its_projection_matrix_plus_half_a_pixel(tmp_path):
    write_idr(tmp_path)
    fmt, meta = load_meta(tmp_path)
    assert fmt == "idr" == detect(tmp_path) == detect(tmp_path / "cameras_sphere.npz")
    assert len(meta["frames"]) == 3
    for i, (frame, eye, intr) in enumerate(zip(meta["frames"], EYES, INTRINSICS)):
        R, t = opencv_pose(eye)
        oracle = pinhole_pixels(K_matrix(*intr), R, t) + 0.5          # integer pixel centres -> corner convention
        np.testing.assert_allclose(project(camera(frame), POINTS), oracle, atol=1e-6, rtol=0)
        assert (frame["w"], frame["h"], frame["camera_model"]) == (W, H, "PINHOLE")
        assert frame["file_path"] == str(tmp_path / "image" / f"{i:06d}.png")
        assert frame["mask_path"] == str(tmp_path / "mask" / f"{i:03d}.png")
        np.testing.assert_allclose(np.asarray(frame["transform_matrix"])[:3, 3], eye, atol=1e-9)
    np.testing.assert_array_equal(meta["normalisation"], np.diag([0.6, 0.6, 0.6, 1.0]))


def test_idr_refusals(tmp_path):
    root = write_idr(tmp_path / "masks2", n_masks=2)
    assert error(root) == (f"expected one mask per image (3 in '{root / 'image'}') in '{root / 'mask'}', got 2")
    root = write_idr(tmp_path / "count", drop=("world_mat_2",))
    assert error(root) == (f"expected one world_mat_i per image of image/ (3) in '{root / 'cameras_sphere.npz'}', "
                           "got 2")
    root = write_idr(tmp_path / "gap", drop=("world_mat_1",))
    np.savez(root / "cameras_sphere.npz", **dict(np.load(root / "cameras_sphere.npz")), world_mat_7=np.eye(4))
    assert error(root) == (f"expected world_mat_1 in '{root / 'cameras_sphere.npz'}' (keys world_mat_0 ... "
                           "world_mat_2), got no such key")
    root = write_idr(tmp_path / "skew", K_of=lambda fx, fy, cx, cy: K_matrix(fx, fy, cx, cy, skew=5.0))
    message = error(root)
    assert message.startswith(f"expected no skew in world_mat_0 in '{root / 'cameras_sphere.npz'}' (mi_loop's "
                              "cameras have none; up to 0.01 px is dropped), got a skew of 5 moving pixels by ")
    root = write_idr(tmp_path / "singular", K_of=lambda fx, fy, cx, cy: np.diag([fx, fy, 0.0]))
    assert error(root) == ("expected a projection matrix with an invertible 3 x 3 block for world_mat_0 in "
                           f"'{root / 'cameras_sphere.npz'}', got a singular one")
    root = write_idr(tmp_path / "nomask")
    for p in (root / "mask").iterdir():
        p.unlink()
    (root / "mask").rmdir()
    assert error(root) == f"expected a mask directory '{root / 'mask'}', got no such directory"
    assert load_meta(root, masks=tmp_path / "count" / "mask")[1]["frames"][2]["mask_path"] == \
        str(tmp_path / "count" / "mask" / "002.png")
    (root / "cameras_sphere.npz").write_bytes(b"not a zip")
    message = error(root, masks=tmp_path / "count" / "mask")
    assert message.startswith(f"expected a readable .npz file, got '{root / 'cameras_sphere.npz'}': ")


# ------------------------------------------------------------------------------------------------------- LLFF


def write_llff(root, factor=2, rows=None, image_size=(W, H), masks=True):
    """An LLFF scene at full size (factor * W) x (factor * H), focal f, its images stored downsampled."""
    root.mkdir(parents=True, exist_ok=True)
    out = []
    for i, eye in enumerate(EYES):
        R, t = opencv_pose(eye)
        pose = np.stack([R[1], R[0], -R[2], eye, [factor * H, factor * W, factor * (50.0 + 5 * i)]], axis=1)
        out.append(np.concatenate([pose.ravel(), [0.5 + i, 6.0 + i]]))
    np.save(root / "poses_bounds.npy", np.array(out) if rows is None else rows)
    images(root / "images", ["IMG_2.JPG", "IMG_0.JPG", "IMG_1.JPG"], size=image_size)
    if masks:
        images(root / "masks", ["IMG_2.png", "IMG_0.png", "IMG_1.png"], size=image_size, mode="L")
    return root


def test_llff_projects_as_a_centred_pinhole_of_its_focal_scaled_to_the_images(tmp_path):
    write_llff(tmp_path)
    fmt, meta = load_meta(tmp_path)
    assert fmt == "llff" == detect(tmp_path / "poses_bounds.npy")
    for i, (frame, eye) in enumerate(zip(meta["frames"], EYES)):
        R, t = opencv_pose(eye)
        f = 50.0 + 5 * i                                               # 2 (50 + 5 i) at twice the size
        oracle = pinhole_pixels(K_matrix(f, f, W / 2, H / 2), R, t)
        np.testing.assert_allclose(project(camera(frame), POINTS), oracle, atol=1e-6, rtol=0)
        assert frame["file_path"] == str(tmp_path / "images" / f"IMG_{i}.JPG")
        assert frame["mask_path"] == str(tmp_path / "masks" / f"IMG_{i}.png")
    assert meta["bounds"] == [[0.5, 6.0], [1.5, 7.0], [2.5, 8.0]]
    frames = load_meta(write_llff(tmp_path / "unmasked", masks=False))[1]["frames"]
    assert not any("mask_path" in frame for frame in frames)


def test_llff_refusals(tmp_path):
    root = write_llff(tmp_path / "shape", rows=np.zeros((3, 15)))
    assert error(root) == ("expected an N x 17 array of numbers (3 x 5 pose and hwf, near, far per image) in "
                           f"'{root / 'poses_bounds.npy'}', got shape (3, 15) of float64")
    rows = np.load(write_llff(tmp_path / "rows") / "poses_bounds.npy")
    np.save(tmp_path / "rows" / "poses_bounds.npy", rows[:2])
    assert error(tmp_path / "rows") == (f"expected one row of '{tmp_path / 'rows' / 'poses_bounds.npy'}' per image "
                                        f"of '{tmp_path / 'rows' / 'images'}' (3), got 2")
    root = write_llff(tmp_path / "aspect", image_size=(W, W))
    assert error(root) == (f"expected an image of the aspect ratio of row 0 of '{root / 'poses_bounds.npy'}' "
                           f"(128 x 96), got 64 x 64 in '{root / 'images' / 'IMG_0.JPG'}'")
    rows[1, 7] = np.nan
    np.save(write_llff(tmp_path / "nan") / "poses_bounds.npy", rows)
    assert error(tmp_path / "nan") == f"expected finite numbers in '{tmp_path / 'nan' / 'poses_bounds.npy'}', " \
                                      "got nan in row 1"
    rows[1, 7], rows[0, 14] = 0.0, -1.0
    np.save(write_llff(tmp_path / "focal") / "poses_bounds.npy", rows)
    assert error(tmp_path / "focal") == (f"expected h, w, focal > 0 in row 0 of "
                                         f"'{tmp_path / 'focal' / 'poses_bounds.npy'}', got 96, 128, -1")
    assert error(tmp_path / "focal", masks=tmp_path / "none") == \
        f"expected a mask directory '{tmp_path / 'none'}', got no such directory"


# ----------------------------------------------------------------------------------------------------- COLMAP

#: Image names (written out of order), camera ids, and the COLMAP model and params of each camera.
COLMAP_IMAGES = [("c.jpg", 3), ("a.jpg", 1), ("b.jpg", 2)]
COLMAP_CAMERAS = {1: ("PINHOLE", [60.0, 60.3, 31.7, 24.2]), 2: ("SIMPLE_PINHOLE", [55.5, 30.1, 25.9]),
                  3: ("OPENCV", [70.2, 70.9, 33.3, 22.4, 0.01, -0.002, 0.0003, -0.0004])}
MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4, "OPENCV_FISHEYE": 5}


def colmap_K(model, params):
    if model == "SIMPLE_PINHOLE":
        return K_matrix(params[0], params[0], params[1], params[2])
    return K_matrix(*params[:4])


def colmap_w2c(name):
    """The world-to-camera quaternion (w, x, y, z) and translation of image ``name`` (eye by name)."""
    R, t = opencv_pose(EYES["abc".index(name[0])])
    x, y, z, w = Rotation.from_matrix(R).as_quat().tolist()
    return [w, x, y, z], t.tolist()


def write_colmap(root, binary, cameras=None, images_=COLMAP_IMAGES, model_ids=MODEL_IDS):
    """``root/sparse/0/{cameras,images}.{bin,txt}`` as COLMAP's read_write_model.py writes them, images/, masks/."""
    cameras = COLMAP_CAMERAS if cameras is None else cameras
    model = root / "sparse" / "0"
    model.mkdir(parents=True)
    rows = [(k + 1, *colmap_w2c(name), cam, name) for k, (name, cam) in enumerate(images_)]
    if binary:
        data = struct.pack("<Q", len(cameras))
        for cam_id, (name, params) in cameras.items():
            data += struct.pack("<iiQQ", cam_id, model_ids[name], W, H) + struct.pack(f"<{len(params)}d", *params)
        (model / "cameras.bin").write_bytes(data)
        data = struct.pack("<Q", len(rows))
        for image_id, q, t, cam, name in rows:
            data += struct.pack("<idddddddi", image_id, *q, *t, cam) + name.encode() + b"\x00"
            data += struct.pack("<Q", 2) + struct.pack("<ddqddq", 1.5, 2.5, 7, 3.0, 4.0, -1)
        (model / "images.bin").write_bytes(data)
    else:
        lines = ["# Camera list with one line of data per camera:", ""]
        lines += [f"{cam_id} {name} {W} {H} " + " ".join(map(repr, params)) for cam_id, (name, params)
                  in cameras.items()]
        (model / "cameras.txt").write_text("\n".join(lines) + "\n")
        lines = ["# Image list with two lines of data per image:", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
        for k, (image_id, q, t, cam, name) in enumerate(rows):
            lines += [" ".join(map(repr, [image_id, *q, *t, cam])) + f" {name}", "" if k else "1.5 2.5 7 3.0 4.0 -1"]
        (model / "images.txt").write_text("\n".join(lines) + "\n")
    images(root / "images", [name for name, _ in images_])
    images(root / "masks", ["a.jpg", "b.jpg.png", "c.png"], mode="L")
    return model


@pytest.mark.parametrize("binary", [True, False], ids=["bin", "txt"])
def test_colmap_projects_as_its_own_pinhole_with_no_shift(tmp_path, binary):
    model = write_colmap(tmp_path, binary)
    assert detect(tmp_path) == detect(model) == detect(model / f"cameras.{'bin' if binary else 'txt'}") == "colmap"
    fmt, meta = load_meta(tmp_path)
    assert fmt == "colmap"
    assert [f["file_path"] for f in meta["frames"]] == [str(tmp_path / "images" / n) for n in ("a.jpg", "b.jpg",
                                                                                                "c.jpg")]
    assert [f["mask_path"] for f in meta["frames"]] == [str(tmp_path / "masks" / n) for n in ("a.jpg", "b.jpg.png",
                                                                                              "c.png")]
    for frame, (name, cam) in zip(meta["frames"], sorted(COLMAP_IMAGES)):
        q, t = colmap_w2c(name)
        R = Rotation.from_quat([*q[1:], q[0]]).as_matrix()
        oracle = pinhole_pixels(colmap_K(*COLMAP_CAMERAS[cam]), R, t)
        np.testing.assert_allclose(project(camera(frame), POINTS), oracle, atol=1e-6, rtol=0)
        assert frame["camera_model"] == COLMAP_CAMERAS[cam][0] and (frame["w"], frame["h"]) == (W, H)
    assert {k: meta["frames"][2][k] for k in ("k1", "k2", "p1", "p2")} == \
        {"k1": 0.01, "k2": -0.002, "p1": 0.0003, "p2": -0.0004}
    assert not any(k in meta["frames"][0] for k in ("k1", "k2", "k3", "k4", "p1", "p2"))


def test_read_colmap_model_gives_world_to_camera_rotations_sorted_by_name(tmp_path):
    model = write_colmap(tmp_path / "bin", True)
    write_colmap(tmp_path / "txt", False)
    (model / "cameras.txt").write_text("")                             # binary is read first
    assert colmap_model_kind(model) == ".bin" and colmap_model_kind(tmp_path / "txt" / "sparse" / "0") == ".txt"
    cameras, images = read_colmap_model(model)
    assert [im.name for im in images] == ["a.jpg", "b.jpg", "c.jpg"]
    for im in images:
        R, t = opencv_pose(EYES["abc".index(im.name[0])])
        assert isinstance(im, ColmapImage) and im.where.startswith("image ")
        np.testing.assert_allclose(im.R, R, atol=1e-12)
        np.testing.assert_allclose(im.t, t, atol=1e-12)
        assert cameras[im.camera_id]["camera_model"] == COLMAP_CAMERAS[im.camera_id][0]
    assert cameras[2] == {"camera_model": "SIMPLE_PINHOLE", "fl_x": 55.5, "fl_y": 55.5, "cx": 30.1, "cy": 25.9,
                          "w": W, "h": H}
    assert colmap_model_kind(tmp_path) is None
    with pytest.raises(ValueError, match=exactly("read_colmap_model(): expected a COLMAP model (cameras + images, "
                                                 f".bin or .txt), got none in '{tmp_path}'")):
        read_colmap_model(tmp_path)


@pytest.mark.parametrize("model, params, expected", [
    ("SIMPLE_RADIAL", [50.0, 31.0, 23.0, 0.1], {"fl_x": 50.0, "fl_y": 50.0, "cx": 31.0, "cy": 23.0, "k1": 0.1}),
    ("RADIAL", [50.0, 31.0, 23.0, 0.1, -0.2],
     {"fl_x": 50.0, "fl_y": 50.0, "cx": 31.0, "cy": 23.0, "k1": 0.1, "k2": -0.2}),
])
def test_colmap_radial_models_map_their_parameters(tmp_path, model, params, expected):
    for binary in (True, False):
        root = tmp_path / str(binary)
        write_colmap(root, binary, cameras={c: (model, params) for c in (1, 2, 3)})
        frame = load_meta(root)[1]["frames"][0]
        assert {k: frame[k] for k in expected} == expected and frame["camera_model"] == model


def test_colmap_refusals(tmp_path):
    fisheye = {c: ("OPENCV_FISHEYE", [50.0, 50.0, 31.0, 23.0, 0.1, 0.0, 0.0, 0.0]) for c in (1, 2, 3)}
    model = write_colmap(tmp_path / "fisheye_bin", True, cameras=fisheye)
    assert error(tmp_path / "fisheye_bin") == (
        "expected a camera model SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV for camera 1 in "
        f"'{model / 'cameras.bin'}', got 'OPENCV_FISHEYE'")
    model = write_colmap(tmp_path / "fisheye_txt", False, cameras=fisheye)
    assert error(tmp_path / "fisheye_txt") == (
        "expected a camera model SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV for line 3 of "
        f"'{model / 'cameras.txt'}', got 'OPENCV_FISHEYE'")
    model = write_colmap(tmp_path / "id", True, model_ids={**MODEL_IDS, "PINHOLE": 99})
    assert error(model) == f"expected a COLMAP camera model id 0 ... 10 for camera 1 in '{model / 'cameras.bin'}', " \
                           "got 99"
    model = write_colmap(tmp_path / "params", False, cameras={**COLMAP_CAMERAS, 2: ("PINHOLE", [1.0, 2.0])})
    assert error(model) == ("expected 4 finite parameters (fl_x, fl_y, cx, cy) of PINHOLE for line 4 of "
                            f"'{model / 'cameras.txt'}', got [1.0, 2.0]")
    model = write_colmap(tmp_path / "camid", False, images_=[("a.jpg", 1), ("b.jpg", 9)])
    assert error(model) == f"expected a camera of '{model / 'cameras.txt'}' for line 5 of " \
                           f"'{model / 'images.txt'}', got camera id 9"
    model = write_colmap(tmp_path / "truncated", True)
    (model / "images.bin").write_bytes((model / "images.bin").read_bytes()[:-10])
    assert error(model) == f"expected a complete COLMAP binary file, got '{model / 'images.bin'}' truncated at " \
                           f"byte {(model / 'images.bin').stat().st_size}"
    (model / "images.bin").write_bytes(struct.pack("<Qi7di", 1, 1, 1, 0, 0, 0, 0, 0, 0, 1) + b"a.jpg")
    assert error(model) == f"expected a complete COLMAP binary file, got '{model / 'images.bin'}' truncated in " \
                           "an image name"
    model = write_colmap(tmp_path / "malformed", False)
    (model / "images.txt").write_text("1 1 0 0 0 x 0 0 1 a.jpg\n\n")
    assert error(model) == ("expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME on line 1 of "
                            f"'{model / 'images.txt'}', got '1 1 0 0 0 x 0 0 1 a.jpg'")
    (model / "images.txt").write_text("1 0 0 0 0 0 0 0 1 a.jpg\n\n")
    assert error(model) == f"expected a non-zero finite quaternion for line 1 of '{model / 'images.txt'}', " \
                           "got [0.0, 0.0, 0.0, 0.0]"
    (model / "images.txt").write_text("# nothing\n")
    assert error(model) == f"expected at least one image in '{model / 'images.txt'}', got none"
    (model / "cameras.txt").write_text("1 PINHOLE 64\n")
    assert error(model) == ("expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS... on line 1 of "
                            f"'{model / 'cameras.txt'}', got '1 PINHOLE 64'")


def test_colmap_refuses_missing_images_and_masks(tmp_path):
    model = write_colmap(tmp_path, False)
    (tmp_path / "masks" / "c.png").unlink()
    assert error(model) == (f"expected a mask for '{tmp_path / 'images' / 'c.jpg'}', got none of "
                            f"'{tmp_path / 'masks' / 'c.jpg'}', '{tmp_path / 'masks' / 'c.jpg.png'}', "
                            f"'{tmp_path / 'masks' / 'c.png'}'")
    frames = load_meta(model, masks=images(tmp_path / "other", ["a.jpg", "b.jpg", "c.jpg"]))[1]["frames"]
    assert frames[2]["mask_path"] == str(tmp_path / "other" / "c.jpg")
    assert error(model, masks=tmp_path / "none") == \
        f"expected a mask directory '{tmp_path / 'none'}' (or pass masks=), got no such directory"
    (tmp_path / "images" / "b.jpg").unlink()
    assert error(model) == (f"expected the image file of line 7 of '{model / 'images.txt'}', got no "
                            f"'{tmp_path / 'images' / 'b.jpg'}'")
    (tmp_path / "images").rename(tmp_path / "pictures")
    assert error(model) == f"expected an images/ directory in '{model}' or up to two levels up, got none"


# ------------------------------------------------------------------------------------------ detection, transforms


def test_detect_names_what_it_looked_for(tmp_path):
    looked_for = ("a capture: transforms.json, cameras_sphere.npz or cameras.npz (IDR), poses_bounds.npy (LLFF) "
                  "or a COLMAP model (cameras + images .bin or .txt, in the directory, sparse/0/ or sparse/)")
    with pytest.raises(ValueError, match=exactly(f"detect(): expected {looked_for}, got none of them in "
                                                 f"'{tmp_path}'")):
        detect(tmp_path)
    assert error(tmp_path) == f"expected {looked_for}, got none of them in '{tmp_path}'"
    assert error(tmp_path / "nowhere") == f"expected an existing capture directory or a file in one, got no " \
                                          f"'{tmp_path / 'nowhere'}'"
    assert FORMATS == ("transforms", "idr", "llff", "colmap")


def test_transforms_json_is_returned_with_absolute_paths(tmp_path):
    (tmp_path / "transforms.json").write_text(
        '{"fl_x": 50, "frames": [{"file_path": "./train/r_0", "mask_path": "m/r_0.png", "transform_matrix": []}]}')
    fmt, meta = load_meta(tmp_path)
    assert fmt == "transforms" == detect(tmp_path / "transforms.json")
    assert meta == {"fl_x": 50, "frames": [{"file_path": str(tmp_path / "train" / "r_0"),
                                            "mask_path": str(tmp_path / "m" / "r_0.png"), "transform_matrix": []}]}
    images(tmp_path / "masks", ["r_0.png"], mode="L")
    assert load_meta(tmp_path, masks=tmp_path / "masks")[1]["frames"][0]["mask_path"] == str(tmp_path / "masks" /
                                                                                             "r_0.png")
    (tmp_path / "transforms.json").write_text('{"frames": 3}')
    assert error(tmp_path) == (f"expected a JSON object with a list of objects 'frames' in "
                               f"'{tmp_path / 'transforms.json'}', got {{'frames': 3}}")


# ------------------------------------------------------------------------------------------------- real data


def test_dtu_scan24_cameras_all_see_the_centre_of_the_scale_mat_sphere():
    root = DATA / "real" / "dtu_scan24"
    fmt, meta = load_meta(root)
    assert fmt == "idr" and len(meta["frames"]) == 49
    centre = np.asarray(meta["normalisation"])[:3, 3]
    for frame in meta["frames"]:
        x, y = project(camera(frame), [centre])[0]
        assert 0 < x < frame["w"] and 0 < y < frame["h"], (frame["file_path"], x, y)
        assert frame["fl_x"] != frame["fl_y"] and (frame["w"], frame["h"]) == (800, 600)


def test_ethiopian_head_optical_axes_meet_within_the_near_far_bounds():
    root = DATA / "real" / "ethiopian_head"
    fmt, meta = load_meta(root)
    assert fmt == "llff" and len(meta["frames"]) == 66
    c2w = np.array([f["transform_matrix"] for f in meta["frames"]])
    centres, axes = c2w[:, :3, 3], -c2w[:, :3, 2] / np.linalg.norm(c2w[:, :3, 2], axis=1)[:, None]
    across = np.eye(3) - axes[:, :, None] * axes[:, None, :]          # projections across each axis
    meet = np.linalg.solve(across.sum(0), np.einsum("kij,kj->i", across, centres))
    depth = np.einsum("ki,ki->k", meet - centres, axes)
    miss = np.linalg.norm(np.einsum("kij,kj->ki", across, meet - centres), axis=1)
    near, far = np.array(meta["bounds"]).T
    assert (miss < 0.1 * depth).all(), miss / depth
    # far is LLFF's 99.9th percentile of the depths of the points a view sees: a few views see only the side of
    # the head nearest to them, and the axes meet inside it, up to 7 % beyond their far bound
    assert ((near < depth) & (depth < 1.1 * far)).all(), np.c_[near, depth, far]


def test_a_sequence_lists_and_reads_captures_of_any_format_one_per_frame(tmp_path):
    """fit-sequence --images DIR: sub-directories holding IDR or LLFF captures count as frames, sorted, each
    read by read_capture as it is; a directory with none is refused naming what it looked for."""
    from mi_loop.io.capture import list_captures, read_capture

    write_idr(tmp_path / "seq" / "0001")
    write_llff(tmp_path / "seq" / "0000")
    (tmp_path / "seq" / "notes").mkdir()
    paths = list_captures([tmp_path / "seq"])
    assert paths == [tmp_path / "seq" / "0000", tmp_path / "seq" / "0001"]
    assert [read_capture(p).format for p in paths] == ["llff", "idr"]
    assert list_captures([tmp_path / "seq" / "0001"]) == [tmp_path / "seq" / "0001"]
    message = value_error(list_captures, [tmp_path / "seq" / "notes"], where="fit-sequence --images")
    assert message == ("fit-sequence --images: expected a directory holding transforms.json or a capture of "
                       "another format (IDR, LLFF, COLMAP), or sub-directories that do, got none in "
                       f"'{tmp_path / 'seq' / 'notes'}'")
