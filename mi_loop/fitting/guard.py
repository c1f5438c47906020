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
  sequence: the previous frame's limit normal).

The points in the way are the corners of the turned triangles and the
control points a flipped normal depends on (its row of the limit operator).
Elsewhere the step is taken in full: one folding corner does not stop the
rest of the surface. After ``halvings`` halvings the points still in the way
do not move at all; at the old points nothing was turned over, so the step
then folds nothing new. What was already folded (or within ``margin`` of it)
may stay so (a template can start with folds; the barrier and the data work
on them).
"""
from __future__ import annotations

import numpy as np

__all__ = ["FoldGuard"]


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

    def __init__(self, op, F, rest, reference=None, halvings: int = 10, margin: float = 0.1):
        from mi_loop.energies.arap import ARAP
        from mi_loop.mesh.geometry import face_normals

        self.op, self.F = op, np.asarray(F, dtype=np.int64)
        self.arap = ARAP(np.asarray(rest, dtype=np.float64), self.F)
        self.rest_normals = face_normals(np.asarray(rest, dtype=np.float64), self.F)
        self.reference = None if reference is None else np.asarray(reference, dtype=np.float64)
        self.halvings, self.margin = int(halvings), float(margin)
        self._last = None            # the step taken last and its limit normals' cosines
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
        limit0 = self._last[1] if self._last is not None and self._last[0] is old else self._limit_cosines(old)
        if limit0 is not None:
            limit0 = limit0 > self.margin * np.linalg.norm(self.reference, axis=1)
        D = np.array(new, dtype=np.float64).reshape(-1, 3) - V0
        s = np.ones(len(V0))
        for k in range(self.halvings + 2):
            x = new if k == 0 else type(old)((V0 + s[:, None] * D).astype(np.float32).ravel())
            V = np.array(x, dtype=np.float64).reshape(-1, 3)
            moved = self.F[faces0 & (self._face_cosines(V, ref) <= 0)].ravel()
            cosines = None
            if limit0 is not None:
                cosines = self._limit_cosines(x)
                bad = np.flatnonzero(limit0 & (cosines <= 0))
                if len(bad):
                    moved = np.r_[moved, self.op.positions_matrix()[bad].indices]
            if len(moved) == 0:
                self.shortened += k > 0
                self.frozen += int(np.sum(s == 0))
                dr.eval(x)
                self._last = (x, cosines)
                return x
            # shorten the step where it folds: the vertices of the turned triangles and the supports of the flipped
            # normals (their last halving stops them: at the old points nothing is turned over)
            s[np.unique(moved)] *= 0.5 if k < self.halvings else 0.0
        self.refused += 1           # stopping the culprits tipped their neighbours: no step this time
        return old
