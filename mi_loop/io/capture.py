"""Calibrated multi-view captures: NeRF / Blender ``transforms.json`` files, read and written.

A capture is a list of :class:`View`: a pinhole :class:`Camera`, the image in
linear RGB and a foreground mask. :func:`read_capture` reads what Blender's
NeRF exporter, instant-ngp and nerfstudio write; :func:`write_capture` writes
one that instant-ngp and nerfstudio read (its ``file_path`` keeps the ``.png``,
which the original NeRF Blender loader would add a second time).

- Cameras: ``c2w`` is camera-to-world with OpenGL axes (the camera looks down
  -Z, +Y up, +X right); pixel coordinates run x right and y down from the
  top-left corner of the top-left pixel, so a centred principal point is
  ``(w / 2, h / 2)``. :mod:`mi_loop.render.cameras` turns them into Mitsuba sensors.
- Images: PNG and JPEG are sRGB-decoded by the exact EOTF (:func:`mi_loop.io.srgb.srgb_to_linear`);
  EXR is linear and kept as stored (EXR's colours are premultiplied by alpha,
  PNG's are not). 8-bit images go through Pillow; 16-bit PNGs (Pillow reduces
  16-bit colour to 8 bits) and EXR through ``mitsuba.Bitmap``, imported when
  needed (it needs no variant).
- Masks: the image's alpha, or the image at ``mask_path`` (its alpha channel
  when it has one, else its first channel; not sRGB-decoded), in [0, 1].
- Distortion is not modelled: non-zero ``k1 k2 k3 k4 p1 p2`` and fisheye or
  equirectangular camera models are refused. instant-ngp's ``scale``,
  ``offset`` and ``aabb_scale`` are its own normalisation and are ignored.

Every rejected file raises a one-line :class:`ValueError` naming the JSON file,
the frame (``frames[i]``) and the field.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.files import ensure_writable_dir, first_missing_ancestor, remove_if_empty, staged_outputs, write_text
from mi_loop.io.srgb import linear_to_srgb, srgb_to_linear

__all__ = ["IMAGE_SUFFIXES", "Camera", "Capture", "View", "read_capture", "write_capture"]

#: Image suffixes :func:`read_capture` reads, in the order it tries them for a ``file_path`` without one.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr")
#: Camera models that are pinholes once their distortion coefficients are zero.
_PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")
_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")


def _pose_problem(c2w):
    """``(what, got)`` when ``c2w`` is no camera-to-world matrix, else None."""
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


def _factor(factor, func: str, downsampling: bool = False) -> float:
    """``factor`` as a float; refuse one that is not finite and > 0 (or is above 1 when ``downsampling``)."""
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
        problem = _pose_problem(self.c2w)
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
        factor = _factor(factor, "Camera.scaled")
        w, h = (_scaled_size(n, factor, "Camera.scaled") for n in (self.width, self.height))
        sx, sy = w / self.width, h / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy, width=w, height=h)


def _box_average(a: np.ndarray, m: int, axis: int) -> np.ndarray:
    """Average ``a`` over ``m`` equal intervals along ``axis``, with exact fractional-pixel weights."""
    n = a.shape[axis]
    if m == n:
        return a
    a = np.moveaxis(a, axis, 0).astype(np.float64)
    if n % m == 0:
        out = a.reshape(m, n // m, *a.shape[1:]).mean(axis=1)
    else:                                   # integral of the piecewise-constant image at m + 1 cuts
        C = np.concatenate([np.zeros((1, *a.shape[1:])), np.cumsum(a, axis=0)])
        t = np.arange(m + 1) * (n / m)
        k = np.minimum(np.floor(t).astype(np.int64), n - 1)
        S = C[k] + (t - k).reshape(-1, *[1] * (a.ndim - 1)) * a[k]
        out = np.diff(S, axis=0) * (m / n)
    return np.moveaxis(out, 0, axis)


@dataclass(frozen=True, eq=False)
class View:
    """One calibrated image: camera, linear RGB, foreground mask.

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

    Raises
    ------
    ValueError
        Arrays whose shape differs from the camera's image, non-finite pixels,
        mask values outside [0, 1].
    """

    camera: Camera
    rgb: np.ndarray
    mask: np.ndarray
    name: str

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

    def resized(self, factor: float) -> View:
        """Return the view downsampled by ``factor`` (area-averaged rgb and mask, :meth:`Camera.scaled`).

        Every new pixel is the mean of the old image over its footprint
        (``old / new`` pixels on each axis, fractional pixels weighted by their area).

        Parameters
        ----------
        factor : float
            In (0, 1]; 1 returns the view itself.

        Returns
        -------
        View
        """
        camera = self.camera.scaled(_factor(factor, "View.resized", downsampling=True))
        if (camera.width, camera.height) == (self.camera.width, self.camera.height):
            return self
        def resample(a):
            return _box_average(_box_average(a, camera.height, 0), camera.width, 1)
        return View(camera, resample(self.rgb), np.clip(resample(self.mask), 0, 1), self.name)


@dataclass(frozen=True, eq=False)
class Capture:
    """A calibrated multi-view capture as read from a ``transforms.json``.

    Attributes
    ----------
    views : tuple of View
        In the order of the JSON's ``frames``.
    path : pathlib.Path
        The ``transforms.json`` file.
    """

    views: tuple
    path: Path


# -------------------------------------------------------------------- reading


def _read_json(path: Path) -> dict:
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        fail("read_capture", f"a readable JSON file '{path}'", f"{type(exc).__name__}: {exc.strerror or exc}")
    except (ValueError, UnicodeDecodeError) as exc:
        fail("read_capture", f"a JSON file '{path}'", f"{type(exc).__name__}: {exc}")
    if not isinstance(meta, dict):
        fail("read_capture", f"a JSON object in '{path}'", type(meta).__name__)
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        fail("read_capture", f"a non-empty list 'frames' in '{path}'",
             "none" if frames is None else repr(frames)[:80])
    return meta


class _Frame:
    """Look-ups in frame ``i`` of a JSON file, falling back to the top level, and their messages."""

    def __init__(self, path: Path, meta: dict, i: int):
        self.path, self.meta, self.i = path, meta, i
        self.frame = meta["frames"][i]
        if not isinstance(self.frame, dict):
            fail("read_capture", f"a JSON object for frames[{i}] in '{path}'", repr(self.frame)[:80])

    def label(self, key: str) -> str:
        if key in self.frame or key not in self.meta:
            return f"frames[{self.i}].{key}"
        return f"{key} (top level, for frames[{self.i}])"

    def fail(self, key: str, what: str, got):
        fail("read_capture", f"{what} for {self.label(key)} in '{self.path}'", got)

    def get(self, key: str):
        return self.frame.get(key, self.meta.get(key))

    def number(self, key: str, what: str = "a finite number", test=lambda v: True):
        value = self.get(key)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or not test(value):
            self.fail(key, what, repr(value) if isinstance(value, str) else value)
        return float(value)


def _image_file(fr: _Frame, key: str) -> Path:
    """The file that ``key`` (``file_path`` or ``mask_path``) names, suffix added as Blender omits it."""
    name = fr.frame.get(key)
    if not isinstance(name, str) or not name:
        fr.fail(key, "a file name", "none" if name is None else repr(name))
    base = fr.path.parent / name
    if base.suffix.lower() in IMAGE_SUFFIXES or base.is_file():
        if not base.is_file():
            fr.fail(key, "an existing image file", f"no file '{base}'")
        if base.suffix.lower() not in IMAGE_SUFFIXES:
            fr.fail(key, f"a {', '.join(IMAGE_SUFFIXES)} image", f"'{base}'")
        return base
    tried = [base.with_name(base.name + s) for s in IMAGE_SUFFIXES]
    found = next((p for p in tried if p.is_file()), None)
    if found is None:
        fr.fail(key, "an existing image file", "none of " + ", ".join(f"'{p}'" for p in tried))
    return found


def _png_bit_depth(path: Path) -> int | None:
    with open(path, "rb") as f:
        head = f.read(26)
    return head[24] if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR" else None


def _read_pixels(path: Path):
    """``(data, format)``: 8-bit PNG / JPEG by Pillow, 16-bit PNG and EXR by ``mitsuba.Bitmap``."""
    if path.suffix.lower() == ".exr" or _png_bit_depth(path) == 16:
        import mitsuba as mi  # Bitmap is a core class: no variant needed

        bitmap = mi.Bitmap(str(path))
        channels = {mi.Bitmap.PixelFormat.Y: 1, mi.Bitmap.PixelFormat.YA: 2, mi.Bitmap.PixelFormat.RGB: 3,
                    mi.Bitmap.PixelFormat.RGBA: 4}
        data = np.array(bitmap)
        scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(data.dtype, 1.0)
        data = (data.astype(np.float32) / np.float32(scale)).reshape(*data.shape[:2], -1)
        return data, None if bitmap.pixel_format() in channels else str(bitmap.pixel_format())
    from PIL import Image

    with Image.open(path) as image:
        image.load()
        alpha = any(b in ("A", "a") for b in image.getbands()) or "transparency" in image.info
        if image.mode not in ("L", "LA", "RGB", "RGBA"):
            image = image.convert("RGBA" if alpha else "RGB")
        return np.asarray(image, dtype=np.float32).reshape(image.height, image.width, -1) / np.float32(255), None


def _decode(path: Path, fr: _Frame, key: str):
    """Pixels ``(h, w, c)`` float32 (c = 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA), in [0, 1] except EXR's,
    and whether the colours are sRGB-encoded (all but EXR)."""
    try:
        data, odd_format = _read_pixels(path)
    except (OSError, RuntimeError, SyntaxError, ValueError) as exc:
        fr.fail(key, "a readable image", f"'{path}': {type(exc).__name__}: {exc}".splitlines()[0])
    if odd_format:
        fr.fail(key, "a grey, grey + alpha, RGB or RGBA image", f"{odd_format} in '{path}'")
    bad = ~np.isfinite(data)
    if bad.any():
        fr.fail(key, "finite pixels", f"{data[bad][0]} at pixel {np.argwhere(bad)[0, :2].tolist()} of '{path}'")
    return data, path.suffix.lower() != ".exr"


def _mask(fr: _Frame, alpha, size) -> np.ndarray:
    """The frame's mask: ``mask_path`` (alpha if it has one, else its first channel), else alpha, else ones."""
    key = "mask_path"
    if fr.frame.get(key) is not None:
        path = _image_file(fr, key)
        data, _ = _decode(path, fr, key)
        alpha = data[..., -1] if data.shape[2] in (2, 4) else data[..., 0]
        if alpha.shape != size:
            fr.fail(key, f"a mask of the image's size {size[1]} x {size[0]}",
                    f"{alpha.shape[1]} x {alpha.shape[0]} in '{path}'")
        bad = ~((alpha >= 0) & (alpha <= 1))
        if bad.any():
            fr.fail(key, "mask values in [0, 1]", f"{alpha[bad][0]} at pixel {np.argwhere(bad)[0].tolist()}")
    else:
        key = "file_path"
        if alpha is None:
            return np.ones(size, dtype=np.float32)
    if not alpha.any():
        fr.fail(key, "a mask with some foreground", "an empty mask (all zero)" if key == "mask_path"
                else "an image whose alpha is zero everywhere (an empty mask)")
    return np.clip(alpha, 0, 1)


