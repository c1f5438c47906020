"""Optical flow between a camera's photos of consecutive frames: correspondences that pin material points.

Geometry says where the surface is, not which material point lies where: a
texture sliding over a surface that keeps its shape costs the distance terms
nothing. The photos see the slide. For each camera whose photos of frames
``t-1`` and ``t`` are given (the same camera: same name and calibration),
:func:`flow_correspondences`

1. computes the dense optical flow from the photo at ``t-1`` to the one at
   ``t`` and back (OpenCV's DIS, on the 8-bit sRGB grey images), and keeps the
   pixels whose forward and backward flows agree within ``consistency`` pixels
   and that are foreground in both masks;
2. projects the limit samples of the previous frame's fit into the camera and
   keeps those it sees (facing it, and in front in a z-buffer of the previous
   limit surface);
3. moves each kept sample's pixel by the flow there: where the same material
   point shows at frame ``t``.

:class:`~mi_loop.fitting.terms.Flow` then pulls each sample's projection at
frame ``t`` onto its target pixel; :func:`flow_rays` turns the targets into camera
rays, which the coarse stage of a frame (:func:`mi_loop.fitting.track.track`) holds
each sample on. No file I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Correspondences", "flow_correspondences", "flow_rays", "optical_flow", "sample_rays"]


@dataclass(frozen=True)
class Correspondences:
    """Samples of the limit surface and where each must project in one camera at frame ``t``.

    Attributes
    ----------
    sample : (k,) int64 NumPy array
        Limit sample (row of the limit operator) of each correspondence.
    target : (k, 2) float64 NumPy array
        Its target pixel (x right, y down, :func:`~mi_loop.render.cameras.project`'s convention).
    cameras : list of mi_loop.io.capture.Camera
        The cameras.
    camera : (k,) int64 NumPy array
        The camera of each correspondence (index into ``cameras``).
    """

    sample: np.ndarray
    target: np.ndarray
    cameras: list
    camera: np.ndarray


def _grey(rgb) -> np.ndarray:
    from mi_loop.io.srgb import linear_to_srgb

    g = linear_to_srgb(np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0)).mean(2)
    return np.clip(np.round(255.0 * g), 0, 255).astype(np.uint8)


def optical_flow(rgb0, rgb1) -> np.ndarray:
    """Dense flow from one linear RGB image to another (OpenCV DIS, medium preset refined to full resolution).

    Parameters
    ----------
    rgb0, rgb1 : (h, w, 3) float NumPy arrays
        Linear RGB in [0, 1] (as :class:`~mi_loop.io.views.View` holds them).

    Returns
    -------
    (h, w, 2) float32 NumPy array
        ``flow[y, x]``: where pixel ``(x, y)`` of ``rgb0`` moved in ``rgb1``.
    """
    import cv2

    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    dis.setFinestScale(0)             # down to full resolution: a subject of a few thousand pixels
    return dis.calc(_grey(rgb0), _grey(rgb1), None)


def _bilinear(img, xy) -> np.ndarray:
    h, w = img.shape[:2]
    x = np.clip(xy[:, 0] - 0.5, 0, w - 1.001)
    y = np.clip(xy[:, 1] - 0.5, 0, h - 1.001)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    a, b = img[y0, x0], img[y0, x0 + 1]
    c, d = img[y0 + 1, x0], img[y0 + 1, x0 + 1]
    if img.ndim == 2:
        a, b, c, d = (v[:, None] for v in (a, b, c, d))
    out = (1 - fy) * ((1 - fx) * a + fx * b) + fy * ((1 - fx) * c + fx * d)
    return out if img.ndim == 3 else out[:, 0]


def _in_front(camera, Q, surface, tolerance: float) -> np.ndarray:
    """Which points ``Q`` (world) are not hidden by the points ``surface`` (a dense tessellation) in ``camera``."""
    from mi_loop.render.cameras import project

    w2c = np.linalg.inv(camera.c2w)
    cell = 4.0                                               # pixels per z-buffer cell: the tessellation is sparse
    pq, ps = project(camera, Q), project(camera, surface)
    dq = -(Q @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]
    ds = -(surface @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]
    ok_s = np.isfinite(ps).all(1)
    W = int(np.ceil(camera.width / cell)) + 1
    key_s = (ps[ok_s, 1] // cell).astype(np.int64) * W + (ps[ok_s, 0] // cell).astype(np.int64)
    zbuf = np.full(W * (int(np.ceil(camera.height / cell)) + 1), np.inf)
    valid = (key_s >= 0) & (key_s < len(zbuf))
    np.minimum.at(zbuf, key_s[valid], ds[ok_s][valid])
    ok_q = np.isfinite(pq).all(1)
    key_q = np.where(ok_q, (np.nan_to_num(pq[:, 1]) // cell).astype(np.int64) * W
                     + (np.nan_to_num(pq[:, 0]) // cell).astype(np.int64), -1)
    inside = ok_q & (key_q >= 0) & (key_q < len(zbuf))
    out = np.zeros(len(Q), dtype=bool)
    out[inside] = dq[inside] <= zbuf[key_q[inside]] + tolerance
    return out


def flow_correspondences(previous, current, Q, N, surface, *, consistency: float = 1.0,
                         margin: int = 2) -> Correspondences:
    """Correspondences of the limit samples from the flow between two frames' photos (module docstring).

    Parameters
    ----------
    previous, current : list of mi_loop.io.views.View
        The photos of frames ``t-1`` and ``t``; photo ``i`` of both from the same camera.
    Q, N : (k, 3) float NumPy arrays
        Limit samples of the previous frame's fit and their unit normals, in the photos' units.
    surface : (m, 3) float NumPy array
        A dense tessellation of the previous frame's limit surface (its vertices), same units: what hides what.
    consistency : float
        Largest disagreement of the forward and backward flows, in pixels.
    margin : int
        Pixels next to the masks' edges are left out (flow is unreliable at silhouettes).

    Returns
    -------
    Correspondences

    Raises
    ------
    ValueError
        Not as many photos at both frames, or another camera in a pair.
    """
    from scipy.ndimage import binary_erosion

    from mi_loop.errors import fail
    from mi_loop.render.cameras import project

    if len(previous) != len(current):
        fail("flow_correspondences", f"as many photos at both frames ({len(previous)})", f"{len(current)}")
    Q, N, surface = (np.asarray(a, dtype=np.float64) for a in (Q, N, surface))
    diag = float(np.linalg.norm(np.ptp(surface, axis=0)))
    samples, targets, cams = [], [], []
    for i, (a, b) in enumerate(zip(previous, current)):
        if not (np.allclose(a.camera.c2w, b.camera.c2w) and a.camera.width == b.camera.width
                and a.camera.height == b.camera.height and np.isclose(a.camera.fx, b.camera.fx)):
            fail("flow_correspondences", f"the same camera for photo {i} at both frames", f"'{a.name}' and '{b.name}'")
        cam = a.camera
        facing = np.einsum("kd,kd->k", N, cam.c2w[:3, 3] - Q) > 0
        seen = np.flatnonzero(facing & _in_front(cam, Q, surface, 0.01 * diag))
        if len(seen) == 0:
            continue
        p = project(cam, Q[seen])
        fw, bw = optical_flow(a.rgb, b.rgb), optical_flow(b.rgb, a.rgb)
        fore = binary_erosion(a.mask >= 0.5, iterations=margin) & binary_erosion(b.mask >= 0.5, iterations=margin)
        u = _bilinear(fw, p)
        q = p + u
        back = _bilinear(bw, q)
        inside = ((q[:, 0] >= 0) & (q[:, 0] < cam.width) & (q[:, 1] >= 0) & (q[:, 1] < cam.height)
                  & (p[:, 0] >= 0) & (p[:, 0] < cam.width) & (p[:, 1] >= 0) & (p[:, 1] < cam.height))
        px = np.clip(p.astype(np.int64), 0, [cam.width - 1, cam.height - 1])
        qx = np.clip(np.nan_to_num(q).astype(np.int64), 0, [cam.width - 1, cam.height - 1])
        keep = (inside & fore[px[:, 1], px[:, 0]] & fore[qx[:, 1], qx[:, 0]]
                & (np.linalg.norm(u + back, axis=1) <= consistency))
        samples.append(seen[keep])
        targets.append(q[keep])
        cams.append(np.full(int(keep.sum()), i))
    cameras = [v.camera for v in previous]
    if not samples:
        return Correspondences(np.zeros(0, np.int64), np.zeros((0, 2)), cameras, np.zeros(0, np.int64))
    return Correspondences(np.concatenate(samples).astype(np.int64), np.concatenate(targets),
                           cameras, np.concatenate(cams).astype(np.int64))


def flow_rays(corr: Correspondences):
    """The camera rays through the correspondences' target pixels: where each sample must lie at frame ``t``.

    Parameters
    ----------
    corr : Correspondences

    Returns
    -------
    sample : (k,) int64 NumPy array
        ``corr.sample``.
    origin, direction : (k, 3) float64 NumPy arrays
        Each ray's camera centre and unit direction (world), through the target pixel by
        :func:`~mi_loop.render.cameras.project`'s pinhole model: ``project(origin + s direction)``
        is the target for every ``s > 0``.

    Examples
    --------
    >>> from mi_loop.io.views import Camera
    >>> cam = Camera(np.eye(4), 100.0, 50.0, 32.0, 24.0, 64, 48)
    >>> c = Correspondences(np.array([3]), np.array([[42.0, 19.0]]), [cam], np.array([0]))
    >>> s, o, d = flow_rays(c)
    >>> s.tolist(), o.tolist(), np.round(d / -d[0, 2], 6).tolist()
    ([3], [[0.0, 0.0, 0.0]], [[0.1, 0.1, -1.0]])
    """
    origin = np.zeros((len(corr.sample), 3))
    direction = np.zeros((len(corr.sample), 3))
    for i, cam in enumerate(corr.cameras):
        at = corr.camera == i
        if not at.any():
            continue
        xy = corr.target[at]
        local = np.stack([(xy[:, 0] - cam.cx) / cam.fx, -(xy[:, 1] - cam.cy) / cam.fy, -np.ones(len(xy))], axis=1)
        direction[at] = local @ np.asarray(cam.c2w)[:3, :3].T
        origin[at] = np.asarray(cam.c2w)[:3, 3]
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-300)
    return np.asarray(corr.sample, dtype=np.int64), origin, direction


def sample_rays(previous, current, x, F, matrices, to_world=(1.0, (0.0, 0.0, 0.0))):
    """The rays each seen limit sample of a fit must lie on at the next frame, in the fit's units.

    :func:`flow_correspondences` of the samples of ``x``, seen in the photos ``previous``
    (frame ``t-1``) and carried by the flow to ``current`` (frame ``t``), as :func:`flow_rays`
    mapped back from the photos' world by ``to_world``: what
    :func:`mi_loop.fitting.track.track` takes as ``rays``.

    Parameters
    ----------
    previous, current : list of mi_loop.io.views.View
        The photos of frames ``t-1`` and ``t``; photo ``i`` of both from the same camera.
    x : (n, 3) float NumPy array
        The control points fitted to frame ``t-1``, in the fit's units.
    F : (m, 3) int NumPy array
        Control faces.
    matrices : (P, Du, Dv) scipy.sparse matrices
        ``(k, n)`` limit positions and derivatives of the samples (:func:`mi_loop.limit_matrix`).
    to_world : (float, (3,) float array)
        ``(scale, centre)``: a point ``p`` of the fit is ``p * scale + centre`` in the photos' world.

    Returns
    -------
    sample : (r,) int64 NumPy array
        Rows of ``matrices``.
    origin, direction : (r, 3) float64 NumPy arrays
        The rays' origins (fit units) and unit directions.
    """
    from mi_loop.fitting.track import limit_samples
    from mi_loop.subdiv.masks import limit_mesh

    scale, centre = float(to_world[0]), np.asarray(to_world[1], dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    Q, N = limit_samples(matrices, x)
    surface = limit_mesh(x * scale + centre, F, level=2)[0]
    sample, origin, direction = flow_rays(flow_correspondences(previous, current, Q * scale + centre, N, surface))
    return sample, (origin - centre) / scale, direction
