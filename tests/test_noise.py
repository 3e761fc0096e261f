"""Read-out noise: reproducibility, white-noise σ, ADC, 1/f synthesis, drift, outliers, drift compensation."""

import math

import numpy as np
import pytest

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS
from bayestouch.physics import noise as nz
from bayestouch.physics.taxel import K_B, Q_E, thermal_voltage


@pytest.fixture(scope="module")
def params():
    return nz.load_noise()


def _quiet(p, **over):
    """Only the components named in ``over`` are on."""
    base = dict(
        flicker=0.0,
        drift_common=0.0,
        drift_local=0.0,
        barrier_spread=0.0,
        outlier_probability=0.0,
        offset=0.0,
        bandwidth=0.0,
    )
    base.update(over)
    return p._replace(**base)


def test_shipped_toml_loads(params):
    assert params.bandwidth == 1e3 and params.feedback_resistance == 1e6 and params.adc_bits == 16.0
    # physics.md §5 table at 1 µA, 1 kHz: shot 18 pA, amplifier 4 pA
    assert math.sqrt(2 * Q_E * 1e-6 * 1e3) == pytest.approx(17.9e-12, rel=0.01)
    assert math.sqrt(4 * K_B * 300 * 1e3 / 1e6) == pytest.approx(4.07e-12, rel=0.01)
    assert float(nz.noise_std(params, 1e-6, adc=False)) == pytest.approx(math.hypot(17.90e-12, 4.07e-12), rel=0.01)
    lsb = 2e-6 / 2**16
    assert float(nz.noise_std(params, 1e-6)) == pytest.approx(
        math.sqrt(17.90e-12**2 + 4.07e-12**2 + lsb**2 / 12), rel=0.01
    )


