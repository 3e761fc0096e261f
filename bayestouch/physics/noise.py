"""Measurement noise of the taxel read-out and drift compensation: fixed-pattern gain, 1/f fluctuation (a sum of
Ornstein–Uhlenbeck processes), common and per-taxel drift, shot and amplifier noise, offset, outliers and the ADC,
on currents in amperes sampled every ``dt`` seconds.

All functions are pure JAX with an explicit PRNG key, except the loader; :func:`add_noise` (``n_flicker``, ``adc``
static), :func:`common_drift` and :func:`drift_compensate` are jitted. The measurement model and the 1/f synthesis:
``docs/physics_notes.md``.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS, Spec, build
from bayestouch.physics.taxel import K_B, Q_E, thermal_voltage

__all__ = [
    "frame_covariance",
    "NoiseParams",
    "NOISE_SPECS",
    "load_noise",
    "adc_lsb",
    "quantise",
    "noise_std",
    "fixed_pattern",
    "flicker_psd",
    "flicker_components",
    "flicker_autocovariance",
    "N_FLICKER",
    "add_noise",
    "common_drift",
    "drift_compensate",
]


class NoiseParams(NamedTuple):
    """Noise of the taxel read-out (a JAX pytree of floats; SI units). Sources: ``models/noise.toml``.

    Attributes
    ----------
    bandwidth : float, Hz
        Noise bandwidth B of the read-out per sample.
    feedback_resistance : float, Ω
        Feedback resistor R_f of the transimpedance amplifier.
    temperature : float, K
        Amplifier temperature (Johnson noise); also the temperature for V_T in :func:`fixed_pattern`.
    flicker : float
        K_f of the relative 1/f PSD S_{δ ln I}(f) = K_f / f (dimensionless).
    flicker_f_min, flicker_f_max : float, Hz
        Lowest and highest OU corner frequency of the 1/f synthesis.
    drift_common : float, 1/√s
        Random-walk rate of ln I₀ common to all taxels.
    drift_local : float, 1/√s
        Random-walk rate of ln I₀ independent per taxel.
    barrier_spread : float, V
        σ_Φ / q, taxel-to-taxel scatter of the barrier height (fixed pattern).
    adc_bits : float
        ADC resolution in bits.
    adc_full_scale : float, A
        ADC input range [0, full scale].
    offset : float, A
        Amplifier offset current I_off.
    outlier_probability : float
        Probability that a sample carries a glitch.
    outlier_scale : float, A
        Standard deviation of a glitch.
    """

    bandwidth: float
    feedback_resistance: float
    temperature: float
    flicker: float
    flicker_f_min: float
    flicker_f_max: float
    drift_common: float
    drift_local: float
    barrier_spread: float
    adc_bits: float
    adc_full_scale: float
    offset: float
    outlier_probability: float
    outlier_scale: float


#: expected constants of ``[noise]``: SI unit and allowed range
NOISE_SPECS: dict[str, Spec] = {
    "bandwidth": Spec("Hz", 0.0, 1e9),
    "feedback_resistance": Spec("Ohm", 1.0, 1e13),
    "temperature": Spec("K", 1.0, 1000.0),
    "flicker": Spec("1", 0.0, 1e-2),
    "flicker_f_min": Spec("Hz", 1e-9, 1e9),
    "flicker_f_max": Spec("Hz", 1e-9, 1e9),
    "drift_common": Spec("1/sqrt(s)", 0.0, 1.0),
    "drift_local": Spec("1/sqrt(s)", 0.0, 1.0),
    "barrier_spread": Spec("V", 0.0, 0.5),
    "adc_bits": Spec("1", 1.0, 32.0),
    "adc_full_scale": Spec("A", 1e-15, 1.0),
    "offset": Spec("A", -1.0, 1.0),
    "outlier_probability": Spec("1", 0.0, 1.0),
    "outlier_scale": Spec("A", 0.0, 1.0),
}


def load_noise(path=MODELS / "noise.toml") -> NoiseParams:
    """Read ``[noise]`` of a parameter file into :class:`NoiseParams` (one-line ``BadInput`` on errors)."""
    p = build(NoiseParams, path, "noise", NOISE_SPECS)
    if not p.flicker_f_min < p.flicker_f_max:
        raise BadInput(
            f"{path} [noise] flicker_f_max: must exceed flicker_f_min ({p.flicker_f_min:g} Hz), "
            f"got {p.flicker_f_max:g} Hz"
        )
    return p


def adc_lsb(params: NoiseParams):
    """ADC step in amperes, LSB = full scale / 2^bits."""
    return params.adc_full_scale / 2.0**params.adc_bits


def quantise(x, lsb, lo=None, hi=None):
    """Round ``x`` to multiples of ``lsb`` with a straight-through gradient (d/dx = 1 inside the range).

    Parameters
    ----------
    x : (...) array
    lsb : float
        Quantisation step, same unit as ``x``.
    lo, hi : float or None
        Clip range applied before rounding (gradient 0 outside it); ``None`` means unbounded.

    Returns
    -------
    (...) array
        ``lsb · round(clip(x) / lsb)`` in value; the gradient of ``clip(x)`` in reverse and forward mode.
    """
    x = jnp.asarray(x)
    if lo is not None or hi is not None:
        x = jnp.clip(x, lo, hi)
    return x + jax.lax.stop_gradient(lsb * jnp.round(x / lsb) - x)


def _safe_sqrt(v):
    pos = v > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, v, 1.0)), 0.0)


def noise_std(params: NoiseParams, current, adc: bool = True):
    """White-noise standard deviation per sample, σ = √(2 q |I| B + 4 k T B / R_f [+ LSB²/12]).

    Shot noise of the taxel current (Schottky) and Johnson noise of the amplifier's feedback resistor, in
    the bandwidth B; with ``adc`` the ADC's rounding error (uniform, variance LSB²/12) is added as white
    noise, which is what a Gaussian likelihood should use.

    Parameters
    ----------
    params : NoiseParams
    current : (...) array, A
    adc : bool
        Static: include LSB²/12.

    Returns
    -------
    (...) array, A
    """
    var = 2.0 * Q_E * jnp.abs(jnp.asarray(current)) * params.bandwidth
    var = var + 4.0 * K_B * params.temperature * params.bandwidth / params.feedback_resistance
    if adc:
        var = var + adc_lsb(params) ** 2 / 12.0
    return _safe_sqrt(var)


def fixed_pattern(key, params: NoiseParams, n_taxels: int, temperature=None):
    """Fixed-pattern gains G_j = exp(−δΦ_j / V_T), δΦ_j ~ N(0, σ_Φ²) (dimensionless).

    Parameters
    ----------
    key : PRNG key
    params : NoiseParams
    n_taxels : int
        Static.
    temperature : float or None, K
        Temperature for V_T; ``None`` uses ``params.temperature``. (The barrier scatter itself is
        temperature independent; the gain it causes scales as 1/T.)

    Returns
    -------
    (n_taxels,) array
        Gains with median 1 and σ(ln G) = σ_Φ / V_T.
    """
    T = params.temperature if temperature is None else temperature
    dphi = params.barrier_spread * jax.random.normal(key, (n_taxels,))
    return jnp.exp(-dphi / thermal_voltage(T))


#: OU components of the 1/f synthesis (:func:`add_noise`'s default ``n_flicker``), and of every model of it
N_FLICKER = 9


def flicker_components(params: NoiseParams, n_components: int = N_FLICKER):
    """Corner frequencies f_c (n_components,) Hz, log-spaced over [f_min, f_max], and the variance
    v = K_f ln r (dimensionless, r = (f_max/f_min)^(1/(n−1))) of each OU component of the 1/f log-fluctuation."""
    k = jnp.arange(n_components)
    ln_r = jnp.log(params.flicker_f_max / params.flicker_f_min) / (n_components - 1)
    fc = params.flicker_f_min * jnp.exp(ln_r * k)
    return fc, params.flicker * ln_r


def flicker_autocovariance(params: NoiseParams, lag, n_components: int = N_FLICKER) -> np.ndarray:
    """Autocovariance Σ_c v exp(−2π f_c |lag|) of the 1/f log-fluctuation (NumPy edge; dimensionless).

    The one home of the 1/f read-out variance: at lag 0 it is the stationary variance n·K_f ln r that every
    likelihood adds to a reading's variance; at the lags between frames it is the frame-to-frame correlation.

    Parameters
    ----------
    params : NoiseParams
    lag : float or array (...), seconds
    n_components : int
        Components of the synthesis (≥ 2).

    Returns
    -------
    array (...)
    """
    fc, v = flicker_components(params, n_components)
    fc, v = np.asarray(fc, float), float(v)
    lag = np.abs(np.asarray(lag, float))
    return v * np.sum(np.exp(-2.0 * np.pi * fc * lag[..., None]), axis=-1)


def frame_covariance(params: NoiseParams, white, times) -> np.ndarray:
    """Covariance (F, F) over frames of one taxel's ln I read-out noise (NumPy edge; dimensionless): its white part
    ``white (F,)`` on the diagonal, the 1/f autocovariance (:func:`flicker_autocovariance`) at the frames' lags and
    the per-taxel random walk drift_local² · min(t_i, t_j), ``times (F,)`` seconds from the stroke's start."""
    t = np.asarray(times, float)
    walk = float(params.drift_local) ** 2 * np.minimum(t[:, None], t[None, :])
    return np.diag(np.asarray(white, float)) + flicker_autocovariance(params, t[:, None] - t[None, :]) + walk


