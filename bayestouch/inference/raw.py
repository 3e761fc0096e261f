"""Raw-current likelihood level: the forward model predicts every (selected) taxel's current along the
recorded strokes, and the read-out noise model of :mod:`bayestouch.physics.noise` gives the likelihood.

Parameters θ (11,): centre (3, m), log semi-axes (3, log m), Euler angles ξ ∈ [0, π], ψ ∈ [0, π),
ζ ∈ [−π, π) (the symmetry-reduced ranges of :func:`bayestouch.inference.contact.bounds_for`), log n, and
log k, a dimensionless multiplier on the modelled noise standard deviation (prior N(0, 1) in log k, inside a
box [log 0.1, log 10⁴]; ``[raw_priors]`` of ``models/priors.toml``); k ≫ 1 in the posterior flags a misspecified
forward or noise model. With the texture (``texture="auto"`` when a grating is found, or ``"on"``;
:func:`run_raw_fit`) five more, θ (16,): the grating
(u, v, log λ, orientation) and log roughness of :mod:`bayestouch.inference.grating`. The hypothesised surface is
the n-ellipsoid (no FFD or defects), whose signed distance is the first-order distance (G − 1)/|∇G| minus the
grating's height at the foot point — the same as :func:`bayestouch.scene.surface.signed_distance` of such a
surface (to ~1e-8 m); the roughness, whose realisation is unknown, is a variance term.

What is known at inference time, and how it is used
---------------------------------------------------
* Pad pose: the finger is position-controlled, so every taxel's world position in every frame is known and
  independent of θ. It is rebuilt from the recording's ``contact_point`` (commanded pad-centre contact),
  ``contact_normal``, ``pressing_depth`` and the tangent of successive contact points within a stroke, with
  :func:`bayestouch.physics.forward.pad_points` (pad centre = contact + (R − depth)·n). ``contact_point`` is used
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
   of each stroke (default 5 → 0.1 s apart without the texture, against the 0.15 s taxel lag: neighbouring frames
   are strongly correlated by the lag and by the 1/f noise anyway; 2 with the texture, whose readings change
   within 0.1 s, see below).
2. Lag: the forward model's exact discrete lag y_{k+1} = y_k + α(x_k − y_k) (α = 1 − e^{−dt/τ}, restarted at
   steady state at every stroke) is applied on the coarse frames under the assumption that the input is
   linear in time between two selected frames: y_{K+1} = βˢ y_K + (1 − βˢ) x_K + w₁ (x_{K+1} − x_K),
   β = 1 − α, w₁ = (α/s) Σ_{j<s} j β^{s−1−j}; exact for piecewise-linear input.
3. Taxels: only taxels within ``radius`` of the pad centre (pad coordinates) are modelled; the pressure on them
   is blurred from penetrations of the same subset. The others are θ-independent for any plausible shape
   (no contact within ``radius`` minus a few blur widths) and are dropped, as are the unloaded reference
   taxels (used for drift, below).
4. Clear taxels (sampling only, :func:`prune_clear`): of the penetrating taxels' (frame, taxel) slots, those more
   than :data:`PRUNE_MARGIN` (0.1 mm) outside the surface of the sampler's start θ are not evaluated; their
   penetration s·softplus(−φ/s) (s = 1 µm) is below 1e-49 m there, zero to float64 rounding against the others, and
   stays so unless a draw moves the surface by a large fraction of 0.1 mm — thousands of posterior sds. Each run
   checks it on its draws (:func:`prune_clearance`; ``summary.model.pruning``). About 58 % of the slots go on the
   standard scenario, the distance kernel's share of an evaluation with them.

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
independent Student-t with ν = 4 of scale c_ν·k·s: the ADC glitches (probability 1e-4, 10 nA ≈ 10³ s at 60 nA) are
outliers a Gaussian cannot take. c_ν = 0.831 (:func:`t_scale_factor`) is the t scale that fits Gaussian readings of
sd 1 best: without it a t fit of Gaussian residuals reads their sd as 0.83 of itself, so k came out 0.86 on the
standard scenario's textured fit and the roughness RMS 7.1 µm for a true 10; with it k = 1.03 and σ_r = 8.5 µm.
The rest of the roughness gap is the realisation: the scene's field is 16 random cosines, and this egg's,
through the linearised model, has 0.87 of the ensemble's response energy (√0.87 · 10 = 9.3 µm; across
realisations the ratio has sd 0.39, so any one recording pins the ensemble RMS only to ~20 %, which the posterior,
conditional on the field's family, does not include). The 1/f noise is correlated over frames (lag-1
autocorrelation ≈ 0.3 at 50 Hz); frame subsampling (stride 5) reduces the effect, the rest shows up as k > 1.

The pointwise log-likelihood (ArviZ ``log_likelihood``) is per selected frame, summed over its taxels.

Measured on the standard scenario (egg, 10 strokes, seed 3, empirical mode; ``benchmarks/bench_raw.py``):
modelled reading noise s ≈ 3.8e-4 (robust sd of the residuals at the truth 4.1e-4); signal Δ ln I up to 0.41
(empirical) but only 7.7e-4 (physics mode, ≈ 2 s per loaded reading). Reduction errors in ln I against the full
bare-shape model: taxel subset (radius 4.5 mm, contact radius 3.2 mm) < 5e-6; coarse lag rms 4e-3 at stride 5,
4e-4 at stride 2 — larger than for a smooth path because the simulator's commanded pad path follows the egg's
50 µm texture (a ±60 µm, ≈ 5 Hz oscillation of the contact points at 1 cm/s), which is not linear between frames
0.1 s apart. The egg's texture itself is observable in empirical mode (its effect on ln I: rms 3.1e-3, max 0.04,
≈ 8 s). Robust sd of the residuals at the truth, in units of the modelled noise s, bare / grating / grating and
the true roughness realisation: stride 5: 6.4 / 5.1 / 4.4; stride 2: 4.5 / 2.4 / 1.3; stride 1: 4.4 / 2.3 / 1.0. So
the texture needs stride ≤ 2 (the lag then follows the ~5 Hz texture signal), and without it the bare shape's
posterior absorbs the misfit in k ≈ 9.6 (misspecification made visible, as intended).
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.inference import contact as cm
from bayestouch.inference import grating as gr
from bayestouch.inference.densities import student_t_logpdf, t_scale_factor
from bayestouch.inference.grating import RawTexture
from bayestouch.params import MODELS, Spec, build
from bayestouch.physics import forward as fw
from bayestouch.physics import noise as nz
from bayestouch.physics import taxel as tx

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
    "t_scale_factor",
    "load_raw_priors",
    "RAW_PREDICTIVE_DRAWS",
    "STUDENT_NU",
    "RAW_TEXTURE_PARAM_NAMES",
    "RAW_TEXTURE_NATURAL_NAMES",
    "raw_log_prob_batch",
    "search_texture",
    "initial_raw_texture",
    "TextureStart",
    "roughness_variance",
    "textured_bounds",
    "texture_reference",
    "canonical_theta",
    "plane_theta",
    "laplace",
    "laplace_ball",
    "RAW_PROPOSAL_NU",
    "curvature_adjustment",
    "Adjustment",
    "DETECT_NATS",
    "TEXTURE_STRIDE",
    "BARE_STRIDE",
    "ADJUST_BLOCK_S",
    "prune_clear",
    "prune_clearance",
    "PRUNE_MARGIN",
]

RAW_PRIOR_SPECS = {
    "noise_scale_min": Spec("1", 1e-3, 1.0),
    "noise_scale_max": Spec("1", 1.0, 1e8),
    "log_noise_scale_sd": Spec("1", 1e-2, 100.0),
}


def load_raw_priors(path=None) -> dict[str, float]:
    """Read ``[raw_priors]`` of ``models/priors.toml`` (or ``path``): the noise multiplier k's box and log-sd."""
    return build(dict, MODELS / "priors.toml" if path is None else path, "raw_priors", RAW_PRIOR_SPECS)


