"""Contact-level model: residuals, priors, the never-NaN log-probability, robust recovery."""

import numpy as np
import pytest
from scipy.optimize import minimize

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_surface
from bayestouch.inference import contact as cm

TRUTH = np.concatenate(
    [[0.004, -0.002, 0.001], np.log([0.03, 0.022, 0.015]), [0.4, 0.3, -0.5], [np.log(3.0)], [np.log(3e-4)]]
)


def test_residuals_exact_on_sphere_and_zero_on_surface():
    theta = np.concatenate([[0.01, 0, 0], np.log([0.02] * 3), [0.3, 0.2, 0.1], [np.log(2.0)], [0.0]])
    x = np.random.default_rng(0).normal(0, 0.03, (100, 3)) + [0.01, 0, 0]
    exact = np.linalg.norm(x - [0.01, 0, 0], axis=1) - 0.02
    np.testing.assert_allclose(np.asarray(cm.residuals(jnp.asarray(theta), jnp.asarray(x))), exact, atol=1e-12)
    s = cm.shape_of(jnp.asarray(TRUTH))
    on = sample_surface(s, 300, seed=1)
    assert np.abs(np.asarray(cm.residuals(jnp.asarray(TRUTH), jnp.asarray(on)))).max() < 1e-9


@pytest.mark.parametrize("n", [3.0, 5.0, 10.0])
def test_first_order_distance_is_the_offset_along_the_normal_on_box_like_faces(n):
    """A surface point moved δ along its outward normal lies at first-order distance δ (to O(δ²κ)) everywhere on a
    box-like n-ellipsoid, including the flat faces of its two equal largest semi-axes, whose support distance
    exceeds the largest semi-axis (there a floor of |∇G| at 1/max(a) shrank the distance by up to 1/1.35)."""
    theta = np.concatenate([[0.002, -0.001, 0.003], np.log([0.035, 0.015, 0.035]), [0.7, 1.1, -0.4], [np.log(n)], [0]])
    s = cm.shape_of(jnp.asarray(theta))
    on = sample_surface(s, 4000, seed=5)
    nrm = np.asarray(ne.normals(s, jnp.asarray(on)))
    q = (on - np.asarray(s.centre)) @ np.asarray(s.rotation) / np.asarray(s.axes)
    support = 1 / np.linalg.norm(np.abs(q) ** (n - 1) / np.asarray(s.axes), axis=1)  # h = 1/|∇G| on the surface
    beyond = support > 0.035 * (1 + 1e-3)  # where a floor at 1/max(a) would act
    assert beyond.mean() > 0.1  # the faces that the old floor distorted are sampled
    for delta in (2e-4, -2e-4):
        d = np.asarray(cm.residuals(jnp.asarray(theta), jnp.asarray(on + delta * nrm)))
        local = np.asarray(ne.to_local(s, jnp.asarray(on + delta * nrm)))
        d_geom = np.asarray(ne.first_order_distance(s, jnp.asarray(local))[0])
        # the likelihood's batched distance (what the sampler reads) is the same
        f = cm.principal_frame(
            jnp.asarray(theta[None]), jnp.asarray(np.r_[(on + delta * nrm).T, np.ones((1, len(on)))])
        )
        np.testing.assert_allclose(np.asarray(f.d[0]), d, rtol=1e-9, atol=1e-15)
        # second order: |d − δ| ~ δ² κ, a few % of δ at the sharpest edges sampled (n = 10)
        np.testing.assert_allclose(d, delta, rtol=0.05)
        np.testing.assert_allclose(d_geom, delta, rtol=0.05)
        assert np.median(np.abs(d[beyond] / delta - 1)) < 1e-3


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
    beyond = (wild < np.asarray(b.lower)) | (wild > np.asarray(b.upper))
    outside = np.any(np.delete(beyond, [6, 7, 8], axis=1), axis=1)  # the Euler angles are periodic, never outside
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
    res = minimize(
        lambda t: tuple(np.asarray(v) for v in g(jnp.asarray(t))),
        start,
        jac=True,
        method="L-BFGS-B",
        bounds=list(zip(np.asarray(b.lower), np.asarray(b.upper), strict=True)),
    )
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


