"""Scenes around one shape (mi_loop.render.scene): the rig's lights, orbit sensors, the old pictures kept.

Since the scenes' sensors are Camera objects through the one
:func:`mi_loop.render.cameras.sensor_dict`, :func:`render_limit_surface` and
:func:`scene_dict` must still draw the pictures that Mitsuba's look-at sensors
drew: the oracle here is that scene, written out as it was.
"""
from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import pytest

from mi_loop import datasets
from mi_loop.render.cameras import _direction, look_at_distance, orbit_camera, sensor_dict
from mi_loop.render.plugin import create
from mi_loop.render.scene import PLASTIC, render_limit_surface, render_view, rig_emitters, scene_dict, to_srgb

from helpers import exactly

BOX = (np.array([-0.4, -0.2, -0.3]), np.array([0.6, 0.5, 0.1]))


def old_scene(shape, views, resolution, bbox, fov=35.0, integrator=None):
    """The scene dictionary of scene_dict before its cameras were Camera objects (Mitsuba look-at sensors)."""
    lo, hi = (np.asarray(c, dtype=np.float64) for c in bbox)
    centre, radius = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    reach = 1.25 * look_at_distance(radius, fov) / radius
    light_at = centre + reach * radius * _direction(60.0, 70.0)
    scene = {
        "type": "scene", "shape": shape,
        "integrator": integrator or {"type": "path", "max_depth": 4},
        "environment": {"type": "constant", "radiance": {"type": "rgb", "value": 0.25}},
        "key_light": {"type": "rectangle",
                      "to_world": mi.ScalarTransform4f().look_at(origin=light_at.tolist(), target=centre.tolist(),
                                                                 up=[0, 1, 0]).scale([0.2 * reach * radius] * 3),
                      "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 6.0}}},
    }
    for i, (azimuth, elevation) in enumerate(views):
        origin = centre + look_at_distance(radius, fov) * _direction(azimuth, elevation)
        scene[f"sensor_{i:03d}"] = {
            "type": "perspective", "fov": fov,
            "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=centre.tolist(), up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution, "pixel_format": "rgb",
                     "rfilter": {"type": "box"}}}
    return scene


def test_render_limit_surface_draws_the_old_picture():
    """Same seed, same samples: the pictures agree to float rounding (measured 6e-7), not just in expectation."""
    V, F = datasets.blob()
    image, shape = render_limit_surface(V, F, level=2, resolution=40, spp=16, seed=5, azimuth=-70.0, elevation=50.0)
    old = create(V, F, level=2, bsdf=mi.load_dict(PLASTIC))
    scene = mi.load_dict(old_scene(old, [(-70.0, 50.0)], 40, (shape.bbox().min, shape.bbox().max)))
    expected = to_srgb(render_view(scene, spp=16, seed=5))
    assert expected.std() > 0.05                                    # a picture, not a flat background
    np.testing.assert_allclose(image, expected, rtol=0, atol=1e-5)


def test_scene_dict_renders_every_view_as_before():
    """Two views of a fixed box with a projective integrator (the multi-view renderer's use), seed 2."""
    V, F = datasets.blob()
    views, integrator = [(0.0, 0.0), (120.0, -30.0)], {"type": "direct_projective", "sppi": 0}
    shape = create(V, F, level=1, bsdf=mi.load_dict(PLASTIC))
    new = mi.load_dict(scene_dict(shape, views=views, resolution=24, bbox=BOX, integrator=integrator,
                                  sample_border=True))
    old = mi.load_dict(old_scene(create(V, F, level=1, bsdf=mi.load_dict(PLASTIC)), views, 24, BOX,
                                 integrator=integrator))
    for k in range(2):
        np.testing.assert_allclose(np.asarray(render_view(new, spp=8, seed=2, sensor=k)),
                                   np.asarray(render_view(old, spp=8, seed=2, sensor=k)), rtol=0, atol=1e-5)


def test_scene_dict_holds_the_rig_lights_and_orbit_sensors():
    shape = create(*datasets.blob(), level=0)
    desc = scene_dict(shape, views=[(10.0, 20.0)], resolution=16, fov=40.0, bbox=BOX, sample_border=True)
    environment, key_light = rig_emitters(BOX, fov=40.0)
    assert desc["environment"] == environment
    np.testing.assert_array_equal(np.array(desc["key_light"]["to_world"].matrix),
                                  np.array(key_light["to_world"].matrix))
    sensor = sensor_dict(orbit_camera(BOX, 10.0, 20.0, fov=40.0, resolution=16), spp=4, near=1e-2, far=1e4)
    np.testing.assert_array_equal(np.array(desc["sensor_000"]["to_world"].matrix), np.array(sensor["to_world"].matrix))
    assert {k: v for k, v in desc["sensor_000"].items() if k != "to_world"} == \
        {k: v for k, v in sensor.items() if k != "to_world"}
    assert scene_dict(shape, bbox=BOX)["sensor_000"]["film"]["sample_border"] is False


@pytest.mark.parametrize("scale", [1.0, 30.0])
def test_the_key_light_sits_beyond_the_cameras_facing_the_subject(scale):
    """At 1.25 times the cameras' distance, azimuth 60 and elevation 70, facing the box centre, and
    subtending the same angle for every box: half-size / distance = 0.2 (a 1.2 r panel at 3 r)."""
    lo, hi = BOX[0] * scale, BOX[1] * scale
    centre, radius = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    environment, key_light = rig_emitters((lo, hi), "shading")
    assert environment == {"type": "constant", "radiance": {"type": "rgb", "value": 0.25}}
    assert key_light["type"] == "rectangle" and key_light["emitter"]["radiance"]["value"] == 6.0
    M = np.array(key_light["to_world"].matrix, dtype=np.float64)
    distance = 1.25 * look_at_distance(radius, 35.0)
    np.testing.assert_allclose(M[:3, 3], centre + distance * _direction(60.0, 70.0), rtol=1e-6)
    normal = M[:3, 2] / np.linalg.norm(M[:3, 2])               # the rectangle's +z, its emitting side
    np.testing.assert_allclose(normal, -_direction(60.0, 70.0), atol=1e-6)
    assert np.linalg.norm(M[:3, 0]) / distance == pytest.approx(0.2, rel=1e-6)
    assert rig_emitters((lo, hi), "silhouette") == [environment]


@pytest.mark.parametrize("call, message", [
    (lambda: rig_emitters(BOX, "depth"), "rig_emitters(): expected mode to be one of ('shading', 'silhouette'), "
                                         "got 'depth'"),
    (lambda: rig_emitters(([0, 0, 0], [1, 1, math.nan])), "rig_emitters(): expected a bbox of finite corners with "
     "lo <= hi and a diagonal > 0, got lo = [0.0, 0.0, 0.0], hi = [1.0, 1.0, nan]"),
])
def test_rig_emitters_refuse_bad_input(call, message):
    with pytest.raises(ValueError, match=exactly(message)):
        call()
