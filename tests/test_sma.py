"""SMA wire: thermal time constant and steady state, latent heat, smooth Brinson hysteresis, Bouc–Wen,
safety limits, gradients, and the parameter file (physics.md §1, §7)."""

import math
import re

import numpy as np
import pytest
from jax.test_util import check_grads

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS
from bayestouch.physics import sma

C0 = 273.15


@pytest.fixture(scope="module")
def wire():
    return sma.load_wire()


def test_shipped_file_loads_with_physics_md_values(wire):
    assert wire.diameter == 100e-6 and wire.convection == 135.0
    assert wire.A_f - C0 == pytest.approx(49.0) and wire.M_f - C0 == pytest.approx(9.0)
    assert wire.C_A == 13.8e6 and wire.E_M == 26.3e9
    # 102–127 Ω/m at 100 µm (physics.md §7)
    assert float(sma.resistance(wire, 1.0)) / wire.length == pytest.approx(101.9, abs=0.1)
    assert float(sma.resistance(wire, 0.0)) / wire.length == pytest.approx(127.3, abs=0.1)


def _with(tmp_path, pattern, repl):
    text = (MODELS / "finger.toml").read_text(encoding="utf-8")
    new, n = re.subn(pattern, repl, text, count=1, flags=re.M)
    assert n == 1
    f = tmp_path / "finger.toml"
    f.write_text(new, encoding="utf-8")
    return f


@pytest.mark.parametrize(
    "pattern,repl,needle",
    [
        (r'^(diameter = \{ value = 100e-6, unit = )"m"', r'\1"um"', 'diameter: unit must be "m"'),
        (r'^(A_f = \{ value = )322\.15, unit = "K"', r'\g<1>49.0, unit = "degC"', 'A_f: unit must be "K"'),
        (r"^(convection = \{ value = )135\.0", r"\g<1>-1.0", "outside the allowed range"),
        (r"^(A_s = \{ value = )307\.65", r"\g<1>330.0", "need A_s < A_f"),
    ],
)
def test_bad_wire_file_is_rejected(tmp_path, pattern, repl, needle):
    with pytest.raises(BadInput) as e:
        sma.load_wire(_with(tmp_path, pattern, repl))
    assert needle in str(e.value) and "\n" not in str(e.value)


# ---------------------------------------------------------------- thermal


def test_time_constant_from_step_response(wire):
    tau = float(sma.time_constant(wire))
    assert tau == pytest.approx(wire.density * wire.specific_heat * wire.diameter / (4 * wire.convection))
    assert tau == pytest.approx(1.0, abs=0.01)  # physics.md §1
    # 60 mA keeps the wire below A_s (no transformation, constant R): a pure first-order response
    I, dt, n = 0.06, 0.01, 400
    tr = sma.simulate_wire(wire, jnp.full(n, I), dt)
    T = np.asarray(tr.temperature)
    assert np.all(np.asarray(tr.xi) == 1.0) and T.max() < wire.A_s
    T_ss = float(sma.steady_state_temperature(wire, I, xi=1.0))
    t = dt * np.arange(1, n + 1)
    frac = (T - wire.ambient) / (T_ss - wire.ambient)
    sel = (frac > 0.1) & (frac < 0.95)
    slope = np.polyfit(t[sel], np.log(1.0 - frac[sel]), 1)[0]
    assert -1.0 / slope == pytest.approx(tau, rel=0.02)
    # time to 63.2 %
    t63 = np.interp(1.0 - math.exp(-1.0), frac, t)
    assert t63 == pytest.approx(tau, rel=0.02)


def test_steady_state_at_150_mA(wire):
    T_cf = float(sma.steady_state_temperature(wire, 0.15))
    assert 85.0 < T_cf - C0 < 95.0  # physics.md §1: ~150 mA for 90 °C
    tr = sma.simulate_wire(wire, jnp.full(400, 0.15), 0.025)  # 10 τ
    assert float(tr.xi[-1]) == pytest.approx(0.0, abs=1e-12)  # fully austenite, R = R_A
    assert float(tr.temperature[-1]) == pytest.approx(T_cf, abs=0.01)
    I90 = float(sma.steady_state_current(wire, C0 + 90.0))
    assert 0.14 < I90 < 0.16
    assert float(sma.steady_state_temperature(wire, I90)) == pytest.approx(C0 + 90.0)


def test_thermal_rhs_is_the_energy_balance(wire):
    # at the closed-form steady state the right-hand side vanishes; latent absorption (ξ̇ < 0) cools
    T = sma.steady_state_temperature(wire, 0.15, xi=0.3)
    assert abs(float(sma.thermal_rhs(wire, T, 0.15, 0.3))) < 1e-9
    assert float(sma.thermal_rhs(wire, T, 0.15, 0.3, xi_rate=-1.0)) == pytest.approx(
        -wire.latent_heat / wire.specific_heat
    )


