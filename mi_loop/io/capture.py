"""Calibrated multi-view captures: NeRF / Blender ``transforms.json`` files, read as ideal pinholes.

A capture is a list of :class:`View`: a pinhole :class:`Camera` with square
pixels, the image in linear RGB, a foreground mask and, for an undistorted
photo, the share of each pixel that the photo saw. :func:`read_capture` reads
what Blender's NeRF exporter, instant-ngp and nerfstudio write;
:func:`write_capture` (:mod:`mi_loop.io.capture_writer`) writes one that
instant-ngp and nerfstudio read.

- Cameras: ``c2w`` is camera-to-world with OpenGL axes (the camera looks down
  -Z, +Y up, +X right); pixel coordinates run x right and y down from the
  top-left corner of the top-left pixel, so a centred principal point is
  ``(w / 2, h / 2)``. :mod:`mi_loop.render.cameras` turns them into Mitsuba sensors.
- Lenses: ``camera_model`` names COLMAP's models as nerfstudio writes them:
  SIMPLE_PINHOLE, PINHOLE; SIMPLE_RADIAL (``k1``), RADIAL (``k1 k2``), OPENCV
  (``k1 k2 p1 p2``, and ``k3`` if given), FULL_OPENCV (``k1 k2 p1 p2 k3 k4 k5
  k6``, the rational model); OPENCV_FISHEYE (``k1 k2 k3 k4``, the equidistant
  fisheye of ``cv2.fisheye``). Without ``camera_model`` a frame is OPENCV, or
  OPENCV_FISHEYE with instant-ngp's ``is_fisheye``. A coefficient the model
  does not have must be 0 or absent; other models (FOV, equirectangular, ...)
  are refused. instant-ngp's ``scale``, ``offset`` and ``aabb_scale`` are its
  own normalisation and are ignored.
- Resampling (``undistort=True``, the default): a photo with lens distortion
  or with ``fl_x != fl_y`` is resampled by OpenCV to the ideal pinhole of
  :func:`~mi_loop.io.undistort.ideal_camera` (square pixels of the longer
  focal length; its image holds the whole photo, so part of it is unseen and
  ``View.valid`` says which); rgb is resampled in linear RGB and the mask with
  it, both area-averaged to the target size (:func:`~mi_loop.io.undistort.undistort`).
  A pinhole photo with square pixels keeps its camera. ``undistort=False``
  keeps every photo as stored and refuses distortion.
- Working size: ``resolution`` (or ``factor``) scales every view as it is read;
  a JPEG is decoded reduced by 2, 4 or 8 when that leaves at least
  :data:`OVERSAMPLE` times the target's resolution (:func:`~mi_loop.io.pixels.read_pixels`),
  then resampled to the target by area in linear RGB, so only one photo at a
  time is ever held at its decoded size.
  Intrinsics scale exactly: pixel coordinates ``x -> s x``.
- Images: PNG and JPEG are sRGB-decoded by the exact EOTF (:func:`mi_loop.io.srgb.srgb_to_linear`);
  EXR is linear and kept as stored (EXR's colours are premultiplied by alpha,
  PNG's are not). 8-bit images go through Pillow; 16-bit PNGs (Pillow reduces
  16-bit colour to 8 bits) and EXR through ``mitsuba.Bitmap``, imported when
  needed (it needs no variant).
- Masks: the image's alpha, or the image at ``mask_path`` (its alpha channel
  when it has one, else its first channel; not sRGB-decoded), in [0, 1]; a
  JPEG mask stays soft.

Every rejected file raises a one-line :class:`ValueError` naming the JSON file,
the frame (``frames[i]``) and the field.
"""
from __future__ import annotations

import glob
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.capture_writer import write_capture
from mi_loop.io.pixels import Pixels, image_size, read_pixels
from mi_loop.io.srgb import srgb_to_linear
from mi_loop.io.undistort import Lens, area_resize, ideal_camera, scale_camera, undistort
from mi_loop.io.views import Camera, Capture, View, check_factor, pose_problem

