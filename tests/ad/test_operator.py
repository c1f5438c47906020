"""The Dr.Jit LimitOperator against the SciPy matrices, and its gradients."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mi_loop

from helpers import as_numpy, exactly, flat, point3f
from meshes import TET_F, TET_V, bipyramid, creased_cube, open_cylinder


def _samples(F, k, seed=0):
    rng = np.random.default_rng(seed)
    uv = rng.random((k, 2))
    flip = uv.sum(1) > 1
    uv[flip] = 1 - uv[flip]
    # include control-vertex corners (irregular vertices) and edge points
    uv[:3] = [[0, 0], [1, 0], [0.5, 0.5]]
    return rng.integers(0, len(F), k), uv


@pytest.mark.parametrize("mesh", [bipyramid(7), creased_cube(), open_cylinder()], ids=lambda m: m.name)
def test_operator_matches_scipy_forward_and_adjoint(mesh, jit_variant):
    fid, uv = _samples(mesh.F, 400)
    op = mi_loop.LimitOperator(mesh.F, len(mesh.V), fid, uv, creases=mesh.creases)
    x = flat(mesh.V, grad=True)
    P, du, dv = op.evaluate(x)
    scale = np.abs(mesh.V).max()
    for got, d in ((P, None), (du, "u"), (dv, "v")):
        want = op.matrix(d) @ mesh.V
        np.testing.assert_allclose(as_numpy(got), want, atol=2e-6 * scale * max(1, np.abs(want).max()))
    # adjoint identity <W x, y> = <x, W^T y> through reverse-mode AD
    y = np.random.default_rng(1).standard_normal((len(fid), 3))
    dr.backward(dr.sum(dr.sum(P * point3f(y))))
    g = np.array(dr.grad(x)).reshape(-1, 3)
    np.testing.assert_allclose(g, op.matrix().T @ y, rtol=1e-4, atol=1e-4 * np.abs(g).max())
    # forward mode: directional derivative equals W @ direction
    x2 = flat(mesh.V, grad=True)
    d = np.random.default_rng(2).standard_normal(mesh.V.shape)
    dr.set_grad(x2, flat(d))
    P2 = op.positions(x2)
    np.testing.assert_allclose(as_numpy(dr.forward_to(P2)), op.matrix() @ d, atol=1e-4 * np.abs(d).max() * 4)


def test_tensor_input_equals_flat_input():
    mesh = bipyramid(5)
    fid, uv = _samples(mesh.F, 50)
    op = mi_loop.LimitOperator(mesh.F, len(mesh.V), fid, uv)
    a = as_numpy(op.positions(mi.TensorXf(mesh.V.astype(np.float32))))
    b = as_numpy(op.positions(flat(mesh.V)))
    np.testing.assert_array_equal(a, b)


def test_normal_loss_gradient_matches_central_differences():
    """A nonlinear loss through positions and normals: AD vs central differences.

    Dr.Jit runs in float32 here; with step 1e-3 on O(1) coordinates the
    truncation error is O(1e-6) and the rounding error O(1e-7 / 1e-3) = 1e-4
    relative, so a 2e-3 relative tolerance on a directional derivative is tight
    enough to catch a wrong term (a missing derivative row changes it by O(1)).
    """
    mesh = bipyramid(4)
    fid, uv = _samples(mesh.F, 200, seed=3)
    op = mi_loop.LimitOperator(mesh.F, len(mesh.V), fid, uv)
    target = np.random.default_rng(4).standard_normal((len(fid), 3)).astype(np.float32)

    def loss(x):
        P, du, dv = op.evaluate(x)
        N = dr.normalize(dr.cross(du, dv))
        t = mi.Vector3f(target.T)
        return dr.sum(dr.sum(dr.square(P - t))) + 10.0 * dr.sum(dr.dot(N, t))

    x = flat(mesh.V, grad=True)
    L = loss(x)
    dr.backward(L)
    g = np.array(dr.grad(x), dtype=np.float64)
    direction = np.random.default_rng(5).standard_normal(g.shape)
    h = 1e-3
    plus = loss(mi.Float((mesh.V.ravel() + h * direction).astype(np.float32)))
    minus = loss(mi.Float((mesh.V.ravel() - h * direction).astype(np.float32)))
    fd = (float(plus[0]) - float(minus[0])) / (2 * h)
    np.testing.assert_allclose(g @ direction, fd, rtol=2e-3)


def test_repeated_calls_reuse_kernels():
    """A second evaluation with new control points compiles no new kernel."""
    mesh = bipyramid(6)
    fid, uv = _samples(mesh.F, 100)
    op = mi_loop.LimitOperator(mesh.F, len(mesh.V), fid, uv)
    for i in range(2):
        P = op.positions(mi.Float((mesh.V.ravel() * (1 + i)).astype(np.float32)))
        dr.eval(P)
    dr.kernel_history_clear() if hasattr(dr, "kernel_history_clear") else dr.kernel_history()
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        P = op.positions(mi.Float((mesh.V.ravel() * 3).astype(np.float32)))
        dr.eval(P)
        hist = dr.kernel_history()
    launched = [k for k in hist if k.get("type") == dr.KernelType.JIT]
    assert launched, "no kernel was launched at all"
    assert all(k.get("cache_hit") for k in launched), [k.get("cache_hit") for k in launched]


def test_gradient_of_two_branches_on_the_same_control_points():
    """Limit-operator energy + ARAP energy of the same x: the gradient is the sum of both.

    (Guards against Dr.Jit's ``dr.unravel`` dropping one branch of the reverse pass.)
    """
    from mi_loop.energies.arap import ARAP

    mesh = bipyramid(6)
    fid, uv = _samples(mesh.F, 80)
    op = mi_loop.LimitOperator(mesh.F, len(mesh.V), fid, uv, derivatives=False)
    arap = ARAP(mesh.V * 0.9, mesh.F)
    R = arap.rotations(mesh.V)

    def grad(parts):
        x = flat(mesh.V, grad=True)
        E = mi.Float(0.0)
        for part in parts:   # ARAP first: the order that lost the other branch
            E = E + (arap.energy(x, R) if part == "arap" else dr.sum(dr.squared_norm(op.positions(x))))
        dr.backward(E)
        return np.array(dr.grad(x), dtype=np.float64)

    g_arap, g_op, g_both = grad(["arap"]), grad(["op"]), grad(["arap", "op"])
    np.testing.assert_allclose(g_both, g_arap + g_op, rtol=1e-4, atol=1e-4 * np.abs(g_op).max())


def test_two_gather_chains_from_one_variable_are_summed():
    """The Dr.Jit 1.5.0 behaviour that ``unravel_points`` works around, pinned down.

    Two independent gather -> gather chains from the same AD variable: the sum
    of their gradients is wrong in the z component unless the first gather is
    shared. If a Dr.Jit upgrade fixes this, the first assertion fails and the
    workaround can go.
    """
    rng = np.random.default_rng(0)
    n = 50
    V = rng.standard_normal((n, 3)).astype(np.float32)
    idx = [mi.UInt32(rng.integers(0, n, k).astype(np.uint32)) for k in (200, 300)]

    def grad(branches, share):
        x = mi.Float(V.ravel())
        dr.enable_grad(x)
        shared = dr.gather(mi.Point3f, x, dr.arange(mi.UInt32, n))
        E = mi.Float(0.0)
        for b in branches:
            src = shared if share else dr.gather(mi.Point3f, x, dr.arange(mi.UInt32, n))
            E = E + (b + 1) * dr.sum(dr.squared_norm(dr.gather(mi.Point3f, src, idx[b])))
        dr.backward(E)
        return as_numpy(dr.grad(x))

    for share in (False, True):
        err = np.abs(grad([0, 1], share) - grad([0], share) - grad([1], share)).max(0)
        if share:
            assert err.max() < 1e-3, err
        else:
            assert err[2] > 1.0 and err[:2].max() < 1e-3, err


def test_operator_rejects_wrong_control_points():
    """Control points of the wrong count, shape or type (the operator's checks live in mi_loop.ad.control)."""
    op = mi_loop.LimitOperator(TET_F, 4, np.array([0]), np.array([[0.2, 0.2]]))
    count = exactly("LimitOperator(): expected 12 control coordinates (4 points, xyz interleaved), got 9")
    with pytest.raises(ValueError, match=count):
        op.positions(mi.Float(np.zeros(9)))
    with pytest.raises(ValueError, match=count):
        op.positions(mi.TensorXf(np.zeros((3, 3))))
    with pytest.raises(ValueError, match=exactly("LimitOperator(): expected a (n, 3) tensor of control points, "
                                                 "got shape (4, 2)")):
        op.positions(mi.TensorXf(np.zeros((4, 2))))
    with pytest.raises(TypeError, match=r"^LimitOperator\(\): expected control points as mi\.Float .*, got list$"):
        op.positions([1.0, 2.0])
    op_p = mi_loop.LimitOperator(TET_F, 4, np.array([0]), np.array([[0.2, 0.2]]), derivatives=False)
    with pytest.raises(ValueError, match="built with derivatives=False"):
        op_p.evaluate(mi.Float(TET_V.ravel()))


def test_derivative_adjoints_and_bit_identical_gradients():
    """Reverse mode through P, du and dv at once equals the matrices' transposes, and repeats bit for bit."""
    mesh = creased_cube()
    fid, uv = _samples(mesh.F, 3000, seed=6)
    op = mi_loop.LimitOperator(mesh.F, len(mesh.V), fid, uv, creases=mesh.creases)
    rng = np.random.default_rng(7)
    ys = [rng.standard_normal((len(fid), 3)) for _ in range(3)]

    def gradient():
        x = flat(mesh.V, grad=True)
        loss = sum(dr.sum(dr.sum(out * point3f(y))) for out, y in zip(op.evaluate(x), ys))
        dr.backward(loss)
        return np.array(dr.grad(x)).reshape(-1, 3)

    g = gradient()
    want = sum(M.T @ y for M, y in zip(op.matrix((None, "u", "v")), ys))
    np.testing.assert_allclose(g, want, rtol=1e-4, atol=1e-4 * np.abs(want).max())
    assert np.array_equal(g, gradient())


def test_transposed_tables_hold_every_entry_once_in_row_order():
    """Independent check of the transposed layout: scattering its chunks back rebuilds the padded rows."""
    from mi_loop.ad.tables import forward_tables, transposed_tables

    rng = np.random.default_rng(8)
    k, w, n = 500, 7, 40
    idx = rng.integers(0, n, (k, w))
    W = [rng.standard_normal((k, w)) * (rng.random((k, w)) < 0.7) for _ in range(2)]
    W[1][W[0] == 0] = 0.0
    W[1][:5] = rng.standard_normal((5, w))            # live in one table only
    order = rng.permutation(k)
    sample, weights, chunk_col = transposed_tables(idx, W, order, n, 8)
    width, chunks = sample.shape
    assert width == 8 and weights.shape == (2, width, chunks) and np.all(np.diff(chunk_col) >= 0)
    for d in range(2):
        dense = np.zeros((k, n))
        np.add.at(dense, (np.repeat(np.arange(k), w), idx.ravel()), W[d].ravel())
        rebuilt = np.zeros((k, n))
        live = sample < k
        cols = np.broadcast_to(chunk_col, sample.shape)
        np.add.at(rebuilt, (order[sample[live]], cols[live]), weights[d][live])
        np.testing.assert_allclose(rebuilt, dense, rtol=1e-6, atol=1e-6)
    assert (sample < k).sum() == ((W[0] != 0) | (W[1] != 0)).sum()
    for c in range(n):                                 # a column's entries by position in ``order``, chunk after chunk
        pos = sample.T[chunk_col == c].ravel()
        pos = pos[pos < k]
        assert np.all(np.diff(pos.astype(np.int64)) >= 0)
    idx_t, w_t = forward_tables(idx, W)
    dead = (W[0] == 0) & (W[1] == 0)
    assert np.all(idx_t.T[dead] == 0) and np.array_equal(idx_t.T[~dead], idx[~dead])
    np.testing.assert_array_equal(w_t[1].T, W[1].astype(np.float32))
