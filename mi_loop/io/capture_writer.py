"""Calibrated captures written as a ``transforms.json`` that instant-ngp and nerfstudio read (:func:`write_capture`).

Its ``file_path`` keeps the ``.png``, which the original NeRF Blender loader
would add a second time; :func:`mi_loop.io.capture.read_capture` reads it back.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.files import ensure_writable_dir, first_missing_ancestor, remove_if_empty, staged_outputs, write_text
from mi_loop.io.srgb import linear_to_srgb
from mi_loop.io.views import View

__all__ = ["write_capture"]


def _frame_entry(view: View, file_path: str) -> dict:
    cam = view.camera
    return {"file_path": file_path, "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy,
            "w": cam.width, "h": cam.height, "transform_matrix": cam.c2w.tolist()}


def write_capture(directory, views, *, name: str = "transforms.json") -> Path:
    """Write views as ``directory/images/NNN.png`` and a ``transforms.json``, atomically.

    Images are 8-bit RGBA PNGs: sRGB-encoded colours, alpha = mask (a view's
    ``valid`` is not written: its unseen pixels go out as they are held, rgb
    and mask 0, and read back as background). Every frame
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
