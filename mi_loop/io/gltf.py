"""glTF 2.0 files read directly: the GLB container or ``.gltf`` JSON, typed accessors, images, base colours.

:class:`GltfFile` parses the container once and reads accessors as NumPy
arrays (strided views honoured, normalised integers scaled to [0, 1] or
[-1, 1]); :func:`base_colors` evaluates a primitive's material base colour
per vertex, the texture filtered by :func:`sample_texture`. Posing and baking
animations is :mod:`mi_loop.io.animation`'s.
"""
from __future__ import annotations

import base64
import io as _bytes_io
import json
import struct
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.srgb import srgb_to_linear

__all__ = ["GltfFile", "base_colors", "sample_texture"]

_COMPONENTS = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_WRAPS = {10497: "repeat", 33071: "clamp", 33648: "mirror"}
#: Linear value of every 8-bit sRGB code.
_SRGB_LUT = srgb_to_linear(np.arange(256) / 255.0).astype(np.float64)


class GltfFile:
    """A parsed glTF 2.0 file: its JSON ``doc``, its buffers read on demand, typed accessors, images.

    Parameters
    ----------
    path : str or os.PathLike
        A binary ``.glb`` (recognised by its magic ``glTF``, whatever the
        suffix) or a JSON ``.gltf`` file, whose buffers and images may be
        ``data:`` URIs or files beside it.
    func : str
        Name of the calling public function, for messages.

    Attributes
    ----------
    path : pathlib.Path
    doc : dict
        The glTF JSON.

    Raises
    ------
    ValueError
        An unreadable file, or one that is neither GLB nor JSON with
        ``asset.version`` 2.x.
    """

    def __init__(self, path, func: str):
        self.path, self.func = Path(path), func
        try:
            data = self.path.read_bytes()
        except OSError as exc:
            fail(func, f"a readable file '{self.path}'", f"{type(exc).__name__}: {exc.strerror or exc}")
        what = f"a glTF 2.0 file (binary .glb or JSON .gltf) '{self.path}'"
        self.bin = None
        try:
            if data[:4] == b"glTF":
                doc, offset = None, 12
                while offset + 8 <= len(data):
                    size, kind = struct.unpack_from("<II", data, offset)
                    chunk = data[offset + 8:offset + 8 + size]
                    doc = json.loads(chunk) if kind == 0x4E4F534A and doc is None else doc
                    self.bin = chunk if kind == 0x004E4942 and self.bin is None else self.bin
                    offset += 8 + size
            else:
                doc = json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, ValueError, struct.error):
            doc = None
        asset = doc.get("asset") if isinstance(doc, dict) else None
        if not isinstance(asset, dict) or not str(asset.get("version", "")).startswith("2"):
            got = f"a file that starts with {data[:12]!r}" if doc is None else "JSON without asset.version 2.x"
            fail(func, what, got)
        self.doc, self._buffers = doc, {}

    def buffer(self, i: int) -> bytes:
        """The bytes of buffer ``i`` (the GLB's BIN chunk for a buffer without ``uri``)."""
        if i not in self._buffers:
            uri = self.doc["buffers"][i].get("uri")
            self._buffers[i] = self.bin if uri is None else self._uri(uri)
        return self._buffers[i]

    def _uri(self, uri: str) -> bytes:
        if uri.startswith("data:"):
            return base64.b64decode(uri.split(",", 1)[1])
        return (self.path.parent / unquote(uri)).read_bytes()

    def view(self, i: int) -> bytes:
        """The bytes of buffer view ``i``."""
        v = self.doc["bufferViews"][i]
        start = v.get("byteOffset", 0)
        return self.buffer(v["buffer"])[start:start + v["byteLength"]]

    def accessor(self, i: int, floats: bool = True) -> np.ndarray:
        """Read accessor ``i`` as a ``(count, width)`` array (``width`` 16 for a MAT4, column-major).

        With ``floats``, float64 (``normalized`` integers divided by their
        type's maximum, as glTF 2.0 section 3.11 says); else int64 as stored.
        Raises ``ValueError`` for a sparse accessor.
        """
        a = self.doc["accessors"][i]
        dtype, width, count = np.dtype(_COMPONENTS[a["componentType"]]), _WIDTHS[a["type"]], a["count"]
        if "sparse" in a:
            fail(self.func, f"accessors without sparse storage in '{self.path}'", f"sparse accessor {i}")
        if "bufferView" not in a:
            out = np.zeros((count, width), dtype)
        else:
            stride = self.doc["bufferViews"][a["bufferView"]].get("byteStride") or dtype.itemsize * width
            out = np.ndarray((count, width), dtype, buffer=self.view(a["bufferView"]),
                             offset=a.get("byteOffset", 0), strides=(stride, dtype.itemsize)).copy()
        if not floats:
            return out.astype(np.int64)
        if a.get("normalized") and dtype.kind in "iu":
            return np.maximum(out / np.iinfo(dtype).max, -1.0)
        return out.astype(np.float64)

    def image(self, i: int) -> np.ndarray:
        """Decode image ``i`` (PNG or JPEG, with Pillow) as ``(H, W, 3)`` uint8 sRGB codes, row 0 at the top."""
        from PIL import Image

        img = self.doc["images"][i]
        raw = self.view(img["bufferView"]) if "bufferView" in img else self._uri(img["uri"])
        with Image.open(_bytes_io.BytesIO(raw)) as im:
            return np.asarray(im.convert("RGB"), dtype=np.uint8)


