"""The coarse stage of a frame (embedded deformation tracking) and the term holding control points along the surface."""
import numpy as np
import pytest
import scipy.sparse as sp

import mi_loop
from mi_loop.datasets import icosphere
from mi_loop.fitting.track import DeformationGraph, _exp, anchor_weights, track
from mi_loop.subdiv.masks import limit_mesh


def _rotation(axis, angle):
    a = np.asarray(axis, dtype=np.float64)
    return _exp((angle * a / np.linalg.norm(a))[None])[0]


def test_rodrigues_is_a_rotation_about_its_axis():
    R = _rotation([0, 0, 1], np.pi / 2)
    assert np.allclose(R @ [1.0, 0, 0], [0, 1, 0], atol=1e-15)
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-15) and np.isclose(np.linalg.det(R), 1.0)


def test_graph_weights_and_pairs():
    V, F = icosphere(3)
    g = DeformationGraph(V, F, spacing=10)
    assert np.allclose(g.weights.sum(axis=1), 1.0) and (g.weights >= 0).all()
    assert len(np.unique(g.nodes)) == len(g.nodes)
    # a node's own control point: that node is its nearest and weighs the most
    j = np.arange(len(g.nodes))
    assert np.all(g.neighbours[g.nodes, 0] == j) and np.all(g.weights[g.nodes].argmax(axis=1) == 0)
    # pairs come in both directions
    pairs = {tuple(e) for e in g.edges.tolist()}
    assert all((b, a) in pairs for a, b in pairs)


def test_deform_with_one_rigid_motion_moves_every_point_rigidly():
    V, F = icosphere(2)
    g = DeformationGraph(V, F, spacing=8)
    R, t = _rotation([1, 2, 3], 0.3), np.array([0.1, -0.2, 0.05])
    # node j at g_j with rotation R and translation t_j = R g_j - g_j + t is the motion x -> R x + t
    nodes = V[g.nodes]
    moved = g.deform(V, np.broadcast_to(R, (len(nodes), 3, 3)).copy(), nodes @ R.T - nodes + t)
    assert np.allclose(moved, V @ R.T + t, atol=1e-14)


def test_a_known_rigid_motion_is_recovered_so_that_material_does_not_drift():
    """Points of the moved limit surface: the tracked control points are the moved control points."""
    mi_loop.set_variant("llvm_ad_rgb")
    V, F = icosphere(2)
    V = V * [1.0, 0.7, 0.5]                        # an ellipsoid: a rotation about any axis is seen
    R, t = _rotation([0.3, 1, 0.2], 0.04), np.array([0.01, 0.0, -0.005])
    target = V @ R.T + t
    P, _, N = limit_mesh(target, F, level=4)
    tess = mi_loop.subdiv.masks.tessellate(F, 1)
    mats = mi_loop.limit_matrix(F, len(V), tess[0], tess[1], derivative=(None, "u", "v"))
    g = DeformationGraph(V, F, spacing=8)
    X, info = track(g, V, mats, P, N, steps=10)
    drift = np.linalg.norm(X - target, axis=1).max() / np.linalg.norm(np.ptp(V, axis=0))
    start = np.linalg.norm(V - target, axis=1).max() / np.linalg.norm(np.ptp(V, axis=0))
    assert start > 0.01 and drift < 2e-3, (start, drift)
    assert info["residual"][-1] < 0.1 * info["residual"][0]
    assert info["held"].all()                      # every sample found the moved surface: every anchor trusted
    assert np.all(anchor_weights(mats[0], info["held"]) == 1.0)


