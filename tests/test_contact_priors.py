"""The contact level's default likelihood and priors: the two-sided outlier model, free-space points, the size
prior, the Haar prior on rotations and the axis order."""

import numpy as np
import pytest

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry.rotation import rotation_matrix
from bayestouch.inference import contact as cm


def _sphere_points(m=60, r=0.02, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(m, 3))
    return r * p / np.linalg.norm(p, axis=1, keepdims=True)


def _theta(r=0.02, n=2.0, sigma=3e-4, w_in=0.05, w_out=0.02):
    return np.array([0, 0, 0, *[np.log(r)] * 3, 1.0, 1.0, 1.0, np.log(n), np.log(sigma), w_in, w_out])


def test_outlier_density_integrates_to_one_and_separates_the_sides():
    # per-point density over the signed distance d: (1 − w_in − w_out) N(0, σ²) + w_in h(d) (d < 0) + w_out h(d)
    # (d > 0), h half-Cauchy of scale s on each side
    s, sigma, w_in, w_out = 5e-3, 3e-4, 0.1, 0.03
    log_u, inv = np.log(2.0 / (np.pi * s)), 1.0 / s

    def density(d):
        return np.exp(np.asarray(cm.outlier_terms(jnp.asarray(d), np.log(sigma), w_in, w_out, log_u, inv)))

    # over ±L the heavy tails hold (w_in + w_out)(1 − (2/π) atan(L/s)) outside: the integral inside is exactly that
    L = 0.5
    d = np.concatenate(
        [np.linspace(-L, -0.01, 200001), np.linspace(-0.01, 0.01, 400001)[1:], np.linspace(0.01, L, 200001)[1:]]
    )
    inside = np.trapezoid(density(d), d)
    expect = 1.0 - (w_in + w_out) * (1.0 - 2.0 / np.pi * np.arctan(L / s))
    assert inside == pytest.approx(expect, abs=1e-5)
    # far inside the density is w_in h(d), far outside w_out h(d): the two events are told apart
    for x, w in ((-0.02, w_in), (0.02, w_out)):
        assert density(np.array([x]))[0] == pytest.approx(w * 2.0 / (np.pi * s * (1 + (x / s) ** 2)), rel=1e-9)
    # the half-Cauchy itself is normalised on (0, ∞): ∫ h = ∫_0^1 h(s tan(πu/2)) s (π/2) sec²(πu/2) du
    u = np.linspace(0.0, 1.0 - 1e-9, 200001)
    x = s * np.tan(0.5 * np.pi * u)
    jac = s * 0.5 * np.pi / np.cos(0.5 * np.pi * u) ** 2
    h = np.exp(np.asarray(cm.outlier_log_density(jnp.asarray(x), log_u, inv)))
    assert np.trapezoid(h * jac, u) == pytest.approx(1.0, abs=1e-6)


def test_outlier_model_mixed_matches_float64():
    pts = _sphere_points()
    pts[:5] *= 0.7  # five contacts displaced into the solid
    th = _theta()[None] + np.random.default_rng(1).normal(0, 1e-3, (8, 13))
    f64, _ = cm.make_log_prob(pts, noise="outlier", precision="float64")
    f32, _ = cm.make_log_prob(pts, noise="outlier", precision="mixed")
    assert np.max(np.abs(f64(th) - f32(th))) < 1e-3


def test_displaced_contacts_do_not_inflate_sigma():
    """Contacts displaced 3 mm inwards: the outlier model's likelihood prefers the true σ (0.3 mm) over a σ
    stretched to cover them (1 mm); the Student-t negative control prefers less of a difference."""
    rng = np.random.default_rng(2)
    pts = _sphere_points(80) * (1 + rng.normal(0, 3e-4 / 0.02, (80, 1)))
    pts[:8] *= 1 - 0.003 / 0.02
    f, _ = cm.make_log_prob(pts, noise="outlier")
    lo, hi = _theta(sigma=3e-4, w_in=0.1), _theta(sigma=1e-3, w_in=0.1)
    assert f(lo[None])[0] - f(hi[None])[0] > 20.0


