"""COLMAP sparse models: cameras and registered images, binary (``.bin``) or text (``.txt``).

The files are those COLMAP's ``scripts/python/read_write_model.py`` reads and
writes (binary little-endian). Cameras come back as ``transforms.json``
intrinsics (``camera_model``, ``fl_x fl_y cx cy``, the distortion coefficients
``k1 k2 p1 p2`` a model has, ``w h``): COLMAP puts the centre of the top-left
pixel at (0.5, 0.5), as ``transforms.json`` does, so ``cx``, ``cy`` are kept as
stored. Images come back as :class:`ColmapImage`, world to camera in OpenCV axes.
:mod:`mi_loop.io.camera_formats` turns both into frames.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop.errors import fail

__all__ = ["COLMAP_MODELS", "ColmapImage", "colmap_model_kind", "read_colmap_model"]

#: COLMAP's camera models by id (COLMAP's ``src/colmap/sensor/models.h``).
_MODEL_IDS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE", "FULL_OPENCV",
              "FOV", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "THIN_PRISM_FISHEYE")
#: The models read, and the transforms.json key of each parameter (``f``: ``fl_x`` and ``fl_y``).
COLMAP_MODELS = {"SIMPLE_PINHOLE": ("f", "cx", "cy"), "PINHOLE": ("fl_x", "fl_y", "cx", "cy"),
                 "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"), "RADIAL": ("f", "cx", "cy", "k1", "k2"),
                 "OPENCV": ("fl_x", "fl_y", "cx", "cy", "k1", "k2", "p1", "p2")}


@dataclass(frozen=True)
class ColmapImage:
    """One registered image of a COLMAP model.

    Attributes
    ----------
    name : str
        Its file, relative to the images directory.
    R : (3, 3) float64 NumPy array
        World-to-camera rotation, OpenCV camera axes (x right, y down, z forward):
        ``x_cam = R x + t``.
    t : (3,) float64 NumPy array
        World-to-camera translation.
    camera_id : int
        Its camera, a key of the cameras :func:`read_colmap_model` returns.
    where : str
        Where it was read, for messages (``"line 5 of '.../images.txt'"``).
    """

    name: str
    R: np.ndarray
    t: np.ndarray
    camera_id: int
    where: str


def colmap_model_kind(directory) -> str | None:
    """Say whether a directory holds a COLMAP model, and in which files.

    Parameters
    ----------
    directory : str or os.PathLike
        A candidate model directory (``sparse/0``).

    Returns
    -------
    str or None
        ``".bin"`` with ``cameras.bin`` and ``images.bin`` (looked for first),
        ``".txt"`` with ``cameras.txt`` and ``images.txt``, else None.
    """
    for ext in (".bin", ".txt"):
        if (Path(directory) / f"cameras{ext}").is_file() and (Path(directory) / f"images{ext}").is_file():
            return ext
    return None


class _Binary:
    """Little-endian reads from a ``.bin`` file, a truncated file refused by name."""

    def __init__(self, path: Path, func: str):
        self.path, self.func, self.data, self.at = path, func, path.read_bytes(), 0

    def read(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.at + size > len(self.data):
            fail(self.func, "a complete COLMAP binary file", f"'{self.path}' truncated at byte {len(self.data)}")
        self.at += size
        return struct.unpack_from("<" + fmt, self.data, self.at - size)

    def name(self) -> str:
        start, self.at = self.at, self.data.find(b"\x00", self.at) + 1
        if not self.at:
            fail(self.func, "a complete COLMAP binary file", f"'{self.path}' truncated in an image name")
        return self.data[start:self.at - 1].decode("utf-8", "replace")


def _lines(path: Path, func: str) -> list:
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        fail(func, "a readable text file", f"'{path}': {type(exc).__name__}: {exc}".splitlines()[0])


def _intrinsics(model: str, params, where: str, func: str) -> dict:
    """transforms.json intrinsics of a camera; refuse models other than :data:`COLMAP_MODELS`."""
    keys = COLMAP_MODELS.get(model)
    if keys is None:
        fail(func, f"a camera model {', '.join(COLMAP_MODELS)} for {where}", repr(model))
    if len(params) != len(keys) or not np.isfinite(params).all():
        fail(func, f"{len(keys)} finite parameters ({', '.join(keys)}) of {model} for {where}",
             [float(p) for p in params])
    out = dict(zip(keys, map(float, params)))
    if "f" in out:
        out["fl_x"] = out["fl_y"] = out.pop("f")
    return {"camera_model": model, **out}


def _cameras(path: Path, func: str) -> dict:
    """``{camera id: intrinsics with w, h}`` of ``cameras.bin`` or ``cameras.txt``."""
    cameras = {}
    if path.suffix == ".bin":
        f = _Binary(path, func)
        for _ in range(f.read("Q")[0]):
            cam_id, model_id, w, h = f.read("iiQQ")
            if not 0 <= model_id < len(_MODEL_IDS):
                fail(func, f"a COLMAP camera model id 0 ... 10 for camera {cam_id} in '{path}'", model_id)
            model = _MODEL_IDS[model_id]                # the parameters of a model read, none of the others
            params = f.read("d" * len(COLMAP_MODELS.get(model, ())))
            cameras[cam_id] = {**_intrinsics(model, params, f"camera {cam_id} in '{path}'", func), "w": w, "h": h}
        return cameras
    for n, line in enumerate(_lines(path, func), 1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        where = f"line {n} of '{path}'"
        try:
            cam_id, model, w, h = int(fields[0]), fields[1], int(fields[2]), int(fields[3])
            params = np.array(fields[4:], dtype=np.float64)
        except (ValueError, IndexError):
            fail(func, f"CAMERA_ID MODEL WIDTH HEIGHT PARAMS... on {where}", repr(line[:80]))
        cameras[cam_id] = {**_intrinsics(model, params, where, func), "w": w, "h": h}
    return cameras


def _rotation(q: np.ndarray, where: str, func: str) -> np.ndarray:
    """The rotation matrix of a quaternion ``(w, x, y, z)``, normalised here."""
    norm = np.linalg.norm(q)
    if not (np.isfinite(q).all() and norm > 0):
        fail(func, f"a non-zero finite quaternion for {where}", q.tolist())
    w, x, y, z = q / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _images(path: Path, func: str) -> list:
    """``[(name, qvec wxyz, tvec, camera id, where)]`` of ``images.bin`` or ``images.txt``."""
    images = []
    if path.suffix == ".bin":
        f = _Binary(path, func)
        for _ in range(f.read("Q")[0]):
            image_id, *qt, cam_id = f.read("idddddddi")
            name = f.name()
            f.read("ddq" * f.read("Q")[0])             # its 2-D points
            images.append((name, np.array(qt[:4]), np.array(qt[4:]), cam_id, f"image {image_id} in '{path}'"))
        return images
    lines = iter(enumerate(_lines(path, func), 1))
    for n, line in lines:
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields, where = line.split(maxsplit=9), f"line {n} of '{path}'"
        try:
            qt, cam_id, name = np.array(fields[1:8], dtype=np.float64), int(fields[8]), fields[9].strip()
        except (ValueError, IndexError):
            fail(func, f"IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME on {where}", repr(line[:80]))
        images.append((name, qt[:4], qt[4:], cam_id, where))
        next(lines, None)                               # its 2-D points: a line of its own, maybe empty
    return images


def read_colmap_model(directory, func: str = "read_colmap_model") -> tuple[dict, list]:
    """Read the cameras and registered images of a COLMAP sparse model.

    Parameters
    ----------
    directory : str or os.PathLike
        The model directory (``sparse/0``), with ``cameras.bin`` and
        ``images.bin`` or, when it has not both, ``cameras.txt`` and ``images.txt``.
    func : str, optional
        The public function reading it, for messages (``"load_meta"``).

    Returns
    -------
    cameras : dict
        ``{camera id: {"camera_model", "fl_x", "fl_y", "cx", "cy", ..., "w", "h"}}``:
        ``SIMPLE_PINHOLE`` (f, cx, cy) and ``SIMPLE_RADIAL`` / ``RADIAL`` (f,
        cx, cy, k1[, k2]) give ``fl_x = fl_y = f``; ``PINHOLE`` (fx, fy, cx, cy);
        ``OPENCV`` (fx, fy, cx, cy, k1, k2, p1, p2).
    images : list of ColmapImage
        Sorted by name; each one's camera is in ``cameras``.

    Raises
    ------
    ValueError
        No model; a truncated binary file or a malformed text line (the message
        names the file and line, or the camera or image id); a camera model
        other than those above; a zero or non-finite quaternion; a non-finite
        translation; an image whose camera is not in the model; no images.
    """
    directory = Path(directory)
    ext = colmap_model_kind(directory)
    if ext is None:
        fail(func, "a COLMAP model (cameras + images, .bin or .txt)", f"none in '{directory}'")
    cameras = _cameras(directory / f"cameras{ext}", func)
    images = []
    for name, q, t, cam_id, where in sorted(_images(directory / f"images{ext}", func), key=lambda item: item[0]):
        if cam_id not in cameras:
            fail(func, f"a camera of '{directory / ('cameras' + ext)}' for {where}", f"camera id {cam_id}")
        if not np.isfinite(t).all():
            fail(func, f"a finite translation for {where}", t.tolist())
        images.append(ColmapImage(name, _rotation(q, where, func), t, int(cam_id), where))
    if not images:
        fail(func, f"at least one image in '{directory / ('images' + ext)}'", "none")
    return cameras, images