_RAW_PRIORS = load_raw_priors()

RAW_PARAM_NAMES = ("x_G", "y_G", "z_G", "log_a", "log_b", "log_c", "xi", "psi", "zeta", "log_n", "log_k")
RAW_NATURAL_NAMES = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n", "noise_scale")
#: with the texture (:mod:`bayestouch.inference.grating`)
RAW_TEXTURE_PARAM_NAMES = RAW_PARAM_NAMES + gr.TEXTURE_NAMES
RAW_TEXTURE_NATURAL_NAMES = RAW_NATURAL_NAMES + gr.TEXTURE_NATURAL_NAMES
#: degrees of freedom of the Student-t reading noise
STUDENT_NU = 4.0
#: draws in a raw fit's posterior predictive group (each replicates all F × M readings)
RAW_PREDICTIVE_DRAWS = 32
#: box of log k (noise-scale multiplier) and the sd of its N(0, ·) prior
#: (``[raw_priors]`` of ``models/priors.toml``)
LOG_K_RANGE = (float(np.log(_RAW_PRIORS["noise_scale_min"])), float(np.log(_RAW_PRIORS["noise_scale_max"])))
LOG_K_PRIOR_SD = float(_RAW_PRIORS["log_noise_scale_sd"])


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
    active : (P,) int or None
        Flat indices into the F·J penetrating-taxel slots whose distance is evaluated (:func:`prune_clear`); the
        others are taken to be clear of the surface (no penetration). None: every slot.
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
    active: np.ndarray | None = None


def _need(ds, name, ndim, where):
    if name not in ds.variables:
        raise BadInput(f"{where}: variable '{name}' is missing; expected a bayestouch recording (bayestouch simulate)")
    v = np.asarray(ds[name].values, dtype=float)
    if v.ndim != ndim:
        raise BadInput(f"{where}: variable '{name}' has {v.ndim} dimensions, expected {ndim}")
    if not np.all(np.isfinite(v)):
        raise BadInput(f"{where}: variable '{name}' contains NaN or infinite values; expected finite numbers")
    return v


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
        A recording (:mod:`bayestouch.io.recording`).
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
    if isinstance(ds_or_path, str | Path):
        p = Path(ds_or_path)
        if not p.is_file():
            raise BadInput(f"recording {p}: no such file; expected a .nc recording from bayestouch simulate")
        from bayestouch.io.recording import read_recording

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
        from bayestouch.physics.virtual import load_finger

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
    flick = float(nz.flicker_autocovariance(finger.noise, 0.0))
    white = (np.asarray(nz.noise_std(finger.noise, jnp.asarray(meas))) / meas) ** 2
    # median over the reference taxels: one read-out glitch on a reference taxel must not shift every taxel
    c_hat = np.median(lnI[:, ref] - np.log(unloaded)[:, None], axis=1)
    s_ref = 0.5 * np.pi * (np.mean(white[:, ref], axis=1) + flick) / ref.sum()  # variance of a median: π/2 · σ²/n
    t_first = {k: t[np.flatnonzero(si == k)[0]] for k in np.unique(si[frames])}
    t_in = t[frames] - np.array([t_first[k] for k in si[frames]])
    var = white[:, taxels] + flick + float(finger.noise.drift_local) ** 2 * t_in[:, None] + s_ref[:, None]
    kernel = np.asarray(finger.kernel)[np.ix_(taxels, pen)]
    lw = tx.coarse_lag_weights(dt_fine, float(finger.taxels.lag), int(stride))
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


def _hom(data: RawData):
    """Homogeneous positions (4, P) m of the evaluated penetrating-taxel slots (all F·J, or ``data.active``)."""
    x = np.asarray(data.taxel_position, float).reshape(-1, 3)
    if data.active is not None:
        x = x[np.asarray(data.active)]
    return jnp.asarray(np.concatenate([x.T, np.ones((1, len(x)))]))


#: signed distance (m) given to the slots :func:`prune_clear` left out: far enough that the softplus penetration is
#: exactly 0 in float64
_CLEAR = 1.0


