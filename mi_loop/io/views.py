"""Pinhole cameras and calibrated views: the data of a capture (NumPy; see :mod:`mi_loop.io.capture`).

- :class:`Camera`: intrinsics in pixels and a camera-to-world matrix, NeRF/OpenGL axes;
- :class:`View`: a camera, its image in linear RGB, a foreground mask and, for an undistorted
  photo, the share of each pixel the photo saw; resizable;
- :class:`Capture`: the views of one ``transforms.json``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import scipy.sparse

from mi_loop.errors import fail

__all__ = ["Camera", "Capture", "View", "area_resize", "check_factor", "pose_problem", "scale_camera"]


def pose_problem(c2w):
    """Say what is wrong with a camera-to-world matrix, or None if nothing is.

    Parameters
    ----------
    c2w : object
        A candidate (4, 4) camera-to-world matrix.

    Returns
    -------
    (str, str) or None
        ``(what was expected, what was got)`` for a message, or None for a finite
        4 x 4 matrix with last row (0, 0, 0, 1) and an invertible 3 x 3 block.
    """
    try:
        M = np.asarray(c2w, dtype=np.float64)
    except (TypeError, ValueError):
        return "a 4 x 4 matrix of numbers", repr(c2w)[:80]
    if M.shape != (4, 4):
        return "a 4 x 4 matrix", f"shape {M.shape}"
    if not np.isfinite(M).all():
        r, c = np.argwhere(~np.isfinite(M))[0]
        return "a finite matrix", f"{M[r, c]} at row {r}, column {c}"
    if np.abs(M[3] - (0, 0, 0, 1)).max() > 1e-9:
        return "a last row (0, 0, 0, 1)", f"{M[3].tolist()}"
    if not np.linalg.cond(M[:3, :3]) < 1e12:
        return "an invertible matrix", f"a singular 3 x 3 block (determinant {np.linalg.det(M[:3, :3]):.3g})"
    return None


def check_factor(factor, func: str, downsampling: bool = False) -> float:
    """Return a scale factor as a float, refusing one that is not finite and > 0.

    Parameters
    ----------
    factor : float
        The factor.
    func : str
        The public function receiving it, for the message.
    downsampling : bool
        Also refuse factors above 1.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        ``func(): expected a factor in (0, 1] ...`` or ``... a finite factor > 0``.
    """
    ok = isinstance(factor, (int, float, np.integer, np.floating)) and not isinstance(factor, bool) \
        and math.isfinite(factor) and factor > 0
    if not ok or (downsampling and factor > 1):
        fail(func, "a factor in (0, 1] (downsampling only)" if downsampling else "a finite factor > 0", factor)
    return float(factor)


def _scaled_size(n: int, factor: float, func: str) -> int:
    """``n * factor`` rounded half up; refuse a factor that leaves no pixel."""
    m = int(math.floor(n * factor + 0.5))
    if m < 1:
        fail(func, f"a factor that leaves at least one of {n} pixels", factor)
    return m


@dataclass(frozen=True)
class Camera:
    """Pinhole camera, NeRF/OpenGL convention.

    A world point ``p`` is seen at ``x = cx + fx X / -Z``, ``y = cy - fy Y / -Z``
    where ``(X, Y, Z) = inv(c2w) p`` (see :func:`mi_loop.render.cameras.project`).
    Cameras compare equal when all fields are equal.

    Attributes
    ----------
    c2w : (4, 4) float64 NumPy array
        Camera-to-world transform (read-only copy), OpenGL axes: the camera looks
        down -Z, +Y up, +X right; last row (0, 0, 0, 1), invertible.
    fx, fy : float
        Focal lengths in pixels (> 0).
    cx, cy : float
        Principal point in pixels, x right and y down from the top-left corner
        of the top-left pixel (centred: ``(width / 2, height / 2)``).
    width, height : int
        Image size in pixels.

    Raises
    ------
    ValueError
        A field of the wrong shape or range.
    """

    c2w: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self):
        problem = pose_problem(self.c2w)
        if problem:
            fail("Camera", f"c2w: {problem[0]}", problem[1])
        c2w = np.array(self.c2w, dtype=np.float64)
        c2w.flags.writeable = False
        object.__setattr__(self, "c2w", c2w)
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(value) or (name in ("fx", "fy") and value <= 0):
                fail("Camera", f"a finite {name}" + (" > 0" if name in ("fx", "fy") else ""), value)
            object.__setattr__(self, name, float(value))
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                fail("Camera", f"an integer {name} >= 1", value)
            object.__setattr__(self, name, int(value))

    def __eq__(self, other):
        if not isinstance(other, Camera):
            return NotImplemented
        return np.array_equal(self.c2w, other.c2w) and self._intrinsics() == other._intrinsics()

    def __hash__(self):
        return hash((self.c2w.tobytes(), self._intrinsics()))

    def _intrinsics(self) -> tuple:
        return (self.fx, self.fy, self.cx, self.cy, self.width, self.height)

    def scaled(self, factor: float) -> Camera:
        """Return the same camera for its image resized by ``factor``.

        The new size is ``round(width * factor) x round(height * factor)`` (half
        up) and pixel coordinates scale by ``new / old`` on each axis, so the
        resized image covers the same field of view. When ``width * factor`` or
        ``height * factor`` is not an integer the two axes scale slightly
        differently and pixels stop being square (:func:`~mi_loop.render.cameras.sensor_dict`
        refuses that): pick a factor that divides both sizes.

        Parameters
        ----------
        factor : float
            Scale, > 0.

        Returns
        -------
        Camera

        Examples
        --------
        >>> cam = Camera(np.eye(4), 100.0, 100.0, 32.0, 24.0, 64, 48).scaled(0.5)
        >>> cam.fx, cam.cx, cam.cy, cam.width, cam.height
        (50.0, 16.0, 12.0, 32, 24)
        """
        factor = check_factor(factor, "Camera.scaled")
        w, h = (_scaled_size(n, factor, "Camera.scaled") for n in (self.width, self.height))
        sx, sy = w / self.width, h / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy, width=w, height=h)


def scale_camera(camera: Camera, scale: float) -> Camera:
    """Return ``camera`` for its image scaled by exactly ``scale``: every pixel coordinate times ``scale``.

    Parameters
    ----------
    camera : Camera
    scale : float
        > 0.

    Returns
    -------
    Camera
        ``fx fy cx cy`` times ``scale`` (square pixels stay square); size
        ``floor(width * scale) x floor(height * scale)`` (at least 1), the last
        part-pixel cropped. :meth:`Camera.scaled` rounds the size instead and
        scales each axis by its own ratio.

    Raises
    ------
    ValueError
        A scale that is not finite and > 0.

    Examples
    --------
    >>> cam = scale_camera(Camera(np.eye(4), 100.0, 100.0, 50.0, 37.5, 100, 75), 0.1)
    >>> cam.fx, cam.cy, cam.width, cam.height
    (10.0, 3.75, 10, 7)
    """
    scale = check_factor(scale, "scale_camera")
    w, h = (max(1, math.floor(n * scale + 1e-6)) for n in (camera.width, camera.height))
    return Camera(camera.c2w, camera.fx * scale, camera.fy * scale, camera.cx * scale, camera.cy * scale, w, h)


def _area_matrix(n: int, m: int, extent: float) -> scipy.sparse.csr_matrix:
    """``(m, n)`` weights averaging ``m`` equal intervals of ``[0, extent]`` over unit pixels ``[i, i + 1]``."""
    a = np.arange(m)[:, None] * (extent / m)                  # (m, 1) interval starts
    b = np.arange(1, m + 1)[:, None] * (extent / m)
    i = np.floor(a).astype(np.int64) + np.arange(math.ceil(extent / m) + 2)[None, :]
    overlap = np.minimum(b, i + 1) - np.maximum(a, i)
    keep = (overlap > 0) & (i < n)
    rows = np.broadcast_to(np.arange(m)[:, None], i.shape)[keep]
    weights = (overlap / (b - a))[keep].astype(np.float32)
    return scipy.sparse.csr_matrix((weights, (rows, i[keep])), shape=(m, n))


def area_resize(image: np.ndarray, size: tuple[int, int], extent: tuple[float, float] | None = None) -> np.ndarray:
    """Reduce an image by area averaging: each new pixel is the mean of the old over its footprint.

    Parameters
    ----------
    image : (h, w) or (h, w, c) float32 NumPy array
    size : (int, int)
        New ``(height, width)``, at most the old.
    extent : (float, float), optional
        The part ``[0, extent_y] x [0, extent_x]`` of the old image (in old
        pixels, at most ``(h, w)``) that the new one covers; default all of it.
        New pixel ``(i, j)`` covers old ``[j ex / W, (j + 1) ex / W] x [...]``,
        fractional pixels weighted by their area.

    Returns
    -------
    (H, W) or (H, W, c) float32 NumPy array

    Raises
    ------
    ValueError
        A size below 1, an extent outside the image.

    Examples
    --------
    >>> area_resize(np.arange(6, dtype=np.float32).reshape(1, 6), (1, 2)).tolist()
    [[1.0, 4.0]]
    """
    h, w = image.shape[:2]
    H, W = size
    ey, ex = (h, w) if extent is None else extent
    if not (H >= 1 and W >= 1 and 0 < ey <= h and 0 < ex <= w):
        fail("area_resize", f"a size >= 1 and an extent in (0, {h}] x (0, {w}]",
             f"size {tuple(size)}, extent {(ey, ex)}")
    if (H, W, ey, ex) == (h, w, h, w):
        return image
    flat = image.reshape(h, -1)
    out = _area_matrix(h, H, ey) @ flat                                         # (H, w * c)
    out = out.reshape(H, w, -1).transpose(1, 0, 2).reshape(w, -1)
    out = (_area_matrix(w, W, ex) @ out).reshape(W, H, -1).transpose(1, 0, 2)   # (H, W, c)
    return np.ascontiguousarray(out.reshape((H, W) + image.shape[2:]), dtype=np.float32)


@dataclass(frozen=True, eq=False)
class View:
    """One calibrated image: camera, linear RGB, foreground mask, and which pixels the photo saw.

    Attributes
    ----------
    camera : Camera
        Its size is the image's.
    rgb : (height, width, 3) float32 NumPy array
        Linear radiance, finite (PNG/JPEG sRGB-decoded; EXR as stored).
    mask : (height, width) float32 NumPy array
        Foreground in [0, 1] (alpha or ``mask_path``; ones when there is neither).
    name : str
        The frame's ``file_path`` as the JSON writes it.
    valid : (height, width) float32 NumPy array or None
        The share of each pixel that the photo saw, in [0, 1]; None (the
        default): all of every pixel. An undistorted photo
        (:func:`~mi_loop.io.undistort.undistort`) does not fill its pinhole
        image: where ``valid`` is 0 nothing is known (``rgb`` and ``mask`` are
        0 there, and mean neither background nor black), elsewhere ``rgb`` and
        ``mask`` are means over the seen part. A loss or a carving that reads
        ``mask`` should weight each pixel by ``valid``.

    Raises
    ------
    ValueError
        Arrays whose shape differs from the camera's image, non-finite pixels,
        mask or valid values outside [0, 1].
    """

    camera: Camera
    rgb: np.ndarray
    mask: np.ndarray
    name: str
    valid: np.ndarray | None = None

    def __post_init__(self):
        if not isinstance(self.camera, Camera):
            fail("View", "a Camera", type(self.camera).__name__, TypeError)
        h, w = self.camera.height, self.camera.width
        rgb = np.ascontiguousarray(self.rgb, dtype=np.float32)
        mask = np.ascontiguousarray(self.mask, dtype=np.float32)
        if rgb.shape != (h, w, 3):
            fail("View", f"rgb of shape (h, w, 3) = {(h, w, 3)} as the camera", f"shape {rgb.shape}")
        if mask.shape != (h, w):
            fail("View", f"a mask of shape (h, w) = {(h, w)} as the camera", f"shape {mask.shape}")
        bad = ~np.isfinite(rgb)
        if bad.any():
            fail("View", "finite rgb", f"{rgb[bad][0]} at pixel {np.argwhere(bad)[0, :2].tolist()}")
        bad = ~((mask >= 0) & (mask <= 1))
        if bad.any():
            fail("View", "mask values in [0, 1]", f"{mask[bad][0]} at pixel {np.argwhere(bad)[0].tolist()}")
        object.__setattr__(self, "rgb", rgb)
        object.__setattr__(self, "mask", mask)
        object.__setattr__(self, "name", str(self.name))
        if self.valid is not None:
            valid = np.ascontiguousarray(self.valid, dtype=np.float32)
            if valid.shape != (h, w):
                fail("View", f"valid of shape (h, w) = {(h, w)} as the camera, or None", f"shape {valid.shape}")
            bad = ~((valid >= 0) & (valid <= 1))
            if bad.any():
                fail("View", "valid values in [0, 1]", f"{valid[bad][0]} at pixel {np.argwhere(bad)[0].tolist()}")
            object.__setattr__(self, "valid", valid)

    def resized(self, factor: float) -> View:
        """Return the view downsampled by ``factor``: area-averaged rgb and mask, the camera by
        :func:`scale_camera`.

        Every pixel coordinate scales by exactly ``factor`` on both axes, so square
        pixels stay square (Mitsuba's sensor needs them); the size is
        ``floor(width * factor) x floor(height * factor)``, the last part-pixel
        cropped. Every new pixel is the mean of the old image over its footprint
        (``1 / factor`` old pixels on each axis, fractional pixels weighted by
        their area: :func:`area_resize`); with ``valid``,
        the mean over the seen part (weighted by ``valid``), and ``valid`` the
        mean of the old.

        Parameters
        ----------
        factor : float
            In (0, 1]; 1 returns the view itself.

        Returns
        -------
        View
        """
        factor = check_factor(factor, "View.resized", downsampling=True)
        if factor == 1:
            return self
        camera = scale_camera(self.camera, factor)
        size = (camera.height, camera.width)
        extent = (min(self.camera.height, camera.height / factor), min(self.camera.width, camera.width / factor))

        def resample(a):
            return area_resize(np.asarray(a, dtype=np.float32), size, extent)
        if self.valid is None:
            return View(camera, resample(self.rgb), np.clip(resample(self.mask), 0, 1), self.name)
        valid = resample(self.valid)
        seen = np.where(valid > 0, valid, 1.0)
        rgb = resample(self.rgb * self.valid[..., None]) / seen[..., None]
        mask = resample(self.mask * self.valid) / seen
        return View(camera, rgb, np.clip(mask, 0, 1), self.name, np.clip(valid, 0, 1))


@dataclass(frozen=True, eq=False)
class Capture:
    """A calibrated multi-view capture as read from a ``transforms.json``.

    Attributes
    ----------
    views : tuple of View
        In the order of the JSON's ``frames``.
    path : pathlib.Path
        The ``transforms.json`` file, or the capture directory.
    format : str
        The camera format read (:data:`mi_loop.io.camera_formats.FORMATS`).
    normalisation : list or None
        IDR / NeuS: ``scale_mat`` (4 x 4), the sphere that capture's own tools
        normalise to; the views stay in the cameras' world frame.
    """

    views: tuple
    path: Path
    format: str = "transforms"
    normalisation: list | None = None


# -------------------------------------------------------------------- reading