def base_colors(gltf: GltfFile, prim: dict, n: int) -> np.ndarray | None:
    """Evaluate a primitive's base colour at its vertices, in linear RGB.

    Parameters
    ----------
    gltf : GltfFile
    prim : dict
        A mesh primitive of ``gltf.doc``.
    n : int
        Its number of vertices.

    Returns
    -------
    (n, 3) float64 numpy array or None
        ``baseColorFactor`` times ``COLOR_0`` times the ``baseColorTexture``
        at the vertex's texture coordinates (decoded from sRGB, then filtered
        bilinearly at the full resolution, as an sRGB texture is on a GPU);
        None when the primitive has none of the three.
    """
    attrs, doc = prim["attributes"], gltf.doc
    color0 = gltf.accessor(attrs["COLOR_0"])[:, :3] if "COLOR_0" in attrs else None
    pbr = doc["materials"][prim["material"]].get("pbrMetallicRoughness", {}) if "material" in prim else {}
    if "baseColorFactor" not in pbr and "baseColorTexture" not in pbr:
        return color0
    C = np.tile(np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), dtype=np.float64)[:3], (n, 1))
    if color0 is not None:
        C *= color0
    if "baseColorTexture" in pbr:
        info = pbr["baseColorTexture"]
        texture = doc["textures"][info["index"]]
        sampler = doc["samplers"][texture["sampler"]] if "sampler" in texture else {}
        wrap = (_WRAPS[sampler.get("wrapS", 10497)], _WRAPS[sampler.get("wrapT", 10497)])
        texels = _SRGB_LUT[gltf.image(texture["source"])]                # decoded, then filtered
        C *= sample_texture(texels, gltf.accessor(attrs[f"TEXCOORD_{info.get('texCoord', 0)}"]), wrap)
    return C


def sample_texture(texels, uv, wrap=("repeat", "repeat")) -> np.ndarray:
    """Sample an image at glTF texture coordinates with bilinear filtering.

    Parameters
    ----------
    texels : (H, W, C) float array-like
        The image, row 0 at the top (``v = 0``), in the space to interpolate in (linear).
    uv : (k, 2) float array-like
        Texture coordinates; texel ``(row r, column c)`` has its centre at
        ``((c + 0.5) / W, (r + 0.5) / H)``.
    wrap : pair of {'repeat', 'clamp', 'mirror'}, optional
        Wrapping along ``u`` and ``v`` (glTF ``wrapS``, ``wrapT``).

    Returns
    -------
    (k, C) float64 numpy array

    Raises
    ------
    ValueError
        Wrong shapes, an unknown wrap mode.

    Examples
    --------
    >>> sample_texture([[[0.0], [1.0]]], [[0.25, 0.5], [0.5, 0.5], [1.0, 0.5]], wrap=("clamp", "clamp")).ravel()
    array([0. , 0.5, 1. ])
    """
    texels, uv = np.asarray(texels, dtype=np.float64), np.asarray(uv, dtype=np.float64)
    if texels.ndim != 3 or 0 in texels.shape:
        fail("sample_texture", "texels of shape (H, W, C)", f"shape {texels.shape}")
    if uv.ndim != 2 or uv.shape[1] != 2:
        fail("sample_texture", "uv of shape (k, 2)", f"shape {uv.shape}")
    if len(wrap) != 2 or any(w not in _WRAPS.values() for w in wrap):
        fail("sample_texture", "wrap modes from ('repeat', 'clamp', 'mirror')", repr(tuple(wrap)))
    H, W = texels.shape[:2]
    x, y = uv[:, 0] * W - 0.5, uv[:, 1] * H - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    c0, c1 = _wrap(x0, W, wrap[0]), _wrap(x0 + 1, W, wrap[0])
    r0, r1 = _wrap(y0, H, wrap[1]), _wrap(y0 + 1, H, wrap[1])
    return ((1 - fy) * ((1 - fx) * texels[r0, c0] + fx * texels[r0, c1])
            + fy * ((1 - fx) * texels[r1, c0] + fx * texels[r1, c1]))


def _wrap(i, n: int, mode: str) -> np.ndarray:
    i = i.astype(np.int64)
    if mode == "clamp":
        return np.clip(i, 0, n - 1)
    if mode == "repeat":
        return np.mod(i, n)
    m = np.mod(i, 2 * n)
    return np.where(m < n, m, 2 * n - 1 - m)