__all__ = ["IMAGE_SUFFIXES", "OVERSAMPLE", "Camera", "Capture", "View", "list_captures", "read_capture",
           "write_capture"]

#: Image suffixes :func:`read_capture` reads, in the order it tries them for a ``file_path`` without one.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr")
#: ``camera_model`` (COLMAP's names) -> its :class:`~mi_loop.io.undistort.Lens` model and the coefficients it has.
_MODELS = {"SIMPLE_PINHOLE": ("opencv", ()), "PINHOLE": ("opencv", ()), "SIMPLE_RADIAL": ("opencv", ("k1",)),
           "RADIAL": ("opencv", ("k1", "k2")), "OPENCV": ("opencv", ("k1", "k2", "p1", "p2", "k3")),
           "FULL_OPENCV": ("opencv", ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
           "OPENCV_FISHEYE": ("fisheye", ("k1", "k2", "k3", "k4"))}
_DISTORTION = ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2")
#: The order of :attr:`Lens.coefficients <mi_loop.io.undistort.Lens.coefficients>` for each model.
_LENS_ORDER = {"opencv": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), "fisheye": ("k1", "k2", "k3", "k4")}
#: A JPEG is decoded reduced to no less than this many times the target's resolution, the rest done by area
#: averaging in linear RGB: libjpeg's reduction filters the sRGB-encoded values (by its scaled inverse DCT),
#: which darkens and rings at edges. At 4000 -> 400 px, a reduction by 8 instead of 4 puts the mean error
#: against the exact linear area average at 1.2 % instead of 0.35 % (on ``bench/bench_read.py``'s copies,
#: upsampled from 1000 px: sharper photos lose more).
OVERSAMPLE = 2
#: sRGB-decoded 8-bit values, as :func:`srgb_to_linear` gives them.
_SRGB_TO_LINEAR = srgb_to_linear(np.arange(256, dtype=np.float32) / np.float32(255))


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

    def fail(self, key: str, what: str, got) -> NoReturn:
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


def _check_image(fr: _Frame, key: str, path: Path) -> tuple[int, int]:
    """``(width, height)`` of the image ``key`` names, from its header."""
    try:
        return image_size(path)
    except (OSError, RuntimeError, SyntaxError, ValueError) as exc:
        fr.fail(key, "a readable image", f"'{path}': {type(exc).__name__}: {exc}".splitlines()[0])


def _decode(path: Path, fr: _Frame, key: str, reduction: int) -> Pixels:
    """The pixels of ``path`` (a JPEG reduced by up to ``reduction``), checked finite and of a known format."""
    try:
        px = read_pixels(path, reduction)
    except (OSError, RuntimeError, SyntaxError, ValueError) as exc:
        fr.fail(key, "a readable image", f"'{path}': {type(exc).__name__}: {exc}".splitlines()[0])
    if px.odd_format:
        fr.fail(key, "a grey, grey + alpha, RGB or RGBA image", f"{px.odd_format} in '{path}'")
    if px.data.dtype != np.uint8:
        bad = ~np.isfinite(px.data)
        if bad.any():
            fr.fail(key, "finite pixels", f"{px.data[bad][0]} at pixel {np.argwhere(bad)[0, :2].tolist()} of '{path}'")
    return px


def _unit(a: np.ndarray) -> np.ndarray:
    return a.astype(np.float32) / np.float32(255) if a.dtype == np.uint8 else a


def _mask(plan: _Plan, alpha, reduction: int, shape) -> np.ndarray:
    """The frame's mask at the image's reduction: ``mask_path`` (its alpha if it has one, else its first
    channel), else the image's alpha, else ones."""
    fr, key = plan.fr, "mask_path"
    if plan.mask is not None:
        px = _decode(plan.mask, fr, key, reduction)
        alpha = px.data[..., -1] if px.data.shape[2] in (2, 4) else px.data[..., 0]
        if alpha.dtype != np.uint8:
            bad = ~((alpha >= 0) & (alpha <= 1))
            if bad.any():
                fr.fail(key, "mask values in [0, 1]", f"{alpha[bad][0]} at pixel {np.argwhere(bad)[0].tolist()}")
        if px.reduction != reduction:          # a PNG mask of a reduced JPEG: reduced by an integer factor
            alpha = area_resize(_unit(alpha), shape)
    else:
        key = "file_path"
        if alpha is None:
            return np.ones(shape, dtype=np.float32)
    if not alpha.any():
        fr.fail(key, "a mask with some foreground", "an empty mask (all zero)" if key == "mask_path"
                else "an image whose alpha is zero everywhere (an empty mask)")
    return np.clip(_unit(alpha), 0, 1)