def _sdf_batch(thetas, data: RawData, texture: RawTexture | None = None):
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
    ``theta``; the rest are taken as clear of the surface (module docstring, point 4). Exact to float64 rounding
    for every θ whose surface stays more than :data:`PRUNE_CHECK` from the left-out slots."""
    full = data._replace(active=None)
    sdf = np.asarray(_sdf_batch(jnp.asarray(np.asarray(theta, float))[None], full, texture))[0].ravel()
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


def _log_current(sdf, data: RawData, finger):
    """ln I (F, M) of the selected taxels from the signed distances ``sdf (F, J)`` m of the penetrating ones."""
    return fw.log_current_from_distance(
        finger, sdf, jnp.asarray(data.kernel), data.temperature, data.start, data.lag_weights, data.mode
    )


def predict_log_current(theta, data: RawData, finger, texture: RawTexture | None = None):
    """Predicted ln I (F, M) of the selected taxels for θ (11,) (16, with the texture parameters, when ``texture``
    is given; log k and log σ_r are ignored); pure JAX."""
    return _log_current(_sdf_batch(jnp.asarray(theta)[None], data, texture)[0], data, finger)


def _scale(theta, data: RawData, texture: RawTexture | None, nu: float = STUDENT_NU):
    """Student-t scale (F, M) of the readings: c_ν·k·s (:func:`t_scale_factor`), with the roughness variance σ_r² v
    added under a texture: c_ν·√(k²s² + σ_r² v)."""
    var = (jnp.exp(theta[10]) * jnp.asarray(data.noise_sd)) ** 2
    if texture is not None:
        var = var + jnp.exp(2.0 * theta[15]) * jnp.asarray(texture.rough_var)
    return t_scale_factor(nu) * jnp.sqrt(var)


def _pointwise(theta, pred, data: RawData, nu, texture):
    r = jnp.asarray(data.log_current) - pred
    r = jnp.where(jnp.isfinite(r), r, 1e6)  # overflowed predictions of absurd shapes: finite, hugely unlikely
    return student_t_logpdf(r, _scale(theta, data, texture, nu), nu)


def raw_pointwise(theta, data: RawData, finger, nu: float = STUDENT_NU, texture: RawTexture | None = None):
    """Log-likelihood (F, M) of every selected reading (Student-t of scale k·s, or √(k²s² + σ_r² v) with the
    texture)."""
    return _pointwise(theta, predict_log_current(theta, data, finger, texture), data, nu, texture)


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
    th = jnp.clip(thetas, bounds.lower, bounds.upper)
    sdf = _sdf_batch(th, data, texture)
    pred = jax.vmap(lambda s: _log_current(s, data, finger))(sdf)
    ll = jax.vmap(lambda t, p: jnp.sum(_pointwise(t, p, data, nu, texture)))(th, pred)
    out = jnp.where(jnp.isfinite(lp), lp + ll, -jnp.inf)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


def raw_log_prob(
    theta, data: RawData, finger, bounds: cm.Bounds, nu: float = STUDENT_NU, texture: RawTexture | None = None
):
    """Log-posterior (unnormalised) of one θ (11,) or (16,) with ``texture``; see :func:`raw_log_prob_batch`."""
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
        box of :func:`textured_bounds`).
    names : tuple of str
        :data:`RAW_PARAM_NAMES`, or :data:`RAW_TEXTURE_PARAM_NAMES` with ``texture``.
    """
    priors = priors or cm.load_priors()
    bounds = raw_bounds(data, priors) if bounds is None else bounds
    batched = jax.jit(lambda t: raw_log_prob_batch(t, data, finger, bounds, nu, texture))

    def f(thetas):
        th = np.atleast_2d(np.asarray(thetas, dtype=float))
        out = np.asarray(batched(jnp.asarray(np.nan_to_num(th, nan=np.inf))))
        return np.where(np.isfinite(th).all(axis=1) & ~np.isnan(out), out, -np.inf)

    return f, bounds, RAW_PARAM_NAMES if texture is None else RAW_TEXTURE_PARAM_NAMES


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
    empirical mode), so the optimiser starts at k = 30 (a smoother, Student-t-robust landscape), in variables scaled
    by the diagonal of the Hessian and restarted until it stops gaining (:func:`_lbfgs`). With few strokes the surface
    patches leave the global shape multimodal, so ``starts`` DE fits (seeds 1000·seed + k) are polished and the best
    log-posterior wins.
    """
    from bayestouch.inference.run import initial_theta

    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    fn = jax.jit(jax.value_and_grad(lambda t: -raw_log_prob(t, data, finger, bounds, nu)))
    best_th, best_f = None, np.inf
    for k in range(starts):
        th = initial_theta(contact_points, int(seed) * 1000 + k, priors, starts=1)
        th[10] = np.log(30.0)
        th = np.clip(th, lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
        th, _ = _lbfgs(fn, th, lo, hi, _OPT_SCALE[:11])
        val = float(fn(jnp.asarray(th))[0])
        if val < best_f:
            best_th, best_f = th, val
    return best_th


def texture_reference(data: RawData) -> np.ndarray:
    """The grating's phase reference point (3,) m: the mean position of the penetrating taxels."""
    return np.asarray(data.taxel_position, float).reshape(-1, 3).mean(axis=0)


def textured_bounds(data: RawData, priors: cm.PriorParams, tp: gr.TexturePriors, orientation: float) -> cm.Bounds:
    """Prior box (16,): :func:`raw_bounds` and :func:`bayestouch.inference.grating.texture_bounds`."""
    b = raw_bounds(data, priors)
    tl, th = gr.texture_bounds(tp, orientation)
    return cm.Bounds(jnp.concatenate([b.lower, jnp.asarray(tl)]), jnp.concatenate([b.upper, jnp.asarray(th)]))


def _height_jvp(th, hh, data: RawData, finger, texture: RawTexture | None = None):
    """Linear response (F, M) of ln I to a height field ``hh (F, J)`` m at the penetrating taxels, at θ."""
    sdf = _sdf_batch(th[None], data, texture)[0]
    return jax.jvp(lambda h: _log_current(sdf - h, data, finger), (jnp.zeros_like(sdf),), (hh,))[1]


def search_texture(
    theta0,
    data: RawData,
    finger,
    tp: gr.TexturePriors,
    nu: float = STUDENT_NU,
    count: int = 5,
    rings: int = 24,
    directions: int = 32,
    planes=(0, 1, 2),
):
    """Grating candidates from the residuals of the bare-shape estimate ``theta0`` (11,), by the generalised
    likelihood-ratio statistic of a grating of wave vector k in the sampled frame's x–y plane, linearised at
    θ₀: |C(k)|²/A(k) with C(k) = Σ_p c_p e^{−i k·y_p}, where c = Jᵀψ is the robust (Student-t) score ψ of the
    residuals pulled back onto the penetrating taxels' foot points y_p (one vector–Jacobian product of ln I in a
    height field, J), and A(k) = ‖J cos(k·y)‖²_W + ‖J sin(k·y)‖²_W the predicted signal energy of a unit
    grating (W: the readings' inverse variances). C comes from one FFT
    (:func:`bayestouch.inference.grating.grating_peaks`); A, which varies with k only on the scale of the pad
    and the lag's memory, is computed on a polar grid of ``rings`` log-spaced |k| × ``directions`` angles and
    interpolated. A alone matters: the taxel lattice, the skin's blur and the response lag pass some wave
    vectors far better than others, and the plain power |C|² peaks at their aliases. Each peak of the FFT grid is
    then refined off the grid (:func:`bayestouch.inference.grating.refine_peak`).

    Each principal plane of ``planes`` (0: x–y, 1: x–z, 2: y–z of θ₀'s frame) is searched in the frame
    :func:`plane_theta` makes it the x–y plane; ``count`` peaks each.

    Returns
    -------
    list of (plane, wavelength m, orientation rad, statistic)
    """
    from scipy.interpolate import RegularGridInterpolator

    th = jnp.asarray(np.asarray(theta0, float)[:11])

    @jax.jit
    def pullback(th):  # the prediction, and c = Jᵀψ (F, J)
        sdf0 = _sdf_batch(th[None], data)[0]
        pred0, vjp = jax.vjp(lambda h: _log_current(sdf0 - h, data, finger), jnp.zeros_like(sdf0))
        r = jnp.asarray(data.log_current) - pred0
        wgt = 1.0 / (jnp.exp(th[10]) * jnp.asarray(data.noise_sd)) ** 2
        return vjp((nu + 1.0) * r * wgt / (nu + r * r * wgt))[0], wgt  # ψ = d log t / d prediction

    c, wgt = pullback(th)
    c = np.asarray(c).ravel()
    x = np.asarray(data.taxel_position, float).reshape(-1, 3)
    foot = gr.foot_points(theta0, x)  # principal frame of θ₀
    s = cm.shape_of(np.asarray(theta0, float))
    yref = (texture_reference(data) - np.asarray(s.centre)) @ np.asarray(s.rotation)

    # A(k) on a polar grid: one linearised forward per (k, cos | sin), in batches; the linearisation is the same
    # for every plane (one surface), only the points' in-plane coordinates differ
    logk = np.linspace(np.log(2 * np.pi / tp.wavelength_max), np.log(2 * np.pi / tp.wavelength_min), rings)
    ang = np.arange(directions) * np.pi / directions
    kv = (np.exp(logk)[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], -1)[None]).reshape(-1, 2)
    nb = 16
    kp = jnp.asarray(np.concatenate([kv, np.repeat(kv[-1:], -len(kv) % nb, 0)]))

    @jax.jit
    def energy(xy_j, kb):
        ph = jnp.einsum("fjd,kd->kfj", xy_j, kb)
        out = jax.vmap(lambda hh: _height_jvp(th, hh, data, finger))(jnp.concatenate([jnp.cos(ph), jnp.sin(ph)]))
        e = jnp.sum(out * out * wgt, axis=(1, 2))
        return e[: kb.shape[0]] + e[kb.shape[0] :]

    found = []
    for plane in planes:
        P = _PLANES[plane]
        xy = (foot @ P)[:, :2] - (yref @ P)[:2]  # coordinates in the frame R P (plane_theta's)
        xy_j = jnp.asarray(xy.reshape(np.shape(data.taxel_position)[:2] + (2,)))
        A = np.concatenate([np.asarray(energy(xy_j, kp[i : i + nb])) for i in range(0, len(kp), nb)])[: len(kv)]
        A = A.reshape(rings, directions)
        # periodic in angle with period π (A(k) = A(−k)): pad one column each side
        interp = RegularGridInterpolator(
            (logk, np.concatenate([[ang[-1] - np.pi], ang, [np.pi]])),
            np.log(np.concatenate([A[:, -1:], A, A[:, :1]], axis=1)),
            bounds_error=False,
            fill_value=None,
        )

        def norm(kx, ky, interp=interp):
            kk = np.clip(np.hypot(kx, ky), np.exp(logk[0]), np.exp(logk[-1]))
            return np.exp(interp(np.column_stack([np.log(kk), np.arctan2(ky, kx) % np.pi])))

        peaks = gr.grating_peaks(c, xy, tp.wavelength_min, tp.wavelength_max, norm=norm, count=count)
        found += [(plane, *gr.refine_peak(c, xy, lam, o, norm)) for lam, o, _ in peaks]
    return found