def flicker_psd(params: NoiseParams, f, n_components: int = N_FLICKER):
    """One-sided PSD (1/Hz) of the OU-sum 1/f model at frequencies ``f (...)`` Hz; ≈ K_f / f in band.

    ``n_components`` (static, ≥ 2) OU processes with corner frequencies log-spaced over [f_min, f_max],
    each of variance K_f ln r, r = (f_max/f_min)^(1/(n−1)).
    """
    fc, var = flicker_components(params, n_components)
    tau = 1.0 / (2.0 * jnp.pi * fc)
    f = jnp.asarray(f)[..., None]
    return jnp.sum(4.0 * var * tau / (1.0 + (2.0 * jnp.pi * f * tau) ** 2), axis=-1)


def _flicker(z, params: NoiseParams, dt, n_components: int):
    """OU-sum 1/f log-fluctuation (T, N) from standard normals ``z (T, n_components, N)``.

    Row 0 draws the stationary initial state, rows 1… are the innovations, so every sample has the
    stationary variance n_components · K_f ln r.
    """
    fc, var = flicker_components(params, n_components)
    sd = jnp.sqrt(var)
    a = jnp.exp(-2.0 * jnp.pi * fc * dt)[:, None]
    b = (sd * jnp.sqrt(-jnp.expm1(-4.0 * jnp.pi * fc * dt)))[:, None]

    def step(x, zk):
        x = a * x + b * zk
        return x, jnp.sum(x, axis=0)

    x0 = sd * z[0]
    _, rest = jax.lax.scan(step, x0, z[1:])
    return jnp.concatenate([jnp.sum(x0, axis=0)[None], rest], axis=0)


