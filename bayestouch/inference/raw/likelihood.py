"""The raw-current likelihood: θ → signed distances of the penetrating-taxel slots (F, J) m → predicted ln I (F, M)
of the selected taxels (:func:`bayestouch.physics.forward.log_current_from_distance`) → Student-t log-likelihood of
the corrected readings; the prior box and the log-posterior, batched over walkers θ (W, 11) or (W, 16) with the
texture (:mod:`bayestouch.inference.grating`); and the pruning of slots clear of the surface. Pure JAX where it is
evaluated per draw. Parameters, noise model and reductions: ``docs/raw_model.md``.
"""

from __future__ import annotations

from functools import wraps

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.inference import contact as cm
from bayestouch.inference import grating as gr
from bayestouch.inference.densities import student_t_logpdf, t_scale_factor
from bayestouch.inference.grating import RawTexture
from bayestouch.inference.raw.data import RawData, join_data, on_device, split_data
from bayestouch.inference.raw.priors import (
    LOG_K_PRIOR_SD,
    LOG_K_RANGE,
    RAW_PRIOR_SPECS,
    RESPONSE_SCALE_SD,
    load_raw_priors,
)
from bayestouch.physics import forward as fw
from bayestouch.physics import taxel as tx

__all__ = [
    "RAW_PRIOR_SPECS",
    "load_raw_priors",
    "RAW_PARAM_NAMES",
    "RAW_NATURAL_NAMES",
    "RAW_TEXTURE_PARAM_NAMES",
    "RAW_TEXTURE_NATURAL_NAMES",
    "STUDENT_NU",
    "LOG_K_RANGE",
    "LOG_K_PRIOR_SD",
    "RESPONSE_SCALE_SD",
    "RAW_OPT_SCALE",
    "LAG_OPT_SCALE",
    "raw_names",
    "opt_scale",
    "at_lag",
    "with_lag_bounds",
    "slot_distances",
    "PRUNE_MARGIN",
    "PRUNE_CHECK",
    "prune_clear",
    "prune_clearance",
    "distance_log_current",
    "predict_log_current",
    "reading_scale",
    "taxel_offsets",
    "reading_log_lik",
    "predict_readings",
    "response_scaled",
    "nuisance_estimates",
    "with_nuisance_fixed",
    "raw_pointwise",
    "raw_log_likelihood",
    "raw_bounds",
    "raw_log_prob_batch",
    "raw_log_prob",
    "make_raw_log_prob",
    "jit_on_data",
    "neg_log_post_vg",
    "log_prob_value",
    "log_prob_batch",
    "frame_log_lik_batch",
    "frame_log_lik_jacobian",
    "readings_batch",
    "raw_objective",
]


RAW_PARAM_NAMES = ("x_G", "y_G", "z_G", "log_a", "log_b", "log_c", "xi", "psi", "zeta", "log_n", "log_k")
RAW_NATURAL_NAMES = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n", "noise_scale")
#: with the texture (:mod:`bayestouch.inference.grating`)
RAW_TEXTURE_PARAM_NAMES = RAW_PARAM_NAMES + gr.TEXTURE_NAMES
RAW_TEXTURE_NATURAL_NAMES = RAW_NATURAL_NAMES + gr.TEXTURE_NATURAL_NAMES
#: degrees of freedom of the Student-t reading noise
STUDENT_NU = 4.0


#: variable scales (16,) of the raw optimiser (:func:`bayestouch.inference.optimize.scaled_lbfgs`), in the units of
#: θ: 10 µm, 1e-4 (log axes), 1 mrad, 1e-4 (log n), 0.1 (log k), then 1 µm (u, v), 1e-4 (log λ), 1e-4 rad (o),
#: 0.1 (log σ_r); the first 11 for the bare shape
RAW_OPT_SCALE = np.concatenate(
    [np.full(3, 1e-5), np.full(3, 1e-4), np.full(3, 1e-3), [1e-4], [1e-1], [1e-6, 1e-6, 1e-4, 1e-4, 1e-1]]
)