def roughness_variance(theta, data: RawData, finger, texture: RawTexture, count: int = 128, seed: int = 0):
    """v (F, M), 1/m²: the variance of each reading's ln I per unit roughness RMS², by Monte Carlo over ``count``
    unit-RMS fields of the scene's roughness family (:func:`bayestouch.inference.grating.roughness_fields`, at the
    grating wavelength of ``theta`` (16,)) through the forward model linearised in the height at ``theta``."""
    th = jnp.asarray(np.asarray(theta, float))
    F, J = np.shape(data.taxel_position)[:2]
    foot = gr.foot_points(theta, np.asarray(data.taxel_position, float).reshape(-1, 3))
    fields = gr.roughness_fields(foot, float(np.exp(theta[13])), count, np.random.default_rng(seed))
    run = jax.jit(lambda hh: jnp.sum(jax.vmap(lambda h: _height_jvp(th, h, data, finger, texture))(hh) ** 2, axis=0))
    acc = np.zeros(np.shape(data.log_current))
    for chunk in np.array_split(fields, max(1, count // 16)):
        acc += np.asarray(run(jnp.asarray(chunk.reshape(-1, F, J))))
    return acc / count


def _fd_hessian(fn, th, steps, lo, hi) -> np.ndarray:
    """Hessian (D, D) of ``fn`` (value and gradient) at ``th`` by central differences of the gradient, column j from
    ±``steps[j]`` (the points clipped into [lo, hi]); columns of fixed variables (lo = hi) are zero."""
    H = np.zeros((th.size, th.size))
    for j in np.flatnonzero(hi > lo):
        e = np.zeros(th.size)
        e[j] = steps[j]
        gp = np.asarray(fn(jnp.asarray(np.clip(th + e, lo, hi)))[1])
        gm = np.asarray(fn(jnp.asarray(np.clip(th - e, lo, hi)))[1])
        H[:, j] = (gp - gm) / (2 * steps[j])
    return H


def _diag_scale(fn, th, lo, hi, scale) -> np.ndarray:
    """Variable scales 1/√H_jj from the diagonal of the Hessian of ``fn`` (value and gradient) at ``th``
    (:func:`_fd_hessian`, steps of 1e-3 ``scale``); ``scale`` where that fails or the variable is fixed."""
    out = np.asarray(scale, float).copy()
    hjj = np.diag(_fd_hessian(fn, th, 1e-3 * out, lo, hi))
    ok = (hi > lo) & np.isfinite(hjj) & (hjj > 0)
    out[ok] = np.clip(1.0 / np.sqrt(hjj[ok]), 1e-4 * out[ok], 1e4 * out[ok])
    return out


def _lbfgs(fn, th, lo, hi, scale, maxiter: int = 3000, rounds: int = 3, rescale: bool = True):
    """L-BFGS-B of ``fn`` (value and gradient) from ``th`` inside [lo, hi], in variables scaled by the diagonal of
    the Hessian (:func:`_diag_scale`, ``scale`` where it fails): the raw posterior is so sharp (centre sd ~50 nm,
    log-axes ~1e-6) that a fixed scaling leaves L-BFGS-B's first steps thousands of nats uphill, after which it
    stops on its relative-reduction test. Up to ``rounds`` restarts (rescaled at the new point) until one gains
    < 1e-3 nat. ``rescale=False`` uses ``scale`` as it is. Returns (θ, value)."""
    from scipy.optimize import minimize

    best = float(fn(jnp.asarray(th))[0])
    for _ in range(rounds):
        sc = _diag_scale(fn, th, lo, hi, scale) if rescale else np.asarray(scale, float)
        t1 = th.copy()

        def obj(z, t1=t1, sc=sc):
            v, g = fn(jnp.asarray(t1 + z * sc))
            v, g = float(v), np.asarray(g) * sc
            if not (np.isfinite(v) and np.all(np.isfinite(g))):
                return 1e30, np.zeros_like(z)
            return v, g

        zb = list(zip((lo - t1) / sc, (hi - t1) / sc, strict=True))
        res = minimize(
            obj,
            np.zeros(t1.size),
            jac=True,
            method="L-BFGS-B",
            bounds=zb,
            options={"maxiter": maxiter, "ftol": 1e-15, "gtol": 1e-6},
        )
        if not res.fun < best:
            break
        th, gain = np.clip(t1 + res.x * sc, lo, hi), best - float(res.fun)
        best = float(res.fun)
        if gain < 1e-3:
            break
    return th, best


#: variable scales of the raw optimiser: 10 µm, 1e-4 (log axes), 1 mrad, 1e-4 (log n), 0.1 (log k), then
#: 1 µm (u, v), 1e-4 (log λ), 1e-4 rad (o), 0.1 (log σ_r)
_OPT_SCALE = np.concatenate(
    [np.full(3, 1e-5), np.full(3, 1e-4), np.full(3, 1e-3), [1e-4], [1e-1], [1e-6, 1e-6, 1e-4, 1e-4, 1e-1]]
)


class TextureStart(NamedTuple):
    """Result of :func:`initial_raw_texture`.

    theta : (16,) float
        The polished textured optimum.
    texture : RawTexture
    bounds : Bounds
        The prior box (16,).
    gain : float
        Log-posterior of the best grating (roughness at its floor) minus the bare shape's, both polished on the same
        data, nats: the evidence for a grating.
    candidates : list of (plane, wavelength m, orientation rad, statistic)
        :func:`search_texture`'s, in each principal plane (0: x–y, 1: x–z, 2: y–z, :func:`plane_theta`).
    neg_log_post : callable
        θ (16,) → (value, gradient) of the negative log-posterior (jitted), for :func:`laplace`.
    """

    theta: np.ndarray
    texture: RawTexture
    bounds: cm.Bounds
    gain: float
    candidates: list
    neg_log_post: object


def _reduce_psi(th: np.ndarray) -> np.ndarray:
    """ψ into [0, π) (the prior box): ψ + π flips the signs of the principal x and y axes, a symmetry of the
    centrally symmetric n-ellipsoid."""
    th = th.copy()
    th[7] = th[7] % np.pi
    return th


def canonical_theta(theta) -> np.ndarray:
    """θ (11,) with its n-ellipsoid in the canonical frame (a ≥ b ≥ c along x, y, z;
    :func:`bayestouch.geometry.compare.canonicalize`, ψ reduced into [0, π)): the same surface, so the same
    likelihood."""
    from bayestouch.geometry.compare import canonicalize_batch

    th = np.asarray(theta, float)[:11].copy()
    v = np.concatenate([th[:3], np.exp(th[3:6]), th[6:9], [np.exp(th[9])]])
    c = canonicalize_batch(v[None])[0]
    th[3:6], th[6:9] = np.log(c[3:6]), c[6:9]
    return _reduce_psi(th)


#: the principal planes a grating may lie in, as the proper signed permutations that make each the x–y plane:
#: (x, y), (x, z) and (y, z) of the canonical frame
_PLANES = (np.eye(3), np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]]))