# --- the fast batched log-probability against plain references, and the likelihood options (issue 4) ---------


def _np_geometry(theta, x):
    """NumPy float64 reference: first-order distance (G − 1)/|∇G| and the world unit normal ∇G/|∇G|."""
    c, a, n = theta[:3], np.exp(theta[3:6]), np.exp(theta[9])
    R = np.asarray(ne.NEllipsoid(jnp.asarray(c), jnp.asarray(a), jnp.asarray(theta[6:9]), jnp.asarray(n)).rotation)
    q = (x - c) @ R / a
    S = np.sum(np.abs(q) ** n, axis=1)
    G = S ** (1 / n)
    grad = (G / S)[:, None] * np.sign(q) * np.abs(q) ** (n - 1) / a  # ∂G/∂y in the principal frame
    gn = np.maximum(np.linalg.norm(grad, axis=1), 1 / np.linalg.norm(a))  # only the centre reaches the floor
    g = grad @ R.T
    return (G - 1) / gn, g / np.linalg.norm(g, axis=1, keepdims=True)


def _np_log_prob(theta, x, nu=4.0, normals=None, noise="student", origin=None):
    """The model's log-likelihood written out in NumPy (scipy for the Student-t density)."""
    from scipy import stats

    r, nw = _np_geometry(theta, x)
    sig, k, out = np.exp(theta[10]), 11, 0.0
    if normals is not None:
        kap = np.exp(theta[k])
        out += np.sum(np.log(kap / (4 * np.pi * np.sinh(kap))) + kap * np.sum(normals * nw, axis=1))
        k += 1
    if noise == "student":
        return out + np.sum(stats.t.logpdf(r, nu, scale=sig) if np.isfinite(nu) else stats.norm.logpdf(r, 0, sig))
    if noise == "multiplicative":
        o = x.mean(axis=0) if origin is None else origin
        var = sig**2 + np.exp(theta[k]) ** 2 / 3 * np.sum(nw**2 * (x - o) ** 2, axis=1)
        return out + np.sum(stats.norm.logpdf(r, 0, np.sqrt(var)))
    w, d = theta[k], np.linalg.norm(x.max(axis=0) - x.min(axis=0))
    return out + np.sum(np.log((1 - w) * stats.norm.pdf(r, 0, sig) + w / (2 * d)))


def _vmf(mu, kappa, rng):
    """Unit vectors (M, 3) von Mises–Fisher distributed about the unit vectors ``mu`` (Wood 1994, exact on S²)."""
    u = rng.uniform(size=len(mu))
    w = 1 + np.log(u + (1 - u) * np.exp(-2 * kappa)) / kappa
    v = rng.normal(size=mu.shape)
    v -= np.sum(v * mu, axis=1, keepdims=True) * mu
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return w[:, None] * mu + np.sqrt(1 - w**2)[:, None] * v


def _lik(f, b, th):
    """The log-likelihood part of ``f``'s log-posterior: minus the prior density (size prior, Haar measure)."""
    th = np.atleast_2d(th)
    return f(th) - np.asarray(cm.log_prior(jnp.asarray(th), b))


@pytest.fixture(scope="module")
def walkers():
    """Points near TRUTH's surface (with 5 % outliers) and 24 walkers spread over n, axes and angles."""
    rng = np.random.default_rng(11)
    s = cm.shape_of(jnp.asarray(TRUTH))
    on = sample_surface(s, 400, seed=11)
    pts = on + rng.normal(0, 3e-4, on.shape)
    pts[:20] += rng.uniform(-0.01, 0.01, (20, 3))
    W = TRUTH + np.concatenate(
        [
            rng.normal(0, 2e-3, (24, 3)),
            rng.normal(0, 0.1, (24, 3)),
            rng.normal(0, 0.3, (24, 3)),
            rng.normal(0, 0.4, (24, 1)),
            rng.normal(0, 0.3, (24, 1)),
        ],
        axis=1,
    )
    W[:, 6:9] = np.clip(W[:, 6:9], [0, 0, -np.pi], [np.pi, np.pi - 1e-9, np.pi - 1e-9])
    W[:, 9] = np.clip(W[:, 9], np.log(1.2), np.log(16.0))
    return pts, W, np.asarray(ne.normals(s, jnp.asarray(on)))


