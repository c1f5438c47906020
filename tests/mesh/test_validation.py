"""Mesh validation (mi_loop.mesh.topology): every mesh and crease input rejected, with the message checked."""
from __future__ import annotations

import numpy as np
import pytest

import mi_loop

from helpers import exactly
from meshes import TET_F, TET_V

NAN_V = np.where(np.arange(12).reshape(4, 3) == 5, np.nan, TET_V)
INF_V = np.where(np.arange(12).reshape(4, 3) == 0, np.inf, TET_V)
DOUBLE = "a closed two-triangle component, whose limit surface is flat and doubly covered and whose " \
         "refinement has double edges; remove it"


@pytest.mark.parametrize("V, F, message", [
    (np.zeros((0, 3)), TET_F, "expected vertices of shape (n, 3) with n > 0, got shape (0, 3)"),
    (TET_V[:, :2], TET_F, "expected vertices of shape (n, 3) with n > 0, got shape (4, 2)"),
    (np.array([["a", "b", "c"]]), TET_F, "expected numeric vertex coordinates, got dtype <U1"),
    (NAN_V, TET_F, "expected finite vertex coordinates, got vertex 1 = [1.0, -1.0, nan] (1 such vertices)"),
    (INF_V, TET_F, "expected finite vertex coordinates, got vertex 0 = [inf, 1.0, 1.0] (1 such vertices)"),
    (TET_V, np.zeros((0, 3), int), "expected faces of shape (m, 3) with m > 0 (triangles only), got shape (0, 3)"),
    (TET_V, np.array([[0, 1, 2, 3]]),
     "expected faces of shape (m, 3) with m > 0 (triangles only), got shape (1, 4)"),
    (TET_V, np.array([[0, 1.5, 2]]), "expected integer face indices, got dtype float64, face 0 = [0.0, 1.5, 2.0]"),
    (TET_V, np.array([[0, 1, 7]]), "expected face indices in [0, 4), got face 0 = [0, 1, 7]"),
    (TET_V, np.array([[0, 1, 2], [0, -1, 2]]), "expected face indices in [0, 4), got face 1 = [0, -1, 2]"),
    (TET_V, np.array([[0, 1, 1]]), "expected faces with three distinct vertices, got face 0 = [0, 1, 1] (degenerate)"),
    (TET_V, np.array([[0, 1, 2], [0, 1, 3]]),
     ("expected consistently oriented faces (each directed edge in one face), "
      "got edge (0, 1) used in the same direction by faces 0 and 1")),
    (np.zeros((5, 3)), np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]),
     "expected a manifold mesh (at most two faces per edge), got non-manifold edge (0, 1) shared by 3 faces (0, 1, 2)"),
    (TET_V[:3], np.array([[0, 1, 2], [0, 2, 1]]),
     f"expected no two faces on the same three vertices, got faces 0 = [0, 1, 2] and 1 = [0, 2, 1]: {DOUBLE}"),
])
def test_validate_mesh_rejects(V, F, message):
    with pytest.raises(ValueError, match=exactly("validate_mesh(): " + message)):
        mi_loop.validate_mesh(V, F)


def test_whole_float_faces_accepted():
    _, F, _ = mi_loop.validate_mesh(TET_V, TET_F.astype(float))
    assert F.dtype == np.int64
    np.testing.assert_array_equal(F, TET_F)


def test_caller_named_in_message():
    """The caller's name replaces validate_mesh; a CLI option is written without parentheses."""
    with pytest.raises(ValueError, match=exactly("fit(): expected face indices in [0, 4), got face 0 = [0, 1, 7]")):
        mi_loop.validate_mesh(TET_V, [[0, 1, 7]], "fit")
    with pytest.raises(ValueError, match=r"^fit --template: expected face indices"):
        mi_loop.validate_mesh(TET_V, [[0, 1, 7]], "fit --template")


