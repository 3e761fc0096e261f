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


# --- the pose-error law from an ensemble of drawn fingers ---------------------------------------------------------


def _ensemble_case(rng, sizes=(5, 8, 4), K=9):
    m = sum(sizes)
    pts = rng.normal(0, 0.02, (m, 3))
    ens = rng.normal(0, 1e-3, (K, m, 3)) + 2e-4
    lab = np.repeat(np.arange(len(sizes)) * 3, sizes)  # any integer labels, strokes of unequal length
    return pts, ens, lab, rng.uniform(0, 10, m)


def test_the_ensemble_law_is_the_dense_gaussian_of_its_parts(rng):
    """Linearised once (relinearise=0), the blocked Woodbury form equals the multivariate normal with covariance
    σ² I + s² B Bᵀ + s² (a aᵀ ∘ ρ) evaluated densely: B the leading components and the per-stroke offsets along
    the model's normals, a the remainder's sd along them, ρ = exp(−|Δt|/ℓ) within a stroke and 0 across strokes."""
    pts, ens, lab, t = _ensemble_case(rng)
    th = _theta(np.log(5e-4), np.log(1.3))
    mod = pe.ensemble_model(pts, ens, lab, t, rank=3)
    got = pe.ensemble_log_likelihood(th[None], mod, relinearise=0)[0]
    hom = np.c_[mod.moved, np.ones(len(pts))].T
    f = cm.principal_frame(jnp.asarray(th[None]), jnp.asarray(hom))
    n, d = np.asarray(cm.frame_normals(f))[0], np.asarray(f.d)[0]
    B = 1.3 * np.einsum("cm,cmk->mk", n, mod.lead)
    a = np.sqrt(np.einsum("cm,cem,em->m", n, mod.resid, n))
    rho = np.exp(-np.abs(t[:, None] - t[None, :]) / mod.ell) * (lab[:, None] == lab[None, :])
    cov = 5e-4**2 * np.eye(len(pts)) + B @ B.T + 1.3**2 * np.outer(a, a) * rho
    assert got == pytest.approx(multivariate_normal(np.zeros(len(pts)), cov).logpdf(d), abs=1e-8 * abs(got))
    # the leading components and the remainder add up to the ensemble's per-contact covariance
    dev = (ens - ens.mean(0)) / np.sqrt(len(ens) - 1)
    full = np.einsum("kmc,kme->cem", dev, dev)
    lead, off = mod.lead[..., :3], mod.lead[..., 3:]
    np.testing.assert_allclose(np.einsum("cmk,emk->cem", lead, lead) + mod.resid, full, atol=1e-15)
    # and the offsets are one per stroke: covariance offset_sd² I₃ between contacts of a stroke, 0 across strokes
    same = (lab[:, None] == lab[None, :]).astype(float)
    want = pe.OFFSET_SD**2 * np.einsum("ij,ce->ciej", same, np.eye(3))
    np.testing.assert_allclose(np.einsum("cik,ejk->ciej", off, off), want, atol=1e-18)


def test_correlation_time_recovers_an_ornstein_uhlenbeck_remainder():
    """Remainders drawn as an Ornstein–Uhlenbeck process of correlation time 2 s along each stroke give ℓ within
    10 % (Monte Carlo sd about 3 % at 400 draws); white remainders (the negative control) give an ℓ at which
    neighbouring contacts (0.8 s apart) are uncorrelated."""
    g = np.random.default_rng(7)
    t = np.tile(np.linspace(0.0, 12.0, 16), 3)
    lab = np.repeat([0, 1, 2], 16)
    cov = np.exp(-np.abs(t[:, None] - t[None, :]) / 2.0) * (lab[:, None] == lab[None, :])
    ou = np.einsum("ij,kjc->kic", np.linalg.cholesky(cov), g.normal(size=(400, 48, 3)))
    assert pe.correlation_time(ou, lab, t) == pytest.approx(2.0, rel=0.1)
    assert np.exp(-0.8 / pe.correlation_time(g.normal(size=(400, 48, 3)), lab, t)) < 0.01