def test_anchor_weights_trust_the_points_whose_support_found_data():
    mi_loop.set_variant("llvm_ad_rgb")
    V, F = icosphere(2)
    tess = mi_loop.subdiv.masks.tessellate(F, 2)
    M = mi_loop.limit_matrix(F, len(V), tess[0], tess[1])
    Q = M @ V
    held = Q[:, 2] > 0                              # only the upper half found data
    w = anchor_weights(M, held)
    assert w.shape == (len(V),) and w.min() >= 0.0 and w.max() <= 1.0
    assert np.all(w[V[:, 2] > 0.3] == 1.0) and np.all(w[V[:, 2] < -0.3] == 0.0)
    # the share itself, written out for one point on the equator band: weight (share - 0.5) / 0.4
    W = abs(M).toarray()
    i = int(np.argmin(np.abs(V[:, 2] - 0.1)))
    share = W[held, i].sum() / W[:, i].sum()
    assert w[i] == pytest.approx(np.clip((share - 0.5) / 0.4, 0, 1), abs=1e-12)


def _anchors_and_normals(seed: int, n: int):
    """Random anchors and unit normals, and the variant the tangential terms run in."""
    mi_loop.set_variant("llvm_ad_rgb")
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 3))
    N = rng.normal(size=(n, 3))
    return rng, A, N / np.linalg.norm(N, axis=1, keepdims=True)


def _state(X):
    """``(state, x)``: a loop state of control points ``X`` (``x`` with gradients enabled)."""
    import drjit as dr
    import mitsuba as mi

    from mi_loop.ad.control import ControlPoints

    x = mi.Float(np.asarray(X, dtype=np.float64).ravel())
    dr.enable_grad(x)
    s = type("State", (), {})()
    s.x, s.values = ControlPoints(x), {"x": x}
    return s, x


def test_tangential_term_prices_sliding_not_normal_motion_and_its_matrix_is_exact():
    import drjit as dr

    from mi_loop.fitting.terms import Tangential

    rng, A, N = _anchors_and_normals(3, 5)
    term = Tangential(A, N, 0.7)
    normal = A + 0.3 * N                                          # moved along the normals only: free
    assert float(term.energy(_state(normal)[0])[0]) == pytest.approx(0.0, abs=1e-6)
    X = A + rng.normal(size=A.shape)
    D = X - A
    T = D - N * np.sum(D * N, axis=1, keepdims=True)
    s, x = _state(X)
    e = term.energy(s)
    assert float(e[0]) == pytest.approx(0.7 * np.mean(np.sum(T * T, axis=1)), rel=1e-5)
    # the energy is quadratic: its gradient at X is H (X - A), H the term's matrix
    dr.backward(e)
    H = term.hessian(s)
    assert sp.issparse(H) and H.shape == (15, 15)
    assert np.allclose(np.array(dr.grad(x)), H @ D.ravel(), rtol=1e-4, atol=1e-6)


def test_tangential_hold_lets_go_of_far_slides_and_of_untrusted_anchors():
    import drjit as dr

    from mi_loop.fitting.terms import Tangential

    rng, A, N = _anchors_and_normals(4, 6)
    h = np.array([1.0, 0.5, 0.0, 1.0, 0.25, 1.0])
    c = 0.3
    term = Tangential(A, N, 0.7, held=h, reach=c)
    X = A + rng.normal(size=A.shape)
    D = X - A
    T = D - N * np.sum(D * N, axis=1, keepdims=True)
    sq = np.sum(T * T, axis=1)
    s, x = _state(X)
    e = term.energy(s)
    assert float(e[0]) == pytest.approx(0.7 * np.mean(h * c * c * sq / (sq + c * c)), rel=1e-5)
    # the matrix is the reweighted one: H (X - A) is the gradient itself
    dr.backward(e)
    H = term.hessian(s)
    assert np.allclose(np.array(dr.grad(x)), H @ D.ravel(), rtol=1e-4, atol=1e-7)
    # an untrusted anchor (h = 0) does not pull at all
    assert np.allclose(np.array(dr.grad(x)).reshape(-1, 3)[2], 0.0)

    # the pull on one point along a tangent: largest near c / sqrt(3), a few percent of that at 10 c
    t = np.cross(N[0], [0.0, 0.0, 1.0])
    t /= np.linalg.norm(t)

    def pull(length):
        Y = A.copy()
        Y[0] += length * t
        s, y = _state(Y)
        dr.backward(term.energy(s))
        return float(np.linalg.norm(np.array(dr.grad(y)).reshape(-1, 3)[0]))

    peak = pull(c / np.sqrt(3.0))
    assert pull(0.5 * c / np.sqrt(3.0)) < peak and pull(2 * c / np.sqrt(3.0)) < peak
    assert pull(10 * c) < 0.05 * peak


