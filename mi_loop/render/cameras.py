"""NeRF / OpenGL pinhole cameras in Mitsuba: the sensor, the projection, cameras framing a box.

A :class:`~mi_loop.io.capture.Camera` has OpenGL axes (it looks down -Z, +Y
up, +X right) and pixel coordinates x right, y down from the top-left corner
of the image. Mitsuba's ``perspective`` sensor images the same world when
(each checked against renders in ``tests/render/test_cameras.py``):

- ``to_world = c2w @ diag(-1, 1, -1, 1)``: Mitsuba's camera looks down its
  local +Z, +Y up, and its local +X points to the *left* of the image, so the
  two frames differ by a half-turn about Y (no reflection);
- ``fov = 2 atan(w / (2 fx))`` degrees with ``fov_axis = 'x'``; Mitsuba's pixels
  are square (``fy = fx``) and it refuses scale in ``to_world``, so a camera
  with ``fx != fy`` has no exact Mitsuba sensor and :func:`sensor_dict` refuses it;
- ``principal_point_offset_x = 0.5 - cx / w``, ``principal_point_offset_y = 0.5 - cy / h``:
  Mitsuba traces film position ``s`` (in [0, 1]^2, pixel / size, same origin
  as ``cx, cy``) as a centred camera traces ``s + offset``, so the optical
  axis falls on ``s = 0.5 - offset``.

Cameras that frame a box (its bounding sphere filling the field of view, as
:func:`look_at_distance` places them): :func:`orbit_camera` from an azimuth and
an elevation, :func:`rig_cameras` on a Fibonacci sphere (:func:`fibonacci_cameras`).

Only :func:`sensor_dict` imports Mitsuba (a variant must be set); the rest is NumPy.
"""
from __future__ import annotations

import math

import numpy as np

from mi_loop.errors import expected, fail
from mi_loop.io.capture import Camera

__all__ = ["fibonacci_cameras", "look_at", "look_at_distance", "orbit_camera", "project", "rig_cameras",
           "sensor_dict"]

#: OpenGL camera axes -> Mitsuba camera axes (a half-turn about Y).
_GL_TO_MITSUBA = np.diag([-1.0, 1.0, -1.0, 1.0])


def _camera(camera, func: str) -> Camera:
    if not isinstance(camera, Camera):
        fail(func, "a mi_loop.io.Camera", type(camera).__name__, TypeError)
    return camera


def sensor_dict(camera: Camera, *, spp: int = 16, near: float = 1e-3, far: float = 1e3) -> dict:
    """Return a Mitsuba ``perspective`` sensor that images the world exactly as ``camera`` does.

    Parameters
    ----------
    camera : Camera
        Square pixels (``fx == fy`` within 1e-6 relative) and a rotation in
        ``c2w`` (orthonormal within 1e-5): Mitsuba's sensor can do no other.
    spp : int, optional
        Samples per pixel of its ``independent`` sampler.
    near, far : float, optional
        Clip distances along the view axis, ``0 < near < far``.

    Returns
    -------
    dict
        ``to_world``, ``fov`` + ``fov_axis='x'``, ``principal_point_offset_x/y``,
        ``near_clip``/``far_clip``, an ``hdrfilm`` of ``width x height`` (rgb,
        box filter, ``sample_border``) and the sampler; pass it to ``mi.load_dict``
        or put it in a scene dictionary.

    Raises
    ------
    ValueError
        ``fx != fy`` (resample the image to square pixels first), a ``c2w``
        with scale or shear, ``spp < 1``, clip distances out of order.
    RuntimeError
        No Mitsuba variant set (see :func:`mi_loop.set_variant`).

    Notes
    -----
    The conventions are in the module's docstring. Pixel ``(i, j)`` of the
    render integrates radiance over ``[i, i + 1] x [j, j + 1]`` in the camera's
    pixel coordinates, as :func:`project` places points.
    """
    camera = _camera(camera, "sensor_dict")
    if abs(camera.fx - camera.fy) > 1e-6 * max(camera.fx, camera.fy):
        fail("sensor_dict", "square pixels, fx == fy within 1e-6 relative (Mitsuba's perspective sensor has "
             "one focal length and refuses scale in to_world; resample the image to square pixels)",
             f"fx = {camera.fx}, fy = {camera.fy}")
    R = camera.c2w[:3, :3]
    shear = float(np.abs(R.T @ R - np.eye(3)).max())
    if shear > 1e-5:
        fail("sensor_dict", "a c2w whose 3 x 3 block is a rotation (orthonormal within 1e-5; Mitsuba refuses "
             "scale in to_world)", f"max |R^T R - I| = {shear:.3g}")
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
        fail("sensor_dict", "an integer spp >= 1", spp)
    if not (0 < near < far < math.inf):
        fail("sensor_dict", "clip distances 0 < near < far < inf", f"near = {near}, far = {far}")
    import mitsuba as mi

    if mi.variant() is None:
        raise RuntimeError(expected("sensor_dict", "a Mitsuba variant to be set (mi_loop.set_variant)", "none"))
    w, h = camera.width, camera.height
    return {
        "type": "perspective",
        "to_world": mi.ScalarTransform4f(camera.c2w @ _GL_TO_MITSUBA),
        "fov": math.degrees(2 * math.atan(0.5 * w / camera.fx)),
        "fov_axis": "x",
        "principal_point_offset_x": 0.5 - camera.cx / w,
        "principal_point_offset_y": 0.5 - camera.cy / h,
        "near_clip": float(near),
        "far_clip": float(far),
        "film": {"type": "hdrfilm", "width": w, "height": h, "pixel_format": "rgb",
                 "rfilter": {"type": "box"}, "sample_border": True},
        "sampler": {"type": "independent", "sample_count": int(spp)},
    }


