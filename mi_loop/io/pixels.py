"""Image files decoded to pixel arrays, JPEGs reduced as they are decoded (the photos of :mod:`mi_loop.io.capture`).

- :func:`image_size`: the size from the file's header (EXR: decoded whole);
- :func:`read_pixels`: the pixels as stored, 8-bit PNG / JPEG by Pillow as
  ``uint8`` (a JPEG reduced by 2, 4 or 8 at decode time on request: libjpeg's
  scaled inverse DCT, each 8 x 8 block giving 4 x 4, 2 x 2 or 1 x 1 pixels),
  16-bit PNG (Pillow reduces 16-bit colour to 8 bits) and EXR by
  ``mitsuba.Bitmap`` (imported when needed; it needs no variant) as ``float32``.

A reduction by ``r`` maps corner-convention pixel coordinates ``x -> x / r``
exactly when ``r`` divides the image's width and height (pixel ``i`` of the
reduced image covers ``[r i, r (i + 1)]``); :func:`read_pixels` reduces only then.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_loop.errors import fail

__all__ = ["Pixels", "image_size", "read_pixels"]

#: Reductions a JPEG decoder offers, largest first.
REDUCTIONS = (8, 4, 2, 1)


def _png_bit_depth(path: Path) -> int | None:
    with open(path, "rb") as f:
        head = f.read(26)
    return head[24] if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR" else None


def _by_mitsuba(path: Path) -> bool:
    return path.suffix.lower() == ".exr" or _png_bit_depth(path) == 16


@dataclass(frozen=True)
class Pixels:
    """The pixels of an image file.

    Attributes
    ----------
    data : (h, w, c) uint8 or float32 NumPy array
        ``c`` = 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA (any count for an odd EXR);
        ``uint8`` for 8-bit PNG and JPEG, ``float32`` in [0, 1] for 16-bit PNG,
        as stored for EXR.
    reduction : int
        The file's size over ``data``'s (1, 2, 4 or 8).
    srgb : bool
        Colours sRGB-encoded (all but EXR).
    odd_format : str or None
        Mitsuba's name of a pixel format other than Y, YA, RGB, RGBA.
    """

    data: np.ndarray
    reduction: int
    srgb: bool
    odd_format: str | None = None


def image_size(path) -> tuple[int, int]:
    """Return ``(width, height)`` of an image file from its header (an EXR is decoded whole).

    Parameters
    ----------
    path : str or os.PathLike
        A PNG, JPEG or EXR file.

    Returns
    -------
    (int, int)

    Raises
    ------
    OSError, RuntimeError, SyntaxError, ValueError
        An unreadable file (Pillow's and Mitsuba's exceptions, as they raise them).
    """
    path = Path(path)
    if path.suffix.lower() == ".exr":
        import mitsuba as mi

        return tuple(int(n) for n in mi.Bitmap(str(path)).size())
    from PIL import Image

    with Image.open(path) as image:
        return image.size


def _reduction(size: tuple[int, int], at_most: int) -> int:
    """The largest of :data:`REDUCTIONS` up to ``at_most`` that divides both sides."""
    return next(r for r in REDUCTIONS if r <= at_most and size[0] % r == 0 and size[1] % r == 0)


def read_pixels(path, reduction: int = 1) -> Pixels:
    """Decode an image file, a JPEG reduced at decode time by up to ``reduction``.

    Parameters
    ----------
    path : str or os.PathLike
        A PNG (8 or 16 bits), JPEG or EXR file.
    reduction : int, optional
        Largest size reduction wanted, >= 1. A JPEG is decoded reduced by the
        largest of 8, 4, 2 that is at most ``reduction`` and divides its width
        and height; other files are decoded at full size.

    Returns
    -------
    Pixels
        Its ``reduction`` says what was done.

    Raises
    ------
    OSError, RuntimeError, SyntaxError, ValueError
        An unreadable file (Pillow's and Mitsuba's exceptions, as they raise them);
        ``ValueError`` for a reduction that is not an integer >= 1.
    """
    if isinstance(reduction, bool) or not isinstance(reduction, (int, np.integer)) or reduction < 1:
        fail("read_pixels", "an integer reduction >= 1", reduction)
    path = Path(path)
    if _by_mitsuba(path):
        import mitsuba as mi  # Bitmap is a core class: no variant needed

        bitmap = mi.Bitmap(str(path))
        channels = (mi.Bitmap.PixelFormat.Y, mi.Bitmap.PixelFormat.YA, mi.Bitmap.PixelFormat.RGB,
                    mi.Bitmap.PixelFormat.RGBA)
        data = np.array(bitmap)
        scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(data.dtype, 1.0)
        data = (data.astype(np.float32) / np.float32(scale)).reshape(*data.shape[:2], -1)
        odd = None if bitmap.pixel_format() in channels else str(bitmap.pixel_format())
        return Pixels(data, 1, path.suffix.lower() != ".exr", odd)
    from PIL import Image

    with Image.open(path) as image:
        full = image.size
        if image.format == "JPEG" and reduction >= 2:
            r = _reduction(full, reduction)
            if r > 1:
                image.draft(None, (full[0] // r, full[1] // r))
        image.load()
        alpha = any(b in ("A", "a") for b in image.getbands()) or "transparency" in image.info
        if image.mode not in ("L", "LA", "RGB", "RGBA"):
            image = image.convert("RGBA" if alpha else "RGB")
        data = np.asarray(image, dtype=np.uint8).reshape(image.height, image.width, -1)
    r = full[0] // data.shape[1]
    if data.shape[:2] != (full[1] // r, full[0] // r):
        raise ValueError(f"a JPEG decoded to {data.shape[1]} x {data.shape[0]} from {full[0]} x {full[1]}")
    return Pixels(data, r, True)
