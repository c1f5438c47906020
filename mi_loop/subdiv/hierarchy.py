"""The subdivision hierarchy that exact limit evaluation stands on (NumPy/SciPy).

The control mesh is subdivided ``L`` times (once, or until semi-sharp creases
have expired) so that every face has at most one irregular corner: after one
step every new vertex is regular (valence 6 inside, a crease vertex with two
3-face sectors on a crease or boundary) and every child face holds at most one
old vertex. The finest level's per-face patch tables are built once, for
:mod:`mi_loop.subdiv.limit`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from mi_loop.mesh.halfedge import Topology
from mi_loop.mesh.topology import sharp_topology
from mi_loop.subdiv.irregular import build_locals
from mi_loop.subdiv.patches import (
    corner_regular,
    irregular_points,
    phantom_matrices,
    stam_points,
)
from mi_loop.subdiv.subdivision import subdivide_topology

__all__ = ["Hierarchy", "build_hierarchy"]


@dataclass
class Hierarchy:
    """Control mesh refined until every face has one irregular corner at most.

    Per-face patch tables at the finest level are built once: regular faces
    keep their 12 box-spline points and phantom pattern, irregular faces their
    rotation, local-configuration id and patch points. Build it with
    :func:`build_hierarchy`, which validates the mesh.

    Parameters
    ----------
    levels : list of :class:`~mi_loop.mesh.halfedge.Topology`
        Topology of levels ``0 .. L`` (level 0 is the control mesh).
    S : list of scipy.sparse.csr_matrix
        ``S[l]`` of shape ``(n_{l+1}, n_l)`` maps level ``l`` to ``l + 1``.
    max_valence : int
        Largest valence at level ``L`` (pads the irregular patch tables).

    Attributes
    ----------
    irr_corner : (m_L,) int64
        Irregular corner (0, 1, 2) of every level-``L`` face, -1 for a regular face.
    reg_P, reg_pid : (m_L, 12) int64, (m_L,) int64
        Box-spline points (phantoms as 0) and phantom pattern of regular faces.
    Phis : (p, 12, 12) float64
        Phantom matrix of every pattern (see :func:`~mi_loop.subdiv.patches.phantom_matrices`).
    phantom : (m_L,) bool
        Regular face whose phantom matrix is not the identity.
    irr_sig, irr_P : (m_L,) int64, (m_L, 1 + 2 max_valence + 5) int64
        Local configuration (index into ``locals``, -1 for regular faces) and
        present patch points (padded with 0) of irregular faces.
    irr_K : (m_L,) int64
        Number of patch points of irregular faces (0 for regular faces).
    locals : list of :class:`~mi_loop.subdiv.irregular.LocalMatrices`
        One per local configuration.
    face_P : (m_L, max(12, 1 + 2 max_valence + 5)) int32
        Patch points of every face (``reg_P`` or ``irr_P``, padded with 0).

    Raises
    ------
    RuntimeError
        If a face at level ``L`` has two irregular corners; never for a mesh
        that :func:`~mi_loop.mesh.topology.validate_faces` accepts (an
        internal error).
    """

    levels: list          # Topology per level 0..L
    S: list               # S[l] maps level l -> l + 1
    max_valence: int

    def __post_init__(self):
        topo = self.top
        F = topo.F
        m = len(F)
        kind = topo.vertex_kind()
        reg = corner_regular(topo, kind, topo.valence(), np.arange(3 * m)).reshape(m, 3)
        n_irr = (~reg).sum(1)
        if (n_irr > 1).any():
            f = int(np.argmax(n_irr > 1))
            raise RuntimeError(f"Hierarchy(): internal error: face {f} = {F[f].tolist()} of level {len(self.S)} "
                               f"has {n_irr[f]} irregular corners; please report the control mesh")
        self.irr_corner = np.where(n_irr == 0, -1, np.argmax(~reg, axis=1))
        self.reg_P = np.zeros((m, 12), dtype=np.int64)
        self.reg_pid = np.zeros(m, dtype=np.int64)
        r = np.flatnonzero(self.irr_corner < 0)
        P = stam_points(topo, 3 * r)
        self.reg_pid[r], self.Phis = phantom_matrices(P)
        self.reg_P[r] = np.maximum(P, 0)
        identity = np.array([np.array_equal(Phi, np.eye(12)) for Phi in self.Phis])
        self.phantom = np.zeros(m, dtype=bool)
        self.phantom[r] = ~identity[self.reg_pid[r]]
        self._irregular_tables(kind)
        self.face_P = np.zeros((m, max(12, self.irr_P.shape[1])), dtype=np.int32)
        self.face_P[r, :12] = self.reg_P[r]
        g = np.flatnonzero(self.irr_corner >= 0)
        self.face_P[g, :self.irr_P.shape[1]] = self.irr_P[g]

    def _irregular_tables(self, kind):
        topo, mv = self.top, self.max_valence
        g = np.flatnonzero(self.irr_corner >= 0)
        rot = self.irr_corner[g]
        P, sharp = irregular_points(topo, 3 * g + rot, mv)
        ok = P >= 0
        sig_arr = np.concatenate([ok, sharp, kind[P[:, 0]][:, None] == np.arange(3)], 1)
        first, sig = _group_rows(sig_arr)
        self.irr_sig = np.full(len(topo.F), -1, dtype=np.int64)
        self.irr_sig[g] = sig
        order = np.argsort(~ok, axis=1, kind="stable")  # present slots first, in order
        self.irr_P = np.zeros((len(topo.F), P.shape[1]), dtype=np.int64)
        self.irr_P[g] = np.maximum(np.take_along_axis(P, order, 1), 0)
        self.irr_K = np.zeros(len(topo.F), dtype=np.int64)
        self.irr_K[g] = ok.sum(1)
        self.locals = build_locals(topo, g[first], rot[first], mv)

    @property
    def top(self) -> Topology:
        """Topology of the finest level ``L``."""
        return self.levels[-1]

    def composed(self) -> sp.csr_matrix:
        """Return the composed subdivision matrix ``S_L = S[L-1] @ ... @ S[0]``.

        Returns
        -------
        scipy.sparse.csr_matrix, shape ``(n_L, n_0)``, float64
        """
        M = self.S[0]
        for S in self.S[1:]:
            M = S @ M
        return M.tocsr()


def _group_rows(bits: np.ndarray):
    """Distinct rows of a bool array in lexicographic order: first occurrences ``(u,)`` and group of every row.

    As ``np.unique(np.packbits(bits, axis=1), axis=0, return_index=True,
    return_inverse=True)``, with the packed rows read as big-endian 64-bit
    words so that the sort is on a few integer columns.
    """
    packed = np.packbits(bits, axis=1)
    words = np.zeros((len(bits), -(-packed.shape[1] // 8) * 8), dtype=np.uint8)
    words[:, :packed.shape[1]] = packed
    words = words.view(">u8")
    order = np.lexsort(words.T[::-1])                # stable: first occurrences lead their groups
    ranked = words[order]
    new = np.ones(len(bits), dtype=bool)
    new[1:] = (ranked[1:] != ranked[:-1]).any(1)
    group = np.empty(len(bits), dtype=np.int64)
    group[order] = np.cumsum(new) - 1
    return order[new], group


def build_hierarchy(F, n_vertices, creases=None, func="limit_matrix", *, corners=None,
                    boundary="edge_and_corner", crease_method="uniform") -> Hierarchy:
    """Validate and refine a control mesh until every face has one irregular corner at most.

    One step suffices without semi-sharp creases or corners; with them, the
    mesh is refined until the largest finite sharpness has expired
    (``ceil(s)`` steps: both crease methods lower the largest sharpness by at
    least one a step).

    Parameters
    ----------
    F : (m, 3) int array_like
        Control faces.
    n_vertices : int
        Number of control vertices.
    creases : None, (c, 2) int numpy array, or tuple ``(E, sharpness)``
        See :func:`mi_loop.subdivision_matrix`.
    func : str, optional
        Name of the calling public function, for messages.
    corners, boundary, crease_method : optional
        The rest of the crease model, see :func:`mi_loop.subdivision_matrix`.

    Returns
    -------
    Hierarchy

    Raises
    ------
    ValueError
        Invalid mesh or creases (see :func:`~mi_loop.mesh.topology.validate_faces`).

    Examples
    --------
    >>> F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> h = build_hierarchy(F, 4)
    >>> len(h.S), h.top.n, h.composed().shape
    (1, 10, (10, 4))
    """
    topo = sharp_topology(F, n_vertices, func, creases, corners, boundary, crease_method)
    s = np.concatenate([topo.sharpness, topo.vertex_sharpness])
    finite = s[np.isfinite(s)]
    n_levels = max(1, int(np.ceil(finite.max())) if len(finite) else 1)
    levels, Ss = [topo], []
    for _ in range(n_levels):
        S, topo = subdivide_topology(topo)
        Ss.append(S)
        levels.append(topo)
    return Hierarchy(levels, Ss, int(topo.valence().max()))
