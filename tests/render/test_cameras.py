"""NeRF cameras in Mitsuba (mi_loop.render.cameras): renders against project(), the sensor, cameras framing a box.

The oracle of the conventions is Mitsuba itself: tiny emissive spheres at
known points, rendered through :func:`sensor_dict`, must light up where
:func:`project` puts them (intensity-weighted blob centroids, to 0.1 px),
for cameras read from ``transforms.json`` files in both intrinsics forms.
Cameras framing a box (orbits, rigs) reproduce the look-at sensors that
scenes used before :func:`sensor_dict` was the only one, and a sphere filling
the box's bounding sphere covers the disc the framing distance predicts.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from mi_loop.io.capture import Camera, read_capture
from mi_loop.render.cameras import (
    fibonacci_cameras,
    look_at,
    look_at_distance,
    orbit_camera,
    project,
    rig_cameras,
    sensor_dict,
)

from helpers import exactly, run_python, sphere_mesh

#: A tilted pose (rolled by an up vector off +Y) looking at a point off the origin.
POSE = look_at([1.0, 0.7, 3.0], [0.1, -0.2, 0.0], up=[0.3, 1.0, 0.0])


def camera_from_json(tmp_path, width, height, **intrinsics) -> Camera:
    """Read the camera of a one-frame ``transforms.json`` with POSE, a black image and ``intrinsics``."""
    Image.fromarray(np.zeros((height, width, 3), np.uint8)).save(tmp_path / "r_0.png")
    meta = {**intrinsics, "frames": [{"file_path": "./r_0", "transform_matrix": POSE.tolist()}]}
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    return read_capture(tmp_path / "transforms.json").views[0].camera


def pixel_targets(camera, spacing=12.0, margin=6.0):
    """Pixel positions on a jittered grid over the whole image (corners and edges included)."""
    rng = np.random.default_rng(3)
    xs = np.arange(margin, camera.width - margin + 1e-9, spacing)
    ys = np.arange(margin, camera.height - margin + 1e-9, spacing)
    uv = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    return uv + rng.uniform(-2, 2, uv.shape)


def unproject(camera, uv, depth):
    """World points seen at pixels ``uv`` at distance ``depth`` along the view axis (written from the axes)."""
    right, up, back, eye = (camera.c2w[:3, k] for k in range(4))
    x = (uv[:, 0] - camera.cx) / camera.fx
    y = -(uv[:, 1] - camera.cy) / camera.fy
    return eye + depth[:, None] * (x[:, None] * right + y[:, None] * up - back)


def blob_centroids(image):
    """Intensity-weighted centroids ``(n, 2)`` (x, y in pixels, top-left corner origin) of the lit blobs."""
    from scipy import ndimage

    labels, n = ndimage.label(image > 0)
    centres = np.array(ndimage.center_of_mass(image, labels, range(1, n + 1))).reshape(-1, 2)
    return centres[:, ::-1] + 0.5


def render_spheres(camera, points, radius_px=1.5, spp=256):
    """Render emissive spheres of about ``radius_px`` pixels at ``points`` on black; the red channel."""
    import mitsuba as mi

    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 1}, "sensor": sensor_dict(camera, spp=spp)}
    depth = -(points @ np.linalg.inv(camera.c2w)[:3, :3].T + np.linalg.inv(camera.c2w)[:3, 3])[:, 2]
    for k, (p, z) in enumerate(zip(points, depth)):
        scene[f"sphere_{k}"] = {"type": "sphere", "center": p.tolist(), "radius": float(radius_px * z / camera.fx),
                                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}}
    return np.asarray(mi.render(mi.load_dict(scene), seed=7))[..., 0]


CASES = {
    "centred, camera_angle_x, 64x64": (64, 64, {"camera_angle_x": 0.9}),
    "centred, camera_angle_x, 96x64": (96, 64, {"camera_angle_x": 1.1}),
    "off-centre, fl_x, 96x64": (96, 64, {"fl_x": 80.0, "fl_y": 80.0, "cx": 0.3 * 96, "cy": 0.72 * 64}),
    "off-centre, fl_x, 64x96": (64, 96, {"fl_x": 75.0, "cx": 44.5, "cy": 25.0}),
}


@pytest.mark.parametrize("case", CASES)
def test_mitsuba_renders_points_where_project_puts_them(tmp_path, case, jit_variant):
    """Spheres of 1.5 px radius at points seen at known pixels all over the image (depths 2.5-4.5), 256 spp.

    The blob centroids match the targets to 0.1 px (measured: at most 0.04-0.06 px, 0.02 on average; the
    perspective image of an off-axis sphere is centred a few hundredths of a
    pixel further out than its centre's image), and a point behind the camera
    lights nothing. A half-pixel shift, a flipped axis or a principal point
    offset of the wrong sign would be off by 0.5 px or more.
    """
    width, height, intrinsics = CASES[case]
    camera = camera_from_json(tmp_path, width, height, **intrinsics)
    uv = pixel_targets(camera)
    depth = np.random.default_rng(5).uniform(2.5, 4.5, len(uv))
    points = unproject(camera, uv, depth)
    np.testing.assert_allclose(project(camera, points), uv, atol=1e-9)
    behind = camera.c2w[:3, 3] + 3.0 * camera.c2w[:3, 2]          # mirrors the image centre
    image = render_spheres(camera, np.vstack([points, behind]))
    found = blob_centroids(image)
    assert len(found) == len(uv), f"{len(found)} blobs for {len(uv)} points"
    distance = np.linalg.norm(found[:, None] - uv[None], axis=2)
    np.testing.assert_allclose(distance.min(axis=0), 0.0, atol=0.1)
    np.testing.assert_array_equal(np.sort(distance.argmin(axis=1)), np.arange(len(uv)))


def test_sensor_dict_fields():
    camera = Camera(POSE, 50.0, 50.0, 20.0, 30.0, 64, 48)
    sensor = sensor_dict(camera, spp=8, near=0.5, far=20.0)
    assert sensor["type"] == "perspective" and sensor["fov_axis"] == "x"
    assert sensor["fov"] == pytest.approx(math.degrees(2 * math.atan(32 / 50)))
    assert sensor["principal_point_offset_x"] == pytest.approx(0.5 - 20 / 64)
    assert sensor["principal_point_offset_y"] == pytest.approx(0.5 - 30 / 48)
    assert (sensor["near_clip"], sensor["far_clip"]) == (0.5, 20.0)
    assert sensor["film"] == {"type": "hdrfilm", "width": 64, "height": 48, "pixel_format": "rgb",
                              "rfilter": {"type": "box"}, "sample_border": True}
    assert sensor["sampler"] == {"type": "independent", "sample_count": 8}
    to_world = np.array(sensor["to_world"].matrix, dtype=np.float64)
    np.testing.assert_allclose(to_world, POSE @ np.diag([-1, 1, -1, 1]), atol=1e-6)


def test_sensor_dict_refuses_what_mitsuba_cannot_image():
    anisotropic = Camera(POSE, 50.0, 50.01, 32.0, 24.0, 64, 48)
    with pytest.raises(ValueError, match=exactly(
            "sensor_dict(): expected square pixels, fx == fy within 1e-6 relative (Mitsuba's perspective sensor "
            "has one focal length and refuses scale in to_world; resample the image to square pixels), "
            "got fx = 50.0, fy = 50.01")):
        sensor_dict(anisotropic)
    sensor_dict(Camera(POSE, 50.0, 50.0 * (1 + 5e-7), 32.0, 24.0, 64, 48))      # within the tolerance
    scaled = POSE @ np.diag([1.0, 1.5, 1.0, 1.0])
    with pytest.raises(ValueError, match=exactly("sensor_dict(): expected a c2w whose 3 x 3 block is a rotation "
                                                 "(orthonormal within 1e-5; Mitsuba refuses scale in to_world), "
                                                 "got max |R^T R - I| = 1.25")):
        sensor_dict(Camera(scaled, 50.0, 50.0, 32.0, 24.0, 64, 48))
    camera = Camera(POSE, 50.0, 50.0, 32.0, 24.0, 64, 48)
    with pytest.raises(ValueError, match=exactly("sensor_dict(): expected an integer spp >= 1, got 0")):
        sensor_dict(camera, spp=0)
    with pytest.raises(ValueError, match=exactly("sensor_dict(): expected clip distances 0 < near < far < inf, "
                                                 "got near = 2.0, far = 1.0")):
        sensor_dict(camera, near=2.0, far=1.0)
    with pytest.raises(TypeError, match=exactly("sensor_dict(): expected a mi_loop.io.Camera, got dict")):
        sensor_dict({})


def test_sensor_dict_without_a_variant_says_so():
    code = """
import numpy as np
from mi_loop.io.capture import Camera
from mi_loop.render.cameras import sensor_dict
try:
    sensor_dict(Camera(np.eye(4), 10.0, 10.0, 8.0, 8.0, 16, 16))
except RuntimeError as exc:
    print(exc)
"""
    result = run_python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == ("sensor_dict(): expected a Mitsuba variant to be set (mi_loop.set_variant), "
                                     "got none")


def test_project_by_hand():
    camera = Camera(np.eye(4), 100.0, 80.0, 30.0, 20.0, 64, 48)
    uv = project(camera, [[0.0, 0.0, -2.0], [0.2, 0.1, -2.0], [-0.4, -0.2, -4.0], [0.0, 0.0, 1.0], [1.0, 0, 0]])
    np.testing.assert_allclose(uv[:3], [[30.0, 20.0], [40.0, 16.0], [20.0, 24.0]])
    assert np.isnan(uv[3:]).all()                     # behind the camera, in its plane
    moved = Camera(look_at([2.0, 1.0, 0.5], [0.0, 0.0, 0.0]), 100.0, 80.0, 30.0, 20.0, 64, 48)
    np.testing.assert_allclose(project(moved, [[0.0, 0.0, 0.0]]), [[30.0, 20.0]], atol=1e-12)
    with pytest.raises(ValueError, match=exactly("project(): expected points of shape (k, 3), got shape (3,)")):
        project(camera, [0.0, 0.0, -1.0])


def test_look_at_axes_and_poles():
    c2w = look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(c2w, [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 5], [0, 0, 0, 1]], atol=1e-15)
    for eye in ([0.0, 3.0, 0.0], [0.0, -3.0, 0.0]):               # straight above and below
        c2w = look_at(eye, [0.0, 0.0, 0.0])
        R = c2w[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(c2w[:3, 2], np.sign(eye[1]) * np.array([0, 1, 0]))
    with pytest.raises(ValueError, match=exactly("look_at(): expected an eye distinct from the target, "
                                                 "got both [1.0, 2.0, 3.0]")):
        look_at([1, 2, 3], [1, 2, 3])


def test_fibonacci_cameras_look_at_the_centre_from_radius_with_y_up():
    centre = np.array([0.3, -0.2, 1.0])
    cameras = fibonacci_cameras(40, centre, 2.5, fov_x_deg=40.0, width=48, height=32)
    assert len(cameras) == 40
    eyes = np.array([c.c2w[:3, 3] for c in cameras])
    np.testing.assert_allclose(np.linalg.norm(eyes - centre, axis=1), 2.5)
    for camera in cameras:
        np.testing.assert_allclose(project(camera, [centre]), [[24.0, 16.0]], atol=1e-9)
        R = camera.c2w[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert R[1, 1] > 0                                    # image up is +Y-ish
        assert R[1, 0] == pytest.approx(0.0, abs=1e-12)       # no roll: the image's x axis is horizontal
        assert camera.fx == camera.fy == pytest.approx(24 / math.tan(math.radians(20)))
    directions = (eyes - centre) / 2.5
    assert np.linalg.norm(directions.mean(axis=0)) < 0.05     # spread over the whole sphere
    assert directions[0, 1] > 0.95 and directions[-1, 1] < -0.95
    single = fibonacci_cameras(1, centre, 1.0, fov_x_deg=30.0, width=8, height=8)
    np.testing.assert_allclose(project(single[0], [centre]), [[4.0, 4.0]])


@pytest.mark.parametrize("kwargs, message", [
    ({"n": 0}, "fibonacci_cameras(): expected an integer n >= 1, got 0"),
    ({"radius": 0.0}, "fibonacci_cameras(): expected a finite radius > 0, got 0.0"),
    ({"fov_x_deg": 180.0}, "fibonacci_cameras(): expected fov_x_deg in (0, 180), got 180.0"),
    ({"center": [0.0, 1.0]}, "fibonacci_cameras(): expected a finite center of shape (3,), got [0.0, 1.0]"),
])
def test_fibonacci_cameras_refuse_bad_input(kwargs, message):
    args = {"n": 4, "center": [0.0, 0.0, 0.0], "radius": 1.0, "fov_x_deg": 40.0, "width": 8, "height": 8, **kwargs}
    n, center, radius = args.pop("n"), args.pop("center"), args.pop("radius")
    with pytest.raises(ValueError, match=exactly(message)):
        fibonacci_cameras(n, center, radius, **args)


# -- cameras framing a box ---------------------------------------------------------

#: An off-centre box (centre (0.1, 0.35, -0.15), half diagonal 0.5 sqrt(1.13)).
BOX = (np.array([-0.3, 0.1, -0.5]), np.array([0.5, 0.6, 0.2]))


def corners(bbox) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of a box."""
    lo, hi = bbox
    return np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


@pytest.mark.parametrize("azimuth, elevation, fov", [(35.0, 25.0, 35.0), (-120.0, -60.0, 50.0), (200.0, 85.0, 20.0),
                                                     (0.0, 0.0, 35.0)])
def test_orbit_camera_sensor_is_the_old_look_at_sensor(azimuth, elevation, fov):
    """Before cameras.sensor_dict was the only one, scene.sensor_dict built its to_world as Mitsuba's
    look_at from ``centre + look_at_distance(r, fov) * (cos e sin a, sin e, cos e cos a)`` to the box
    centre, +Y up, with ``fov`` about x and a centred film: the orbit camera's sensor is the same."""
    import mitsuba as mi

    lo, hi = BOX
    centre, radius = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    a, e = np.radians(azimuth), np.radians(elevation)
    direction = np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
    origin = centre + look_at_distance(radius, fov) * direction
    old = mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=centre.tolist(), up=[0, 1, 0])
    sensor = sensor_dict(orbit_camera(BOX, azimuth, elevation, fov=fov, resolution=40))
    np.testing.assert_allclose(np.array(sensor["to_world"].matrix), np.array(old.matrix), atol=1e-6)
    assert sensor["fov"] == pytest.approx(fov) and sensor["fov_axis"] == "x"
    assert sensor["principal_point_offset_x"] == sensor["principal_point_offset_y"] == 0.0
    assert (sensor["film"]["width"], sensor["film"]["height"]) == (40, 40)