def project(camera: Camera, points) -> np.ndarray:
    """Project world points to pixel coordinates by the NeRF / OpenGL pinhole model.

    Parameters
    ----------
    camera : Camera
        The camera.
    points : (k, 3) float array-like
        World points.

    Returns
    -------
    (k, 2) float64 NumPy array
        ``x = cx + fx X / -Z``, ``y = cy - fy Y / -Z`` with ``(X, Y, Z) = inv(c2w) p``:
        x right, y down, from the top-left corner of the image. NaN for points
        not in front of the camera (``Z >= 0``).

    Raises
    ------
    ValueError
        ``points`` not of shape (k, 3).

    Examples
    --------
    >>> cam = Camera(np.eye(4), 100.0, 100.0, 32.0, 24.0, 64, 48)
    >>> project(cam, [[0.0, 0.0, -2.0], [0.2, 0.1, -2.0], [0.0, 0.0, 1.0]]).tolist()
    [[32.0, 24.0], [42.0, 19.0], [nan, nan]]
    """
    camera = _camera(camera, "project")
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        fail("project", "points of shape (k, 3)", f"shape {P.shape}")
    w2c = np.linalg.inv(camera.c2w)
    X = P @ w2c[:3, :3].T + w2c[:3, 3]
    depth = -X[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([camera.cx + camera.fx * X[:, 0] / depth, camera.cy - camera.fy * X[:, 1] / depth], axis=1)
    uv[~(depth > 0)] = np.nan
    return uv


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Return the OpenGL camera-to-world matrix of a camera at ``eye`` looking at ``target``.

    Parameters
    ----------
    eye, target : (3,) float array-like
        Camera centre and the point it looks at (distinct).
    up : (3,) float array-like, optional
        Direction that appears up in the image. When it is parallel to the
        viewing direction (a camera straight above or below), -Z or +Z is used
        instead, so that the image's top points away from the viewer's side.

    Returns
    -------
    (4, 4) float64 NumPy array
        Columns: right (+X), up (+Y), back (+Z, away from ``target``), ``eye``.

    Raises
    ------
    ValueError
        ``eye == target``.
    """
    eye, target, up = (np.asarray(a, dtype=np.float64).reshape(3) for a in (eye, target, up))
    back = eye - target
    if not np.linalg.norm(back) > 0:
        fail("look_at", "an eye distinct from the target", f"both {eye.tolist()}")
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-9 * np.linalg.norm(up):           # looking along up: a pole
        right = np.cross([0.0, 0.0, -1.0 if back @ up > 0 else 1.0], back)
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(back, right), back, eye
    return c2w


def fibonacci_cameras(n: int, center, radius: float, *, fov_x_deg: float, width: int, height: int) -> list:
    """Return ``n`` cameras on a Fibonacci sphere around ``center``, looking at it, +Y up.

    Parameters
    ----------
    n : int
        Number of cameras, >= 1.
    center : (3,) float array-like
        The point every camera looks at (it projects to the principal point).
    radius : float
        Distance of every camera from ``center``, > 0.
    fov_x_deg : float
        Horizontal field of view in degrees, in (0, 180).
    width, height : int
        Image size; square pixels, centred principal point.

    Returns
    -------
    list of Camera
        Camera ``i`` at height ``y = 1 - (2 i + 1) / n`` (times ``radius``, top
        to bottom) and azimuth ``i`` golden angles; image up is world +Y
        projected onto the image plane (see :func:`look_at` for the poles).

    Raises
    ------
    ValueError
        ``n < 1``, ``radius <= 0``, a field of view out of range, a non-finite centre.

    Examples
    --------
    >>> cams = fibonacci_cameras(4, [0, 0, 0], 2.0, fov_x_deg=40.0, width=32, height=24)
    >>> [round(float(np.linalg.norm(c.c2w[:3, 3])), 6) for c in cams]
    [2.0, 2.0, 2.0, 2.0]
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        fail("fibonacci_cameras", "an integer n >= 1", n)
    if not (isinstance(radius, (int, float, np.integer, np.floating)) and 0 < radius < math.inf):
        fail("fibonacci_cameras", "a finite radius > 0", radius)
    if not (isinstance(fov_x_deg, (int, float, np.integer, np.floating)) and 0 < fov_x_deg < 180):
        fail("fibonacci_cameras", "fov_x_deg in (0, 180)", fov_x_deg)
    c = np.asarray(center, dtype=np.float64)
    if c.shape != (3,) or not np.isfinite(c).all():
        fail("fibonacci_cameras", "a finite center of shape (3,)", repr(center))
    i = np.arange(n) + 0.5
    y = 1 - 2 * i / n
    phi = i * math.pi * (3 - math.sqrt(5))                           # golden angle steps
    directions = np.stack([np.sqrt(1 - y**2) * np.cos(phi), y, np.sqrt(1 - y**2) * np.sin(phi)], axis=1)
    f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
    return [Camera(look_at(c + radius * d, c), f, f, 0.5 * width, 0.5 * height, width, height)
            for d in directions]


def look_at_distance(radius: float, fov: float, margin: float = 1.1) -> float:
    """Return the camera distance at which a sphere of ``radius`` fills 1 / ``margin`` of the field of view.

    Parameters
    ----------
    radius : float
        Radius of the sphere to frame.
    fov : float
        Field of view in degrees.
    margin : float, optional
        1 makes the sphere's tangent cone the field of view.

    Returns
    -------
    float
        ``margin * radius / sin(fov / 2)``.

    Examples
    --------
    >>> round(look_at_distance(1.0, 35.0), 3)
    3.658
    """
    return float(margin * radius / np.sin(np.radians(fov) / 2))


def _direction(azimuth: float, elevation: float) -> np.ndarray:
    """Unit vector at ``azimuth`` (about +y, from +z) and ``elevation`` (degrees); y is up."""
    a, e = np.radians(azimuth), np.radians(elevation)
    return np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])


