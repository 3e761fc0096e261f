"""The contact-patch posterior: a least-squares start and emcee sampling of the patch model
(:mod:`bayestouch.inference.patch.model`), summarised with ArviZ. The model and how it is sampled:
``docs/patch_model.md``.
"""

from __future__ import annotations

import math
import time

import arviz as az
import numpy as np
from scipy.optimize import least_squares

from bayestouch.backend import jnp, release_compiled
from bayestouch.errors import BadInput, check_int, check_seed, shown
from bayestouch.inference.patch.model import (
    A_MIN,
    DEPTH_MIN,
    SUMMARY_NAMES,
    PatchModel,
    PatchParams,
    PatchPosterior,
    batched_patch_force,
    make_patch_log_prob,
    make_patch_model,
    patch_depth,
    patch_residual,
    theta_from_params,
)
from bayestouch.inference.posterior import interval
from bayestouch.inference.sampler import convergence, sample
from bayestouch.physics import skin as sk
from bayestouch.physics import taxel as tx
from bayestouch.physics.forward import Finger
from bayestouch.physics.patch import superellipse_area
from bayestouch.physics.virtual import VirtualFinger

__all__ = ["initial_patch_theta", "patch_posterior"]


# ---------------------------------------------------------------- start


def initial_patch_theta(model: PatchModel, mode: str = "empirical") -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Newton start θ̂ (7,) and its covariance (7, 7) ((JᵀJ)⁻¹, each sd clipped to ≤ 0.1 of the box).

    A moment guess (centroid and second moments of the signal above 3σ, less the blur variance; δ0 from the
    signal's total force for an n = 2 paraboloid, F = M δ0 π a b / 2h) refined by ``scipy.optimize.least_squares``
    on the whitened residuals with the offset profiled out, from n₀ = 2 and 4.
    """
    lo, hi = np.asarray(model.lower), np.asarray(model.upper)
    pos = np.asarray(model.positions)
    loaded = np.asarray(model.loaded) > 0
    y, sig = np.asarray(model.y), np.asarray(model.sigma)
    c0 = np.median(y[~loaded]) if (~loaded).any() else np.median(y)
    i0 = tx.taxel_current(model.taxels, 0.0, model.temperature, mode=mode)
    slope = float(jnp.log(tx.taxel_current(model.taxels, 1.0, model.temperature, mode=mode) / i0))  # per Pa
    s = np.where(loaded, y - c0, 0.0) * np.sign(slope)
    w = np.maximum(s - 3.0 * sig, 0.0)
    area_cell = float(model.cell_area)
    M = float(sk.bonded_layer_modulus(model.skin.E, model.skin.nu))
    h = float(model.skin.h)
    if w.sum() > 0:
        cu, cv = (w @ pos) / w.sum()
        d = pos - [cu, cv]
        cov = (w[:, None] * d).T @ d / w.sum()
        lam, vec = np.linalg.eigh(cov)
        var_blur = float(sk.blur_width(model.skin)) ** 2
        a0, b0 = (math.sqrt(6.0 * max(lam[k] - var_blur, A_MIN**2)) for k in (1, 0))
        ang0 = math.atan2(vec[1, 1], vec[0, 1])
        force = np.sum(np.maximum(s, 0.0)) / abs(slope) * area_cell
        d0 = 2.0 * h * force / (M * math.pi * a0 * b0)
    else:
        cu, cv, a0, b0, ang0, d0 = 0.0, 0.0, 1e-3, 1e-3, 0.0, 1e-5
    wts = 1.0 / sig**2

    def resid(t):
        r = np.asarray(patch_residual(jnp.asarray(t), model, mode))
        return (r - np.sum(wts * r) / np.sum(wts)) / sig

    eps = 1e-6 * (hi - lo)
    best = None
    for n0 in (2.0, 4.0):
        t0 = theta_from_params(PatchParams(cu, cv, a0, b0, ang0, n0, min(max(d0, 2 * DEPTH_MIN), 0.5 * h)))
        t0 = np.clip(t0, lo + eps, hi - eps)
        r = least_squares(
            resid, t0, bounds=(lo + eps, hi - eps), x_scale=np.maximum(0.01 * (hi - lo), 1e-6), max_nfev=400
        )
        if best is None or r.cost < best.cost:
            best = r
    cov = np.linalg.pinv(best.jac.T @ best.jac)
    sd = np.sqrt(np.abs(np.diag(cov)))
    sd_ok = np.clip(np.where(np.isfinite(sd), sd, np.inf), 1e-6 * (hi - lo), 0.1 * (hi - lo))
    shrink = np.where(np.isfinite(sd) & (sd > 0), sd_ok / np.where(sd > 0, sd, 1.0), 0.0)
    cov = shrink[:, None] * np.where(np.isfinite(cov), cov, 0.0) * shrink[None, :]
    return best.x, cov + np.diag(np.where(shrink > 0, 0.0, sd_ok**2))


# ---------------------------------------------------------------- sampling


def _canonical(flat: np.ndarray) -> np.ndarray:
    """θ draws (M, 7) → natural (M, 7) ``SUMMARY_NAMES`` with a ≥ b and angle in (−π/2, π/2]."""
    a, b, ang = np.exp(flat[:, 2]), np.exp(flat[:, 3]), flat[:, 4]
    swap = b > a
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    ang = ang + np.where(swap, np.pi / 2, 0.0)
    ang = np.pi / 2 - np.mod(np.pi / 2 - ang, np.pi)
    return np.column_stack([flat[:, 0], flat[:, 1], a, b, ang, np.exp(flat[:, 5]), np.asarray(patch_depth(flat))])


def _axial_stats(x: np.ndarray) -> dict:
    """Statistics of an axial angle (period π): circular mean and sd of 2φ, halved; quantiles about the mean."""
    z = np.mean(np.exp(2j * x))
    m = 0.5 * float(np.angle(z))
    d = np.pi / 2 - np.mod(np.pi / 2 - (x - m), np.pi)
    sd = 0.5 * math.sqrt(max(-2.0 * math.log(max(abs(z), 1e-300)), 0.0))
    return {"mean": m, "sd": sd, "q05": m + float(np.quantile(d, 0.05)), "q95": m + float(np.quantile(d, 0.95))}


def _start_ensemble(logp, theta0, cov, lo, hi, walkers, rng) -> np.ndarray:
    """Walkers drawn from N(θ̂, cov) inside the prior box; draws outside the support (δ0 ∉ [1 µm, h]) are redrawn."""
    eps = 1e-9 * (hi - lo)

    def draw(k):
        return np.clip(rng.multivariate_normal(theta0, cov, size=k, method="eigh"), lo + eps, hi - eps)

    start = draw(walkers)
    for _ in range(200):
        bad = ~np.isfinite(logp(start))
        if not bad.any():
            return start
        start[bad] = draw(int(bad.sum()))
    raise RuntimeError("could not place the walkers inside the prior's support around the initial fit")


def patch_posterior(
    currents,
    finger,
    *,
    seed: int,
    mode: str = "empirical",
    walkers: int = 32,
    steps: int = 3000,
    dt: float = 0.02,
    temperature: float = 300.0,
    gains=None,
    baseline=None,
    sigma=None,
    elapsed_s: float = 0.0,
    chain_path=None,
    progress: bool = False,
) -> PatchPosterior:
    """Posterior of the contact patch (a, b, n, orientation, centre, depth) from a frame or a short window.

    Parameters
    ----------
    currents : (N,) or (K, N) float, A
        Measured taxel currents of a static contact (K consecutive frames are averaged).
    finger : VirtualFinger or Finger
        :func:`bayestouch.load_finger` or its ``.finger`` (the forward model's finger).
    seed : int
        Seeds the walkers' start and emcee's random state (checked after setting).
    mode : {"physics", "empirical"}
        Taxel response used by the model (the one the data come from).
    walkers, steps : int
        Ensemble size (even, ≥ 16) and chain length (≥ 100).
    dt, temperature, gains, baseline, sigma, elapsed_s
        See :func:`make_patch_model`.
    chain_path : path or None
        emcee HDF5 checkpoint through :func:`bayestouch.inference.sampler.sample`; ``None`` samples in memory.
    progress : bool
        Show emcee's progress bar.

    Returns
    -------
    PatchPosterior

    Raises
    ------
    BadInput
        Bad currents, mode, walkers or steps (one line).
    """
    t0 = time.perf_counter()
    release_compiled()
    if isinstance(finger, VirtualFinger):  # what bt.load_finger returns: its forward-model finger
        finger = finger.finger
    if not isinstance(finger, Finger):
        raise BadInput(
            f"finger: expected bt.load_finger() (a VirtualFinger) or its .finger, got {type(finger).__name__} "
            f"{shown(finger, 60)}"
        )
    if mode not in tx.MODES:
        raise BadInput(f"mode: must be one of {', '.join(tx.MODES)}, got {mode!r}")
    if isinstance(walkers, bool) or not isinstance(walkers, int | np.integer) or walkers < 16 or walkers % 2:
        raise BadInput(f"walkers: expected an even number ≥ 16, got {walkers!r}")
    check_int(steps, "steps", 100, None, "an integer number of steps")
    check_seed(seed)
    if isinstance(currents, str | bytes):
        raise BadInput(f"currents: expected taxel currents as an (N,) or (K, N) array in amperes, got {currents!r:.60}")
    model = make_patch_model(
        currents,
        finger,
        dt=dt,
        temperature=temperature,
        gains=gains,
        baseline=baseline,
        sigma=sigma,
        elapsed_s=elapsed_s,
    )
    logp, bounds = make_patch_log_prob(model, mode)
    theta0, cov = initial_patch_theta(model, mode)
    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    rng = np.random.default_rng(seed)
    start = _start_ensemble(logp, theta0, cov, lo, hi, walkers, rng)
    ch = sample(logp, start, chain_path, walkers=walkers, ndim=7, seed=seed, steps=steps, progress=progress, t0=t0)
    kept = ch.kept  # (S, W, 7)
    flat = kept.reshape(-1, 7)
    nat = _canonical(flat)
    draws = {name: nat[:, i] for i, name in enumerate(SUMMARY_NAMES)}
    draws["area_m2"] = np.asarray(superellipse_area(draws["a"], draws["b"], draws["n"]))
    draws["force_N"] = np.asarray(batched_patch_force(jnp.asarray(flat), model))
    shape = kept.shape[:2]
    post = {k: np.swapaxes(v.reshape(shape), 0, 1) for k, v in draws.items() if k != "angle"}
    idata = az.from_dict(posterior=post)
    ess, rhat = az.ess(idata, method="bulk"), az.rhat(idata)
    params = {}
    for name in SUMMARY_NAMES:
        st = _axial_stats(draws[name]) if name == "angle" else interval(draws[name])
        if name != "angle":
            st.update(r_hat=float(rhat[name]), ess_bulk=float(ess[name]))
        params[name] = st
    derived = {
        k: {**interval(draws[k]), "r_hat": float(rhat[k]), "ess_bulk": float(ess[k])} for k in ("area_m2", "force_N")
    }
    checked = [n for n in SUMMARY_NAMES if n != "angle"]
    diag = convergence(
        [params[n]["r_hat"] for n in checked], [params[n]["ess_bulk"] for n in checked], ch, names=checked
    )
    k = 1 if np.ndim(currents) == 1 else int(np.shape(currents)[0])
    summary = {
        "parameters": params,
        "derived": derived,
        "diagnostics": {**diag, "seconds": time.perf_counter() - t0},
        "model": {
            "level": "patch",
            "mode": mode,
            "frames": k,
            "seed": seed,
            "likelihood": "Gaussian on drift-compensated log-currents, offset marginalised",
            "sigma_median": float(np.median(np.asarray(model.sigma))),
        },
    }
    return PatchPosterior(draws, summary, ch, model, theta0)
