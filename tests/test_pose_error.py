"""The contact likelihood with each stroke's pose error marginalised (bayestouch.inference.pose_error)."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_surface
from bayestouch.inference import contact as cm
from bayestouch.inference import pose_error as pe

TRUE = ne.NEllipsoid(
    jnp.array([0.0, 0.01, 0.0]), jnp.array([0.03, 0.02, 0.015]), jnp.array([0.3, 0.2, 0.1]), jnp.array(2.5)
)


def _data(rng, strokes=4, per=15):
    pts = np.asarray(sample_surface(TRUE, strokes * per, seed=2)) + rng.normal(0, 3e-4, (strokes * per, 3))
    return pts, np.repeat(np.arange(strokes) * 7 + 3, per)  # any integer labels


def _theta(log_sigma, log_tau):
    return np.array(
        [0.0005, 0.0105, 0.0, *np.log([0.031, 0.019, 0.015]), 0.3, 0.2, 0.1, np.log(2.4), log_sigma, log_tau]
    )


def test_the_marginal_is_the_dense_gaussian_of_the_linearised_offsets(rng):
    """Per stroke, the closed form equals the multivariate normal N(0, σ² I + τ² N Nᵀ) of the residuals with the
    model's unit normals, evaluated densely."""
    pts, lab = _data(rng)
    th = _theta(np.log(4e-4), np.log(1.5e-3))
    got = pe.pose_log_likelihood(th[None], pts, lab)[0]
    f = cm.principal_frame(jnp.asarray(th[None]), jnp.asarray(np.c_[pts, np.ones(len(pts))].T))
    g = np.einsum("kj,jm->km", np.asarray(f.R[0]), np.sign(np.asarray(f.q[0])) * np.asarray(f.v[0]))
    n = (g / np.linalg.norm(g, axis=0)).T
    d = np.asarray(f.d[0])
    want = 0.0
    for s in np.unique(lab):
        k = lab == s
        cov = 4e-4**2 * np.eye(k.sum()) + 1.5e-3**2 * n[k] @ n[k].T
        want += multivariate_normal(np.zeros(k.sum()), cov).logpdf(d[k])
    assert got == pytest.approx(want, abs=1e-6 * abs(want))


def test_no_pose_error_is_the_gaussian_contact_likelihood(rng):
    """τ → 0: the plain Gaussian likelihood of the contact level; a large τ is a different (and, on these
    unshifted contacts, lower) likelihood — the control."""
    pts, lab = _data(rng)
    th = _theta(np.log(3e-4), np.log(1e-9))
    plain = float(cm.log_likelihood(jnp.asarray(th[:11]), pts, np.inf))
    assert pe.pose_log_likelihood(th[None], pts, lab)[0] == pytest.approx(plain, abs=1e-6 * abs(plain))
    big = pe.pose_log_likelihood(_theta(np.log(3e-4), np.log(5e-3))[None], pts, lab)[0]
    assert big < plain - 5


def test_a_stroke_shifted_rigidly_costs_little_under_the_pose_model(rng):
    """Shifting one stroke's contacts by 2 mm costs the plain Gaussian likelihood over a hundred nats and the
    pose-error model (τ 2 mm) only a few: the model absorbs what a pad pose error does."""
    pts, lab = _data(rng)
    moved = pts.copy()
    moved[lab == lab[0]] += np.array([0.0015, -0.001, 0.001])
    th = _theta(np.log(3e-4), np.log(2e-3))
    plain = [float(cm.log_likelihood(jnp.asarray(th[:11]), p, np.inf)) for p in (pts, moved)]
    pose = [pe.pose_log_likelihood(th[None], p, lab)[0] for p in (pts, moved)]
    assert plain[0] - plain[1] > 100
    assert pose[0] - pose[1] < 10


def test_log_prob_prior_and_bad_input(rng):
    pts, lab = _data(rng)
    f, bounds = pe.make_pose_log_prob(pts, lab, 1e-3)
    assert len(bounds.lower) == len(pe.POSE_PARAM_NAMES) == 12
    th = _theta(np.log(3e-4), np.log(1e-3))
    far = th.copy()
    far[11] = np.log(1e-3) + 2 * pe.TAU_LOG_SD  # two prior sds away: 2 nats lower prior, same-ish likelihood
    out = f(np.stack([th, far, np.r_[th[:11], np.log(0.05)]]))
    assert np.isfinite(out[:2]).all() and out[2] == -np.inf
    with pytest.raises(BadInput, match="strokes: expected one integer stroke label per contact"):
        pe.make_pose_log_prob(pts, lab[:-1], 1e-3)
    with pytest.raises(BadInput, match="strokes"):
        pe.make_pose_log_prob(pts, lab + 0.5, 1e-3)
    with pytest.raises(BadInput, match="tau_m"):
        pe.make_pose_log_prob(pts, lab, 0.5)
