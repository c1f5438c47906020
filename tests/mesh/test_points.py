"""Normal estimation for point clouds (mi_loop.mesh.points): spheres, orientation, errors, determinism."""
from __future__ import annotations

import numpy as np
import pytest

from mi_loop.mesh.points import estimate_normals

from helpers import DATA, REPO, sphere_points


@pytest.mark.parametrize("centre", [(0.0, 0.0, 0.0), (3.0, -2.0, 1.0)])
def test_estimate_normals_on_sphere(centre):
    U = sphere_points(4000, seed=1)[0]
    P = U * 0.5 + centre
    N = estimate_normals(P, k=16)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-12)
    dots = np.sum(N * U, 1)
    assert np.mean(np.abs(dots) > 0.99) > 0.99
    assert np.mean(dots > 0.99) > 0.99          # oriented outward, consistently


def test_estimate_normals_two_components_each_outward():
    U = sphere_points(3000, seed=2)[0]
    P = np.vstack([U, U + [5.0, 0, 0]])
    N = estimate_normals(P)
    assert np.mean(np.sum(N * np.vstack([U, U]), 1) > 0.99) > 0.99


def test_estimate_normals_errors():
    P = sphere_points(100)[0]
    with pytest.raises(ValueError, match=r"estimate_normals\(\): expected an integer k in \[3, 200\], got 2"):
        estimate_normals(P, k=2)
    with pytest.raises(ValueError, match=r"estimate_normals\(\): expected at least k \+ 1 = 17 points, got 10"):
        estimate_normals(P[:10])
    with pytest.raises(ValueError, match=r"estimate_normals\(\): expected points of shape \(k, 3\) with k > 0, "
                                         r"got shape \(100, 2\)"):
        estimate_normals(P[:, :2])
    Q = P.copy()
    Q[5, 2] = np.inf
    with pytest.raises(ValueError, match=r"estimate_normals\(\): expected finite points, got row 5 = \[.*inf\]"):
        estimate_normals(Q)


def test_estimate_normals_is_deterministic():
    """Same points, same normals, bit for bit: twice in this process and once more with one thread."""
    import hashlib
    import subprocess
    import sys

    P = np.load(DATA / "sequences" / "fox_walk_24f.npz")["vertices"][0].astype(np.float64)
    P = np.vstack([P, P[:40] + 1e-3, P[:10]])            # near and exact duplicates: ties in the kNN
    first, second = estimate_normals(P), estimate_normals(P.copy())
    assert first.tobytes() == second.tobytes()
    code = ("import sys, hashlib, numpy as np\nfrom mi_loop.mesh.points import estimate_normals\n"
            "P = np.frombuffer(sys.stdin.buffer.read()).reshape(-1, 3)\n"
            "print(hashlib.sha256(estimate_normals(P).tobytes()).hexdigest())\n")
    env = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}
    out = subprocess.run([sys.executable, "-c", code], input=P.tobytes(), capture_output=True, env=env, cwd=REPO,
                         check=True, timeout=120)
    assert out.stdout.decode().strip() == hashlib.sha256(first.tobytes()).hexdigest()


# --- noise_level ------------------------------------------------------------------------------

def _plane(n, sigma, seed):
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-1, 1, size=(n, 2)), sigma * rng.normal(size=n)]


@pytest.mark.parametrize("sigma", [0.0005, 0.001, 0.003])   # below 1/10 of the neighbourhood (0.03)
def test_noise_level_recovers_the_sigma_of_gaussian_noise_on_a_plane(sigma):
    from mi_loop.mesh.points import noise_level

    est = noise_level(_plane(30_000, sigma, seed=2))
    assert abs(est / sigma - 1) < 0.1, (sigma, est)


def test_noise_level_sees_no_noise_in_curvature_and_is_invariant_to_rigid_motion_and_scale():
    from mi_loop.mesh.points import noise_level

    U = sphere_points(20_000, seed=3)[0]
    assert noise_level(0.5 * U) < 1e-5 * 0.5                      # a clean sphere: curvature, not noise
    rng = np.random.default_rng(4)
    noisy = U * (1 + 0.005 * rng.normal(size=(len(U), 1)))
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    a, b = noise_level(noisy), noise_level(3.0 * noisy @ Q.T + [1.0, -2.0, 5.0])
    assert abs(a / 0.005 - 1) < 0.1, a
    assert abs(b / a - 3.0) < 1e-6, (a, b)


@pytest.mark.parametrize("points, k, message", [
    (np.zeros((20, 3)), 24, r"noise_level\(\): expected points of shape \(N, 3\) with N > k = 24, got shape \(20, 3\)"),
    (np.zeros((100, 2)), 24, r"expected points of shape \(N, 3\) .* got shape \(100, 2\)"),
    (np.zeros((100, 3)), 5, r"noise_level\(\): expected k an integer >= 10, got 5"),
    (np.zeros((100, 3)), 12.0, r"expected k an integer >= 10, got 12.0"),
])
def test_noise_level_rejects_bad_input(points, k, message):
    from mi_loop.mesh.points import noise_level

    with pytest.raises(ValueError, match=message):
        noise_level(points, k=k)
