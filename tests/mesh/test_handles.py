"""Handle cutting (mi_loop.mesh.handles): the shortest non-separating loop on tori, cuts, errors."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop import datasets
from mi_loop.mesh.handles import cut_handles, shortest_handle_loop
from mi_loop.mesh.topology import validate_mesh

from helpers import genus


def torus(tube, n_around: int = 48, n_tube: int = 16, R: float = 1.0):
    """A closed torus mesh on an ``n_around x n_tube`` grid; ``tube(phi)`` is the tube's radius at angle ``phi``."""
    phi = 2 * np.pi * np.arange(n_around) / n_around
    theta = 2 * np.pi * np.arange(n_tube) / n_tube
    P, T = np.meshgrid(phi, theta, indexing="ij")
    r = tube(P)
    V = np.stack([(R + r * np.cos(T)) * np.cos(P), (R + r * np.cos(T)) * np.sin(P), r * np.sin(T)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_around), np.arange(n_tube), indexing="ij")
    a, b = i * n_tube + j, ((i + 1) % n_around) * n_tube + j
    c, d = ((i + 1) % n_around) * n_tube + (j + 1) % n_tube, i * n_tube + (j + 1) % n_tube
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return V, F


def test_the_shortest_handle_loop_of_a_torus_is_a_meridian():
    V, F = torus(lambda phi: np.full_like(phi, 0.3))
    loop, length = shortest_handle_loop(V, F)
    # a meridian is the regular 16-gon of radius 0.3: perimeter 2 n r sin(pi / n); a longitude is >= 2 pi 0.7
    assert length == pytest.approx(2 * 16 * 0.3 * np.sin(np.pi / 16), rel=1e-9)
    angles = np.arctan2(V[loop, 1], V[loop, 0])
    assert np.ptp(np.unwrap(angles)) < 1e-9                     # one angle around the axis: a meridian
    assert len(set(loop)) == len(loop) == 16


def test_the_shortest_handle_loop_is_where_the_tube_is_narrowest():
    """A contact is a short tube: the loop cut goes around its neck, not around the thick part."""
    def tube(phi):
        return 0.3 - 0.22 * np.exp(-(np.angle(np.exp(1j * (phi - 2.0))) / 0.2) ** 2)

    V, F = torus(tube, n_around=96)
    loop, length = shortest_handle_loop(V, F)
    angles = np.arctan2(V[loop, 1], V[loop, 0])
    assert np.ptp(np.unwrap(angles)) < 1e-9 and abs(angles[0] - 2.0) < 2 * np.pi / 96
    # the narrowest ring of the grid: a 16-gon of the tube's radius there
    narrowest = tube(2 * np.pi * np.arange(96) / 96).min()
    assert length == pytest.approx(2 * 16 * narrowest * np.sin(np.pi / 16), rel=1e-9)


def test_cut_handles_leaves_a_closed_manifold_of_the_genus_asked():
    V, F = torus(lambda phi: np.full_like(phi, 0.3))
    V2, F2, loops = cut_handles(V, F)
    validate_mesh(V2, F2)
    assert genus(V2, F2) == 0 and len(loops) == 1
    assert len(V2) == len(V) + 16 + 2                     # the loop's vertices split, one cap centre per side
    # the caps close the cut: the volume is that of the torus less the wedge the caps cut off (none here)
    assert abs(signed_volume(V2, F2) - signed_volume(V, F)) < 0.02 * signed_volume(V, F)
    V3, F3, loops = cut_handles(V, F, genus=1)             # already there: unchanged
    assert loops == [] and np.array_equal(F3, F)


def signed_volume(V, F) -> float:
    return float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6)


def test_handle_errors():
    V, F = datasets.icosphere(2)
    with pytest.raises(ValueError, match=r"^shortest_handle_loop\(\): expected a mesh of genus >= 1, got genus 0$"):
        shortest_handle_loop(V, F)
    with pytest.raises(ValueError, match=r"^shortest_handle_loop\(\): expected a closed mesh, got 3 boundary edges$"):
        shortest_handle_loop(V, F[1:])
    Vt, Ft = torus(lambda phi: np.full_like(phi, 0.3))
    with pytest.raises(ValueError, match=r"^cut_handles\(\): expected genus an integer >= 0, got -1$"):
        cut_handles(Vt, Ft, genus=-1)
    with pytest.raises(ValueError, match=r"^cut_handles\(\): expected a closed mesh, got 3 boundary edges$"):
        cut_handles(V, F[1:])
    with pytest.raises(ValueError, match=r"^cut_handles\(\): expected at most 0 handles to cut, got genus 1 down "
                                         r"to 0$"):
        cut_handles(Vt, Ft, max_cuts=0)