def test_free_space_point_inside_costs_the_mislabel_probability():
    pts = _sphere_points()
    th = _theta()[None]
    f0, _ = cm.make_log_prob(pts, noise="outlier")
    f_out, _ = cm.make_log_prob(pts, noise="outlier", free=np.array([[0.03, 0.0, 0.0]]))
    f_in, _ = cm.make_log_prob(pts, noise="outlier", free=np.array([[0.01, 0.0, 0.0]]))
    priors = cm.load_priors()
    # a free point well outside costs nothing; one well inside costs log(free_miss)
    assert f_out(th)[0] == pytest.approx(f0(th)[0], abs=1e-9)
    assert f_in(th)[0] - f0(th)[0] == pytest.approx(np.log(priors.free_miss), abs=1e-3)
    # the pointwise group holds contacts then free points, and sums to the likelihood
    pw = cm.pointwise_log_likelihood(th, pts, noise="outlier", free=np.array([[0.01, 0.0, 0.0]]))
    assert pw.shape == (1, len(pts) + 1)


def test_size_prior_quantiles_and_errors():
    pr = cm.with_size_prior(cm.load_priors(), 0.01, 0.1)
    mu, sd = cm.size_prior(pr)
    # 2a = 2 exp(log a): its 2.5 % and 97.5 % quantiles are the stated range
    assert 2 * np.exp(mu - 1.959963984540054 * sd) == pytest.approx(0.01)
    assert 2 * np.exp(mu + 1.959963984540054 * sd) == pytest.approx(0.1)
    with pytest.raises(BadInput, match="size prior"):
        cm.with_size_prior(pr, 0.1, 0.01)
    with pytest.raises(BadInput, match="size prior"):
        cm.with_size_prior(pr, 0.01, 5.0)


def test_prior_draws_are_uniform_over_rotations_and_follow_the_size_prior():
    """Haar measure: E[R_ij²] = 1/3 for every entry. Uniform Euler angles give E[R_33²] = E[cos² ξ] = 1/2 (the
    negative control), 37 standard errors away at 20 000 draws."""
    b = cm.bounds_for(_sphere_points(), cm.load_priors())
    x = cm.sample_prior(b, 20000, np.random.default_rng(0))
    R = np.asarray(jax.vmap(rotation_matrix)(jnp.asarray(x[:4000, 6:9])))
    r2 = (R**2).mean(axis=0)
    se = np.sqrt(4 / 45 / 4000)  # sd of R_ij² under Haar is √(4/45)
    assert np.all(np.abs(r2 - 1 / 3) < 4 * se)
    uniform_xi = np.random.default_rng(1).uniform(0, np.pi, 4000)
    assert abs(np.mean(np.cos(uniform_xi) ** 2) - 1 / 3) > 4 * se
    # log semi-axes: normal(mu, sd) truncated far in the tails
    mu, sd = cm.size_prior(cm.load_priors())
    assert abs(x[:, 3].mean() - mu) < 4 * sd / np.sqrt(len(x))
    assert abs(x[:, 3].std() / sd - 1) < 0.03
    # log_prior includes log sin ξ: the prior draws' density ratio at two ξ is the Haar ratio
    t = x[:2].copy()
    t[:, 3:6] = mu
    t[0, 6], t[1, 6] = np.pi / 2, np.pi / 6
    lp = np.asarray(cm.log_prior(jnp.asarray(t), b))
    assert lp[0] - lp[1] == pytest.approx(np.log(2.0), abs=1e-12)


