"""Small Mitsuba scenes around one shape: cameras framing its bounding box, lights, rendering.

Nothing here reads or writes files (see :mod:`mi_loop.io`) and nothing sets a
Mitsuba variant (see :func:`mi_loop.set_variant`), which must be done first.
"""
from __future__ import annotations

import numpy as np

__all__ = ["PLASTIC", "look_at_bbox", "render_limit_surface", "render_view",
           "scene_dict", "sensor_dict", "to_srgb"]

#: Default material of rendered limit surfaces: a blue rough plastic.
PLASTIC = {"type": "roughplastic", "alpha": 0.15,
           "diffuse_reflectance": {"type": "rgb", "value": [0.18, 0.38, 0.72]}}


def _direction(azimuth: float, elevation: float) -> np.ndarray:
    """Unit vector at ``azimuth`` (about +y, from +z) and ``elevation`` (degrees); y is up."""
    a, e = np.radians(azimuth), np.radians(elevation)
    return np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])


def look_at_bbox(bbox_min, bbox_max, azimuth: float = 35.0, elevation: float = 25.0,
                 fov: float = 35.0, margin: float = 1.1):
    """Return a camera-to-world transform that frames a bounding box.

    Parameters
    ----------
    bbox_min, bbox_max : (3,) float array-like
        Corners of the box to frame.
    azimuth, elevation : float, optional
        Viewing direction in degrees: azimuth about the +y (up) axis measured
        from +z, elevation above the xz plane.
    fov : float, optional
        Horizontal field of view in degrees of the camera that will use it.
    margin : float, optional
        Distance factor; 1 makes the bounding sphere touch the image border.

    Returns
    -------
    mi.ScalarTransform4f
        Look-at transform from the camera position towards the box centre.
    """
    import mitsuba as mi

    lo, hi = np.asarray(bbox_min, dtype=np.float64), np.asarray(bbox_max, dtype=np.float64)
    centre, radius = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    distance = look_at_distance(radius, fov, margin)
    origin = centre + distance * _direction(azimuth, elevation)
    return mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=centre.tolist(), up=[0, 1, 0])


def look_at_distance(radius: float, fov: float, margin: float = 1.1) -> float:
    """Camera distance at which a sphere of ``radius`` fills ``margin`` times the field of view.

    >>> round(look_at_distance(1.0, 35.0), 3)
    3.658
    """
    return float(margin * radius / np.sin(np.radians(fov) / 2))


def sensor_dict(bbox_min, bbox_max, *, azimuth: float = 35.0, elevation: float = 25.0,
                resolution: int = 256, fov: float = 35.0, sample_border: bool = False) -> dict:
    """Return a perspective sensor dictionary framing a bounding box.

    Parameters
    ----------
    bbox_min, bbox_max : (3,) float array-like
        Box to frame.
    azimuth, elevation, fov : float, optional
        See :func:`look_at_bbox`.
    resolution : int, optional
        Width and height of the square film in pixels.
    sample_border : bool, optional
        Film ``sample_border``; set it when differentiating shapes that may
        move across the image border.

    Returns
    -------
    dict
        A ``perspective`` sensor with a ``hdrfilm`` (RGB) and a box filter.
    """
    return {
        "type": "perspective",
        "fov": fov,
        "to_world": look_at_bbox(bbox_min, bbox_max, azimuth, elevation, fov),
        "film": {"type": "hdrfilm", "width": int(resolution), "height": int(resolution),
                 "pixel_format": "rgb", "rfilter": {"type": "box"}, "sample_border": sample_border},
    }