#: optimiser scale of the sampled lag's column, log τ
LAG_OPT_SCALE = 1e-2


def raw_names(textured: bool, lag: bool, natural: bool = False) -> tuple[str, ...]:
    """Names of θ's columns (or of the natural parameters with ``natural``): the bare shape's 11, the texture's 5
    with ``textured``, then the sampled lag (``log_lag``; natural ``lag``, s) with ``lag``."""
    if natural:
        base = RAW_TEXTURE_NATURAL_NAMES if textured else RAW_NATURAL_NAMES
        return base + (("lag",) if lag else ())
    base = RAW_TEXTURE_PARAM_NAMES if textured else RAW_PARAM_NAMES
    return base + (("log_lag",) if lag else ())


def opt_scale(textured: bool, lag: bool) -> np.ndarray:
    """Variable scales of the optimiser for θ's columns (:data:`RAW_OPT_SCALE`, :data:`LAG_OPT_SCALE`)."""
    return np.concatenate([RAW_OPT_SCALE[: 16 if textured else 11], [LAG_OPT_SCALE] if lag else []])


def at_lag(theta, data: RawData) -> RawData:
    """``data`` at the lag of θ (D,) when the lag is sampled (``data.lag_prior`` set: θ's last column is log τ):
    the coarse-frame lag weights and the zero-pressure baseline recomputed for τ, and the lag then fixed
    (``lag_prior`` None), so that a second call on the result is free; pure JAX (θ may be traced). ``data`` as it
    is otherwise."""
    if data.lag_prior is None:
        return data
    lw = tx.coarse_lag_weights(float(data.dt) / int(data.lag_stride), jnp.exp(theta[-1]), int(data.lag_stride))
    base = data.baseline
    if data.unloaded is not None:
        base = jnp.log(tx.coarse_lag(jnp.asarray(data.unloaded), jnp.asarray(data.start), lw))
    return data._replace(lag_weights=lw, baseline=base, lag_prior=None)


def with_lag_bounds(bounds: cm.Bounds, lag_prior) -> cm.Bounds:
    """``bounds`` with the column of the sampled lag appended: log τ in [log τ_min, log τ_max] (``lag_prior`` s)."""
    lo, hi = (float(v) for v in lag_prior)
    if not 0 < lo < hi:
        raise ValueError(f"lag_prior must be 0 < tau_min < tau_max (s), got {lag_prior}")
    return cm.Bounds(
        jnp.concatenate([jnp.asarray(bounds.lower), jnp.asarray([np.log(lo)])]),
        jnp.concatenate([jnp.asarray(bounds.upper), jnp.asarray([np.log(hi)])]),
    )


def _hom(data: RawData):
    """Homogeneous positions (4, P) m of the evaluated penetrating-taxel slots (all F·J, or ``data.active``); pure
    JAX (``data`` may be traced)."""
    x = jnp.asarray(data.taxel_position, dtype=float).reshape(-1, 3)
    if data.active is not None:
        x = x[jnp.asarray(data.active)]
    return jnp.concatenate([x.T, jnp.ones((1, x.shape[0]))])


#: signed distance (m) given to the slots :func:`prune_clear` left out: far enough that the softplus penetration is
#: exactly 0 in float64
_CLEAR = 1.0


def slot_distances(thetas, data: RawData, texture: RawTexture | None = None):
    """Signed distances (W, F, J) m of the penetrating taxels to the surfaces of ``thetas (W, D)``
    (:func:`bayestouch.inference.grating.distance_batch`, float64); the slots left out by :func:`prune_clear` get
    :data:`_CLEAR`."""
    F, J = np.shape(data.taxel_position)[:2]
    ref = None if texture is None else texture.ref
    d = gr.distance_batch(thetas, _hom(data), ref)
    if data.active is not None:
        d = jnp.full((d.shape[0], F * J), _CLEAR).at[:, jnp.asarray(data.active)].set(d)
    return d.reshape(-1, F, J)