@pytest.mark.parametrize(
    "old,new,needle",
    [
        ('unit = "Ohm"', 'unit = "MOhm"', 'feedback_resistance: unit must be "Ohm"'),
        ("flicker_f_max = { value = 1.0e2,", "flicker_f_max = { value = 1.0e-3,", "must exceed flicker_f_min"),
    ],
)
def test_bad_toml_raises_badinput(tmp_path, old, new, needle):
    text = (MODELS / "noise.toml").read_text(encoding="utf-8")
    assert old in text
    f = tmp_path / "n.toml"
    f.write_text(text.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(BadInput, match=needle):
        nz.load_noise(f)


# one array shape for all add_noise runs, so the jitted function compiles once per static variant
SHAPE = (20, 20_000)
N_SAMPLES = SHAPE[0] * SHAPE[1]


def _run(p, key, current=1e-6, dt=1e-3, gains=None):
    """add_noise on SHAPE with the ADC off (one compiled variant for every statistical test)."""
    gains = jnp.ones(SHAPE[1]) if gains is None else gains
    return nz.add_noise(jax.random.key(key), p, jnp.broadcast_to(jnp.asarray(current), SHAPE), dt, gains, adc=False)


def test_seeded_reproducibility(params):
    a, b, c = (_run(params, k, 3e-7) for k in (7, 7, 8))
    np.testing.assert_array_equal(a, b)
    assert np.mean(np.asarray(a) != np.asarray(c)) > 0.9  # negative control: another key differs
    g1 = nz.fixed_pattern(jax.random.key(1), params, SHAPE[1])
    np.testing.assert_array_equal(g1, nz.fixed_pattern(jax.random.key(1), params, SHAPE[1]))
    assert not np.allclose(g1, nz.fixed_pattern(jax.random.key(2), params, SHAPE[1]))


def test_white_noise_sigma(params):
    """std(measured − I) = √(2qIB + 4kTB/R_f); relative SE of a std estimate ≈ 1/√(2n), tolerance 4 SE."""
    I0 = 1e-6
    y = _run(_quiet(params, bandwidth=1e3), 3, I0)
    s = float(jnp.std(y - I0))
    expected = math.sqrt(2 * Q_E * I0 * 1e3 + 4 * K_B * 300.0 * 1e3 / 1e6)
    tol = 4 / math.sqrt(2 * N_SAMPLES)  # = 0.45 %
    assert abs(s / expected - 1) < tol
    assert abs(s / math.sqrt(2 * Q_E * I0 * 1e3) - 1) > tol  # shot noise alone (2.5 % lower) would fail
    assert abs(float(jnp.mean(y - I0))) < 4 * expected / math.sqrt(N_SAMPLES)
    assert float(nz.noise_std(params, I0, adc=False)) == pytest.approx(expected, rel=1e-12)


def test_adc_quantisation_uniform(params):
    lsb = float(nz.adc_lsb(params))
    assert lsb == pytest.approx(2e-6 / 65536, rel=1e-15)
    n = 100_000
    x = jnp.asarray(np.random.default_rng(4).uniform(0.1e-6, 1.9e-6, n))
    e = np.asarray(nz.quantise(x, lsb, 0.0, params.adc_full_scale - lsb) - x)
    assert np.abs(e).max() <= lsb / 2 * (1 + 1e-9)
    # σ = LSB/√12; for a uniform error the std's relative SE is √(0.2/n) < 1/√(2n): 4/√(2n) is conservative
    assert abs(e.std() / (lsb / math.sqrt(12)) - 1) < 4 / math.sqrt(2 * n)
    # uniform on [−LSB/2, LSB/2]: half the errors within ±LSB/4 (binomial SE √(0.25/n))
    assert abs(np.mean(np.abs(e) < lsb / 4) - 0.5) < 4 * math.sqrt(0.25 / n)
    # clipping and straight-through gradient
    np.testing.assert_allclose(nz.quantise(jnp.array([-1e-6, 5e-6]), lsb, 0.0, 2e-6 - lsb), [0.0, 2e-6 - lsb])
    g = jax.grad(lambda v: jnp.sum(nz.quantise(v, lsb, 0.0, 2e-6 - lsb)))(jnp.array([-1e-7, 3.3e-7, 1.2e-6, 3e-6]))
    np.testing.assert_array_equal(g, [0.0, 1.0, 1.0, 0.0])


def test_flicker_psd_is_one_over_f(params):
    f = jnp.logspace(-1, 1, 41)  # a decade inside each end of [f_min, f_max] = [0.01, 100] Hz
    ratio = nz.flicker_psd(params, f) * f / params.flicker
    assert float(jnp.max(jnp.abs(ratio - 1))) < 0.06
    # outside the band the synthesis rolls off (1/f² above f_max)
    assert float(nz.flicker_psd(params, 1e4) * 1e4 / params.flicker) < 0.05


def test_flicker_stationary_variance(params):
    """The OU sum starts stationary: Var(ln I) = n K_f ln r at every sample (9 components, r = 10^0.5)."""
    y = _run(_quiet(params, flicker=1e-6), 5)
    x = jnp.log(y / 1e-6)
    expected = 9 * 1e-6 * math.log(10**0.5)
    for k in (0, SHAPE[0] - 1):
        assert abs(float(jnp.std(x[k])) / math.sqrt(expected) - 1) < 4 / math.sqrt(2 * SHAPE[1])


def test_random_walk_drift(params):
    dt, rate = 0.01, 1e-3
    x = jnp.log(_run(_quiet(params, drift_local=rate), 6, dt=dt) / 1e-6)
    np.testing.assert_array_equal(x[0], 0.0)
    expected = rate * math.sqrt((SHAPE[0] - 1) * dt)  # Var = rate² t
    assert abs(float(jnp.std(x[-1])) / expected - 1) < 4 / math.sqrt(2 * SHAPE[1])
    # the common drift is one walk shared by all taxels
    c = jnp.log(_run(_quiet(params, drift_common=rate), 6, dt=dt) / 1e-6)
    assert float(jnp.max(jnp.std(c, axis=1))) < 1e-12 and float(jnp.abs(c[-1, 0])) > 0


def test_fixed_pattern_spread(params):
    n = SHAPE[1]
    g = nz.fixed_pattern(jax.random.key(9), params, n)
    expected = params.barrier_spread / float(thermal_voltage(300.0))  # σ_lnI₀ = σ_Φ/V_T
    assert abs(float(jnp.std(jnp.log(g))) / expected - 1) < 4 / math.sqrt(2 * n)


def test_outlier_rate(params):
    I0 = 1e-6
    p = _quiet(params, bandwidth=1e3, outlier_probability=0.01)
    y = _run(p, 10, I0)
    thr = 10 * float(nz.noise_std(p, I0, adc=False))
    frac = float(jnp.mean(jnp.abs(y - I0) > thr))
    # an outlier N(0, s²) exceeds thr unless |z| < thr/s; the white noise never does at 10 σ
    expected = 0.01 * math.erfc(thr / p.outlier_scale / math.sqrt(2))
    assert abs(frac - expected) < 4 * math.sqrt(expected / N_SAMPLES)


def test_drift_compensation_exact_noiseless(params):
    """Common random-walk drift and a uniform temperature step are removed exactly with no other noise."""
    n_t, n_x = SHAPE
    ref = np.zeros(n_x, bool)
    ref[:100] = True
    t = np.arange(n_t)[:, None]
    base = np.where(ref, 1e-7, 1e-7 * (1 + 0.3 * np.sin(0.5 * t + np.arange(n_x))))
    y = _run(_quiet(params, drift_common=1e-1), 12, base, dt=1e-2)
    assert np.max(np.abs(np.log(np.asarray(y) / base))) > 1e-2  # the drift is really there
    np.testing.assert_allclose(nz.drift_compensate(y, ref), base, rtol=1e-12)
    # a multiplicative common factor (e.g. uniform ΔT) is also removed, relative to the first sample
    common = np.exp(0.08 * np.linspace(0.0, 1.0, n_t))[:, None]
    np.testing.assert_allclose(nz.drift_compensate(base * common, ref), base, rtol=1e-12)
    # negative control: a drift on the loaded taxels only is not (and must not be) removed
    local = np.where(ref, 1.0, common)
    assert not np.allclose(nz.drift_compensate(base * local, ref), base, rtol=1e-3)


def test_gains_and_gradient(params):
    """Without white noise y = G I exp(log-noise), so ∂y/∂I = y/I exactly; the ADC passes it straight through."""
    p = _quiet(params, flicker=1e-8, drift_local=1e-3)
    gains = nz.fixed_pattern(jax.random.key(11), params, SHAPE[1])
    i0 = 2e-8  # small enough that G I stays inside the ADC range (no clipping, so ∂/∂I ≠ 0)
    i = jnp.full(SHAPE, i0)
    y = _run(p, 13, i, gains=gains)
    assert float(jnp.max(y)) < params.adc_full_scale
    # at t = 0 (no drift yet, flicker variance 1e-7 ≪ σ_G² = 0.6) the spread is the fixed pattern's
    sigma_g = params.barrier_spread / float(thermal_voltage(300.0))
    assert abs(float(jnp.std(jnp.log(y[0] / i0))) / sigma_g - 1) < 4 / math.sqrt(2 * SHAPE[1])
    # forward mode with a unit tangent: ∂y_k/∂I_k (the map is elementwise in I)
    _, g = jax.jvp(lambda c: nz.add_noise(jax.random.key(13), p, c, 1e-3, gains, adc=True), (i,), (jnp.ones(SHAPE),))
    np.testing.assert_allclose(g, y / i0, rtol=1e-12)
    # noise_std has a finite gradient even where the variance is zero
    assert np.isfinite(float(jax.grad(lambda c: nz.noise_std(_quiet(p), c, adc=False))(0.0)))