def test_latent_heat_slows_heating_and_energy_is_conserved(wire):
    I, dt, n = 0.15, 0.01, 300
    tr = sma.simulate_wire(wire, jnp.full(n, I), dt)
    tr0 = sma.simulate_wire(wire._replace(latent_heat=0.0), jnp.full(n, I), dt)
    T, T0 = np.asarray(tr.temperature), np.asarray(tr0.temperature)
    t = dt * np.arange(1, n + 1)
    target = wire.A_f + 5.0
    assert np.interp(target, T, t) > np.interp(target, T0, t) + 0.1  # absorbing Δh delays the crossing
    assert np.all(T <= T0 + 1e-9)
    # ∫(I²R − hA(T − T∞)) dt = ρcV ΔT − ρVΔh Δξ (physics.md §1 balance, ξ: 1 → 0)
    Ts = np.concatenate([[wire.ambient], T])
    xi = np.concatenate([[1.0], np.asarray(tr.xi)])
    assert xi[-1] == 0.0
    V = float(sma.wire_area(wire)) * wire.length
    power = I**2 * np.asarray(sma.resistance(wire, xi)) - wire.convection * float(sma.surface_area(wire)) * (
        Ts - wire.ambient
    )
    e_in = np.trapezoid(power, dx=dt)
    stored = wire.density * V * (wire.specific_heat * (Ts[-1] - Ts[0]) - wire.latent_heat * (xi[-1] - xi[0]))
    assert e_in == pytest.approx(stored, rel=0.01)
    latent = wire.density * V * wire.latent_heat
    assert stored > wire.density * V * wire.specific_heat * (Ts[-1] - Ts[0]) + 0.99 * latent


def test_thermal_scan_gradients(wire):
    def f(currents):
        tr = sma.simulate_wire(wire, currents, 0.2, substeps=2, stress=50e6)
        return jnp.stack([tr.temperature, tr.xi, tr.strain])

    c = jnp.linspace(0.12, 0.2, 6)  # heats through the A_s–A_f window
    xi = np.asarray(f(c)[1])
    assert xi[0] == 1.0 and 0.0 < xi[3] < 1.0
    check_grads(f, (c,), order=1, modes=("fwd", "rev"), eps=1e-6)


# ---------------------------------------------------------------- Brinson kinetics


def _tri(lo, hi, n):
    return jnp.concatenate([jnp.linspace(lo, hi, n), jnp.linspace(hi, lo, n)[1:]])


def _cross(T, xi, level=0.5):
    """Temperature where a monotone branch crosses ``level``."""
    order = np.argsort(xi)
    return float(np.interp(level, np.asarray(xi)[order], np.asarray(T)[order]))


def test_brinson_major_loop_and_hysteresis(wire):
    n = 181
    T = _tri(C0 - 5.0, C0 + 85.0, n)
    xi = np.asarray(sma.transformation(wire, T, 0.1).xi)
    assert xi[0] == 1.0 and xi[n - 1] == 0.0 and xi[-1] == pytest.approx(1.0)
    d = np.diff(xi)
    assert np.all(d[: n - 1] <= 1e-15) and np.all(d[n - 1 :] >= -1e-15)  # heating lowers ξ, cooling raises it
    Th, Tc = _cross(T[:n], xi[:n]), _cross(T[n - 1 :], xi[n - 1 :])
    # cosine kinetics: ξ = ½ at the middle of each window (Brinson 1993)
    assert Th == pytest.approx(0.5 * (wire.A_s + wire.A_f), abs=0.3)
    assert Tc == pytest.approx(0.5 * (wire.M_s + wire.M_f), abs=0.3)
    assert Th - Tc > 25.0
    # at 30 °C the heating curve is still martensite and the cooling curve still austenite
    T30 = np.argmin(np.abs(np.asarray(T[:n]) - (C0 + 30)))
    assert xi[T30] == 1.0 and xi[2 * (n - 1) - T30] == 0.0


def test_stress_shifts_the_windows(wire):
    n = 181
    T = _tri(C0 - 5.0, C0 + 115.0, n)
    s = 200e6
    xi = np.asarray(sma.transformation(wire, T, 0.1, stress=s).xi)
    Th, Tc = _cross(T[:n], xi[:n]), _cross(T[n - 1 :], xi[n - 1 :])
    assert Th == pytest.approx(0.5 * (wire.A_s + wire.A_f) + s / wire.C_A, abs=0.3)
    assert Tc == pytest.approx(0.5 * (wire.M_s + wire.M_f) + (s - wire.sigma_s_cr) / wire.C_M, abs=0.3)


