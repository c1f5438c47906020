"""Camera files of real captures read as a ``transforms.json``: IDR / NeuS / DTU, LLFF, COLMAP.

:func:`load_meta` turns each format into the dict a NeRF / nerfstudio
``transforms.json`` holds, in its conventions (:mod:`mi_loop.io.capture`):
``transform_matrix`` is camera-to-world with OpenGL axes (the camera looks down
-Z, +Y up, +X right); pixel coordinates run x right and y down from the top-left
corner of the image (pixel centres at half-integers). Each frame carries
``transform_matrix`` (4 x 4 list), ``file_path`` and, when there is a mask,
``mask_path`` (absolute paths), ``fl_x fl_y cx cy`` (floats), ``w h`` (ints),
``camera_model`` and the distortion coefficients the format has (COLMAP's
``k1 k2 p1 p2``). :func:`detect` says which format a directory holds:
``"idr"`` (``cameras_sphere.npz`` or ``cameras.npz``, ``image/``, ``mask/``),
``"llff"`` (``poses_bounds.npy``, ``images/``, optionally ``masks/``),
``"colmap"`` (a sparse model, ``images/`` beside it or up to two levels up,
``masks/`` beside that; the model files are parsed by :mod:`mi_loop.io.colmap`)
or ``"transforms"``.

Images are the ``.png``, ``.jpg`` and ``.jpeg`` files (any case) of a directory,
sorted by name. Every rejected input raises a one-line :class:`ValueError`
naming the file and the field.
"""
from __future__ import annotations

import json
import os
import re
import zipfile
from pathlib import Path

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.colmap import colmap_model_kind, read_colmap_model
from mi_loop.io.views import pose_problem

__all__ = ["FORMATS", "detect", "load_meta"]

#: The formats :func:`detect` recognises, in the order it looks for them.
FORMATS = ("transforms", "idr", "llff", "colmap")
_PHOTOS = (".png", ".jpg", ".jpeg")
#: OpenCV camera axes (x right, y down, z forward) -> OpenGL (x right, y up, z backward).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0])
#: Largest image shift, in pixels, of an IDR camera's skew that is dropped rather than refused.
_SKEW_PX = 0.01


def _locate(path, func: str) -> tuple[str, Path]:
    """The format at ``path`` and its camera file (the model directory for COLMAP)."""
    p = Path(path)
    if not p.exists():
        fail(func, "an existing capture directory or a file in one", f"no '{p}'")
    if p.is_file() and p.suffix.lower() == ".json":
        return "transforms", p
    d = p if p.is_dir() else p.parent
    for fmt, name in (("transforms", "transforms.json"), ("idr", "cameras_sphere.npz"), ("idr", "cameras.npz"),
                      ("llff", "poses_bounds.npy")):
        if (d / name).is_file():
            return fmt, d / name
    for model in (d, d / "sparse" / "0", d / "sparse"):
        if colmap_model_kind(model):
            return "colmap", model
    fail(func, "a capture: transforms.json, cameras_sphere.npz or cameras.npz (IDR), poses_bounds.npy (LLFF) "
         "or a COLMAP model (cameras + images .bin or .txt, in the directory, sparse/0/ or sparse/)",
         f"none of them in '{d}'")


def detect(path) -> str:
    """Say which camera format a capture directory holds.

    Parameters
    ----------
    path : str or os.PathLike
        The directory, or a file in it (a ``.json`` file is taken as a ``transforms.json``).

    Returns
    -------
    str
        One of :data:`FORMATS`, the first found of: ``transforms.json``
        (``"transforms"``); ``cameras_sphere.npz`` or ``cameras.npz``
        (``"idr"``); ``poses_bounds.npy`` (``"llff"``); a COLMAP model in the
        directory, ``sparse/0/`` or ``sparse/`` (``"colmap"``).

    Raises
    ------
    ValueError
        A path that does not exist, or none of these files.
    """
    return _locate(path, "detect")[0]


def _photos(directory: Path, what: str) -> list:
    """The image files of ``directory``, sorted by name; refuse a missing or empty directory."""
    if not directory.is_dir():
        fail("load_meta", f"{what} directory '{directory}'", "no such directory")
    files = sorted(p for p in directory.iterdir() if p.is_file() and p.suffix.lower() in _PHOTOS)
    if not files:
        fail("load_meta", f"{', '.join(_PHOTOS)} images in '{directory}'", "none")
    return files


