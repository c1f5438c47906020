"""The fold guard (mi_loop.fitting.guard): no step turns a control triangle over or flips a limit normal."""
from __future__ import annotations

import numpy as np

import mi_loop
from mi_loop.datasets import icosphere
from mi_loop.fitting.guard import FoldGuard
from mi_loop.mesh.geometry import face_normals


def _flat(V):
    import mitsuba as mi

    return mi.Float(np.asarray(V, dtype=np.float32).ravel())


def _setup():
    V, F = icosphere(2)
    V = V.astype(np.float32).astype(np.float64)
    op = mi_loop.LimitOperator(F, len(V), np.repeat(np.arange(len(F)), 3),
                               np.tile([[0.2, 0.2], [0.6, 0.2], [0.2, 0.6]], (len(F), 1)))
    return V, F, op


def test_a_step_that_would_turn_triangles_over_is_shortened_where_it_would():
    """Vertex 0 pushed through the sphere's centre, every other vertex shifted by (0.01, 0, 0):
    the step turns over no triangle, vertex 0 stops short, the vertices away from it take their whole step."""
    V, F, op = _setup()
    new = V + [0.01, 0.0, 0.0]
    new[0] = -0.5 * V[0]
    assert np.any(np.einsum("fd,fd->f", face_normals(new, F), face_normals(V, F)) <= 0)   # the step would fold
    guard = FoldGuard(op, F, V)
    taken = np.array(guard(_flat(V), _flat(new)), dtype=np.float64).reshape(-1, 3)
    assert np.all(np.einsum("fd,fd->f", face_normals(taken, F), face_normals(V, F)) > 0)
    assert np.linalg.norm(taken[0] - V[0]) < np.linalg.norm(new[0] - V[0])
    near = np.unique(F[np.any(F == 0, axis=1)])                     # vertex 0 and its one ring
    far = np.setdiff1d(np.arange(len(V)), near)
    np.testing.assert_array_equal(taken[far], new[far].astype(np.float32))
    assert guard.shortened == 1


def test_a_step_that_would_flip_limit_normals_is_shortened_until_none_flips():
    """Reference normals: the limit normals before the step. A dent pushed through the surface flips some;
    after the guard none that pointed along its reference points against it."""
    import drjit as dr

    V, F, op = _setup()
    N0 = np.array(op.normals(_flat(V)), dtype=np.float64).T
    new = V.copy()
    dent = np.flatnonzero(V[:, 2] > 0.8)
    new[dent] *= -0.2                                               # the cap pushed through to the other side
    with dr.suspend_grad():
        flipped = np.einsum("kd,kd->k", np.array(op.normals(_flat(new)), dtype=np.float64).T, N0) <= 0
    assert flipped.any()
    guard = FoldGuard(op, F, V, reference=N0)
    taken = guard(_flat(V), _flat(new))
    N = np.array(op.normals(taken), dtype=np.float64).T
    assert np.all(np.einsum("kd,kd->k", N, N0) > 0)
    assert guard.shortened == 1


def test_a_step_that_folds_nothing_is_taken_as_it_is():
    V, F, op = _setup()
    new = 1.1 * V + [0.02, -0.01, 0.0]
    N0 = np.array(op.normals(_flat(V)), dtype=np.float64).T
    guard = FoldGuard(op, F, V, reference=N0)
    taken = guard(_flat(V), _flat(new))
    np.testing.assert_array_equal(np.array(taken), np.array(_flat(new)))
    assert guard.shortened == 0 and guard.frozen == 0