def test_minor_loop_has_no_jump(wire):
    # heat half-way through A_s–A_f, cool 4 K, reheat: Brinson's latched ξ₀ would jump at the reversal;
    # the rescaled branch passes through the current point
    up = jnp.linspace(C0 + 20.0, C0 + 42.0, 221)
    down = jnp.linspace(C0 + 42.0, C0 + 38.0, 41)[1:]
    again = jnp.linspace(C0 + 38.0, C0 + 60.0, 221)[1:]
    T = jnp.concatenate([up, down, again])
    xi = np.asarray(sma.transformation(wire, T, 0.1).xi)
    i_rev = 220
    assert 0.3 < xi[i_rev] < 0.7
    assert np.all(np.abs(np.diff(xi)) < 0.02)  # continuous at both reversals
    assert np.allclose(xi[i_rev : i_rev + 41], xi[i_rev])  # cooling above M_s leaves ξ unchanged
    assert xi[-1] == 0.0


def test_strain_recovery_under_load(wire):
    s = 172e6  # Dynalloy's recommended stress for the 100 µm wire (physics.md §7)
    T = _tri(C0 - 5.0, C0 + 90.0, 96)
    tr = sma.transformation(wire, T, 0.1, stress=s)
    eps = np.asarray(tr.strain)
    cold = (s - wire.Theta * (float(T[0]) - wire.ambient)) / wire.E_M + wire.eps_L  # detwinned martensite
    hot = (s - wire.Theta * (float(T[95]) - wire.ambient)) / wire.E_A  # austenite
    assert eps[0] == pytest.approx(cold) and eps[95] == pytest.approx(hot)
    assert eps[0] - eps[95] > 0.06


def test_steady_state_in_window_does_not_drift(wire):
    # hold the temperature inside A_s–A_f: ξ must stay put (no creeping transformation)
    T = jnp.concatenate([jnp.linspace(C0 + 20.0, C0 + 42.0, 23), jnp.full(200, C0 + 42.0)])
    xi = np.asarray(sma.transformation(wire, T, 0.1).xi)
    assert 0.3 < xi[22] < 0.7 and np.allclose(xi[22:], xi[22], atol=1e-12)


# ---------------------------------------------------------------- quasi-static law


def test_quasi_static_stress_inverts_strain(wire):
    T = jnp.array([wire.ambient, C0 + 40.0, C0 + 90.0, wire.ambient])
    s = jnp.array([135e6, 250e6, 400e6, 300e6])
    eps = sma.quasi_static_strain(wire, s, T)
    assert np.allclose(np.asarray(sma.quasi_static_stress(wire, eps, T)), np.asarray(s), rtol=1e-10)
    # cold wire on the detwinning plateau: σ_s^cr ≤ σ ≤ σ_f^cr for strains between the plateau ends
    cold = np.asarray(sma.quasi_static_stress(wire, jnp.array([0.01, 0.04, 0.07]), wire.ambient))
    assert wire.sigma_s_cr <= cold[0] <= cold[1] <= cold[2] and cold[1] < wire.sigma_f_cr
    check_grads(
        jax.jit(lambda e, t: sma.quasi_static_stress(wire, e, t)), (eps, T), order=1, modes=("fwd", "rev"), eps=1e-7
    )


# ---------------------------------------------------------------- Bouc–Wen


def test_bouc_wen_hysteresis():
    bw = sma.BoucWenParams(alpha=0.2, k=1.0, A=1.0, beta=0.5, gamma=0.5, n=1.0)
    x = 3.0 * jnp.sin(jnp.linspace(0.0, 4.0 * jnp.pi, 801))
    y, z = sma.bouc_wen(bw, x)
    y, z, x = np.asarray(y), np.asarray(z), np.asarray(x)
    zmax = (bw.A / (bw.beta + bw.gamma)) ** (1.0 / bw.n)
    assert np.abs(z).max() <= zmax * (1 + 1e-6) and np.abs(z).max() > 0.9 * zmax
    # second cycle: the loop encloses area (∮ y dx ≠ 0), the up and down branches differ at x = 0
    area = np.sum(0.5 * (y[401:] + y[400:-1]) * np.diff(x[400:]))
    assert abs(area) > 0.5
    bw1 = bw._replace(alpha=1.0)
    assert np.allclose(np.asarray(sma.bouc_wen(bw1, x)[0]), x)  # no hysteretic part: y = k x


# ---------------------------------------------------------------- safety


def test_safety_limits(wire):
    s = sma.check_safety(wire, jnp.array([0.1, 0.3, 0.1]), jnp.array([350.0, 350.0, 400.0]))
    assert np.asarray(s.current_ok).tolist() == [True, False, True]
    assert np.asarray(s.temperature_ok).tolist() == [True, True, False]
    assert np.asarray(s.ok).tolist() == [True, False, False]
    assert float(sma.safe_current(wire, 0.5)) == wire.max_current
    assert float(sma.safe_current(wire, -0.5)) == -wire.max_current
    assert float(sma.safe_current(wire, 0.15, wire.max_temperature)) == 0.0
    assert float(sma.safe_current(wire, 0.15, 350.0)) == 0.15
    i_max = float(sma.max_steady_current(wire))
    assert float(sma.steady_state_temperature(wire, i_max)) <= wire.max_temperature + 1e-9
    assert 0.15 < i_max <= wire.max_current
