"""The terms of the fitting loop (:mod:`mi_loop.fitting.loop`): one object per energy, one interface.

A term has a ``name`` (its key in the loop's history), a ``kind`` and a
``refresh(state)`` hook that the loop calls under its refresh rule:

- ``kind = 'energy'``: ``energy(state)`` returns its weighted value as a
  differentiable Dr.Jit scalar of the iterate (``state.x``, the control points
  shared by all terms of one iteration; ``wrt`` names the parameters it
  depends on); the loop sums the energy terms and differentiates them in one
  reverse pass.
- ``kind = 'render'``: ``gradient(state)`` runs its own reverse passes (one per
  rendered view) every ``every`` iterations and returns ``({name: gradient},
  loss)``; the gradients of the parameters in ``reuse`` are added again on the
  iterations in between.

Geometric terms here: :class:`Distance` (IMLS), :class:`Coverage`,
:class:`Rigidity` (ARAP), :class:`Fold` (barrier on turned limit normals),
:class:`CageLaplacian`, :class:`Flow` (samples onto the pixels optical flow
carried them to); the image term, :class:`ImageTerm`, renders the limit
surface against photos or rendered targets.
"""
from __future__ import annotations

import numpy as np

__all__ = ["CageLaplacian", "Coverage", "Distance", "Flow", "Fold", "ImageTerm", "Rigidity", "Tangential", "Term",
           "block_gram",
           "keep_lighting", "lighting_parameters"]


class Term:
    """Base class: an energy term that needs no refresh."""

    kind = "energy"
    name = "term"
    #: The parameters whose gradients the energy has (the control points).
    wrt = ("x",)

    def refresh(self, state) -> None:
        """Rebuild what depends on the iterate (called by the loop's refresh rule)."""

    def energy(self, state):
        """The weighted energy, ``mi.Float (1)``, differentiable with respect to ``state.values``."""
        raise NotImplementedError

    def hessian(self, state):
        """Gauss-Newton matrix of the weighted energy in the control points, ``(3n, 3n)`` SciPy sparse
        (``2 J^T J`` of its residuals, xyz interleaved), or None: the term has none, and a Gauss-Newton
        solver preconditions its gradient by the other terms' (:class:`~mi_loop.fitting.optimisers.GaussNewton`)."""
        return None


def block_gram(W, B):
    """``sum_j W_j^T B_j W_j`` over samples ``j``: the Gauss-Newton matrix of residuals of limit samples.

    Parameters
    ----------
    W : (s, n) SciPy sparse matrix
        Limit rows of the samples (:meth:`~mi_loop.ad.operator.LimitOperator.matrix`).
    B : (s, 3, 3) float NumPy array
        Symmetric 3x3 weight of each sample (``g_j g_j^T`` for a residual ``g_j . Q_j``).

    Returns
    -------
    (3n, 3n) scipy.sparse.csr_matrix
        xyz interleaved (coordinate ``d`` of control point ``a`` at ``3 a + d``).

    Examples
    --------
    >>> import scipy.sparse as sp
    >>> W = sp.csr_matrix([[0.5, 0.5]]); B = np.diag([1.0, 0.0, 0.0])[None]
    >>> (block_gram(W, B).toarray()[[0, 3]][:, [0, 3]] * 4).tolist()
    [[1.0, 1.0], [1.0, 1.0]]
    """
    import scipy.sparse as sp

    W = sp.csr_matrix(W, dtype=np.float64)
    n = W.shape[1]
    rows, cols, vals = [], [], []
    for d in range(3):
        for e in range(d, 3):
            M = (W.T @ sp.diags(B[:, d, e]) @ W).tocoo()
            pairs = ((d, e),) if d == e else ((d, e), (e, d))
            for a, b in pairs:
                rows.append(3 * M.row + a)
                cols.append(3 * M.col + b)
                vals.append(M.data)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))


