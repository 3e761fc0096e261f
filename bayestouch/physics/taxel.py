"""Metal–ZnO–metal piezotronic taxels: pressure (Pa) and skin temperature (K) → taxel current (A), in the
``"physics"`` mode (the piezotronic chain) or the ``"empirical"`` mode (a calibrated log-sensitivity), with the
taxels' layout on the skin (pad coordinates (u, v) in metres; the first ``reference_rows`` rows unloaded, for drift
compensation) and their first-order response lag.

Everything here is a pure JAX function of arrays and the :class:`TaxelParams` pytree, except :func:`layout` and the
loaders, which build static (NumPy/Python) data outside ``jit``. The chain, the polarity convention, the modes and
the layout: ``docs/physics_notes.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS, Spec, build, read_toml

__all__ = [
    "Q_E",
    "K_B",
    "EPS_0",
    "MODES",
    "TaxelParams",
    "TaxelLayout",
    "TAXEL_SPECS",
    "load_taxels",
    "load_taxel_mode",
    "layout",
    "cell_area",
    "thermal_voltage",
    "coarse_lag",
    "coarse_lag_weights",
    "saturation_current",
    "axial_modulus",
    "piezo_coefficient",
    "nanowire_strain",
    "barrier_change",
    "msm_current",
    "gauge_factor",
    "taxel_current",
    "first_order_lag",
]

#: elementary charge, C (exact in the 2019 SI; CODATA 2018)
Q_E = 1.602176634e-19
#: Boltzmann constant, J/K (exact in the 2019 SI; CODATA 2018)
K_B = 1.380649e-23
#: vacuum permittivity, F/m (CODATA 2018)
EPS_0 = 8.8541878128e-12

#: the two taxel response modes (static choice)
MODES = ("physics", "empirical")


class TaxelParams(NamedTuple):
    """Parameters of the taxel array (a JAX pytree of floats; SI units). Sources: ``models/taxels.toml``.

    Attributes
    ----------
    rows, cols : float
        Array size (integers stored as floats; used only by :func:`layout`, outside ``jit``).
    pitch : float, m
        Centre-to-centre spacing of neighbouring taxels (along a row).
    reference_rows : float
        Number of unloaded reference rows at the array's first edge (integer stored as float).
    hexagonal : float
        1: hexagonal (pore) layout, rows √3/2·pitch apart and odd rows shifted by pitch/2; 0: square grid.
    bias : float, V
        Bias V across the M–S–M taxel.
    barrier : float, V
        Effective Schottky barrier Φ_B / q at zero strain.
    contact_area : float, m²
        Effective electrical contact area A_c of the taxel.
    richardson : float, A m⁻² K⁻²
        Effective Richardson constant A* of ZnO.
    width_piezo : float, m
        Width W of the piezo-charge layer at each contact.
    permittivity : float
        Relative permittivity ε_s / ε₀ of ZnO along c (κ₃₃).
    e31, e33 : float, C/m²
        Piezoelectric stress coefficients of ZnO.
    c11, c12, c13, c33 : float, Pa
        Elastic stiffnesses of ZnO (hexagonal).
    load_fraction : float
        φ_load: nanowire stress = p / φ_load (fraction of the taxel area carried by the wires).
    polarity : float
        s = +1 or −1, c-axis orientation (see the module docstring).
    sensitivity : float, 1/Pa
        Empirical-mode log-sensitivity S_p (Δ ln I = s S_p p).
    lag : float, s
        Time constant τ of the first-order response lag.
    """

    rows: float
    cols: float
    pitch: float
    reference_rows: float
    hexagonal: float
    bias: float
    barrier: float
    contact_area: float
    richardson: float
    width_piezo: float
    permittivity: float
    e31: float
    e33: float
    c11: float
    c12: float
    c13: float
    c33: float
    load_fraction: float
    polarity: float
    sensitivity: float
    lag: float


#: expected constants of ``[taxels]``: SI unit and allowed range
TAXEL_SPECS: dict[str, Spec] = {
    "rows": Spec("1", 1, 4096),
    "cols": Spec("1", 1, 4096),
    "pitch": Spec("m", 1e-6, 1e-2),
    "reference_rows": Spec("1", 0, 4096),
    "hexagonal": Spec("1", 0, 1),
    "bias": Spec("V", -20.0, 20.0),
    "barrier": Spec("V", 0.05, 2.0),
    "contact_area": Spec("m^2", 1e-18, 1e-4),
    "richardson": Spec("A/(m^2*K^2)", 1e2, 2e6),
    "width_piezo": Spec("m", 1e-12, 1e-7),
    "permittivity": Spec("1", 1.0, 100.0),
    "e31": Spec("C/m^2", -10.0, 10.0),
    "e33": Spec("C/m^2", -10.0, 10.0),
    "c11": Spec("Pa", 1e9, 1e13),
    "c12": Spec("Pa", 1e9, 1e13),
    "c13": Spec("Pa", 1e9, 1e13),
    "c33": Spec("Pa", 1e9, 1e13),
    "load_fraction": Spec("1", 1e-6, 1.0),
    "polarity": Spec("1", -1.0, 1.0),
    # > 0 (the sign is the polarity's): at 1e-8 1/Pa 100 kPa moves ln I by 1e-3, below the read-out noise, so a
    # smaller value (0 was accepted) is a finger that feels nothing
    "sensitivity": Spec("1/Pa", 1e-8, 1e-2),
    "lag": Spec("s", 1e-6, 100.0),
}


class TaxelLayout(NamedTuple):
    """Static taxel geometry from :func:`layout`.

    Attributes
    ----------
    positions : (N, 2) ndarray, m
        Taxel centres (u, v) in skin-local coordinates, row-major (index = row · cols + col).
    reference : (N,) bool ndarray
        True for unloaded reference taxels.
    rows, cols : int
    """

    positions: np.ndarray
    reference: np.ndarray
    rows: int
    cols: int


def _as_int(value: float, name: str, where: str) -> int:
    if not float(value).is_integer():
        raise BadInput(f"{where} [taxels] {name}: must be a whole number, got {value:g}")
    return int(value)


def load_taxels(path=MODELS / "taxels.toml") -> TaxelParams:
    """Read ``[taxels]`` of a parameter file into :class:`TaxelParams`.

    Raises :class:`~bayestouch.errors.BadInput` (one line) for a wrong unit, a missing or unknown
    constant, a value out of range, non-integer ``rows``/``cols``/``reference_rows``, ``reference_rows ≥
    rows`` or a polarity other than ±1.
    """
    p = build(TaxelParams, path, "taxels", TAXEL_SPECS)
    rows = _as_int(p.rows, "rows", str(path))
    _as_int(p.cols, "cols", str(path))
    ref = _as_int(p.reference_rows, "reference_rows", str(path))
    if ref >= rows:
        raise BadInput(
            f"{path} [taxels] reference_rows: {ref} leaves no loaded rows (rows = {rows}); "
            f"expected 0 ≤ reference_rows < rows"
        )
    if abs(p.polarity) != 1.0:
        raise BadInput(f"{path} [taxels] polarity: must be 1 or -1, got {p.polarity:g}")
    return p


def load_taxel_mode(path=MODELS / "taxels.toml") -> str:
    """The default response mode, ``[taxel_model] mode = "physics" | "empirical"`` (``"physics"`` if absent)."""
    doc = read_toml(path)
    tab = doc.get("taxel_model", {})
    mode = tab.get("mode", "physics") if isinstance(tab, dict) else None
    if mode not in MODES:
        raise BadInput(f"{path} [taxel_model] mode: must be one of {', '.join(MODES)}, got {mode!r}")
    return mode


def layout(params: TaxelParams) -> TaxelLayout:
    """Taxel positions (hexagonal or square layout) and the reference (unloaded) mask.

    Call outside ``jit`` (the array size is static).

    Parameters
    ----------
    params : TaxelParams

    Returns
    -------
    TaxelLayout
        ``positions (rows·cols, 2)`` in metres, centred on the origin (the bounding box's centre), u along
        columns and v along rows;
        ``reference (rows·cols,)`` true on the first ``reference_rows`` rows (most negative v).
    """
    rows, cols, nref = int(params.rows), int(params.cols), int(params.reference_rows)
    pitch = float(params.pitch)
    hexa = bool(round(float(params.hexagonal)))
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    u = (c.ravel() + (0.5 * (r.ravel() % 2) if hexa else 0.0)) * pitch
    v = r.ravel() * pitch * (np.sqrt(3.0) / 2.0 if hexa else 1.0)
    pos = np.stack([u, v], axis=1)
    pos -= 0.5 * (pos.max(axis=0) + pos.min(axis=0))
    return TaxelLayout(pos, r.ravel() < nref, rows, cols)


def cell_area(params: TaxelParams) -> float:
    """Skin area per taxel, m²: pitch² (square) or √3/2·pitch² (hexagonal)."""
    return float(params.pitch) ** 2 * (np.sqrt(3.0) / 2.0 if round(float(params.hexagonal)) else 1.0)


def thermal_voltage(temperature):
    """V_T = k T / q in volts for ``temperature (...)`` in kelvin."""
    return K_B * jnp.asarray(temperature) / Q_E


def saturation_current(params: TaxelParams, temperature):
    """Unstrained thermionic saturation current I₀(T) = A_c A* T² exp(−Φ_B/V_T) (Sze & Ng 2007).

    Parameters
    ----------
    params : TaxelParams
    temperature : (...) array, K

    Returns
    -------
    (...) array, A
    """
    T = jnp.asarray(temperature)
    return params.contact_area * params.richardson * T**2 * jnp.exp(-params.barrier / thermal_voltage(T))


def axial_modulus(params: TaxelParams):
    """E_c = 1/s₃₃ = c₃₃ − 2 c₁₃² / (c₁₁ + c₁₂) in Pa (uniaxial stress along c, hexagonal crystal) ≈ 140 GPa."""
    return params.c33 - 2.0 * params.c13**2 / (params.c11 + params.c12)


def piezo_coefficient(params: TaxelParams):
    """P₃/ε₃ = e₃₃ + 2 e₃₁ s₁₃/s₃₃ = e₃₃ − 2 e₃₁ c₁₃/(c₁₁ + c₁₂) in C/m² (uniaxial stress along c) ≈ 1.55."""
    return params.e33 - 2.0 * params.e31 * params.c13 / (params.c11 + params.c12)


def nanowire_strain(params: TaxelParams, pressure):
    """Axial nanowire strain ε = −p / (E_c φ_load) (dimensionless, < 0 in compression) for ``pressure (...)`` Pa."""
    return -jnp.asarray(pressure) / (axial_modulus(params) * params.load_fraction)


def barrier_change(params: TaxelParams, pressure, polarity=None):
    """Barrier change at the drain contact, ΔΦ_D = s P₃ W / (2 ε_s ε₀), in volts (Zhang, Liu & Wang 2011).

    The source contact changes by −ΔΦ_D. With s = +1 compression (P₃ < 0) lowers the drain barrier.

    Parameters
    ----------
    params : TaxelParams
    pressure : (...) array, Pa
        Normal pressure on the taxel, positive in compression.
    polarity : (...) array or None
        s = ±1 per taxel; ``None`` uses ``params.polarity``.

    Returns
    -------
    (...) array, V
    """
    s = params.polarity if polarity is None else jnp.asarray(polarity)
    p3 = piezo_coefficient(params) * nanowire_strain(params, pressure)
    return s * p3 * params.width_piezo / (2.0 * params.permittivity * EPS_0)


def msm_current(i_ss, i_sd, bias, v_t):
    """Current of back-to-back Schottky diodes (metal–semiconductor–metal).

    I = 2 I_sS I_sD sinh(V/2V_T) / (I_sS e^{V/2V_T} + I_sD e^{−V/2V_T}) (physics.md §4), evaluated in an
    overflow-free form: with x = V/2V_T and e = exp(−2|x|), I = I_sS I_sD (1 − e) / (I_sS + I_sD e) for
    x ≥ 0 and −I_sS I_sD (1 − e) / (I_sS e + I_sD) for x < 0. Limits: I → I_sD for V ≫ V_T and I → −I_sS
    for V ≪ −V_T.

    Parameters
    ----------
    i_ss, i_sd : (...) arrays, A
        Saturation currents of the source and drain contacts (> 0).
    bias : (...) array, V
    v_t : (...) array, V
        Thermal voltage.

    Returns
    -------
    (...) array, A
    """
    x = jnp.asarray(bias) / (2.0 * v_t)
    sgn = jnp.where(x >= 0, 1.0, -1.0)
    e = jnp.exp(-2.0 * sgn * x)
    den = jnp.where(x >= 0, i_ss + i_sd * e, i_ss * e + i_sd)
    return sgn * i_ss * i_sd * (-jnp.expm1(-2.0 * sgn * x)) / den


def gauge_factor(params: TaxelParams, temperature):
    """Physics-mode gauge factor GF = |d ln I_sD / d ε| = (P₃/ε) W / (2 ε_s ε₀ V_T), dimensionless.

    ≈ 380 at W = 1 nm and 300 K (physics.md §4).
    """
    return (
        piezo_coefficient(params)
        * params.width_piezo
        / (2.0 * params.permittivity * EPS_0 * thermal_voltage(temperature))
    )


def taxel_current(params: TaxelParams, pressure, temperature, mode: str = "physics", polarity=None):
    """Taxel current at the bias ``params.bias`` for a given pressure and temperature.

    Parameters
    ----------
    params : TaxelParams
    pressure : (...) array, Pa
        Normal pressure on each taxel, positive in compression (0 on reference taxels).
    temperature : (...) array, K
        Taxel (skin) temperature; broadcast against ``pressure``.
    mode : {"physics", "empirical"}
        Static (a Python string; mark it static under ``jit``). ``"physics"``: strain → polarisation →
        barrier change → M–S–M current. ``"empirical"``: the unstrained M–S–M current times exp(s S_p p).
    polarity : (...) array or None
        s = ±1 per taxel; ``None`` uses ``params.polarity``.

    Returns
    -------
    (...) array, A
        Broadcast shape of ``pressure`` and ``temperature``.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    p = jnp.asarray(pressure)
    T = jnp.asarray(temperature)
    v_t = thermal_voltage(T)
    i0 = saturation_current(params, T)
    if mode == "physics":
        r = barrier_change(params, p, polarity) / v_t
        return msm_current(i0 * jnp.exp(r), i0 * jnp.exp(-r), params.bias, v_t)
    s = params.polarity if polarity is None else jnp.asarray(polarity)
    return msm_current(i0, i0, params.bias, v_t) * jnp.exp(s * params.sensitivity * p)


def first_order_lag(x, dt, tau, x0=None):
    """First-order response lag τ ẏ = x − y, discretised exactly for an input held over each step.

    y₀ = x0 and y_{k+1} = y_k + α (x_k − y_k) with α = 1 − exp(−dt/τ), so for a unit step applied at
    t = 0 from rest, y_k = 1 − exp(−k dt/τ) exactly (sample k at time k dt).

    Parameters
    ----------
    x : (T, N) array
        Input samples (any unit), sample k at time k·dt.
    dt : float, s
        Sample interval.
    tau : float or (N,) array, s
        Time constant (> 0).
    x0 : (N,) array or None
        Output at k = 0; ``None`` starts at steady state, y₀ = x[0].

    Returns
    -------
    (T, N) array
        Lagged signal, same unit as ``x``.
    """
    x = jnp.asarray(x)
    alpha = -jnp.expm1(-dt / jnp.asarray(tau))
    y0 = x[0] if x0 is None else jnp.broadcast_to(jnp.asarray(x0, dtype=x.dtype), x.shape[1:])

    def step(y, xk):
        return y + alpha * (xk - y), y

    _, ys = jax.lax.scan(step, y0, x)
    return ys


def coarse_lag_weights(dt_fine: float, tau, stride: int):
    """Weights (βˢ, W₋₁, W₀, W₁, W₂) of the exact first-order lag over ``stride`` fine steps for an input that is
    the cubic through the four nearest coarse samples (β = exp(−dt_fine/τ)); pure JAX in ``tau`` (which may be
    traced: the raw fit samples the lag).

    Over one coarse step the fine lag y ← βy + (1 − β)x gives y_{K+1} = βˢ y_K + Σ_j (1 − β) β^{s−1−j} x(K + j/s),
    and with x(K + t) = Σ_i L_i(t) X_{K+i} (the cubic Lagrange basis on the nodes i = −1, 0, 1, 2) that is
    βˢ y_K + Σ_i W_i X_{K+i}. A piecewise-linear input (W₋₁ = W₂ = 0) attenuated a 5 Hz texture signal sampled
    every 40 ms by ~10 %, which a sampled lag then absorbed (``docs/raw_model.md``); the cubic is exact for cubic
    input. With ``stride`` 1 the weights are (β, 0, 1 − β, 0, 0), the fine lag itself.

    Parameters
    ----------
    dt_fine : float, s
        Interval of the fine (recorded) frames.
    tau : float, s
        Lag time constant.
    stride : int
        Fine steps per coarse step (≥ 1).

    Returns
    -------
    (5,) float
    """
    a = -jnp.expm1(-dt_fine / jnp.asarray(tau, dtype=float))
    b = 1.0 - a
    j = jnp.arange(int(stride), dtype=float)
    c = a * b ** (stride - 1 - j)  # weight of the fine input x(K + j/s)
    t = j / stride
    basis = jnp.stack(
        [
            -t * (t - 1) * (t - 2) / 6,
            (t + 1) * (t - 1) * (t - 2) / 2,
            -(t + 1) * t * (t - 2) / 2,
            (t + 1) * t * (t - 1) / 6,
        ]
    )
    return jnp.concatenate([jnp.atleast_1d(b**stride), basis @ c])


def coarse_lag(x, start, w):
    """First-order lag (F, M) of inputs ``x (F, M)`` on coarse frames (weights ``w`` (5,) from
    :func:`coarse_lag_weights`), restarting at steady state where ``start (F,)`` is true.

    y_K = w₀ y_{K−1} + w₁ X_{K−2} + w₂ X_{K−1} + w₃ X_K + w₄ X_{K+1}; a neighbour beyond the stroke's ends is
    extrapolated linearly from the two samples inside. Same unit as ``x``. The inputs' sums are formed for every
    frame at once, the recursion in a sequential scan (a parallel prefix over the affine maps,
    ``jax.lax.associative_scan``, or a blocked lower-triangular product were 3–4× slower on CPU for 1000 frames)."""
    x = jnp.asarray(x)
    start = jnp.asarray(start, dtype=bool)
    w = jnp.asarray(w)
    pad = jnp.zeros((1,) + x.shape[1:], x.dtype)
    prev1 = jnp.concatenate([pad, x[:-1]])  # X_{K−1}
    prev2 = jnp.concatenate([pad, prev1[:-1]])  # X_{K−2}
    next1 = jnp.concatenate([x[1:], pad])  # X_{K+1}
    shape = (-1,) + (1,) * (x.ndim - 1)
    has_prev2 = ~jnp.concatenate([jnp.ones(1, bool), start[:-1]]).reshape(shape)  # K−1 is not a stroke's first
    has_next = ~jnp.concatenate([start[1:], jnp.ones(1, bool)]).reshape(shape)  # K+1 is in K's stroke
    prev2 = jnp.where(has_prev2, prev2, 2 * prev1 - x)
    next1 = jnp.where(has_next, next1, 2 * x - prev1)
    drive = w[1] * prev2 + w[2] * prev1 + w[3] * x + w[4] * next1

    def step(y, xs):
        xk, uk, s = xs
        yk = jnp.where(s, xk, w[0] * y + uk)
        return yk, yk

    _, ys = jax.lax.scan(step, x[0], (x, drive, start))
    return ys