def _masks_by_index(images: list, directory: Path, required: bool) -> list:
    """Masks paired with ``images`` by sorted order: the files of ``directory`` (or Nones)."""
    if not required and not directory.exists():
        return [None] * len(images)
    masks = _photos(directory, "a mask")
    if len(masks) != len(images):
        fail("load_meta", f"one mask per image ({len(images)} in '{images[0].parent}') in '{directory}'",
             len(masks))
    return masks


def _image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` from the image's header."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            return image.size
    except (OSError, SyntaxError, ValueError) as exc:
        fail("load_meta", "a readable image", f"'{path}': {type(exc).__name__}: {exc}".splitlines()[0])


def _load(path: Path):
    """The arrays (a dict) of an ``.npz`` file or the array of an ``.npy`` file, no pickles."""
    try:
        data = np.load(path, allow_pickle=False)
        if isinstance(data, np.lib.npyio.NpzFile):
            with data:
                data = {key: data[key] for key in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        data = f"'{path}': {type(exc).__name__}: {exc}".splitlines()[0]
    if isinstance(data, str) or isinstance(data, dict) != (path.suffix == ".npz"):
        fail("load_meta", f"a readable {path.suffix} file", data if isinstance(data, str) else f"'{path}'")
    return data


def _frame(R: np.ndarray, centre, image: Path, mask, camera_model: str = "PINHOLE", **intrinsics) -> dict:
    """A transforms.json frame: rotation ``R`` (columns: the camera's OpenGL axes) and ``centre``, the files,
    corner-convention intrinsics ``fl_x fl_y cx cy w h`` and distortion coefficients."""
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = R, centre
    frame = {"transform_matrix": c2w.tolist(), "file_path": os.path.abspath(image)}
    if mask is not None:
        frame["mask_path"] = os.path.abspath(mask)
    numbers = {k: int(v) if k in ("w", "h") else float(v) for k, v in intrinsics.items()}
    return {**frame, **numbers, "camera_model": camera_model}


# ------------------------------------------------------------------------------------------------ IDR / NeuS


def _decompose(P: np.ndarray, label: str):
    """``K`` (upper triangular, ``K[2, 2] = 1``, positive diagonal), the OpenGL camera-to-world rotation and
    the centre of a 3 x 4 OpenCV projection ``P = s K [R | t]`` (any scale ``s``, of either sign)."""
    M, p4 = P[:, :3], P[:, 3]
    if not np.linalg.cond(M) < 1e12:
        fail("load_meta", f"a projection matrix with an invertible 3 x 3 block for {label}", "a singular one")
    if np.linalg.det(M) < 0:
        M, p4 = -M, -p4
    flip = np.eye(3)[::-1]
    Q, U = np.linalg.qr((flip @ M).T)               # RQ decomposition M = K R through the QR of (flip M)^T
    K, R = flip @ U.T @ flip, flip @ Q.T
    signs = np.diag(np.sign(np.diag(K)))
    K, R = K @ signs, signs @ R
    return K / K[2, 2], R.T @ _CV_TO_GL, -np.linalg.solve(M, p4)


def _read_idr(npz: Path, masks) -> dict:
    """IDR / NeuS cameras: ``world_mat_i`` (and ``scale_mat_i``) of ``npz``, ``image/``, ``mask/``."""
    images = _photos(npz.parent / "image", "an IDR image/")
    mask_files = _masks_by_index(images, Path(masks) if masks else npz.parent / "mask", required=True)
    arrays = _load(npz)
    count = sum(1 for key in arrays if re.fullmatch(r"world_mat_\d+", key))
    if count != len(images):
        fail("load_meta", f"one world_mat_i per image of image/ ({len(images)}) in '{npz}'", count)
    frames = []
    for i, (image, mask) in enumerate(zip(images, mask_files)):
        P = arrays.get(f"world_mat_{i}")
        label = f"world_mat_{i} in '{npz}'"
        if P is None:
            fail("load_meta", f"{label} (keys world_mat_0 ... world_mat_{count - 1})", "no such key")
        if P.shape not in ((3, 4), (4, 4)) or not np.isfinite(P).all():
            fail("load_meta", f"a finite 3 x 4 or 4 x 4 matrix for {label}", f"{P.shape} {P.ravel()[:12].tolist()}")
        K, R, centre = _decompose(np.asarray(P[:3, :4], dtype=np.float64), label)
        w, h = _image_size(image)
        shift = abs(K[0, 1]) * max(K[1, 2] + 0.5, h - K[1, 2] - 0.5) / K[1, 1]
        if shift > _SKEW_PX:
            fail("load_meta", f"no skew in {label} (mi_loop's cameras have none; up to {_SKEW_PX} px is dropped)",
                 f"a skew of {K[0, 1]:.4g} moving pixels by {shift:.3g} px")
        frames.append(_frame(R, centre, image, mask, fl_x=K[0, 0], fl_y=K[1, 1], cx=K[0, 2] + 0.5,
                             cy=K[1, 2] + 0.5, w=w, h=h))
    meta = {"frames": frames}
    scale = arrays.get("scale_mat_0")
    if scale is not None:
        if scale.shape != (4, 4) or not np.isfinite(scale).all():
            fail("load_meta", f"a finite 4 x 4 matrix for scale_mat_0 in '{npz}'", f"shape {scale.shape}")
        meta["normalisation"] = np.asarray(scale, dtype=np.float64).tolist()
    return meta


# ------------------------------------------------------------------------------------------------------- LLFF


def _read_llff(path: Path, masks) -> dict:
    """LLFF cameras: ``poses_bounds.npy`` (N x 17), ``images/`` and optionally ``masks/``."""
    arr = _load(path)
    if arr.ndim != 2 or arr.shape[1] != 17 or not np.issubdtype(arr.dtype, np.number):
        fail("load_meta", f"an N x 17 array of numbers (3 x 5 pose and hwf, near, far per image) in '{path}'",
             f"shape {arr.shape} of {arr.dtype}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        fail("load_meta", f"finite numbers in '{path}'", f"{arr[~np.isfinite(arr)][0]} in row "
             f"{np.argwhere(~np.isfinite(arr))[0, 0]}")
    images = _photos(path.parent / "images", "an LLFF images/")
    if len(images) != len(arr):
        fail("load_meta", f"one row of '{path}' per image of '{images[0].parent}' ({len(images)})", len(arr))
    mask_files = _masks_by_index(images, Path(masks) if masks else path.parent / "masks", required=masks is not None)
    frames = []
    for i, (image, mask) in enumerate(zip(images, mask_files)):
        pose = arr[i, :15].reshape(3, 5)
        h, w, f = pose[:, 4]
        if not (h > 0 and w > 0 and f > 0):
            fail("load_meta", f"h, w, focal > 0 in row {i} of '{path}'", f"{h:g}, {w:g}, {f:g}")
        w_img, h_img = _image_size(image)
        if abs(w * h_img / h - w_img) > 1:
            fail("load_meta", f"an image of the aspect ratio of row {i} of '{path}' ({w:g} x {h:g})",
                 f"{w_img} x {h_img} in '{image}'")
        R = np.stack([pose[:, 1], -pose[:, 0], pose[:, 2]], axis=1)    # [down, right, back] -> [right, up, back]
        sx, sy = w_img / w, h_img / h
        frames.append(_frame(R, pose[:, 3], image, mask, fl_x=f * sx, fl_y=f * sy, cx=w_img / 2, cy=h_img / 2,
                             w=w_img, h=h_img))
    return {"frames": frames, "bounds": arr[:, 15:17].tolist()}


# ----------------------------------------------------------------------------------------------------- COLMAP


def _find_mask(directory: Path, name: str, image: Path) -> Path:
    tried = [directory / name, directory / (name + ".png"), (directory / name).with_suffix(".png")]
    found = next((p for p in tried if p.is_file()), None)
    if found is None:
        fail("load_meta", f"a mask for '{image}'", "none of " + ", ".join(f"'{p}'" for p in tried))
    return found


def _read_colmap(model: Path, masks) -> dict:
    """A COLMAP sparse model, its ``images/`` (here or up to two levels up) and ``masks/`` beside it."""
    cameras, images = read_colmap_model(model, "load_meta")
    image_dir = next((d / "images" for d in (model, model.parent, model.parent.parent) if (d / "images").is_dir()),
                     None)
    if image_dir is None:
        fail("load_meta", f"an images/ directory in '{model}' or up to two levels up", "none")
    mask_dir = Path(masks) if masks else image_dir.parent / "masks"
    if not mask_dir.is_dir():
        fail("load_meta", f"a mask directory '{mask_dir}' (or pass masks=)", "no such directory")
    frames = []
    for im in images:
        image = image_dir / im.name
        if not image.is_file():
            fail("load_meta", f"the image file of {im.where}", f"no '{image}'")
        frames.append(_frame(im.R.T @ _CV_TO_GL, -im.R.T @ im.t, image, _find_mask(mask_dir, im.name, image),
                             **cameras[im.camera_id]))
    return {"frames": frames}


# ------------------------------------------------------------------------------------------------- transforms


def _read_transforms(path: Path, masks) -> dict:
    """A ``transforms.json`` as stored, ``file_path`` / ``mask_path`` made absolute (suffixes not added)."""
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        fail("load_meta", "a readable JSON file", f"'{path}': {type(exc).__name__}: {exc}".splitlines()[0])
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not isinstance(frames, list) or not all(isinstance(f, dict) for f in frames):
        fail("load_meta", f"a JSON object with a list of objects 'frames' in '{path}'", repr(meta)[:80])
    for frame in frames:
        for key in ("file_path", "mask_path"):
            if isinstance(frame.get(key), str):
                frame[key] = os.path.abspath(path.parent / frame[key])
        if masks is not None and isinstance(frame.get("file_path"), str):
            image = Path(frame["file_path"])
            frame["mask_path"] = os.path.abspath(_find_mask(Path(masks), image.name, image))
    return meta


_READERS = {"transforms": _read_transforms, "idr": _read_idr, "llff": _read_llff, "colmap": _read_colmap}


def load_meta(path, *, masks=None) -> tuple[str, dict]:
    """Read the cameras of a capture in any of :data:`FORMATS` as a ``transforms.json`` dict.

    Parameters
    ----------
    path : str or os.PathLike
        The capture directory or a file in it (as :func:`detect`).
    masks : str or os.PathLike, optional
        The mask directory, in place of the format's own (``mask/`` for IDR,
        ``masks/`` for LLFF and COLMAP). IDR and LLFF pair masks with images by
        sorted order; COLMAP and transforms.json by name (the image's name, with
        ``.png`` added, or with its suffix replaced by ``.png``).

    Returns
    -------
    format : str
        One of :data:`FORMATS`.
    meta : dict
        ``{"frames": [...]}`` with a frame per image, in the module's conventions
        (see its docstring); IDR also gives ``"normalisation"`` (``scale_mat_0``,
        4 x 4 list: the unit sphere's map into the world frame of the cameras, a
        hint of where the object is), LLFF ``"bounds"`` (N x 2 list of near, far).
        Frames are in the sorted order of the image files (COLMAP: image names),
        a transforms.json's in its own order.

    Raises
    ------
    ValueError
        No format found; a missing or empty image or mask directory; counts of
        images, masks and cameras that differ; a malformed or truncated camera
        file; a COLMAP camera model other than ``SIMPLE_PINHOLE``, ``PINHOLE``,
        ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``; an IDR camera with skew.

    Notes
    -----
    - IDR: ``world_mat_i[:3, :4] = s K [R | t]`` maps the scan's world frame to
      pixels with pixel centres at integer coordinates (OpenCV's convention).
      It is split by an RQ decomposition (as IDR's ``load_K_Rt_from_P`` does with
      OpenCV), ``K`` normalised so ``K[2, 2] = 1``; ``cx``, ``cy`` are then
      shifted by +0.5 into the corner convention. ``camera_mat_i`` and the other
      ``scale_mat_i`` are not read: cameras stay in the world frame of the scan,
      not the unit sphere of ``scale_mat``.
    - LLFF: each row is a 3 x 5 matrix whose rotation columns point down, right
      and backward, then the centre and ``(h, w, focal)``; the axes become
      OpenGL's as LLFF's ``load_llff_data`` does. Images of another size than
      ``(w, h)`` (downsampled copies) scale the focal length per axis; the
      principal point is the image's centre.
    - COLMAP: images are world-to-camera quaternions ``(qw, qx, qy, qz)`` and
      translations in OpenCV axes; pixel centres are at half-integers already.
    """
    fmt, found = _locate(path, "load_meta")
    meta = _READERS[fmt](found, masks)
    if fmt != "transforms":
        for i, frame in enumerate(meta["frames"]):
            problem = pose_problem(frame["transform_matrix"])
            if problem:
                fail("load_meta", f"{problem[0]} for the camera of '{frame['file_path']}' (frame {i})", problem[1])
    return fmt, meta