@pytest.mark.parametrize("precision", ["float64", "mixed"])
def test_log_posterior_is_the_same_at_every_alias_of_the_angles(precision):
    """The whole log-posterior (prior + likelihood, and the tempering gradients) is periodic in the Euler angles: an
    alias outside the box ψ ∈ [0, π), ζ ∈ [−π, π) scores as its wrapped twin. Clipping the angles into the box
    before the likelihood (the likelihood of the box edge everywhere beyond it: an improper plateau) is the
    negative control."""
    pts = _sphere_points()
    free = pts[:5] * 1.5
    f, b = cm.make_log_prob(pts, cm.load_priors(), noise="outlier", precision=precision, free=free)
    x = cm.sample_prior(b, 64, np.random.default_rng(3))
    x[:, 0:3] = 0.0
    x[:, 3:6] = np.log([0.03, 0.025, 0.02])
    x[:, 9:11] = [np.log(3.0), np.log(3e-4)]
    rng = np.random.default_rng(4)
    y = x.copy()
    y[:, 7] += np.pi * rng.choice([-2, -1, 1, 2], len(y))
    y[:, 8] += 2 * np.pi * rng.choice([-1, 1], len(y))
    np.testing.assert_allclose(f(y), f(x), rtol=1e-9, atol=1e-6)
    lp_x, ll_x, g_x, h_x = f.parts(x)
    lp_y, ll_y, g_y, h_y = f.parts(y)
    np.testing.assert_allclose(ll_y, ll_x, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(h_y, h_x, rtol=1e-6, atol=1e-3)
    # negative control: the same aliases with their angles clipped into the box are other surfaces
    lo, hi = np.asarray(b.lower), np.asarray(b.upper)
    z = y.copy()
    z[:, 6:9] = np.clip(z[:, 6:9], lo[6:9], hi[6:9])
    assert np.max(np.abs(f(z) - f(x))) > 10.0


def test_angles_are_periodic_and_wrap_to_the_same_surface():
    pts = _sphere_points()
    b = cm.bounds_for(pts, cm.load_priors())
    x = cm.sample_prior(b, 200, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    y = x.copy()
    # aliases outside the box: ψ + kπ, ζ + 2kπ and (ξ, ψ, ζ) → (−ξ, ψ + π, ζ + π)
    y[:, 7] += np.pi * rng.integers(-3, 4, len(y))
    y[:, 8] += 2 * np.pi * rng.integers(-3, 4, len(y))
    flip = rng.random(len(y)) < 0.5
    y[flip, 6] = -y[flip, 6] + 2 * np.pi * rng.integers(-2, 3, flip.sum())
    y[flip, 7] += np.pi
    y[flip, 8] += np.pi
    lp_x, lp_y = (np.asarray(cm.log_prior(jnp.asarray(v), b)) for v in (x, y))
    np.testing.assert_allclose(lp_y, lp_x, atol=1e-9)  # no wall at the box's angle edges; same density
    # the same surface: every point's residual agrees
    r = np.stack([np.asarray(cm.residuals(jnp.asarray(v[:11]), jnp.asarray(pts))) for v in (x[0], y[0])])
    np.testing.assert_allclose(r[1], r[0], atol=1e-12)
    w = cm.wrap_angles(y)
    lo, hi = np.asarray(b.lower), np.asarray(b.upper)
    assert np.all((w[:, 6:9] >= lo[6:9]) & (w[:, 6:9] <= hi[6:9]))
    for u, v in zip(w[:20], y[:20], strict=True):
        ru, rv = rotation_matrix(jnp.asarray(u[6:9])), rotation_matrix(jnp.asarray(v[6:9]))
        # R and R·diag(−1, −1, 1) (ψ + π) are one n-ellipsoid's frames
        assert np.allclose(ru, rv, atol=1e-9) or np.allclose(ru, rv @ np.diag([-1.0, -1.0, 1.0]), atol=1e-9)
    # negative control: a centre outside the box is still outside the prior
    z = x[:1].copy()
    z[0, 0] = float(hi[0]) + 1.0
    assert np.isinf(np.asarray(cm.log_prior(jnp.asarray(z), b))[0])


def test_a_warm_start_keeps_its_angles_and_an_ensemble_across_xi_zero_stays_one():
    """``walkers_inside`` moves walkers into the box in every non-angle column and leaves the angles alone: an
    ensemble of an orientation near ξ = 0 (half its walkers at ξ < 0, which the prior and the likelihood allow) keeps
    its spread in ξ. Clipping every column (what the exploration loop did before) leaves ξ with zero spread, and
    emcee refuses such a start (the control)."""
    import emcee

    pts = _sphere_points()
    b = cm.bounds_for(pts, cm.load_priors())
    lo, hi = np.asarray(b.lower), np.asarray(b.upper)
    x = cm.sample_prior(b, 32, np.random.default_rng(3))
    x[:, 6] = -np.abs(np.random.default_rng(4).normal(0.0, 0.02, 32))  # just below ξ = 0, as a chain can wander
    x[:5, 0] = hi[0] + 0.01  # five centres beyond the (moved) box
    got = cm.walkers_inside(x, b)
    for col, period in zip((6, 7, 8), cm.ANGLE_PERIODS, strict=True):  # the same angles, up to whole periods
        np.testing.assert_allclose(np.mod(got[:, col] - x[:, col] + 0.5 * period, period), 0.5 * period, atol=1e-12)
    np.testing.assert_allclose(got[:, 6], x[:, 6], atol=1e-15)  # ξ's spread kept where it was
    assert np.all(got[:5, 0] < hi[0]) and np.all(got[:5, 0] > hi[0] - 1e-6)
    keep = np.r_[0:6, 9 : x.shape[1]]
    np.testing.assert_array_equal(got[5:][:, keep], x[5:][:, keep])
    assert np.all(np.isfinite(np.asarray(cm.log_prior(jnp.asarray(got), b))))
    sampler = emcee.EnsembleSampler(32, x.shape[1], lambda t: float(cm.log_prior(jnp.asarray(t), b)))
    sampler.run_mcmc(got, 2)  # accepted as a start
    clipped = np.clip(x, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    assert np.std(clipped[:, 6]) < 1e-12  # every walker at the edge: the ensemble has lost a dimension

    # angles that drifted by whole periods (a million radians: what a periodic likelihood lets a chain do) come back
    # within half a period of their circular mean, the surface and the density unchanged
    far = x.copy()
    turns = np.random.default_rng(5).integers(-300_000, 300_000, (32, 3))
    far[:, 6:9] += turns * np.asarray(cm.ANGLE_PERIODS)
    back = cm.walkers_inside(far, b)
    for col, period in zip((6, 7, 8), cm.ANGLE_PERIODS, strict=True):
        assert np.ptp(back[:, col]) < period
        np.testing.assert_allclose(np.mod(back[:, col] - x[:, col] + 0.5 * period, period), 0.5 * period, atol=1e-6)
    np.testing.assert_allclose(
        np.asarray(cm.log_prior(jnp.asarray(back), b)), np.asarray(cm.log_prior(jnp.asarray(got), b)), atol=1e-6
    )
    assert np.ptp(far[:, 7]) > 1e5  # the control: as they were, the walkers span 10^5 radians


def test_the_angle_window_keeps_one_image_of_every_surface():
    """``angle_window`` restricts a log-density to one period of each Euler angle around the given centres: inside
    it is the density itself, outside −∞, and every θ has exactly one image there (``shift_angles``: whole periods,
    the same surface and density). So a chain held in the windows samples the same posterior over surfaces, and an
    angle a whole period away (which a periodic density accepts as readily as staying) is refused."""
    pts = _sphere_points()
    b = cm.bounds_for(pts, cm.load_priors())
    x = cm.sample_prior(b, 64, np.random.default_rng(7))

    def logp(t):
        return np.asarray(cm.log_prior(jnp.asarray(t), b))

    centres = np.array([1.0, -0.4, 2.5])
    windowed = cm.angle_window(logp, centres)
    far = x.copy()
    far[:, 6:9] += np.random.default_rng(8).integers(-1000, 1000, (64, 3)) * np.asarray(cm.ANGLE_PERIODS)
    home = cm.shift_angles(far, centres)
    half = 0.5 * np.asarray(cm.ANGLE_PERIODS)
    assert np.all((home[:, 6:9] >= centres - half) & (home[:, 6:9] < centres + half))
    np.testing.assert_allclose(cm.wrap_angles(home), cm.wrap_angles(x), atol=1e-9)  # the same surfaces
    np.testing.assert_allclose(windowed(home), logp(x), atol=1e-9)
    moved = np.any(np.abs(far[:, 6:9] - home[:, 6:9]) > 1.0, axis=1)
    assert moved.all() and np.all(np.isneginf(windowed(far)))  # the far images refused
    # the circular means move with the draws by whole periods only, and sit among the draws they are taken of
    turn = (cm.angle_centres(home) - cm.angle_centres(x)) / np.asarray(cm.ANGLE_PERIODS)
    np.testing.assert_allclose(turn, np.round(turn), atol=1e-9)
    assert np.all(np.abs(cm.angle_centres(far) - np.median(far[:, 6:9], axis=0)) <= half + 1e-9)
    # just inside and just beyond each window's upper edge
    for j, col in enumerate((6, 7, 8)):
        edge = home[:1].copy()
        edge[0, col] = centres[j] + half[j] - 1e-9
        beyond = edge.copy()
        beyond[0, col] += 2e-9
        assert np.isfinite(windowed(edge)[0]) and np.isneginf(windowed(beyond)[0])
