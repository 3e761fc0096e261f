"""Contact-level model: residuals, priors, the never-NaN log-probability, robust recovery."""

import numpy as np
import pytest
from scipy.optimize import minimize

from bayestouch._jax import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_surface
from bayestouch.inference import contact as cm

TRUTH = np.concatenate([[0.004, -0.002, 0.001], np.log([0.03, 0.022, 0.015]), [0.4, 0.3, -0.5], [np.log(3.0)],
                        [np.log(3e-4)]])


def test_residuals_exact_on_sphere_and_zero_on_surface():
    theta = np.concatenate([[0.01, 0, 0], np.log([0.02] * 3), [0.3, 0.2, 0.1], [np.log(2.0)], [0.0]])
    x = np.random.default_rng(0).normal(0, 0.03, (100, 3)) + [0.01, 0, 0]
    exact = np.linalg.norm(x - [0.01, 0, 0], axis=1) - 0.02
    np.testing.assert_allclose(np.asarray(cm.residuals(jnp.asarray(theta), jnp.asarray(x))), exact, atol=1e-12)
    s = cm.shape_of(jnp.asarray(TRUTH))
    on = sample_surface(s, 300, seed=1)
    assert np.abs(np.asarray(cm.residuals(jnp.asarray(TRUTH), jnp.asarray(on)))).max() < 1e-9


def test_log_prob_is_minus_inf_outside_and_never_nan():
    pts = sample_surface(cm.shape_of(jnp.asarray(TRUTH)), 200, seed=2)
    f, b = cm.make_log_prob(pts)
    assert np.isfinite(f(TRUTH[None]))[0]
    rng = np.random.default_rng(3)
    wild = rng.uniform(np.asarray(b.lower) - 5, np.asarray(b.upper) + 5, (500, 11))
    wild[:10, 3:6] = -700.0  # absurdly small axes
    wild[10:20, 9] = 50.0  # huge exponent
    out = f(wild)
    assert not np.isnan(out).any()
    outside = np.any((wild < np.asarray(b.lower)) | (wild > np.asarray(b.upper)), axis=1)
    assert np.all(out[outside] == -np.inf) and np.all(np.isfinite(out[~outside]))


def test_gaussian_noise_scale_posterior_mode_is_closed_form():
    """With the shape fixed, p(log σ | r) ∝ σ^(−M) exp(−Σr²/2σ²): its mode is σ² = Σr²/M."""
    s = cm.shape_of(jnp.asarray(TRUTH))
    rng = np.random.default_rng(4)
    on = sample_surface(s, 400, seed=4)
    nrm = np.asarray(ne.normals(s, jnp.asarray(on)))
    pts = on + rng.normal(0, 3e-4, (400, 1)) * nrm
    r = np.asarray(cm.residuals(jnp.asarray(TRUTH), jnp.asarray(pts)))
    f, _ = cm.make_log_prob(pts, nu=np.inf)
    grid = np.log(np.sqrt(np.mean(r**2))) + np.linspace(-0.05, 0.05, 2001)
    th = np.tile(TRUTH, (len(grid), 1))
    th[:, 10] = grid
    best = grid[np.argmax(f(th))]
    assert best == pytest.approx(np.log(np.sqrt(np.mean(r**2))), abs=1e-4)


def _fit(pts, nu, start):
    f, b = cm.make_log_prob(pts, nu=nu)
    pj = jnp.asarray(pts)
    g = jax.jit(jax.value_and_grad(lambda t: -cm.log_prob(t, pj, b, nu)))
    res = minimize(lambda t: tuple(np.asarray(v) for v in g(jnp.asarray(t))), start, jac=True, method="L-BFGS-B",
                   bounds=list(zip(np.asarray(b.lower), np.asarray(b.upper), strict=True)))
    return res.x


def test_student_t_recovers_the_shape_through_outliers_and_gaussian_does_not():
    s = cm.shape_of(jnp.asarray(TRUTH))
    rng = np.random.default_rng(5)
    on = sample_surface(s, 300, seed=5)
    nrm = np.asarray(ne.normals(s, jnp.asarray(on)))
    pts = on + rng.normal(0, 3e-4, (300, 1)) * nrm
    bad = rng.choice(300, 45, replace=False)  # 15 % outliers, 5–15 mm off the surface
    pts[bad] += rng.uniform(0.005, 0.015, (45, 1)) * nrm[bad]
    start = TRUTH + np.concatenate([[1e-3, -1e-3, 1e-3], [0.05, -0.05, 0.05], [0.02, 0.02, 0.02], [0.1], [1.0]])
    robust = _fit(pts, 4.0, start)
    gauss = _fit(pts, np.inf, start)
    vol = float(ne.volume(s))
    err_t = abs(float(ne.volume(cm.shape_of(jnp.asarray(robust)))) / vol - 1)
    err_g = abs(float(ne.volume(cm.shape_of(jnp.asarray(gauss)))) / vol - 1)
    assert err_t < 0.02  # robust: volume within 2 %
    assert err_g > 2 * err_t  # negative control: the Gaussian likelihood is pulled out by the outliers
    assert np.exp(robust[10]) < 0.3 * np.exp(gauss[10])  # the t scale is not inflated by the outliers