def _walk(z, rate, dt):
    """Random walk (T, N) from standard normals ``z (T, N)``: w_0 = 0, w_k = rate √dt Σ_{1≤i≤k} z_i."""
    steps = rate * jnp.sqrt(dt) * z[1:]
    return jnp.concatenate([jnp.zeros_like(z[:1]), jnp.cumsum(steps, axis=0)], axis=0)


@partial(jax.jit, static_argnames=("n_flicker", "adc"))
def add_noise(key, params: NoiseParams, current, dt, gains=None, *, n_flicker: int = N_FLICKER, adc: bool = True):
    """Measured taxel currents: fixed pattern, 1/f, drift, white noise, offset, outliers and the ADC.

    Jitted (``n_flicker`` and ``adc`` static). Random draws: one normal array (T, n_flicker + 4, N) and
    one uniform array (T, N) from ``key``.

    Parameters
    ----------
    key : PRNG key
        All randomness; the same key gives the same output.
    params : NoiseParams
    current : (T, N) array, A
        Noise-free (lagged) taxel currents, sample k at time k·dt.
    dt : float, s
        Sample interval.
    gains : (N,) array or None
        Fixed-pattern gains (:func:`fixed_pattern`, drawn once per device); ``None`` means 1.
    n_flicker : int
        Number (≥ 2) of OU processes of the 1/f synthesis, corner frequencies log-spaced over
        [f_min, f_max]; the log-fluctuation has stationary variance n_flicker · K_f ln r,
        r = (f_max/f_min)^(1/(n_flicker−1)), and PSD :func:`flicker_psd`.
    adc : bool
        Quantise (and clip to [0, full scale − LSB]) with a straight-through gradient.

    Returns
    -------
    (T, N) array, A
        Var of the drifts at sample k: drift_common² k dt (common to all taxels) + drift_local² k dt.
    """
    if n_flicker < 2:
        raise ValueError(f"n_flicker must be ≥ 2, got {n_flicker}")
    current = jnp.asarray(current)
    n_steps, n_taxels = current.shape
    kz, ku = jax.random.split(key)
    z = jax.random.normal(kz, (n_steps, n_flicker + 4, n_taxels))
    u = jax.random.uniform(ku, (n_steps, n_taxels))
    log_mod = _flicker(z[:, :n_flicker], params, dt, n_flicker)
    log_mod = log_mod + _walk(z[:, n_flicker, :1], params.drift_common, dt)
    log_mod = log_mod + _walk(z[:, n_flicker + 1], params.drift_local, dt)
    signal = current * jnp.exp(log_mod)
    if gains is not None:
        signal = signal * jnp.asarray(gains)
    y = signal + noise_std(params, signal, adc=False) * z[:, n_flicker + 2] + params.offset
    y = y + jnp.where(u < params.outlier_probability, params.outlier_scale * z[:, n_flicker + 3], 0.0)
    if adc:
        lsb = adc_lsb(params)
        y = quantise(y, lsb, 0.0, params.adc_full_scale - lsb)
    return y