def plane_theta(theta, plane: int) -> np.ndarray:
    """θ (11,) in the frame whose x–y plane is principal plane ``plane`` (0: x–y, 1: x–z, 2: y–z) of θ's frame: the
    same surface, the axes and rotation permuted (R' = R P, det P = 1)."""
    from bayestouch.geometry.rotation import euler_from_matrix

    th = np.asarray(theta, float)[:11].copy()
    P = _PLANES[plane]
    R = np.asarray(cm.shape_of(th).rotation) @ P
    perm = np.argmax(np.abs(P), axis=0)  # new axis j is old axis perm[j]
    th[3:6] = th[3:6][perm]
    th[6:9] = np.asarray(euler_from_matrix(jnp.asarray(R)))
    return _reduce_psi(th)


def laplace(neg_log_post, theta, lo, hi, scale) -> tuple[np.ndarray, np.ndarray]:
    """The Laplace approximation N(θ̂, H⁻¹) at the optimum ``theta`` (D,): its mean (D,) and covariance (D, D).

    H is :func:`_fd_hessian` of ``neg_log_post`` (value and gradient, as for L-BFGS-B) in the variables scaled by
    ``scale`` (steps of 1e-3 scaled units), symmetrised, with its eigenvalues floored at 1e-6 of the largest. On the
    standard scenario its sds are within 4 % of the sampled posterior's and its mean within 0.02 sd."""
    th = np.asarray(theta, float)
    H = scale[:, None] * _fd_hessian(neg_log_post, th, 1e-3 * scale, lo, hi) * scale[None, :]  # scaled variables
    H = 0.5 * (H + H.T)
    w, V = np.linalg.eigh(H)
    w = np.maximum(w, 1e-6 * max(w.max(), 1e-300))
    cov = (V / w) @ V.T * scale[:, None] * scale[None, :]
    return th, 0.5 * (cov + cov.T)


def laplace_ball(moments, lo, hi, walkers: int, rng: np.random.Generator) -> np.ndarray:
    """Walkers (W, D) drawn from the Laplace approximation ``moments`` = (mean, cov) of :func:`laplace`, clipped
    into the prior box [lo, hi]. Starting at the posterior's scale matters here: the raw posterior is ~100× narrower
    than any fixed ball (centre sd ~50 nm), and a ball too wide costs thousands of steps of burn-in."""
    mean, cov = moments
    w, V = np.linalg.eigh(cov)
    z = rng.normal(size=(walkers, len(mean))) * np.sqrt(np.maximum(w, 0.0))
    p = mean + z @ V.T
    return np.clip(p, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))


