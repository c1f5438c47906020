"""The simulated sequence capture (bench/capture_sequence.py) on two frames of an icosphere.

Depth: 3 cameras on the +X side (40 x 30 pixels); the points must lie on the frame's mesh
within 5 sigma, project back to their pixel centres, leave the back (facing away from every
depth camera) empty and carry no normals. RGB: 3 Fibonacci views at 32 x 32, 4 spp; every
frame's transforms.json reads back with its views and non-empty masks.
"""
from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from helpers import REPO, sphere_mesh

SIGMA = 0.0015


@pytest.fixture(scope="module")
def cs():
    spec = importlib.util.spec_from_file_location("capture_sequence", REPO / "bench" / "capture_sequence.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def sequence():
    """Two frames: the icosphere of radius 0.4, then stretched 10 % along x."""
    V, F = sphere_mesh(0.4, 3)
    return np.stack([V, V * [1.1, 1.0, 1.0]]), F


@pytest.fixture(scope="module")
def depth_cams(cs):
    return cs.depth_cameras(azimuths=(-60.0, 0.0, 60.0), elevation=15.0, distance=1.9, fov_x_deg=40.0,
                            width=40, height=30)


@pytest.fixture(scope="module")
def written(cs, sequence, depth_cams, tmp_path_factory):
    from mi_loop.render.cameras import fibonacci_cameras

    Vs, F = sequence
    out = tmp_path_factory.mktemp("capture_seq")
    rgb_cams = fibonacci_cameras(3, [0, 0, 0], 1.9, fov_x_deg=35.0, width=32, height=32)
    stats = cs.write_frames(out, Vs, F, np.full((Vs.shape[1], 3), 0.5), depth_cams=depth_cams,
                            rgb_cams=rgb_cams, sigma=SIGMA, spp=4, log=lambda *_: None)
    return out, stats


def test_rays_match_the_mitsuba_sensor(cs, depth_cams):
    """pixel_rays gives the rays that sensor_dict's Mitsuba sensor traces through the pixel centres."""
    import mitsuba as mi

    from mi_loop.render.cameras import sensor_dict

    cam = depth_cams[2]
    origin, d, pixels = cs.pixel_rays(cam)
    sensor = mi.load_dict(sensor_dict(cam))
    film = pixels / [cam.width, cam.height]
    ray, _ = sensor.sample_ray(0.0, 0.0, mi.Point2f(film[:, 0], film[:, 1]), mi.Point2f(0.5, 0.5))
    np.testing.assert_allclose(np.asarray(ray.d).reshape(3, -1).T, d, atol=1e-5)
    offset = np.asarray(ray.o).reshape(3, -1).T - origin             # Mitsuba starts rays at the near clip
    np.testing.assert_allclose(offset - np.sum(offset * d, axis=1, keepdims=True) * d, 0.0, atol=1e-5)


def test_depth_points_lie_on_the_surface_and_project_to_their_pixels(cs, sequence, depth_cams):
    from mi_loop.mesh.sampling import surface_distances
    from mi_loop.render.cameras import project

    Vs, F = sequence
    scene = cs.ray_scene(Vs[1], F)
    for k, cam in enumerate(depth_cams):
        P, pixels = cs.depth_scan(scene, cam, SIGMA, np.random.default_rng(k))
        assert len(P) > 0.2 * cam.width * cam.height
        np.testing.assert_array_less(surface_distances(Vs[1], F, P), 5 * SIGMA)
        np.testing.assert_allclose(project(cam, P), pixels, atol=1e-6)
        exact, _ = cs.depth_scan(scene, cam, 0.0, np.random.default_rng(k))
        np.testing.assert_array_less(surface_distances(Vs[1], F, exact), 1e-5)


def test_depth_clouds_have_no_normals_and_no_back(cs, sequence, depth_cams, written):
    from mi_loop.io import load_oriented_points
    from mi_loop.mesh.geometry import vertex_normals
    from mi_loop.mesh.sampling import surface_distances

    Vs, F = sequence
    out, stats = written
    eyes = np.array([cam.c2w[:3, 3] for cam in depth_cams])
    for t in range(len(Vs)):
        path = out / "depth" / f"{t:04d}.ply"
        header = path.read_bytes().split(b"end_header")[0]
        assert b"property float nx" not in header and b"element face 0" in header
        P, N, info = load_oriented_points(path)
        assert N is None and info["kind"] == "points" and len(P) == stats[t]["n_points"]
        np.testing.assert_array_less(surface_distances(Vs[t], F, P), 5 * SIGMA)
        V = Vs[t]
        n = vertex_normals(V, F)
        to_eyes = eyes[None] - V[:, None]
        cosine = np.einsum("vd,vcd->vc", n, to_eyes / np.linalg.norm(to_eyes, axis=2, keepdims=True))
        back = cosine.max(axis=1) < -0.1
        assert back.mean() > 0.2, back.mean()
        gap, _ = cKDTree(P).query(V[back])
        np.testing.assert_array_less(0.02, gap)


def test_rgb_captures_read_back(cs, sequence, written):
    from mi_loop.io import read_capture
    from mi_loop.io.capture import list_captures

    out, stats = written
    paths = list_captures([out / "images"])
    assert [p.parent.name for p in paths] == ["0000", "0001"]
    for path, s in zip(paths, stats):
        capture = read_capture(path)
        assert len(capture.views) == 3
        for view in capture.views:
            assert view.mask.shape == (32, 32) and view.mask.sum() > 20
        assert 0.05 < s["mask_coverage"] < 0.5
    # the sphere of radius 0.4 at 1.9, centred in a 35-degree view, covers
    # pi (0.4 / sqrt(1.9^2 - 0.4^2) / tan(17.5 deg))^2 / 4 of the frame
    expected = math.pi * (0.4 / math.sqrt(1.9**2 - 0.4**2) / math.tan(math.radians(17.5))) ** 2 / 4
    np.testing.assert_allclose(read_capture(paths[0]).views[0].mask.mean(), expected, rtol=0.1)


def test_seen_area_of_the_sphere(cs, sequence, depth_cams, written):
    """About 60 % of the sphere faces some camera of the 120-degree fan; never the whole of it."""
    _, stats = written
    for s in stats:
        assert 0.4 < s["seen_area"] < 0.8, s["seen_area"]
