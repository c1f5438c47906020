"""Photos resampled to ideal pinhole cameras: lens distortion undone, pixels made square, sizes reduced by area.

- :class:`Lens`: OpenCV's lens models, radial-tangential (``cv2``'s ``k1 k2 p1
  p2 k3 k4 k5 k6``) and the equidistant fisheye (``cv2.fisheye``'s ``k1 k2 k3 k4``);
- :func:`ideal_camera`: the pinhole camera with square pixels that sees what
  a camera sees through its lens; :func:`scale_camera` (a camera for its image
  scaled by an exact factor) and :func:`area_resize` live in :mod:`mi_loop.io.views`,
  which :meth:`~mi_loop.io.views.View.resized` shares, and are re-exported here;
- :func:`undistort`: an image resampled from a camera with a lens to a pinhole
  camera, with the share of each pixel that the photo saw;
- :func:`area_resize`: an image reduced by area averaging.

Pixel coordinates are mi_loop's (:class:`~mi_loop.io.views.Camera`): from the
top-left corner of the top-left pixel, centres at half-integers. OpenCV puts
pixel centres at integers, so its principal point is ``cx - 0.5, cy - 0.5``
and its maps hold ``x - 0.5, y - 0.5``. NumPy and OpenCV only.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.views import Camera, area_resize, scale_camera

__all__ = ["LENS_MODELS", "Lens", "area_resize", "ideal_camera", "scale_camera", "undistort"]

#: Lens models and their number of coefficients.
LENS_MODELS = {"opencv": 8, "fisheye": 4}
#: Largest size of an undistorted image relative to the photo's on each axis (as COLMAP's ``max_scale``).
MAX_SPAN = 2.0
#: Border samples per side whose undistorted positions bound the ideal camera's image.
_BORDER_SAMPLES = 256
#: OpenCV's iterative undistortion of the border: iterations and tolerance.
_CRITERIA = (3, 100, 1e-12)              # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS


@dataclass(frozen=True)
class Lens:
    """Lens distortion, in normalised image coordinates (OpenCV's models).

    For an undistorted normalised point ``(x, y)`` (``X / Z``, ``Y / Z`` in
    OpenCV's camera axes, y down), ``r^2 = x^2 + y^2``:

    - ``"opencv"``: ``x' = x g + 2 p1 x y + p2 (r^2 + 2 x^2)``,
      ``y' = y g + p1 (r^2 + 2 y^2) + 2 p2 x y`` with
      ``g = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)``;
    - ``"fisheye"`` (equidistant): ``theta = atan(r)``,
      ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
      ``(x', y') = (theta_d / r) (x, y)``;

    and the pixel is ``(fx x' + cx, fy y' + cy)``.

    Attributes
    ----------
    model : {'opencv', 'fisheye'}
    coefficients : tuple of float
        ``(k1, k2, p1, p2, k3, k4, k5, k6)`` for ``'opencv'`` (OpenCV's order),
        ``(k1, k2, k3, k4)`` for ``'fisheye'``; shorter tuples are padded with zeros.

    Raises
    ------
    ValueError
        An unknown model, too many or non-finite coefficients.
    """

    model: str = "opencv"
    coefficients: tuple = ()

    def __post_init__(self):
        if self.model not in LENS_MODELS:
            fail("Lens", f"a model in {tuple(LENS_MODELS)}", repr(self.model))
        n = LENS_MODELS[self.model]
        k = tuple(float(c) for c in self.coefficients)
        if len(k) > n or not all(math.isfinite(c) for c in k):
            fail("Lens", f"at most {n} finite coefficients for model '{self.model}'", self.coefficients)
        object.__setattr__(self, "coefficients", k + (0.0,) * (n - len(k)))

    @property
    def is_pinhole(self) -> bool:
        """No distortion: the radial-tangential model with zero coefficients."""
        return self.model == "opencv" and not any(self.coefficients)

    def radial(self, r):
        """Distorted radius (``r g`` or ``theta_d``) of undistorted normalised radii ``r``, radial terms only."""
        r = np.asarray(r, dtype=np.float64)
        k = self.coefficients
        if self.model == "fisheye":
            t = np.arctan(r)
            t2 = t * t
            return t * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
        r2 = r * r
        return r * (1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))) / (1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7])))

    def fold_radius(self, r_max: float) -> float:
        """The undistorted radius up to ``r_max`` where :meth:`radial` stops increasing (inf if it does not).

        Beyond it a polynomial lens model folds back on itself: rays there map to
        pixels that nearer rays already map to, so they count as unseen.
        """
        r = np.linspace(0.0, r_max, 4097)
        g = self.radial(r)
        bad = np.flatnonzero(~(np.diff(g) > 0))
        return float(r[bad[0]]) if bad.size else math.inf


def _intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """OpenCV's camera matrix of a camera's intrinsics (principal point in its integer-centre convention)."""
    return np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])


def _extent(camera: Camera, lens: Lens) -> tuple[float, float, float, float]:
    """Normalised ``(left, right, top, bottom)`` of the photo's undistorted border (y down), bounded."""
    import cv2

    w, h = camera.width, camera.height
    t = np.linspace(0.0, 1.0, _BORDER_SAMPLES)
    edges = [np.stack([t * w, 0 * t], 1), np.stack([t * w, h + 0 * t], 1),
             np.stack([0 * t, t * h], 1), np.stack([w + 0 * t, t * h], 1)]
    border = (np.concatenate(edges) - 0.5).reshape(-1, 1, 2)
    K = _intrinsics(camera.fx, camera.fy, camera.cx, camera.cy)
    if lens.model == "fisheye":
        xy = cv2.fisheye.undistortPoints(border, K, np.array(lens.coefficients), criteria=_CRITERIA)
    else:
        xy = cv2.undistortPoints(border, K, np.array(lens.coefficients), criteria=_CRITERIA)
    x, y = xy.reshape(-1, 2).T
    # the pinhole's own extent, and at most MAX_SPAN times its span about it
    x0, x1, y0, y1 = -camera.cx / camera.fx, (w - camera.cx) / camera.fx, -camera.cy / camera.fy, \
        (h - camera.cy) / camera.fy
    mx, my = 0.5 * (MAX_SPAN - 1) * (x1 - x0), 0.5 * (MAX_SPAN - 1) * (y1 - y0)
    lo = np.array([x0 - mx, x1 + mx, y0 - my, y1 + my])
    fold = lens.fold_radius(float(np.hypot(np.abs(lo[:2]).max(), np.abs(lo[2:]).max())))
    ok = np.isfinite(x) & np.isfinite(y)
    found = [x[ok].min(), x[ok].max(), y[ok].min(), y[ok].max()] if ok.any() else [x0, x1, y0, y1]
    left, right, top, bottom = (max(found[0], lo[0], -fold), min(found[1], lo[1], fold),
                                max(found[2], lo[2], -fold), min(found[3], lo[3], fold))
    return float(left), float(right), float(top), float(bottom)


def ideal_camera(camera: Camera, lens: Lens) -> Camera:
    """Return the pinhole camera with square pixels that sees what ``camera`` sees through ``lens``.

    Parameters
    ----------
    camera : Camera
        The photo's camera: its intrinsics in ``lens``'s model (``fx`` may differ from ``fy``).
    lens : Lens
        Its distortion.

    Returns
    -------
    Camera
        The same ``c2w``; focal length ``max(fx, fy)`` on both axes (no axis
        loses resolution); its image is the bounding box of the photo's
        undistorted border (every pixel of the photo lands in it), at most
        :data:`MAX_SPAN` times the photo's pinhole extent on each axis and
        within :meth:`Lens.fold_radius`, cropped by less than a pixel to a
        whole number of pixels. For a pinhole lens this is the photo's
        camera with its narrower axis stretched to the longer focal length.
    """
    f = max(camera.fx, camera.fy)
    left, right, top, bottom = _extent(camera, lens)
    w = max(1, math.floor((right - left) * f + 1e-6))
    h = max(1, math.floor((bottom - top) * f + 1e-6))
    return Camera(camera.c2w, f, f, -left * f, -top * f, w, h)


def undistort(image: np.ndarray, camera: Camera, lens: Lens, target: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Resample a photo taken by ``camera`` through ``lens`` to the pinhole camera ``target``.

    Each target pixel is the mean of ``m x m`` bilinear samples of the photo
    (``cv2.remap``) at the rays of its sub-pixels, ``m`` the photo's pixels per
    target pixel (rounded up), so a target smaller than the photo is area
    averaged. Samples that fall outside the photo, or beyond the lens model's
    fold (:meth:`Lens.fold_radius`), are unseen: a pixel is the mean of its
    seen samples, and 0 where it has none.

    Parameters
    ----------
    image : (h, w, c) float32 NumPy array
        The photo, ``c <= 4`` (linear values: the means are taken as they are).
    camera : Camera
        Its camera, of its size, intrinsics in ``lens``'s model.
    lens : Lens
        Its distortion.
    target : Camera
        A pinhole with square pixels (:func:`ideal_camera`, :func:`scale_camera`).

    Returns
    -------
    image : (H, W, c) float32 NumPy array
        The target's image.
    seen : (H, W) float32 NumPy array
        The share of each pixel's samples that the photo saw, in [0, 1].

    Raises
    ------
    ValueError
        A target with ``fx != fy``, an image of another size than ``camera``'s.
    """
    import cv2

    if target.fx != target.fy:
        fail("undistort", "a target with square pixels (fx == fy)", f"fx = {target.fx}, fy = {target.fy}")
    if image.shape[:2] != (camera.height, camera.width):
        fail("undistort", f"an image of the camera's size {camera.width} x {camera.height}",
             f"{image.shape[1]} x {image.shape[0]}")
    mx, my, seen, m = _maps(*(float(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy)), camera.width,
                            camera.height, lens, float(target.fx), float(target.cx), float(target.cy), target.width,
                            target.height)
    out = cv2.remap(np.ascontiguousarray(image, dtype=np.float32), mx, my, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE).reshape(seen.shape[0], seen.shape[1], -1)
    out *= seen[..., None]
    c = out.shape[2]
    out = out.reshape(target.height, m, target.width, m, c).mean(axis=(1, 3), dtype=np.float32)
    share = seen.reshape(target.height, m, target.width, m).mean(axis=(1, 3), dtype=np.float32)
    np.divide(out, share[..., None], out=out, where=share[..., None] > 0)
    return out, share


@functools.lru_cache(maxsize=2)
def _maps(fx, fy, cx, cy, width, height, lens, f, tcx, tcy, twidth, theight):
    """OpenCV's remap tables of :func:`undistort` and the pixels they saw, once per camera: a capture's photos
    usually share one (COLMAP, nerfstudio), and building the tables costs more than the remap.

    Returns ``(mx, my, seen, m)``: float32 (H m, W m) source coordinates, the bool mask of those inside the
    photo and before the model folds, and the sub-pixels per target pixel ``m``. Read-only.
    """
    import cv2

    m = max(1, math.ceil(max(fx, fy) / f - 1e-9))
    P = np.array([[f * m, 0.0, tcx * m - 0.5], [0.0, f * m, tcy * m - 0.5], [0.0, 0.0, 1.0]])
    size = (twidth * m, theight * m)
    K, D = _intrinsics(fx, fy, cx, cy), np.array(lens.coefficients)
    if lens.model == "fisheye":
        mx, my = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), P, size, cv2.CV_32FC1)
    else:
        mx, my = cv2.initUndistortRectifyMap(K, D, np.eye(3), P, size, cv2.CV_32FC1)
    seen = (mx >= -0.5) & (mx <= width - 0.5) & (my >= -0.5) & (my <= height - 0.5)
    x = ((np.arange(size[0], dtype=np.float32) + 0.5) / m - np.float32(tcx)) / np.float32(f)
    y = ((np.arange(size[1], dtype=np.float32) + 0.5) / m - np.float32(tcy)) / np.float32(f)
    fold = lens.fold_radius(float(np.hypot(np.abs(x).max(), np.abs(y).max())))
    if math.isfinite(fold):
        seen &= x[None, :] ** 2 + y[:, None] ** 2 < fold**2
    for a in (mx, my, seen):
        a.flags.writeable = False
    return mx, my, seen, m
