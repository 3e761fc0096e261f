"""The contact fit's sampling coordinates (semi-axes in metres, :func:`bayestouch.inference.contact.to_sampling`):
the map and the Jacobian of the density. A run's log-posterior back in θ is checked in ``tests/test_fit_cli.py``."""

import numpy as np
import pytest
from scipy.integrate import quad

from bayestouch.inference import contact as cm


def test_round_trip_and_only_the_axes_change():
    rng = np.random.default_rng(0)
    theta = rng.normal(size=(5, 13))
    theta[:, 3:6] = np.log(rng.uniform(0.005, 0.08, (5, 3)))
    u = cm.to_sampling(theta)
    assert np.allclose(u[:, 3:6], np.exp(theta[:, 3:6]), rtol=1e-15)
    keep = [k for k in range(13) if k not in cm.AXIS_COLUMNS]
    assert np.array_equal(u[:, keep], theta[:, keep])
    assert np.allclose(cm.from_sampling(u), theta, rtol=0, atol=1e-15)


def test_the_sampled_density_keeps_its_mass_and_a_missing_jacobian_would_not():
    """A normalised density over log a (log-normal a, median 2 cm) becomes a normalised density over a in metres:
    ∫ p_u da = 1 (quadrature). Without the Jacobian 1/a the integral would be E[a] ≈ 0.02, not 1."""
    mu, sd = np.log(0.02), 0.3

    def logp(theta):
        x = (theta[:, 3] - mu) / sd
        return -0.5 * x * x - np.log(sd * np.sqrt(2 * np.pi))

    logp_u = cm.sampling_log_prob(logp)
    base = np.zeros(11)

    def p_u(a):
        u = base.copy()
        u[3:6] = [a, 1.0, 1.0]  # unit b, c: their Jacobian factors are 1
        return float(np.exp(logp_u(u[None]))[0])

    mass, err = quad(p_u, 0, 0.2, points=[0.02], limit=200)
    assert mass == pytest.approx(1.0, abs=1e-6)
    naive, _ = quad(lambda a: p_u(a) * a, 0, 0.2, points=[0.02], limit=200)  # the density without 1/a
    assert abs(naive - 1.0) > 0.9
    # outside the coordinates' domain (a semi-axis ≤ 0) the density is zero, not NaN
    u = np.zeros((2, 11))
    u[:, 3:6] = [[-0.01, 0.01, 0.01], [0.0, 0.01, 0.01]]
    assert np.all(logp_u(u) == -np.inf)