def _camera(fr: _Frame, w_img: int, h_img: int) -> Camera:
    """The frame's camera from its own or the top level's intrinsics and its transform_matrix."""
    for key in ("w", "h"):
        size = w_img if key == "w" else h_img
        value = fr.number(key, "a positive integer", lambda v: v > 0 and v == int(v))
        if value is not None and int(value) != size:
            fr.fail(key, f"the size of the image ({w_img} x {h_img})", int(value))
    model = fr.get("camera_model")
    if model is not None and model not in _PINHOLE_MODELS:
        fr.fail("camera_model", f"a pinhole model ({', '.join(_PINHOLE_MODELS)})", repr(model))
    if fr.get("is_fisheye"):
        fr.fail("is_fisheye", "a pinhole camera (false)", fr.get("is_fisheye"))
    for key in _DISTORTION:
        if fr.number(key):
            fr.fail(key, "no lens distortion (0: mi_loop models pinholes; undistort the images first)", fr.get(key))
    fx = fr.number("fl_x", "a focal length > 0", lambda v: v > 0)
    fy = fr.number("fl_y", "a focal length > 0", lambda v: v > 0)
    angle_x = fr.number("camera_angle_x", "an angle in (0, pi) radians", lambda v: 0 < v < math.pi)
    angle_y = fr.number("camera_angle_y", "an angle in (0, pi) radians", lambda v: 0 < v < math.pi)
    if fx is None:
        if angle_x is None:
            fail("read_capture", f"intrinsics fl_x or camera_angle_x (per frame or at the top level) for "
                 f"frames[{fr.i}] in '{fr.path}'", "neither")
        fx = 0.5 * w_img / math.tan(0.5 * angle_x)
        if fy is None and angle_y is not None:
            fy = 0.5 * h_img / math.tan(0.5 * angle_y)
    cx = fr.number("cx")
    cy = fr.number("cy")
    matrix = fr.frame.get("transform_matrix")
    problem = _pose_problem(matrix) if matrix is not None else ("a camera-to-world 4 x 4 matrix", "none")
    if problem:
        fail("read_capture", f"{problem[0]} for frames[{fr.i}].transform_matrix in '{fr.path}'", problem[1])
    return Camera(np.asarray(matrix, dtype=np.float64), fx, fx if fy is None else fy,
                  0.5 * w_img if cx is None else cx, 0.5 * h_img if cy is None else cy, w_img, h_img)


