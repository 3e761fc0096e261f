"""FFD displacements marginalised analytically at the contact level: limits, the dense formula, recovery."""

import numpy as np
import pytest
from scipy.optimize import minimize_scalar
from scipy.stats import multivariate_normal

from bayestouch.backend import jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_surface
from bayestouch.inference import contact as cm
from bayestouch.inference import ffd_marginal as fm

TRUTH = np.concatenate(
    [[0.004, -0.002, 0.001], np.log([0.03, 0.022, 0.015]), [0.4, 0.3, -0.5], [np.log(2.5)], [np.log(1e-4)]]
)
DIMS = (3, 3, 3)
NOISE = 1e-4  # m
TAU = 2e-3  # m: lattice displacements of the data sets, and the matched prior sd


def _data(seed, amplitude):
    """Points of the n-ellipsoid moved by a random lattice displacement of the given RMS (m), plus noise."""
    rng = np.random.default_rng(seed)
    s = cm.shape_of(jnp.asarray(TRUTH))
    local = np.asarray(ne.to_local(s, jnp.asarray(sample_surface(s, 300, seed=seed))))
    dP = rng.normal(0, amplitude, (27, 3))
    moved = np.asarray(fm.deformed_points(jnp.asarray(TRUTH), jnp.asarray(dP), jnp.asarray(local), DIMS))
    return moved + rng.normal(0, NOISE, moved.shape), moved, local, dP


def test_tau_to_zero_is_the_gaussian_contact_likelihood():
    pts, *_ = _data(0, TAU)
    th, p = jnp.asarray(TRUTH), jnp.asarray(pts)
    plain = float(cm.log_likelihood(th, p, np.inf))
    marg = float(fm.marginal_log_likelihood(th, p, DIMS, tau=1e-9))
    assert marg == pytest.approx(plain, rel=1e-9)
    # and a real prior on the lattice explains the deformation: far more likely than the rigid n-ellipsoid
    assert float(fm.marginal_log_likelihood(th, p, DIMS, tau=TAU)) > plain + 1000


def test_woodbury_equals_the_dense_gaussian():
    pts, *_ = _data(1, 3e-4)
    th = jnp.asarray(TRUTH)
    r, A = (np.asarray(a) for a in fm.design_matrix(th, jnp.asarray(pts[:80]), DIMS))
    tau = 4e-4
    C = NOISE**2 * np.eye(80) + tau**2 * A @ A.T
    dense = multivariate_normal(np.zeros(80), C).logpdf(r)
    assert float(fm.marginal_log_likelihood(th, jnp.asarray(pts[:80]), DIMS, tau=tau)) == pytest.approx(
        dense, rel=1e-10
    )


def test_conditional_lattice_recovers_the_deformed_surface():
    pts, moved, local, dP = _data(2, TAU)
    th = jnp.asarray(TRUTH)
    mean, cov = fm.conditional_lattice(th, jnp.asarray(pts), DIMS, tau=TAU)
    assert np.all(np.linalg.eigvalsh(np.asarray(cov)) > 0)
    rec = np.asarray(fm.deformed_points(th, mean, jnp.asarray(local), DIMS))
    rigid = np.asarray(fm.deformed_points(th, jnp.zeros((27, 3)), jnp.asarray(local), DIMS))
    err = np.sqrt(np.mean(np.sum((rec - moved) ** 2, axis=1)))
    err_rigid = np.sqrt(np.mean(np.sum((rigid - moved) ** 2, axis=1)))
    # along the normal the surface is pinned to the noise level; tangential displacements are not observable from
    # surface points, so compare the normal component of the error (the rigid surface is the negative control)
    s = cm.shape_of(th)
    nrm = np.asarray(ne.normals(s, jnp.asarray(moved)))
    en = np.abs(np.sum((rec - moved) * nrm, axis=1))
    en_rigid = np.abs(np.sum((rigid - moved) * nrm, axis=1))
    assert np.sqrt(np.mean(en**2)) < 1.5 * NOISE < 0.2 * np.sqrt(np.mean(en_rigid**2))
    assert err < err_rigid


def test_noise_scale_is_not_inflated_by_the_deformation():
    """Profile σ at the true shape: the marginal model finds the sensor noise, the rigid model absorbs the
    deformation into σ (negative control)."""
    pts, *_ = _data(3, TAU)
    p = jnp.asarray(pts)

    def best(fn):
        def neg(ls):
            t = TRUTH.copy()
            t[10] = ls
            return -float(fn(jnp.asarray(t)))

        return np.exp(minimize_scalar(neg, bounds=(np.log(1e-6), np.log(1e-2)), method="bounded").x)

    s_marg = best(lambda t: fm.marginal_log_likelihood(t, p, DIMS, tau=TAU))
    s_rigid = best(lambda t: cm.log_likelihood(t, p, np.inf))
    # 300 residuals: the σ estimate's relative sd is about 1/√(2·300) ≈ 4 %; 20 % is five of those
    assert s_marg == pytest.approx(NOISE, rel=0.2)
    assert s_rigid > 2.5 * NOISE


def test_log_prob_never_nan_and_minus_inf_outside():
    pts, *_ = _data(4, 3e-4)
    f, b = fm.make_ffd_log_prob(pts, DIMS)
    rng = np.random.default_rng(5)
    wild = rng.uniform(np.asarray(b.lower) - 3, np.asarray(b.upper) + 3, (200, 11))
    out = f(np.vstack([TRUTH, wild]))
    assert np.isfinite(out[0]) and not np.isnan(out).any()
    outside = np.any((wild < np.asarray(b.lower)) | (wild > np.asarray(b.upper)), axis=1)
    assert np.all(out[1:][outside] == -np.inf)
    with pytest.raises(ValueError, match="dims"):
        fm.make_ffd_log_prob(pts, (1, 3, 3))