class Distance(Term):
    """``mean_j f(Q_j)^2``: the IMLS distance of the limit samples to the data (:class:`~mi_loop.energies.imls.IMLS`).

    Parameters
    ----------
    imls : IMLS
        Of the data points.
    op : LimitOperator
        The samples ``Q = op.positions(x)``.
    facing : bool
        Refresh the neighbour lists with the samples' limit normals, so that only
        data points facing the same way count (``op`` needs derivatives).
    """

    name = "imls"

    def __init__(self, imls, op, facing: bool = False):
        self.imls, self.op, self.facing = imls, op, bool(facing)

    def refresh(self, state) -> None:
        self.imls.update(state.host(self.op, "positions"), state.host(self.op, "normals") if self.facing else None)

    def energy(self, state):
        return self.imls.energy(state.evaluate(self.op), reduce="mean")

    def hessian(self, state):
        """``(2/s) sum_j W_j^T g_j g_j^T W_j``, ``g_j`` the IMLS gradient at sample ``j`` (point-to-plane)."""
        G = self.imls.gradients(state.host(self.op, "positions"))
        return (2.0 / len(G)) * block_gram(self.op.positions_matrix(), G[:, :, None] * G[:, None, :])


class Coverage(Term):
    """``weight E_cover``: data points pull their nearest samples (:class:`~mi_loop.energies.coverage.Coverage`).

    Parameters
    ----------
    coverage : mi_loop.energies.coverage.Coverage
    op : LimitOperator
        The samples (shared with :class:`Distance`).
    weight : float
    facing : bool
        As for :class:`Distance`.
    """

    name = "cover"

    def __init__(self, coverage, op, weight: float, facing: bool = False):
        self.coverage, self.op, self.weight, self.facing = coverage, op, float(weight), bool(facing)

    def refresh(self, state) -> None:
        self.coverage.update(state.host(self.op, "positions"),
                             state.host(self.op, "normals") if self.facing else None)

    def energy(self, state):
        return self.weight * self.coverage.energy(state.evaluate(self.op))

    def hessian(self, state):
        """``2 weight sum_i w_i W_j(i)^T n_i n_i^T W_j(i)``: each data point's normal at its nearest sample."""
        c = self.coverage
        w = c.weight / c.weight.sum()
        B = np.zeros((c.n_samples, 3, 3))
        np.add.at(B, c.nearest, w[:, None, None] * c.normals[:, :, None] * c.normals[:, None, :])
        return (2.0 * self.weight) * block_gram(self.op.positions_matrix(), B)


class Rigidity(Term):
    """``weight E_arap(x; rest)``: ARAP of the control mesh to a rest shape (:class:`~mi_loop.energies.arap.ARAP`).

    Parameters
    ----------
    arap : ARAP
        Built on the rest shape.
    weight : float
        Weight (already divided by the number of control points where the
        fit normalises it so).
    stiff : (float, int), optional
        ``(factor, until)``: the weight is ``factor`` times larger before
        iteration ``until`` (stiff to soft: thin parts follow the bulk first).
    name : str
        History key (two ARAP terms in one loop need two names).
    """

    def __init__(self, arap, weight: float, stiff=None, name: str = "arap"):
        import drjit as dr
        import mitsuba as mi

        self.arap, self.name, self.stiff = arap, name, stiff
        self._w = dr.opaque(mi.Float, float(weight))
        self._L3 = None          # the Gauss-Newton matrix's Laplacian, (3n, 3n), built at the first call

    def _factor(self, state) -> float:
        """``stiff[0]`` before iteration ``stiff[1]``, else 1."""
        return self.stiff[0] if self.stiff is not None and state.it < self.stiff[1] else 1.0

    def energy(self, state):
        w, factor = self._w, self._factor(state)
        if factor != 1.0:
            w = w * factor
        return w * self.arap.energy(state.x, self.arap.rotations(state.numpy("x")))

    def hessian(self, state):
        """``2 weight (L (x) I_3)``, ``L = sum_ij w_ij (e_i - e_j)(e_i - e_j)^T`` (rotations held; built once)."""
        if self._L3 is None:
            import scipy.sparse as sp

            a = self.arap
            L = sp.csr_matrix((np.r_[a.w, -a.w], (np.r_[a.I, a.I], np.r_[a.I, a.J])), shape=(a.n, a.n))
            self._L3 = sp.kron(L + L.T, sp.identity(3), format="csr")
        return (2.0 * float(self._w[0]) * self._factor(state)) * self._L3