def scene_dict(shape, *, views=((35.0, 25.0),), resolution: int = 256, fov: float = 35.0,
               integrator: dict | None = None, sample_border: bool = False, bbox=None) -> dict:
    """Return a scene dictionary: the shape, one sensor per view, environment and area light.

    Parameters
    ----------
    shape : mi.Shape
        The loaded shape (e.g. from :func:`mi_loop.render.plugin.create`).
    views : sequence of (azimuth, elevation) in degrees, optional
        One sensor per entry, in order (``sensor=i`` of :func:`render_view`).
    resolution, fov, sample_border :
        See :func:`sensor_dict`.
    integrator : dict, optional
        Integrator dictionary (default: ``path`` with ``max_depth`` 4). Use
        ``{'type': 'direct_projective'}`` to differentiate silhouettes.
    bbox : ((3,), (3,)) float array-like, optional
        Box that places the cameras and the light (default: the shape's
        bounding box). Fix it to keep the same views while the shape changes.

    Returns
    -------
    dict
        Pass it to ``mi.load_dict``.
    """
    if bbox is None:
        bbox = (shape.bbox().min, shape.bbox().max)
    lo, hi = (np.array(corner, dtype=np.float64).reshape(3) for corner in bbox)
    centre, radius = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    import mitsuba as mi

    # The key light sits high (60, 70 degrees) and beyond the cameras: a panel
    # between a camera and the subject would hide the subject from views near
    # its direction. Its size grows with its distance, so the solid angle it
    # subtends from the subject (hence the irradiance) stays that of a
    # 1.2 r panel at 3 r.
    reach = 1.25 * look_at_distance(radius, fov) / radius
    light_at = centre + reach * radius * _direction(60.0, 70.0)
    scene = {
        "type": "scene",
        "integrator": integrator if integrator is not None else {"type": "path", "max_depth": 4},
        "shape": shape,
        "environment": {"type": "constant", "radiance": {"type": "rgb", "value": 0.25}},
        "key_light": {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f().look_at(origin=light_at.tolist(), target=centre.tolist(),
                                                       up=[0, 1, 0]).scale([0.2 * reach * radius] * 3),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 6.0}},
        },
    }
    for i, (azimuth, elevation) in enumerate(views):
        scene[f"sensor_{i:03d}"] = sensor_dict(lo, hi, azimuth=azimuth, elevation=elevation,
                                               resolution=resolution, fov=fov, sample_border=sample_border)
    return scene


def render_view(scene, *, spp: int, seed: int = 0, sensor: int = 0, params=None):
    """Render one sensor of a scene (differentiably when ``params`` carry gradients).

    Parameters
    ----------
    scene : mi.Scene
        Scene from ``mi.load_dict(scene_dict(...))``.
    spp : int
        Samples per pixel.
    seed : int, optional
        Sampler seed; fix it for reproducible images and finite differences.
    sensor : int, optional
        Index into ``scene.sensors()``. Views are rendered one at a time: the
        ``batch`` sensor fails with projective integrators.
    params : mi.SceneParameters, optional
        Parameters to differentiate with respect to.

    Returns
    -------
    mi.TensorXf, shape (h, w, 3)
        Linear RGB radiance (Dr.Jit, with gradients if ``params`` have them).
    """
    import mitsuba as mi

    return mi.render(scene, params, spp=spp, seed=seed, sensor=int(sensor))


def to_srgb(image) -> np.ndarray:
    """Tone-map linear RGB to display sRGB in [0, 1] (clip, then the sRGB curve).

    Parameters
    ----------
    image : (h, w, c) float array-like or mi.TensorXf
        Linear radiance.

    Returns
    -------
    (h, w, c) float32 NumPy array
        Gamma-encoded values in [0, 1], ready for :func:`mi_loop.io.write_png`.
    """
    from mi_loop.io.srgb import linear_to_srgb

    return linear_to_srgb(np.asarray(image, dtype=np.float32))


def render_limit_surface(V, F, *, level: int = 3, creases=None, resolution: int = 256,
                         spp: int = 64, seed: int = 0, azimuth: float = 35.0, elevation: float = 25.0,
                         corners=None, boundary: str = "edge_and_corner", crease_method: str = "uniform"):
    """Render the Loop limit surface of a control mesh with the default lights and plastic.

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Control points.
    F : (m, 3) int NumPy array
        Control triangles.
    level : int, optional
        Tessellation level of the ``loop_subdiv`` shape.
    creases : None, (c, 2) int array or (E, sharpness), optional
        Sharp edges.
    resolution, spp, seed, azimuth, elevation :
        Image size, samples per pixel, sampler seed and view direction.
    corners, boundary, crease_method : optional
        The rest of the crease model, as in :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    image : (resolution, resolution, 3) float32 NumPy array
        Display sRGB in [0, 1].
    shape : mi.Mesh
        The rendered ``loop_subdiv`` shape (its buffers hold the limit surface).
    """
    import mitsuba as mi

    from mi_loop.render.plugin import create

    shape = create(V, F, level=level, creases=creases, bsdf=mi.load_dict(PLASTIC), corners=corners,
                   boundary=boundary, crease_method=crease_method)
    scene = mi.load_dict(scene_dict(shape, views=[(azimuth, elevation)], resolution=resolution))
    image = render_view(scene, spp=spp, seed=seed)
    return to_srgb(image), shape
