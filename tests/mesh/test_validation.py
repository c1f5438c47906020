"""Every input rejected at the public boundary, with the message checked."""
from __future__ import annotations

import numpy as np
import pytest

import mi_loop

TET_V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
TET_F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])


@pytest.mark.parametrize("V, F, match", [
    (np.zeros((0, 3)), TET_F, "no vertices"),
    (TET_V, np.zeros((0, 3), int), "no faces"),
    (TET_V, np.array([[0, 1, 2, 3]]), r"shape \(m, 3\) \(triangles only\)"),
    (TET_V[:, :2], TET_F, r"vertices must have shape \(n, 3\)"),
    (TET_V, np.array([[0, 1, 7]]), r"face 0 = \[0, 1, 7\] has an index outside \[0, 4\)"),
    (TET_V, np.array([[0, 1, 2], [0, -1, 2]]), r"face 1 = \[0, -1, 2\] has an index outside"),
    (np.where(np.arange(12).reshape(4, 3) == 5, np.nan, TET_V), TET_F, "vertex 1 has a non-finite"),
    (np.where(np.arange(12).reshape(4, 3) == 0, np.inf, TET_V), TET_F, "vertex 0 has a non-finite"),
    (TET_V, np.array([[0, 1, 1]]), r"face 0 = \[0, 1, 1\] is degenerate"),
    (TET_V, np.array([[0, 1, 2], [0, 1, 3]]), r"edge \(0, 1\) is used twice in the same direction"),
    (np.zeros((5, 3)), np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]), r"used twice|non-manifold"),
    (TET_V, np.array([[0, 1.5, 2]]), "face indices must be integers"),
])
def test_validate_mesh_rejects(V, F, match):
    with pytest.raises(ValueError, match=match):
        mi_loop.validate_mesh(V, F)


def test_non_manifold_edge_named():
    # Three faces on edge (0, 1) with consistent directions impossible: two share 0->1.
    F = np.array([[0, 1, 2], [1, 0, 3], [1, 0, 4]])
    with pytest.raises(ValueError, match=r"edge \(1, 0\) is used twice|non-manifold"):
        mi_loop.validate_mesh(np.random.rand(5, 3), F)


def test_non_manifold_vertex_named():
    # Two tetrahedra sharing only vertex 0: a bow-tie vertex.
    F = np.concatenate([TET_F, np.where(TET_F == 0, 0, TET_F + 3)])
    with pytest.raises(ValueError, match="vertex 0 is non-manifold .*2 separate fans"):
        mi_loop.validate_mesh(np.random.rand(7, 3), F)


def test_unreferenced_vertices_dropped_with_warning():
    V = np.concatenate([TET_V, [[9.0, 9, 9], [8, 8, 8]]])
    with pytest.warns(UserWarning, match="dropped 2 unreferenced vertices"):
        V2, F2, kept = mi_loop.validate_mesh(V, TET_F)
    np.testing.assert_array_equal(kept, [0, 1, 2, 3])
    np.testing.assert_array_equal(F2, TET_F)


def test_open_mesh_accepted():
    V, F, _ = mi_loop.validate_mesh(TET_V, TET_F[:3])
    assert len(F) == 3 and len(V) == 4


@pytest.mark.parametrize("creases, match", [
    (np.array([[0, 1, 2]]), r"shape \(c, 2\)"),
    (np.array([[0.0, 1.0]]), "integer array"),
    ((np.array([[0, 1]]), np.array([1.0, 2.0])), "1 crease edges but 2 sharpness"),
    ((np.array([[0, 1]]), np.array([0.0])), "sharpness 0.0; expected a positive integer or inf"),
    ((np.array([[0, 1]]), np.array([1.5])), "sharpness 1.5"),
    ((np.array([[0, 1]]), np.array([7.0])), "above 4 is not supported"),
    (np.array([[0, 9]]), r"crease 0 = \[0, 9\] is not a pair of distinct vertex indices"),
    (np.array([[1, 1]]), r"not a pair of distinct"),
])
def test_creases_rejected(creases, match):
    with pytest.raises(ValueError, match=match):
        mi_loop.subdivision_matrix(TET_F, 4, creases)


def test_crease_not_an_edge():
    F = np.array([[0, 1, 2], [0, 2, 3]])
    with pytest.raises(ValueError, match=r"crease 0 = \[1, 3\] is not an edge of the mesh"):
        mi_loop.limit_matrix(F, 4, np.array([0]), np.array([[0.1, 0.1]]), creases=np.array([[1, 3]]))


@pytest.mark.parametrize("face_ids, uv, match", [
    (np.array([4]), np.array([[0.1, 0.1]]), r"sample 0 has face id 4 outside \[0, 4\)"),
    (np.array([0, -1]), np.array([[0.1, 0.1]] * 2), "sample 1 has face id -1"),
    (np.array([0]), np.array([[0.7, 0.7]]), r"sample 0 has uv = \[0.7, 0.7\]; expected"),
    (np.array([0]), np.array([[-0.1, 0.2]]), "sample 0 has uv"),
    (np.array([0]), np.array([[np.nan, 0.2]]), "sample 0 has uv"),
    (np.array([0]), np.array([[0.1, 0.1, 0.1]]), r"uv must have shape \(1, 2\)"),
    (np.array([0.0]), np.array([[0.1, 0.1]]), "face_ids must be a 1-D integer array"),
])
def test_samples_rejected(face_ids, uv, match):
    with pytest.raises(ValueError, match=match):
        mi_loop.limit_matrix(TET_F, 4, face_ids, uv)


def test_derivative_name_rejected():
    with pytest.raises(ValueError, match="derivative must be None, 'u' or 'v', got 'w'"):
        mi_loop.limit_matrix(TET_F, 4, np.array([0]), np.array([[0.1, 0.1]]), derivative="w")


@pytest.mark.parametrize("level", [-1, 9, 2.5, True])
def test_tessellate_level_rejected(level):
    with pytest.raises(ValueError, match="level must be an integer in \\[0, 8\\]"):
        mi_loop.tessellate(TET_F, level)


def test_limit_positions_rejects_unused_vertices():
    V = np.concatenate([TET_V, [[5.0, 5, 5]]])
    with pytest.raises(ValueError, match="1 control vertices are not used"):
        mi_loop.limit_positions(V, TET_F)


def test_operator_rejects_wrong_control_points():
    import mitsuba as mi
    op = mi_loop.LimitOperator(TET_F, 4, np.array([0]), np.array([[0.2, 0.2]]))
    with pytest.raises(ValueError, match="expected 12 control coordinates .*got 9"):
        op.positions(mi.Float(np.zeros(9)))
    with pytest.raises(ValueError, match=r"expected a \(4, 3\) tensor"):
        op.positions(mi.TensorXf(np.zeros((3, 3))))
    with pytest.raises(TypeError, match="control points must be mi.Float"):
        op.positions([1.0, 2.0])
    op_p = mi_loop.LimitOperator(TET_F, 4, np.array([0]), np.array([[0.2, 0.2]]), derivatives=False)
    with pytest.raises(ValueError, match="built with derivatives=False"):
        op_p.evaluate(mi.Float(TET_V.ravel()))
