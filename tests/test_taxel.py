"""Piezotronic taxels: M–S–M limits, polarity, gauge factor, temperature, empirical mode, lag, gradients, TOML."""

import math

import numpy as np
import pytest
from jax.test_util import check_grads

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS
from bayestouch.physics import taxel as tx


@pytest.fixture(scope="module")
def params():
    return tx.load_taxels()


def test_shipped_toml_loads_and_derived_constants(params):
    assert tx.load_taxel_mode() == "physics"
    assert (params.rows, params.cols, params.polarity) == (16.0, 16.0, 1.0)
    # physics.md §4/§7 [D]: E_c = 140 GPa and P/ε = 1.55 C/m² (1.22 with e33 alone) from the ZnO constants
    assert tx.axial_modulus(params) == pytest.approx(140e9, rel=2e-3)
    assert tx.piezo_coefficient(params) == pytest.approx(1.55, rel=3e-3)
    # V_T(300 K) = 25.85 mV (CODATA constants)
    assert float(tx.thermal_voltage(300.0)) == pytest.approx(0.025852, rel=1e-4)
    # nominal I₀ inside 10 nA–1 µA (physics.md §4)
    assert 1e-8 < float(tx.saturation_current(params, 300.0)) < 1e-6


def _write(tmp_path, old, new):
    text = (MODELS / "taxels.toml").read_text(encoding="utf-8")
    assert old in text
    f = tmp_path / "t.toml"
    f.write_text(text.replace(old, new, 1), encoding="utf-8")
    return f


@pytest.mark.parametrize(
    "old,new,needle",
    [
        ('unit = "m", source = "Wu', 'unit = "um", source = "Wu', 'pitch: unit must be "m"'),
        ("rows = { value = 16,", "rows = { value = 16.5,", "rows: must be a whole number"),
        ("polarity = { value = 1,", "polarity = { value = 0.5,", "polarity: must be 1 or -1"),
        ("reference_rows = { value = 1,", "reference_rows = { value = 16,", "leaves no loaded rows"),
        ('mode = "physics"', 'mode = "magic"', "mode: must be one of"),
        # issue 24, tenth review: a finger that feels nothing (S_p = 0) ran texture-id to confident wrong answers
        ("sensitivity = { value = 5.0e-5,", "sensitivity = { value = 0.0,", "sensitivity"),
        ("sensitivity = { value = 5.0e-5,", "sensitivity = { value = -5.0e-5,", "sensitivity"),
    ],
)
def test_bad_toml_raises_badinput(tmp_path, params, old, new, needle):
    f = _write(tmp_path, old, new)
    with pytest.raises(BadInput, match=needle) as e:
        tx.load_taxels(f)
        tx.load_taxel_mode(f)
    assert "\n" not in str(e.value)


def test_layout_square_grid_and_reference_row(params):
    lay = tx.layout(params._replace(hexagonal=0.0))
    assert lay.positions.shape == (256, 2) and lay.reference.shape == (256,)
    np.testing.assert_allclose(lay.positions.mean(axis=0), 0.0, atol=1e-15)
    # neighbours along a row are one pitch apart in u; along a column one pitch apart in v
    np.testing.assert_allclose(lay.positions[1] - lay.positions[0], [params.pitch, 0.0], rtol=1e-12)
    np.testing.assert_allclose(lay.positions[16] - lay.positions[0], [0.0, params.pitch], rtol=1e-12)
    assert lay.reference.sum() == 16 and lay.reference[:16].all() and not lay.reference[16:].any()
    assert tx.cell_area(params._replace(hexagonal=0.0)) == pytest.approx(params.pitch**2)


def test_layout_hexagonal_pores(params):
    assert params.hexagonal == 1.0  # the shipped finger: taxels in the skin's hexagonal pores
    lay = tx.layout(params)
    pos = lay.positions
    # every interior taxel has six nearest neighbours, all one pitch away
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    interior = (np.abs(pos[:, 0]) < 5 * params.pitch) & (np.abs(pos[:, 1]) < 5 * params.pitch)
    for i in np.flatnonzero(interior):
        near = np.sort(d[i])[1:8]
        np.testing.assert_allclose(near[:6], params.pitch, rtol=1e-12)
        assert near[6] > 1.5 * params.pitch
    np.testing.assert_allclose(pos[16, 0] - pos[0, 0], params.pitch / 2, rtol=1e-12)  # odd rows shifted
    assert tx.cell_area(params) == pytest.approx(np.sqrt(3) / 2 * params.pitch**2)
    assert lay.reference.sum() == 16 and lay.reference[:16].all()


def test_msm_limits():
    v_t = 0.025
    i_ss, i_sd = 2e-7, 5e-8  # unequal, so swapping the two limits would fail
    assert float(tx.msm_current(i_ss, i_sd, 40 * v_t, v_t)) == pytest.approx(i_sd, rel=1e-12)
    assert float(tx.msm_current(i_ss, i_sd, -40 * v_t, v_t)) == pytest.approx(-i_ss, rel=1e-12)
    assert float(tx.msm_current(i_ss, i_sd, 0.0, v_t)) == 0.0
    # the overflow-free form equals the textbook formula where the latter is finite
    V = np.linspace(-0.3, 0.3, 13)
    x = V / (2 * v_t)
    ref = 2 * i_ss * i_sd * np.sinh(x) / (i_ss * np.exp(x) + i_sd * np.exp(-x))
    np.testing.assert_allclose(tx.msm_current(i_ss, i_sd, V, v_t), ref, rtol=1e-12, atol=1e-30)
    # no overflow at large bias / low temperature
    assert np.isfinite(float(tx.msm_current(i_ss, i_sd, 50.0, 0.001)))