def test_relinearising_removes_the_curvature_bias_of_large_pose_errors():
    """A 20 mm sphere touched along two arcs whose contacts are recorded 3 mm off (one rigid offset per stroke,
    drawn as the ensemble's are): linear in the pose error, the law misreads the curvature of 3 mm tangential
    shifts (|e_t|²/2R ≈ 0.2 mm against 0.1 mm noise); linearised again about the pose error's posterior mean, the
    radius that maximises the likelihood is on average closer to the truth."""
    g = np.random.default_rng(4)
    R, per = 0.02, 30
    arcs = []
    for _ in range(2):
        u = g.normal(size=3)
        u /= np.linalg.norm(u)
        v = np.cross(u, g.normal(size=3))
        v /= np.linalg.norm(v)
        ang = g.uniform(0, 2 * np.pi) + np.linspace(0, 0.8, per)
        arcs.append(R * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v))
    x, lab, t = np.concatenate(arcs), np.repeat([0, 1], per), np.tile(np.linspace(0, 10, per), 2)
    ens = g.normal(0, 3e-3, (60, 2, 3))[:, lab]
    radii = R * np.linspace(0.9, 1.1, 201)
    th = np.array([[0, 0, 0, *[np.log(r)] * 3, 0.3, 0.2, 0.1, np.log(2.0), np.log(1e-4), 0.0] for r in radii])
    err = {0: [], 1: []}
    for _ in range(12):
        e = g.normal(0, 3e-3, (2, 3))[lab]
        mod = pe.ensemble_model(x - e + g.normal(0, 1e-4, x.shape), ens, lab, t, offset_sd=0.0)
        for k in err:
            err[k].append(radii[np.argmax(pe.ensemble_log_likelihood(th, mod, relinearise=k))] / R - 1)
    lin, relin = np.abs(err[0]).mean(), np.abs(err[1]).mean()
    assert relin < 0.7 * lin
    assert abs(np.mean(err[1])) < 0.015


def test_ensemble_log_prob_prior_and_bad_input(rng):
    pts, ens, lab, t = _ensemble_case(rng)
    mod = pe.ensemble_model(pts, ens, lab, t)
    assert mod.lead.shape[-1] == min(pe.RANK, len(ens) - 1) + 3 * len(np.unique(lab))
    assert pe.ensemble_model(pts, ens, lab, t, offset_sd=0).lead.shape[-1] == min(pe.RANK, len(ens) - 1)
    f, bounds = pe.make_ensemble_pose_log_prob(mod)
    assert len(bounds.lower) == len(pe.ENSEMBLE_PARAM_NAMES) == 12
    th = _theta(np.log(5e-4), 0.0)
    far = np.r_[th[:11], 2 * pe.SCALE_LOG_SD]
    out = f(np.stack([th, far, np.r_[th[:11], np.log(50.0)]]))
    assert np.isfinite(out[:2]).all() and out[2] == -np.inf
    with pytest.raises(BadInput, match="ensemble: expected finite pose errors of shape"):
        pe.ensemble_model(pts, ens[:, :-1], lab, t)
    with pytest.raises(BadInput, match="times: expected one finite time"):
        pe.ensemble_model(pts, ens, lab, t[:-1])
    with pytest.raises(BadInput, match="rank: expected an integer in"):
        pe.ensemble_model(pts, ens, lab, t, rank=len(ens))
    for bad in (-1e-3, np.nan, "1 mm", 0.5):
        with pytest.raises(BadInput, match=r"offset_sd: expected a per-stroke offset sd in metres in \[0, 0.1\)"):
            pe.ensemble_model(pts, ens, lab, t, offset_sd=bad)
    with pytest.raises(BadInput, match="relinearise"):
        pe.make_ensemble_pose_log_prob(mod, relinearise=-1)
    with pytest.raises(BadInput, match="thetas"):
        f(np.zeros((2, 11)))


def test_the_offset_absorbs_a_stroke_shift_the_drawn_fingers_do_not_make(rng):
    """An ensemble of fingers that barely differ (0.01 mm) and one stroke's contacts recorded 2 mm off: without
    the per-stroke offset the law charges the shift hundreds of nats (the negative control); with the default
    1 mm offset a few, as the single-offset pose model does for its τ."""
    pts, lab = _data(rng)
    t = np.tile(np.linspace(0.0, 10.0, np.sum(lab == lab[0])), len(np.unique(lab)))
    moved = pts.copy()
    moved[lab == lab[0]] += np.array([0.0015, -0.001, 0.001])
    ens = rng.normal(0, 1e-5, (12, len(pts), 3))
    th = _theta(np.log(3e-4), 0.0)[None]
    cost = {}
    for sd in (0.0, pe.OFFSET_SD):
        ll = [pe.ensemble_log_likelihood(th, pe.ensemble_model(p, ens, lab, t, offset_sd=sd))[0] for p in (pts, moved)]
        cost[sd] = ll[0] - ll[1]
    assert cost[0.0] > 100
    assert cost[pe.OFFSET_SD] < 10
