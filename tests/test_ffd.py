"""FFD (Bernstein lattice, X = B P) and the paper's two-step refinement (eq. 9–10)."""

import numpy as np
import pytest

from bayestouch.backend import jnp
from bayestouch.geometry import ffd, mesh
from bayestouch.geometry import nellipsoid as ne

LO, HI = np.array([-1.2, -0.8, -0.5]), np.array([1.3, 0.9, 0.6])


@pytest.mark.parametrize("dims", [(2, 2, 2), (7, 7, 7), (6, 4, 4), (6, 6, 3), (3, 5, 2)])
def test_partition_of_unity_and_identity_lattice(dims, rng):
    X = rng.uniform(LO, HI, (200, 3))
    B = ffd.deformation_matrix(X, LO, HI, dims)
    assert B.shape == (200, np.prod(dims))
    np.testing.assert_allclose(B.sum(axis=1), 1.0, atol=1e-14)
    assert B.min() >= 0
    np.testing.assert_allclose(B @ ffd.identity_lattice(LO, HI, dims), X, atol=1e-14)


def test_bernstein_matches_definition():
    s = np.array([0.0, 0.3, 1.0])
    b = ffd.bernstein(3, s)
    np.testing.assert_allclose(b[1], [0.7**3, 3 * 0.3 * 0.7**2, 3 * 0.3**2 * 0.7, 0.3**3])
    np.testing.assert_allclose(b[0], [1, 0, 0, 0])
    np.testing.assert_allclose(b[2], [0, 0, 0, 1])


def test_exact_recovery_of_lattice_displacement(rng):
    dims = (4, 3, 3)
    P_true = ffd.identity_lattice(LO, HI, dims) + rng.normal(0, 0.05, (36, 3))
    X0 = rng.uniform(LO, HI, (500, 3))
    B = ffd.deformation_matrix(X0, LO, HI, dims)
    P = ffd.solve_lattice(B, B @ P_true)
    np.testing.assert_allclose(P, P_true, atol=1e-10)
    # the ridge only pulls unreached control points: with full data it changes P by O(ridge)
    P_r = ffd.solve_lattice(B, B @ P_true, ffd.identity_lattice(LO, HI, dims), ridge=1e-9)
    np.testing.assert_allclose(P_r, P_true, atol=1e-6)


def test_two_step_fits_a_deformed_surface(rng):
    s = ne.from_vector(jnp.array([0.0, 0.0, 0.0, 0.03, 0.02, 0.012, 0.0, 0.0, 0.0, 3.0]))
    v, f = mesh.nellipsoid_mesh(s, 20)
    half = np.abs(v).max(axis=0) * 1.15
    dims = (4, 4, 3)
    P_true = ffd.identity_lattice(-half, half, dims) + rng.normal(0, 1e-3, (48, 3))
    data = ffd.deform(mesh.sample_mesh(v, f, 2000, seed=rng)[0], P_true, -half, half, dims)
    before = mesh.closest_points(v, f, data)[1].mean()
    # the paper's algorithm (no prior on δP, ridge only damps): converges on dense data
    fit = ffd.fit_two_step(v, f, data, -half, half, dims, anchor="previous", ridge=1e-6)
    after = mesh.closest_points(fit.vertices, f, data)[1]
    assert fit.converged and fit.iterations < 200
    assert after.mean() < 0.1 * before and after.mean() < 2e-5
    assert fit.residual == pytest.approx(min(fit.history)) and fit.residual < 1e-3
    assert fit.history[-1] < fit.history[0]
    # the default prior on δP costs little accuracy on dense data
    fit_p = ffd.fit_two_step(v, f, data, -half, half, dims, max_iter=40)
    after_p = mesh.closest_points(fit_p.vertices, f, data)[1]
    assert after_p.mean() < 0.2 * before
    with pytest.raises(ValueError, match="anchor"):
        ffd.fit_two_step(v, f, data, -half, half, dims, anchor="nowhere")


def test_bad_dims():
    with pytest.raises(ValueError, match="dims"):
        ffd.deformation_matrix(np.zeros((1, 3)), LO, HI, (1, 3, 3))
    with pytest.raises(ValueError, match="upper"):
        ffd.deformation_matrix(np.zeros((1, 3)), HI, LO, (3, 3, 3))
