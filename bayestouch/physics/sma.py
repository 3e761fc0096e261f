"""NiTi shape-memory wires: lumped thermal model (current → temperature), smooth Brinson (1993) kinetics
(temperature and stress → martensite fraction), Bouc–Wen hysteresis, and the wires' current and temperature limits.

Every function is a pure JAX function of arrays (elementwise: one wire or several at once) and of a
:class:`WireParams` NamedTuple (a pytree) read from ``[wire]`` of ``models/finger.toml``, where the constants'
sources are given. SI units throughout: metres, kelvin, seconds, amperes, pascals, ohms. The equations, their
differentiable form and the simplifications: ``docs/physics_notes.md``.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS, Spec, build

__all__ = [
    "WireParams",
    "WIRE_SPECS",
    "load_wire",
    "wire_area",
    "surface_area",
    "resistance",
    "time_constant",
    "thermal_rhs",
    "steady_state_temperature",
    "steady_state_current",
    "modulus",
    "heating_fraction",
    "cooling_progress",
    "detwinned_share",
    "brinson_strain",
    "brinson_stress",
    "BrinsonState",
    "brinson_init",
    "brinson_update",
    "WireTrace",
    "WireState",
    "wire_state_init",
    "wire_step",
    "simulate_wire",
    "transformation",
    "quasi_static_fraction",
    "quasi_static_strain",
    "quasi_static_stress",
    "BoucWenParams",
    "bouc_wen",
    "SafetyStatus",
    "check_safety",
    "safe_current",
    "max_steady_current",
]

_TINY = 1e-12


class WireParams(NamedTuple):
    """Constants of one NiTi wire (``[wire]`` of ``models/finger.toml``; sources are in that file).

    Attributes
    ----------
    diameter : float, m
        Wire diameter d (100 µm, Dynalloy Flexinol).
    length : float, m
        Active wire length L.
    density : float, kg/m³
        ρ (6450 kg/m³, Dynalloy).
    specific_heat : float, J/(kg K)
        c (837 J/(kg K), Dynalloy).
    latent_heat : float, J/kg
        Transformation enthalpy Δh (24.2 J/g, Dynalloy).
    resistivity_martensite, resistivity_austenite : float, Ω m
        ρ_M, ρ_A (80 and 100 µΩ cm, Dynalloy).
    convection : float, W/(m² K)
        Film coefficient h (135 W/(m² K), still air, Morgan 1975; physics.md §1).
    ambient : float, K
        Air and reference temperature T∞ (also Brinson's reference temperature T₀).
    E_A, E_M : float, Pa
        Austenite and martensite Young's moduli (Brinson 1993).
    eps_L : float, 1
        Maximum recoverable strain ε_L (Brinson 1993).
    Theta : float, Pa/K
        Thermoelastic coefficient Θ (Brinson 1993).
    M_f, M_s, A_s, A_f : float, K
        Stress-free transformation temperatures (Brinson 1993).
    C_M, C_A : float, Pa/K
        Slopes of the critical-stress lines (Brinson 1993).
    sigma_s_cr, sigma_f_cr : float, Pa
        Critical stresses for the start and end of detwinning (Brinson 1993).
    prestrain : float, 1
        Strain ε_pre of each wire in the straight, cold finger (physics.md §2).
    max_current : float, A
        Safety limit on |I|.
    max_temperature : float, K
        Safety limit on T.
    """

    diameter: float
    length: float
    density: float
    specific_heat: float
    latent_heat: float
    resistivity_martensite: float
    resistivity_austenite: float
    convection: float
    ambient: float
    E_A: float
    E_M: float
    eps_L: float
    Theta: float
    M_f: float
    M_s: float
    A_s: float
    A_f: float
    C_M: float
    C_A: float
    sigma_s_cr: float
    sigma_f_cr: float
    prestrain: float
    max_current: float
    max_temperature: float


#: unit and allowed range of every field of :class:`WireParams` (``"1"`` = dimensionless)
WIRE_SPECS = {
    "diameter": Spec("m", 1e-5, 1e-3),
    "length": Spec("m", 1e-3, 2.0),
    "density": Spec("kg/m^3", 1e3, 2e4),
    "specific_heat": Spec("J/(kg K)", 50.0, 5e3),
    "latent_heat": Spec("J/kg", 0.0, 1e6),
    "resistivity_martensite": Spec("ohm m", 1e-8, 1e-5),
    "resistivity_austenite": Spec("ohm m", 1e-8, 1e-5),
    "convection": Spec("W/(m^2 K)", 1.0, 1e5),
    "ambient": Spec("K", 200.0, 400.0),
    "E_A": Spec("Pa", 1e9, 3e11),
    "E_M": Spec("Pa", 1e9, 3e11),
    "eps_L": Spec("1", 0.0, 0.15),
    "Theta": Spec("Pa/K", -1e8, 1e8),
    "M_f": Spec("K", 150.0, 500.0),
    "M_s": Spec("K", 150.0, 500.0),
    "A_s": Spec("K", 150.0, 500.0),
    "A_f": Spec("K", 150.0, 500.0),
    "C_M": Spec("Pa/K", 1e5, 1e9),
    "C_A": Spec("Pa/K", 1e5, 1e9),
    "sigma_s_cr": Spec("Pa", 0.0, 3e9),
    "sigma_f_cr": Spec("Pa", 0.0, 3e9),
    "prestrain": Spec("1", 0.0, 0.15),
    "max_current": Spec("A", 0.0, 20.0),
    "max_temperature": Spec("K", 250.0, 800.0),
}


def load_wire(path=None) -> WireParams:
    """Read ``[wire]`` of a parameter file (default: the shipped ``models/finger.toml``).

    Besides the unit/range/source checks of :func:`bayestouch.params.read_section`, the transformation
    temperatures must be ordered M_f < M_s, A_s < A_f and the critical stresses σ_s^cr < σ_f^cr.

    Raises
    ------
    bayestouch.errors.BadInput
        Missing file or constant, wrong unit, out-of-range value, missing source or a wrong order (one line).
    """
    path = MODELS / "finger.toml" if path is None else path
    p = build(WireParams, path, "wire", WIRE_SPECS)
    for lo, hi in (("M_f", "M_s"), ("A_s", "A_f"), ("sigma_s_cr", "sigma_f_cr")):
        if not getattr(p, lo) < getattr(p, hi):
            raise BadInput(f"{path} [wire] {lo}, {hi}: need {lo} < {hi}, got {getattr(p, lo):g} and {getattr(p, hi):g}")
    return p


# ---------------------------------------------------------------- geometry and thermal model


def wire_area(p: WireParams):
    """Cross-section A_w = π d²/4 in m²."""
    return jnp.pi * p.diameter**2 / 4.0


def surface_area(p: WireParams):
    """Lateral (convecting) surface π d L in m² (the two end faces are neglected, d ≪ L)."""
    return jnp.pi * p.diameter * p.length


def resistance(p: WireParams, xi):
    """Electrical resistance R(ξ) = L [ξ ρ_M + (1 − ξ) ρ_A] / A_w (physics.md §1).

    Parameters
    ----------
    p : WireParams
    xi : array, 1
        Martensite fraction ξ ∈ [0, 1].

    Returns
    -------
    array, ohms (shape of ``xi``)
    """
    rho_e = xi * p.resistivity_martensite + (1.0 - xi) * p.resistivity_austenite
    return p.length * rho_e / wire_area(p)


def time_constant(p: WireParams):
    """Thermal time constant τ = ρ c V / (h A_s) = ρ c d / (4 h), seconds (physics.md §1)."""
    return p.density * p.specific_heat * p.diameter / (4.0 * p.convection)


def thermal_rhs(p: WireParams, temperature, current, xi, xi_rate=0.0):
    """Right-hand side dT/dt of the lumped energy balance (physics.md §1).

    ρ c V dT/dt = I² R(ξ) − h A_s (T − T∞) + ρ V Δh dξ/dt.

    Parameters
    ----------
    p : WireParams
    temperature : array, K
    current : array, amperes
    xi : array, 1
        Martensite fraction.
    xi_rate : array, 1/s
        dξ/dt (negative on heating through A_s–A_f).

    Returns
    -------
    array, K/s
    """
    vol = wire_area(p) * p.length
    heat = (
        current**2 * resistance(p, xi)
        - p.convection * surface_area(p) * (temperature - p.ambient)
        + p.density * vol * p.latent_heat * xi_rate
    )
    return heat / (p.density * p.specific_heat * vol)


def steady_state_temperature(p: WireParams, current, xi=0.0):
    """Steady temperature T∞ + I² R(ξ)/(h A_s) in K, latent heat ignored (physics.md §1).

    Parameters
    ----------
    p : WireParams
    current : array, amperes
    xi : array, 1
        Martensite fraction held fixed (default 0: austenite, the state of a wire driven hot).
    """
    return p.ambient + current**2 * resistance(p, xi) / (p.convection * surface_area(p))


def steady_state_current(p: WireParams, temperature, xi=0.0):
    """Current in amperes that holds the wire at ``temperature`` (K), the inverse of
    :func:`steady_state_temperature` (≈ 150 mA for 90 °C, physics.md §1)."""
    dT = jnp.maximum(temperature - p.ambient, 0.0)
    return jnp.sqrt(p.convection * surface_area(p) * dT / resistance(p, xi))


# ---------------------------------------------------------------- Brinson 1993, smooth form


def _ramp(x):
    """Clip to [0, 1]; composed with cos(π·) the ramps below are C¹ at both ends."""
    return jnp.clip(x, 0.0, 1.0)


def modulus(p: WireParams, xi):
    """Young's modulus E(ξ) = E_A + ξ (E_M − E_A) in Pa (Brinson 1993; physics.md §1)."""
    return p.E_A + xi * (p.E_M - p.E_A)


def heating_fraction(p: WireParams, temperature, stress=0.0):
    """Brinson's heating (M → A) shape g = ½{cos[π (T − A_s − σ/C_A)/(A_f − A_s)] + 1} ∈ [0, 1].

    On a heating branch that started at ξ₀ below A_s, ξ = ξ₀ g (Brinson 1993; physics.md §1). g = 1 below
    A_s + σ/C_A and 0 above A_f + σ/C_A. Only tension shifts the window (σ⁺ = max(σ, 0)) [A].

    Parameters
    ----------
    p : WireParams
    temperature : array, K
    stress : array, Pa
    """
    s = jnp.maximum(stress, 0.0)
    x = _ramp((temperature - p.A_s - s / p.C_A) / (p.A_f - p.A_s))
    return 0.5 * (jnp.cos(jnp.pi * x) + 1.0)


def cooling_progress(p: WireParams, temperature, stress=0.0):
    """Brinson's cooling (A → M) shape h = ½{1 − cos[π (T − M_f − Δ)/(M_s − M_f)]} ∈ [0, 1].

    On a cooling branch that started at ξ₀ above the window, ξ = 1 − (1 − ξ₀) h, which is Brinson's
    ((1 − ξ₀)/2) cos[…] + (1 + ξ₀)/2 (Brinson 1993; physics.md §1). The window starts on Brinson's
    critical-stress line, shifted by Δ = max(σ − σ_s^cr, 0)/C_M [A: the M_s − M_f width is kept].
    h = 1 above M_s + Δ (no martensite formed yet) and 0 below M_f + Δ.
    """
    shift = jnp.maximum(stress - p.sigma_s_cr, 0.0) / p.C_M
    x = _ramp((temperature - p.M_f - shift) / (p.M_s - p.M_f))
    return 0.5 * (1.0 - jnp.cos(jnp.pi * x))


def detwinned_share(p: WireParams, stress):
    """Detwinned share of the martensite, ½{1 − cos[π (σ − σ_s^cr)/(σ_f^cr − σ_s^cr)]} ∈ [0, 1].

    Brinson's detwinning ramp between the critical stresses (Brinson 1993; physics.md §1), used as a
    reversible function of stress (the loading curve) [A]. ξ_s = ξ · share.
    """
    x = _ramp((stress - p.sigma_s_cr) / (p.sigma_f_cr - p.sigma_s_cr))
    return 0.5 * (1.0 - jnp.cos(jnp.pi * x))


def brinson_strain(p: WireParams, stress, temperature, xi, xi_s):
    """Strain ε = (σ − Θ (T − T∞))/E(ξ) + ε_L ξ_s, Brinson's stress law solved for ε (physics.md §1).

    Parameters
    ----------
    p : WireParams
    stress : array, Pa
    temperature : array, K
    xi, xi_s : array, 1
        Total and detwinned martensite fractions.

    Returns
    -------
    array, 1
    """
    return (stress - p.Theta * (temperature - p.ambient)) / modulus(p, xi) + p.eps_L * xi_s


def brinson_stress(p: WireParams, strain, temperature, xi, xi_s):
    """Stress σ = E(ξ)(ε − ε_L ξ_s) + Θ (T − T∞) in Pa (Brinson 1993 with a stress-free, strain-free
    austenite reference at T∞; physics.md §1)."""
    return modulus(p, xi) * (strain - p.eps_L * xi_s) + p.Theta * (temperature - p.ambient)


class BrinsonState(NamedTuple):
    """Branch state of the smooth Brinson kinetics, carried through ``lax.scan``.

    Attributes
    ----------
    xi : array, 1
        Martensite fraction ξ.
    latch_h : array, 1
        ξ₀ of the heating branch (so that ξ = ξ₀ g(T) on heating).
    latch_c : array, 1
        ξ₀ of the cooling branch (so that ξ = 1 − (1 − ξ₀) h(T) on cooling).
    """

    xi: jax.Array
    latch_h: jax.Array
    latch_c: jax.Array


def _latches(xi, g, h):
    """ξ₀ values that put the heating curve ξ₀ g and the cooling curve 1 − (1 − ξ₀) h through the point ξ
    (the rescaling idea of Chung et al. 2007)."""
    lat_h = jnp.minimum(1.0, xi / jnp.maximum(g, _TINY))
    lat_c = jnp.maximum(0.0, 1.0 - (1.0 - xi) / jnp.maximum(h, _TINY))
    return lat_h, lat_c


def brinson_init(p: WireParams, temperature, stress=0.0, xi=1.0) -> BrinsonState:
    """Initial branch state at (T, σ, ξ), with both branches latched through the current point.

    Parameters
    ----------
    p : WireParams
    temperature : array, K
    stress : array, Pa
    xi : array, 1
        Initial martensite fraction (1: all martensite, the cold pre-strained wire).
    """
    temperature, stress, xi = jnp.broadcast_arrays(*(jnp.asarray(a, dtype=float) for a in (temperature, stress, xi)))
    lat_h, lat_c = _latches(xi, heating_fraction(p, temperature, stress), cooling_progress(p, temperature, stress))
    return BrinsonState(xi, lat_h, lat_c)


def _branch_xi(state, g, h, w):
    """ξ after a step: w min(ξ, ξ₀ʰ g) + (1 − w) max(ξ, 1 − (1 − ξ₀ᶜ) h)."""
    xi_h = jnp.minimum(state.xi, state.latch_h * g)
    xi_c = jnp.maximum(state.xi, 1.0 - (1.0 - state.latch_c) * h)
    return w * xi_h + (1.0 - w) * xi_c


def brinson_update(p: WireParams, state: BrinsonState, temperature, stress, rate, rate_scale=0.1) -> BrinsonState:
    """One step of the smooth Brinson kinetics to a new temperature (physics.md §1 [D]).

    ξ_heat = min(ξ, ξ₀ʰ g(T)), ξ_cool = max(ξ, 1 − (1 − ξ₀ᶜ) h(T)), and the new ξ = w ξ_heat + (1 − w) ξ_cool
    with w = ½[1 + tanh(Ṫ/Ṫ_s)]. The heating latch ξ₀ʰ is re-latched through the new point with weight
    max(−tanh(Ṫ/Ṫ_s), 0) (i.e. while cooling) and frozen while heating; the cooling latch likewise.

    Parameters
    ----------
    p : WireParams
    state : BrinsonState
    temperature : array, K
        Temperature at the end of the step.
    stress : array, Pa
    rate : array, K/s
        Ṫ over the step; only its sign and size relative to ``rate_scale`` matter.
    rate_scale : float, K/s
        Ṫ_s, width of the smooth heating/cooling switch.

    Returns
    -------
    BrinsonState
    """
    t = jnp.tanh(rate / rate_scale)
    g = heating_fraction(p, temperature, stress)
    h = cooling_progress(p, temperature, stress)
    xi = _branch_xi(state, g, h, 0.5 * (1.0 + t))
    lat_h, lat_c = _latches(xi, g, h)
    a_c = jnp.maximum(-t, 0.0)
    a_h = jnp.maximum(t, 0.0)
    return BrinsonState(
        xi, state.latch_h + a_c * (lat_h - state.latch_h), state.latch_c + a_h * (lat_c - state.latch_c)
    )


class WireTrace(NamedTuple):
    """Time series of a wire simulation; every field has the shape of the input currents (N,) or (N, W).

    Attributes
    ----------
    temperature : array, K
    xi : array, 1
        Martensite fraction ξ.
    xi_s : array, 1
        Detwinned (stress-induced) martensite fraction ξ_s.
    resistance : array, ohms
    strain : array, 1
        Wire strain ε under the applied stress (Brinson's stress law).
    stress : array, Pa
        The applied stress (echoed).
    """

    temperature: jax.Array
    xi: jax.Array
    xi_s: jax.Array
    resistance: jax.Array
    strain: jax.Array
    stress: jax.Array


def _substep(p, carry, current, stress, h, rate_scale, n_newton=2):
    """One thermal substep of length h: exact exponential step of the linear part (Joule heat with R(ξ)
    from the start of the step, convection), then the latent heat as an implicit enthalpy correction
    T = T_pred + (Δh/c)(ξ(T) − ξ_old), solved by Newton (its slope 1 − (Δh/c) dξ/dT ≥ 1)."""
    T, st = carry
    hA = p.convection * surface_area(p)
    T_eq = p.ambient + current**2 * resistance(p, st.xi) / hA
    T_pred = T_eq + (T - T_eq) * jnp.exp(-h / time_constant(p))
    rate = (T_pred - T) / h
    lat = p.latent_heat / p.specific_heat

    w = 0.5 * (1.0 + jnp.tanh(rate / rate_scale))

    def xi_of(Tn):
        return _branch_xi(st, heating_fraction(p, Tn, stress), cooling_progress(p, Tn, stress), w)

    Tn = T_pred
    for _ in range(n_newton):
        x, dx = jax.jvp(xi_of, (Tn,), (jnp.ones_like(Tn),))
        Tn = Tn - (Tn - T_pred - lat * (x - st.xi)) / (1.0 - lat * dx)
    st_new = brinson_update(p, st, Tn, stress, rate, rate_scale)
    # energy-consistent split: the enthalpy released/absorbed by Δξ goes into T exactly
    return T_pred + lat * (st_new.xi - st.xi), st_new


class WireState(NamedTuple):
    """A wire's state between samples, carried through ``lax.scan`` by callers that set the stress sample by sample
    (e.g. from the bend it produces, :mod:`bayestouch.physics.pose`).

    Attributes
    ----------
    temperature : array, K
    brinson : BrinsonState
    """

    temperature: jax.Array
    brinson: BrinsonState


def wire_state_init(p: WireParams, T0=None, xi0=1.0, stress=0.0) -> WireState:
    """The state at temperature ``T0`` (K, default ambient), martensite fraction ``xi0`` and stress ``stress`` (Pa),
    with both Brinson branches latched through it."""
    T0 = jnp.asarray(p.ambient if T0 is None else T0, dtype=float)
    T0, stress, xi0 = jnp.broadcast_arrays(T0, jnp.asarray(stress, dtype=float), jnp.asarray(xi0, dtype=float))
    return WireState(T0, brinson_init(p, T0, stress, xi0))


def wire_step(p: WireParams, state: WireState, current, stress, dt, substeps: int = 10, rate_scale=0.1) -> WireState:
    """One sample of :func:`simulate_wire`: the current (A) and stress (Pa) held for ``dt`` seconds, integrated in
    ``substeps`` steps."""
    carry = (state.temperature, state.brinson)
    for _ in range(substeps):
        carry = _substep(p, carry, current, stress, dt / substeps, rate_scale)
    return WireState(*carry)


def _outputs(p, T, xi, stress):
    xs = xi * detwinned_share(p, stress)
    return T, xi, xs, resistance(p, xi), brinson_strain(p, stress, T, xi, xs)


@partial(jax.jit, static_argnames=("substeps",))
def _simulate(p, currents, stress, dt, T0, xi0, substeps, rate_scale):
    st0 = brinson_init(p, T0, stress[0], xi0)
    h = dt / substeps

    def step(carry, inp):
        I, s = inp
        carry = _substep(p, carry, I, s, h, rate_scale)
        return carry, (carry[0], carry[1].xi)

    # one flat scan over all substeps (zero-order hold), outputs taken at the end of each sample
    _, (T, xi) = jax.lax.scan(
        step, (T0, st0), (jnp.repeat(currents, substeps, axis=0), jnp.repeat(stress, substeps, axis=0))
    )
    T, xi = T[substeps - 1 :: substeps], xi[substeps - 1 :: substeps]
    return WireTrace(*_outputs(p, T, xi, stress), stress)


def simulate_wire(p: WireParams, currents, dt, T0=None, xi0=1.0, stress=0.0, substeps=10, rate_scale=0.1) -> WireTrace:
    """Drive a wire (or W wires) with a current history: thermal ODE + smooth Brinson kinetics.

    The current is held for ``dt`` per sample (zero-order hold). Each sample is integrated in ``substeps``
    steps, each an exact exponential step of the linear thermal balance (Joule heat with R(ξ) of the step
    start, convection) followed by an implicit latent-heat correction T = T_pred + (Δh/c)(ξ(T) − ξ_old)
    solved by two Newton steps. The scheme is unconditionally stable and conserves the enthalpy exactly;
    keep dt/substeps ≲ 10 ms inside the transformation windows for accuracy (errors ~1e-9 K at 1 ms).

    Parameters
    ----------
    p : WireParams
    currents : (N,) or (N, W) array, amperes
    dt : float, seconds
        Sample period.
    T0 : float or (W,) array, K
        Initial temperature (default: ambient).
    xi0 : float or (W,) array, 1
        Initial martensite fraction (default 1, the cold pre-strained wire).
    stress : float or array broadcastable to ``currents``, Pa
        Applied tensile stress (dead load); it shifts the transformation temperatures and sets the strain.
    substeps : int
        Integration steps per sample (static).
    rate_scale : float, K/s
        Width of the smooth heating/cooling switch of :func:`brinson_update`.

    Returns
    -------
    WireTrace
        State at the end of each sample, t = (k + 1) dt.
    """
    currents = jnp.asarray(currents, dtype=float)
    stress = jnp.broadcast_to(jnp.asarray(stress, dtype=float), currents.shape)
    T0 = p.ambient if T0 is None else T0
    T0 = jnp.broadcast_to(jnp.asarray(T0, dtype=float), currents.shape[1:])
    xi0 = jnp.broadcast_to(jnp.asarray(xi0, dtype=float), currents.shape[1:])
    return _simulate(p, currents, stress, dt, T0, xi0, substeps, rate_scale)


@jax.jit
def _transformation(p, temperatures, stress, dt, xi0, rate_scale):
    st0 = brinson_init(p, temperatures[0], stress[0], xi0)

    def step(carry, inp):
        T_old, st = carry
        T, s = inp
        st = brinson_update(p, st, T, s, (T - T_old) / dt, rate_scale)
        return (T, st), _outputs(p, T, st.xi, s)

    _, out = jax.lax.scan(step, (temperatures[0], st0), (temperatures, stress))
    return WireTrace(*out, stress)


def transformation(p: WireParams, temperatures, dt, stress=0.0, xi0=1.0, rate_scale=0.1) -> WireTrace:
    """Smooth Brinson kinetics driven by a prescribed temperature history (no thermal model).

    Parameters
    ----------
    p : WireParams
    temperatures : (N,) or (N, W) array, K
        Temperature at each sample; the first one is the initial state.
    dt : float, seconds
        Sample period (sets Ṫ relative to ``rate_scale``).
    stress : float or array broadcastable to ``temperatures``, Pa
    xi0 : float or (W,) array, 1
        Martensite fraction at ``temperatures[0]``.
    rate_scale : float, K/s

    Returns
    -------
    WireTrace
        With ``temperature`` echoing the input.
    """
    temperatures = jnp.asarray(temperatures, dtype=float)
    stress = jnp.broadcast_to(jnp.asarray(stress, dtype=float), temperatures.shape)
    xi0 = jnp.broadcast_to(jnp.asarray(xi0, dtype=float), temperatures.shape[1:])
    return _transformation(p, temperatures, stress, dt, xi0, rate_scale)


# ---------------------------------------------------------------- quasi-static stress law for bending


def quasi_static_fraction(p: WireParams, stress, temperature):
    """Martensite fraction on the major heating branch from a fully martensitic wire, ξ = g(T, σ)
    (:func:`heating_fraction`, Brinson 1993 with ξ₀ = 1): the state of a pre-strained wire heated from cold."""
    return heating_fraction(p, temperature, stress)


def quasi_static_strain(p: WireParams, stress, temperature, xi=None):
    """Strain of a wire at stress σ and temperature T on the quasi-static loading curve.

    ε = (σ − Θ (T − T∞))/E(ξ) + ε_L ξ D(σ), with D the detwinning ramp (:func:`detwinned_share`, the
    Brinson plateau σ_s^cr … σ_f^cr along which cold antagonist wires stretch, physics.md §2) and ξ from
    :func:`quasi_static_fraction` unless given (e.g. from :func:`simulate_wire`, which carries the
    hysteresis). Increasing in σ for the Brinson constants, so it can be inverted
    (:func:`quasi_static_stress`).

    Parameters
    ----------
    p : WireParams
    stress : array, Pa
    temperature : array, K
    xi : array or None, 1

    Returns
    -------
    array, 1
    """
    x = quasi_static_fraction(p, stress, temperature) if xi is None else xi
    return brinson_strain(p, stress, temperature, x, x * detwinned_share(p, stress))


@partial(jax.jit, static_argnames=("n_bisect", "bracket"))
def quasi_static_stress(p: WireParams, strain, temperature, xi=None, n_bisect=64, bracket=(-5e9, 5e9)):
    """Invert :func:`quasi_static_strain`: the stress (Pa) of a wire held at ``strain`` and ``temperature``.

    Bisection on ``bracket`` (a fixed number of steps, jit-able), then one Newton step whose derivatives
    carry the implicit-function-theorem tangent dσ = (dε − ∂ε/∂θ dθ)/(∂ε/∂σ), so gradients with respect
    to strain, temperature, ξ and the wire constants are exact at the converged root.

    Parameters
    ----------
    p : WireParams
    strain : array, 1
    temperature : array, K
    xi : array or None, 1
    n_bisect : int
        Bisection steps (64 resolve 10 GPa to below 1e-9 Pa).
    bracket : (float, float), Pa

    Returns
    -------
    array, Pa (broadcast shape of the inputs)
    """
    args = [jnp.asarray(strain, dtype=float), jnp.asarray(temperature, dtype=float)]
    if xi is not None:
        args.append(jnp.asarray(xi, dtype=float))
    args = jnp.broadcast_arrays(*args)
    strain, temperature = args[0], args[1]
    xi = args[2] if xi is not None else None
    sg = jax.lax.stop_gradient
    ps, es, ts = sg(p), sg(strain), sg(temperature)
    xs = None if xi is None else sg(xi)

    def f(s):
        return quasi_static_strain(ps, s, ts, xs) - es

    def body(_, lohi):
        lo, hi = lohi
        mid = 0.5 * (lo + hi)
        below = f(mid) < 0.0
        return jnp.where(below, mid, lo), jnp.where(below, hi, mid)

    lo = jnp.full(strain.shape, bracket[0])
    hi = jnp.full(strain.shape, bracket[1])
    lo, hi = jax.lax.fori_loop(0, n_bisect, body, (lo, hi))
    s0 = 0.5 * (lo + hi)
    slope = jax.jvp(lambda s: quasi_static_strain(ps, s, ts, xs), (s0,), (jnp.ones_like(s0),))[1]
    return s0 - (quasi_static_strain(p, s0, temperature, xi) - strain) / slope


# ---------------------------------------------------------------- Bouc–Wen


class BoucWenParams(NamedTuple):
    """Bouc–Wen hysteresis constants (Wen 1976; Ismail et al. 2009; physics.md §1).

    y = α k x + (1 − α) k z,  ż = A ẋ − β |ẋ| |z|^(n−1) z − γ ẋ |z|^n.

    Attributes
    ----------
    alpha : float, 1
        Stiffness ratio α.
    k : float, units of y per unit of x
        Scale (e.g. strain per kelvin when x = T, y = strain).
    A : float, 1
        Slope and amplitude; |z|max = (A/(β + γ))^(1/n).
    beta, gamma : float, 1/(units of x)^n
        Loop shape and width.
    n : float, 1
        Sharpness of the transition (n ≥ 1).
    """

    alpha: float
    k: float
    A: float
    beta: float
    gamma: float
    n: float


@partial(jax.jit, static_argnames=("substeps",))
def bouc_wen(bw: BoucWenParams, x, z0=0.0, eps=1e-9, substeps=4):
    """Bouc–Wen output for an input path x (e.g. temperature → strain), rate-independent.

    The ODE is integrated in the increments of x (dz = A dx − β|dx||z|^(n−1)z − γ dx|z|^n, explicit
    Euler on ``substeps`` equal parts of each increment), with the smooth absolute value
    |a| ≈ √(a² + ε²) for dx and z (physics.md §1) so the map is differentiable everywhere. Keep
    (β + γ) n |dx| |z|^(n−1) / substeps ≪ 1 for accuracy.

    Parameters
    ----------
    bw : BoucWenParams
    x : (N,) array
        Input path; x[0] is the starting point.
    z0 : float
        Initial hysteretic variable.
    eps : float, units of x
        Smoothing of the absolute values.
    substeps : int
        Euler steps per increment (static).

    Returns
    -------
    y : (N,) array
    z : (N,) array
    """
    x = jnp.asarray(x, dtype=float)

    def sabs(a):
        return jnp.sqrt(a * a + eps * eps)

    def step(z, dx):
        d = dx / substeps

        def euler(_, z):
            az = sabs(z)
            return z + bw.A * d - bw.beta * sabs(d) * az ** (bw.n - 1.0) * z - bw.gamma * d * az**bw.n

        z = jax.lax.fori_loop(0, substeps, euler, z)
        return z, z

    dx = jnp.diff(x, prepend=x[:1])
    _, z = jax.lax.scan(step, jnp.asarray(z0, dtype=float), dx)
    return bw.alpha * bw.k * x + (1.0 - bw.alpha) * bw.k * z, z


# ---------------------------------------------------------------- safety


class SafetyStatus(NamedTuple):
    """Result of :func:`check_safety` (boolean arrays of the broadcast input shape)."""

    current_ok: jax.Array
    temperature_ok: jax.Array
    ok: jax.Array


def check_safety(p: WireParams, current, temperature) -> SafetyStatus:
    """Is |I| ≤ ``max_current`` and T ≤ ``max_temperature``?

    Parameters
    ----------
    p : WireParams
    current : array, amperes
    temperature : array, K
    """
    c_ok = jnp.abs(current) <= p.max_current
    t_ok = temperature <= p.max_temperature
    return SafetyStatus(c_ok, t_ok, c_ok & t_ok)


def safe_current(p: WireParams, current, temperature=None, margin=5.0):
    """Clamp a current command to the wire's limits.

    |I| is clipped to ``max_current``; if a temperature is given the current is also tapered smoothly
    (cosine ramp) to zero over the last ``margin`` kelvin below ``max_temperature``, so a wire at or above
    its limit gets no current.

    Parameters
    ----------
    p : WireParams
    current : array, amperes
    temperature : array or None, K
    margin : float, K

    Returns
    -------
    array, amperes
    """
    I = jnp.clip(current, -p.max_current, p.max_current)
    if temperature is None:
        return I
    x = _ramp((temperature - (p.max_temperature - margin)) / margin)
    return I * 0.5 * (1.0 + jnp.cos(jnp.pi * x))


def max_steady_current(p: WireParams):
    """Largest current (A) whose austenitic steady state stays at ``max_temperature``, capped at
    ``max_current`` (R_A > R_M, so this is the conservative bound)."""
    return jnp.minimum(steady_state_current(p, p.max_temperature, 0.0), p.max_current)