class Fold(Term):
    """``weight mean_j max(0, c |r_j| - n_j . r_j)^2``: a barrier on limit normals turned from references.

    Parameters
    ----------
    op : LimitOperator
        The samples whose limit normals ``n_j`` are watched (with derivatives).
    weight : float
    reference : mi.Normal3f (k), optional
        Fixed reference normals (a sequence: the previous frame's limit normals).
    data : (cKDTree, (N, 3) NumPy array, int), optional
        Instead of ``reference``: the data's k-d tree, normals and how many of
        the nearest data normals to average into each sample's reference,
        refreshed with the loop (:func:`~mi_loop.energies.fold.nearest_data_normals`).
    cosine : float
        Cosine of the free angle (default 60 degrees).
    opaque : bool
        The weight as an opaque Dr.Jit value instead of a literal (no effect on values).
    """

    name = "fold"

    def __init__(self, op, weight: float, *, reference=None, data=None, cosine: float = 0.5, opaque: bool = False):
        import drjit as dr
        import mitsuba as mi

        if (reference is None) == (data is None):
            raise ValueError("Fold(): expected one of reference and data, got "
                             f"{'both' if data is not None else 'neither'}")
        self.op, self.reference, self.data, self.cosine = op, reference, data, float(cosine)
        self.weight = dr.opaque(mi.Float, float(weight)) if opaque else float(weight)
        self._what = "normals" if data is None else "positions_normals"

    def refresh(self, state) -> None:
        if self.data is None:
            return
        import mitsuba as mi

        from mi_loop.ad.upload import upload_vec
        from mi_loop.energies.fold import nearest_data_normals

        tree, normals, k = self.data
        Q = np.array(state.evaluate(self.op, self._what)[0], dtype=np.float64).T
        self.reference = upload_vec(mi.Normal3f, nearest_data_normals(tree, normals, Q, k))

    def energy(self, state):
        from mi_loop.energies.fold import fold_energy

        n = state.evaluate(self.op, self._what)
        if self._what == "positions_normals":
            n = n[1]
        return self.weight * fold_energy(n, self.reference, self.cosine)


class Flow(Term):
    """``weight mean_k |pi_k(Q_s(k)) - p_k|^2 pixel^2``: limit samples onto the pixels optical flow carried them to.

    Parameters
    ----------
    op : LimitOperator
        The samples (those of :func:`~mi_loop.fitting.flow.flow_correspondences`).
    correspondences : mi_loop.fitting.flow.Correspondences
        Sample, camera and target pixel of each correspondence.
    weight : float
    to_world : (float, (3,) array)
        ``(scale, centre)`` from the fit's unit box to the cameras' units.
    pixel : float
        Width of one pixel at the subject, in the fit's units: the residual is in the fit's units.
    """

    name = "flow"

    def __init__(self, op, correspondences, weight: float, to_world, pixel: float):
        import mitsuba as mi

        from mi_loop.ad.sparse import IndexMap
        from mi_loop.ad.upload import upload_float, upload_vec

        c = correspondences
        self.op, self.c, self.weight, self.pixel = op, c, float(weight), float(pixel)
        self.scale, self.centre = float(to_world[0]), np.asarray(to_world[1], dtype=np.float64)
        w2c = np.stack([np.linalg.inv(cam.c2w) for cam in c.cameras])[c.camera]          # (k, 4, 4)
        self._w2c = w2c
        self._rows = [upload_vec(mi.Vector3f, w2c[:, r, :3]) for r in range(3)]
        self._t = [upload_float(w2c[:, r, 3]) for r in range(3)]
        f = np.array([[cam.fx, cam.fy, cam.cx, cam.cy] for cam in c.cameras])[c.camera]
        self._f = [upload_float(f[:, i]) for i in range(4)]
        self._target = [upload_float(c.target[:, i]) for i in range(2)]
        self._gather = IndexMap(c.sample, op.n_samples)
        self._centre = mi.Point3f(*(float(v) for v in self.centre))

    def energy(self, state):
        import drjit as dr
        import mitsuba as mi

        if len(self.c.sample) == 0:
            return mi.Float(0.0)
        X = self._gather(state.evaluate(self.op)) * self.scale + self._centre
        x, y, z = (dr.dot(self._rows[r], mi.Vector3f(X)) + self._t[r] for r in range(3))
        fx, fy, cx, cy = self._f
        dx = (cx - fx * x / z) - self._target[0]
        dy = (cy + fy * y / z) - self._target[1]
        return (self.weight * self.pixel ** 2) * dr.mean(dx * dx + dy * dy)

    def hessian(self, state):
        """``(2 weight / k) sum_k W_s^T J_k^T J_k W_s``, ``J_k`` the projection's Jacobian in the fit's units."""
        k = len(self.c.sample)
        if k == 0:
            return None
        Q = state.host(self.op, "positions")[self.c.sample] * self.scale + self.centre
        R = self._w2c[:, :3, :3]
        Xc = np.einsum("kab,kb->ka", R, Q) + self._w2c[:, :3, 3]
        f = np.array([[cam.fx, cam.fy] for cam in self.c.cameras])[self.c.camera]
        x, y, z = Xc.T
        Jc = np.zeros((k, 2, 3))
        Jc[:, 0, 0], Jc[:, 0, 2] = -f[:, 0] / z, f[:, 0] * x / z ** 2
        Jc[:, 1, 1], Jc[:, 1, 2] = f[:, 1] / z, -f[:, 1] * y / z ** 2
        J = np.einsum("kab,kbc->kac", Jc, R) * (self.scale * self.pixel)
        JtJ = np.einsum("kab,kac->kbc", J, J)
        B = np.zeros((self.op.n_samples, 3, 3))
        np.add.at(B, self.c.sample, JtJ)
        return (2.0 * self.weight / k) * block_gram(self.op.positions_matrix(), B)