@pytest.mark.parametrize("mode", tx.MODES)
def test_zero_pressure_and_polarity(params, mode):
    T = 300.0
    i0 = tx.saturation_current(params, T)
    unstrained = i0 * jnp.tanh(params.bias / (2 * tx.thermal_voltage(T)))  # I_sS = I_sD = I₀
    assert float(tx.taxel_current(params, 0.0, T, mode)) == pytest.approx(float(unstrained), rel=1e-13)
    dlnI = {s: float(jnp.log(tx.taxel_current(params, 1e3, T, mode, polarity=s) / unstrained)) for s in (1, -1)}
    assert dlnI[1] > 0 > dlnI[-1]
    assert dlnI[1] == pytest.approx(-dlnI[-1], rel=1e-6)
    # per-taxel polarity array broadcasts
    mixed = tx.taxel_current(params, jnp.array([1e3, 1e3]), T, mode, polarity=jnp.array([1.0, -1.0]))
    np.testing.assert_allclose(jnp.log(mixed / unstrained), [dlnI[1], dlnI[-1]], rtol=1e-6)


@pytest.mark.parametrize("W,gf", [(0.25e-9, 95.0), (1e-9, 380.0), (4e-9, 1520.0)])
def test_gauge_factor(params, W, gf):
    """GF = |d ln I / d ε| = 1.55 W / (2 ε_s V_T): 95 / 380 / 1520 (physics.md §4 table), by autodiff."""
    p = params._replace(width_piezo=W)
    dlnI_dp = jax.grad(lambda pr: jnp.log(tx.taxel_current(p, pr, 300.0)))(1e3)
    GF = float(dlnI_dp) * float(tx.axial_modulus(p)) * p.load_fraction  # dε/dp = −1/(E_c φ)
    assert GF == pytest.approx(gf, rel=0.01)
    assert float(tx.gauge_factor(p, 300.0)) == pytest.approx(GF, rel=1e-9)


def test_physics_response_at_1kpa(params):
    """physics.md §4: Δ ln I ≈ 3e-5 at 1 kPa, φ_load = 0.1, W = 1 nm."""
    d = float(jnp.log(tx.taxel_current(params, 1e3, 300.0) / tx.taxel_current(params, 0.0, 300.0)))
    assert d == pytest.approx(380.8 * 1e3 / (140.16e9 * 0.1), rel=1e-3)
    assert 2e-5 < d < 4e-5


@pytest.mark.parametrize("T", [280.0, 300.0, 340.0])
def test_temperature_coefficient(params, T):
    """d ln I/dT = 2/T + Φ_B/(V_T T) (physics.md §0 finding 2) for V ≫ V_T."""
    g = jax.grad(lambda t: jnp.log(tx.taxel_current(params, 500.0, t)))(T)
    expected = 2 / T + params.barrier / (float(tx.thermal_voltage(T)) * T)
    assert float(g) == pytest.approx(expected, rel=1e-6)
    assert 0.05 < float(g) < 0.11  # 6–11 %/K


def test_empirical_mode_exact(params):
    p = jnp.array([0.0, 1e2, 1e3, 1e4])
    T = jnp.array([300.0, 300.0, 300.0, 300.0])
    i = tx.taxel_current(params, p, T, "empirical")
    np.testing.assert_allclose(jnp.log(i / i[0]), params.sensitivity * p, rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="mode"):
        tx.taxel_current(params, p, T, "magic")


def test_jit_with_static_mode(params):
    f = jax.jit(tx.taxel_current, static_argnames="mode")
    for mode in tx.MODES:
        assert float(f(params, 1e3, 310.0, mode)) == pytest.approx(
            float(tx.taxel_current(params, 1e3, 310.0, mode)), rel=1e-13
        )


@pytest.mark.parametrize("mode", tx.MODES)
def test_gradients(params, mode):
    # a smaller load fraction makes the physics response large enough for a meaningful check
    p = params._replace(load_fraction=1e-3)
    i_ref = float(tx.saturation_current(p, 300.0))

    def f(p_kpa, T):  # pressure in kPa, current in units of I₀(300 K)
        return tx.taxel_current(p, 1e3 * p_kpa, T, mode) / i_ref

    check_grads(f, (jnp.array([0.5, 3.0, 10.0]), jnp.array([295.0, 300.0, 320.0])), order=1, atol=1e-7, rtol=1e-5)


def test_first_order_lag_step():
    dt, tau = 1e-3, 0.15
    n = 400
    x = jnp.ones((n, 3))
    y = tx.first_order_lag(x, dt, tau, x0=jnp.zeros(3))
    k = round(tau / dt)
    np.testing.assert_allclose(y[k], 1 - math.exp(-1), rtol=1e-12)
    np.testing.assert_allclose(y[0], 0.0)
    np.testing.assert_allclose(y[-1], 1 - math.exp(-(n - 1) * dt / tau), rtol=1e-12)
    # default start is steady state: a constant input stays put; per-taxel τ broadcasts
    np.testing.assert_allclose(tx.first_order_lag(2.0 * x, dt, jnp.array([0.1, 0.2, 0.3])), 2.0)
    yt = tx.first_order_lag(x, dt, jnp.array([0.1, 0.2, 0.3]), x0=0.0)
    np.testing.assert_allclose(yt[100], 1 - np.exp(-0.1 / np.array([0.1, 0.2, 0.3])), rtol=1e-12)