def _number(value, func: str, what: str, test=lambda v: True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or not test(value):
        fail(func, what, value)
    return float(value)


def _box_sphere(bbox, func: str) -> tuple[np.ndarray, float]:
    """Centre ``(3,)`` and radius (half the diagonal) of ``bbox = (lo, hi)``, checked for ``func``."""
    try:
        lo, hi = bbox
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    except (TypeError, ValueError):
        got = f"{type(bbox).__name__} of {len(bbox)} items" if hasattr(bbox, "__len__") else type(bbox).__name__
        fail(func, "a bbox (lo, hi) of two (3,) corners", got)
    if lo.shape != (3,) or hi.shape != (3,):
        fail(func, "a bbox (lo, hi) of two (3,) corners", f"shapes {lo.shape} and {hi.shape}")
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (hi >= lo).all() and radius > 0):
        fail(func, "a bbox of finite corners with lo <= hi and a diagonal > 0",
             f"lo = {lo.tolist()}, hi = {hi.tolist()}")
    return 0.5 * (lo + hi), radius


def orbit_camera(bbox, azimuth: float = 35.0, elevation: float = 25.0, *, fov: float = 35.0,
                 resolution: int = 256, margin: float = 1.1) -> Camera:
    """Return a square camera that looks at the centre of a box from a direction, framing it.

    Parameters
    ----------
    bbox : ((3,), (3,)) float array-like
        Corners ``(lo, hi)`` of the box, ``lo <= hi``, non-zero diagonal.
    azimuth, elevation : float, optional
        Viewing direction in degrees: azimuth about the +y (up) axis measured
        from +z, elevation above the xz plane. The camera sits on that side.
    fov : float, optional
        Horizontal (and vertical) field of view in degrees, in (0, 180).
    resolution : int, optional
        Width and height in pixels.
    margin : float, optional
        Distance factor (:func:`look_at_distance`); 1 makes the box's bounding
        sphere touch the image border, > 0.

    Returns
    -------
    Camera
        At ``centre + look_at_distance(radius, fov, margin) * direction``, looking
        at the box centre (the principal point, centred), image up towards +Y
        (:func:`look_at`).

    Raises
    ------
    ValueError
        A malformed or empty box, a non-finite angle, a field of view out of
        range, ``resolution < 1``, ``margin <= 0``.

    Examples
    --------
    >>> cam = orbit_camera(([-1, -1, -1], [1, 1, 1]), 0.0, 0.0, fov=90.0, resolution=64, margin=1.0)
    >>> cam.c2w[:3, 3].round(3).tolist(), round(cam.fx, 9), (cam.cx, cam.cy)
    ([0.0, 0.0, 2.449], 32.0, (32.0, 32.0))
    """
    centre, radius = _box_sphere(bbox, "orbit_camera")
    azimuth = _number(azimuth, "orbit_camera", "a finite azimuth in degrees")
    elevation = _number(elevation, "orbit_camera", "a finite elevation in degrees")
    fov = _number(fov, "orbit_camera", "fov in (0, 180) degrees", lambda v: 0 < v < 180)
    margin = _number(margin, "orbit_camera", "a margin > 0", lambda v: v > 0)
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 1:
        fail("orbit_camera", "an integer resolution >= 1", resolution)
    eye = centre + look_at_distance(radius, fov, margin) * _direction(azimuth, elevation)
    f = 0.5 * resolution / math.tan(math.radians(fov) / 2)
    return Camera(look_at(eye, centre), f, f, 0.5 * resolution, 0.5 * resolution, int(resolution), int(resolution))


