"""Renders of a triangle mesh, or of the emitters alone, from calibrated cameras: the views to fit.

- :func:`render_views`: synthetic captures (RGB clipped as a camera's, the
  render's alpha as the mask) for tests and benchmarks;
- :func:`render_targets`: the targets of a rig (a mesh frame rendered in the
  fit's own emitters, mask all ones);
- :func:`background`: what the cameras see of the emitters alone, over which
  :class:`~mi_loop.render.images.ImageRenderer` composites photos;
- :func:`camera_scene`: the scene of a shape, emitters and one sensor per camera
  (:func:`mi_loop.render.cameras.sensor_dict`) that all of them render;
- :func:`check_count`, :func:`check_albedo`, :func:`check_views`: the input
  checks they share with :class:`~mi_loop.render.images.ImageRenderer`.

Compositing. At a pixel a fraction ``a`` covered by the mesh, Mitsuba's
``hdrfilm`` stores ``a S + (1 - a) B`` in RGB (``S`` the mesh's mean radiance
there, ``B`` the emitters seen past it) and ``a`` in alpha: the RGB already
holds the background, as a photo's does. A photo is compared over a render of
the emitters, ``mask * rgb + (1 - mask) * B``; a target rendered in the
renderer's own emitters is compared as it is, hence its mask of ones.

Seeds. :func:`view_seed` is the sampler seed of view ``k`` in a call with seed
``s``, in :func:`render_targets` and in every render of
:class:`~mi_loop.render.images.ImageRenderer`; :func:`render_views` and
:func:`background` keep ``s + k``.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail
from mi_loop.render.plugin import COLOR_ATTRIBUTE, albedo_bsdf, plain_mesh

__all__ = ["background", "camera_scene", "render_geometry", "render_targets", "render_views", "view_seed"]


def view_seed(seed: int, k: int) -> int:
    """Return the sampler seed of view ``k`` in a call with seed ``seed``: one word of ``SeedSequence(seed, (k,))``.

    The seed tree of the fits (:class:`mi_loop.fitting.rules.Seeds`) spawned one
    level further, by view: two different ``(seed, k)`` pairs never share a
    stream by construction (unlike an affine rule such as ``1009 seed + k``).

    Parameters
    ----------
    seed : int
        The call's seed (an iteration's, say), ``>= 0``.
    k : int
        The view, ``>= 0``.

    Returns
    -------
    int
        In ``[0, 2**32)``, as Mitsuba's samplers take.

    Examples
    --------
    >>> view_seed(5, 0) == view_seed(5, 0) != view_seed(5, 1)
    True
    """
    return int(np.random.SeedSequence(int(seed), spawn_key=(int(k),)).generate_state(1, np.uint32)[0])


def camera_scene(shape, cameras, emitters, *, integrator: dict | None, spp: int, alpha: bool = False):
    """Load the scene of one shape (or none), the emitters and one sensor per camera.

    Parameters
    ----------
    shape : mi.Shape or None
        A ``loop_subdiv`` shape or a :func:`~mi_loop.render.plugin.plain_mesh`.
    cameras : list of mi_loop.io.capture.Camera
        Sensor ``k`` is :func:`mi_loop.render.cameras.sensor_dict` of camera ``k``.
    emitters : list of dict or mi.Emitter
        The lighting (shapes with an ``area`` emitter too).
    integrator : dict or None
        Integrator dictionary (None: Mitsuba's default).
    spp : int
        Samples per pixel of the sensors' samplers.
    alpha : bool, optional
        Films with an alpha channel (``rgba``).

    Returns
    -------
    mi.Scene
    """
    import mitsuba as mi

    from mi_loop.render.cameras import sensor_dict

    desc = {"type": "scene"}
    if integrator is not None:
        desc["integrator"] = integrator
    if shape is not None:
        desc["shape"] = shape
    for j, emitter in enumerate(emitters):
        desc[f"emitter_{j}"] = emitter
    for k, camera in enumerate(cameras):
        sensor = sensor_dict(camera, spp=spp)
        if alpha:
            sensor["film"]["pixel_format"] = "rgba"
        desc[f"sensor_{k:03d}"] = sensor
    return mi.load_dict(desc)


def check_count(value, func: str, what: str, low: int) -> int:
    """``value`` as an int, or ``ValueError`` ``func(): expected an integer what >= low``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        fail(func, f"an integer {what} >= {low}", value)
    return int(value)


def check_albedo(albedo, n: int, func: str) -> np.ndarray:
    """``albedo`` as a (n, 3) float32 array in [0, 1], checked for ``func`` (one RGB per vertex)."""
    A = np.asarray(albedo, dtype=np.float64)
    if A.shape != (n, 3):
        fail(func, f"albedo of shape (n, 3) = ({n}, 3), one linear RGB per vertex", f"shape {A.shape}")
    bad = np.flatnonzero(~(np.isfinite(A) & (A >= 0) & (A <= 1)).all(axis=1))
    if len(bad):
        fail(func, "albedo in [0, 1]", f"{A[bad[0]].tolist()} at vertex {int(bad[0])}")
    return A.astype(np.float32)


def check_views(views, func: str) -> list:
    """``views`` as a non-empty list of :class:`mi_loop.io.View`, checked for ``func``."""
    from mi_loop.io.capture import View

    views = list(views)
    if not views:
        fail(func, "at least one view", "none")
    for k, view in enumerate(views):
        if not isinstance(view, View):
            fail(func, "views that are mi_loop.io.View objects", f"{type(view).__name__} at views[{k}]", TypeError)
    return views


def background(cameras, emitters, *, spp: int = 16, seed: int = 0) -> list:
    """Render what each camera sees of the emitters alone (the photos' stand-in background).

    Parameters
    ----------
    cameras : list of mi_loop.io.capture.Camera
        The cameras.
    emitters : list of dict or mi.Emitter
        The lighting.
    spp : int
        Samples per pixel (an environment seen directly needs few).
    seed : int
        Sampler seed of the first camera (camera ``k`` uses ``seed + k``).

    Returns
    -------
    list of (h, w, 3) float32 NumPy arrays
        Linear RGB per camera.
    """
    import mitsuba as mi

    scene = camera_scene(None, cameras, emitters, integrator={"type": "direct"}, spp=spp)
    return [np.asarray(mi.render(scene, spp=spp, seed=seed + k, sensor=k), dtype=np.float32)[..., :3]
            for k in range(len(cameras))]


def render_views(V, F, cameras, emitters, *, colors=None, normals=None, spp: int = 64, seed: int = 0,
                 emission: bool = False) -> list:
    """Photograph a triangle mesh with calibrated cameras: synthetic captures for tests and benchmarks.

    Parameters
    ----------
    V : (k, 3) float NumPy array
        Vertex positions.
    F : (t, 3) int NumPy array
        Triangles.
    cameras : list of mi_loop.io.capture.Camera
        The cameras.
    emitters : list of dict or mi.Emitter
        The lighting.
    colors : (k, 3) float NumPy array, optional
        Per-vertex linear albedo (default: grey 0.5) of a diffuse BSDF.
    normals : (k, 3) float NumPy array, optional
        Vertex normals (smooth shading); flat without.
    spp : int
        Samples per pixel (``direct`` integrator).
    seed : int
        Seed of the first view's sampler (view ``k`` uses ``seed + k``).
    emission : bool
        The ``colors`` are the radiance the mesh sends towards every camera (a
        lighting already applied, :mod:`mi_loop.render.lighting`): the mesh
        emits them and reflects nothing; the emitters are only its backdrop.

    Returns
    -------
    list of mi_loop.io.capture.View
        Linear RGB clipped to [0, 1] (as an 8-bit camera saturates; Monte Carlo
        noise can exceed a white albedo) and the render's alpha as the mask,
        named ``view_000`` ... The RGB holds the emitters where the mesh leaves a
        pixel uncovered (module docstring), as a photo holds its background;
        :func:`render_targets` gives the targets of a rig instead.
    """
    import mitsuba as mi

    from mi_loop.io.capture import View

    emitter = None
    if emission:
        if colors is None:
            fail("render_views", "colors (the emitted radiance) with emission=True", "none")
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}
        emitter = mi.load_dict({"type": "area", "radiance": {"type": "mesh_attribute", "name": COLOR_ATTRIBUTE}})
    elif colors is None:
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}
    else:
        bsdf = albedo_bsdf()
    mesh = plain_mesh(V, F, normals=normals, bsdf=mi.load_dict(bsdf), colors=colors, emitter=emitter)
    return [View(camera=camera, rgb=np.clip(image[..., :3], 0, 1), mask=np.clip(image[..., 3], 0, 1),
                 name=f"view_{k:03d}")
            for k, camera, image in _renders(mesh, cameras, emitters, spp, lambda k: seed + k, alpha=True)]