def read_capture(path, *, factor: float = 1.0) -> Capture:
    """Read a NeRF / Blender / instant-ngp / nerfstudio ``transforms.json`` and its images.

    Intrinsics are ``fl_x`` (``fl_y`` defaults to it), ``cx``, ``cy`` (default
    ``w / 2``, ``h / 2``), or ``camera_angle_x`` (horizontal field of view in
    radians: ``fx = fy = w / 2 / tan(camera_angle_x / 2)``; with
    ``camera_angle_y``, ``fy = h / 2 / tan(camera_angle_y / 2)``); ``fl_x`` wins
    when both are given. Each key may sit at the top level or in a frame (the
    frame's wins). ``w`` and ``h``, when given, must be the image's size.
    ``file_path`` and ``mask_path`` are relative to the JSON's directory; without
    an image suffix (Blender's ``./train/r_0``) ``.png``, ``.jpg``, ``.jpeg``,
    ``.exr`` are tried in that order.

    Parameters
    ----------
    path : str or os.PathLike
        The JSON file.
    factor : float, optional
        Downsample every view as it is read (:meth:`View.resized`), in (0, 1].

    Returns
    -------
    Capture
        Views in the order of ``frames``.

    Raises
    ------
    ValueError
        A missing or unreadable JSON file; no ``frames``; a missing or unreadable
        image; an image size other than ``w`` x ``h``; a ``transform_matrix`` not
        4 x 4, not finite, singular or whose last row is not (0, 0, 0, 1); no
        ``fl_x`` nor ``camera_angle_x``; a focal length or angle out of range;
        lens distortion; an all-zero mask or one of another size than its image.
        The message names the file, the frame and the field.
    """
    factor = _factor(factor, "read_capture", downsampling=True)
    path = Path(path)
    meta = _read_json(path)
    views = []
    for i in range(len(meta["frames"])):
        fr = _Frame(path, meta, i)
        data, srgb = _decode(_image_file(fr, "file_path"), fr, "file_path")
        rgb = data[..., :3] if data.shape[2] >= 3 else np.repeat(data[..., :1], 3, axis=2)
        alpha = data[..., -1] if data.shape[2] in (2, 4) else None
        h, w = rgb.shape[:2]
        view = View(_camera(fr, w, h), srgb_to_linear(rgb) if srgb else rgb,
                    _mask(fr, alpha, (h, w)), fr.frame["file_path"])
        views.append(view if factor == 1 else view.resized(factor))
    return Capture(tuple(views), path)