def test_orbit_camera_by_hand():
    """Azimuth 90, elevation 0: on +X of the centre at the framing distance, looking down -X, +Y up."""
    camera = orbit_camera(([-1, -1, -1], [1, 1, 1]), 90.0, 0.0, fov=60.0, resolution=32, margin=1.0)
    d = math.sqrt(3) / math.sin(math.radians(30))                  # the bounding sphere touches the border
    np.testing.assert_allclose(camera.c2w, [[0, 0, 1, d], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]], atol=1e-12)
    assert camera.fx == camera.fy == pytest.approx(16 / math.tan(math.radians(30)))
    assert (camera.cx, camera.cy, camera.width, camera.height) == (16.0, 16.0, 32, 32)


def check_frames(camera, bbox):
    """The box centre projects to the principal point and every corner into the image."""
    lo, hi = bbox
    np.testing.assert_allclose(project(camera, [0.5 * (lo + hi)]), [[camera.cx, camera.cy]], atol=1e-9)
    uv = project(camera, corners(bbox))
    assert (uv > 0).all() and (uv[:, 0] < camera.width).all() and (uv[:, 1] < camera.height).all(), uv


@pytest.mark.parametrize("azimuth, elevation", [(35.0, 25.0), (-120.0, -60.0), (0.0, 90.0), (10.0, -90.0)])
def test_orbit_camera_looks_at_the_box_centre_and_frames_the_box(azimuth, elevation):
    """Poles included (look_at picks the image's up there)."""
    check_frames(orbit_camera(BOX, azimuth, elevation, fov=35.0, resolution=48), BOX)