@pytest.mark.parametrize("nu", [4.0, np.inf])
def test_fast_log_prob_equals_the_first_order_distance_reference(walkers, nu):
    """The fused batched log-probability equals Σ log t(r/σ) − M log σ built from ``first_order_distance``."""
    from jax.scipy.special import gammaln

    pts, W, _ = walkers
    f, b = cm.make_log_prob(pts, nu=nu)
    ref = []
    res = np.asarray(jax.jit(jax.vmap(cm.residuals, (0, None)))(jnp.asarray(W), jnp.asarray(pts)))
    for th, r in zip(W, res, strict=True):
        z2 = (r / np.exp(th[10])) ** 2
        if np.isinf(nu):
            ref.append(-0.5 * z2.sum() - len(pts) * (th[10] + 0.5 * np.log(2 * np.pi)))
        else:
            c = float(gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * np.log(nu * np.pi))
            ref.append(len(pts) * (c - th[10]) - 0.5 * (nu + 1) * np.sum(np.log1p(z2 / nu)))
    out = _lik(f, b, W)
    np.testing.assert_allclose(out, ref, rtol=1e-12)
    np.testing.assert_allclose(out, [_np_log_prob(th, pts, nu) for th in W], rtol=1e-12)
    # negative control: a walker's log-probability is not that of another (the comparison can fail)
    assert np.max(np.abs(out[1:] / np.asarray(ref[:-1]) - 1)) > 1e-3


@pytest.mark.parametrize("noise", ["multiplicative", "mixture"])
def test_options_equal_their_numpy_formulas_and_grow_theta(walkers, noise):
    """Normals (vMF) with each new noise model: value = the written-out NumPy formula; names and box match."""
    pts, W, nrm = walkers
    extra = {"multiplicative": np.log(3e-3), "mixture": 0.1}[noise]
    th = np.column_stack([W, np.full(len(W), np.log(50.0)), np.full(len(W), extra)])
    f, b = cm.make_log_prob(pts, normals=nrm, noise=noise)
    names = cm.param_names(True, noise)
    assert names[:11] == cm.PARAM_NAMES and names[11] == "log_kappa" and len(names) == len(b.lower) == 13
    assert names[12] == {"multiplicative": "log_eps", "mixture": "w_outlier"}[noise]
    np.testing.assert_allclose(_lik(f, b, th), [_np_log_prob(t, pts, normals=nrm, noise=noise) for t in th], rtol=1e-12)
    assert cm.param_names() == cm.PARAM_NAMES and len(cm.bounds_for(pts, cm.load_priors()).lower) == 11
    rng = np.random.default_rng(12)
    wild = rng.uniform(np.asarray(b.lower), np.asarray(b.upper), (300, 13))
    wild[::2] += rng.normal(0, 0.1, (150, 13)) * (rng.uniform(size=(150, 13)) < 0.2)  # half of them pushed out
    out = f(wild)
    beyond = (wild < np.asarray(b.lower)) | (wild > np.asarray(b.upper))
    outside = np.any(np.delete(beyond, [6, 7, 8], axis=1), axis=1)  # the Euler angles are periodic, never outside
    assert np.all(out[outside] == -np.inf) and np.all(np.isfinite(out[~outside])) and (~outside).sum() > 0


def test_bad_options_are_one_line_bad_input(walkers):
    from bayestouch.errors import BadInput

    pts, _, nrm = walkers
    for kwargs, field in [
        ({"noise": "cauchy"}, "noise"),
        ({"noise": "mixture", "nu": 3.0}, "nu"),
        ({"normals": nrm[:10]}, "normals"),
        ({"nu": -1.0}, "nu"),
    ]:
        with pytest.raises(BadInput, match=f"^{field}: "):
            cm.make_log_prob(pts, **kwargs)
    with pytest.raises(BadInput, match="^points: "):
        cm.make_log_prob(np.ones((5, 2)))
    f, _ = cm.make_log_prob(pts)
    with pytest.raises(BadInput, match="^thetas: "):
        f(np.zeros((3, 12)))