# -------------------------------------------------------------------- writing


def _frame_entry(view: View, file_path: str) -> dict:
    cam = view.camera
    return {"file_path": file_path, "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy,
            "w": cam.width, "h": cam.height, "transform_matrix": cam.c2w.tolist()}


def write_capture(directory, views, *, name: str = "transforms.json") -> Path:
    """Write views as ``directory/images/NNN.png`` and a ``transforms.json``, atomically.

    Images are 8-bit RGBA PNGs: sRGB-encoded colours, alpha = mask. Every frame
    carries its own ``fl_x fl_y cx cy w h`` and ``transform_matrix`` (floats
    written exactly); when all views share one centred, square-pixel camera the
    top level also gets ``camera_angle_x`` for readers that know only that.
    Nothing is written unless everything is: the files are staged and moved in
    at the end (images first, the JSON last). Other files already in
    ``directory/images`` stay.

    Parameters
    ----------
    directory : str or os.PathLike
        Created if needed.
    views : sequence of View
        At least one; rgb in [0, 1] (clip HDR renders first).
    name : str, optional
        File name of the JSON.

    Returns
    -------
    pathlib.Path
        The JSON file; :func:`read_capture` of it gives the cameras back exactly
        and the images to 8-bit precision.

    Raises
    ------
    ValueError
        No views, rgb outside [0, 1], a directory that cannot be written.
    TypeError
        An item that is not a View.
    """
    from PIL import Image

    views = tuple(views)
    if not views:
        fail("write_capture", "at least one View", "none")
    for k, view in enumerate(views):
        if not isinstance(view, View):
            fail("write_capture", f"a View at views[{k}]", type(view).__name__, TypeError)
        bad = (view.rgb < 0) | (view.rgb > 1)
        if bad.any():
            fail("write_capture", f"rgb in [0, 1] for an 8-bit PNG at views[{k}] (clip it first)",
                 f"{view.rgb[bad][0]} at pixel {np.argwhere(bad)[0, :2].tolist()}")
    directory = Path(directory)
    images = directory / "images"
    top = first_missing_ancestor(images)
    ensure_writable_dir(images)
    digits = max(3, len(str(len(views) - 1)))
    files = [f"images/{k:0{digits}d}.png" for k in range(len(views))]
    meta = {"frames": [_frame_entry(v, f) for v, f in zip(views, files)]}
    cams = {(v.camera.fx, v.camera.fy, v.camera.width, v.camera.height, 2 * v.camera.cx, 2 * v.camera.cy)
            for v in views}
    if len(cams) == 1 and (c := next(iter(cams)))[0] == c[1] and c[4:] == c[2:4]:
        meta = {"camera_angle_x": 2 * math.atan(0.5 * c[2] / c[0]), **meta}
    try:
        with staged_outputs(directory) as stage, staged_outputs(images) as stage_images:
            for view, file in zip(views, files):
                rgba = np.dstack([linear_to_srgb(view.rgb), view.mask])
                pixels = np.round(rgba * 255).astype(np.uint8)
                Image.fromarray(pixels).save(stage_images / Path(file).name, format="PNG")
            write_text(stage / name, json.dumps(meta, indent=1) + "\n")
    except BaseException:
        remove_if_empty(top, images)
        raise
    return directory / name