def test_rig_cameras_are_a_fibonacci_sphere_at_the_framing_distance():
    lo, hi = BOX
    centre, radius = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    cameras = rig_cameras(20, BOX, 48, fov=40.0)
    assert cameras == fibonacci_cameras(20, centre, look_at_distance(radius, 40.0), fov_x_deg=40.0, width=48,
                                        height=48)
    for camera in cameras:
        check_frames(camera, BOX)
    D = np.array([c.c2w[:3, 3] - centre for c in cameras])
    np.testing.assert_allclose(np.linalg.norm(D, axis=1), look_at_distance(radius, 40.0))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    probes = np.random.default_rng(0).normal(size=(20_000, 3))
    probes /= np.linalg.norm(probes, axis=1, keepdims=True)
    worst = np.degrees(np.arccos(np.clip((probes @ D.T).max(1), -1, 1))).max()
    assert worst < 40, worst                                        # every direction is seen (spacing ~30)
    gap = np.degrees(np.arccos(np.clip(D @ D.T - 2 * np.eye(20), -1, 1))).min()
    assert gap > 20, gap                                            # no two cameras coincide


def test_a_sphere_filling_the_box_sphere_covers_the_predicted_disc():
    """The box's bounding sphere, seen from the rig, is a centred disc of radius f tan(asin(1 / 1.1 sin(fov / 2))).

    Rendered by the cameras' sensors (mask = alpha, 32x32, 64 spp): the mask
    covers the principal point's four pixels fully, its area is that of the
    disc (pi 14.4^2 px at fov 35, to 2 %) and its centroid is the principal point.
    """
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.render.captures import render_views

    lo, hi = BOX
    radius = 0.5 * np.linalg.norm(hi - lo)
    V, F = sphere_mesh(radius, 5)
    V = V / np.linalg.norm(V, axis=1, keepdims=True) * radius + 0.5 * (lo + hi)
    cameras = rig_cameras(3, BOX, 32)
    f = cameras[0].fx
    rho = f * math.tan(math.asin(math.sin(math.radians(17.5)) / 1.1))
    for view in render_views(V, F, cameras, [dict(e) for e in DEFAULT_EMITTERS], spp=64):
        np.testing.assert_allclose(view.mask[15:17, 15:17], 1.0)
        assert view.mask.sum() == pytest.approx(math.pi * rho**2, rel=0.02)
        ys, xs = np.mgrid[0:32, 0:32] + 0.5
        np.testing.assert_allclose([(view.mask * xs).sum() / view.mask.sum(), (view.mask * ys).sum() / view.mask.sum()],
                                   [16.0, 16.0], atol=0.05)