def initial_raw_texture(
    theta0,
    data: RawData,
    finger,
    priors: cm.PriorParams,
    tp: gr.TexturePriors,
    nu: float = STUDENT_NU,
    count: int = 5,
    seed: int = 0,
    polish: int = 6,
):
    """Textured start from the bare-shape estimate ``theta0`` (11,).

    1. The bare shape is polished on ``data`` (L-BFGS-B, :func:`_lbfgs`) and put in the canonical frame
       (:func:`canonical_theta`).
    2. Each principal plane (x–y, x–z, y–z) is searched for ``count`` grating candidates (:func:`search_texture` in
       the frame :func:`plane_theta` makes that plane its x–y plane): the grating's plane fixes the frame where
       the shape alone does not (the egg's b = c). The orientation is measured from the first axis of that plane.
    3. Each candidate's amplitude and phase (u, v) are the weighted least-squares fit of the forward model
       linearised in (u, v), with the noise multiplier k profiled out.
    4. The ``polish`` best are ranked by short L-BFGS-B runs over all parameters but the roughness (held at its
       floor): a few strokes leave aliases ~5–10 % apart in wavelength nearly as good, and the linearised ranking,
       done in a frame the grating's plane may be tilted from, can put one first. The best is polished to
       convergence; its gain over the polished bare shape is the evidence for a grating.
    5. The roughness variance :func:`roughness_variance` is computed there, and all 16 parameters are polished
       again from a roughness of a fifth of the amplitude.

    Returns
    -------
    TextureStart
    """
    # the bare shape polished on these data (θ₀ may come from other frames): its residuals then hold no first-order
    # shape misfit for the search to mistake for a grating, and its log-posterior is the baseline of the gain
    bare_b = raw_bounds(data, priors)
    bare_fn = jax.jit(jax.value_and_grad(lambda t: -raw_log_prob(t, data, finger, bare_b, nu)))
    theta0, f_bare = _lbfgs(
        bare_fn, canonical_theta(theta0), np.asarray(bare_b.lower), np.asarray(bare_b.upper), _OPT_SCALE[:11]
    )
    theta0 = canonical_theta(theta0)
    ref = texture_reference(data)
    frames = [plane_theta(theta0, p) for p in range(len(_PLANES))]
    cands = search_texture(theta0, data, finger, tp, nu, count, planes=range(len(_PLANES)))
    zero = RawTexture(ref, np.zeros(np.shape(data.log_current)), tp.amplitude_scale)
    pred0 = jax.jit(lambda t: predict_log_current(t, data, finger))(jnp.asarray(theta0))
    w = (1.0 / (np.exp(theta0[10]) * np.asarray(data.noise_sd)) ** 2).ravel()
    r = (np.asarray(data.log_current) - np.asarray(pred0)).ravel()  # the textured prediction at u = v = 0

    @jax.jit
    def jac_uv(th):  # ∂ ln I / ∂(u, v) at u = v = 0, (F, M, 2)
        return jax.jacfwd(lambda uv: predict_log_current(th.at[11:13].set(uv), data, finger, zero))(jnp.zeros(2))

    value = jax.jit(lambda t, b, tex: raw_log_prob(t, data, finger, b, nu, tex))

    def profile_k(th, b, tex):  # max over the noise multiplier log k of the log-posterior at θ's other entries
        from scipy.optimize import minimize_scalar

        def neg(lk):
            return -float(value(jnp.asarray(th).at[10].set(lk), b, tex))

        res = minimize_scalar(
            neg, bounds=(float(b.lower[10]), float(b.upper[10])), method="bounded", options={"xatol": 1e-3}
        )
        return -float(res.fun), float(res.x)

    ranked = []
    for p, lam, o, _ in cands:
        b = textured_bounds(data, priors, tp, o)
        th = np.concatenate([frames[p], [0.0, 0.0, np.log(lam), o, np.log(tp.roughness_min)]])
        X = np.asarray(jac_uv(jnp.asarray(th))).reshape(-1, 2)
        uv = np.linalg.lstsq(X.T @ (w[:, None] * X), X.T @ (w * r), rcond=None)[0]
        th[11:13] = np.clip(uv, np.asarray(b.lower)[11:13], np.asarray(b.upper)[11:13])
        val, th[10] = profile_k(th, b, zero)
        ranked.append((val, th, b))
    ranked.sort(key=lambda x: -x[0])
    # the linearised ranking can put an alias first: a few strokes leave wavelengths ~5–10 % apart nearly as good
    # while the grating's plane is tilted from the search frame's (the egg's frame is fixed about its long axis only
    # to ~4° by four strokes). Short L-BFGS-B runs (roughness at its floor, all else free) from the ``polish`` best
    # rank them; the best is polished to convergence.
    # one compiled program for every box and both roughness models (b and tex are arguments, not constants)
    fn_any = jax.jit(jax.value_and_grad(lambda t, b, tex: -raw_log_prob(t, data, finger, b, nu, tex)))
    fn0 = partial(fn_any, tex=zero)

    def floored(b):  # the box with the roughness held at its floor
        lo, hi = np.array(b.lower), np.array(b.upper)
        hi[15] = lo[15]
        return lo, hi

    sc = None
    best = None
    for _, th, b in ranked[:polish]:
        lo, hi = floored(b)
        sc = _diag_scale(partial(fn0, b=b), th, lo, hi, _OPT_SCALE) if sc is None else sc
        th, f = _lbfgs(partial(fn0, b=b), th, lo, hi, sc, maxiter=25, rounds=1, rescale=False)
        if best is None or -f > best[0]:
            best = (-f, th, b)
    _, th, b = best
    th, f = _lbfgs(partial(fn0, b=b), th, *floored(b), _OPT_SCALE)
    gain = f_bare - f  # the evidence for the grating: against the bare shape polished on the same data
    lo, hi = np.array(b.lower), np.array(b.upper)
    tex = zero._replace(rough_var=roughness_variance(th, data, finger, zero, seed=seed))
    th[15] = np.clip(np.log(max(np.hypot(th[11], th[12]) / 5.0, tp.roughness_min * 10)), lo[15], hi[15])
    fn = partial(fn_any, b=b, tex=tex)
    th, _ = _lbfgs(fn, th, lo, hi, _OPT_SCALE)
    return TextureStart(th, tex, b, gain, cands, fn)


def _natural(flat: np.ndarray) -> np.ndarray:
    """θ draws (S, 11) or (S, 16) → canonicalised natural parameters: centre, a ≥ b ≥ c, angles, n, k (the contact
    level's transform: the 11th column, log k here, is exponentiated like log σ there), then the texture's
    amplitude, wavelength, orientation, phase and roughness (:func:`bayestouch.inference.grating.texture_natural`)."""
    from bayestouch.inference.run import natural_draws as contact_natural

    nat = contact_natural(flat[:, :11])
    return nat if flat.shape[1] == 11 else np.column_stack([nat, gr.texture_natural(flat)])


#: block length of the curvature adjustment, seconds of recording: longer than the roughness's and the lag's
#: correlation (~2 mm of travel at 1 cm/s), short enough for ≥ 3 blocks per parameter
ADJUST_BLOCK_S = 0.2


class Adjustment(NamedTuple):
    """The curvature adjustment of :func:`curvature_adjustment`: draws θ ↦ mean + (θ − mean) Cᵀ.

    mean : (D,) float
    C : (D, D) float
    info : dict
        Written as ``summary["model"]["adjustment"]``.
    """

    mean: np.ndarray
    C: np.ndarray
    info: dict

    def __call__(self, flat: np.ndarray) -> np.ndarray:
        return self.mean + (np.asarray(flat) - self.mean) @ self.C.T