class Tangential(Term):
    """``weight mean_i h_i rho(|(I - n_i n_i^T)(x_i - a_i)|^2)``: control points held to anchors along the surface.

    The anchors ``a_i`` are where the frame's coarse stage carried the control
    points (:func:`mi_loop.fitting.track.track`), ``n_i`` the unit limit normal
    at each anchor. Motion along the normal is free (the data terms decide
    it); sliding along the surface, which no distance term measures, costs
    as much as lying that far off the surface: ``rho(s) = s`` for small
    slides. An anchor can be wrong, though: a leg that swung farther between
    two frames than the correspondences reach is carried by its neighbours'
    motions and lands beside the data. Two things let such a point go:
    ``h_i``, the anchor's weight from the share of the point's limit support
    that the coarse stage brought onto the data
    (:func:`mi_loop.fitting.track.anchor_weights`), and, with ``reach`` ``c``,
    the Geman-McClure ``rho(s) = c^2 s / (s + c^2)``, whose pull is largest
    at a slide of ``c / sqrt(3)`` and fades beyond: the data terms move a
    point that they want more than a few ``c`` away.

    Parameters
    ----------
    anchors, normals : (n, 3) float NumPy arrays
        Anchor of every control point and the unit normal there.
    weight : float
        Weight of the mean (the distance terms' units: squared lengths).
    held : (n,) float array-like, optional
        ``h_i >= 0`` (default: all 1).
    reach : float, optional
        ``c`` (lengths of the control points); default: ``rho(s) = s``.

    Examples
    --------
    >>> import mitsuba as mi, mi_loop
    >>> mi_loop.set_variant("llvm_ad_rgb")
    >>> from types import SimpleNamespace
    >>> from mi_loop.ad.control import ControlPoints
    >>> term = Tangential(np.zeros((1, 3)), np.array([[0.0, 0, 1]]), 2.0)
    >>> x = ControlPoints(mi.Float([3.0, 4.0, 5.0]))      # 5 along the normal: free
    >>> float(term.energy(SimpleNamespace(x=x))[0])
    50.0
    >>> robust = Tangential(np.zeros((1, 3)), np.array([[0.0, 0, 1]]), 2.0, reach=5.0)
    >>> float(robust.energy(SimpleNamespace(x=x))[0])     # 2 * 25 * 25 / (25 + 25)
    25.0
    """

    name = "tangential"

    def __init__(self, anchors, normals, weight: float, held=None, reach: float | None = None):
        import mitsuba as mi

        from mi_loop.ad.upload import upload_vec

        N = np.asarray(normals, dtype=np.float64)
        h = np.ones(len(N)) if held is None else np.asarray(held, dtype=np.float64)
        self._anchors, self._held = np.asarray(anchors, dtype=np.float64), h
        self._P = np.eye(3) - np.einsum("ia,ib->iab", N, N)                   # (n, 3, 3) tangent projectors
        self._a, self._n = upload_vec(mi.Point3f, anchors), upload_vec(mi.Vector3f, N)
        self._h = mi.Float(h.astype(np.float32))
        self.weight, self.n, self.reach = float(weight), len(N), None if reach is None else float(reach)

    def energy(self, state):
        import drjit as dr

        d = state.x.points - self._a
        s = dr.squared_norm(d - self._n * dr.dot(self._n, d))
        if self.reach is not None:
            c2 = self.reach ** 2
            s = c2 * s / (s + c2)
        return (self.weight / self.n) * dr.sum(self._h * s)

    def hessian(self, state):
        """``(2 weight / n) diag(h_i rho'(s_i) (I - n_i n_i^T))`` (xyz interleaved; rho's curvature left out)."""
        import drjit as dr
        import scipy.sparse as sp

        w = self._held
        if self.reach is not None:
            x = np.array(dr.detach(state.values["x"]), dtype=np.float64).reshape(-1, 3)
            t = np.einsum("iab,ib->ia", self._P, x - self._anchors)
            c2 = self.reach ** 2
            w = w * (c2 / (np.sum(t * t, axis=1) + c2)) ** 2
        return (2.0 * self.weight / self.n) * sp.block_diag(w[:, None, None] * self._P, format="csr")


