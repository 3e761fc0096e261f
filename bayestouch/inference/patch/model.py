"""The contact-patch model: a superellipse patch (a, b, n) of the paper's eq. 16–18 and its likelihood for one taxel
frame or a window of K frames of the whole array's currents (K, N) A. θ (7,): centre (u0, v0) m on the pad, log a,
log b (log m), orientation rad, log n, log V (log m³, the indentation volume); the model's N taxel predictions are
Δ ln I (N,). The model, its likelihood and prior, and how it is sampled: ``docs/patch_model.md``.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.inference.contact import Bounds
from bayestouch.params import MODELS, Spec, build
from bayestouch.physics import noise as nz
from bayestouch.physics import skin as sk
from bayestouch.physics import taxel as tx
from bayestouch.physics.patch import superellipse, superellipse_area

__all__ = [
    "PARAM_NAMES",
    "SUMMARY_NAMES",
    "PatchParams",
    "load_patch_priors",
    "PatchModel",
    "PatchPosterior",
    "theta_from_params",
    "params_from_theta",
    "window_flicker_variance",
    "make_patch_model",
    "patch_pressure",
    "patch_log_current",
    "patch_log_prob",
    "patch_force",
    "batched_patch_force",
    "make_patch_log_prob",
    "patch_currents",
    "patch_depth",
    "patch_residual",
    "volume_factor",
    "A_MIN",
    "DEPTH_MIN",
    "FLOOR",
]

#: names of the 7 sampled parameters θ
PARAM_NAMES = ("u0", "v0", "log_a", "log_b", "angle", "log_n", "log_volume")
#: names of the summarised natural parameters (canonical a ≥ b)
SUMMARY_NAMES = ("u0", "v0", "a", "b", "angle", "n", "depth")

#: prior ranges (``docs/patch_model.md``; ``[patch_priors]`` of ``models/priors.toml``): a, b ≥ A_MIN m,
#: n ∈ [N_MIN, N_MAX], δ0 ≥ DEPTH_MIN m
PATCH_PRIOR_SPECS = {
    "a_min": Spec("m", 1e-6, 1e-2),
    "n_min": Spec("1", 0.5, 10.0),
    "n_max": Spec("1", 1.0, 100.0),
    "depth_min": Spec("m", 1e-9, 1e-3),
}


def load_patch_priors(path=None) -> dict[str, float]:
    """Read ``[patch_priors]`` of ``models/priors.toml`` (or ``path``): a_min m, n_min, n_max, depth_min m."""
    return build(dict, MODELS / "priors.toml" if path is None else path, "patch_priors", PATCH_PRIOR_SPECS)


_PP = load_patch_priors()
A_MIN = float(_PP["a_min"])
N_MIN, N_MAX = float(_PP["n_min"]), float(_PP["n_max"])
DEPTH_MIN = float(_PP["depth_min"])
#: floor for log-currents (ADC zeros), A
FLOOR = 1e-15


class PatchParams(NamedTuple):
    """A contact patch with its indentation (SI units).

    Attributes
    ----------
    u0, v0 : float, m
        Patch centre in skin-local taxel coordinates (``Finger.grid``).
    a, b : float, m
        Semi-axes along and across ``angle``.
    angle : float, rad
        Direction of the a-axis from the pad's u-axis.
    n : float, 1
        Superellipse exponent of eq. 16.
    depth : float, m
        Skin penetration δ0 at the patch centre.
    """

    u0: float
    v0: float
    a: float
    b: float
    angle: float
    n: float
    depth: float


class PatchModel(NamedTuple):
    """The data and fixed model inputs of :func:`patch_log_prob` (a pytree of arrays; N taxels).

    Attributes
    ----------
    positions : (N, 2) float, m
        Taxel positions (u, v).
    loaded : (N,) float
        1 on taxels with a load path, 0 on the reference rows.
    kernel : (N, N) float
        The skin's pressure blur (``Finger.kernel``).
    skin : SkinParams
    taxels : TaxelParams
    y : (N,) float
        Observed log-currents, drift compensated, window-averaged, gain corrected (ln A).
    sigma : (N,) float
        Standard deviation of ``y`` (dimensionless, natural log).
    temperature : float, K
        Temperature at which the pressure response is evaluated (matters in ``"physics"`` mode only).
    cell_area : float, m²
        Skin area per taxel (force = Σ p · cell_area).
    lower, upper : (7,) float
        Prior box of θ.
    """

    positions: jnp.ndarray
    loaded: jnp.ndarray
    kernel: jnp.ndarray
    skin: sk.SkinParams
    taxels: tx.TaxelParams
    y: jnp.ndarray
    sigma: jnp.ndarray
    temperature: jnp.ndarray
    cell_area: jnp.ndarray
    lower: jnp.ndarray
    upper: jnp.ndarray


class PatchPosterior(NamedTuple):
    """Result of :func:`patch_posterior`.

    draws : dict of str → (S·W,) float
        Canonicalised natural parameters (``SUMMARY_NAMES``, SI units) and the derived ``area_m2`` (eq. 18) and
        ``force_N`` (Σ p · cell_area of the model's pressure), S kept steps × W walkers, step-major.
    summary : dict
        ``parameters.<name>.{mean,sd,q05,q95,r_hat,ess_bulk}``, ``derived.{area_m2,force_N}.{...}``,
        ``diagnostics`` (:func:`~bayestouch.inference.sampler.convergence` plus ``seconds``), ``model``.
    chain : Chain
        The raw chain in θ (:class:`~bayestouch.inference.sampler.Chain`).
    model : PatchModel
    theta0 : (7,) float
        The Gauss–Newton start.
    """

    draws: dict
    summary: dict
    chain: object
    model: PatchModel
    theta0: np.ndarray


def theta_from_params(p: PatchParams) -> np.ndarray:
    """θ (7,) of a :class:`PatchParams` (``PARAM_NAMES`` order)."""
    vol = p.depth * p.a * p.b * float(volume_factor(p.n))
    return np.array([p.u0, p.v0, math.log(p.a), math.log(p.b), p.angle, math.log(p.n), math.log(vol)])


def params_from_theta(theta) -> PatchParams:
    """:class:`PatchParams` of θ (7,) (not canonicalised)."""
    t = [float(x) for x in np.asarray(theta, dtype=float)]
    a, b, n = math.exp(t[2]), math.exp(t[3]), math.exp(t[5])
    return PatchParams(t[0], t[1], a, b, t[4], n, math.exp(t[6]) / (a * b * float(volume_factor(n))))


def volume_factor(n):
    """V / (δ0 a b) for the profile δ0 (1 − L)₊: ∫(1 − ρ^n)₊ dA = A n/(n + 2), A = 4ab Γ(1+1/n)²/Γ(1+2/n) (eq. 18)."""
    return superellipse_area(1.0, 1.0, n) * n / (n + 2.0)


def patch_depth(theta):
    """Centre penetration δ0 (m) of θ (..., 7)."""
    return jnp.exp(theta[..., 6] - theta[..., 2] - theta[..., 3]) / volume_factor(jnp.exp(theta[..., 5]))


# ---------------------------------------------------------------- noise of a window mean


def window_flicker_variance(noise: nz.NoiseParams, k: int, dt: float, n_flicker: int = nz.N_FLICKER) -> float:
    """Variance of the mean of ``k`` consecutive samples of the OU-sum 1/f log-fluctuation (dimensionless).

    The 1/f noise of :func:`bayestouch.physics.noise.add_noise` is a sum of ``n_flicker`` independent OU
    processes with corner frequencies f_c log-spaced over [f_min, f_max], each of variance v = K_f ln r and lag-l
    correlation a^l, a = exp(−2π f_c dt). The mean of k samples has variance
    v/k² · (k + 2 Σ_{l=1}^{k−1} (k − l) a^l) per component: v/k for fast components, v for slow ones.

    Parameters
    ----------
    noise : NoiseParams
    k : int
        Number of frames averaged (≥ 1).
    dt : float, s
        Frame interval.
    n_flicker : int
        Components of the synthesis (``add_noise``'s ``n_flicker``, ≥ 2).

    Returns
    -------
    float
    """
    if k < 1:
        raise ValueError(f"k must be ≥ 1, got {k}")
    lags = np.arange(k)
    cov = nz.flicker_autocovariance(noise, lags * dt, n_flicker)  # C(l·dt), l = 0 … k−1
    # mean of k samples: (1/k²) Σ_ij C(|i − j| dt) = (1/k²) (k C(0) + 2 Σ_{l≥1} (k − l) C(l dt))
    return float((k * cov[0] + 2.0 * np.sum((k - lags[1:]) * cov[1:])) / k**2)


def _log_window(currents, ref_mask):
    """Drift-compensated mean log-current (N,) and mean current (N,) of a (K, N) window."""
    comp = np.asarray(nz.drift_compensate(jnp.asarray(currents), jnp.asarray(ref_mask), FLOOR))
    return np.mean(np.log(np.maximum(comp, FLOOR)), axis=0), np.mean(np.maximum(comp, FLOOR), axis=0)


def _as_window(x, n, name):
    try:
        x = np.asarray(x, dtype=float)
    except (TypeError, ValueError):  # text, a ragged nesting
        raise BadInput(
            f"{name}: expected currents of shape (N,) or (K, N) with N = {n} taxels, got {type(x).__name__}"
        ) from None
    if x.ndim == 1:
        x = x[None]
    if x.ndim != 2 or x.shape[1] != n or x.shape[0] < 1:
        raise BadInput(f"{name}: expected currents of shape (N,) or (K, N) with N = {n} taxels, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise BadInput(f"{name}: currents must be finite amperes")
    return x


def make_patch_model(
    currents,
    finger,
    *,
    dt: float = 0.02,
    temperature: float = 300.0,
    gains=None,
    baseline=None,
    sigma=None,
    elapsed_s: float = 0.0,
    n_flicker: int = nz.N_FLICKER,
) -> PatchModel:
    """Turn a window of measured currents into the :class:`PatchModel` of ``docs/patch_model.md`` (NumPy edge).

    Parameters
    ----------
    currents : (N,) or (K, N) float, A
        One frame or K consecutive frames of the whole array (reference rows included) of a static contact.
    finger : Finger
        :class:`bayestouch.physics.forward.Finger` (grid, reference rows, kernel, skin, taxels, noise, gains).
    dt : float, s
        Frame interval (for the 1/f variance of the window mean).
    temperature : float, K
        Skin temperature for the pressure response (``"physics"`` mode); the unloaded level is marginalised.
    gains : (N,) float or None
        Fixed-pattern gains; ``None`` uses ``finger.gains``. Ignored when ``baseline`` is given.
    baseline : (N,) or (K0, N) float, A, or None
        An unloaded window; its mean log-current replaces the gains (and adds its own noise).
    sigma : float or (N,) float or None
        Standard deviation of each y_j in natural-log units; ``None`` derives it from the noise model.
    elapsed_s : float, s
        Time since the gains or baseline were taken (per-taxel drift random walk).
    n_flicker : int
        Components of the 1/f synthesis (as in ``add_noise``).

    Returns
    -------
    PatchModel

    Raises
    ------
    BadInput
        Wrong shapes, non-finite currents, non-positive ``dt``/``temperature``/``sigma``, negative ``elapsed_s``.
    """
    pos = np.asarray(finger.grid, dtype=float).reshape(-1, 2)
    n = len(pos)
    ref = np.asarray(finger.reference, dtype=bool).ravel()
    cur = _as_window(currents, n, "currents")
    if not (dt > 0 and temperature > 0 and elapsed_s >= 0):
        raise BadInput(
            f"patch model: dt > 0 s, temperature > 0 K and elapsed_s ≥ 0 s expected; got dt={dt:g}, "
            f"temperature={temperature:g}, elapsed_s={elapsed_s:g}"
        )
    nzp = finger.noise
    y, mean_i = _log_window(cur, ref)
    k = cur.shape[0]
    var = (np.asarray(nz.noise_std(nzp, mean_i)) / mean_i) ** 2 / k + window_flicker_variance(nzp, k, dt, n_flicker)
    var = var + float(nzp.drift_local) ** 2 * elapsed_s
    if baseline is not None:
        base = _as_window(baseline, n, "baseline")
        yb, mean_b = _log_window(base, ref)
        y = y - yb
        var = var + (np.asarray(nz.noise_std(nzp, mean_b)) / mean_b) ** 2 / len(base)
        var = var + window_flicker_variance(nzp, len(base), dt, n_flicker)
    else:
        g = np.asarray(finger.gains if gains is None else gains, dtype=float).ravel()
        if g.shape != (n,) or not np.all(g > 0):
            raise BadInput(f"gains: expected ({n},) positive fixed-pattern gains, got shape {g.shape}")
        y = y - np.log(g)
    if sigma is not None:
        s = np.asarray(sigma, dtype=float)
        s = np.full(n, float(s)) if s.ndim == 0 else s
        if s.shape != (n,) or not np.all(np.isfinite(s) & (s > 0)):
            raise BadInput(f"sigma: expected a positive float or ({n},) positive log-current standard deviations")
        var = s.astype(float) ** 2
    loaded_pos = pos[~ref]
    half = 0.5 * float(np.max(np.ptp(pos, axis=0)))
    h = float(finger.skin.h)
    lower = [
        loaded_pos[:, 0].min(),
        loaded_pos[:, 1].min(),
        math.log(A_MIN),
        math.log(A_MIN),
        -math.pi,
        math.log(N_MIN),
        math.log(DEPTH_MIN * A_MIN**2),
    ]
    upper = [
        loaded_pos[:, 0].max(),
        loaded_pos[:, 1].max(),
        math.log(half),
        math.log(half),
        math.pi,
        math.log(N_MAX),
        math.log(4.0 * h * half**2),
    ]
    return PatchModel(
        jnp.asarray(pos),
        jnp.asarray((~ref).astype(float)),
        jnp.asarray(finger.kernel),
        finger.skin,
        finger.taxels,
        jnp.asarray(y),
        jnp.asarray(np.sqrt(var)),
        jnp.asarray(float(temperature)),
        jnp.asarray(finger.cell_area),
        jnp.asarray(lower),
        jnp.asarray(upper),
    )


# ---------------------------------------------------------------- the pure model


def _local_stress(theta, model: PatchModel):
    """Unblurred foam stress σ_foam(δ0 (1 − L)₊ / h) (N,) Pa at the taxels of the patch θ (7,)."""
    theta = jnp.asarray(theta)
    dx = model.positions[:, 0] - theta[0]
    dy = model.positions[:, 1] - theta[1]
    c, s = jnp.cos(theta[4]), jnp.sin(theta[4])
    lev = superellipse(jnp.exp(theta[2]), jnp.exp(theta[3]), jnp.exp(theta[5]), c * dx + s * dy, -s * dx + c * dy)
    return sk.foam_stress(model.skin, patch_depth(theta) * jnp.maximum(1.0 - lev, 0.0) / model.skin.h)


def patch_pressure(theta, model: PatchModel):
    """Pressure (N,) Pa at the taxels of the patch θ (7,): p = K σ_foam(δ0 (1 − L)₊ / h), 0 on reference rows.

    Parameters
    ----------
    theta : (7,) float
        ``PARAM_NAMES``: u0, v0 (m), log a, log b (log m), angle (rad), log n, log V (log m³).
    model : PatchModel

    Returns
    -------
    (N,) float, Pa
    """
    p = model.kernel @ _local_stress(theta, model)
    return p * model.loaded


def patch_log_current(theta, model: PatchModel, mode: str = "empirical"):
    """Predicted Δ ln I (N,) of the patch θ: ln I(p, T) − ln I(0, T) (``mode`` static)."""
    p = patch_pressure(theta, model)
    i0 = tx.taxel_current(model.taxels, 0.0, model.temperature, mode=mode)
    return jnp.log(tx.taxel_current(model.taxels, p, model.temperature, mode=mode)) - jnp.log(i0)


def patch_log_prob(theta, model: PatchModel, mode: str = "empirical"):
    """Log-posterior (up to a constant) of θ (7,): Gaussian likelihood with the offset marginalised, box prior.

    Pure JAX (``mode`` static); −inf outside the prior box or where anything is not finite, never NaN.

    Returns
    -------
    () float
    """
    theta = jnp.asarray(theta)
    depth = patch_depth(theta)
    inside = jnp.all((theta >= model.lower) & (theta <= model.upper)) & (depth >= DEPTH_MIN) & (depth <= model.skin.h)
    r = model.y - patch_log_current(theta, model, mode)
    w = 1.0 / model.sigma**2
    sw = jnp.sum(w)
    rbar = jnp.sum(w * r) / sw
    ll = (
        -0.5 * jnp.sum(w * (r - rbar) ** 2)
        - 0.5 * jnp.sum(jnp.log(2.0 * jnp.pi * model.sigma**2))
        + 0.5 * jnp.log(2.0 * jnp.pi / sw)
    )
    return jnp.where(inside & jnp.isfinite(ll), ll, -jnp.inf)


def patch_force(theta, model: PatchModel):
    """Normal force (N) of the patch θ: Σ_j p_j · cell_area over the loaded taxels, as
    :func:`bayestouch.physics.forward.elastic_force` computes it (evaluated as σ_foam · (Kᵀ loaded), no matrix
    product)."""
    local = _local_stress(theta, model)
    return model.cell_area * (local @ (model.kernel.T @ model.loaded))


# compiled once per mode and batch shape, shared by every model (the model is an argument, not a constant)
_batched_log_prob = jax.jit(jax.vmap(patch_log_prob, in_axes=(0, None, None)), static_argnums=2)
batched_patch_force = jax.jit(jax.vmap(patch_force, in_axes=(0, None)))


@partial(jax.jit, static_argnums=2)
def patch_residual(theta, model: PatchModel, mode: str):
    """Residuals (N,) of the modelled taxels' Δ ln I under θ (7,) (dimensionless)."""
    return model.y - patch_log_current(theta, model, mode)


def make_patch_log_prob(model: PatchModel, mode: str = "empirical"):
    """Vectorised NumPy log-posterior for emcee: ``(f, bounds)``, ``f(thetas (W, 7)) -> (W,)``, −inf outside.

    Parameters
    ----------
    model : PatchModel
    mode : {"physics", "empirical"}

    Returns
    -------
    f : callable
    bounds : Bounds
        The prior box (``model.lower``, ``model.upper``).
    """
    if mode not in tx.MODES:
        raise BadInput(f"mode: must be one of {', '.join(tx.MODES)}, got {mode!r}")

    def f(thetas):
        t = np.atleast_2d(np.asarray(thetas, dtype=float))
        v = np.asarray(_batched_log_prob(jnp.asarray(t), model, mode))
        return np.where(np.isfinite(v), v, -np.inf)

    return f, Bounds(model.lower, model.upper)


def patch_currents(params: PatchParams, finger, *, mode: str = "empirical", temperature: float = 300.0):
    """Noise-free currents (N,) A of the patch model (without fixed-pattern gains), for simulation and checks.

    ``add_noise(key, finger.noise, tile(I, (K, 1)), dt, finger.gains)`` turns them into a measured window.
    """
    n = int(np.asarray(finger.grid).shape[0] * np.asarray(finger.grid).shape[1])
    model = make_patch_model(np.ones(n), finger, temperature=temperature, gains=np.ones(n))
    d = patch_log_current(jnp.asarray(theta_from_params(params)), model, mode)
    return np.asarray(tx.taxel_current(finger.taxels, 0.0, temperature, mode=mode) * jnp.exp(d))