def test_a_bend_the_coarse_stage_left_where_no_data_hold_it_is_undone_by_arap_to_the_previous_fit():
    """The fox's lost legs: a tracked start whose cap the graph pushed out, no data at the cap, its anchors untrusted.

    With ARAP's rest at the tracked start the bend is kept (it costs nothing); at the previous fit, ARAP undoes it.
    """
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.fitting.options import SequenceOptions
    from mi_loop.fitting.sequence import fit_frame
    from mi_loop.fitting.static import sample_parameters
    from mi_loop.mesh.geometry import mean_edge_length
    from mi_loop.subdiv.masks import vertex_samples

    mi_loop.set_variant("llvm_ad_rgb")
    V, F = icosphere(2)
    V, n = 0.5 * V, len(V)
    P, _, N = limit_mesh(V, F, level=4)
    seen = P[:, 2] < 0.2                                       # no data on the cap
    z = V[:, 2] / 0.5
    start = V * (1.0 + 0.3 * np.clip((z - 0.5) / 0.5, 0.0, 1.0))[:, None]
    cap = V[:, 2] > 0.3
    op = LimitOperator(F, n, *sample_parameters(F, n, "level1", 0), derivatives=True)
    vertex_op = LimitOperator(F, n, *vertex_samples(F, n), derivatives=True)
    options = SequenceOptions(image=False, iterations=60, tangential=1.0)
    bend = {}
    for rest in ("start", "previous"):
        X, _ = fit_frame(start, F, P[seen], N[seen], op, None, options, frame=1, lr=0.02 * mean_edge_length(V, F),
                         vertex_op=vertex_op, held=(V[:, 2] < 0.2).astype(float), complete=True,
                         previous=V if rest == "previous" else None)
        bend[rest] = np.linalg.norm(X - V, axis=1)[cap].mean() / np.linalg.norm(start - V, axis=1)[cap].mean()
    assert bend["start"] > 0.85 and bend["previous"] < 0.75, bend


def test_partial_depth_holds_its_unseen_parts_where_the_coarse_stage_carried_them_and_complete_data_let_go():
    """A tracked start whose unseen cap the coarse stage turned about the axis (a slide along the surface).

    Partial depth: the cap is unseen, not lost, and the hold keeps it where it was carried. Complete data: the
    anchors that found no data are let go of, and ARAP to the previous fit turns the cap back.
    """
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.fitting.options import SequenceOptions
    from mi_loop.fitting.sequence import fit_frame
    from mi_loop.fitting.static import sample_parameters
    from mi_loop.mesh.geometry import mean_edge_length
    from mi_loop.subdiv.masks import vertex_samples

    mi_loop.set_variant("llvm_ad_rgb")
    V, F = icosphere(2)
    V, n = 0.5 * V, len(V)
    P, _, N = limit_mesh(V, F, level=4)
    seen = P[:, 2] < 0.2
    cap = V[:, 2] > 0.3
    start = V.copy()
    start[cap] = V[cap] @ _rotation([0, 0, 1], 0.15).T
    op = LimitOperator(F, n, *sample_parameters(F, n, "level1", 0), derivatives=True)
    vertex_op = LimitOperator(F, n, *vertex_samples(F, n), derivatives=True)
    options = SequenceOptions(image=False, iterations=60, tangential=1.0)
    back = {}
    for complete, held in ((False, np.ones(n)), (True, (V[:, 2] < 0.2).astype(float))):
        X, _ = fit_frame(start, F, P[seen], N[seen], op, None, options, frame=1, lr=0.02 * mean_edge_length(V, F),
                         vertex_op=vertex_op, held=held, complete=complete, previous=V)
        back[complete] = np.linalg.norm(X - start, axis=1)[cap].mean() / np.linalg.norm(V - start, axis=1)[cap].mean()
    assert back[False] < 0.25 and back[True] > 1.5 * back[False], back