def curvature_adjustment(
    flat,
    data: RawData,
    finger,
    nu: float = STUDENT_NU,
    texture: RawTexture | None = None,
    block_s: float = ADJUST_BLOCK_S,
):
    """The sandwich (Godambe) correction of the posterior of an independence likelihood, as the curvature adjustment
    of Ribatet, Cooley & Davison (2012, Statistica Sinica 22, 813–845).

    The likelihood treats every reading as independent, but the 1/f noise, the response lag and above all the
    surface's unmodelled roughness correlate neighbouring frames: the posterior is then far too narrow (on the
    standard scenario the true volume lies ~30 posterior sds from the mean). With H⁻¹ ≈ Σ the posterior covariance of
    the draws ``flat (N, D)`` and J the covariance of the score summed over blocks of ``block_s`` seconds within each
    stroke (their sums nearly independent), the asymptotically right covariance is Σ J Σ (the inverse Godambe
    information); draws are mapped affinely, θ ↦ θ̄ + C(θ − θ̄), C = chol(ΣJΣ) chol(Σ)⁻¹, so their covariance becomes
    Σ J Σ while the mean and the shape of the posterior stay. Measured on the standard scenario (textured egg, 10
    strokes): sds grow 6–18×, the volume's z-score falls from 30 to 2.1 (blocks of 0.1, 0.2, 0.4, 0.8 s: 2.5, 2.1,
    2.9, 3.2). Blocks are shortened to keep ≥ 3 per parameter.

    Returns
    -------
    Adjustment, or None when Σ or ΣJΣ is not positive definite (the draws are then left as they are).
    """
    flat = np.asarray(flat, float)
    D = flat.shape[1]
    mean = flat.mean(axis=0)
    S = np.cov(flat.T)
    G = np.asarray(
        jax.jit(jax.jacfwd(lambda t: jnp.sum(raw_pointwise(t, data, finger, nu, texture), axis=1)))(jnp.asarray(mean))
    )  # (F, D): the score of each frame
    starts = np.flatnonzero(np.asarray(data.start))
    ends = np.append(starts[1:], len(G))
    L = max(1, int(round(block_s / float(data.dt))))
    while L > 1 and sum(-(-(e - s) // L) for s, e in zip(starts, ends, strict=True)) < 3 * D:
        L -= 1
    blocks = np.array(
        [G[i : min(i + L, e)].sum(axis=0) for s, e in zip(starts, ends, strict=True) for i in range(s, e, L)]
    )
    blocks -= blocks.mean(axis=0)
    J = blocks.T @ blocks * len(blocks) / max(len(blocks) - 1, 1)
    try:
        Ls = np.linalg.cholesky(S)
        C = np.linalg.cholesky(S @ J @ S) @ np.linalg.inv(Ls)
    except np.linalg.LinAlgError:
        return None
    Sa = S @ J @ S
    info = {
        "method": "curvature adjustment to the sandwich covariance (Ribatet, Cooley & Davison 2012)",
        "block_s": L * float(data.dt),
        "blocks": int(len(blocks)),
        "sd_ratio": [float(r) for r in np.sqrt(np.diag(Sa) / np.diag(S))],
    }
    return Adjustment(mean, C, info)


def raw_model(
    data: RawData,
    finger,
    nu: float = STUDENT_NU,
    texture: RawTexture | None = None,
    info: dict | None = None,
    adjust: Adjustment | None = None,
):
    """The raw-current level as a :class:`~bayestouch.inference.run.PosteriorModel`: pointwise log-likelihood per
    selected frame (summed over its taxels: per reading would make posterior.nc ~200 MB for 10 strokes); the
    observed data are the corrected ln I (F, M), and the posterior predictive replicates them (float32, for
    :data:`RAW_PREDICTIVE_DRAWS` draws only: 7 MB on the standard scenario) with the Student-t reading noise.
    ``info`` is merged into the model description; ``adjust`` (:func:`curvature_adjustment`) maps the draws before
    every summary, the posterior group and the log-likelihood (``chain.h5`` keeps emcee's draws as sampled)."""
    from bayestouch.inference.posterior import PosteriorModel

    pw = jax.jit(jax.vmap(lambda t: jnp.sum(raw_pointwise(t, data, finger, nu, texture), axis=1)))

    adj = adjust if adjust is not None else (lambda flat: flat)

    def ll(thetas):
        thetas = adj(thetas)
        return np.concatenate(
            [np.asarray(pw(jnp.asarray(c))) for c in np.array_split(thetas, max(1, len(thetas) // 64))]
        )

    one = jax.jit(jax.vmap(lambda t: (predict_log_current(t, data, finger, texture), _scale(t, data, texture, nu))))

    def predictive(thetas, rng: np.random.Generator):
        reps = []
        for c in np.array_split(adj(thetas), max(1, len(thetas) // 32)):
            mu, sc = (np.asarray(a) for a in one(jnp.asarray(c)))
            reps.append((mu + sc * rng.standard_t(nu, size=mu.shape)).astype(np.float32))
        return {"log_current": np.concatenate(reps)}

    F, M = np.shape(data.log_current)
    names = RAW_PARAM_NAMES if texture is None else RAW_TEXTURE_PARAM_NAMES
    desc = {
        "level": "raw-current",
        "mode": data.mode,
        "likelihood": f"Student-t, nu = {nu:g}, scale {t_scale_factor(nu):.3f} x the sd below (the t that fits "
        "Gaussian readings best), per taxel-frame reading; pointwise log-likelihood per frame (summed over its taxels)",
        "noise_model": "ln I corrected by fixed-pattern gains and reference-row common drift; sd² = white(shot+"
        "amplifier+ADC)/I² + stationary 1/f + local random walk + reference-mean variance; "
        f"times k (sampled, prior log k ~ N(0, {LOG_K_PRIOR_SD:g}))"
        + ("" if texture is None else "; plus roughness² × its Monte-Carlo response variance"),
        "frames_used": int(F),
        "frame_interval_s": float(data.dt),
        "taxels_used": int(M),
        "readings": int(F * M),
        "texture": "not sampled (bare n-ellipsoid)"
        if texture is None
        else (
            "sampled: grating u sin(2 pi s / wavelength) + v cos(2 pi s / wavelength), s = (foot - reference) . "
            "(cos orientation, sin orientation, 0) in the sampled principal frame; amplitude = hypot(u, v), phase = "
            "atan2(v, u) at the reference point; roughness RMS as a variance term"
        ),
        "parameters_sampled": list(names),
    }
    if texture is not None:
        desc["texture_reference_m"] = [float(v) for v in texture.ref]
    desc["adjustment"] = adjust.info if adjust is not None else "none: intervals assume independent readings"
    return PosteriorModel(
        RAW_NATURAL_NAMES if texture is None else RAW_TEXTURE_NATURAL_NAMES,
        lambda flat: _natural(adj(flat)),
        lambda nat: nat[:, :10],
        ll,
        predictive,
        {"log_current": np.asarray(data.log_current)},
        {**desc, **(info or {})},
        checks=partial(_raw_warnings, textured=texture is not None),
        predictive_draws=RAW_PREDICTIVE_DRAWS,
    )


#: noise multiplier k above which a raw fit's summary warns that the model does not fit the readings
MISFIT_K = 3.0


def misfit_warnings(summary: dict, textured: bool = False) -> list[str]:
    """Warnings of a raw-current fit: the posterior mean of the noise multiplier k above :data:`MISFIT_K` says
    the residuals are k times the modelled read-out noise — a forward model that misses something (a texture that
    is not modelled, the lag approximated on coarse frames). Without the curvature adjustment the shape intervals,
    computed as if the model were right, are then too narrow (standard scenario without the texture: k ≈ 9.6, the
    true volume ~6 sds from the mean); with it (the default) they are widened for the correlated residuals, and the
    warning says that a systematic misfit may still bias them (``benchmarks/bench_raw.py``)."""
    k = float(summary["parameters"]["noise_scale"]["mean"])
    if k <= MISFIT_K:
        return []
    why = (
        "the lag is approximated on coarse frames (try a smaller stride)"
        if textured
        else ("the texture is not modelled (try texture='on'); the lag is approximated on coarse frames")
    )
    adjusted = isinstance(summary.get("model", {}).get("adjustment"), dict)
    tail = (
        "the sandwich adjustment widens the intervals for correlated residuals, but a systematic misfit can "
        "still bias them"
        if adjusted
        else "the intervals assume the model is right and are likely too narrow"
    )
    return [
        f"noise_scale k = {k:.1f} > {MISFIT_K:g}: the residuals are {k:.0f}x the modelled read-out noise, so the "
        f"forward model misses part of the signal ({why}); {tail}"
    ]


def _raw_warnings(summary: dict, textured: bool = False) -> list[str]:
    """:func:`misfit_warnings`, and a warning when a draw came within :data:`PRUNE_CHECK` of a taxel slot the
    sampler left out (``summary.model.pruning``, :func:`prune_clearance`)."""
    out = misfit_warnings(summary, textured)
    pr = summary.get("model", {}).get("pruning")
    if isinstance(pr, dict) and not pr.get("exact", True):
        out.append(
            f"a posterior draw came {pr['min_clearance_m']:.2g} m from a taxel left out as clear of the "
            f"surface (margin {pr['margin_m']:g} m): the sampled likelihood may be inexact; rerun with "
            "run_raw_fit(..., prune=False)"
        )
    return out


def _contact_points(ds, frames):
    return np.asarray(ds["contact_point"].values, float)[frames]


#: log-posterior gain (nats) of the best grating over the bare shape above which texture="auto" models the texture.
#: The maximum of N independent χ²₂/2 gains is ≈ ln N ≈ 12 nats for the ~10⁵ wave vectors searched; on the
#: untextured egg, whose residuals are not white (1/f noise, lag approximation), the best grating gains ~25–50;
#: on the textured egg thousands
DETECT_NATS = 100.0
#: frame strides: with the texture modelled (its readings vary within 0.1 s, which the coarse-frame lag does not
#: follow: robust residual sd 1.3 s at stride 2 and 4.4 s at stride 5 at the truth), and without
TEXTURE_STRIDE = 2
BARE_STRIDE = 5
#: degrees of freedom of the raw fit's independence proposal (:func:`bayestouch.inference.sampler.adaptive_moves`):
#: the raw posterior is close to Gaussian (10⁵ readings), and in 16 dimensions a t proposal matched to a Gaussian
#: target is accepted at most ~70 % of the time with ν = 10, ~85 % with ν = 30 (its tails stay heavier than the
#: target's, so π/g stays bounded)
RAW_PROPOSAL_NU = 30.0


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
    stride: int | None = None,
    radius: float = 4.5e-3,
    strokes=None,
    models: Path = MODELS,
    starts: int = 4,
    stop_when_converged: bool = True,
    texture: str = "auto",
    adjust: bool = True,
    prune: bool = True,
) -> dict:
    """Sample the raw-current posterior of a recording and write the run folder ``out``.

    Parameters
    ----------
    recording : path or xarray.Dataset
    out : path
        Run folder (``chain.h5``, ``summary.json``, ``posterior.nc``, meshes).
    seed : int
        Seeds the initial fit, the roughness Monte Carlo, the walkers and emcee.
    walkers, steps : int
    resume : bool
        Continue the chain in ``out/chain.h5`` (the start, texture search included, is deterministic given the
        seed, so the same model is rebuilt).
    budget_s : float, seconds, optional
        Stop sampling after this wall-clock time.
    stride : int, optional
        Frame stride of :func:`load_raw_data`; default :data:`TEXTURE_STRIDE` when the texture is modelled,
        :data:`BARE_STRIDE` otherwise.
    radius, strokes, models
        See :func:`load_raw_data`.
    starts : int
        Number of DE starts of :func:`initial_raw_theta`.
    stop_when_converged : bool
        Stop before ``steps`` once converged (:func:`bayestouch.inference.sampler.sample`). Sampling is adaptive
        (``sample(..., adapt=True)``, as :func:`bayestouch.inference.run.run_contact_fit`).
    texture : {"auto", "on", "off"}
        Sample the texture (grating and roughness, :mod:`bayestouch.inference.grating`): "on" always, "off" never
        (the bare n-ellipsoid), "auto" when the best grating found by :func:`initial_raw_texture` gains more than
        :data:`DETECT_NATS` of log-posterior over the bare shape.
    adjust : bool
        Widen the posterior to the sandwich covariance (:func:`curvature_adjustment`): the likelihood treats
        correlated readings as independent. ``False`` gives the independence posterior as sampled.
    prune : bool
        Sample without the taxel slots more than :data:`PRUNE_MARGIN` outside the start's surface
        (:func:`prune_clear`), checked on the draws afterwards (``summary.model.pruning``).

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    from bayestouch.inference.posterior import write_posterior
    from bayestouch.inference.sampler import adaptive_moves, sample

    if texture not in ("auto", "on", "off"):
        raise BadInput(f"texture must be one of auto, on, off; got {texture!r}")
    if stride is not None and int(stride) < 1:
        raise BadInput(f"stride must be an integer ≥ 1, got {stride}")
    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if isinstance(recording, str | Path):
        from bayestouch.io.recording import read_recording

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
    priors = cm.load_priors()
    # the bare shape: DE on the commanded contact points, then L-BFGS-B on the raw posterior at the coarse stride
    bare_stride = BARE_STRIDE if stride is None or texture != "off" else int(stride)
    bare_data, finger = load_raw_data(ds, models=models, stride=bare_stride, radius=radius, strokes=strokes)
    th0 = initial_raw_theta(
        bare_data,
        finger,
        _contact_points(ds, bare_data.frames),
        seed,
        priors,
        raw_bounds(bare_data, priors),
        starts=starts,
    )
    data, tex, info = bare_data, None, {}
    if texture != "off":
        data, _ = load_raw_data(
            ds, models=models, stride=stride or TEXTURE_STRIDE, radius=radius, strokes=strokes, finger=finger
        )
        tp = gr.load_texture_priors()
        ts = initial_raw_texture(th0, data, finger, priors, tp, seed=seed)
        planes = ("x-y", "x-z", "y-z")
        info = {
            "texture_search": {
                "candidates": [
                    {"plane": planes[p], "wavelength_m": lam, "orientation_rad": o, "statistic": st}
                    for p, lam, o, st in ts.candidates
                ],
                "grating_gain_nats": ts.gain,
                "detect_nats": DETECT_NATS,
                "requested": texture,
            }
        }
        if texture == "on" or ts.gain > DETECT_NATS:
            tex, th_start, bounds, nlp = ts.texture, ts.theta, ts.bounds, ts.neg_log_post
        elif stride is None:
            data = bare_data
    if tex is None:
        th_start = th0
    if prune:
        data = prune_clear(data, th_start, tex)
    if tex is None:
        bounds = raw_bounds(data, priors)
        nlp = jax.jit(jax.value_and_grad(lambda t: -raw_log_prob(t, data, finger, bounds)))
    logp, _, names = make_raw_log_prob(data, finger, priors, texture=tex, bounds=bounds)
    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    # the Laplace approximation starts the walkers and is the first independence proposal (deterministic given the
    # seed, so a resumed run rebuilds it)
    moments = laplace(nlp, th_start, lo, hi, _OPT_SCALE[: len(names)])
    ch = sample(
        logp,
        lambda: laplace_ball(moments, lo, hi, walkers, np.random.default_rng(seed)),
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
        proposal=moments,
        moves=adaptive_moves(RAW_PROPOSAL_NU),
        monitor=_natural,
    )
    flat = ch.kept.reshape(-1, ch.kept.shape[2])
    if prune:
        info["pruning"] = prune_clearance(flat[:: max(1, len(flat) // 256)], data, tex)
    adjust = curvature_adjustment(flat, data, finger, texture=tex) if adjust else None
    return write_posterior(out, ch, raw_model(data, finger, texture=tex, info=info, adjust=adjust), seed=seed, t0=t0)