@pytest.mark.parametrize("call, message", [
    (lambda: orbit_camera(None), "orbit_camera(): expected a bbox (lo, hi) of two (3,) corners, got NoneType"),
    (lambda: orbit_camera(([0, 0, 0], [1, 1, 1], [2, 2, 2])),
     "orbit_camera(): expected a bbox (lo, hi) of two (3,) corners, got tuple of 3 items"),
    (lambda: orbit_camera(([0, 0], [1, 1])),
     "orbit_camera(): expected a bbox (lo, hi) of two (3,) corners, got shapes (2,) and (2,)"),
    (lambda: orbit_camera(([0, 0, 0], [1, 1, -1])), "orbit_camera(): expected a bbox of finite corners with lo <= hi "
     "and a diagonal > 0, got lo = [0.0, 0.0, 0.0], hi = [1.0, 1.0, -1.0]"),
    (lambda: orbit_camera(([0, 0, 0], [0, 0, 0])), "orbit_camera(): expected a bbox of finite corners with lo <= hi "
     "and a diagonal > 0, got lo = [0.0, 0.0, 0.0], hi = [0.0, 0.0, 0.0]"),
    (lambda: orbit_camera(BOX, math.nan), "orbit_camera(): expected a finite azimuth in degrees, got nan"),
    (lambda: orbit_camera(BOX, 0.0, "up"), "orbit_camera(): expected a finite elevation in degrees, got up"),
    (lambda: orbit_camera(BOX, fov=180.0), "orbit_camera(): expected fov in (0, 180) degrees, got 180.0"),
    (lambda: orbit_camera(BOX, resolution=0), "orbit_camera(): expected an integer resolution >= 1, got 0"),
    (lambda: orbit_camera(BOX, margin=0.0), "orbit_camera(): expected a margin > 0, got 0.0"),
    (lambda: rig_cameras(0, BOX, 16), "rig_cameras(): expected an integer n_views >= 1, got 0"),
    (lambda: rig_cameras(2.0, BOX, 16), "rig_cameras(): expected an integer n_views >= 1, got 2.0"),
    (lambda: rig_cameras(2, ([0, 0, math.inf], [1, 1, 1]), 16), "rig_cameras(): expected a bbox of finite corners "
     "with lo <= hi and a diagonal > 0, got lo = [0.0, 0.0, inf], hi = [1.0, 1.0, 1.0]"),
    (lambda: rig_cameras(2, BOX, True), "rig_cameras(): expected an integer resolution >= 1, got True"),
    (lambda: rig_cameras(2, BOX, 16, fov=-5.0), "rig_cameras(): expected fov in (0, 180) degrees, got -5.0"),
])
def test_cameras_framing_a_box_refuse_bad_input(call, message):
    with pytest.raises(ValueError, match=exactly(message)):
        call()
