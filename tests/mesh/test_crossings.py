"""Crossing triangles (mi_loop.mesh.crossings): hand-built pairs, and MeshLab's self-intersection test as the oracle."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop.datasets import icosphere
from mi_loop.mesh.crossings import crossing_faces, crossing_pairs
from mi_loop.metrics import self_intersections

TRIANGLE = [[0.0, 0, 0], [2, 0, 0], [0, 2, 0]]


@pytest.mark.parametrize("other, crosses", [
    ([[0.5, 0.5, -1], [0.5, 0.5, 1], [1.5, 1.5, 0]], True),      # an edge pierces the inside
    ([[3.0, 3, -1], [3, 3, 1], [4, 4, 0]], False),              # beside it
    ([[0.5, 0.5, 0], [0.5, 0.5, 1], [1.5, 1.5, 1]], False),      # a corner touches it
    ([[0.2, 0.2, 0], [0.9, 0.2, 0], [0.2, 0.9, 0]], False),      # inside it, in its plane
    ([[1.5, 1.5, -1], [1.5, 1.5, 1], [2.5, 2.5, 0]], False),     # through its plane, outside its hypotenuse
    ([[-1.0, 0.5, 0.5], [3, 0.5, 0.5], [1, 0.5, -0.5]], True),   # a triangle through it that no edge of its own pierces
])
def test_two_triangles_cross_where_an_edge_passes_through_the_inside(other, crosses):
    V = np.array(TRIANGLE + other)
    F = np.array([[0, 1, 2], [3, 4, 5]])
    assert crossing_pairs(V, F).tolist() == ([[0, 1]] if crosses else [])
    assert crossing_faces(V, F).tolist() == [crosses, crosses]


def test_triangles_that_share_a_corner_are_left_out():
    """A fan that turned through itself shares a corner: MeshLab counts it, the crossing test leaves it to the
    guard's normal tests."""
    V = np.array(TRIANGLE + [[0.5, 0.5, -1], [1.5, 1.5, 1]])
    F = np.array([[0, 1, 2], [0, 3, 4]])
    assert self_intersections(V, F).tolist() == [True, True]
    assert crossing_pairs(V, F).tolist() == []


@pytest.mark.parametrize("shift", [0.3, 1.0, 1.7, 1.99, 2.5])
def test_two_spheres_cross_where_meshlab_says_they_intersect(shift):
    """Two icospheres (radius 1) at a distance: no triangle of one shares a corner with one of the other, so
    the crossing faces are MeshLab's self-intersecting faces, triangle by triangle."""
    V, F = icosphere(3)
    rng = np.random.default_rng(0)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]               # the second sphere turned: no symmetric ties
    V2, F2 = np.r_[V, V @ R.T + [shift, 0.03, 0.01]], np.r_[F, F + len(V)]
    expected = self_intersections(V2, F2)
    assert expected.any() == (shift < 2.0)
    np.testing.assert_array_equal(crossing_faces(V2, F2), expected)
    pairs = crossing_pairs(V2, F2)
    assert np.all(pairs[:, 0] < len(F)) and np.all(pairs[:, 1] >= len(F))      # always one of each sphere
    assert len(np.unique(pairs, axis=0)) == len(pairs)


def test_a_closed_surface_that_passes_through_itself_is_found_and_one_that_does_not_is_clean():
    """A sphere with its cap pushed through the far side crosses near the far side; the sphere alone does not."""
    V, F = icosphere(3)
    assert not crossing_faces(V, F).any()
    dented = V.copy()
    cap = V[:, 2] > 0.7
    dented[cap, 2] -= 1.8                       # the cap pushed down through the bottom
    crossed = crossing_faces(dented, F)
    assert crossed.any()
    np.testing.assert_array_equal(crossed & ~self_intersections(dented, F), False)


@pytest.mark.parametrize("V, F, message", [
    (np.zeros((3, 2)), np.array([[0, 1, 2]]), r"crossing_pairs\(\): expected mesh vertices of shape \(n, 3\)"),
    (np.zeros((3, 3)), np.array([[0, 1, 3]]), r"crossing_pairs\(\): expected mesh face indices in \[0, 3\), "
                                              r"got face 0 = \[0, 1, 3\]"),
    (np.full((3, 3), np.nan), np.array([[0, 1, 2]]),
     r"crossing_pairs\(\): expected finite mesh vertices, got vertex 0"),
])
def test_a_malformed_mesh_is_refused_with_the_function_named(V, F, message):
    with pytest.raises(ValueError, match=message):
        crossing_pairs(V, F)


def test_near_pairs_are_the_pairs_whose_boxes_come_within_the_reach():
    """Against all pairs of a sphere's triangles, boxes compared one by one."""
    from mi_loop.mesh.crossings import near_pairs

    V, F = icosphere(2)
    lo, hi = V[F].min(axis=1), V[F].max(axis=1)
    for reach in (0.0, 0.05, 0.2):
        gap = np.maximum(lo[:, None] - hi[None], lo[None] - hi[:, None]).max(axis=2)     # largest axis gap
        shared = (F[:, None, :, None] == F[None, :, None, :]).any(axis=(2, 3))
        i, j = np.nonzero(np.triu((gap <= reach) & ~shared, 1))
        np.testing.assert_array_equal(near_pairs(V, F, reach), np.stack([i, j], axis=1))


def test_near_pairs_leave_out_pairs_whose_groups_share_a_corner():
    from mi_loop.mesh.crossings import near_pairs

    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0.1], [1, 0, 0.1], [0, 1, 0.1]])
    F = np.array([[0, 1, 2], [3, 4, 5]])
    assert near_pairs(V, F, 0.2).tolist() == [[0, 1]]
    assert near_pairs(V, F, 0.2, groups=(np.array([0, 1]), np.array([[0, 1, 2], [2, 3, 4]]))).tolist() == []
    assert near_pairs(V, F, 0.2, groups=(np.array([0, 1]), np.array([[0, 1, 2], [3, 4, 5]]))).tolist() == [[0, 1]]


@pytest.mark.parametrize("reach, groups, message", [
    (-1.0, None, "near_pairs(): expected a finite reach >= 0, got -1.0"),
    (np.nan, None, "near_pairs(): expected a finite reach >= 0, got nan"),
    (0.1, (np.array([0]), np.array([[0, 1, 2]])),
     "near_pairs(): expected groups (group, G): group of shape (2,) indexing the faces G (g, 3), got group of "
     "shape (1,) and G of shape (1, 3)"),
    (0.1, (np.array([0, 2]), np.array([[0, 1, 2]])),
     "near_pairs(): expected groups (group, G): group of shape (2,) indexing the faces G (g, 3), got group of "
     "shape (2,) and G of shape (1, 3)"),
])
def test_near_pairs_refuse_a_bad_reach_or_groups(reach, groups, message):
    from mi_loop.mesh.crossings import near_pairs

    V = np.array(TRIANGLE + [[0.0, 0, 1], [1, 0, 1], [0, 1, 1]])
    with pytest.raises(ValueError) as err:
        near_pairs(V, np.array([[0, 1, 2], [3, 4, 5]]), reach, groups)
    assert str(err.value) == message
