"""Every input the subdivision layer rejects at its public boundary (limit_matrix, tessellate, masks), message checked.

Mesh and crease validation (validate_mesh, creases of subdivision_matrix) is in tests/mesh/test_validation.py.
"""
from __future__ import annotations

import numpy as np
import pytest

import mi_loop

from helpers import exactly
from meshes import TET_F, TET_V


def test_crease_not_an_edge():
    F = np.array([[0, 1, 2], [0, 2, 3]])
    with pytest.raises(ValueError, match=exactly(
            "limit_matrix(): expected crease edges that are edges of the mesh, got crease 0 = [1, 3]")):
        mi_loop.limit_matrix(F, 4, np.array([0]), np.array([[0.1, 0.1]]), creases=np.array([[1, 3]]))


@pytest.mark.parametrize("face_ids, uv, message", [
    (np.array([4]), np.array([[0.1, 0.1]]), "expected face ids in [0, 4), got face id 4 at sample 0"),
    (np.array([0, -1]), np.array([[0.1, 0.1]] * 2), "expected face ids in [0, 4), got face id -1 at sample 1"),
    (np.array([0]), np.array([[0.7, 0.7]]), "expected uv with u >= 0, v >= 0, u + v <= 1, got uv = [0.7, 0.7] at "
                                            "sample 0"),
    (np.array([0, 0]), np.array([[0.1, 0.1], [-0.1, 0.2]]),
     "expected uv with u >= 0, v >= 0, u + v <= 1, got uv = [-0.1, 0.2] at sample 1"),
    (np.array([0]), np.array([[np.nan, 0.2]]), "expected uv with u >= 0, v >= 0, u + v <= 1, got uv = [nan, 0.2] at "
                                               "sample 0"),
    (np.array([0]), np.array([[0.1, 0.1, 0.1]]), "expected uv of shape (1, 2) (one row per face id), got shape (1, 3)"),
    (np.array([0.0]), np.array([[0.1, 0.1]]), "expected face_ids as a 1-D integer array, got float64 array of shape "
                                              "(1,)"),
])
def test_samples_rejected(face_ids, uv, message):
    with pytest.raises(ValueError, match=exactly("limit_matrix(): " + message)):
        mi_loop.limit_matrix(TET_F, 4, face_ids, uv)


@pytest.mark.parametrize("derivative", ["w", (), (None, "w"), [None, ("u",)], ("uv",)])
def test_derivative_name_rejected(derivative):
    with pytest.raises(ValueError, match=exactly("limit_matrix(): expected derivative None, 'u' or 'v', or a "
                                                 f"non-empty tuple of them, got {derivative!r}")):
        mi_loop.limit_matrix(TET_F, 4, np.array([0]), np.array([[0.1, 0.1]]), derivative=derivative)


@pytest.mark.parametrize("derivatives, derivative, have", [
    (True, "w", "None, 'u' or 'v'"), (True, (), "None, 'u' or 'v'"),
    (False, "u", "None (built with derivatives=False)"), (False, (None, "v"), "None (built with derivatives=False)")])
def test_operator_matrix_derivative_rejected(derivatives, derivative, have):
    op = mi_loop.LimitOperator(TET_F, 4, np.array([0]), np.array([[0.1, 0.1]]), derivatives=derivatives)
    with pytest.raises(ValueError, match=exactly(f"LimitOperator.matrix(): expected derivative {have}, or a "
                                                 f"non-empty tuple of them, got {derivative!r}")):
        op.matrix(derivative)


def test_box_basis_derivative_rejected():
    from mi_loop.subdiv.boxspline import box_basis

    with pytest.raises(ValueError, match=exactly("box_basis(): expected derivative None, 'u' or 'v', got 'uv'")):
        box_basis(np.zeros((1, 2)), "uv")


@pytest.mark.parametrize("level", [-1, 9, 2.5, True])
def test_tessellate_level_rejected(level):
    with pytest.raises(ValueError, match=exactly(f"tessellate(): expected an integer level in [0, 8], got {level!r}")):
        mi_loop.tessellate(TET_F, level)


def test_vertex_functions_reject_unused_vertices():
    V = np.concatenate([TET_V, [[5.0, 5, 5]]])
    what = "expected every control vertex used by a face (mi_loop.validate_mesh drops the others), " \
           "got 1 unused vertices, the first vertex 4"
    with pytest.raises(ValueError, match=exactly("limit_positions(): " + what)):
        mi_loop.limit_positions(V, TET_F)
    with pytest.raises(ValueError, match=exactly("limit_normals(): " + what)):
        mi_loop.limit_normals(V, TET_F)
    with pytest.raises(ValueError, match=exactly("limit_masks(): " + what)):
        mi_loop.limit_masks(TET_F, 5)
    from mi_loop.subdiv.masks import tangent_masks

    with pytest.raises(ValueError, match=exactly("tangent_masks(): " + what)):
        tangent_masks(TET_F, 5)


def test_vertex_functions_reject_bad_control_points():
    from mi_loop.subdiv.masks import limit_mesh

    with pytest.raises(ValueError, match=exactly("limit_positions(): expected control points V of shape (n, 3) with n "
                                                 "> 0, "
                                                 "got shape (4, 2)")):
        mi_loop.limit_positions(TET_V[:, :2], TET_F)
    with pytest.raises(ValueError, match=exactly("limit_normals(): expected finite vertex coordinates, "
                                                 "got vertex 1 = [1.0, -1.0, nan] (1 such vertices)")):
        mi_loop.limit_normals(np.where(np.arange(12).reshape(4, 3) == 5, np.nan, TET_V), TET_F)
    with pytest.raises(ValueError, match=exactly("limit_mesh(): expected control points V of shape (n, 3), got shape "
                                                 "(12,)")):
        limit_mesh(TET_V.ravel(), TET_F)