def _mode(f, base, index, grid):
    th = np.tile(base, (len(grid), 1))
    th[:, index] = grid
    v = f(th)
    return grid[np.argmax(v)], v.max()


def test_vmf_concentration_mode_is_the_closed_form_mle_and_recovers_kappa():
    """Shape fixed at the truth, points on it: p(log κ | normals) peaks where coth κ − 1/κ = mean(m·m̂)."""
    from scipy.optimize import brentq

    s = cm.shape_of(jnp.asarray(TRUTH))
    on = sample_surface(s, 500, seed=13)
    true_n = np.asarray(ne.normals(s, jnp.asarray(on)))
    kappa = 200.0
    meas = _vmf(true_n, kappa, np.random.default_rng(13))
    f, _ = cm.make_log_prob(on, normals=meas)
    rbar = np.mean(np.sum(meas * true_n, axis=1))
    k_hat = brentq(lambda k: 1 / np.tanh(k) - 1 / k - rbar, 1e-3, 1e6)
    base = np.append(TRUTH, 0.0)
    grid = np.log(k_hat) + np.linspace(-0.05, 0.05, 401)
    assert _mode(f, base, 11, grid)[0] == pytest.approx(np.log(k_hat), abs=grid[1] - grid[0])
    # for large κ, Σ(1 − m·m̂) is Gamma(M, 1/κ): sd(log κ̂) ≈ 1/√M = 0.045; allow 4 sd
    assert abs(np.log(k_hat / kappa)) < 4 / np.sqrt(len(on))
    # negative control: isotropic normals carry no information, the mode sits at the prior's lower bound
    rng = np.random.default_rng(14)
    iso = rng.normal(size=on.shape)
    f0, b0 = cm.make_log_prob(on, normals=iso)
    grid = np.linspace(float(b0.lower[11]), float(b0.upper[11]), 401)
    assert _mode(f0, base, 11, grid)[0] == grid[0]


def test_multiplicative_noise_recovers_epsilon_and_beats_additive_only_when_it_should():
    """The paper's perturbation x' = o + (x − o)(1 + r), r ~ U[−ε, ε], of a sphere; shape fixed at the truth."""
    from bayestouch.paper import perturb

    c0, rad, eps = np.array([0.01, -0.005, 0.002]), 0.02, 0.01
    sph = np.concatenate([c0, np.log([rad] * 3), [0.3, 0.2, 0.1], [np.log(2.0)], [np.log(1e-6)]])
    on = sample_surface(cm.shape_of(jnp.asarray(sph)), 1000, seed=15)
    origin = c0 - [0.04, 0.0, 0.0]  # the perturbation's frame origin, off the centre: levers 2–6 cm
    pts = perturb(on, eps, seed=15, origin=origin)
    f, b = cm.make_log_prob(pts, noise="multiplicative", origin=origin)
    # closed form: with σ → 0, the Gaussian MLE of ε² is mean(r² / (Σ n_k² (x_k − o_k)² / 3))
    r = np.linalg.norm(pts - c0, axis=1) - rad
    nrm = (pts - c0) / np.linalg.norm(pts - c0, axis=1, keepdims=True)
    lever = np.sum(nrm**2 * (pts - origin) ** 2, axis=1) / 3
    e_hat = np.sqrt(np.mean(r**2 / lever))
    grid = np.log(e_hat) + np.linspace(-0.02, 0.02, 401)
    e_mode, ll_mult = _mode(f, np.append(sph, 0.0), 11, grid)
    assert e_mode == pytest.approx(np.log(e_hat), abs=grid[1] - grid[0])
    # r/√v is a weighted sum of uniforms (kurtosis ≤ 3), so sd(ε̂²)/ε² ≤ √(2/M) and sd(log ε̂) ≤ 0.016; 4 sd
    assert abs(np.log(e_hat / eps)) < 4 * np.sqrt(2 / len(pts)) / 2
    # the additive Gaussian model (best σ) explains the same data worse: the lever structure is real ... (a wrong
    # variance profile costs ≈ M Var(log v_i)/4 nats, ≈ 100 here; chance differences between one-parameter
    # fits are a few nats (χ²₁/2 < 3.3 at 99 %), so 50 nats separates the two cases)
    g, _ = cm.make_log_prob(pts, nu=np.inf)
    sig = np.sqrt(np.mean(r**2))
    ll_add = _mode(g, sph, 10, np.log(sig) + np.linspace(-0.3, 0.3, 401))[1]
    assert ll_mult > ll_add + 50
    # ... and on homoscedastic data of the same size the multiplicative model (σ at its floor) is the worse one
    hom = on + rng_normal(len(on), sig) * nrm
    fh, _ = cm.make_log_prob(hom, noise="multiplicative", origin=origin)
    gh, _ = cm.make_log_prob(hom, nu=np.inf)
    ll_mult_h = _mode(fh, np.append(sph, 0.0), 11, np.log(eps) + np.linspace(-1, 1, 401))[1]
    ll_add_h = _mode(gh, sph, 10, np.log(sig) + np.linspace(-0.3, 0.3, 401))[1]
    assert ll_add_h > ll_mult_h + 50