#: slots farther than this (m) outside the start's surface are not evaluated while sampling (:func:`prune_clear`)
PRUNE_MARGIN = 1e-4
#: a draw that brings a left-out slot closer than this (m) to its surface is reported (:func:`prune_clearance`):
#: there the left-out penetration s·softplus(−φ/s) (s = 1 µm) is still below 1e-19 m
PRUNE_CHECK = 3e-5


def prune_clear(data: RawData, theta, texture: RawTexture | None = None, margin: float = PRUNE_MARGIN) -> RawData:
    """``data`` evaluating only the penetrating-taxel slots within ``margin`` (m) of (or inside) the surface of
    ``theta``; the rest are taken as clear of the surface (``docs/raw_model.md``, reduction 4). Exact to float64
    rounding for every θ whose surface stays more than :data:`PRUNE_CHECK` from the left-out slots."""
    full = data._replace(active=None)
    sdf = np.asarray(slot_distances(jnp.asarray(np.asarray(theta, float))[None], full, texture))[0].ravel()
    return data._replace(active=np.flatnonzero(sdf < margin))


def prune_clearance(draws, data: RawData, texture: RawTexture | None = None) -> dict:
    """How close the slots :func:`prune_clear` left out come to the surfaces of ``draws (S, D)``: the smallest
    signed distance (m) over draws and left-out slots, and whether it stays above :data:`PRUNE_CHECK`."""
    F, J = np.shape(data.taxel_position)[:2]
    info = {"margin_m": PRUNE_MARGIN, "slots_total": int(F * J)}
    if data.active is None:
        return {**info, "slots_kept": int(F * J), "min_clearance_m": None, "exact": True}
    out = np.setdiff1d(np.arange(F * J), np.asarray(data.active))
    info["slots_kept"] = int(F * J - out.size)
    if out.size == 0:
        return {**info, "min_clearance_m": None, "exact": True}
    rest = data._replace(active=out)
    ref = None if texture is None else texture.ref
    d = np.asarray(_jit_distance(jnp.asarray(np.asarray(draws, float)), _hom(rest), ref))
    m = float(d.min())
    return {**info, "min_clearance_m": m, "exact": bool(m > PRUNE_CHECK)}


@jax.jit
def _jit_distance(th, hom, ref):
    return gr.distance_batch(th, hom, ref)


def distance_log_current(sdf, data: RawData, finger):
    """ln I (F, M) of the selected taxels from the signed distances ``sdf (F, J)`` m of the penetrating ones."""
    return fw.log_current_from_distance(
        finger, sdf, jnp.asarray(data.kernel), data.temperature, data.start, data.lag_weights, data.mode
    )


def predict_log_current(theta, data: RawData, finger, texture: RawTexture | None = None):
    """Predicted ln I (F, M) of the selected taxels for θ (11,) (16, with the texture parameters, when ``texture``
    is given; log k and log σ_r are ignored; with a sampled lag, its last column is log τ); pure JAX."""
    theta = jnp.asarray(theta)
    return distance_log_current(slot_distances(theta[None], data, texture)[0], at_lag(theta, data), finger)


def reading_scale(theta, data: RawData, texture: RawTexture | None, nu: float = STUDENT_NU):
    """Student-t scale (F, M) of the readings: c_ν·k·s (:func:`~bayestouch.inference.densities.t_scale_factor`),
    with the roughness variance σ_r² v added under a texture: c_ν·√(k²s² + σ_r² v)."""
    var = (jnp.exp(theta[10]) * jnp.asarray(data.noise_sd)) ** 2
    if texture is not None:
        var = var + jnp.exp(2.0 * theta[15]) * jnp.asarray(texture.rough_var)
    return t_scale_factor(nu) * jnp.sqrt(var)


