"""The raw-current fit: the bare-shape start θ (11,) from the commanded contact points, the level's
:class:`~bayestouch.inference.posterior.PosteriorModel` (natural parameters, pointwise log-likelihood per frame,
posterior predictive ln I (F, M)), its warnings, and :func:`run_raw_fit`, which samples the posterior of a recording
and writes the run folder. The model: ``docs/raw_model.md``.
"""

from __future__ import annotations

import os
import time
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jnp, pad_pow2, release_compiled
from bayestouch.errors import BadInput, check_path
from bayestouch.inference import contact as cm
from bayestouch.inference import grating as gr
from bayestouch.inference.densities import t_scale_factor
from bayestouch.inference.grating import RawTexture
from bayestouch.inference.optimize import laplace, laplace_ball, scaled_lbfgs
from bayestouch.inference.posterior import PosteriorModel, judged_quantities, write_posterior
from bayestouch.inference.raw.adjustment import OUTSIDE_PRIOR_WARN, Adjustment, curvature_adjustment
from bayestouch.inference.raw.data import (
    RawData,
    check_contact_motion,
    check_full_scale,
    check_stroke_selection,
    check_taxel_layout,
    commanded_points,
    host_device,
    load_raw_data,
    need_variable,
    on_device,
    open_recording,
    recording_mode,
)
from bayestouch.inference.raw.likelihood import (
    LOG_K_PRIOR_SD,
    RAW_OPT_SCALE,
    STUDENT_NU,
    frame_log_lik_batch,
    make_raw_log_prob,
    nuisance_estimates,
    opt_scale,
    prune_clear,
    prune_clearance,
    raw_bounds,
    raw_names,
    raw_objective,
    readings_batch,
    with_lag_bounds,
    with_nuisance_fixed,
)
from bayestouch.inference.raw.priors import LAG_RANGE
from bayestouch.inference.raw.texture import initial_raw_texture
from bayestouch.inference.run import initial_theta, natural_draws
from bayestouch.inference.sampler import adaptive_moves, sample
from bayestouch.io.device_file import DeviceCalibration, read_device_file
from bayestouch.io.runfolder import dataset_digest, fingerprint, prepare_run_folder, release_run_folder
from bayestouch.params import MODELS

__all__ = [
    "initial_raw_theta",
    "raw_polisher",
    "texture_start",
    "NUISANCE_ROUNDS",
    "raw_model",
    "RAW_PREDICTIVE_DRAWS",
    "MISFIT_K",
    "misfit_warnings",
    "DETECT_NATS",
    "TEXTURE_STRIDE",
    "BARE_STRIDE",
    "RAW_PROPOSAL_NU",
    "LAG_RESTART",
    "run_raw_fit",
]