def rng_normal(m, scale):
    return np.random.default_rng(16).normal(0, scale, (m, 1))


def test_outlier_mixture_recovers_fraction_and_scale_where_gaussian_inflates():
    """Shape fixed at the truth; 15 % of the residuals uniform over ±D: the mixture's (σ, w) MLE is near the truth."""
    s = cm.shape_of(jnp.asarray(TRUTH))
    rng = np.random.default_rng(17)
    on = sample_surface(s, 1000, seed=17)
    nrm = np.asarray(ne.normals(s, jnp.asarray(on)))
    sig, w = 3e-4, 0.15
    d = np.linalg.norm(on.max(axis=0) - on.min(axis=0))
    out = rng.uniform(size=len(on)) < w
    res = np.where(out, rng.uniform(-0.3 * d, 0.3 * d, len(on)), rng.normal(0, sig, len(on)))
    pts = on + res[:, None] * nrm
    f, b = cm.make_log_prob(pts, noise="mixture")
    ls, ws = np.meshgrid(np.log(sig) + np.linspace(-0.3, 0.3, 41), np.linspace(0.05, 0.3, 41), indexing="ij")
    th = np.tile(np.append(TRUTH, 0.0), (ls.size, 1))
    th[:, 10], th[:, 11] = ls.ravel(), ws.ravel()
    best = th[np.argmax(f(th))]
    # the outliers are found: w within 4 binomial sd of the realised fraction; σ within 4 sd (sd(log σ̂) ≈ 1/√(2M))
    assert abs(best[11] - out.mean()) < 4 * np.sqrt(w * (1 - w) / len(on)) + 0.005
    assert abs(best[10] - np.log(np.std(res[~out]))) < 4 / np.sqrt(2 * (~out).sum()) + 0.01
    # negative control: the Gaussian's best σ is inflated many times by the same outliers
    g, _ = cm.make_log_prob(pts, nu=np.inf)
    assert np.exp(_mode(g, TRUTH, 10, np.linspace(np.log(1e-5), np.log(1e-2), 401))[0]) > 10 * sig


# --- mixed precision (float32 per-point transcendentals, float64 affine map and sum): opt-in, not the default ---


def _mixed_case(m, seed):
    """M points (σ = 0.3 mm, a ≤ 3 cm) and 200 walkers: 100 near the mode (σ from 3 µm to 0.3 mm, where a/σ
    runs from 100 to 10⁴), 100 anywhere in the prior box."""
    rng = np.random.default_rng(seed)
    on = sample_surface(cm.shape_of(jnp.asarray(TRUTH)), m, seed=seed)
    pts = on + rng.normal(0, 3e-4, on.shape)
    f, b = cm.make_log_prob(pts)
    g, _ = cm.make_log_prob(pts, precision="mixed")
    near = TRUTH + rng.normal(0, 1, (100, 11)) * np.r_[[3e-4] * 3, [0.01] * 3, [0.01] * 3, 0.03, 0.0]
    near[:, 10] = np.log(3e-4) - rng.uniform(0, np.log(100), 100)
    far = rng.uniform(np.asarray(b.lower), np.asarray(b.upper), (100, 11))
    return pts, f, g, np.vstack([near, far])