def taxel_offsets(residual, variance, gain_sd):
    """Posterior mean (M,) of each taxel's remaining log-gain δ ~ N(0, ``gain_sd``²) given the residuals
    ``residual (F, M)`` = ln I − prediction of variances ``variance (F, M)``: Σ_f r/v / (1/s² + Σ_f 1/v)."""
    w = 1.0 / variance
    return jnp.sum(w * residual, axis=0) / (1.0 / jnp.asarray(gain_sd) ** 2 + jnp.sum(w, axis=0))


def _marginalised(theta, pred, data: RawData, nu, texture):
    """The nuisance terms of the readings marginalised (Gaussian algebra, exact for Gaussian readings):

    - the taxels' common response factor a ~ N(``data.response_scale``, ``data.response_sd``²) on
      Δ ln I = prediction − ``data.baseline``, and
    - each taxel's remaining log-gain δ_k ~ N(0, ``data.gain_sd``²).

    With Σ the per-taxel covariance V + s²11ᵀ and D = Δ ln I, the response is b̂ = DᵀΣ⁻¹r / (1/σ_a² + DᵀΣ⁻¹D)
    away from its prior mean, then the offsets :func:`taxel_offsets` of r − b̂D. Returns the prediction with both
    added (F, M) — what the readings are compared with — and the log-determinant and prior terms spread evenly over
    the readings (F, M)."""
    y = jnp.asarray(data.log_current)
    pred = jnp.where(jnp.isfinite(pred), pred, y - 1e6)  # absurd shapes: finite, hugely unlikely
    var = (reading_scale(theta, data, texture, nu) / t_scale_factor(nu)) ** 2
    w = 1.0 / var
    F, M = y.shape
    if data.gain_sd is not None:
        s2 = jnp.asarray(data.gain_sd) ** 2
        A = 1.0 / s2 + jnp.sum(w, axis=0)

        def inner(x, z):
            return jnp.sum(jnp.sum(w * x * z, axis=0) - jnp.sum(w * x, axis=0) * jnp.sum(w * z, axis=0) / A)
    else:

        def inner(x, z):
            return jnp.sum(w * x * z)

    spread = jnp.zeros((F, M))
    b = d = jnp.zeros(())
    if data.response_sd is not None:
        D = (pred - data.baseline) / data.response_scale
        sa2 = jnp.asarray(data.response_sd) ** 2
        DD = inner(D, D)
        b = inner(D, y - pred) / (1.0 / sa2 + DD)
        pred = pred + b * D
        spread = spread + (-0.5 * b * b / sa2 - 0.5 * jnp.log1p(sa2 * DD)) / (F * M)
    if data.gain_sd is not None:
        d = taxel_offsets(y - pred, var, data.gain_sd)
        pred = pred + d
        spread = spread + (-0.5 * d * d / s2 - 0.5 * jnp.log1p(s2 * jnp.sum(w, axis=0))) / F
    return pred, spread, b, d


def response_scaled(pred, data: RawData):
    """The prediction ``pred (F, M)`` at the data's response factor a: baseline + a (pred − baseline) (``pred``
    itself without a baseline); a may be traced."""
    if data.baseline is None:
        return pred
    return data.baseline + data.response_scale * (pred - data.baseline)


def nuisance_estimates(theta, data: RawData, finger, nu: float = STUDENT_NU, texture: RawTexture | None = None):
    """Posterior means at θ of the marginalised device terms: the response factor a (float) and each selected
    taxel's log-gain offset (M,) (zeros where they are not marginalised)."""
    data = at_lag(jnp.asarray(theta), data)
    pred = response_scaled(predict_log_current(theta, data, finger, texture), data)
    _, _, b, d = _marginalised(theta, pred, data, nu, texture)
    M = np.shape(data.log_current)[1]
    return float(data.response_scale + b), np.broadcast_to(np.asarray(d, float), (M,)).copy()