class CageLaplacian(Term):
    """``weight |L x|^2``, ``L = I - D^-1 A``: each control point (or its albedo) against the mean of its neighbours.

    Parameters
    ----------
    F : (m, 3) int NumPy array
        Control faces.
    n : int
        Control points.
    weight : float
        Multiplies the sum over the control points.
    of : {'x', 'albedo'}
        The parameter smoothed: the control points, or the per-control-vertex
        albedo (history key ``albedo_laplacian``).
    """

    name = "laplacian"

    def __init__(self, F, n: int, weight: float, of: str = "x"):
        import mitsuba as mi

        from mi_loop.ad.sparse import IndexMap, SegmentSum
        from mi_loop.ad.upload import upload_float
        from mi_loop.mesh.geometry import edges

        E = edges(F)
        heads, tails = np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]]     # both directions of every edge
        self._J, self._sum = IndexMap(tails, n), SegmentSum(heads, n)
        degree = np.bincount(heads, minlength=n).astype(np.float64)
        self._inv_degree = upload_float(1.0 / np.maximum(degree, 1.0))
        self.weight, self.n = float(weight), int(n)
        self._mi = mi
        self.of, self.wrt = of, (of,)
        if of != "x":
            self.name = f"{of}_laplacian"

    def energy(self, state):
        import drjit as dr

        P = state.x.points if self.of == "x" else dr.unravel(self._mi.Point3f, state.values[self.of])
        mean = self._mi.Point3f(self._sum(self._J(P))) * self._inv_degree
        return self.weight * dr.sum(dr.squared_norm(P - mean))