def render_geometry(V, F, normals, cameras, *, spp: int = 16, seed: int = 7) -> list:
    """Render a mesh's geometry alone: grey, lit from above each camera's right, without shadows or noise.

    Relief in the geometry shows here; relief painted into an albedo does not.
    The shading ``0.06 + 0.7 max(0, n . l)`` (``l`` towards the camera's right,
    up and back) is the mesh's emission (:func:`render_views` with
    ``emission=True``) over a dark backdrop.

    Parameters
    ----------
    V : (k, 3) float NumPy array
    F : (t, 3) int NumPy array
    normals : (k, 3) float NumPy array
        Unit vertex normals.
    cameras : list of mi_loop.io.capture.Camera
    spp : int, optional
        Samples per pixel (antialiasing only).
    seed : int, optional

    Returns
    -------
    list of (h, w, 3) float32 NumPy arrays
        Linear RGB per camera.
    """
    N = np.asarray(normals, dtype=np.float64)
    backdrop = [{"type": "constant", "radiance": {"type": "rgb", "value": 0.05}}]
    images = []
    for camera in cameras:
        right, up, back = (camera.c2w[:3, i] for i in range(3))
        light = 0.8 * right + 0.5 * up + 0.35 * back
        grey = 0.06 + 0.7 * np.maximum(N @ (light / np.linalg.norm(light)), 0.0)
        images.append(render_views(V, F, [camera], backdrop, colors=np.repeat(grey[:, None], 3, axis=1),
                                   normals=N, spp=spp, seed=seed, emission=True)[0].rgb)
    return images