def with_nuisance_fixed(data: RawData, response_scale, offsets) -> RawData:
    """``data`` with the device terms fixed at ``response_scale`` and the taxel ``offsets (M,)`` (divided out of the
    readings), nothing marginalised: the smooth likelihood of a known device, for the start's first polish. Pure
    JAX: both may be traced, so one compiled log-density serves every estimate of them."""
    return data._replace(
        log_current=jnp.asarray(data.log_current) - jnp.asarray(offsets)[None, :],
        gain_sd=None,
        response_scale=response_scale,
        response_sd=None,
    )


def reading_log_lik(theta, pred, data: RawData, nu, texture):
    """Log-likelihood (F, M) of every selected reading given the predicted ln I ``pred (F, M)`` at θ (which supplies
    the noise multiplier k and, with ``texture``, the roughness σ_r): Student-t(``nu``) of scale
    :func:`reading_scale`; a non-finite residual counts as 1e6.

    With ``data.response_sd`` and ``data.gain_sd`` the taxels' common response factor and each taxel's remaining
    log-gain are marginalised (:func:`_marginalised`): the residuals less their posterior means enter the
    Student-t, and the Gaussian marginal's prior and log-determinant terms are added, spread evenly over the
    readings (exact for Gaussian readings; ``docs/raw_model.md``)."""
    scale = reading_scale(theta, data, texture, nu)
    pred = response_scaled(pred, data)
    if data.gain_sd is None and data.response_sd is None:
        r = jnp.asarray(data.log_current) - pred
        r = jnp.where(jnp.isfinite(r), r, 1e6)  # overflowed predictions of absurd shapes: finite, hugely unlikely
        return student_t_logpdf(r, scale, nu)
    full, extra, _, _ = _marginalised(theta, pred, data, nu, texture)
    return student_t_logpdf(jnp.asarray(data.log_current) - full, scale, nu) + extra


def predict_readings(theta, data: RawData, finger, nu: float = STUDENT_NU, texture: RawTexture | None = None):
    """What the corrected readings ``data.log_current`` are compared with at θ (F, M): :func:`predict_log_current`
    with, where they are marginalised, the posterior means of the response factor and the taxel offsets added
    (:func:`_marginalised`); pure JAX."""
    data = at_lag(jnp.asarray(theta), data)
    pred = response_scaled(predict_log_current(theta, data, finger, texture), data)
    if data.gain_sd is None and data.response_sd is None:
        return pred
    return _marginalised(theta, pred, data, nu, texture)[0]


def raw_pointwise(theta, data: RawData, finger, nu: float = STUDENT_NU, texture: RawTexture | None = None):
    """Log-likelihood (F, M) of every selected reading (Student-t of scale k·s, or √(k²s² + σ_r² v) with the
    texture)."""
    data = at_lag(jnp.asarray(theta), data)
    return reading_log_lik(theta, predict_log_current(theta, data, finger, texture), data, nu, texture)


def raw_log_likelihood(theta, data: RawData, finger, nu: float = STUDENT_NU, texture: RawTexture | None = None):
    """Σ of :func:`raw_pointwise`."""
    return jnp.sum(raw_pointwise(theta, data, finger, nu, texture))


def raw_bounds(data: RawData, priors: cm.PriorParams) -> cm.Bounds:
    """Prior box: the contact level's (centre range from the known pad-centre contact region) with log k."""
    pts = np.asarray(data.taxel_position).reshape(-1, 3)
    b = cm.bounds_for(pts, priors)
    lo, hi = np.asarray(b.lower).copy(), np.asarray(b.upper).copy()
    lo[10], hi[10] = LOG_K_RANGE
    return cm.Bounds(jnp.asarray(lo), jnp.asarray(hi))