@jax.jit
def common_drift(measured, reference_mask, floor: float = 1e-15):
    """Common log-drift d̂(t) = ⟨ln I_ref(t)⟩ − ⟨ln I_ref(0)⟩ over the reference taxels.

    Parameters
    ----------
    measured : (T, N) array, A
    reference_mask : (N,) bool or 0/1 array
        Unloaded reference taxels (at least one).
    floor : float, A
        Currents below it are clipped to it before the logarithm (ADC zeros, negative noise).

    Returns
    -------
    (T,) array
        Dimensionless, 0 at t = 0.
    """
    w = jnp.asarray(reference_mask, dtype=jnp.result_type(float))
    lnI = jnp.log(jnp.maximum(jnp.asarray(measured), floor))
    m = (lnI @ w) / jnp.sum(w)
    return m - m[0]


@jax.jit
def drift_compensate(measured, reference_mask, floor: float = 1e-15):
    """Divide out the common drift seen by the reference taxels: I_j(t) exp(−d̂(t)) (see :func:`common_drift`).

    A drift that multiplies every taxel by the same exp(d(t)) (common random walk, uniform temperature
    change) is removed relative to the first sample; in the noiseless case exactly.

    Parameters
    ----------
    measured : (T, N) array, A
    reference_mask : (N,) bool array
    floor : float, A

    Returns
    -------
    (T, N) array, A
    """
    d = common_drift(measured, reference_mask, floor)
    return jnp.asarray(measured) * jnp.exp(-d)[:, None]