def _lens(fr: _Frame, undistort: bool) -> Lens:
    """The frame's lens: its ``camera_model`` (default OPENCV, or OPENCV_FISHEYE with ``is_fisheye``)."""
    fisheye = fr.get("is_fisheye")
    model = fr.get("camera_model")
    default = model is None
    if default:
        model = "OPENCV_FISHEYE" if fisheye else "OPENCV"
    elif model not in _MODELS:
        fr.fail("camera_model", f"a camera model mi_loop reads ({', '.join(_MODELS)})", repr(model))
    if fisheye and model != "OPENCV_FISHEYE":
        fr.fail("is_fisheye", f"false for camera_model {model}", fisheye)
    kind, keys = _MODELS[model]
    values = {key: fr.number(key) or 0.0 for key in _DISTORTION}
    for key in _DISTORTION:
        if values[key] and key not in keys:
            fr.fail(key, f"0 (camera_model {model}{' (the default)' if default else ''} has no {key})", fr.get(key))
    lens = Lens(kind, tuple(values[key] for key in _LENS_ORDER[kind]))
    if not undistort and not lens.is_pinhole:
        key = next((k for k in _DISTORTION if values[k]), "is_fisheye" if default else "camera_model")
        fr.fail(key, "a pinhole without distortion (read with undistort=True to undistort)",
                repr(model) if key == "camera_model" else fr.get(key))
    return lens


def _camera(fr: _Frame, w_img: int, h_img: int) -> Camera:
    """The frame's camera from its own or the top level's intrinsics and its transform_matrix."""
    for key in ("w", "h"):
        size = w_img if key == "w" else h_img
        value = fr.number(key, "a positive integer", lambda v: v > 0 and v == int(v))
        if value is not None and int(value) != size:
            fr.fail(key, f"the size of the image ({w_img} x {h_img})", int(value))
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
    problem = pose_problem(matrix) if matrix is not None else ("a camera-to-world 4 x 4 matrix", "none")
    if problem:
        fail("read_capture", f"{problem[0]} for frames[{fr.i}].transform_matrix in '{fr.path}'", problem[1])
    return Camera(np.asarray(matrix, dtype=np.float64), fx, fx if fy is None else fy,
                  0.5 * w_img if cx is None else cx, 0.5 * h_img if cy is None else cy, w_img, h_img)


@dataclass(frozen=True)
class _Plan:
    """What a frame is read as, known from the JSON and the files' headers before any pixel is decoded."""

    fr: _Frame
    image: Path
    mask: Path | None
    camera: Camera              # the photo's, full size, intrinsics in the lens's model
    lens: Lens
    ideal: Camera | None        # the pinhole it is resampled to at full size; None: the photo's own camera

    @property
    def out(self) -> Camera:
        return self.camera if self.ideal is None else self.ideal


def _plan(fr: _Frame, undistort: bool) -> _Plan:
    image = _image_file(fr, "file_path")
    w, h = _check_image(fr, "file_path", image)
    mask = None
    if fr.frame.get("mask_path") is not None:
        mask = _image_file(fr, "mask_path")
        size = _check_image(fr, "mask_path", mask)
        if size != (w, h):
            fr.fail("mask_path", f"a mask of the image's size {w} x {h}", f"{size[0]} x {size[1]} in '{mask}'")
    camera = _camera(fr, w, h)
    lens = _lens(fr, undistort)
    square = abs(camera.fx - camera.fy) <= 1e-6 * max(camera.fx, camera.fy)
    ideal = None if not undistort or (lens.is_pinhole and square) else ideal_camera(camera, lens)
    return _Plan(fr, image, mask, camera, lens, ideal)