def test_rays_through_where_the_material_moved_carry_a_texture_turning_on_a_shape_that_stays():
    """A sphere whose material turns about its axis: its points say nothing of the turn and the graph stays;
    camera rays through each sample's turned position (what optical flow sees) carry it along the turn."""
    mi_loop.set_variant("llvm_ad_rgb")
    V, F = icosphere(3)
    R = _rotation([0, 0, 1], 0.08)
    P, _, N = limit_mesh(V, F, level=4)             # the frame's points: the same shape
    tess = mi_loop.subdiv.masks.tessellate(F, 1)
    mats = mi_loop.limit_matrix(F, len(V), tess[0], tess[1], derivative=(None, "u", "v"))
    Q = mats[0] @ V
    Nq = np.cross(mats[1] @ V, mats[2] @ V)
    sample, origin, direction = [], [], []
    for c in 4.0 * np.concatenate([np.eye(3), -np.eye(3)]):        # six cameras, each seeing what faces it
        seen = np.flatnonzero(np.sum(Nq * (c - Q), axis=1) > 0)
        ray = Q[seen] @ R.T - c
        sample.append(seen)
        origin.append(np.broadcast_to(c, (len(seen), 3)))
        direction.append(ray / np.linalg.norm(ray, axis=1, keepdims=True))
    rays = tuple(np.concatenate(a) for a in (sample, origin, direction))
    g = DeformationGraph(V, F, spacing=8)
    diag = np.linalg.norm(np.ptp(V, axis=0))
    turned = V @ R.T
    error = {}
    for name, r in (("points", None), ("rays", rays)):
        X, info = track(g, V, mats, P, N, steps=10, rays=r)
        error[name] = np.linalg.norm(X - turned, axis=1).max() / diag
    start = np.linalg.norm(V - turned, axis=1).max() / diag
    assert start > 0.02                                    # 2.3 % of the diagonal at the equator
    assert error["points"] > 0.9 * start                   # the points alone: the graph does not turn
    assert error["rays"] < 0.01 * start, error             # measured 1e-4 of the diagonal
    assert info["rays"][-1] > 0.9                          # the rays agree: few are trimmed


def test_in_silhouettes_finds_the_points_a_photo_sees_outside_its_grown_mask():
    """A camera on +z looking at a disc-shaped mask (radius 10 px, 100 px focal length, 2 units away): a point
    projecting 12 px from the centre is outside, but inside with the mask grown by 3 px; a point behind the
    camera or out of frame says nothing; a second photo whose mask is empty rejects what it sees."""
    from mi_loop.fitting.track import in_silhouettes
    from mi_loop.io.views import Camera, View
    from mi_loop.render.cameras import look_at

    cam = Camera(look_at([0.0, 0.0, 2.0], [0.0, 0.0, 0.0]), 100.0, 100.0, 32.0, 32.0, 64, 64)
    yy, xx = np.mgrid[0:64, 0:64] + 0.5
    disc = ((xx - 32) ** 2 + (yy - 32) ** 2 <= 10.0 ** 2).astype(np.float32)
    view = View(cam, np.zeros((64, 64, 3)), disc, "disc")
    points = np.array([[0.0, 0.0, 0.0],           # centre: inside
                       [0.24, 0.0, 0.0],          # 12 px right: outside the disc
                       [0.0, 0.0, 3.0],           # behind the camera: not seen
                       [2.0, 0.0, 0.0]])          # 100 px right: out of frame, not seen
    assert in_silhouettes([view], points, margin=0).tolist() == [True, False, True, True]
    assert in_silhouettes([view], points, margin=3).tolist() == [True, True, True, True]
    empty = View(cam, np.zeros((64, 64, 3)), np.zeros((64, 64)), "empty")
    assert in_silhouettes([view, empty], points, margin=3).tolist() == [False, False, True, True]