def raw_log_prob_batch(
    thetas, data: RawData, finger, bounds: cm.Bounds, nu: float = STUDENT_NU, texture: RawTexture | None = None
):
    """Log-posterior (W,) (unnormalised) of walkers ``thetas (W, D)``: −inf outside the prior box, never NaN;
    pure JAX. The signed distances of all walkers come from one batched kernel; the skin, taxel and lag models
    are mapped over walkers."""
    lp = cm.log_prior(thetas, bounds) - 0.5 * (thetas[:, 10] / LOG_K_PRIOR_SD) ** 2
    if texture is not None:
        lp = lp + gr.texture_log_prior(thetas, texture.amplitude_scale)
    if data.lag_prior is not None:
        lp = lp + thetas[:, -1]  # uniform in τ: the density of log τ is ∝ τ
    th = cm.clip_to_box(thetas, bounds)
    sdf = slot_distances(th, data, texture)

    def one(t, s):
        d = at_lag(t, data)
        return jnp.sum(reading_log_lik(t, distance_log_current(s, d, finger), d, nu, texture))

    ll = jax.vmap(one)(th, sdf)
    out = jnp.where(jnp.isfinite(lp), lp + ll, -jnp.inf)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


def raw_log_prob(
    theta, data: RawData, finger, bounds: cm.Bounds, nu: float = STUDENT_NU, texture: RawTexture | None = None
):
    """Log-posterior (unnormalised) of one θ (11,) or (16,) with ``texture`` (one more, log τ, with a sampled lag);
    see :func:`raw_log_prob_batch`."""
    return raw_log_prob_batch(jnp.asarray(theta)[None], data, finger, bounds, nu, texture)[0]


def make_raw_log_prob(
    data: RawData,
    finger,
    priors: cm.PriorParams | None = None,
    nu: float = STUDENT_NU,
    texture: RawTexture | None = None,
    bounds: cm.Bounds | None = None,
):
    """A jitted, walker-vectorised log-posterior for ``emcee(vectorize=True)``.

    Returns
    -------
    f : callable
        ``f(thetas (W, D)) → (W,)`` NumPy; −inf outside the prior, never NaN.
    bounds : Bounds
        ``bounds`` if given, else :func:`raw_bounds` (which has no texture part: a textured model needs the
        box of :func:`~bayestouch.inference.raw.texture.textured_bounds`).
    names : tuple of str
        :func:`raw_names` (the bare shape's, the texture's with ``texture``, the lag's when ``data`` samples it).
    """
    priors = priors or cm.load_priors()
    if bounds is None:
        bounds = raw_bounds(data, priors)
        if data.lag_prior is not None:
            bounds = with_lag_bounds(bounds, data.lag_prior)
    data = on_device(data)

    def f(thetas):
        th = np.atleast_2d(np.asarray(thetas, dtype=float))
        th_j = jnp.asarray(np.nan_to_num(th, nan=np.inf))
        out = np.asarray(log_prob_batch(th_j, data, finger, bounds, texture, nu=nu))
        return np.where(np.isfinite(th).all(axis=1) & ~np.isnan(out), out, -np.inf)

    return f, bounds, raw_names(texture is not None, data.lag_prior is not None)


def jit_on_data(fun):
    """``fun(theta, data, *args, nu=...)`` compiled with ``data``'s arrays as an argument
    (:func:`~bayestouch.inference.raw.data.split_data`; its non-array fields and ``nu`` static): one program per
    shape, shared by every call site and every recording of those shapes, where a ``jax.jit`` of a closure over
    ``data`` compiles again for each, with the arrays baked in as constants. ``args`` are pytrees of arrays or None
    (the finger, the prior box, the texture)."""

    def inner(theta, arrays, static, nu, *args):
        return fun(theta, join_data(arrays, static), *args, nu=nu)

    compiled = jax.jit(inner, static_argnums=(2, 3))

    @wraps(fun)
    def call(theta, data: RawData, *args, nu: float = STUDENT_NU):
        arrays, static = split_data(data)
        return compiled(theta, arrays, static, float(nu), *args)

    return call