def test_non_manifold_edge_named():
    """Three or more faces on an edge are reported as a non-manifold edge, never as an orientation error."""
    F = np.array([[0, 1, 2], [1, 0, 3], [1, 0, 4]])     # two of them share the direction 1 -> 0
    with pytest.raises(ValueError, match=exactly(
            "validate_mesh(): expected a manifold mesh (at most two faces per edge), "
            "got non-manifold edge (0, 1) shared by 3 faces (0, 1, 2)")):
        mi_loop.validate_mesh(np.random.rand(5, 3), F)
    # Four faces, consistently paired: no direction is used twice, but still non-manifold.
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [1, 0, 5], [7, 8, 9]])
    with pytest.raises(ValueError, match=exactly(
            "validate_mesh(): expected a manifold mesh (at most two faces per edge), "
            "got non-manifold edge (0, 1) shared by 4 faces (0, 1, 2, 3)")):
        mi_loop.validate_mesh(np.random.rand(10, 3), F)


def test_two_sided_bipyramid_is_non_manifold():
    """A 'bipyramid' over a 2-gon (two triangles glued to two others along one edge) is refused."""
    F = np.array([[0, 1, 2], [1, 0, 2], [1, 0, 3], [0, 1, 3]])
    with pytest.raises(ValueError, match=r"non-manifold edge \(0, 1\) shared by 4 faces \(0, 1, 2, 3\)"):
        mi_loop.validate_mesh(np.random.rand(4, 3), F)


def test_non_manifold_vertex_named():
    # Two tetrahedra sharing only vertex 0: a bow-tie vertex.
    F = np.concatenate([TET_F, np.where(TET_F == 0, 0, TET_F + 3)])
    with pytest.raises(ValueError, match=exactly(
            "validate_mesh(): expected a manifold mesh (the faces around each vertex form one fan), "
            "got non-manifold vertex 0, whose faces form 2 separate fans")):
        mi_loop.validate_mesh(np.random.rand(7, 3), F)


def test_double_face_component_named_inside_a_larger_mesh():
    """A two-triangle closed component next to a valid one is named by its faces."""
    F = np.concatenate([TET_F, [[4, 5, 6], [5, 4, 6]]])
    message = f"expected no two faces on the same three vertices, got faces 4 = [4, 5, 6] and 5 = [5, 4, 6]: {DOUBLE}"
    V = np.random.default_rng(0).random((7, 3))
    with pytest.raises(ValueError, match=exactly("validate_mesh(): " + message)):
        mi_loop.validate_mesh(V, F)
    for call, name in ((lambda: mi_loop.subdivision_matrix(F, 7), "subdivision_matrix"),
                       (lambda: mi_loop.limit_matrix(F, 7, [0], [[0.2, 0.2]]), "limit_matrix"),
                       (lambda: mi_loop.tessellate(F, 1), "tessellate"),
                       (lambda: mi_loop.limit_positions(V, F), "limit_positions"),
                       (lambda: mi_loop.limit_masks(F, 7), "limit_masks")):
        with pytest.raises(ValueError, match=exactly(f"{name}(): " + message)):
            call()


def test_unreferenced_vertices_dropped_with_warning():
    V = np.concatenate([TET_V, [[9.0, 9, 9], [8, 8, 8]]])
    with pytest.warns(UserWarning, match=exactly("validate_mesh(): dropped 2 unreferenced vertices")):
        V2, F2, kept = mi_loop.validate_mesh(V, TET_F)
    np.testing.assert_array_equal(kept, [0, 1, 2, 3])
    np.testing.assert_array_equal(F2, TET_F)
    np.testing.assert_array_equal(V2, TET_V)


def test_open_mesh_accepted():
    V, F, _ = mi_loop.validate_mesh(TET_V, TET_F[:3])
    assert len(F) == 3 and len(V) == 4