@pytest.mark.parametrize("m", [1000, 10000])
def test_mixed_precision_error_is_float32_resolution_of_the_residual(m):
    """float32 resolves G ≈ 1 to ~1e-7, so each point's term is off by ~1e-7 (a/σ) ψ(r/σ) (ψ ≤ ~1 for ν = 4),
    independently between points: the sum is off by ~1e-7 (a/σ) √M. Assert a bound 10× that, per walker."""
    pts, f, g, th = _mixed_case(m, 21)
    ref, out = f(th), g(th)
    assert not np.isnan(out).any() and np.array_equal(np.isfinite(out), np.isfinite(ref))
    err = np.abs(out - ref)
    ok = np.isfinite(ref)
    near = th[:100]
    bound = 1e-6 * np.exp(near[:, 3:6]).max(axis=1) / np.exp(near[:, 10]) * np.sqrt(m)
    assert np.all(err[:100] <= bound), np.max(err[:100] / bound)
    # where the data are best explained (σ = 0.3 mm, a/σ = 100), M = 1000 meets the 1e-3-nat criterion ...
    best = np.abs(th[:100, 10] - np.log(3e-4)) < 0.2
    if m == 1000:
        assert err[:100][best].max() < 1e-3
    else:  # ... and M = 10,000 does not: the reason float64 stays the default (flip it if this starts failing)
        assert err[:100][best].max() > 1e-3
    # far from the mode the error is small relative to |log p| (there log-probability differences are huge)
    assert np.all(err[100:][ok[100:]] <= 1e-4 * np.abs(ref[100:][ok[100:]]))


def _prior_of(th, pts):
    return np.asarray(cm.log_prior(jnp.asarray(th), cm.bounds_for(pts, cm.load_priors())))


def test_mixed_precision_sums_in_float64_and_float32_accumulation_would_not():
    """Negative control: the same per-point terms, exact but accumulated in float32 (sequentially), miss the sum
    by far more than the mixed kernel does (a float32 total of ~6e4 nats alone has a 4e-3-nat spacing)."""
    pts, f, g, th = _mixed_case(10000, 22)
    near = th[:20].copy()
    near[:, 10] = np.log(3e-4)  # the data's σ: where the mixed kernel is accurate
    ref = f(near)
    terms = cm.pointwise_log_likelihood(near, pts, cm.load_priors().student_nu)
    f32 = np.cumsum(terms.astype(np.float32), axis=1, dtype=np.float32)[:, -1].astype(float)
    ref = ref - _prior_of(near, pts)
    np.testing.assert_allclose(terms.sum(axis=1), ref, rtol=1e-12)  # the pointwise terms are the float64 sum's
    err32, err_mixed = np.abs(f32 - ref), np.abs(g(near) - _prior_of(near, pts) - ref)
    assert np.median(err32) > 1e-2 and np.median(err32) > 10 * np.median(err_mixed)


def test_precision_option_checks():
    from bayestouch.errors import BadInput

    pts = sample_surface(cm.shape_of(jnp.asarray(TRUTH)), 50, seed=23)
    for kwargs in [{"precision": "float16"}, {"precision": "mixed", "noise": "mixture"}]:
        with pytest.raises(BadInput, match="^precision: "):
            cm.make_log_prob(pts, **kwargs)
    with pytest.raises(BadInput, match="^precision: "):
        cm.make_log_prob(pts, normals=pts, precision="mixed")
    # the default is float64: bit-identical to the explicit option
    f, _ = cm.make_log_prob(pts)
    f64, _ = cm.make_log_prob(pts, precision="float64")
    assert np.array_equal(f(TRUTH[None]), f64(TRUTH[None]))


