"""Per-contact superellipse patch posterior (bayestouch.inference.patch): model facts, recovery, Table 1's trend."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.inference import patch as pp
from bayestouch.physics import forward as fw
from bayestouch.physics import noise as nz
from bayestouch.physics import skin as sk
from bayestouch.physics.patch import superellipse_area
from bayestouch.physics.virtual import load_finger
from bayestouch.scene.objects import load_object

ROOT = Path(__file__).parent.parent
F = load_finger(seed=0).finger
R_TIP = float(F.tip_radius)
N_TAXELS = int(np.asarray(F.gains).size)
#: an elongated patch (a ≠ b, n ≠ 2) well inside the pad
TRUTH = pp.PatchParams(u0=3e-4, v0=1e-3, a=2.2e-3, b=1.4e-3, angle=0.4, n=3.0, depth=2.0e-4)
#: 99.9 % quantile of χ² with 7 degrees of freedom (scipy.stats.chi2.ppf(0.999, 7))
CHI2_7_999 = 24.32


def _model(y=None):
    m = pp.make_patch_model(np.ones(N_TAXELS), F, gains=np.ones(N_TAXELS))
    return m if y is None else m._replace(y=jnp.asarray(y))


def _window(params, seed, k=10, mode="empirical"):
    """K static frames of the patch model with the full noise model (fixed pattern, 1/f, drift, white, ADC)."""
    i = jnp.asarray(pp.patch_currents(params, F, mode=mode))
    return np.asarray(nz.add_noise(jax.random.PRNGKey(seed), F.noise, jnp.tile(i, (k, 1)), 0.02, F.gains))


def _plate_frames(load, seed, mode, k=10):
    """K frames of the real forward model: the fingertip pressed on the flat plate at a normal force ``load`` N.

    Returns (Frames, pressing depth m)."""
    plate = replace(load_object(ROOT / "models" / "objects" / "graphite_plate.toml"), defects=())
    surf = plate.surface()
    contact = np.stack([np.zeros(k), np.zeros(k), np.full(k, 0.005)], 1)
    st = (
        jnp.asarray(contact),
        jnp.tile(jnp.array([0.0, 0.0, 1.0]), (k, 1)),
        jnp.tile(jnp.array([1.0, 0.0, 0.0]), (k, 1)),
        jnp.asarray(0.0),
    )
    d = fw.depths_for_force(surf, F, st, load)
    return fw.simulate_jit(surf, (*st[:3], d), F, jax.random.PRNGKey(seed), dt=0.02, mode=mode), float(d[0])


def _plate_window(load, seed, mode, k=10):
    fr, d = _plate_frames(load, seed, mode, k)
    return np.asarray(fr.taxel_current), d


def _log_natural(draws):
    """(M, 7) draws in the near-Gaussian coordinates u0, v0, ln a, ln b, angle, ln n, ln δ0."""
    return np.column_stack(
        [
            draws["u0"],
            draws["v0"],
            np.log(draws["a"]),
            np.log(draws["b"]),
            draws["angle"],
            np.log(draws["n"]),
            np.log(draws["depth"]),
        ]
    )


def _mahalanobis2(draws, truth: pp.PatchParams):
    x = _log_natural(draws)
    t = np.array(
        [truth.u0, truth.v0, np.log(truth.a), np.log(truth.b), truth.angle, np.log(truth.n), np.log(truth.depth)]
    )
    d = t - x.mean(axis=0)
    return float(d @ np.linalg.solve(np.cov(x, rowvar=False), d))


# ---------------------------------------------------------------- model facts (fast)


def test_theta_round_trip():
    back = pp.params_from_theta(pp.theta_from_params(TRUTH))
    np.testing.assert_allclose(back, TRUTH, rtol=1e-12)


@pytest.mark.slow  # compiles the forward model (shared with the load test below)
def test_profile_reproduces_the_forward_pressure_of_a_sphere_on_flat_skin():
    # A sphere of radius R pressed δ0 into the skin: gap δ0 − R(1 − cos(ρ/R)), contact radius R acos(1 − δ0/R);
    # the n = 2 profile is its parabolic approximation (error ~ρ⁴/24R³ ≈ 2 µm at the rim, far less inside).
    fr, d = _plate_frames(0.07, seed=0, mode="empirical")
    p_fwd = np.asarray(fr.pressure[0]).ravel()
    a = R_TIP * np.arccos(1 - d / R_TIP)
    p_mod = np.asarray(
        pp.patch_pressure(
            jnp.asarray(pp.theta_from_params(TRUTH._replace(u0=0.0, v0=0.0, a=a, b=a, angle=0.0, n=2.0, depth=d))),
            _model(),
        )
    )
    assert np.max(np.abs(p_mod - p_fwd)) < 0.01 * p_fwd.max()  # measured 0.2 %
    # negative control: a 10 % larger patch is clearly a different pressure map
    p_big = np.asarray(
        pp.patch_pressure(
            jnp.asarray(
                pp.theta_from_params(TRUTH._replace(u0=0.0, v0=0.0, a=1.1 * a, b=1.1 * a, angle=0.0, n=2.0, depth=d))
            ),
            _model(),
        )
    )
    assert np.max(np.abs(p_big - p_fwd)) > 0.05 * p_fwd.max()


def test_empirical_response_is_sensitivity_times_pressure_and_zero_on_reference_rows():
    m = _model()
    th = jnp.asarray(pp.theta_from_params(TRUTH))
    p = np.asarray(pp.patch_pressure(th, m))
    dlog = np.asarray(pp.patch_log_current(th, m, "empirical"))
    np.testing.assert_allclose(
        dlog, float(F.taxels.sensitivity) * p, rtol=1e-9, atol=1e-13
    )  # ln I − ln I0 at ln I0 ≈ −16: ~1e-15 rounding
    ref = np.asarray(F.reference).ravel()
    assert np.all(p[ref] == 0) and p.max() > 1e3
    # the blur conserves force: Σ p = Σ σ_foam(δ_j) of the unblurred profile (reference row aside)
    pos = np.asarray(F.grid).reshape(-1, 2)
    c, s = np.cos(TRUTH.angle), np.sin(TRUTH.angle)
    x, y = (
        c * (pos[:, 0] - TRUTH.u0) + s * (pos[:, 1] - TRUTH.v0),
        -s * (pos[:, 0] - TRUTH.u0) + c * (pos[:, 1] - TRUTH.v0),
    )
    delta = TRUTH.depth * np.maximum(1 - np.abs(x / TRUTH.a) ** TRUTH.n - np.abs(y / TRUTH.b) ** TRUTH.n, 0)
    local = np.asarray(sk.foam_stress(F.skin, delta / float(F.skin.h)))
    assert p.sum() == pytest.approx(local.sum(), rel=5e-3)  # less the ~0.2 % blurred onto the reference row


def test_offset_is_marginalised_exactly():
    m = _model()
    th = jnp.asarray(pp.theta_from_params(TRUTH))
    rng = np.random.default_rng(0)
    sig = 3e-4 * (1 + rng.random(N_TAXELS))
    c_true = -16.0
    y = c_true + np.asarray(pp.patch_log_current(th, m)) + sig * rng.normal(size=N_TAXELS)
    m = m._replace(y=jnp.asarray(y), sigma=jnp.asarray(sig))
    th2 = th.at[2].add(0.01)  # a slightly wrong patch, so the residuals are not pure noise
    lp = float(pp.patch_log_prob(th2, m))
    # numerical ∫ N(y | c + Δ, σ²) dc over a grid that covers the whole c-likelihood (width ~ σ/√N ≈ 2e-5)
    r = y - np.asarray(pp.patch_log_current(th2, m))
    cs = np.linspace(r.mean() - 4e-4, r.mean() + 4e-4, 20001)
    ll = np.array([-0.5 * np.sum(((r - c) / sig) ** 2) for c in cs]) - 0.5 * np.sum(np.log(2 * np.pi * sig**2))
    top = ll.max()
    numeric = top + np.log(np.trapezoid(np.exp(ll - top), cs))
    assert lp == pytest.approx(numeric, abs=1e-6)
    # a common shift of every log-current (temperature, gain level) changes nothing ...
    assert float(pp.patch_log_prob(th2, m._replace(y=m.y + 0.3))) == pytest.approx(lp, abs=1e-6)
    # ... a shift of the loaded taxels only is a different signal (negative control)
    assert float(pp.patch_log_prob(th2, m._replace(y=m.y + 1e-3 * m.loaded))) < lp - 10


def test_log_prob_is_minus_inf_outside_the_prior_and_never_nan():
    m = _model(y=np.log(pp.patch_currents(TRUTH, F)))
    f, b = pp.make_patch_log_prob(m)
    lo, hi = np.asarray(b.lower), np.asarray(b.upper)
    rng = np.random.default_rng(1)
    th = lo - 0.1 * (hi - lo) + 1.2 * (hi - lo) * rng.random((2000, 7))  # 10 % beyond each face
    v = f(th)
    assert not np.any(np.isnan(v))
    inside = np.all((th >= lo) & (th <= hi), axis=1)
    depth = np.exp(th[:, 6] - th[:, 2] - th[:, 3]) / np.asarray(pp.volume_factor(np.exp(th[:, 5])))
    ok = inside & (depth >= pp.DEPTH_MIN) & (depth <= float(F.skin.h))
    assert ok.sum() > 100 and (~ok).sum() > 1000
    assert np.all(np.isfinite(v[ok])) and np.all(v[~ok] == -np.inf)


def test_window_flicker_variance_limits_and_monte_carlo():
    noise = F.noise
    ln_r = np.log(float(noise.flicker_f_max) / float(noise.flicker_f_min)) / 8
    stationary = 9 * float(noise.flicker) * ln_r  # 9 OU components of variance K_f ln r each
    assert pp.window_flicker_variance(noise, 1, 0.02) == pytest.approx(stationary, rel=1e-12)
    assert pp.window_flicker_variance(noise, 8, 1e6) == pytest.approx(stationary / 8, rel=1e-9)  # independent
    v = [pp.window_flicker_variance(noise, k, 0.02) for k in (1, 4, 16)]
    assert v[0] > v[1] > v[2] > stationary / 16  # slow components do not average out
    # Monte Carlo: the 1/f part alone of add_noise (no white noise, drift, outliers or ADC), 4000 taxels
    quiet = noise._replace(bandwidth=0.0, drift_common=0.0, drift_local=0.0, outlier_probability=0.0)
    k = 8
    y = np.asarray(nz.add_noise(jax.random.PRNGKey(5), quiet, jnp.full((k, 4000), 1e-7), 0.02, adc=False))
    emp = float(np.var(np.log(y / 1e-7).mean(axis=0)))
    # the variance of 4000 independent window means has relative sd √(2/4000) = 2.2 %; allow 5 sd
    assert emp == pytest.approx(pp.window_flicker_variance(noise, k, 0.02), rel=0.11)


def test_bad_inputs_raise_one_line():
    good = np.ones(N_TAXELS)
    cases = [
        (lambda: pp.make_patch_model(np.ones(10), F), "currents"),
        (lambda: pp.make_patch_model(np.full(N_TAXELS, np.nan), F), "currents"),
        (lambda: pp.make_patch_model(good, F, sigma=-1.0), "sigma"),
        (lambda: pp.make_patch_model(good, F, gains=np.ones(3)), "gains"),
        (lambda: pp.make_patch_model(good, F, dt=0.0), "dt"),
        (lambda: pp.patch_posterior(good, F, seed=0, mode="magic"), "mode"),
        (lambda: pp.patch_posterior(good, F, seed=0, walkers=15), "walkers"),
        (lambda: pp.patch_posterior(good, F, seed=0, steps=5), "steps"),
    ]
    for call, field in cases:
        with pytest.raises(BadInput, match=field) as err:
            call()
        assert "\n" not in str(err.value)


# ---------------------------------------------------------------- posteriors (slow)


@pytest.mark.slow
def test_recovers_a_simulated_patch_and_a_wrong_noise_scale_breaks_coverage():
    cur = _window(TRUTH, seed=3)
    post = pp.patch_posterior(cur, F, seed=1, walkers=32, steps=700)
    d = post.draws
    truth = {**TRUTH._asdict(), "area_m2": float(superellipse_area(TRUTH.a, TRUTH.b, TRUTH.n))}
    for name in ("u0", "v0", "a", "b", "angle", "n", "depth", "area_m2"):
        x = d[name]
        lo, hi = np.quantile(x, [0.005, 0.995])
        assert lo <= truth[name] <= hi, name
        assert abs(x.mean() - truth[name]) < 3.5 * x.std(), name
    s = post.summary["parameters"]
    assert s["a"]["q05"] <= TRUTH.a <= s["a"]["q95"] and s["n"]["q05"] <= TRUTH.n <= s["n"]["q95"]
    assert s["a"]["sd"] < 0.05 * TRUTH.a and s["n"]["sd"] < 0.15 * TRUTH.n  # informative: a few %
    # jointly: the truth's squared Mahalanobis distance is ~χ²₇ under a calibrated, near-Gaussian posterior
    d2 = _mahalanobis2(d, TRUTH)
    assert d2 < CHI2_7_999
    # negative control: claiming 10× less noise shrinks the posterior 10× around the same noisy data, so the
    # truth lands ~10 sd away (d² ≈ 100 × a χ²₇ draw; below 24.3 only if that draw is < 0.24, p ≈ 1e-5)
    wrong = pp.patch_posterior(cur, F, seed=1, walkers=32, steps=400, sigma=0.1 * np.asarray(post.model.sigma))
    assert _mahalanobis2(wrong.draws, TRUTH) > CHI2_7_999
    assert wrong.summary["parameters"]["a"]["sd"] < 0.3 * s["a"]["sd"]


@pytest.mark.slow
def test_patch_area_grows_with_load_and_physics_mode_is_uninformative():
    # Table 1's trend on the real forward model: the fingertip pressed on the flat plate at the table's
    # smallest and largest loads; the patch's geometric radius is R acos(1 − δ0/R).
    areas, geo = [], []
    for load in (0.04, 0.09):
        cur, depth = _plate_window(load, seed=7, mode="empirical")
        post = pp.patch_posterior(cur, F, seed=2, walkers=32, steps=600)
        areas.append(post.summary["derived"]["area_m2"])
        geo.append(np.pi * (R_TIP * np.arccos(1 - depth / R_TIP)) ** 2)
        # the force of the inferred pressure map is the force the plate was pressed with
        assert post.summary["derived"]["force_N"]["mean"] == pytest.approx(load, rel=0.01)
        # the contact area within 10 % of the geometric one (the parabolic profile and the skin's 1 µm
        # softplus are the model's only approximations here; measured 1–5 %)
        assert areas[-1]["mean"] == pytest.approx(geo[-1], rel=0.10)
    assert areas[1]["q05"] > areas[0]["q95"]  # the whole 90 % intervals are ordered
    assert areas[1]["mean"] / areas[0]["mean"] == pytest.approx(geo[1] / geo[0], rel=0.15)
    # negative control: physics mode (Δ ln I ≈ 3e-5 per kPa, below the noise) gives a near-prior posterior
    cur, _ = _plate_window(0.09, seed=7, mode="physics")
    phys = pp.patch_posterior(cur, F, seed=2, walkers=32, steps=400, mode="physics")
    ph = phys.summary["derived"]["area_m2"]
    assert ph["sd"] > 10 * areas[1]["sd"]
    assert ph["q95"] - ph["q05"] > 0.5 * areas[1]["mean"]


def test_in_memory_sampling_reproduces_the_checkpointed_engine(tmp_path):
    # same seed, start and moves: the in-memory run and bayestouch.inference.sampler.sample (HDF5) give the same chain
    cur = _window(TRUTH, seed=4)  # same shapes as the other tests: shares their compiled functions
    mem = pp.patch_posterior(cur, F, seed=5, walkers=32, steps=100)
    disk = pp.patch_posterior(cur, F, seed=5, walkers=32, steps=100, chain_path=tmp_path / "chain.h5")
    assert (tmp_path / "chain.h5").exists()
    np.testing.assert_array_equal(mem.chain.kept, disk.chain.kept)
    assert mem.chain.burn == disk.chain.burn and mem.summary["diagnostics"]["n_samples"] == 32 * (100 - mem.chain.burn)
    other = pp.patch_posterior(cur, F, seed=6, walkers=32, steps=100)
    assert not np.array_equal(other.chain.kept, mem.chain.kept)  # the seed matters