def rig_cameras(n_views: int, bbox, resolution: int, fov: float = 35.0) -> list:
    """Return the cameras of a rig around a box: a Fibonacci sphere at the framing distance.

    Parameters
    ----------
    n_views : int
        Number of cameras, >= 1.
    bbox : ((3,), (3,)) float array-like
        Corners ``(lo, hi)`` of the box every camera frames, ``lo <= hi``, non-zero diagonal.
    resolution : int
        Width and height of the square images in pixels.
    fov : float, optional
        Field of view in degrees, in (0, 180).

    Returns
    -------
    list of Camera
        :func:`fibonacci_cameras` about the box centre at radius
        ``look_at_distance(r, fov)`` (``r`` half the box diagonal): the box's
        bounding sphere fills 1 / 1.1 of every image, first camera near +Y.

    Raises
    ------
    ValueError
        ``n_views < 1``, a malformed or empty box, ``resolution < 1``, a field
        of view out of range.

    Examples
    --------
    >>> cams = rig_cameras(3, ([0, 0, 0], [1, 1, 1]), 32)
    >>> len(cams), cams[0].width, round(float(cams[0].c2w[1, 3]), 3)
    (3, 32, 2.612)
    """
    if isinstance(n_views, bool) or not isinstance(n_views, (int, np.integer)) or n_views < 1:
        fail("rig_cameras", "an integer n_views >= 1", n_views)
    centre, radius = _box_sphere(bbox, "rig_cameras")
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 1:
        fail("rig_cameras", "an integer resolution >= 1", resolution)
    fov = _number(fov, "rig_cameras", "fov in (0, 180) degrees", lambda v: 0 < v < 180)
    return fibonacci_cameras(int(n_views), centre, look_at_distance(radius, fov), fov_x_deg=fov,
                             width=int(resolution), height=int(resolution))
