"""No step folds the surface: the fold guard of the fitting loop's steps.

A barrier (:class:`~mi_loop.fitting.terms.Fold`) makes folding expensive; the
guard makes it impossible step by step. A step from ``old`` to ``new`` is
shortened where it folds: the step of every control point in the way is
halved, ``old_i + s_i (new_i - old_i)``, until the step

- turns over no control triangle that was not turned over before: a triangle
  is turned over when its normal points against its rest normal rotated by its
  ARAP rotation (the sum of its three vertices' ARAP rotations to the rest
  shape, at ``old``), and
- flips no limit normal that was not flipped before: a limit normal is
  flipped when it points against the sample's reference normal (in a
  sequence: the previous frame's limit normal), and
- (with a :class:`CrossingTest`) makes the limit surface pass through itself
  nowhere it did not before: no new pair of crossing triangles in a
  tessellation of the limit surface.

The points in the way are the corners of the turned triangles and the
control points a flipped normal depends on (its row of the limit operator);
the control points of a new crossing pair of limit triangles stop at once (a
crossing is no shallower for a shorter step).
Elsewhere the step is taken in full: one folding corner does not stop the
rest of the surface. After ``halvings`` halvings the points still in the way
do not move at all; at the old points nothing was turned over, so the step
then folds nothing new. What was already folded (or within ``margin`` of it)
may stay so (a template can start with folds; the barrier and the data work
on them).
"""
from __future__ import annotations

import numpy as np

__all__ = ["CROSSING_LEVEL", "CrossingTest", "FoldGuard", "hold_apart"]

CROSSING_LEVEL = 2
"""Tessellation level of the crossing test: 16 limit triangles per control face."""