def _read_view(plan: _Plan, scale: float) -> View:
    """Decode one frame's image and mask, reduced, undistorted and resized to ``scale`` of :attr:`_Plan.out`."""
    fr = plan.fr
    target = plan.out if scale == 1 else scale_camera(plan.out, scale)
    if plan.ideal is None:                      # decoded at OVERSAMPLE times the target's size or more
        most = max(1, math.floor(1 / (OVERSAMPLE * scale) + 1e-9))
    else:                                       # at OVERSAMPLE times the target's focal length or more
        most = max(1, math.floor(min(plan.camera.fx, plan.camera.fy) / (OVERSAMPLE * target.fx) + 1e-9))
    px = _decode(plan.image, fr, "file_path", most)
    r, data = px.reduction, px.data
    c = data.shape[2]
    rgb = data[..., :3] if c >= 3 else np.repeat(data[..., :1], 3, axis=2)
    rgb = _SRGB_TO_LINEAR[rgb] if rgb.dtype == np.uint8 else srgb_to_linear(rgb) if px.srgb else rgb
    mask = _mask(plan, data[..., -1] if c in (2, 4) else None, r, rgb.shape[:2])
    del data, px
    source = scale_camera(plan.camera, 1 / r)   # exact: r divides the photo's size
    if plan.ideal is None:
        s = scale * r
        extent = (target.height / s, target.width / s)
        size = (target.height, target.width)
        return View(target, area_resize(rgb, size, extent), np.clip(area_resize(mask, size, extent), 0, 1),
                    fr.frame["file_path"])
    out, seen = undistort(np.dstack([rgb, mask]), source, plan.lens, target)
    return View(target, out[..., :3], np.clip(out[..., 3], 0, 1), fr.frame["file_path"],
                None if seen.min() >= 1 else seen)


def read_capture(path, *, factor: float = 1.0, resolution: int | None = None, undistort: bool = True) -> Capture:
    """Read a NeRF / Blender / instant-ngp / nerfstudio ``transforms.json`` and its images.

    Intrinsics are ``fl_x`` (``fl_y`` defaults to it), ``cx``, ``cy`` (default
    ``w / 2``, ``h / 2``), or ``camera_angle_x`` (horizontal field of view in
    radians: ``fx = fy = w / 2 / tan(camera_angle_x / 2)``; with
    ``camera_angle_y``, ``fy = h / 2 / tan(camera_angle_y / 2)``); ``fl_x`` wins
    when both are given. Each key may sit at the top level or in a frame (the
    frame's wins). ``w`` and ``h``, when given, must be the image's size.
    ``file_path`` and ``mask_path`` are relative to the JSON's directory; without
    an image suffix (Blender's ``./train/r_0``) ``.png``, ``.jpg``, ``.jpeg``,
    ``.exr`` are tried in that order. Lenses and resampling: the module's docstring.

    Every frame is checked (the JSON, the files' headers) before any image is
    decoded; then the images are decoded one at a time, each straight to its
    final size, so that at most one photo is held at full size.

    Parameters
    ----------
    path : str or os.PathLike
        The JSON file, or a capture directory in any format
        :func:`mi_loop.io.camera_formats.detect` recognises (IDR / NeuS,
        LLFF, COLMAP, or one holding a ``transforms.json``).
    factor : float, optional
        Scale every view by exactly this factor as it is read, in (0, 1]: pixel
        coordinates ``x -> factor x``, the size ``floor(factor * size)`` (the last
        part-pixel cropped; :func:`~mi_loop.io.undistort.scale_camera`).
    resolution : int, optional
        Instead of ``factor``: the longest side, in pixels, of the largest view
        (all views scale by the one factor ``resolution / longest``, never above 1).
    undistort : bool, optional
        Resample photos with lens distortion or non-square pixels to ideal
        pinholes with square pixels (the default). False: every photo as stored,
        its camera's ``fx`` and ``fy`` as given, lens distortion refused.

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
        an unknown ``camera_model`` or a coefficient it does not have; an
        all-zero mask or one of another size than its image; a bad ``factor``
        or ``resolution``, or both given. The message names the file, the frame
        and the field.
    """
    factor = check_factor(factor, "read_capture", downsampling=True)
    if resolution is not None:
        if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 1:
            fail("read_capture", "an integer resolution >= 1 or None", resolution)
        if factor != 1:
            fail("read_capture", "factor or resolution, not both", f"factor = {factor}, resolution = {resolution}")
    path = Path(path)
    fmt, meta = _load_meta(path)
    plans = [_plan(_Frame(path, meta, i), bool(undistort)) for i in range(len(meta["frames"]))]
    if resolution is not None:
        factor = min(1.0, resolution / max(max(p.out.width, p.out.height) for p in plans))
    return Capture(tuple(_read_view(p, factor) for p in plans), path, fmt, meta.get("normalisation"))