def _neg_log_post_vg(theta, data: RawData, finger, bounds: cm.Bounds, texture=None, *, nu):
    """(−:func:`raw_log_prob`, its gradient) at one θ."""
    return jax.value_and_grad(lambda t: -raw_log_prob(t, data, finger, bounds, nu, texture))(theta)


def _log_prob(theta, data: RawData, finger, bounds: cm.Bounds, texture=None, *, nu):
    """:func:`raw_log_prob` of one θ."""
    return raw_log_prob(theta, data, finger, bounds, nu, texture)


def _log_prob_batch(thetas, data: RawData, finger, bounds: cm.Bounds, texture=None, *, nu):
    """:func:`raw_log_prob_batch` of walkers θ (W, D)."""
    return raw_log_prob_batch(thetas, data, finger, bounds, nu, texture)


def _frame_log_lik(theta, data: RawData, finger, texture, nu):
    """Log-likelihood (F,) of each selected frame (its taxels' readings summed) at one θ."""
    return jnp.sum(raw_pointwise(theta, data, finger, nu, texture), axis=1)


def _frame_log_lik_batch(thetas, data: RawData, finger, texture=None, *, nu):
    """:func:`_frame_log_lik` of draws θ (S, D): (S, F)."""
    return jax.vmap(lambda t: _frame_log_lik(t, data, finger, texture, nu))(thetas)


def _frame_log_lik_jacobian(theta, data: RawData, finger, texture=None, *, nu):
    """Jacobian (F, D) of :func:`_frame_log_lik` at one θ."""
    return jax.jacfwd(lambda t: _frame_log_lik(t, data, finger, texture, nu))(theta)


def _readings_batch(thetas, data: RawData, finger, texture=None, *, nu):
    """(:func:`predict_readings`, :func:`reading_scale`), each (S, F, M), of draws θ (S, D)."""
    return jax.vmap(lambda t: (predict_readings(t, data, finger, nu, texture), reading_scale(t, data, texture, nu)))(
        thetas
    )


#: (−log-posterior, its gradient) of one θ: ``neg_log_post_vg(θ, data, finger, bounds, texture=None, nu=ν)``,
#: the optimisers' objective (:func:`jit_on_data`)
neg_log_post_vg = jit_on_data(_neg_log_post_vg)
#: log-posterior of one θ: ``log_prob_value(θ, data, finger, bounds, texture=None, nu=ν)``
log_prob_value = jit_on_data(_log_prob)
#: log-posterior (W,) of walkers θ (W, D): ``log_prob_batch(θs, data, finger, bounds, texture=None, nu=ν)``
log_prob_batch = jit_on_data(_log_prob_batch)
#: log-likelihood (S, F) of each frame for draws θ (S, D): ``frame_log_lik_batch(θs, data, finger, texture, nu=ν)``
frame_log_lik_batch = jit_on_data(_frame_log_lik_batch)
#: Jacobian (F, D) of the frames' log-likelihoods at one θ: ``frame_log_lik_jacobian(θ, data, finger, texture, nu=ν)``
frame_log_lik_jacobian = jit_on_data(_frame_log_lik_jacobian)
#: (prediction, Student-t scale), each (S, F, M), of draws θ (S, D): ``readings_batch(θs, data, finger, texture,
#: nu=ν)``
readings_batch = jit_on_data(_readings_batch)


def raw_objective(data: RawData, finger, bounds: cm.Bounds, texture: RawTexture | None = None, nu: float = STUDENT_NU):
    """The optimisers' objective θ (D,) → (−log-posterior, its gradient (D,)): :data:`neg_log_post_vg` on ``data``
    (moved to the device once, :func:`~bayestouch.inference.raw.data.on_device`)."""
    data = on_device(data)
    return lambda theta: neg_log_post_vg(theta, data, finger, bounds, texture, nu=nu)
