"""The fold guard (mi_loop.fitting.guard): no step turns a control triangle over, flips a limit normal or makes the
limit surface pass through itself."""
from __future__ import annotations

import numpy as np

import mi_loop
from mi_loop.datasets import icosphere
from mi_loop.fitting.guard import CrossingTest, FoldGuard
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


def _f32(V):
    """As the guard sees points: rounded to float32."""
    return np.asarray(V, dtype=np.float32).astype(np.float64)


def _two_spheres():
    """Two control spheres (radius 1), their centres 2.2 apart along x, with limit samples on both."""
    V, F = icosphere(2)
    V2 = _f32(np.r_[V, V + [2.2, 0.0, 0.0]])
    F2 = np.r_[F, F + len(V)]
    op = mi_loop.LimitOperator(F2, len(V2), np.arange(len(F2)), np.full((len(F2), 2), 1 / 3))
    return V2, F2, op, len(V)


def test_a_step_that_would_push_one_surface_through_another_is_stopped_where_they_would_cross():
    """The second sphere moved 0.4 towards the first: their limit surfaces would overlap (crossing pairs of the
    level-1 tessellation). With the crossing test the step leaves no crossing pair; the first sphere, which does
    not move, and the far side of the second are where the step put them."""
    V, F, op, half = _two_spheres()
    new = V.copy()
    new[half:, 0] -= 0.4
    test = CrossingTest(F, len(V), level=1)
    assert len(test.pairs(V)) == 0 and len(test.pairs(new)) > 0
    taken = np.array(FoldGuard(op, F, V, crossings=test)(_flat(V), _flat(new)), dtype=np.float64).reshape(-1, 3)
    assert len(test.pairs(taken)) == 0
    stopped = np.linalg.norm(taken - new.astype(np.float32), axis=1) > 1e-6
    assert stopped[half:].any() and not stopped[:half].any()
    far = np.flatnonzero(V[:, 0] > 2.7)                          # the second sphere's far cap: nowhere near the first
    np.testing.assert_array_equal(taken[far], new[far].astype(np.float32))
    # without the crossing test the same guard takes the step whole: it is the crossing test that stops it
    whole = np.array(FoldGuard(op, F, V)(_flat(V), _flat(new)), dtype=np.float64).reshape(-1, 3)
    np.testing.assert_array_equal(whole, new.astype(np.float32))


def test_crossings_there_before_the_step_may_stay_but_no_new_ones_are_made():
    """The spheres start overlapping; a step that moves the second one further in is shortened to make no
    crossing pair that was not there, and a step that moves it back out is taken whole."""
    V, F, op, half = _two_spheres()
    start = V.copy()
    start[half:, 0] -= 0.4                               # 0.2 deep into each other
    start = _f32(start)
    test = CrossingTest(F, len(V), level=1)
    before = test.pairs(start)
    assert len(before) > 0
    deeper = start.copy()
    deeper[half:, 0] -= 0.3
    guard = FoldGuard(op, F, V, crossings=test)
    taken = np.array(guard(_flat(start), _flat(deeper)), dtype=np.float64).reshape(-1, 3)
    assert np.all(np.isin(test.pairs(taken), before))
    assert guard.shortened + guard.refused == 1
    out = start.copy()
    out[half:, 0] += 0.3
    taken = np.array(guard(_flat(start), _flat(out)), dtype=np.float64).reshape(-1, 3)
    np.testing.assert_array_equal(taken, out.astype(np.float32))
    assert len(test.pairs(taken)) == 0


def test_the_crossing_test_keeps_its_candidates_only_while_they_cover_every_crossing():
    """Two spheres walked into each other in small random steps: at every step the crossing pairs are
    those of a full test of the limit tessellation (crossing_pairs), less the pairs whose control faces
    share a corner, although the candidates are found anew only now and then."""
    from mi_loop.mesh.crossings import crossing_pairs

    V, F, _, half = _two_spheres()
    test = CrossingTest(F, len(V))
    G, F_t = test.groups[0], test.F_t
    rng = np.random.default_rng(1)
    X = V.copy()
    for _ in range(40):
        X = X + rng.normal(scale=0.004, size=X.shape)
        X[half:, 0] -= 0.01                               # 0.4 in all: 0.2 deep into each other at the end
        full = crossing_pairs(test.P @ X, F_t)
        far = ~np.array([np.isin(F[G[i]], F[G[j]]).any() for i, j in full], dtype=bool)
        expected = full[far] if len(full) else full
        np.testing.assert_array_equal(np.sort(test.pairs(X)), np.sort(expected[:, 0] * len(F_t) + expected[:, 1]))
    assert len(expected) > 0
    assert 1 < test.refreshes < 40
