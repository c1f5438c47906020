"""Optical flow correspondences (mi_loop.fitting.flow) and the flow term (terms.Flow): photos that pin material."""
from __future__ import annotations

import numpy as np
import pytest

import mi_loop
from mi_loop.datasets import icosphere
from mi_loop.fitting.flow import flow_correspondences, optical_flow


def test_dis_flow_recovers_a_known_shift_of_a_textured_image():
    rng = np.random.default_rng(0)
    from scipy.ndimage import gaussian_filter

    img = gaussian_filter(rng.uniform(size=(96, 96)), 2.0)
    img = (img - img.min()) / np.ptp(img)
    a = np.repeat(img[..., None], 3, axis=2)
    b = np.roll(a, (2, 3), axis=(0, 1))                   # 3 px right, 2 px down
    flow = optical_flow(a, b)[16:-16, 16:-16]
    np.testing.assert_allclose(np.median(flow.reshape(-1, 2), axis=0), [3.0, 2.0], atol=0.1)


@pytest.mark.parametrize("dx", [0.3, 0.7])
def test_dis_flow_follows_a_sub_pixel_shift_of_fine_texture_at_full_resolution(dx):
    """A frame's motion in a photo is often under a pixel: the flow must resolve it where the texture is fine.
    The image moved by cubic interpolation; DIS's medium preset alone (finest scale 1) is off by 0.04-0.06 px."""
    from scipy.ndimage import gaussian_filter, shift

    img = gaussian_filter(np.random.default_rng(0).uniform(size=(96, 96)), 1.5)
    img = (img - img.min()) / np.ptp(img)
    a = np.repeat(img[..., None], 3, axis=2)
    b = np.repeat(shift(img, (0.0, dx), order=3, mode="wrap")[..., None], 3, axis=2)
    flow = optical_flow(a, b)[16:-16, 16:-16]
    assert np.mean(np.abs(flow[..., 0] - dx)) < 0.02
    assert np.mean(np.abs(flow[..., 1])) < 0.02