def _load_meta(path: Path) -> tuple[str, dict]:
    """A ``transforms.json`` file's contents, or a capture directory's cameras in its form (any format)."""
    if path.suffix.lower() == ".json" or not path.is_dir():
        return "transforms", _read_json(path)
    from mi_loop.io.camera_formats import load_meta

    fmt, meta = load_meta(path)
    if not meta.get("frames"):
        fail("read_capture", f"at least one photo in the {fmt} capture '{path}'", "none")
    return fmt, meta


def _capture_in(directory: Path, name: str):
    """``directory / name``, the directory itself if it holds a capture of another format, or None."""
    from mi_loop.io.camera_formats import detect

    if (directory / name).is_file():
        return directory / name
    try:
        detect(directory)
    except ValueError:
        return None
    return directory


def list_captures(inputs, name: str = "transforms.json", where: str = "list_captures") -> list:
    """The captures of a sequence, one per frame, sorted: ``transforms.json`` paths (not read yet).

    Parameters
    ----------
    inputs : list of str or os.PathLike
        ``transforms.json`` files (any name ending in ``.json``); directories
        holding one (``DIR/transforms.json``) or a capture of another format
        (:func:`mi_loop.io.camera_formats.detect`: IDR / NeuS, LLFF, COLMAP),
        or whose sub-directories do (``DIR/0000/transforms.json`` ...,
        ``DIR/0000/cameras_sphere.npz`` ..., sorted by name); or quoted glob
        patterns (``'cap/*/transforms.json'``, sorted). The order given is kept
        between items.
    name : str
        The file name looked for in directories.
    where : str
        Who asks, for messages (``'fit-sequence --images'``).

    Returns
    -------
    list of pathlib.Path
        ``transforms.json`` files, or the directories of captures in another
        format (:func:`read_capture` takes either).

    Raises
    ------
    ValueError
        A path that does not exist, a directory without captures, a pattern
        that matches nothing.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     for f in ("b", "a"):
    ...         os.makedirs(os.path.join(d, f)); _ = open(os.path.join(d, f, "transforms.json"), "w").write("{}")
    ...     [p.parent.name for p in list_captures([d])]
    ['a', 'b']
    """
    out = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            if _capture_in(p, name) is not None:
                out.append(_capture_in(p, name))
                continue
            found = sorted(c for c in (_capture_in(q, name) for q in p.iterdir() if q.is_dir()) if c is not None)
            if not found:
                fail(where, f"a directory holding {name} or a capture of another format (IDR, LLFF, COLMAP), "
                     "or sub-directories that do", f"none in '{p}'")
            out += found
        elif p.is_file():
            out.append(p)
        elif any(c in str(item) for c in "*?["):
            matches = sorted(Path(m) for m in glob.glob(str(item)))
            matches = [m / name if m.is_dir() else m for m in matches]
            matches = [m for m in matches if m.is_file()]
            if not matches:
                fail(where, "captures matching the pattern", f"none for '{item}'")
            out += matches
        else:
            fail(where, "an existing transforms.json, directory or glob pattern",
                 f"'{p}': no such file or directory")
    return out