#: rounds of the start's polish with the marginalised device terms fixed at their posterior means
#: (:func:`initial_raw_theta`)
NUISANCE_ROUNDS = 2
#: draws in a raw fit's posterior predictive group (each replicates all F × M readings)
RAW_PREDICTIVE_DRAWS = 32
#: units of the raw level's natural parameters and data (``posterior.nc``'s ``units`` attributes; ln I is of I in A)
RAW_UNITS = {
    **dict.fromkeys(("x_G", "y_G", "z_G", "a", "b", "c", "amplitude", "wavelength", "roughness"), "m"),
    **dict.fromkeys(("xi", "psi", "zeta", "orientation", "phase"), "rad"),
    **dict.fromkeys(("n", "noise_scale"), "1"),
    "lag": "s",
    "log_current": "ln(A)",
}


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
    by the diagonal of the Hessian and restarted until it stops gaining
    (:func:`~bayestouch.inference.optimize.scaled_lbfgs`). With few strokes the surface patches leave the global
    shape multimodal, so ``starts`` DE fits (seeds 1000·seed + k) are polished and the best log-posterior wins.
    """
    polish = raw_polisher(data, finger, bounds, nu)
    best_th, best_f = None, np.inf
    for k in range(starts):
        th = initial_theta(contact_points, int(seed) * 1000 + k, priors, starts=1)
        th[10] = np.log(30.0)
        th, val = polish(th)
        if val < best_f:
            best_th, best_f = th, val
    return best_th


def raw_polisher(data: RawData, finger, bounds: cm.Bounds, nu: float = STUDENT_NU):
    """The bare shape's polish on the raw log-posterior of ``data``: a function θ (11,) → (θ polished, its negative
    log-posterior), L-BFGS-B in scaled variables (:func:`~bayestouch.inference.optimize.scaled_lbfgs`).

    With the device terms marginalised the log-posterior is rugged (the readings' levels no longer pin the size):
    θ is polished first with them fixed at their posterior means at θ, a known device's smooth landscape, and
    re-estimated there (:data:`NUISANCE_ROUNDS` rounds), then on the marginal log-posterior itself."""
    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    data = on_device(data)
    marginal = data.gain_sd is not None or data.response_sd is not None
    fn = raw_objective(data, finger, bounds, nu=nu)

    def polish(th):
        th = np.clip(np.asarray(th, float), lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
        for _ in range(NUISANCE_ROUNDS if marginal else 0):
            fixed = with_nuisance_fixed(data, *nuisance_estimates(th, data, finger, nu))
            th, _ = scaled_lbfgs(raw_objective(fixed, finger, bounds, nu=nu), th, lo, hi, RAW_OPT_SCALE[:11])
        th, _ = scaled_lbfgs(fn, th, lo, hi, RAW_OPT_SCALE[:11])
        return th, float(fn(jnp.asarray(th))[0])

    return polish


def texture_start(th0, data: RawData, finger, priors: cm.PriorParams, tp: gr.TexturePriors, seed: int = 0):
    """:func:`~bayestouch.inference.raw.texture.initial_raw_texture` from the bare start ``th0`` (11,) on the
    known-device landscape — the marginalised device terms fixed at their posterior means at ``th0``
    (:func:`~bayestouch.inference.raw.likelihood.with_nuisance_fixed`), where the grating search and its evidence
    (``gain``, compared with :data:`DETECT_NATS`) behave as with a known device — then the textured start polished
    with the device terms marginalised again. Returns the :class:`~bayestouch.inference.raw.texture.TextureStart`."""
    fixed = with_nuisance_fixed(data, *nuisance_estimates(th0, data, finger))
    ts = initial_raw_texture(th0, fixed, finger, priors, tp, seed=seed)
    if data.gain_sd is None and data.response_sd is None:
        return ts
    fn = raw_objective(data, finger, ts.bounds, ts.texture)
    lo, hi = np.asarray(ts.bounds.lower), np.asarray(ts.bounds.upper)
    th, _ = scaled_lbfgs(fn, ts.theta, lo, hi, RAW_OPT_SCALE)
    return ts._replace(theta=th, neg_log_post=fn)


def _natural(flat: np.ndarray, textured: bool, lag: bool = False) -> np.ndarray:
    """θ draws (S, D) → canonicalised natural parameters: centre, a ≥ b ≥ c, angles, n, k (the contact level's
    transform: the 11th column, log k here, is exponentiated like log σ there), then with ``textured`` the texture's
    amplitude, wavelength, orientation, phase and roughness (:func:`bayestouch.inference.grating.texture_natural`),
    then with ``lag`` the sampled lag τ (s)."""
    flat = np.asarray(flat, float)
    cols = [natural_draws(flat[:, :11])]
    if textured:
        cols.append(gr.texture_natural(flat))
    if lag:
        cols.append(np.exp(flat[:, -1:]))
    return np.column_stack(cols)


def _blocks(thetas, size: int):
    """Draws ``thetas (S, D)`` in blocks of ``size`` rows, the last padded to ``size`` (:func:`pad_pow2`; ``size``
    a power of two), so that one compiled program serves every chain length: yields (block (size, D), its real
    rows)."""
    for i in range(0, len(thetas), size):
        c = thetas[i : i + size]
        yield jnp.asarray(pad_pow2(c, min_size=size)), len(c)


def raw_model(
    data: RawData,
    finger,
    nu: float = STUDENT_NU,
    texture: RawTexture | None = None,
    info: dict | None = None,
    adjust: Adjustment | None = None,
):
    """The raw-current level as a :class:`~bayestouch.inference.posterior.PosteriorModel`: pointwise log-likelihood per
    selected frame (summed over its taxels: per reading would make posterior.nc ~200 MB for 10 strokes); the
    observed data are the corrected ln I (F, M), and the posterior predictive replicates them (float32, for
    :data:`RAW_PREDICTIVE_DRAWS` draws only: 7 MB on the standard scenario) with the Student-t reading noise.
    ``info`` is merged into the model description; ``adjust`` (:func:`curvature_adjustment`) maps the draws before
    every summary, the posterior group and the log-likelihood (``chain.h5`` keeps emcee's draws as sampled)."""
    data = on_device(data)

    adj = adjust if adjust is not None else (lambda flat: flat)

    def ll(thetas):
        per_frame = [
            np.asarray(frame_log_lik_batch(c, data, finger, texture, nu=nu))[:n] for c, n in _blocks(adj(thetas), 64)
        ]
        return {"log_current": np.concatenate(per_frame)}

    def predictive(thetas, rng: np.random.Generator):
        reps = []
        for c, n in _blocks(adj(thetas), 32):
            mu, sc = (np.asarray(a)[:n] for a in readings_batch(c, data, finger, texture, nu=nu))
            reps.append((mu + sc * rng.standard_t(nu, size=mu.shape)).astype(np.float32))
        return {"log_current": np.concatenate(reps)}

    F, M = np.shape(data.log_current)
    lag = data.lag_prior is not None
    names = raw_names(texture is not None, lag)
    desc = {
        "level": "raw-current",
        "mode": data.mode,
        "likelihood": f"Student-t, nu = {nu:g}, scale {t_scale_factor(nu):.3f} x the sd below (the t that fits "
        "Gaussian readings best), per taxel-frame reading; pointwise log-likelihood per frame (summed over its taxels)",
        "noise_model": "ln I corrected by fixed-pattern gains and reference-row common drift; sd² = white(shot+"
        "amplifier+ADC)/I² + stationary 1/f + local random walk + reference-mean variance; "
        f"times k (sampled, prior log k ~ N(0, {LOG_K_PRIOR_SD:g}))"
        + ("" if texture is None else "; plus roughness² × its Monte-Carlo response variance"),
        "gains": "known exactly (given with the finger)"
        if data.gain_sd is None
        else "each taxel's remaining log-gain marginalised, prior sd "
        f"{float(np.median(data.gain_sd)):.3g} (median over taxels; "
        + str((info or {}).get("calibration", "no calibration: unit gains, the nominal spread of models/noise.toml"))
        + ")",
        "response": "exact (the models' constants)"
        if data.response_sd is None
        else f"the taxels' common response factor on Δ ln I marginalised, N({data.response_scale:.4g}, "
        f"{data.response_sd:.3g}²)",
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
        "lag": f"sampled: log tau, uniform in tau on [{data.lag_prior[0]:g}, {data.lag_prior[1]:g}] s"
        if lag
        else f"known: the finger's {float(finger.taxels.lag):.4g} s",
    }
    if texture is not None:
        desc["texture_reference_m"] = [float(v) for v in texture.ref]
    desc["adjustment"] = adjust.info if adjust is not None else "none: intervals assume independent readings"
    return PosteriorModel(
        raw_names(texture is not None, lag, natural=True),
        lambda flat: _natural(adj(flat), texture is not None, lag),
        lambda nat: nat[:, :10],
        ll,
        predictive,
        {"log_current": np.asarray(data.log_current)},
        {**desc, **(info or {})},
        checks=partial(_raw_warnings, textured=texture is not None),
        predictive_draws=RAW_PREDICTIVE_DRAWS,
        dims={"log_current": ("frame", "taxel")},
        units=RAW_UNITS,
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


def adjustment_warnings(summary: dict) -> list[str]:
    """A warning when the curvature adjustment put more than :data:`OUTSIDE_PRIOR_WARN` of the draws outside the
    prior box (``summary.model.adjustment.outside_prior``): the strokes do not determine the shape, and the
    intervals of the parameters held at the box's faces are the prior's, not the data's."""
    adj = summary.get("model", {}).get("adjustment")
    share = adj.get("outside_prior", 0.0) if isinstance(adj, dict) else 0.0
    if share <= OUTSIDE_PRIOR_WARN:
        return []
    worst = max(adj.get("sd_ratio", [1.0]))
    return [
        f"the sandwich adjustment (sds up to {worst:.1f}x wider) put {100 * share:.0f} % of the draws outside the "
        "prior box, where they are held at its faces: these strokes do not determine the shape, and the intervals "
        "that reach the box are the prior's, not the data's"
    ]


def _raw_warnings(summary: dict, textured: bool = False) -> list[str]:
    """:func:`misfit_warnings`, and a warning when a draw came within :data:`PRUNE_CHECK` of a taxel slot the
    sampler left out (``summary.model.pruning``, :func:`prune_clearance`)."""
    out = misfit_warnings(summary, textured) + adjustment_warnings(summary)
    pr = summary.get("model", {}).get("pruning")
    if isinstance(pr, dict) and not pr.get("exact", True):
        out.append(
            f"a posterior draw came {pr['min_clearance_m']:.2g} m from a taxel left out as clear of the "
            f"surface (margin {pr['margin_m']:g} m): the sampled likelihood may be inexact; rerun from Python with "
            "bayestouch.run_raw_fit(..., prune=False) (every taxel kept; the command line has no switch for it)"
        )
    return out


#: log-posterior gain (nats) of the best grating over the bare shape above which texture="auto" models the texture.
#: The maximum of N independent χ²₂/2 gains is ≈ ln N ≈ 12 nats for the ~10⁵ wave vectors searched; on the
#: untextured egg, whose residuals are not white (1/f noise, lag approximation), the best grating gained ~25–50
#: with the simulator's own gains, and 160–190 (a sub-millimetre grating of < 1 µm and the roughness variance
#: taking up misfit) with the gains estimated from the data (4 strokes, tests/test_raw_texture.py); on the
#: textured egg ~19,000 (4 strokes) and ~33,000 (10 strokes)
DETECT_NATS = 400.0
#: frame strides: with the texture modelled (its readings vary within 0.1 s, which the coarse-frame lag does not
#: follow: robust residual sd 1.3 s at stride 2 and 4.4 s at stride 5 at the truth), and without
TEXTURE_STRIDE = 2
BARE_STRIDE = 5
#: degrees of freedom of the raw fit's independence proposal (:func:`bayestouch.inference.sampler.adaptive_moves`):
#: the raw posterior is close to Gaussian (10⁵ readings), and in 16 dimensions a t proposal matched to a Gaussian
#: target is accepted at most ~70 % of the time with ν = 10, ~85 % with ν = 30 (its tails stay heavier than the
#: target's, so π/g stays bounded)
RAW_PROPOSAL_NU = 30.0


#: with the lag sampled, the start is made again at the lag its polish reached when that lies more than this far
#: from the lag the start assumed (in log τ: 5 %, a quarter of the lag range's half-width)
LAG_RESTART = 0.05


class _StartSetup(NamedTuple):
    """What every start of :func:`run_raw_fit` reads: the recording and the run's options."""

    ds: object
    models: Path
    stride: int | None
    radius: float
    strokes: object
    cal: DeviceCalibration | None
    texture: str
    seed: int
    starts: int
    prune: bool
    sampled: bool


class _Start(NamedTuple):
    """One start of :func:`run_raw_fit`: the data to sample (pruned), the finger, the bare shape θ₀ (11,), the
    texture (None: bare), the start θ with its prior box and jitted negative log-posterior (value, gradient), the
    texture search's record, and with a sampled lag the negative log-posterior at θ (``objective``, nats)."""

    data: RawData
    finger: object
    th0: np.ndarray
    texture: RawTexture | None
    theta: np.ndarray
    bounds: cm.Bounds
    nlp: object
    search: dict | None
    objective: float | None


def _raw_start(setup: _StartSetup, host, priors: cm.PriorParams, th0=None) -> _Start:
    """The start on the finger ``host`` (its lag the one assumed where the lag is sampled): the bare shape (``th0``
    polished on this finger, or :func:`initial_raw_theta`'s DE starts), the texture search (:func:`texture_start`),
    the data pruned at the start, and with a sampled lag log τ appended and polished with the rest."""
    s = setup
    finger = host.finger
    # the bare shape at the coarse stride (coarse for speed, never coarser than a stride the user gave: a short
    # recording may need every frame)
    bare_stride = (
        BARE_STRIDE if s.stride is None else int(s.stride) if s.texture == "off" else min(BARE_STRIDE, int(s.stride))
    )
    dev = {"device": host, "calibration": s.cal}
    bare_data, _ = load_raw_data(s.ds, models=s.models, stride=bare_stride, radius=s.radius, strokes=s.strokes, **dev)
    bare_bounds = raw_bounds(bare_data, priors)
    if th0 is None:
        points = commanded_points(s.ds, bare_data.frames)
        th0 = initial_raw_theta(bare_data, finger, points, s.seed, priors, bare_bounds, starts=s.starts)
    else:
        th0, _ = raw_polisher(bare_data, finger, bare_bounds)(th0)
    data, tex, search = bare_data, None, None
    if s.texture != "off":
        data, _ = load_raw_data(
            s.ds, models=s.models, stride=s.stride or TEXTURE_STRIDE, radius=s.radius, strokes=s.strokes, **dev
        )
        ts = texture_start(th0, data, finger, priors, gr.load_texture_priors(), s.seed)
        planes = ("x-y", "x-z", "y-z")
        search = {
            "candidates": [
                {"plane": planes[p], "wavelength_m": lam, "orientation_rad": o, "statistic": st}
                for p, lam, o, st in ts.candidates
            ],
            "grating_gain_nats": ts.gain,
            "detect_nats": DETECT_NATS,
            "requested": s.texture,
        }
        if s.texture == "on" or ts.gain > DETECT_NATS:
            tex, theta, bounds, nlp = ts.texture, ts.theta, ts.bounds, ts.neg_log_post
        elif s.stride is None:
            data = bare_data
    if tex is None:
        theta = th0
    if s.prune:
        data = prune_clear(data, theta, tex)
    if tex is None:
        bounds = raw_bounds(data, priors)
        nlp = raw_objective(data, finger, bounds)
    objective = None
    if s.sampled:
        # the lag joins θ as its last column, started at the lag assumed and polished with the rest
        data = data._replace(lag_prior=LAG_RANGE)
        bounds = with_lag_bounds(bounds, LAG_RANGE)
        theta = np.append(theta, np.log(float(finger.taxels.lag)))
        nlp = raw_objective(data, finger, bounds, tex)
        lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
        theta, objective = scaled_lbfgs(nlp, theta, lo, hi, opt_scale(tex is not None, True))
    return _Start(data, finger, th0, tex, theta, bounds, nlp, search, objective)


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
    overwrite: bool = False,
    calibration=None,
    lag: str = "sampled",
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
        Walkers are raised to two per sampled parameter where fewer (emcee's ensemble moves need them; 34 for a
        textured fit with the lag sampled), and the summary says so (``model.walkers``).
    resume : bool
        Continue the chain in ``out/chain.h5`` (the start, texture search included, is deterministic given the
        seed, so the same model is rebuilt); refused when ``out`` holds a run of another recording or other
        options (:mod:`bayestouch.io.runfolder`).
    overwrite : bool
        Replace a run already in ``out``, which is otherwise refused.
    budget_s : float, seconds, optional
        Stop sampling once this much wall-clock time has passed since the call (the search counts; the outputs
        written after the chain add their time, tens of seconds for a textured fit).
    stride : int, optional
        Frame stride of :func:`load_raw_data`; default :data:`TEXTURE_STRIDE` when the texture is modelled,
        :data:`BARE_STRIDE` otherwise. The bare shape's first stage uses at most :data:`BARE_STRIDE`.
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
    calibration : path or DeviceCalibration, optional
        The finger's device file (``bayestouch calibrate``): its per-taxel gains are divided out and their standard
        errors marginalised. Without it the gains are unknown (1 ± the nominal spread of ``models/noise.toml``,
        marginalised per taxel). The recording's simulator seed is never read.
    lag : {"sampled", "known"}
        The taxels' response lag τ: "sampled" (the default: log τ, uniform in τ over ``[raw_priors]``
        ``lag_min``–``lag_max`` of ``models/priors.toml``; no calibration measures it, and it scales a texture's
        signal as its amplitude does) or "known" (the finger's, ``models/taxels.toml``). A sampled lag's start
        assumes the range's middle; where its polish moves the lag more than :data:`LAG_RESTART` away, the bare
        shape and the texture search are done again at the lag reached and the better start is kept
        (``summary.model.lag_starts``, ``docs/raw_model.md``).
    prune : bool
        Sample without the taxel slots more than :data:`~bayestouch.inference.raw.likelihood.PRUNE_MARGIN` outside
        the start's surface (:func:`prune_clear`), checked on the draws afterwards (``summary.model.pruning``).

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    release_compiled()
    if texture not in ("auto", "on", "off"):
        raise BadInput(f"texture must be one of auto, on, off; got {texture!r}")
    if lag not in ("sampled", "known"):
        raise BadInput(f"lag must be one of sampled, known; got {lag!r}")
    if stride is not None and (isinstance(stride, bool) or not isinstance(stride, int | np.integer) or stride < 1):
        raise BadInput(f"stride must be an integer ≥ 1, got {stride!r}")
    if strokes is not None:
        check_stroke_selection(strokes)
    check_path(out, "out")
    t0 = time.perf_counter()
    out = Path(out)
    ds, where = open_recording(recording)
    cal, cal_name = calibration, None
    if calibration is not None and not isinstance(calibration, DeviceCalibration | str | os.PathLike):
        raise BadInput(
            f"calibration: expected a device file (TOML path) or a DeviceCalibration, got {type(calibration).__name__}"
        )
    if calibration is not None and not isinstance(calibration, DeviceCalibration):
        cal, cal_name = read_device_file(calibration), str(calibration)
    recording_mode(ds, where, cal)  # checked before the run folder is touched (--overwrite sets aside)
    host = host_device(Path(models), cal)
    if lag == "sampled":  # one value where one is needed (the start, the texture search, the reference row): the
        # middle of the lag's range, so that neither end is more than half the range off
        host = host.with_lag(np.sqrt(LAG_RANGE[0] * LAG_RANGE[1]))
    finger = host.finger
    # before the run folder is made (or a finished run in it set aside): a refused fit leaves nothing behind
    check_taxel_layout(ds, finger, where)
    check_full_scale(need_variable(ds, "taxel_current", 2, where), float(finger.noise.adc_full_scale), where)
    check_contact_motion(ds, where)
    options = {
        "walkers": int(walkers),
        "seed": int(seed),
        "stride": None if stride is None else int(stride),
        "radius": float(radius),
        "strokes": None if strokes is None else [int(k) for k in np.atleast_1d(strokes)],
        "models": str(Path(models).resolve()),
        "starts": int(starts),
        "texture": texture,
        "adjust": bool(adjust),
        "prune": bool(prune),
        "lag": lag,
        "calibration": None
        if cal is None
        else {
            "log_gain": [float(v) for v in cal.log_gain],
            "log_gain_sd": [float(v) for v in cal.log_gain_sd],
            "response": [cal.response_scale, cal.response_scale_sd],
        },
    }
    prepare_run_folder(
        out, fingerprint("raw", {"recording": dataset_digest(ds)}, options), resume=resume, overwrite=overwrite
    )
    priors = cm.load_priors()
    info = {
        "calibration": "no calibration: unit gains, the nominal spread of models/noise.toml"
        if cal is None
        else f"device file {cal_name or '(given)'}, {cal.info.get('object', 'unknown object')}, mode {cal.mode}"
    }
    setup = _StartSetup(ds, models, stride, radius, strokes, cal, texture, seed, starts, prune, lag == "sampled")
    st = _raw_start(setup, host, priors)
    if lag == "sampled":
        # the bare shape and the texture search assume one lag; where the polish moved it well away from the
        # range's middle, both are done again at the lag it reached and the better start is kept (from the
        # middle, a finger at the range's end can send the search to a neighbouring period)
        reached = float(np.exp(st.theta[-1]))
        tried = [{"lag_s": float(host.finger.taxels.lag), "reached_s": reached, "neg_log_post": st.objective}]
        if abs(np.log(reached / float(host.finger.taxels.lag))) > LAG_RESTART:
            again = _raw_start(setup, host.with_lag(reached), priors, th0=st.th0)
            tried.append(
                {"lag_s": reached, "reached_s": float(np.exp(again.theta[-1])), "neg_log_post": again.objective}
            )
            if again.objective < st.objective:
                st = again
        info["lag_starts"] = tried
    data, finger, tex, th_start, bounds, nlp = st.data, st.finger, st.texture, st.theta, st.bounds, st.nlp
    if st.search is not None:
        info["texture_search"] = st.search
    scale = opt_scale(tex is not None, lag == "sampled")
    logp, _, names = make_raw_log_prob(data, finger, priors, texture=tex, bounds=bounds)
    if walkers < 2 * len(names):  # emcee's ensemble moves need two walkers per dimension
        info["walkers"] = f"raised from {walkers} to {2 * len(names)}: two per sampled parameter"
        walkers = 2 * len(names)
    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    # the Laplace approximation starts the walkers and is the first independence proposal (deterministic given the
    # seed, so a resumed run rebuilds it)
    moments = laplace(nlp, th_start, lo, hi, scale)
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
        monitor=judged_quantities(
            raw_names(tex is not None, lag == "sampled", natural=True),
            partial(_natural, textured=tex is not None, lag=lag == "sampled"),
        ),
    )
    flat = ch.kept.reshape(-1, ch.kept.shape[2])
    if prune:
        info["pruning"] = prune_clearance(flat[:: max(1, len(flat) // 256)], data, tex)
    adjust = curvature_adjustment(flat, data, finger, texture=tex, bounds=bounds) if adjust else None
    summary = write_posterior(out, ch, raw_model(data, finger, texture=tex, info=info, adjust=adjust), seed=seed, t0=t0)
    release_run_folder(out)
    return summary
