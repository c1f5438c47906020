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

import glob
import json
import math
from pathlib import Path
from typing import NoReturn

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.files import ensure_writable_dir, first_missing_ancestor, remove_if_empty, staged_outputs, write_text
from mi_loop.io.srgb import linear_to_srgb, srgb_to_linear
from mi_loop.io.views import Camera, Capture, View, check_factor, pose_problem

__all__ = ["IMAGE_SUFFIXES", "Camera", "Capture", "View", "list_captures", "read_capture", "write_capture"]

#: Image suffixes :func:`read_capture` reads, in the order it tries them for a ``file_path`` without one.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr")
#: Camera models that are pinholes once their distortion coefficients are zero.
_PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")
_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")


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
    problem = pose_problem(matrix) if matrix is not None else ("a camera-to-world 4 x 4 matrix", "none")
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
    factor = check_factor(factor, "read_capture", downsampling=True)
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


def list_captures(inputs, name: str = "transforms.json", where: str = "list_captures") -> list:
    """The captures of a sequence, one per frame, sorted: ``transforms.json`` paths (not read yet).

    Parameters
    ----------
    inputs : list of str or os.PathLike
        ``transforms.json`` files (any name ending in ``.json``); directories
        holding one (``DIR/transforms.json``) or whose sub-directories do
        (``DIR/0000/transforms.json`` ..., sorted by name); or quoted glob
        patterns (``'cap/*/transforms.json'``, sorted). The order given is kept
        between items.
    name : str
        The file name looked for in directories.
    where : str
        Who asks, for messages (``'fit-sequence --images'``).

    Returns
    -------
    list of pathlib.Path

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
            if (p / name).is_file():
                out.append(p / name)
                continue
            found = sorted(q / name for q in p.iterdir() if q.is_dir() and (q / name).is_file())
            if not found:
                fail(where, f"a directory holding {name} or sub-directories that do", f"none in '{p}'")
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