def test_padded_log_prob_equals_the_unpadded_sum_and_sizes_share_one_program():
    """make_log_prob pads the data to padded_size columns masked out of every sum: its value (float64 and mixed
    precision, contacts and free-space points, outlier noise) and its tempering gradient equal the unpadded
    pointwise terms' sum; two data sets in one size bucket compile one program (negative control: a set in the
    next bucket compiles another)."""
    sizes = [cm.padded_size(n) for n in range(1, 3000)]
    n = np.arange(1, 3000)
    assert np.all(np.diff(sizes) >= 0) and np.all(np.asarray(sizes) >= n) and np.all(np.asarray(sizes) % 8 == 0)
    assert np.all(np.asarray(sizes)[n > 64] <= 1.19 * n[n > 64] + 8)
    rng = np.random.default_rng(5)
    s = ne.NEllipsoid(jnp.zeros(3), jnp.array([0.03, 0.02, 0.015]), jnp.array([0.3, 0.5, 0.2]), jnp.asarray(3.0))
    pts = sample_surface(s, 90, 5) + rng.normal(0, 3e-4, (90, 3))
    free = pts[:12] * 1.4
    assert cm.padded_size(90 + 12) > 102
    priors = cm.load_priors()
    for precision in ("float64", "mixed"):
        f, b = cm.make_log_prob(pts, priors, noise="outlier", precision=precision, free=free)
        th = np.column_stack(
            [
                rng.normal(0, 1e-3, (6, 3)),
                np.log([[0.03, 0.02, 0.015]] * 6),
                [[0.3, 0.5, 0.2]] * 6,
                np.full((6, 1), np.log(3.0)),
                np.full((6, 1), np.log(3e-4)),
                np.full((6, 2), 0.02),
            ]
        )
        ref = cm.pointwise_log_likelihood(th, pts, noise="outlier", free=free, free_miss=priors.free_miss).sum(axis=1)
        ref = ref + np.asarray(cm.log_prior(jnp.asarray(th), b))
        tol = 1e-9 if precision == "float64" else 1e-3
        np.testing.assert_allclose(f(th), ref, rtol=0, atol=tol)
        _, ll, _, g = f.parts(th)
        assert np.all(np.isfinite(g))
        if precision == "float64":  # the masked columns add nothing to the gradient: finite differences agree
            h = 1e-7
            e = np.zeros_like(th)
            e[:, 3] = h
            fd = (f.parts(th + e)[1] - f.parts(th - e)[1]) / (2 * h)
            np.testing.assert_allclose(g[:, 3], fd, rtol=1e-5)
    jit = cm._log_prob_jit
    f1, b1 = cm.make_log_prob(pts[:70], priors, noise="outlier")
    f1(th[:2])
    before = jit._cache_size()
    cm.make_log_prob(pts[:75], priors, noise="outlier")[0](th[:2])  # 70 and 75 share the bucket of 80
    assert cm.padded_size(70) == cm.padded_size(75) == 80 and cm.padded_size(81) == 96
    assert jit._cache_size() == before
    cm.make_log_prob(pts[:81], priors, noise="outlier")[0](th[:2])  # 81 pads to 96: a new program
    assert jit._cache_size() == before + 1


def test_tempering_terms_in_blocks_equal_the_rows_one_by_one():
    """The SMC's 2048 particles are evaluated in blocks of TEMPERING_BLOCK rows (a 2.3x faster gradient here):
    every row's log-prior, log-likelihood and gradients equal those of the same row evaluated alone in a small
    batch. Negative control: a block whose rows were permuted gives other rows, so the comparison can fail."""
    rng = np.random.default_rng(5)
    d = rng.normal(size=(80, 3))
    pts = np.array([0.03, 0.02, 0.015]) * d / np.linalg.norm(d, axis=1, keepdims=True)
    f, b = cm.make_log_prob(pts, noise="outlier")
    n = 2 * cm.TEMPERING_BLOCK
    th = np.column_stack(
        [
            rng.normal(0, 1e-3, (n, 3)),
            np.log([0.03, 0.02, 0.015]) + rng.normal(0, 0.05, (n, 3)),
            rng.uniform(0.1, 1.0, (n, 3)),
            np.log(rng.uniform(2.0, 4.0, (n, 1))),
            np.full((n, 1), np.log(3e-4)),
            np.full((n, 2), 0.02),
        ]
    )
    big = f.parts(th)
    idx = np.r_[0:8, cm.TEMPERING_BLOCK - 4 : cm.TEMPERING_BLOCK + 4, n - 8 : n]
    small = f.parts(th[idx])
    for a, s in zip(big, small, strict=True):
        np.testing.assert_allclose(a[idx], s, rtol=1e-10, atol=1e-10)
    assert not np.allclose(big[1][idx], small[1][::-1])