def render_targets(V, F, cameras, emitters, *, albedo, normals=None, spp: int = 64, seed: int = 0) -> list:
    """Render a triangle mesh (a frame to fit) from cameras: the targets of an image fit.

    Parameters
    ----------
    V : (k, 3) float NumPy array
        Vertex positions.
    F : (t, 3) int NumPy array
        Triangles.
    cameras : list of mi_loop.io.capture.Camera
        The cameras (e.g. :func:`mi_loop.render.cameras.rig_cameras`).
    emitters : list of dict or mi.Emitter
        The lighting, the same as the renderer's (e.g. :func:`mi_loop.render.scene.rig_emitters`).
    albedo : (k, 3) float NumPy array
        Per-vertex linear RGB in [0, 1] of the diffuse :func:`~mi_loop.render.plugin.albedo_bsdf`
        (``np.full((k, 3), 0.6)``: the rig's grey; zeros: silhouettes).
    normals : (k, 3) float NumPy array, optional
        Vertex normals (smooth shading); flat without.
    spp : int, optional
        Samples per pixel (``direct`` integrator), >= 1.
    seed : int, optional
        View ``k`` uses the sampler seed :func:`view_seed` ``(seed, k)``.

    Returns
    -------
    list of mi_loop.io.capture.View
        The linear RGB render, unclipped, with a mask of ones: the target of
        :class:`~mi_loop.render.images.ImageRenderer` is the render itself,
        emitters included (module docstring). Named ``view_000`` ...

    Raises
    ------
    ValueError
        ``albedo`` not of shape (k, 3) or outside [0, 1], ``spp < 1``.
    """
    import mitsuba as mi

    from mi_loop.io.capture import View

    A = check_albedo(albedo, len(np.asarray(V)), "render_targets")
    spp = check_count(spp, "render_targets", "spp", 1)
    mesh = plain_mesh(V, F, normals=normals, bsdf=mi.load_dict(albedo_bsdf()), colors=A)
    return [View(camera=camera, rgb=image[..., :3], mask=np.ones(image.shape[:2], np.float32), name=f"view_{k:03d}")
            for k, camera, image in _renders(mesh, cameras, emitters, spp, lambda k: view_seed(seed, k))]


def _renders(mesh, cameras, emitters, spp: int, seed_of, alpha: bool = False):
    """``(k, camera, float32 image (h, w, 3 or 4))`` of a mesh from each camera (``direct``, seed ``seed_of(k)``)."""
    import mitsuba as mi

    scene = camera_scene(mesh, cameras, emitters, integrator={"type": "direct"}, spp=spp, alpha=alpha)
    for k, camera in enumerate(cameras):
        yield k, camera, np.asarray(mi.render(scene, spp=spp, seed=seed_of(k), sensor=k), dtype=np.float32)