def _rotation_z(deg):
    t = np.radians(deg)
    return np.array([[np.cos(t), -np.sin(t), 0.0], [np.sin(t), np.cos(t), 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def sliding_sphere():
    """A sphere whose texture turns by 4 degrees about z between two frames while its shape stays:
    control points, the dense limit surface at both frames with its (turned) texture, and 8 photos of each."""
    from mi_loop.io.emitters import DEFAULT_EMITTERS
    from mi_loop.render.cameras import fibonacci_cameras
    from mi_loop.render.captures import render_views
    from mi_loop.subdiv.masks import limit_mesh

    V, F = icosphere(2)
    Vl, Fl, Nl = limit_mesh(V, F, level=3)
    u = np.arctan2(Vl[:, 1], Vl[:, 0])
    pattern = 0.5 + 0.35 * np.sign(np.sin(9 * u)) * np.sign(np.sin(7 * Vl[:, 2]))    # a checker in longitude
    albedo = np.repeat(pattern[:, None], 3, axis=1)
    cameras = fibonacci_cameras(8, [0, 0, 0], 3.5, fov_x_deg=40.0, width=96, height=96)
    R = _rotation_z(4.0)
    lights = [dict(e) for e in DEFAULT_EMITTERS]
    before = render_views(Vl, Fl, cameras, lights, colors=albedo, normals=Nl, spp=16, seed=0)
    after = render_views(Vl @ R.T, Fl, cameras, lights, colors=albedo, normals=Nl @ R.T, spp=16, seed=1)
    return V, F, Vl, Nl, before, after


def _fit(V, F, Vl, Nl, flow):
    """Gauss-Newton on the frame-1 points (the same sphere) with ARAP, with or without the flow term."""
    import mitsuba as mi

    from mi_loop.energies.arap import ARAP
    from mi_loop.energies.imls import IMLS
    from mi_loop.fitting import terms
    from mi_loop.fitting.loop import Parameter, optimise
    from mi_loop.fitting.optimisers import Constant, GaussNewton
    from mi_loop.fitting.rules import Refresh, Seeds
    from mi_loop.fitting.static import sample_parameters

    op = mi_loop.LimitOperator(F, len(V), *sample_parameters(F, len(V), "level1", 0))
    parts = [terms.Distance(IMLS(Vl, Nl), op, facing=True), terms.Rigidity(ARAP(V, F), 1.0 / len(V))]
    if flow is not None:
        before, after = flow
        x = mi.Float(V.ravel().astype(np.float32))
        Q, N = (np.array(a, dtype=np.float64).T for a in op.positions_normals(x))
        corr = flow_correspondences(before, after, Q, N, Vl)
        assert len(corr.sample) > 100
        parts.append(terms.Flow(op, corr, 1.0, (1.0, np.zeros(3)), 3.5 / before[0].camera.fx))
    x = mi.Float(V.ravel().astype(np.float32))
    result = optimise({"x": Parameter(x, GaussNewton(), Constant(1.0))}, parts, iterations=8, seeds=Seeds(0),
                      refresh=Refresh(1))
    return result.values["x"]


def _turn_about_z(A, B) -> float:
    """Best rotation angle about z (degrees) taking points A to B (least squares in xy)."""
    cross = np.sum(A[:, 0] * B[:, 1] - A[:, 1] * B[:, 0])
    dot = np.sum(A[:, 0] * B[:, 0] + A[:, 1] * B[:, 1])
    return float(np.degrees(np.arctan2(cross, dot)))


def test_the_flow_term_recovers_a_texture_sliding_over_a_shape_that_stays(sliding_sphere):
    """Geometry alone does not turn the control points (the shape did not change); with the flow between
    the photos they turn with the texture, within 1 degree of the 4."""
    V, F, Vl, Nl, before, after = sliding_sphere
    without = _turn_about_z(V, _fit(V, F, Vl, Nl, None))
    with_flow = _turn_about_z(V, _fit(V, F, Vl, Nl, (before, after)))
    assert abs(without) < 0.5, without
    assert abs(with_flow - 4.0) < 1.0, with_flow


def test_flow_correspondences_need_the_same_cameras(sliding_sphere):
    import dataclasses

    V, F, Vl, Nl, before, after = sliding_sphere
    moved = [dataclasses.replace(after[0], camera=dataclasses.replace(after[0].camera, fx=2 * after[0].camera.fx))]
    with pytest.raises(ValueError) as e:
        flow_correspondences(before[:1], moved, Vl, Nl, Vl)
    assert str(e.value) == ("flow_correspondences(): expected the same camera for photo 0 at both frames, "
                            f"got '{before[0].name}' and '{after[0].name}'")
    with pytest.raises(ValueError) as e:
        flow_correspondences(before[:2], after[:1], Vl, Nl, Vl)
    assert str(e.value) == "flow_correspondences(): expected as many photos at both frames (2), got 1"


def test_the_coarse_stage_turns_with_a_texture_sliding_over_a_shape_that_stays(sliding_sphere):
    """The graph of the coarse stage on the frame-1 points alone does not turn; held on the rays through
    where the flow carried the samples it turns with the texture, within 1 degree of the 4. The fit is
    in a unit box of its own (scale 0.5, centre off the origin): the rays are mapped back into it."""
    from mi_loop.fitting.flow import sample_rays
    from mi_loop.fitting.static import sample_parameters
    from mi_loop.fitting.track import DeformationGraph, track

    V, F, Vl, Nl, before, after = sliding_sphere
    scale, centre = 0.5, np.array([0.2, -0.1, 0.3])
    x = (V - centre) / scale
    mats = mi_loop.limit_matrix(F, len(V), *sample_parameters(F, len(V), "level1", 0), derivative=(None, "u", "v"))
    rays = sample_rays(before, after, x, F, mats, (scale, centre))
    assert len(rays[0]) > 100 and np.allclose(np.linalg.norm(rays[2], axis=1), 1.0)
    graph = DeformationGraph(x, F, spacing=8)
    P, N = (Vl - centre) / scale, Nl
    turn = {}
    for name, r in (("points", None), ("rays", rays)):
        X, info = track(graph, x, mats, P, N, steps=8, rays=r)
        turn[name] = _turn_about_z(V, X * scale + centre)
        pinned = np.flatnonzero(info["pinned"])                   # the samples whose ray counts at the end
        if r is None:
            assert len(pinned) == 0
        else:
            assert set(pinned) <= set(rays[0]) and len(pinned) > 0.8 * len(np.unique(rays[0]))
    assert abs(turn["points"]) < 0.5, turn
    assert abs(turn["rays"] - 4.0) < 1.0, turn