@pytest.mark.parametrize("creases, message", [
    (np.array([[0, 1, 2]]), "expected creases as an integer array of shape (c, 2), got int64 array of shape (1, 3)"),
    (np.array([[0.0, 1.0]]), "expected creases as an integer array of shape (c, 2), got float64 array of shape (1, 2)"),
    ((np.array([[0, 1]]), np.array([1.0, 2.0])), "expected one sharpness per crease edge (1), got 2 sharpness values"),
    ((np.array([[0, 1]]), np.array([-0.5])), "expected crease sharpness >= 0 (0 smooth, 10 or more or inf infinitely "
                                             "sharp), got sharpness -0.5 at crease 0"),
    ((np.array([[0, 1], [1, 2]]), np.array([1.0, np.nan])),
     "expected crease sharpness >= 0 (0 smooth, 10 or more or inf infinitely sharp), got sharpness nan at crease 1"),
    (np.array([[0, 9]]), "expected creases as pairs of distinct vertex indices in [0, 4), got crease 0 = [0, 9]"),
    (np.array([[0, 1], [1, 1]]),
     "expected creases as pairs of distinct vertex indices in [0, 4), got crease 1 = [1, 1]"),
])
def test_creases_rejected(creases, message):
    with pytest.raises(ValueError, match=exactly("subdivision_matrix(): " + message)):
        mi_loop.subdivision_matrix(TET_F, 4, creases)


@pytest.mark.parametrize("kwargs, message", [
    ({"corners": np.array([[0, 1]])}, "expected corners as a 1-D integer array of vertex ids, got int64 array of "
                                      "shape (1, 2)"),
    ({"corners": np.array([0.0])}, "expected corners as a 1-D integer array of vertex ids, got float64 array of "
                                   "shape (1,)"),
    ({"corners": ([0, 1], [2.0])}, "expected one sharpness per corner vertex (2), got 1 sharpness values"),
    ({"corners": ([0], [-1.0])}, "expected corner sharpness >= 0 (0 smooth, 10 or more or inf infinitely sharp), "
                                 "got sharpness -1.0 at corner 0"),
    ({"corners": [2, 4]}, "expected corner vertices in [0, 4), got vertex 4 at corner 1"),
    ({"boundary": "corner"}, "expected boundary one of 'edge_and_corner', 'edge_only', 'none', got 'corner'"),
    ({"crease_method": "CHAIKIN"}, "expected crease_method one of 'uniform', 'chaikin', got 'CHAIKIN'"),
])
def test_crease_model_rejected(kwargs, message):
    """Every rejected corner, boundary rule and crease method is named (subdivision and limit alike)."""
    with pytest.raises(ValueError, match=exactly("subdivision_matrix(): " + message)):
        mi_loop.subdivision_matrix(TET_F, 4, **kwargs)
    with pytest.raises(ValueError, match=exactly("limit_matrix(): " + message)):
        mi_loop.limit_matrix(TET_F, 4, np.array([0]), np.array([[0.2, 0.2]]), **kwargs)


def test_sharpness_of_ten_or_more_is_infinite():
    """OpenSubdiv's SHARPNESS_INFINITE: 10, 12.5 and inf give the same rows; 9.5 does not."""
    E = np.array([[0, 1]])
    S_inf, _ = mi_loop.subdivision_matrix(TET_F, 4, (E, [np.inf]))
    for s in (10.0, 12.5):
        S, _ = mi_loop.subdivision_matrix(TET_F, 4, (E, [s]))
        assert abs(S - S_inf).max() == 0
    S, _ = mi_loop.subdivision_matrix(TET_F, 4, (E, [9.5]))
    assert abs(S - S_inf).max() == 0          # one step: still a crease, but a semi-sharp one...
    from mi_loop.subdiv.hierarchy import build_hierarchy

    assert len(build_hierarchy(TET_F, 4, (E, [9.5])).S) == 10    # ...refined until it has decayed
    assert len(build_hierarchy(TET_F, 4, (E, [10.0])).S) == 1
