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
from mi_loop.mesh.topology import check_creases, validate_faces
from mi_loop.subdiv.irregular import build_local
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
        kind = topo.vertex_kind()
        val = topo.valence()
        reg = np.stack([corner_regular(topo, kind, val, F[:, c], F[:, (c + 1) % 3])
                        for c in range(3)], 1)
        n_irr = (~reg).sum(1)
        if (n_irr > 1).any():
            f = int(np.argmax(n_irr > 1))
            raise RuntimeError(f"Hierarchy(): internal error: face {f} = {F[f].tolist()} of level {len(self.S)} "
                               f"has {n_irr[f]} irregular corners; please report the control mesh")
        self.irr_corner = np.where(n_irr == 0, -1, np.argmax(~reg, axis=1))
        m = len(F)
        self.reg_P = np.zeros((m, 12), dtype=np.int64)
        self.reg_pid = np.zeros(m, dtype=np.int64)
        r = np.flatnonzero(self.irr_corner < 0)
        P = stam_points(topo, F[r, 0], F[r, 1], F[r, 2])
        self.reg_pid[r], self.Phis = phantom_matrices(P)
        self.reg_P[r] = np.maximum(P, 0)
        self._irregular_tables(kind)

    def _irregular_tables(self, kind):
        topo, mv = self.top, self.max_valence
        g = np.flatnonzero(self.irr_corner >= 0)
        rot = self.irr_corner[g]
        F = topo.F[g]
        r = np.arange(len(g))
        v, ri, rj = F[r, rot], F[r, (rot + 1) % 3], F[r, (rot + 2) % 3]
        P = irregular_points(topo, v, ri, rj, mv)
        ok = P >= 0
        sector = ok.copy()
        sector[:, 0] = False
        sector[:, 1 + 2 * mv:] = False
        sharp = np.zeros_like(ok)
        sharp[sector] = topo.edge_sharp(np.broadcast_to(v[:, None], P.shape)[sector], P[sector])
        sig_arr = np.concatenate([ok, sharp, kind[v][:, None] == np.arange(3)], 1)
        _, first, sig = np.unique(np.packbits(sig_arr, axis=1), axis=0,
                                  return_index=True, return_inverse=True)
        self.irr_sig = np.full(len(topo.F), -1, dtype=np.int64)
        self.irr_sig[g] = sig
        order = np.argsort(~ok, axis=1, kind="stable")  # present slots first, in order
        self.irr_P = np.zeros((len(topo.F), P.shape[1]), dtype=np.int64)
        self.irr_P[g] = np.maximum(np.take_along_axis(P, order, 1), 0)
        self.locals = []
        if len(g):
            S_next, fine = subdivide_topology(topo)
            self.locals = [build_local(topo, fine, S_next, g[i], rot[i], mv) for i in first]

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


def build_hierarchy(F, n_vertices, creases=None, func="limit_matrix") -> Hierarchy:
    """Validate and refine a control mesh until every face has one irregular corner at most.

    One step suffices without semi-sharp creases; with them, the mesh is
    refined until the largest finite sharpness has expired.

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
    F = validate_faces(F, n_vertices, func)
    cr = check_creases(creases, F, int(n_vertices), func)
    topo = Topology.build(F, int(n_vertices), cr)
    finite = topo.sharpness[np.isfinite(topo.sharpness)]
    n_levels = max(1, int(finite.max()) if len(finite) else 1)
    levels, Ss = [topo], []
    for _ in range(n_levels):
        S, topo = subdivide_topology(topo)
        Ss.append(S)
        levels.append(topo)
    return Hierarchy(levels, Ss, int(topo.valence().max()))