class CrossingTest:
    """Where a control mesh's limit surface passes through itself: crossing triangles of a tessellation of it.

    Pairs of limit triangles whose control faces share a corner are left out:
    a fold that close turns normals, which the guard's other tests watch.

    Parameters
    ----------
    F : (m, 3) int NumPy array
        Control faces.
    n_vertices : int
        Number of control points.
    level : int, optional
        Tessellation level of the limit surface (4**level triangles per control face). At level 1
        the tessellation's chords miss crossings of thin slits that level 2 finds (D-FAUST's armpits:
        BENCHMARKS.md).
    creases : optional
        The control mesh's creases, as in :func:`mi_loop.subdivision_matrix`.

    Attributes
    ----------
    refreshes : int
        How often the candidate pairs were found anew.

    Notes
    -----
    The candidates (:func:`~mi_loop.mesh.crossings.near_pairs`) are the pairs
    whose bounding boxes come within a reach ``r`` (the median limit
    triangle's side) and are kept until some control point has moved ``r / 2``
    from where they were found. Loop's limit stencils are convex combinations,
    so no limit point has moved farther, and no other pair can have met.

    Examples
    --------
    Two spheres pushed into each other cross; apart, they do not:

    >>> import numpy as np
    >>> from mi_loop.datasets import icosphere
    >>> V, F = icosphere(1)
    >>> test = CrossingTest(np.r_[F, F + len(V)], 2 * len(V))
    >>> apart, overlapping = np.r_[V, V + [3, 0, 0]], np.r_[V, V + [1, 0, 0]]
    >>> len(test.pairs(apart)), len(test.pairs(overlapping)) > 0
    (0, True)
    """

    def __init__(self, F, n_vertices: int, level: int = CROSSING_LEVEL, creases=None):
        from mi_loop.subdiv.masks import limit_matrix
        from mi_loop.subdiv.tessellation import tessellate

        F = np.asarray(F, dtype=np.int64)
        face_ids, uv, self.F_t = tessellate(F, level)
        self.P = limit_matrix(F, n_vertices, face_ids, uv, creases=creases).tocsr()
        self.groups = (np.arange(len(self.F_t)) // 4 ** level, F)
        self._near = self._found_at = None       # the candidate pairs, and the control points they were found at
        self._reach = 0.0
        self.refreshes = 0

    def pairs(self, V) -> np.ndarray:
        """Crossing pairs of limit triangles at control points ``V`` ((n, 3) NumPy), each encoded as ``i m + j``."""
        from mi_loop.mesh.crossings import crossing_among, near_pairs

        V = np.asarray(V, dtype=np.float64)
        Q = self.P @ V
        if self._found_at is None or np.max(np.linalg.norm(V - self._found_at, axis=1)) >= 0.5 * self._reach:
            self._reach = float(np.median(np.ptp(Q[self.F_t], axis=1).max(axis=1)))
            self._near = near_pairs(Q, self.F_t, self._reach, self.groups)
            self._found_at = V.copy()
            self.refreshes += 1
        ij = crossing_among(Q, self.F_t, self._near)
        return ij[:, 0] * len(self.F_t) + ij[:, 1]

    def culprits(self, V, before) -> tuple[np.ndarray, np.ndarray]:
        """The crossing pairs at ``V`` and the control points of those not among ``before`` (:meth:`pairs`)."""
        now = self.pairs(V)
        new = now[~np.isin(now, before)]
        faces = np.unique(np.r_[new // len(self.F_t), new % len(self.F_t)])
        return now, np.unique(self.P[self.F_t[faces].ravel()].indices)


def hold_apart(test: CrossingTest, old, new, rounds: int = 8) -> np.ndarray:
    """Put the control points of a step that make the limit surface cross itself anew back where they were.

    Parameters
    ----------
    test : CrossingTest
        The crossing test.
    old, new : (n, 3) float NumPy arrays
        Control points before and after the step.
    rounds : int, optional
        Most rounds: putting some points back can make others cross.

    Returns
    -------
    (n, 3) float64 NumPy array
        ``new``, where the points of every crossing pair of limit triangles
        that ``old`` did not have are ``old``'s; ``old`` itself if
        ``rounds`` were not enough.
    """
    old, V = np.asarray(old, dtype=np.float64), np.array(new, dtype=np.float64)
    before = test.pairs(old)
    for _ in range(rounds):
        culprits = test.culprits(V, before)[1]
        if len(culprits) == 0:
            return V
        V[culprits] = old[culprits]
    return old.copy()


class FoldGuard:
    """Shorten steps of the control points until they fold nothing new (module docstring).

    Parameters
    ----------
    op : LimitOperator
        Samples whose limit normals are watched (with derivatives).
    F : (m, 3) int NumPy array
        Control faces.
    rest : (n, 3) float NumPy array
        Rest shape of the control mesh (the template).
    reference : (k, 3) float NumPy array or None
        Reference normal at every sample of ``op`` (None: no limit-normal test).
    halvings : int
        Most halvings of a step.
    margin : float
        Only normals whose cosine to their reference exceeds it before the
        step are kept from turning over (a normal at 90 degrees already is
        on the edge of a fold: any step may tip it).
    crossings : CrossingTest or None
        Also keep the limit surface from passing through itself anew.

    Attributes
    ----------
    shortened : int
        Steps shortened somewhere so far.
    frozen : int
        Control points kept where they were by those steps (summed over steps).
    refused : int
        Steps not taken at all (stopping the points in the way tipped others).

    Examples
    --------
    A step that pushes a vertex of a sphere through its centre turns over its five triangles; half of it does not:

    >>> import numpy as np, mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> from mi_loop.datasets import icosphere
    >>> V, F = icosphere(1)
    >>> op = mi_loop.LimitOperator(F, len(V), np.arange(len(F)), np.full((len(F), 2), 1 / 3))
    >>> guard = FoldGuard(op, F, V)
    >>> new = V.copy(); new[0] = -0.5 * V[0]          # vertex 0 pushed through the sphere's centre
    >>> x = guard(mi.Float(V.ravel().astype(np.float32)), mi.Float(new.ravel().astype(np.float32)))
    >>> guard.shortened, np.allclose(x.numpy().reshape(-1, 3)[0], 0.25 * V[0], atol=1e-6)
    (1, True)
    """

    def __init__(self, op, F, rest, reference=None, halvings: int = 10, margin: float = 0.1, crossings=None):
        from mi_loop.energies.arap import ARAP
        from mi_loop.mesh.geometry import face_normals

        self.op, self.F = op, np.asarray(F, dtype=np.int64)
        self.arap = ARAP(np.asarray(rest, dtype=np.float64), self.F)
        self.rest_normals = face_normals(np.asarray(rest, dtype=np.float64), self.F)
        self.reference = None if reference is None else np.asarray(reference, dtype=np.float64)
        self.halvings, self.margin = int(halvings), float(margin)
        self.crossings = crossings
        self._last = None            # the step taken last, its limit normals' cosines and crossing pairs
        self.shortened = self.frozen = self.refused = 0

    def _limit_cosines(self, x):
        import drjit as dr

        if self.reference is None:
            return None
        with dr.suspend_grad():
            N = np.array(self.op.normals(x), dtype=np.float64).T
        return np.einsum("kd,kd->k", N, self.reference)

    def _face_cosines(self, V, ref):
        from mi_loop.mesh.geometry import face_normals

        return np.einsum("fd,fd->f", face_normals(V, self.F), ref)

    def __call__(self, old, new):
        """The step actually taken from ``old`` to ``new`` (flat ``mi.Float (3n)``, xyz interleaved)."""
        import drjit as dr

        V0 = np.array(old, dtype=np.float64).reshape(-1, 3)
        R = self.arap.rotations(V0)
        Rf = R[self.F[:, 0]] + R[self.F[:, 1]] + R[self.F[:, 2]]
        ref = np.einsum("fab,fb->fa", Rf, self.rest_normals)          # rest normals, rotated
        ref /= np.maximum(np.linalg.norm(ref, axis=1, keepdims=True), 1e-300)
        faces0 = self._face_cosines(V0, ref) > self.margin               # what the step must not turn over
        # the limit normals at old: those of the step taken last, if old is it
        cached = self._last is not None and self._last[0] is old
        limit0 = self._last[1] if cached else self._limit_cosines(old)
        if limit0 is not None:
            limit0 = limit0 > self.margin * np.linalg.norm(self.reference, axis=1)
        crossed0 = None
        if self.crossings is not None:
            crossed0 = self._last[2] if cached and self._last[2] is not None else self.crossings.pairs(V0)
        D = np.array(new, dtype=np.float64).reshape(-1, 3) - V0
        s = np.ones(len(V0))
        for k in range(self.halvings + 2):
            x = new if k == 0 else type(old)((V0 + s[:, None] * D).astype(np.float32).ravel())
            V = np.array(x, dtype=np.float64).reshape(-1, 3)
            moved = self.F[faces0 & (self._face_cosines(V, ref) <= 0)].ravel()
            cosines = crossed = None
            if limit0 is not None:
                cosines = self._limit_cosines(x)
                bad = np.flatnonzero(limit0 & (cosines <= 0))
                if len(bad):
                    moved = np.r_[moved, self.op.positions_matrix()[bad].indices]
            stop = np.zeros(0, dtype=np.int64)
            if crossed0 is not None:     # a crossing is not shallower for a shorter step: its culprits stay put
                crossed, stop = self.crossings.culprits(V, crossed0)
            if len(moved) == 0 and len(stop) == 0:
                self.shortened += k > 0
                self.frozen += int(np.sum(s == 0))
                dr.eval(x)
                self._last = (x, cosines, crossed)
                return x
            # shorten the step where it folds: the vertices of the turned triangles and the supports of the flipped
            # normals and of the new crossings (their last halving stops them: at the old points none of it was so)
            s[np.unique(moved)] *= 0.5 if k < self.halvings else 0.0
            s[stop] = 0.0
        self.refused += 1           # stopping the culprits tipped their neighbours: no step this time
        return old
