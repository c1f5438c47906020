"""Small Mitsuba scenes around one shape: cameras framing its bounding box, lights, rendering.

The cameras are :class:`mi_loop.io.Camera` objects (:func:`mi_loop.render.cameras.orbit_camera`,
:func:`~mi_loop.render.cameras.rig_cameras`) turned into sensors by the one
:func:`mi_loop.render.cameras.sensor_dict`; the lights are :func:`rig_emitters`.

Nothing here reads or writes files (see :mod:`mi_loop.io`) and nothing sets a
Mitsuba variant (see :func:`mi_loop.set_variant`), which must be done first.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail
from mi_loop.render.cameras import _box_sphere, _direction, look_at_distance, orbit_camera, sensor_dict

__all__ = ["PLASTIC", "RIG_MODES", "look_at_distance", "render_limit_surface", "render_view", "rig_emitters",
           "scene_dict", "to_srgb"]

#: Default material of rendered limit surfaces: a blue rough plastic.
PLASTIC = {"type": "roughplastic", "alpha": 0.15,
           "diffuse_reflectance": {"type": "rgb", "value": [0.18, 0.38, 0.72]}}
#: Image modes of a rig (:func:`rig_emitters`).
RIG_MODES = ("shading", "silhouette")
# Mitsuba's defaults for a perspective sensor given none: clip distances and sample count.
_NEAR, _FAR, _DEFAULT_SPP = 1e-2, 1e4, 4


def rig_emitters(bbox, mode: str = "shading", *, fov: float = 35.0) -> list:
    """Return the lights of a rig around a box: a grey environment, and a key light for shading.

    Parameters
    ----------
    bbox : ((3,), (3,)) float array-like
        Corners ``(lo, hi)`` of the box the cameras frame (the light is placed from it).
    mode : {'shading', 'silhouette'}, optional
        ``'shading'``: the environment and the key light; ``'silhouette'``: the
        environment alone (a black subject then shows as its silhouette, radiance
        0, against the environment's 0.25).
    fov : float, optional
        Field of view of the rig's cameras in degrees (the light sits beyond them).

    Returns
    -------
    list of dict
        Scene-dictionary entries: a ``constant`` environment of radiance 0.25,
        then (shading) a ``rectangle`` shape with an ``area`` emitter of radiance
        6; pass them as the ``emitters`` of :class:`mi_loop.render.images.ImageRenderer`.

    Raises
    ------
    ValueError
        An unknown ``mode``, a malformed or empty box.

    Notes
    -----
    The key light sits high (azimuth 60, elevation 70 degrees) and beyond the
    cameras: a panel between a camera and the subject would hide the subject
    from views near its direction. Its size grows with its distance, so the
    solid angle it subtends from the subject (hence the irradiance) stays that
    of a 1.2 r panel at 3 r (``r`` half the box diagonal). Needs a Mitsuba
    variant (its transform is a ``mi.ScalarTransform4f``).
    """
    if mode not in RIG_MODES:
        fail("rig_emitters", f"mode to be one of {RIG_MODES}", repr(mode))
    centre, radius = _box_sphere(bbox, "rig_emitters")
    environment = {"type": "constant", "radiance": {"type": "rgb", "value": 0.25}}
    if mode == "silhouette":
        return [environment]
    import mitsuba as mi

    reach = 1.25 * look_at_distance(radius, fov) / radius
    light_at = centre + reach * radius * _direction(60.0, 70.0)
    key_light = {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f().look_at(origin=light_at.tolist(), target=centre.tolist(),
                                                   up=[0, 1, 0]).scale([0.2 * reach * radius] * 3),
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 6.0}},
    }
    return [environment, key_light]


def _orbit_sensor(bbox, azimuth: float, elevation: float, *, resolution: int, fov: float = 35.0,
                  sample_border: bool = False) -> dict:
    """The sensor of :func:`~mi_loop.render.cameras.orbit_camera`, with Mitsuba's default clip distances
    and sample count (4, overridden by ``mi.render(spp=)``): the pictures of the sensors that
    :func:`scene_dict` built before it used :class:`~mi_loop.io.Camera` objects. ``sample_border``
    changes nothing with the box filter."""
    sensor = sensor_dict(orbit_camera(bbox, azimuth, elevation, fov=fov, resolution=resolution),
                         spp=_DEFAULT_SPP, near=_NEAR, far=_FAR)
    sensor["film"]["sample_border"] = bool(sample_border)
    return sensor


def scene_dict(shape, *, views=((35.0, 25.0),), resolution: int = 256, fov: float = 35.0,
               integrator: dict | None = None, sample_border: bool = False, bbox=None) -> dict:
    """Return a scene dictionary: the shape, one sensor per view, the rig's environment and key light.

    Parameters
    ----------
    shape : mi.Shape
        The loaded shape (e.g. from :func:`mi_loop.render.plugin.create`).
    views : sequence of (azimuth, elevation) in degrees, optional
        One sensor per entry, in order (``sensor=i`` of :func:`render_view`).
    resolution : int, optional
        Width and height of the square films in pixels.
    fov : float, optional
        Field of view in degrees (:func:`mi_loop.render.cameras.orbit_camera`).
    sample_border : bool, optional
        Film ``sample_border``; set it when differentiating shapes that may
        move across the image border.
    integrator : dict, optional
        Integrator dictionary (default: ``path`` with ``max_depth`` 4). Use
        ``{'type': 'direct_projective'}`` to differentiate silhouettes.
    bbox : ((3,), (3,)) float array-like, optional
        Box that places the cameras and the light (default: the shape's
        bounding box). Fix it to keep the same views while the shape changes.

    Returns
    -------
    dict
        Pass it to ``mi.load_dict``; the lights are the entries ``environment``
        and ``key_light`` (:func:`rig_emitters` in ``'shading'`` mode), the
        sensors ``sensor_000``, ``sensor_001``, ...
    """
    if bbox is None:
        bbox = (shape.bbox().min, shape.bbox().max)
    bbox = tuple(np.array(corner, dtype=np.float64).reshape(3) for corner in bbox)
    environment, key_light = rig_emitters(bbox, "shading", fov=fov)
    scene = {
        "type": "scene",
        "integrator": integrator if integrator is not None else {"type": "path", "max_depth": 4},
        "shape": shape,
        "environment": environment,
        "key_light": key_light,
    }
    for i, (azimuth, elevation) in enumerate(views):
        scene[f"sensor_{i:03d}"] = _orbit_sensor(bbox, azimuth, elevation, resolution=resolution, fov=fov,
                                                 sample_border=sample_border)
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
