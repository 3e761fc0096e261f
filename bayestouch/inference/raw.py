"""Raw-current likelihood level: the forward model predicts every (selected) taxel's current along the
recorded strokes, and the read-out noise model of :mod:`bayestouch.physics.noise` gives the likelihood.

Parameters θ (11,): centre (3, m), log semi-axes (3, log m), Euler angles ξ ∈ [0, π], ψ ∈ [0, π),
ζ ∈ [−π, π) (the symmetry-reduced ranges of :func:`bayestouch.inference.contact.bounds_for`), log n, and
log k, a dimensionless multiplier on the modelled noise standard deviation (prior N(0, 1) in log k, inside a
box [log 0.1, log 10⁴]); k ≫ 1 in the posterior flags a misspecified forward or noise model. Texture
(amplitude, wavelength, orientation, roughness) is not sampled: the hypothesised surface is the bare
n-ellipsoid (no FFD, texture or defects), whose signed distance is the first-order distance
(G − 1)/|∇G| — the same as :func:`bayestouch.scene.surface.signed_distance` of such a surface.

What is known at inference time, and how it is used
---------------------------------------------------
* Pad pose: the finger is position-controlled, so every taxel's world position in every frame is known and
  independent of θ. It is rebuilt from the recording's ``contact_point`` (commanded pad-centre contact),
  ``contact_normal``, ``pressing_depth`` and the tangent of successive contact points within a stroke, with
  :func:`bayestouch.forward.pad_points` (pad centre = contact + (R − depth)·n). ``contact_point`` is used
  only for this, never as a shape datum (except to seed the initial optimiser, see :func:`initial_raw_theta`).
* Device: the fixed-pattern gains G_j are those of a calibrated device; for a simulated recording the finger is
  rebuilt with ``load_finger(seed=int(ds.attrs['seed']))``. The skin temperature per frame is recorded and enters
  the taxel law exactly (currents move 6–11 %/K, physics.md §0).

Forward model per evaluation (pure JAX, ``vmap``-ed over walkers)
---------------------------------------------------------------
θ → signed distance at the known taxel positions → penetration (softplus, :func:`skin.penetration`) → foam
stress → Gaussian blur between taxels → current (physics or empirical mode, recorded skin temperature) →
first-order lag → ln I. Reductions (all measured against the full model, see the tests and
``benchmarks/bench_raw.py``):

1. Frames: only frames with a commanded contact (``pressing_depth > 0``) are used; every ``stride``-th frame
   of each stroke (default 5 → 0.1 s apart, against the 0.15 s taxel lag: neighbouring frames are strongly
   correlated by the lag and by the 1/f noise anyway).
2. Lag: the forward model's exact discrete lag y_{k+1} = y_k + α(x_k − y_k) (α = 1 − e^{−dt/τ}, restarted at
   steady state at every stroke) is applied on the coarse frames under the assumption that the input is
   linear in time between two selected frames: y_{K+1} = βˢ y_K + (1 − βˢ) x_K + w₁ (x_{K+1} − x_K),
   β = 1 − α, w₁ = (α/s) Σ_{j<s} j β^{s−1−j}; exact for piecewise-linear input.
3. Taxels: only taxels within ``radius`` of the pad centre (pad coordinates) are modelled; the pressure on them
   is blurred from penetrations of the same subset. The others are θ-independent for any plausible shape
   (no contact within ``radius`` minus a few blur widths) and are dropped, as are the unloaded reference
   taxels (used for drift, below).

Noise model (derived from :mod:`bayestouch.physics.noise`)
----------------------------------------------------------
Data are y_tj = ln I_meas − ln G_j − ĉ_t, with ĉ_t the common log-drift measured by the reference row
(median over reference taxels of ln I_meas − ln G − ln Î_clean(unloaded), the unloaded current passed through the
taxels' response lag, which is θ-independent; its variance is π/2 · σ²/n_ref, a median's): this removes
the common random walk and any uniform gain change, as :func:`noise.drift_compensate` does. The residual
r = y − ln Î(θ) has, per reading, variance

    s² = (σ_white(I)/I)² + σ²_1/f + drift_local² · t_stroke + s²_ref,

with σ_white from :func:`noise.noise_std` (shot + amplifier + ADC, at the measured current), the stationary
variance of the OU-sum 1/f model n_fl · K_f · ln r (n_fl = 9, as :func:`noise.add_noise` uses), the per-taxel
random walk since the stroke began, and the variance of the reference-row median s²_ref = π/2 · (σ²_white,ref +
σ²_1/f) / n_ref (treated as independent per reading, a slight over-statement of the information; readings are
also treated as independent over frames although the 1/f and drift parts are correlated, so the posterior is
somewhat too narrow; :func:`bayestouch.planning.texture_id.frame_whitener` whitens them for texture
identification). Readings are
independent Student-t with ν = 4 of scale k·s: the ADC glitches (probability 1e-4, 10 nA ≈ 10³ s at 60 nA) are
outliers a Gaussian cannot take. The 1/f noise is correlated over frames (lag-1 autocorrelation ≈ 0.3 at 50 Hz);
frame subsampling (stride 5) reduces the effect, the rest shows up as k > 1.

The pointwise log-likelihood (ArviZ ``log_likelihood``) is per selected frame, summed over its taxels.

Measured on the standard scenario (egg, 10 strokes, seed 3, empirical mode; ``benchmarks/bench_raw.py``):
modelled reading noise s ≈ 3.8e-4 (robust sd of the residuals at the truth 4.1e-4); signal Δ ln I up to 0.41
(empirical) but only 7.7e-4 (physics mode, ≈ 2 s per loaded reading). Reduction errors in ln I against the full
bare-shape model: taxel subset (radius 4.5 mm, contact radius 3.2 mm) < 5e-6; coarse lag rms 4e-3 at stride 5,
4e-4 at stride 2 — larger than for a smooth path because the simulator's commanded pad path follows the egg's
50 µm texture (a ±60 µm, ≈ 5 Hz oscillation of the contact points at 1 cm/s), which is not linear between frames
0.1 s apart. The egg's texture itself is observable in empirical mode (its effect on ln I: rms 3.1e-3, max 0.04,
≈ 8 s) but not sampled; with the lag error it is absorbed by k ≈ 8 in the posterior (misspecification made
visible, as intended).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch._jax import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import contact as cm
from bayestouch.params import MODELS

__all__ = [
    "RawData",
    "RAW_PARAM_NAMES",
    "RAW_NATURAL_NAMES",
    "load_raw_data",
    "predict_log_current",
    "raw_log_likelihood",
    "raw_log_prob",
    "make_raw_log_prob",
    "raw_bounds",
    "initial_raw_theta",
    "raw_model",
    "run_raw_fit",
    "misfit_warnings",
    "MISFIT_K",
    "STUDENT_NU",
]

RAW_PARAM_NAMES = ("x_G", "y_G", "z_G", "log_a", "log_b", "log_c", "xi", "psi", "zeta", "log_n", "log_k")
RAW_NATURAL_NAMES = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n", "noise_scale")
#: degrees of freedom of the Student-t reading noise
STUDENT_NU = 4.0
#: box of log k (noise-scale multiplier) and the sd of its N(0, ·) prior
LOG_K_RANGE = (np.log(0.1), np.log(1e4))
LOG_K_PRIOR_SD = 1.0
_N_FLICKER = 9
#: pressure cap, Pa: far beyond the skin's densification (tens of kPa), it only keeps absurd shapes finite
P_MAX = 1e6


class RawData(NamedTuple):
    """Everything the raw-current likelihood needs (F selected frames, M selected taxels).

    taxel_position : (F, J, 3) float, metres
        World positions of the taxels that may penetrate (within ``contact_radius``; known pad pose).
    temperature : (F,) float, kelvin
        Skin temperature.
    log_current : (F, M) float
        Measured ln(I / 1 A), divided by the fixed-pattern gains and the reference-row common drift.
    noise_sd : (F, M) float
        Modelled standard deviation of ``log_current`` (dimensionless, before the multiplier k).
    start : (F,) bool
        First selected frame of a stroke (the lag restarts at steady state).
    kernel : (M, J) float
        Pressure blur from the J penetrating taxels onto the M modelled ones.
    lag_weights : (3,) float
        (βˢ, 1 − βˢ, w₁) of the coarse-frame lag.
    frames : (F,) int
        Indices of the selected frames in the recording.
    taxels : (M,) int
        Indices of the selected taxels.
    dt : float, seconds
        Interval between selected frames.
    mode : str
        Taxel response mode of the recording ("physics" or "empirical").
    """

    taxel_position: np.ndarray
    temperature: np.ndarray
    log_current: np.ndarray
    noise_sd: np.ndarray
    start: np.ndarray
    kernel: np.ndarray
    lag_weights: np.ndarray
    frames: np.ndarray
    taxels: np.ndarray
    dt: float
    mode: str


def _need(ds, name, ndim, where):
    if name not in ds.variables:
        raise BadInput(f"{where}: variable '{name}' is missing; expected a bayestouch recording (bayestouch simulate)")
    v = np.asarray(ds[name].values, dtype=float)
    if v.ndim != ndim:
        raise BadInput(f"{where}: variable '{name}' has {v.ndim} dimensions, expected {ndim}")
    if not np.all(np.isfinite(v)):
        raise BadInput(f"{where}: variable '{name}' contains NaN or infinite values; expected finite numbers")
    return v


def lag_weights(dt_fine: float, tau: float, stride: int) -> np.ndarray:
    """(βˢ, 1 − βˢ, w₁) of the exact coarse-step lag for piecewise-linear input (module docstring, point 2)."""
    a = -np.expm1(-dt_fine / tau)
    b = 1.0 - a
    j = np.arange(stride)
    w1 = a / stride * np.sum(j * b ** (stride - 1 - j))
    return np.array([b**stride, 1.0 - b**stride, w1])


def load_raw_data(
    ds_or_path,
    *,
    models: Path = MODELS,
    stride: int = 5,
    radius: float = 4.5e-3,
    contact_radius: float = 3.2e-3,
    strokes=None,
    finger=None,
):
    """Read a recording into :class:`RawData` and rebuild its finger.

    Parameters
    ----------
    ds_or_path : xarray.Dataset or path
        A recording (:mod:`bayestouch.recording`).
    models : path
        Parameter folder of the finger (``finger.toml``, ``skin.toml``, ``taxels.toml``, ``noise.toml``).
    stride : int
        Use every ``stride``-th frame of each stroke (≥ 1).
    radius : float, metres
        Model the taxels within this pad-coordinate distance of the pad centre.
    contact_radius : float, metres
        Taxels that may touch the object (penetration computed), ≤ ``radius``; the others get pressure only
        through the blur.
    strokes : sequence of int, optional
        Use only these strokes (default all).
    finger : Finger, optional
        The device; default ``load_finger(models, seed=int(ds.attrs['seed']))`` (the simulated device's gains).

    Returns
    -------
    (RawData, Finger)
    """
    from bayestouch import forward as fw
    from bayestouch.physics import noise as nz
    from bayestouch.physics import taxel as tx

    if isinstance(ds_or_path, str | Path):
        p = Path(ds_or_path)
        if not p.is_file():
            raise BadInput(f"recording {p}: no such file; expected a .nc recording from bayestouch simulate")
        from bayestouch.recording import read_recording

        try:
            ds = read_recording(p)
        except Exception as e:  # not netCDF/HDF5
            raise BadInput(
                f"recording {p}: cannot be read as netCDF ({type(e).__name__}); expected a .nc recording"
            ) from None
        where = str(p)
    else:
        ds, where = ds_or_path, "recording"
    if int(stride) < 1:
        raise BadInput(f"stride must be an integer ≥ 1, got {stride}")
    if not radius > 0:
        raise BadInput(f"radius must be positive (metres), got {radius}")
    cur = _need(ds, "taxel_current", 2, where)
    contact = _need(ds, "contact_point", 2, where)
    normal = _need(ds, "contact_normal", 2, where)
    depth = _need(ds, "pressing_depth", 1, where)
    temp = _need(ds, "skin_temperature", 1, where)
    t = _need(ds, "time", 1, where)
    si = _need(ds, "stroke_index", 1, where).astype(int)
    nF, nT = cur.shape
    for name, v in (("contact_point", contact), ("contact_normal", normal)):
        if v.shape != (nF, 3):
            raise BadInput(f"{where}: variable '{name}' has shape {v.shape}, expected ({nF}, 3) (frame, xyz)")
    for name, v in (("pressing_depth", depth), ("skin_temperature", temp), ("time", t), ("stroke_index", si)):
        if v.shape != (nF,):
            raise BadInput(f"{where}: variable '{name}' has shape {v.shape}, expected ({nF},) (frame)")
    mode = str(ds.attrs.get("mode", "physics"))
    if mode not in tx.MODES:
        raise BadInput(f"{where}: attribute 'mode' is {mode!r}, expected one of {tx.MODES}")
    if finger is None:
        from bayestouch.virtual import load_finger

        try:
            seed = int(ds.attrs.get("seed", 0))
        except ValueError:
            raise BadInput(f"{where}: attribute 'seed' must be an integer, got {ds.attrs.get('seed')!r}") from None
        finger = load_finger(Path(models), seed=seed).finger
    N = int(np.asarray(finger.reference).size)
    if nT != N:
        raise BadInput(f"{where}: variable 'taxel_current' has {nT} taxels, expected {N} (the finger's array)")
    ref = np.asarray(finger.reference).ravel().astype(bool)
    if "taxel_reference" in ds.variables and not np.array_equal(np.asarray(ds["taxel_reference"].values) != 0, ref):
        raise BadInput(f"{where}: variable 'taxel_reference' differs from the finger's reference taxels")

    # -- pad pose of every frame (known kinematics), tangent from successive contact points within a stroke
    tangent = np.zeros_like(contact)
    for k in np.unique(si):
        sel = si == k
        tangent[sel] = np.gradient(contact[sel], axis=0) if sel.sum() > 1 else np.array([1.0, 0.0, 0.0])
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-30)
    use_strokes = np.unique(si) if strokes is None else np.asarray(list(strokes), int)
    frames, start = [], []
    for k in use_strokes:
        idx = np.flatnonzero((si == k) & (depth > 0))
        if idx.size == 0:
            continue
        idx = idx[::stride]
        frames.append(idx)
        start.append(np.arange(idx.size) == 0)
    if not frames:
        raise BadInput(f"{where}: no frames with contact (pressing_depth > 0) in the selected strokes")
    frames, start = np.concatenate(frames), np.concatenate(start)
    dts = np.diff(t[si == si[frames[0]]])
    dt_fine = float(np.median(dts)) if dts.size else 0.02

    grid = np.asarray(finger.grid).reshape(-1, 2)
    rho = np.hypot(grid[:, 0], grid[:, 1])
    taxels = np.flatnonzero((rho <= radius) & ~ref)
    pen = np.flatnonzero((rho <= min(contact_radius, radius)) & ~ref)
    if pen.size == 0:
        raise BadInput(
            f"radius {radius:g} m, contact_radius {contact_radius:g} m select no taxels; expected "
            "distances of a few taxel pitches"
        )
    x = jax.vmap(lambda c, n, tg, d: fw.pad_points(finger, c, n, tg, d))(
        jnp.asarray(contact[frames]),
        jnp.asarray(normal[frames]),
        jnp.asarray(tangent[frames]),
        jnp.asarray(depth[frames]),
    )
    x = np.asarray(x).reshape(len(frames), -1, 3)[:, pen]

    # -- data: gain- and drift-corrected log currents, and their modelled noise
    gains = np.asarray(finger.gains).ravel()
    floor = float(nz.adc_lsb(finger.noise))
    meas = np.maximum(cur[frames], floor)
    lnI = np.log(meas) - np.log(gains)
    # the unloaded current at the skin temperature, through the taxels' response lag exactly as the reference
    # taxels see it (each stroke starts at steady state, as the forward model does); without the lag a warming
    # skin leaves a drift bias of ~1e-3 in ln I over a 1 s stroke, twice the reading noise
    unloaded_all = np.asarray(
        tx.taxel_current(finger.taxels, jnp.zeros((nF, 1)), jnp.asarray(temp)[:, None], mode=mode)
    )[:, 0]
    lagged = np.empty_like(unloaded_all)
    for k in np.unique(si):
        sel = np.flatnonzero(si == k)
        lagged[sel] = np.asarray(tx.first_order_lag(unloaded_all[sel, None], dt_fine, float(finger.taxels.lag)))[:, 0]
    unloaded = lagged[frames]
    flick = (
        _N_FLICKER
        * float(finger.noise.flicker)
        * np.log(float(finger.noise.flicker_f_max) / float(finger.noise.flicker_f_min))
        / (_N_FLICKER - 1)
    )
    white = (np.asarray(nz.noise_std(finger.noise, jnp.asarray(meas))) / meas) ** 2
    # median over the reference taxels: one read-out glitch on a reference taxel must not shift every taxel
    c_hat = np.median(lnI[:, ref] - np.log(unloaded)[:, None], axis=1)
    s_ref = 0.5 * np.pi * (np.mean(white[:, ref], axis=1) + flick) / ref.sum()  # variance of a median: π/2 · σ²/n
    t_first = {k: t[np.flatnonzero(si == k)[0]] for k in np.unique(si[frames])}
    t_in = t[frames] - np.array([t_first[k] for k in si[frames]])
    var = white[:, taxels] + flick + float(finger.noise.drift_local) ** 2 * t_in[:, None] + s_ref[:, None]
    kernel = np.asarray(finger.kernel)[np.ix_(taxels, pen)]
    lw = lag_weights(dt_fine, float(finger.taxels.lag), int(stride))
    data = RawData(
        x,
        temp[frames],
        lnI[:, taxels] - c_hat[:, None],
        np.sqrt(var),
        start,
        kernel,
        lw,
        frames,
        taxels,
        dt_fine * stride,
        mode,
    )
    return data, finger


def _coarse_lag(x, start, w):
    """Lag (F, M) of inputs ``x`` on the coarse frames (piecewise-linear input), restarting where ``start``."""

    def step(carry, xs):
        y, xp = carry
        xk, s = xs
        yk = jnp.where(s, xk, w[0] * y + w[1] * xp + w[2] * (xk - xp))
        return (yk, xk), yk

    _, ys = jax.lax.scan(step, (x[0], x[0]), (x, start))
    return ys


def _sdf32(s: ne.NEllipsoid, x):
    """First-order signed distance (…,) m of world points ``x (…, 3)``, the transcendental part in float32.

    The rotation is done in float64; the power law in float32 (2.3× faster on CPU) loses < 1e-8 m, against the
    1 µm contact smoothing length."""
    y = ((x - s.centre) @ s.rotation).astype(jnp.float32)
    s32 = ne.NEllipsoid(*(jnp.asarray(a).astype(jnp.float32) for a in s))
    return ne.first_order_distance(s32, y)[0].astype(jnp.float64)


def predict_log_current(theta, data: RawData, finger):
    """Predicted ln I (F, M) of the selected taxels for shape θ (11,) (the last entry is ignored); pure JAX."""
    from bayestouch.physics import skin as sk
    from bayestouch.physics import taxel as tx

    s = cm.shape_of(theta)
    delta = sk.penetration(_sdf32(s, jnp.asarray(data.taxel_position)), finger.skin.s)
    p = jnp.minimum(sk.pressure_at_taxels(finger.skin, delta, jnp.asarray(data.kernel)), P_MAX)
    cur = tx.taxel_current(finger.taxels, p, jnp.asarray(data.temperature)[:, None], mode=data.mode)
    cur = _coarse_lag(cur, jnp.asarray(data.start), jnp.asarray(data.lag_weights))
    return jnp.log(cur)


def _student_t(r, scale, nu):
    from jax.scipy.special import gammaln

    c = gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * jnp.log(nu * jnp.pi)
    return c - jnp.log(scale) - 0.5 * (nu + 1) * jnp.log1p((r / scale) ** 2 / nu)


def raw_pointwise(theta, data: RawData, finger, nu: float = STUDENT_NU):
    """Log-likelihood (F, M) of every selected reading (Student-t of scale k·s)."""
    r = jnp.asarray(data.log_current) - predict_log_current(theta, data, finger)
    r = jnp.where(jnp.isfinite(r), r, 1e6)  # overflowed predictions of absurd shapes: finite, hugely unlikely
    return _student_t(r, jnp.exp(theta[10]) * jnp.asarray(data.noise_sd), nu)


def raw_log_likelihood(theta, data: RawData, finger, nu: float = STUDENT_NU):
    """Σ of :func:`raw_pointwise`."""
    return jnp.sum(raw_pointwise(theta, data, finger, nu))


def raw_bounds(data: RawData, priors: cm.PriorParams) -> cm.Bounds:
    """Prior box: the contact level's (centre range from the known pad-centre contact region) with log k."""
    pts = np.asarray(data.taxel_position).reshape(-1, 3)
    b = cm.bounds_for(pts, priors)
    lo, hi = np.asarray(b.lower).copy(), np.asarray(b.upper).copy()
    lo[10], hi[10] = LOG_K_RANGE
    return cm.Bounds(jnp.asarray(lo), jnp.asarray(hi))


def raw_log_prob(theta, data: RawData, finger, bounds: cm.Bounds, nu: float = STUDENT_NU):
    """Log-posterior (unnormalised) of θ (11,): −inf outside the prior box, never NaN; pure JAX."""
    lp = cm.log_prior(theta, bounds) - 0.5 * (theta[10] / LOG_K_PRIOR_SD) ** 2
    ll = raw_log_likelihood(jnp.clip(theta, bounds.lower, bounds.upper), data, finger, nu)
    out = jnp.where(jnp.isfinite(lp), lp + ll, -jnp.inf)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


def make_raw_log_prob(data: RawData, finger, priors: cm.PriorParams | None = None, nu: float = STUDENT_NU):
    """A jitted, walker-vectorised log-posterior for ``emcee(vectorize=True)``.

    Returns
    -------
    f : callable
        ``f(thetas (W, 11)) → (W,)`` NumPy; −inf outside the prior, never NaN.
    bounds : Bounds
    names : tuple of str
        :data:`RAW_PARAM_NAMES`.
    """
    priors = priors or cm.load_priors()
    bounds = raw_bounds(data, priors)
    batched = jax.jit(jax.vmap(lambda t: raw_log_prob(t, data, finger, bounds, nu)))

    def f(thetas):
        th = np.atleast_2d(np.asarray(thetas, dtype=float))
        out = np.asarray(batched(jnp.asarray(np.nan_to_num(th, nan=np.inf))))
        return np.where(np.isfinite(th).all(axis=1) & ~np.isnan(out), out, -np.inf)

    return f, bounds, RAW_PARAM_NAMES


def initial_raw_theta(
    data: RawData,
    finger,
    contact_points,
    seed: int,
    priors: cm.PriorParams,
    bounds: cm.Bounds,
    nu: float = STUDENT_NU,
    starts: int = 4,
) -> np.ndarray:
    """Start θ (11,): the contact-level DE fit (:func:`bayestouch.inference.run.initial_theta`) to the commanded
    contact points (= pad centre − (R − depth)·n), then L-BFGS-B on the raw log-posterior with exact JAX gradients.

    The raw log-posterior is extremely sharp at k = 1 (relative noise ~4e-4 against signals of 0.05–0.4 in
    empirical mode), so the optimiser starts at k = 30 (a smoother, Student-t-robust landscape) in variables scaled
    to 10 µm / 1e-4 / 1 mrad steps, and is then restarted once from its optimum. With few strokes the surface
    patches leave the global shape multimodal, so ``starts`` DE fits (seeds 1000·seed + k) are polished and the best
    log-posterior wins.
    """
    from scipy.optimize import minimize

    from bayestouch.inference.run import initial_theta

    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    fn = jax.jit(jax.value_and_grad(lambda t: -raw_log_prob(t, data, finger, bounds, nu)))
    scale = np.concatenate([np.full(3, 1e-5), np.full(3, 1e-4), np.full(3, 1e-3), [1e-4], [1e-1]])
    best_th, best_f = None, np.inf
    for k in range(starts):
        th = initial_theta(contact_points, int(seed) * 1000 + k, priors, starts=1)
        th[10] = np.log(30.0)
        th = np.clip(th, lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
        for _ in range(2):
            t1 = th.copy()

            def obj(z, t1=t1):
                v, g = fn(jnp.asarray(t1 + z * scale))
                v, g = float(v), np.asarray(g) * scale
                if not (np.isfinite(v) and np.all(np.isfinite(g))):
                    return 1e30, np.zeros_like(z)
                return v, g

            zb = list(zip((lo - t1) / scale, (hi - t1) / scale, strict=True))
            res = minimize(
                obj,
                np.zeros(11),
                jac=True,
                method="L-BFGS-B",
                bounds=zb,
                options={"maxiter": 3000, "ftol": 1e-14, "gtol": 1e-8},
            )
            th = np.clip(t1 + res.x * scale, lo, hi)
        val = float(fn(jnp.asarray(th))[0])
        if val < best_f:
            best_th, best_f = th, val
    return best_th


def _natural(flat: np.ndarray) -> np.ndarray:
    """θ draws (S, 11) → canonicalised natural parameters (S, 11): centre, a ≥ b ≥ c, angles, n, k (the contact
    level's transform: the 11th column, log k here, is exponentiated like log σ there)."""
    from bayestouch.inference.run import _natural as contact_natural

    return contact_natural(flat)


def raw_model(data: RawData, finger, nu: float = STUDENT_NU):
    """The raw-current level as a :class:`~bayestouch.inference.run.PosteriorModel`: pointwise log-likelihood per
    selected frame (summed over its taxels: per reading would make posterior.nc ~200 MB for 10 strokes); no
    posterior predictive group (the same size problem); the observed data are the corrected ln I (F, M)."""
    from bayestouch.inference.run import PosteriorModel

    pw = jax.jit(jax.vmap(lambda t: jnp.sum(raw_pointwise(t, data, finger, nu), axis=1)))

    def ll(thetas):
        return np.concatenate(
            [np.asarray(pw(jnp.asarray(c))) for c in np.array_split(thetas, max(1, len(thetas) // 64))]
        )

    F, M = np.shape(data.log_current)
    info = {
        "level": "raw-current",
        "mode": data.mode,
        "likelihood": f"Student-t, nu = {nu:g}, per taxel-frame reading; pointwise log-likelihood per frame (summed "
        "over its taxels)",
        "noise_model": "ln I corrected by fixed-pattern gains and reference-row common drift; sd² = white(shot+"
        "amplifier+ADC)/I² + stationary 1/f + local random walk + reference-mean variance; "
        "times k (sampled, prior log k ~ N(0, 1))",
        "frames_used": int(F),
        "frame_interval_s": float(data.dt),
        "taxels_used": int(M),
        "readings": int(F * M),
        "texture": "not sampled (bare n-ellipsoid)",
        "parameters_sampled": list(RAW_PARAM_NAMES),
    }
    return PosteriorModel(
        RAW_NATURAL_NAMES,
        _natural,
        lambda nat: nat[:, :10],
        ll,
        None,
        {"log_current": np.asarray(data.log_current)},
        info,
        checks=misfit_warnings,
    )


#: noise multiplier k above which a raw fit's summary warns that the model does not fit the readings
MISFIT_K = 3.0


def misfit_warnings(summary: dict) -> list[str]:
    """Warnings of a raw-current fit: the posterior mean of the noise multiplier k above :data:`MISFIT_K` says
    the residuals are k times the modelled read-out noise — a forward model that misses something (the texture is
    not sampled, the coarse-frame lag is approximate) — and the shape intervals, computed as if the model were
    right, are then too narrow. Measured on the standard scenario (egg, empirical mode): k ≈ 8, and the true
    volume lies ~6 posterior sds from the mean (``benchmarks/bench_raw.py``)."""
    k = float(summary["parameters"]["noise_scale"]["mean"])
    if k <= MISFIT_K:
        return []
    return [f"noise_scale k = {k:.1f} > {MISFIT_K:g}: the residuals are {k:.0f}x the modelled read-out noise, so the "
            "forward model misses part of the signal (texture is not sampled; the lag is approximated on coarse "
            "frames); the intervals assume the model is right and are likely too narrow"]


def _contact_points(ds, frames):
    return np.asarray(ds["contact_point"].values, float)[frames]


def run_raw_fit(
    recording,
    out,
    *,
    seed: int = 0,
    walkers: int = 32,
    steps: int = 1500,
    resume: bool = False,
    budget_s: float | None = None,
    progress: bool = True,
    stride: int = 5,
    radius: float = 4.5e-3,
    strokes=None,
    models: Path = MODELS,
    starts: int = 4,
    stop_when_converged: bool = True,
) -> dict:
    """Sample the raw-current posterior of a recording and write the run folder ``out``.

    Parameters
    ----------
    recording : path or xarray.Dataset
    out : path
        Run folder (``chain.h5``, ``summary.json``, ``posterior.nc``, meshes).
    seed : int
        Seeds the initial fit, the walkers and emcee.
    walkers, steps : int
    resume : bool
        Continue the chain in ``out/chain.h5``.
    budget_s : float, seconds, optional
        Stop sampling after this wall-clock time.
    stride, radius, strokes, models
        See :func:`load_raw_data`.
    starts : int
        Number of DE starts of :func:`initial_raw_theta`.
    stop_when_converged : bool
        Stop before ``steps`` once converged (:func:`bayestouch.inference.sampler.sample`). Sampling is adaptive
        (``sample(..., adapt=True)``, as :func:`bayestouch.inference.run.run_contact_fit`).

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    from bayestouch.inference.run import write_posterior
    from bayestouch.inference.sampler import sample

    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if isinstance(recording, str | Path):
        from bayestouch.recording import read_recording

        p = Path(recording)
        if not p.is_file():
            raise BadInput(f"recording {p}: no such file; expected a .nc recording from bayestouch simulate")
        try:
            ds = read_recording(p)
        except Exception as e:
            raise BadInput(
                f"recording {p}: cannot be read as netCDF ({type(e).__name__}); expected a .nc recording"
            ) from None
    else:
        ds = recording
    data, finger = load_raw_data(ds, models=models, stride=stride, radius=radius, strokes=strokes)
    priors = cm.load_priors()
    logp, bounds, names = make_raw_log_prob(data, finger, priors)

    def start():
        th = initial_raw_theta(data, finger, _contact_points(ds, data.frames), seed, priors, bounds, starts=starts)
        rng = np.random.default_rng(seed)
        lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
        sc = np.concatenate([np.full(3, 1e-6), np.full(3, 1e-5), np.full(3, 1e-4), [1e-5], [1e-2]])
        p = th + sc * rng.normal(size=(walkers, th.size))
        return np.clip(p, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

    ch = sample(
        logp,
        start,
        out / "chain.h5",
        walkers=walkers,
        ndim=len(names),
        seed=seed,
        steps=steps,
        resume=resume,
        budget_s=budget_s,
        progress=progress,
        t0=t0,
        stop_when_converged=stop_when_converged,
        adapt=True,
    )
    return write_posterior(out, ch, raw_model(data, finger), seed=seed, t0=t0)