class ImageTerm(Term):
    """The image loss of the limit surface against photos or rendered targets, and its gradients.

    Parameters
    ----------
    renderer : ImageRenderer
        Scene of the cameras with the ``loop_subdiv`` shape; ``renderer.backward(x, c,
        view_ids, seed=...)`` accumulates the gradients of the mean loss over
        ``view_ids`` into ``x`` and ``c`` and returns the per-view losses.
    albedo : mi.Float (3n)
        The fixed per-control-vertex albedo, used when the loop has no
        ``'albedo'`` parameter (otherwise the parameter's value is rendered and
        receives gradients). Likewise the loop's parameters ``'light'`` and
        ``'gain'``, where it has them, are the coefficients and log-gains of the
        renderer's estimated lighting and receive their gradients.
    views_per_iteration : int
        Views rendered per evaluation, a seeded sweep through all of them.
    every : int
        Iterations between evaluations; in between the control-point gradient is reused.
    to_world : (float, (3,) array), optional
        ``(scale, centre)``: the renderer's coordinates are ``x * scale +
        centre`` of the loop's (a fit in the unit box against photos in the
        capture's units); the gradient is mapped back.
    shaping : object, optional
        ``shaping(g, state) -> g`` post-processes the control-point gradient
        (a sequence's smoothing and per-vertex weights), ``shaping.refresh(state)``
        is called with the loop's refresh.
    seeds : Seeds
        The term's seeds: the view order and the renders' samplers.
    """

    kind = "render"
    name = "image"
    reuse = ("x",)
    #: Loop parameters of an estimated lighting (:class:`~mi_loop.render.lighting.Lighting`) and its attributes.
    LIGHTING = (("light", "coefficients"), ("gain", "log_gain"))

    def __init__(self, renderer, albedo, *, views_per_iteration: int, every: int = 1, to_world=None,
                 shaping=None, seeds):
        self.renderer, self.albedo = renderer, albedo
        self.k, self.every, self.to_world, self.shaping = int(views_per_iteration), int(every), to_world, shaping
        self.n_views = renderer.n_views
        self._rng, self._seeds, self._order = seeds.generator(0), seeds, []

    def refresh(self, state) -> None:
        if self.shaping is not None:
            self.shaping.refresh(state)

    def views(self) -> list:
        """The next ``views_per_iteration`` views of the seeded sweep."""
        if len(self._order) < self.k:
            self._order += self._rng.permutation(self.n_views).tolist()
        ids, self._order = self._order[:self.k], self._order[self.k:]
        return ids

    def gradient(self, state):
        import drjit as dr
        import mitsuba as mi

        x = dr.detach(state.values["x"])
        if self.to_world is not None:
            scale, centre = self.to_world
            x = mi.Float(x * scale + dr.tile(mi.Float(np.asarray(centre, dtype=np.float32)), dr.width(x) // 3))
        fit_albedo = "albedo" in state.values
        c = mi.Float(dr.detach(state.values["albedo"])) if fit_albedo else self.albedo
        dr.enable_grad(x)
        if fit_albedo:
            dr.enable_grad(c)
        lit = {}
        for name, attr in self.LIGHTING:             # the estimated lighting's leaves, read by the renders
            if name in state.values:
                lit[name] = mi.Float(dr.detach(state.values[name]))
                dr.enable_grad(lit[name])
                setattr(self.renderer.lighting, attr, lit[name])
        losses = self.renderer.backward(x, c, self.views(), seed=self._seeds.integer(1, state.it))
        g = dr.grad(x)
        if self.to_world is not None:
            g = g * self.to_world[0]
        if self.shaping is not None:
            g = self.shaping(g, state)
        out = {"x": g}
        if fit_albedo:
            out["albedo"] = dr.grad(c)
        out |= {name: dr.grad(v) for name, v in lit.items()}
        return out, float(np.mean(losses))


def lighting_parameters(lighting, lr: float, exposure: bool) -> dict:
    """The loop parameters of an estimated lighting that :class:`ImageTerm` differentiates.

    Parameters
    ----------
    lighting : mi_loop.render.lighting.Lighting or None
        The renderer's lighting (None: a given one, nothing to estimate).
    lr : float
        Adam step of the coefficients and the log-gains; 0: kept as they are.
    exposure : bool
        Estimate the photos' gains too.

    Returns
    -------
    dict of str to Parameter
        ``'light'`` (and ``'gain'``), or empty.
    """
    import mitsuba as mi

    from mi_loop.fitting.loop import Parameter
    from mi_loop.fitting.optimisers import Adam, Constant

    if lighting is None or lr <= 0:
        return {}
    out = {"light": Parameter(mi.Float(lighting.coefficients), Adam(), Constant(lr))}
    if exposure:
        out["gain"] = Parameter(mi.Float(lighting.log_gain), Adam(), Constant(lr))
    return out


def keep_lighting(lighting, values: dict) -> None:
    """Leave in ``lighting`` the estimate a loop found.

    Parameters
    ----------
    lighting : mi_loop.render.lighting.Lighting
        Updated in place: its ``coefficients`` and ``log_gain`` where the loop estimated them.
    values : dict of str to NumPy array
        A loop's :attr:`~mi_loop.fitting.loop.LoopResult.values` (``'light'``, ``'gain'``).
    """
    import mitsuba as mi

    for name, attr in ImageTerm.LIGHTING:
        if name in values:
            setattr(lighting, attr, mi.Float(values[name].astype(np.float32).ravel()))
