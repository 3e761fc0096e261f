"""The contact-level fit: the initial estimate of the n-ellipsoid from contact points (m), the walkers' start, the
canonicalised natural parameters of draws, the contact level's :class:`~bayestouch.inference.posterior.PosteriorModel`
(Student-t, multiplicative, mixture or FFD-marginalised likelihood) and :func:`run_contact_fit`, which samples it
and writes the run folder (:func:`bayestouch.inference.posterior.write_posterior`).

θ (11,) or more is the contact level's sampled vector (:mod:`bayestouch.inference.contact`); points are (M, 3) m.
"""

from __future__ import annotations

import time
import zipfile
from functools import partial
from pathlib import Path

import emcee
import numpy as np
from scipy.optimize import minimize

from bayestouch.backend import jax, jnp, pad_pow2, release_compiled
from bayestouch.errors import BadInput, check_bools, check_int, check_path, check_seed, shown
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.symmetry import aliases, align_batch, canonicalize_batch
from bayestouch.inference import contact as cm
from bayestouch.inference import ffd_marginal as fm
from bayestouch.inference import pose_error as pe
from bayestouch.inference.de import de_search
from bayestouch.inference.misfit import residual_structure
from bayestouch.inference.modes import find_modes, gaussian_mixture
from bayestouch.inference.optimize import fd_hessian, lockstep_lbfgs
from bayestouch.inference.parts import occupancy_grid
from bayestouch.inference.posterior import (
    PosteriorModel,
    draw_volumes,
    interval,
    judged_quantities,
    vmf_sample,
    write_posterior,
)
from bayestouch.inference.reach import REACH_LIMIT, surface_reach
from bayestouch.inference.sampler import IndependenceMixture, prune_stuck_walkers, sample, snooker_move
from bayestouch.inference.smc import tempered_smc
from bayestouch.inference.trimmed import trimmed_starts
from bayestouch.io.contacts import check_normals_outward
from bayestouch.io.files import atomic_path, write_json
from bayestouch.io.occupancy import OCCUPANCY_FILE, write_occupancy
from bayestouch.io.runfolder import OPTIMUM_FILE, fingerprint, prepare_run_folder, release_run_folder

__all__ = [
    "contaminated_share",
    "TRIM_TRIGGER",
    "initial_theta",
    "run_contact_fit",
    "check_walkers",
    "check_budget",
    "MIN_WALKERS",
    "contact_model",
    "ffd_contact_model",
    "pose_contact_model",
    "NATURAL_NAMES",
    "natural_draws",
    "natural_names",
    "start_ball",
    "smc_stage",
    "save_stage",
    "load_stage",
    "read_optimum",
    "smc_moves",
    "align_particles",
    "optimum_mode",
    "sigma_continuation",
    "ANNEAL_ROUNDS",
    "ANNEAL_STEP",
    "ANNEAL_RUNS",
    "ANNEAL_MAXITER",
    "describe_modes",
    "SMC_PARTICLES",
    "DEFAULT_BUDGET_S",
    "sampling_budget",
    "DENSE_POINTS",
    "surrounds",
    "SMC_ESS",
    "MIXTURE_SHARE",
    "noise_to_size",
    "NOISE_SIZE_LIMIT",
]

#: particles and conditional-ESS target of the tempered SMC that starts a default fit
#: (``benchmarks/bench_user_sets.py``: at ESS 0.5 the particles of a one-sided 87-contact set collapsed into
#: a mode 47 nats below the truth's)
SMC_PARTICLES = 2048
SMC_ESS = 0.8
#: wall-clock budget (s) of a contact-level fit unless given: a user waits at most about this long for a posterior;
#: one that has not converged by then says so (``diagnostics.converged``, ``stopped_by_budget``) and can be
#: continued with ``resume``
DEFAULT_BUDGET_S = 60.0
#: fewest walkers of a fit: twice the 11 parameters of the contact model, plus a margin (emcee's moves split the
#: ensemble in halves, so the count is even)
MIN_WALKERS = 24
#: ``init="auto"`` starts from the optimum (no SMC) for at least this many contacts surrounding the object, at least
#: this fraction of them beyond ±½ of each semi-axis on each side (:func:`surrounds`)
DENSE_POINTS = 300
SURROUND_FRACTION = 0.03
#: most random-walk steps per stage after the HMC steps
SMC_RW_STEPS = 10
#: the independence mixture after the SMC (:func:`smc_moves`): its share of the chain's moves, the degrees of freedom
#: of its t components and the factor on each component's sd (``benchmarks/bench_user_sets.py``, set 11: τ 22 steps
#: at 0.8, ν 10, scale 1.0 against 34 at ν 5, scale 1.2, and 85 with differential evolution alone; sets 4 and 35:
#: acceptance 0.37-0.53 at ν 10-30, scale 1.0, against 0.18-0.34 at ν 5, scale 1.1)
MIXTURE_SHARE = 0.8
MIXTURE_NU = 10.0
MIXTURE_SCALE = 1.0
#: sampled parameters that the independence mixture proposes in log space (positive, their mass often piled near 0)
POSITIVE_NEAR_ZERO = ("w_outlier", "w_in", "w_out")
#: steps the chain runs even when its preparation (SMC, the optimum check) used up the budget (a few seconds)
MIN_CHAIN_STEPS = 200
#: shares of a fit's time budget the tempered SMC may use, and that the SMC and the optimum check together may use
#: (on the user sets the two take ~15 s and ~4 s of the default 60 s; 50,000 contacts would take hours)
SMC_BUDGET_SHARE = 0.5
OPTIMUM_BUDGET_SHARE = 0.7
#: time (s) the outputs after the chain take (posterior.nc with its pointwise log-likelihood and predictive, meshes,
#: occupancy grid), reserved from the budget so that it covers every phase: a fixed part and a part per contact
#: (measured here: 2.3-2.7 s for 1,000-5,000 contacts, 4.0 s for 50,000), at most OUTPUT_SHARE of the budget
OUTPUT_SECONDS = 3.0
OUTPUT_SECONDS_PER_POINT = 4e-5
OUTPUT_SHARE = 0.25
#: most contacts the evolutionary starts are polished on (a seeded subset; a posterior on more points is narrower
#: than the start's distance from its mode, and the polish of every start on 50,000 contacts took 12 s); the best
#: start is then polished once more on every point
POLISH_POINTS = 4096
#: scale of the robust loss of the robust evolutionary searches (:func:`candidate_thetas`), a fraction of the data's
#: radius (0.5 mm for a 25 mm object: a few noise sds, well below displacements of 3-10 mm)
ROBUST_SCALE = 0.02
#: independent evolutionary searches of the optimum check (:func:`optimum_mode`), each result polished on the
#: sampled posterior (``bench_user_sets`` sets 4, 17, 36: one search found the truth's mode for 1–2 of 6 seeds)
OPTIMUM_STARTS = 8
#: an optimum this many nats above every SMC particle is a mode the SMC missed (:func:`optimum_mode`): its
#: log-posterior is e^5 ≈ 150 times the best particle's, which a population of posterior draws would not miss
MISSED_MODE_NATS = 5.0
#: share of the walkers started in, and of the independence mixture's components centred on, such a mode
MISSED_MODE_SHARE = 0.5
#: the optimum check also starts from fits to the least displaced half of the contacts
#: (:func:`bayestouch.inference.trimmed.trimmed_starts`) when the SMC's particles put at least this mean share of
#: the contacts among the outliers (w_in + w_out), with this many evolutionary searches per trimmed fit, and continues
#: its optima downwards in σ (:func:`sigma_continuation`) (``benchmarks/bench_sbc_missed.py``: heavily contaminated
#: low-noise sets whose dominant mode the SMC missed)
TRIM_TRIGGER = 0.2
TRIM_SEARCHES = 4
#: rounds of the optimum check's σ continuation (:func:`optimum_mode`, ``anneal``): each halves every run's σ, polishes
#: the rest of θ with σ held there, then everything; a run stops at the first round that does not raise its best
ANNEAL_ROUNDS = 5
#: each round's step down in log σ
ANNEAL_STEP = float(np.log(2.0))
#: the continuation's runs (the best distinct polished optima) and each polish's iteration limit (set 19: all 19
#: optima at 1000 iterations reach the same mode as these 8 at 300, in a third of the time)
ANNEAL_RUNS = 8
ANNEAL_MAXITER = 300

#: summary names (natural units) of the 11 sampled contact-level parameters
NATURAL_NAMES = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n", "sigma")
#: units of the contact level's natural parameters and data (the ``units`` attributes of ``posterior.nc``)
CONTACT_UNITS = {
    **dict.fromkeys(("x_G", "y_G", "z_G", "a", "b", "c", "sigma", "points", "free_points", "radius"), "m"),
    **dict.fromkeys(("xi", "psi", "zeta"), "rad"),
    **dict.fromkeys(("n", "kappa", "epsilon", "w_outlier", "w_in", "w_out", "pose_scale", "normals"), "1"),
}
#: dims of the contact level's observations (ArviZ ``observed_data``, ``posterior_predictive``, ``log_likelihood``).
#: ``radius`` is each contact's distance from the contacts' centroid (m), the scalar per point that ``az.loo_pit``
#: and ``az.plot_ppc`` need (the log-likelihood is one value per point, keyed ``points``)
CONTACT_DIMS = {
    "points": ("point", "xyz"),
    "normals": ("point", "xyz"),
    "free_points": ("free_point", "xyz"),
    "radius": ("point",),
}


@jax.jit
@partial(jax.vmap, in_axes=(0, None))
def _foot_and_normal(theta, pts):
    """Each point's foot on the surface along the normal, at the likelihood's residual (the first-order distance:
    ``pts = foot + d · normal``), and the unit normal there; a replicate ``foot + e · normal`` then has residual e."""
    s = cm.shape_of(theta)
    d = ne.first_order_distance(s, ne.to_local(s, pts))[0]
    foot = pts - d[:, None] * ne.normals(s, pts)
    return foot, ne.normals(s, foot)


# module level, data as arguments: one compiled program per number of points, shared by every initial fit
_neg_log_post_and_grad = jax.jit(
    jax.value_and_grad(lambda t, pts, bounds, nu: -cm.log_prob(t, pts, bounds, nu)), static_argnums=3
)


def sampling_budget(budget_s: float | None, output_s: float) -> float | None:
    """The part of a fit's wall-clock budget (seconds) that ends the chain: the budget less ``output_s``, the time
    its outputs will take (seconds), at most :data:`OUTPUT_SHARE` of the budget; None (no budget) stays None."""
    if budget_s is None:
        return None
    return budget_s - min(OUTPUT_SHARE * budget_s, output_s)


def initial_theta(points, seed: int, priors: cm.PriorParams, starts: int = 3) -> np.ndarray:
    """A starting point that respects the symmetries and resists outliers: the best of :func:`candidate_thetas`."""
    return candidate_thetas(points, seed, priors, starts)[0]


def contaminated_share(particles, sampled: tuple) -> float:
    """Mean over ``particles (N, D)`` of the outlier fractions w_in + w_out (0 when ``sampled`` has none)."""
    cols = [i for i, name in enumerate(sampled) if name in ("w_in", "w_out")]
    if not cols:
        return 0.0
    return float(np.mean(np.sum(np.asarray(particles, float)[:, cols], axis=1)))


def candidate_thetas(
    points, seed: int, priors: cm.PriorParams, starts: int = 3, *, return_raw: bool = False
) -> list[np.ndarray] | tuple[list[np.ndarray], list[np.ndarray]]:
    """Distinct local optima (11,) of the robust log-posterior, best first.

    ``starts`` independent differential-evolution searches of the 10 shape parameters on the radial cost
    (:func:`bayestouch.inference.de.de_search`, one compiled program, at most 128 points; symmetry-reduced angle
    ranges; centre within the data centroid ± half the data's span, semi-axes up to 1.2 × the data's radius), each
    polished by L-BFGS-B on the robust (Student-t) log-posterior the sampler uses, on all points (beyond
    :data:`POLISH_POINTS`, on a seeded subset of that many, and the best once more on all) and inside the same
    search box; the start with the highest log-posterior wins. σ starts from the search's RMS.

    The box is deliberate: on data covering one side of an object, a wider search (or an unconstrained robust
    polish) runs off to surfaces several times too large whose local curvature matches the touched patch — the
    likelihood cannot tell them apart, and the sampler explores that ridge from a sensible start instead.

    With ``return_raw`` also the distinct search results themselves, unpolished (σ from the search's RMS): on
    heavily contaminated low-noise data the Student-t polish carries a search result that lies in the truth's basin
    into a wide-noise one (SBC set 35 of ``benchmarks/bench_sbc_users.py``: 40 % displaced contacts, σ 0.11 mm;
    every polished start 50 nats below the truth's mode, the raw ones in its basin), so :func:`optimum_mode`
    polishes both on the sampled posterior.

    Returns
    -------
    list of (11,) float
        One θ per distinct search result, by decreasing robust log-posterior; with ``return_raw``, the pair
        (that list, the unpolished results in search order).
    """
    pts = np.asarray(points, float)
    c = pts.mean(axis=0)
    half = 0.5 * np.ptp(pts, axis=0)
    ext = float(np.max(np.linalg.norm(pts - c, axis=1)))
    bounds = cm.bounds_for(pts, priors)
    lo, hi = np.array(bounds.lower), np.array(bounds.upper)
    lo[:3], hi[:3] = np.maximum(lo[:3], c - half - 1e-9), np.minimum(hi[:3], c + half + 1e-9)
    lo[3:6], hi[3:6] = np.maximum(lo[3:6], np.log(0.02 * ext)), np.minimum(hi[3:6], np.log(1.2 * ext))
    # the search runs in natural units (semi-axes and n, not their logs), as the paper's fit does
    de_lo = np.concatenate([lo[:3], np.exp(lo[3:6]), lo[6:9], [priors.n_min]])
    de_hi = np.concatenate([hi[:3], np.exp(hi[3:6]), hi[6:9], [priors.n_max]])
    # every other search robust (Cauchy loss at ROBUST_SCALE of the data's radius): with displaced contacts the
    # squared cost's optimum lies in another basin than the truth's
    scales = np.where(np.arange(starts) % 2 == 1, ROBUST_SCALE * ext, 0.0)
    found, cost = de_search(pts, de_lo, de_hi, seed, starts=starts, max_points=128, robust_scale=scales)
    nu = float(priors.student_nu)
    every = jnp.asarray(pts)
    if len(pts) > POLISH_POINTS:
        pick = np.random.default_rng([seed, 0x9F]).choice(len(pts), POLISH_POINTS, replace=False)
        pj = jnp.asarray(pts[np.sort(pick)])
    else:
        pj = every

    box = list(zip(lo, hi, strict=True))

    def fg(t, on):
        v, g = _neg_log_post_and_grad(jnp.asarray(t), on, bounds, nu)
        return float(v), np.asarray(g)

    def polish(t0, on) -> tuple[float, np.ndarray]:
        """L-BFGS-B from ``t0`` on the points ``on``: (value, θ), or ``t0``'s when the polish did not improve it."""
        f = partial(fg, on=on)
        v0 = f(t0)[0]
        res = minimize(f, t0, jac=True, method="L-BFGS-B", bounds=box, options={"maxiter": 500})
        return (float(res.fun), res.x) if np.isfinite(res.fun) and res.fun <= v0 else (v0, t0)

    results: list[tuple[float, np.ndarray]] = []
    raw: list[np.ndarray] = []
    polished: list[float] = []
    for v, c2 in zip(found, cost, strict=True):
        if any(abs(c2 - c) <= 1e-6 * c for c in polished):
            continue  # the same optimum as a start already polished (dense data: every search finds it)
        polished.append(c2)
        sigma = float(np.clip(np.sqrt(c2), priors.sigma_min * 2, priors.sigma_max / 2))
        t0 = np.clip(
            np.concatenate([v[:3], np.log(v[3:6]), v[6:9], [np.log(v[9])], [np.log(sigma)]]),
            lo + 1e-9 * (hi - lo),
            hi - 1e-9 * (hi - lo),
        )
        raw.append(t0)
        results.append(polish(t0, pj))
    ranked = [t for _, t in sorted(results, key=lambda r: r[0])]
    if pj is not every:  # the best start polished on every point
        ranked[0] = polish(ranked[0], every)[1]
    return (ranked, raw) if return_raw else ranked


def start_ball(theta0, bounds, n, rng, sampled: tuple = cm.PARAM_NAMES) -> np.ndarray:
    """A small ball of ``n`` walkers around ``theta0`` (optional parameters started at :data:`_EXTRA_START`),
    inside the prior box."""
    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    extra = sampled[11:]
    theta0 = np.concatenate([theta0[:11], [_EXTRA_START[k] for k in extra]])
    # a small ball: the DE moves expand the ensemble to the posterior's width within the burn-in
    scale = np.concatenate(
        [np.full(3, 1e-4), np.full(3, 1e-3), np.full(3, 1e-3), [1e-3], [1e-2], [_EXTRA_SCALE[k] for k in extra]]
    )
    p = cm.wrap_angles(np.clip(theta0, lo, hi) + scale * rng.normal(size=(n, theta0.size)))
    return np.clip(p, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))


#: natural names and transforms of the optional contact-level parameters (after σ)
_EXTRA_NATURAL = {
    "log_kappa": ("kappa", np.exp),
    "log_eps": ("epsilon", np.exp),
    "w_outlier": ("w_outlier", None),
    "w_in": ("w_in", None),
    "w_out": ("w_out", None),
    "log_pose_scale": ("pose_scale", np.exp),
}


def natural_names(sampled: tuple = cm.PARAM_NAMES) -> tuple:
    """The names of :func:`natural_draws`' columns for θ with parameter names ``sampled``."""
    return NATURAL_NAMES + tuple(_EXTRA_NATURAL[k][0] for k in sampled[11:])


def natural_draws(flat: np.ndarray, sampled: tuple = cm.PARAM_NAMES) -> np.ndarray:
    """θ draws (S, D) with parameter names ``sampled`` → canonicalised natural parameters (S, D): centre,
    a ≥ b ≥ c, angles, n, σ, then the optional parameters (κ, ε, w) in natural units."""
    v = np.column_stack([flat[:, :3], np.exp(flat[:, 3:6]), flat[:, 6:9], np.exp(flat[:, 9])])
    extra = [np.exp(flat[:, 10])]
    for j, name in enumerate(sampled[11:], start=11):
        fn = _EXTRA_NATURAL[name][1]
        extra.append(fn(flat[:, j]) if fn is not None else flat[:, j])
    return np.column_stack([canonicalize_batch(v), *extra])


#: starting values of the optional parameters: κ = 100 (normals good to ~6°), ε = 10⁻³ (the paper's), w = 5 %, the
#: pose-error law's scale s = 1 (:mod:`bayestouch.inference.pose_error`)
_EXTRA_START = {
    "log_kappa": np.log(100.0),
    "log_eps": np.log(1e-3),
    "w_outlier": 0.05,
    "w_in": 0.025,
    "w_out": 0.025,
    "log_pose_scale": 0.0,
}
_EXTRA_SCALE = {
    "log_kappa": 1e-2,
    "log_eps": 1e-2,
    "w_outlier": 1e-3,
    "w_in": 1e-3,
    "w_out": 1e-3,
    "log_pose_scale": 0.05,
}


_prior_jit = jax.jit(cm.log_prior)


def smc_stage(
    logp,
    bounds: cm.Bounds | None,
    seed: int,
    path: Path | None = None,
    *,
    progress: bool = False,
    budget_s=None,
    prior=None,
    particles: int = SMC_PARTICLES,
    ess: float = SMC_ESS,
    stream: tuple[int, ...] = (0x5AC,),
    label: str = "tempering",
):
    """The tempered SMC from the prior (:func:`bayestouch.inference.smc.tempered_smc`) of a contact-level
    log-posterior ``logp`` (W, D) → (W,) with prior ``bounds``: ``particles`` particles (:data:`SMC_PARTICLES`),
    conditional-ESS target ``ess`` (:data:`SMC_ESS`), HMC moves through ``logp.parts`` where it has them, seeded by
    ``seed`` and ``stream`` (``np.random.default_rng([seed, *stream])``).

    ``prior``: ``(log_prior, sample_prior)`` callables — (N, D) → (N,) and (count, Generator) → (count, D) — for a
    model whose prior is not a contact-level box (the parts fit's); ``bounds`` is then unused.

    ``budget_s`` (seconds): tempering stops after the stage that passes it (``complete`` False; the fit warns).

    With ``path`` the particles, their log-likelihoods and log-priors, the log-evidence and the temperatures are
    saved there atomically (``smc.npz``) and read back instead of recomputed when the file exists (a resumed run
    proposes from the same mixture as the uninterrupted one did).

    Returns
    -------
    dict
        ``particles`` (N, D), ``log_lik`` (N,), ``log_prior`` (N,), ``log_evidence`` (nats), ``betas`` (T,),
        ``complete`` (reached β = 1), ``evaluations``, ``seconds``.
    """
    if path is not None and Path(path).exists():
        return load_stage(path, "a finished tempering stage")

    if prior is None:

        def log_prior(x):
            return np.asarray(_prior_jit(jnp.asarray(x), bounds))

        def sample_prior(count, g):
            return cm.sample_prior(bounds, count, g)

    else:
        log_prior, sample_prior = prior

    def log_lik(x):
        with np.errstate(invalid="ignore"):
            return np.asarray(logp(x)) - log_prior(x)

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=1000, desc=label, unit="‰β", leave=False)

    def tick(beta, stage):
        if bar is not None:
            bar.update(int(1000 * beta) - bar.n)

    rng = np.random.default_rng([seed, *stream])
    try:
        r = tempered_smc(
            log_lik,
            log_prior,
            sample_prior,
            rng,
            particles=particles,
            ess_target=ess,
            progress=tick,
            gradients=getattr(logp, "parts", None),
            max_steps=SMC_RW_STEPS,
            budget_s=budget_s,
        )
    finally:
        if bar is not None:
            bar.close()
    res = {
        "particles": r.particles,
        "log_lik": r.log_lik,
        "log_prior": r.log_prior,
        "log_evidence": r.log_evidence,
        "betas": r.betas,
        "complete": bool(r.complete),
        "evaluations": int(r.evaluations),
        "seconds": float(r.seconds),
    }
    if path is not None:
        save_stage(path, res)
    return res


def save_stage(path: Path, arrays: dict) -> None:
    """A stage of a run (``arrays``: names → arrays or numbers) written atomically to the ``.npz`` file ``path``,
    which :func:`load_stage` reads back on a resume."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def load_stage(path: Path, what: str, keys=None) -> dict:
    """A stage :func:`save_stage` wrote to ``path``: its arrays (``keys`` of them, default all; 0-d ones as numbers).

    Raises
    ------
    BadInput
        The file cannot be read (cut off by a kill mid-write) or lacks a key: one line naming it as ``what``.
    """
    try:
        with open(path, "rb") as fh, np.load(fh) as z:  # the file closed whatever np.load makes of it
            return {k: (z[k] if z[k].ndim else z[k].item()) for k in (z.files if keys is None else keys)}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as e:  # cut off by a kill mid-write
        raise BadInput(
            f"--resume: {path} cannot be read as {what} ({type(e).__name__}); pass --overwrite to start the run "
            "again (its files are set aside), or choose another folder"
        ) from None


def read_optimum(path: Path) -> dict | None:
    """The optimum check a run saved in ``path`` (:data:`bayestouch.io.runfolder.OPTIMUM_FILE`): ``theta``
    (D,), ``log_post`` (nats), ``cov`` (D, D) and ``trimmed_starts``; None when the run has none (it was interrupted
    before the check finished, or made by a version that did not keep it)."""
    if not Path(path).exists():
        return None
    return load_stage(path, "a finished optimum check", ("theta", "log_post", "cov", "trimmed_starts"))


def optimum_mode(
    points,
    logp,
    bounds: cm.Bounds,
    priors: cm.PriorParams,
    seed: int,
    sampled: tuple = cm.PARAM_NAMES,
    theta0=None,
    batch: int = 32,
    budget_s: float | None = None,
    extra_starts=(),
    anneal: bool = False,
) -> dict:
    """The best of :data:`OPTIMUM_STARTS` evolutionary searches (:func:`candidate_thetas`, and ``theta0``), each
    result polished by L-BFGS on the sampled log-posterior both as found and after the robust polish, and its
    Laplace covariance: the check that a tempered SMC did not miss the dominant mode.

    Tempering from the prior can lose a narrow mode whose prior mass is small (one-sided data: a compact surface
    fitting every contact beside broad ones fitting most); a global search of the fit's cost finds it directly.

    With ``anneal`` the polished results are continued downwards in σ (:data:`ANNEAL_ROUNDS` rounds: σ halved and
    held while the rest is polished, then everything polished; each run kept at its best). Under the outlier mixture a
    contact more than a few σ off a nearly right shape counts as displaced and no longer pulls the shape: a polish
    that starts at twice the mode's σ stops in a wider mode that calls some undisplaced contacts outliers. SBC set
    19 of ``benchmarks/bench_sbc_users.py`` (33 of 98 contacts displaced, σ 26 µm): the polished trimmed start nearest
    the truth stops at σ 49 µm, 44 nats below the truth's mode; continued, it reaches σ 24 µm and the mode.

    Parameters
    ----------
    points : (M, 3) float, metres
    logp : callable
        :func:`~bayestouch.inference.contact.make_log_prob`'s ``f`` (with ``f.parts``), D parameters.
    bounds : Bounds
        Its prior; the polish stays inside the box (the angles are free, as in the prior).
    seed : int
        Seeds the evolutionary search.
    sampled : tuple of str
        ``logp``'s parameter names (:func:`~bayestouch.inference.contact.param_names`); the optional ones start
        at their usual values.
    theta0 : (11,) float, optional
        The evolutionary-search optimum when already found.
    batch : int
        ``logp.parts`` is called on blocks of this many rows (padded), the walkers' count, whose program the
        chain compiles anyway.
    extra_starts : sequence of (≥ 11,) float
        More starts polished alongside the searches' (:func:`bayestouch.inference.trimmed.trimmed_starts`).
    anneal : bool
        Continue the polished results downwards in σ (above); the fit does so on heavily contaminated data.
    budget_s : float, seconds, optional
        The polishes (run in lockstep, :func:`~bayestouch.inference.optimize.lockstep_lbfgs`) stop once this much
        time has passed, each at the best point it had reached.

    Returns
    -------
    dict
        ``theta`` (D,), ``log_post`` (nats) and ``cov`` (D, D): the inverse of the negative Hessian (central
        differences of the gradient), its eigenvalues floored at 1 (no direction wider than one unit of θ).
    """
    lo, hi = np.asarray(bounds.lower, float), np.asarray(bounds.upper, float)
    d = lo.size
    starts = [np.asarray(theta0, float)] if theta0 is not None else []
    # the searches' results both polished on the robust cost and as found (candidate_thetas, return_raw)
    ranked, raw = candidate_thetas(
        points, seed + 1 if theta0 is not None else seed, priors, OPTIMUM_STARTS, return_raw=True
    )
    starts += ranked + raw
    starts += [np.asarray(t, float) for t in extra_starts]
    angle = np.isin(np.arange(d), cm.ANGLE_COLUMNS)  # periodic: no bounds
    box = [(None, None) if angle[j] else (lo[j], hi[j]) for j in range(d)]

    def fg_batch(xs):
        """The negative log-posterior (k,) and its gradient (k, D) at the rows of ``xs`` (k, D) (1e300 and zeros
        where it is not finite), through ``logp.parts`` on blocks of ``batch`` rows (padded with the last row)."""
        xs = np.atleast_2d(xs)
        rows = -(-len(xs) // batch) * batch
        lp, ll, glp, gll = logp.parts(np.concatenate([xs, np.repeat(xs[-1:], rows - len(xs), axis=0)]))
        v = (np.asarray(lp, float) + np.asarray(ll, float))[: len(xs)]
        g = (np.asarray(glp, float) + np.asarray(gll, float))[: len(xs)]
        ok = np.isfinite(v)
        return np.where(ok, -v, 1e300), np.where(ok[:, None], -g, 0.0)

    def fg(x):
        v, g = fg_batch(x)
        return float(v[0]), g[0]

    # each search result polished on the sampled posterior (the robust cost ranks them otherwise), all at once: the
    # runs' steps share the calls of logp.parts, whose rows are computed alike whatever the others hold
    x0s = [
        np.clip(
            np.concatenate([th[:11], [_EXTRA_START[k] for k in sampled[11:]]]),
            lo + 1e-9 * (hi - lo),
            hi - 1e-9 * (hi - lo),
        )
        for th in starts
    ]
    f0, _ = fg_batch(np.stack(x0s))
    deadline = None if budget_s is None else time.perf_counter() + budget_s

    polished = []
    for x0, f0_, res in zip(x0s, f0, lockstep_lbfgs(fg_batch, x0s, box, 1000, deadline), strict=True):
        polished.append((res.x, float(res.fun)) if res.fun <= f0_ else (x0, float(f0_)))
    if anneal:
        polished += sigma_continuation(fg_batch, polished, box, deadline)
    x, fx = min(polished, key=lambda r: r[1])
    hess = fd_hessian(fg, x, np.full(d, 1e-6), np.where(angle, -np.inf, lo), np.where(angle, np.inf, hi))
    lam, vec = np.linalg.eigh(0.5 * (hess + hess.T))
    cov = (vec / np.maximum(lam, 1.0)) @ vec.T
    return {"theta": x, "log_post": -fx, "cov": cov}


def sigma_continuation(
    fg_batch,
    polished,
    box,
    deadline: float | None = None,
    rounds: int = ANNEAL_ROUNDS,
    runs: int = ANNEAL_RUNS,
    maxiter: int = ANNEAL_MAXITER,
) -> list:
    """Local optima continued downwards in the noise scale σ (:func:`optimum_mode`'s ``anneal``).

    Each round halves every active run's log σ (column ``log_sigma``, not below its lower bound), polishes the rest
    of θ with σ held there, then polishes everything; a run whose round did not raise its best value stops. All
    active runs polish in lockstep (:func:`~bayestouch.inference.optimize.lockstep_lbfgs`).

    Parameters
    ----------
    fg_batch : callable
        θ (k, D) → (negative log-posterior (k,), its gradient (k, D)).
    polished : list of (θ (D,), value)
        The optima (values: negative log-posterior); the ``runs`` best of distinct value are continued.
    box : list of D (low, high)
        The polish's bounds.
    deadline : float, optional
        ``time.perf_counter()`` value after which nothing more is polished.
    rounds : int
        Most halvings.
    runs : int
        Optima continued.
    maxiter : int
        Iteration limit of each polish.

    Returns
    -------
    list of (θ, value)
        Every run's best point reached by the continuation (not its start).
    """
    j = cm.PARAM_NAMES.index("log_sigma")
    floor = box[j][0]
    start, seen = [], set()  # the continued optima (θ, value), best first, of distinct value
    for th, v in sorted(polished, key=lambda r: r[1]):
        key = round(float(v), 3)
        if np.isfinite(v) and key not in seen and len(start) < runs:
            seen.add(key)
            start.append((np.asarray(th, float), float(v)))
    best = list(start)
    current = [th for th, _ in start]
    active = list(range(len(start)))
    for _ in range(int(rounds)):
        active = [k for k in active if floor is None or current[k][j] - ANNEAL_STEP > floor]
        if not active or (deadline is not None and time.perf_counter() > deadline):
            break
        held = []
        for k in active:
            v = current[k][j] - ANNEAL_STEP
            held.append([(v, v) if i == j else b for i, b in enumerate(box)])
        fixed = lockstep_lbfgs(fg_batch, [current[k] for k in active], box, maxiter, deadline, run_bounds=held)
        free = lockstep_lbfgs(fg_batch, [r.x for r in fixed], box, maxiter, deadline)
        still = []
        for k, r in zip(active, free, strict=True):
            current[k] = np.asarray(r.x, float)
            if np.isfinite(r.fun) and r.fun < best[k][1] - 1e-6:
                best[k] = (current[k], float(r.fun))
                still.append(k)
        active = still
    return [b for b, s in zip(best, start, strict=True) if b[1] < s[1]]


def _laplace_draws(centre, chol, count: int, logp, rng, tries: int = 100) -> np.ndarray:
    """``count`` draws (count, D) of N(centre, chol cholᵀ) with a finite log-posterior ``logp`` ((count, D) ->
    (count,); redrawn up to ``tries`` times, then the centre itself)."""
    out = np.repeat(np.asarray(centre, float)[None], count, axis=0)
    todo = np.arange(count)
    for _ in range(tries):
        if not len(todo):
            break
        # always ``count`` candidates: one batch shape, one compiled log-density
        y = centre + rng.standard_normal((count, len(centre))) @ chol.T
        ok = np.ones(count, bool) if logp is None else np.isfinite(np.asarray(logp(y), float))
        good = y[ok][: len(todo)]
        out[todo[: len(good)]] = good
        todo = todo[len(good) :]
    return out


def smc_moves(particles, walkers: int, seed: int, extra_mode: dict | None = None, logp=None, log_columns=()):
    """Moves and starting walkers of an emcee run after :func:`smc_stage`, from posterior draws ``particles (N, D)``
    aligned to one alias (:func:`align_particles`).

    A Gaussian mixture is fitted to the particles (:func:`bayestouch.inference.modes.gaussian_mixture`: EM, the
    number of components by BIC), in coordinates where ``log_columns`` (positive parameters piled near 0, such as
    outlier fractions) are logarithms; each component becomes a multivariate t (ν = :data:`MIXTURE_NU`, covariance
    × :data:`MIXTURE_SCALE`²) of the same weight. Separated modes take components of their own, and a skewed or
    curved mode (an unseen semi-axis bounded on one side by the contacts, open on the other) several. The
    independence mixture (:class:`~bayestouch.inference.sampler.IndependenceMixture`) is :data:`MIXTURE_SHARE`
    of the moves: a proposal shaped like the posterior is accepted often and is independent of the walker's place,
    so walkers jump between modes in one step; the rest are differential evolution (80 %) and its snooker variant
    (20 %, :func:`~bayestouch.inference.sampler.snooker_move`: the published move, which keeps the posterior
    invariant), which follow the local shape the mixture misses. The walkers start at distinct particles (distinct
    in value where the particles hold that many: resampling copies a particle that no mutation moved).

    ``extra_mode`` (:func:`optimum_mode`'s dict), a mode the particles missed: :data:`MISSED_MODE_SHARE` of the
    walkers start from its Laplace approximation N(θ*, Σ) instead (finite under ``logp``, ``(W, D) -> (W,)``), and
    a component of that weight fitted to such draws joins the mixture, so walkers move between it and the
    particles' modes in both directions.

    Returns
    -------
    moves : list of (move, weight)
    walkers : (W, D) float
    """
    x = np.asarray(particles, float)
    n, d = x.shape
    cols = np.asarray(log_columns, int)
    rng = np.random.default_rng([seed, 0x313])
    # walkers on distinct particles: resampling leaves copies of a particle that no mutation moved (a narrow
    # posterior), and walkers on one point give the red-blue moves no direction between them
    distinct = np.unique(x, axis=0, return_index=True)[1]
    if len(distinct) >= walkers:
        start = rng.choice(distinct, walkers, replace=False)
    else:  # every distinct value once, the rest copies
        start = rng.permutation(np.concatenate([distinct, rng.choice(n, walkers - len(distinct))]))
    ws = x[start].copy()

    def to_mixture_space(y):
        u = np.array(y, dtype=float)
        u[:, cols] = np.log(np.maximum(u[:, cols], 1e-300))
        return u

    def ridged(cov):
        return cov + np.diag(1e-10 * np.diag(cov) + 1e-300)

    weights, centres, covs = gaussian_mixture(to_mixture_space(x), rng)
    weights, centres = list(weights), list(centres)
    chols = [np.linalg.cholesky(ridged(c)) * MIXTURE_SCALE for c in covs]
    if extra_mode is not None:
        share = MISSED_MODE_SHARE
        chol = np.linalg.cholesky(extra_mode["cov"])
        moved = np.arange(walkers) < round(share * walkers)
        # one batch of draws: the component is fitted to them, and the moved walkers start at the first of them
        draws = _laplace_draws(extra_mode["theta"], chol, max(4 * d, 256, int(moved.sum())), logp, rng)
        near = to_mixture_space(draws)
        centres.append(near.mean(axis=0))
        chols.append(np.linalg.cholesky(ridged(np.cov(near.T))))
        weights = [w * (1 - share) for w in weights] + [share]
        ws[moved] = draws[: int(moved.sum())]
    mix = IndependenceMixture(
        np.array(centres), np.array(chols), emcee.moves.DEMove(), MIXTURE_NU, weights, log_columns=cols, adaptive=True
    )
    rest = 1.0 - MIXTURE_SHARE
    if walkers < 2 * d:  # too few walkers for red-blue moves: a random walk with the particles' covariance instead
        return [(mix, MIXTURE_SHARE), (emcee.moves.GaussianMove(ridged(np.cov(x.T)) * 0.25 * 2.38**2 / d), rest)], ws
    return [(mix, MIXTURE_SHARE), (emcee.moves.DEMove(), 0.8 * rest), (snooker_move(), 0.2 * rest)], ws


def align_particles(particles, log_post, ref=None) -> np.ndarray:
    """Posterior draws θ (N, D) rewritten as the aliases nearest one reference frame
    (:func:`bayestouch.geometry.symmetry.align_batch`): ``ref (D,)``, by default the alias of the
    highest-``log_post (N,)`` particle whose Euler angle ξ is nearest π/2 (farthest from the angles' gimbal poles)."""
    x = np.asarray(particles, float)
    if ref is None:
        al = aliases(x[int(np.nanargmax(log_post))])
        ref = al[int(np.argmin(np.abs(al[:, 6] - 0.5 * np.pi)))]
    return align_batch(x, ref)


def describe_modes(nat, volumes, seed: int) -> list[dict]:
    """The separated modes (:func:`bayestouch.inference.modes.find_modes`) of canonical natural draws ``nat (N, ≥
    10)`` with their volumes ``volumes (N,)`` m³: per mode its ``weight`` (fraction of the draws), the volume's and
    each semi-axis's and n's mean, sd and 90 % interval; heaviest first."""
    feats = np.column_stack([np.log(nat[:, 3:6]), np.log(nat[:, 9])])
    lab = find_modes(feats, np.random.default_rng([seed, 0x30D]))
    out = []
    for j in range(int(lab.max()) + 1):
        m = lab == j
        out.append(
            {
                "weight": float(m.mean()),
                "volume_m3": interval(volumes[m]),
                **{k: interval(nat[m, i]) for k, i in (("a", 3), ("b", 4), ("c", 5), ("n", 9))},
            }
        )
    return out


def contact_model(
    points, priors: cm.PriorParams, nu: float, *, normals=None, noise: str = "student", free=None
) -> PosteriorModel:
    """The contact level as a :class:`~bayestouch.inference.posterior.PosteriorModel`: pointwise log-likelihood of
    each point (:func:`~bayestouch.inference.contact.pointwise_log_likelihood`); replicated points are surface points
    of each draw displaced along the normal by noise of the model's scale (Student-t or Gaussian σ; σ_i for the
    multiplicative model; the mixture's outliers are drawn uniformly along the normal within the data's extent, the
    two-sided outlier model's half-Cauchy (scale ``priors.outlier_scale``) on their side, inwards with probability
    w_in and outwards with w_out); free-space points (``free``) count in the pointwise log-likelihood after the
    contacts; with measured ``normals``, replicated normals are von Mises–Fisher (κ of the draw) about the draw's normal
    (:func:`~bayestouch.inference.posterior.vmf_sample`), and the observed group holds the normalised measured
    normals too."""
    m = len(points)
    # padded to a power of two (copies of the first point, cut off again): one compiled program per size bucket
    pts = jax.device_put(pad_pow2(np.asarray(points, dtype=np.float64)))
    sampled = cm.param_names(normals is not None, noise)
    names = natural_names(sampled)
    lo, hi = np.asarray(points).min(axis=0), np.asarray(points).max(axis=0)
    half_diag = 0.5 * float(np.linalg.norm(hi - lo))
    centroid = np.asarray(points).mean(axis=0)
    lever = np.asarray(points) - centroid

    def predictive(thetas, rng):
        foot, nrm = (np.asarray(a)[:, :m] for a in _foot_and_normal(jnp.asarray(thetas[:, :11]), pts))
        shape = (len(thetas), m)
        sigma = np.exp(thetas[:, 10])[:, None]
        if noise == "student":
            e = sigma * (rng.standard_normal(shape) if np.isinf(nu) else rng.standard_t(nu, shape))
        elif noise == "multiplicative":
            k = sampled.index("log_eps")
            var = sigma**2 + np.exp(2 * thetas[:, k])[:, None] / 3 * np.einsum("wmk,mk->wm", nrm**2, lever**2)
            e = np.sqrt(var) * rng.standard_normal(shape)
        elif noise == "outlier":
            w_in = thetas[:, sampled.index("w_in")][:, None]
            w_out = thetas[:, sampled.index("w_out")][:, None]
            u = rng.random(shape)
            e = sigma * rng.standard_normal(shape)
            # displaced contacts: half-Cauchy of scale outlier_scale on their side (cm.outlier_log_density)
            far = priors.outlier_scale * np.tan(0.5 * np.pi * rng.random(shape))
            e = np.where(u < w_in, -far, e)
            e = np.where((u >= w_in) & (u < w_in + w_out), far, e)
        else:
            w = thetas[:, sampled.index("w_outlier")][:, None]
            e = np.where(
                rng.random(shape) < w, rng.uniform(-half_diag, half_diag, shape), sigma * rng.standard_normal(shape)
            )
        rep = {"points": foot + e[..., None] * nrm}
        rep["radius"] = np.linalg.norm(rep["points"] - centroid, axis=-1)
        if normals is not None:  # measured normals: vMF about the draw's normal at its replicated foot point
            rep["normals"] = vmf_sample(nrm, np.exp(thetas[:, sampled.index("log_kappa")])[:, None], rng)
        return rep

    def ll(thetas):
        terms = cm.pointwise_log_likelihood(
            thetas,
            points,
            nu,
            normals=normals,
            noise=noise,
            free=free,
            free_miss=priors.free_miss,
            outlier_scale=priors.outlier_scale,
        )
        return {"points": terms[:, :m], **({"free_points": terms[:, m:]} if n_free else {})}

    likelihood = {
        "student": "Gaussian" if np.isinf(nu) else f"Student-t, nu = {nu:g}",
        "multiplicative": "Gaussian with the paper's multiplicative (1 + r) perturbation",
        "mixture": "Gaussian + uniform outlier mixture",
        "outlier": "Gaussian + two-sided outliers (into the solid, out into free space)",
    }[noise]
    n_free = 0 if free is None else len(free)
    if n_free:
        likelihood += f"; {n_free} free-space points"
    if normals is not None:
        likelihood += "; normals: von Mises-Fisher"
    observed = {"points": np.asarray(points), "radius": np.linalg.norm(np.asarray(points) - centroid, axis=-1)}
    if normals is not None:
        nn = np.asarray(normals, float)
        observed["normals"] = nn / np.linalg.norm(nn, axis=1, keepdims=True)
    if n_free:
        observed["free_points"] = np.asarray(free, float)
    return PosteriorModel(
        names,
        lambda flat: natural_draws(flat, sampled),
        lambda nat: nat[:, :10],
        ll,
        predictive,
        observed,
        {
            "level": "contact",
            "likelihood": likelihood,
            "noise": noise,
            "normals_used": normals is not None,
            "n_points": int(m),
            "n_free_points": int(n_free),
            "parameters_sampled": list(sampled),
        },
        dims=CONTACT_DIMS,
        units=CONTACT_UNITS,
    )


def _check_pose(pose, points, **others) -> None:
    """Refuse a pose-error law that is not one of ``points``, or options the pose-marginalised fit does not take."""
    if not isinstance(pose, pe.EnsembleModel):
        raise BadInput(
            f"pose: expected an EnsembleModel (bayestouch.inference.pose_error.ensemble_model) or None, got "
            f"{type(pose).__name__}"
        )
    if np.shape(pose.moved) != np.shape(points):
        raise BadInput(
            f"pose: its law covers {len(pose.moved)} contacts, the fit has {len(points)}; build it from these points"
        )
    given = {
        "ffd": others["ffd"] is not None,
        "normals": others["normals"] is not None,
        "free": others["free"] is not None,
        "noise": others["noise"] not in ("auto", "gaussian", "student") or others["nu"] not in (None, np.inf),
        "precision": others["precision"] == "mixed",
    }
    bad = [k for k, v in given.items() if v]
    if bad:
        raise BadInput(
            f"pose: the pose-marginalised fit has Gaussian contact noise in float64 and no {', '.join(bad)}; drop "
            f"{'it' if len(bad) == 1 else 'them'} or the pose-error law"
        )


def pose_contact_model(points, pose: pe.EnsembleModel) -> PosteriorModel:
    """The contact level with the pad's pose error marginalised (:func:`run_contact_fit`'s ``pose``) as a
    :class:`~bayestouch.inference.posterior.PosteriorModel`. Its likelihood couples the contacts of a stroke (and,
    through the law's leading components, all strokes), so it has no pointwise log-likelihood and no replicated
    data; the observed group holds the contacts as the host computed them."""
    sampled = pe.ENSEMBLE_PARAM_NAMES
    return PosteriorModel(
        natural_names(sampled),
        lambda flat: natural_draws(flat, sampled),
        lambda nat: nat[:, :10],
        None,
        None,
        {"points": np.asarray(points, float)},
        {
            "level": "contact",
            "likelihood": (
                f"Gaussian, the pad's pose error marginalised (ensemble law of {pose.lead.shape[2]} columns, "
                f"per-stroke offset sd {pose.offset_sd:g} m)"
            ),
            "noise": "gaussian",
            "normals_used": False,
            "n_points": int(len(points)),
            "n_free_points": 0,
            "parameters_sampled": list(sampled),
            "pose_error": {"offset_sd_m": float(pose.offset_sd), "correlation_time_s": float(pose.ell)},
        },
        dims=CONTACT_DIMS,
        units=CONTACT_UNITS,
    )


def _theta_of_natural(nat) -> np.ndarray:
    """Natural contact-level parameters (11,) → the sampled θ (11,)."""
    nat = np.asarray(nat, float)
    return np.concatenate([nat[:3], np.log(nat[3:6]), nat[6:9], [np.log(nat[9])], [np.log(nat[10])]])


def ffd_contact_model(points, dims, tau: float) -> PosteriorModel:
    """The contact level with a Gaussian likelihood and the FFD lattice marginalised
    (:mod:`bayestouch.inference.ffd_marginal`). The pointwise log-likelihood and the replicated points are taken
    conditional on the lattice's posterior mean at each draw; the mean mesh is moved by that mean lattice."""
    pts = jnp.asarray(points, dtype=jnp.float64)
    m = len(points)

    @jax.jit
    @jax.vmap
    def conditional(theta):
        dP, _ = fm.conditional_lattice(theta, pts, dims, tau=tau)
        r, A = fm.design_matrix(theta, pts, dims)
        resid = r - A @ dP.T.reshape(-1)
        sigma = jnp.exp(theta[10])
        ll = -0.5 * (resid / sigma) ** 2 - theta[10] - 0.5 * jnp.log(2 * jnp.pi)
        s = cm.shape_of(theta)
        nrm = ne.normals(s, pts)
        return ll, pts - resid[:, None] * nrm  # conditional surface points nearest the data

    def ll(thetas):
        return {"points": np.asarray(conditional(jnp.asarray(thetas))[0])}

    centroid = np.asarray(points).mean(axis=0)

    def predictive(thetas, rng):
        foot = np.asarray(conditional(jnp.asarray(thetas))[1])
        rep = foot + np.exp(thetas[:, 10])[:, None, None] * rng.standard_normal(foot.shape)
        return {"points": rep, "radius": np.linalg.norm(rep - centroid, axis=-1)}

    def refine(mean_nat, verts):
        th = jnp.asarray(_theta_of_natural(mean_nat))
        dP, _ = fm.conditional_lattice(th, pts, dims, tau=tau)
        s = cm.shape_of(th)
        return np.asarray(fm.deformed_points(th, dP, ne.to_local(s, jnp.asarray(verts)), dims))

    return PosteriorModel(
        NATURAL_NAMES,
        natural_draws,
        lambda nat: nat[:, :10],
        ll,
        predictive,
        {"points": np.asarray(points), "radius": np.linalg.norm(np.asarray(points) - centroid, axis=-1)},
        {
            "level": "contact",
            "likelihood": "Gaussian, FFD lattice marginalised",
            "ffd_size": "x".join(map(str, dims)),
            "ffd_tau_m": tau,
            "n_points": int(m),
            "parameters_sampled": list(cm.PARAM_NAMES),
        },
        refine,
        dims=CONTACT_DIMS,
        units=CONTACT_UNITS,
    )


#: the Student-t degrees of freedom a contact fit takes: ν < 0.5 is heavier-tailed than any read-out or contact error
#: (Cauchy is 1), ν > 1000 is Gaussian to within 1e-3 in the log-density of a 3-sd residual (``noise gaussian``)
NU_RANGE = (0.5, 1000.0)


def check_walkers(walkers) -> int:
    """``walkers`` as an int, or a one-line refusal when it is not an even integer ≥ :data:`MIN_WALKERS` (the check
    of :func:`bayestouch.fit` and :func:`run_contact_fit`)."""
    if isinstance(walkers, bool) or not isinstance(walkers, int | np.integer) or walkers < MIN_WALKERS or walkers % 2:
        raise BadInput(
            f"walkers must be an even integer ≥ {MIN_WALKERS} (twice the parameters, plus a margin), got {walkers!r}"
        )
    return int(walkers)


def check_budget(budget_s, auto: bool = False) -> None:
    """Refuse (one line) a wall-clock budget ``budget_s`` that is not a number of seconds > 0 or None (no budget),
    or with ``auto`` also ``"auto"`` (:func:`bayestouch.fit`): -1 or 0 had started a fit that ran on past it (the
    check of :func:`bayestouch.fit`, :func:`run_contact_fit` and
    :func:`~bayestouch.inference.parts_run.run_parts_fit`)."""
    if budget_s is None or (auto and isinstance(budget_s, str) and budget_s == "auto"):
        return
    number = not isinstance(budget_s, bool | np.bool_) and isinstance(budget_s, int | float | np.integer | np.floating)
    if not (number and budget_s > 0):
        raise BadInput(
            f"budget_s must be > 0 seconds{', ' + repr('auto') if auto else ''} or None (no budget), got "
            f"{shown(budget_s)}"
        )


def run_contact_fit(
    points,
    out: Path,
    *,
    seed: int = 0,
    walkers: int = 32,
    steps: int = 20000,
    resume: bool = False,
    budget_s: float | None = DEFAULT_BUDGET_S,
    progress: bool = True,
    normals=None,
    noise: str = "auto",
    nu: float | None = None,
    ffd: tuple[int, int, int] | None = None,
    ffd_tau: float | None = None,
    stop_when_converged: bool = True,
    start=None,
    precision: str = "auto",
    free=None,
    size_prior: tuple[float, float] | None = None,
    init: str = "auto",
    overwrite: bool = False,
    pose=None,
) -> dict:
    """Sample the contact-level posterior of ``points (M, 3)`` m and write the run folder ``out``.

    Parameters
    ----------
    points : (M, 3) float, metres
        The contacts as an array (a path is refused: :func:`bayestouch.fit` reads files, or pass
        ``bayestouch.load_contact_points(PATH).points``).
    out : path
        The run folder.
    seed : int
        Seeds the initial fit, the walkers and emcee's random state (checked after setting).
    walkers, steps : int
        Ensemble size and the largest number of steps of the chain.
    resume : bool
        Continue the chain in ``out/chain.h5`` up to ``steps`` (nothing already sampled is lost); refused when
        ``out`` holds a run of other data or options (:mod:`bayestouch.io.runfolder`).
    overwrite : bool
        Replace a run already in ``out``, which is otherwise refused.
    budget_s : float, seconds
        Wall-clock time of the whole fit: the SMC and the optimum check take shares of it, and the chain stops
        early enough (:func:`sampling_budget`) for the outputs to be written by about then; the chain still runs
        :data:`MIN_CHAIN_STEPS` steps, and a chain stopped by the budget says so in the summary.
    stop_when_converged : bool
        Stop before ``steps`` once the chain is longer than 50 autocorrelation times, τ is stable and R-hat and
        the bulk ESS pass (:func:`bayestouch.inference.sampler.sample`).

        Sampling is adaptive (``sample(..., adapt=True)``): differential-evolution moves for the first 100 steps,
        then mostly independence proposals from a multivariate t fitted to the draws so far (refitted at steps
        200, 400, …), which on a near-Gaussian posterior cuts τ from ~45 steps to ~5.
    normals : (M, 3) float, optional
        Measured outward normals: adds the von Mises-Fisher term (and κ).
    noise : {"auto", "outlier", "student", "gaussian", "multiplicative", "mixture"}
        Residual model (:mod:`bayestouch.inference.contact`). ``"outlier"``: a Gaussian core with contacts
        displaced into the solid and out into free space as separate outlier events (fractions w_in, w_out).
        ``"gaussian"``: Student-t with ν = ∞ (as ``bayestouch fit --noise gaussian``). ``"auto"`` (default):
        ``"outlier"`` for a fit started by SMC, ``"student"`` (robust, 11 parameters) for a fit from the optimum
        (dense data surrounding the object), with ``start`` (an exploration's 11-parameter ensemble) or with
        ``ffd``; ``nu`` is Student-t's degrees of freedom (default from ``models/priors.toml``; inf is Gaussian).
    free : (K, 3) float, metres, optional
        Free-space points: finger positions that touched nothing (outside the object).
    size_prior : (min, max) float, metres, optional
        Objects ``min``–``max`` across (the central 95 % of each axis's full length); default
        ``models/priors.toml`` size_min, size_max.
    init : {"auto", "smc", "optimize"}
        How the chain starts. ``"auto"`` (default): ``"optimize"`` for dense data that surround the object
        (:func:`surrounds`: at least :data:`DENSE_POINTS` contacts on both sides of every principal axis of the
        evolutionary-search optimum), where the posterior is one near-Gaussian mode and the optimum's ball
        converges in seconds, else ``"smc"``. ``"smc"``: from a tempered SMC from the prior (:func:`smc_stage`; the
        particles, evidence and temperatures in ``smc.npz``), its walkers drawn from the particles aligned to one
        alias (:func:`align_particles`) and its moves mostly an independence mixture fitted to them
        (:func:`smc_moves`: EM, components by BIC), so separated modes are found and walked between;
        ``"optimize"`` from a small ball around the evolutionary-search optimum (:func:`initial_theta`) with the
        adaptive t proposal. Ignored with ``start`` or ``ffd``.
    pose : EnsembleModel, optional
        The contacts' pose-error law (:func:`bayestouch.inference.pose_error.ensemble_model` of these ``points``,
        e.g. from :meth:`bayestouch.planning.device_prober.DeviceProber.pose_ensemble`): the pad's pose error is
        marginalised (:func:`~bayestouch.inference.pose_error.make_ensemble_pose_log_prob`, Gaussian contact
        noise) and its scale sampled (``pose_scale``). Not combined with ``normals``, ``ffd``, ``free`` or another
        noise model. The likelihood couples the contacts of a stroke, so ``posterior.nc`` has no pointwise
        log-likelihood or replicated data, and the residuals' neighbour check (``misfit``) is not made: the pose
        error correlates neighbouring residuals by design.
    ffd : (l, m, k) int, optional
        Refine the n-ellipsoid with an FFD lattice of this size, marginalised analytically (Gaussian noise);
        ``ffd_tau`` (m) is the prior sd of the control-point displacements. Not combined with normals or another
        noise model.
    start : (walkers, D) or (walkers, 11) float, optional
        A starting ensemble in θ (e.g. the last ensemble of an exploration's posterior; an 11-parameter one gets the
        noise model's extra parameters at their usual start): replaces the evolutionary initial fit; walkers are
        clipped into the prior box, and walkers stuck far below the best are replaced
        (:func:`bayestouch.inference.sampler.prune_stuck_walkers`).
    precision : {"auto", "float64", "mixed"}
        Arithmetic of the log-density the sampler evaluates (:func:`bayestouch.inference.contact.make_log_prob`):
        ``"auto"`` is ``"mixed"`` where it applies (Student-t or Gaussian noise without normals or FFD) and
        ``"float64"`` elsewhere. Its error (< 3e-4 nat for 1000 points, ~2e-3 for 10,000; measured in
        ``benchmarks/bench_inference.py``) moves any posterior probability by less than that many parts (a target
        perturbed by a factor e^ε with |ε| ≤ δ is within total variation ½(e^(2δ) − 1) ≈ δ of it), far below the
        Monte-Carlo error of the run. The initial fit, the summaries and the pointwise log-likelihood are float64.

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    t0 = time.perf_counter()
    release_compiled()
    points, _ = cm.check_points(points)  # a path, text or a wrong shape refused before any work
    check_path(out, "out")
    check_walkers(walkers)
    check_seed(seed)
    check_int(steps, "steps", 1, None, "an integer number of steps")
    check_budget(budget_s)
    check_bools(resume=resume, overwrite=overwrite, progress=progress, stop_when_converged=stop_when_converged)
    free = cm.check_free(free)
    out = Path(out)
    priors = cm.load_priors()
    if size_prior is not None and ffd is not None:
        raise BadInput("size_prior: the FFD-marginalised fit keeps its own prior; give size_prior or ffd, not both")
    if size_prior is not None:
        priors = cm.with_size_prior(priors, *size_prior)
    if init not in ("auto", "smc", "optimize"):
        raise BadInput(f"init: expected 'auto', 'smc' or 'optimize', got {init!r}")
    if noise not in ("auto", "gaussian", *cm.NOISE_MODELS):
        raise BadInput(
            f"noise: unknown noise model {noise!r}; expected one of auto, gaussian, {', '.join(cm.NOISE_MODELS)}"
        )
    if nu is not None and not (isinstance(nu, int | float) and (NU_RANGE[0] <= nu <= NU_RANGE[1] or nu == np.inf)):
        # ν = 1e300 or 1e-300 overflowed to "every particle has zero likelihood", exit 1, after JAX warnings
        raise BadInput(
            f"nu: Student-t degrees of freedom must be in [{NU_RANGE[0]:g}, {NU_RANGE[1]:g}] (or inf: Gaussian), "
            f"got {nu!r}"
        )
    if noise == "gaussian":  # the command line's name for Student-t with ν = ∞
        if nu is not None and not np.isinf(nu):
            raise BadInput(f"nu: the gaussian noise model has no degrees of freedom (nu = inf), got nu={nu}")
        noise, nu = "student", float("inf")
    if pose is not None:
        _check_pose(pose, points, ffd=ffd, normals=normals, free=free, noise=noise, nu=nu, precision=precision)
        noise, nu, precision = "student", float("inf"), "float64"
    theta0 = None
    if init == "auto":
        init = "smc"
        if start is None and ffd is None and pose is None and len(points) >= DENSE_POINTS:
            theta0 = initial_theta(points, seed, priors)
            if surrounds(points, theta0):
                init = "optimize"
    if noise == "auto":
        # dense data surrounding the object: Student-t, whose near-Gaussian posterior the optimum's t proposal
        # samples in seconds; else the outlier model, whose fractions w_in, w_out near 0 the SMC start handles
        noise = "student" if init == "optimize" or ffd is not None or start is not None else "outlier"
    if free is not None:
        free = free if len(free) else None
    if normals is not None:
        check_normals_outward(points, normals)
    sampled = cm.PARAM_NAMES
    logp_exact = None  # a float64 twin of a mixed-precision logp, for the optimum check
    if pose is not None:
        logp, bounds = pe.make_ensemble_pose_log_prob(pose, priors)
        sampled = pe.ENSEMBLE_PARAM_NAMES
        model = pose_contact_model(points, pose)
    elif ffd is None:
        if precision not in ("auto", "float64", "mixed"):
            raise BadInput(f"precision: expected 'auto', 'float64' or 'mixed', got {precision!r}")
        if precision == "auto":
            precision = "mixed" if noise in ("student", "outlier") and normals is None else "float64"
        make = partial(
            cm.make_log_prob,
            points,
            priors,
            nu if noise == "student" else None,
            normals=normals,
            noise=noise,
            free=free,
        )
        logp, bounds = make(precision=precision)
        # the optimum check polishes in float64: the mixed log-density's float32 rounding (≲ 10⁻³ nat) stops L-BFGS's
        # line searches short of a needle-thin mode (SBC set 19: 605 nats instead of 628, 643 at the truth's mode)
        if precision == "mixed":
            logp_exact = make(precision="float64")[0]
        sampled = cm.param_names(normals is not None, noise)
        model = contact_model(
            points, priors, float(priors.student_nu if nu is None else nu), normals=normals, noise=noise, free=free
        )
    else:
        if free is not None:
            raise BadInput("--ffd: free-space points are not used by the FFD-marginalised likelihood; drop them")
        if normals is not None or noise != "student" or (nu is not None and not np.isinf(nu)):
            raise BadInput(
                "--ffd: the lattice is marginalised under Gaussian noise; use it without --noise and "
                "--nu, and with --ignore-normals for a file with normals"
            )
        tau = fm.DEFAULT_TAU if ffd_tau is None else float(ffd_tau)
        if precision == "mixed":
            raise BadInput("precision: 'mixed' is not available with --ffd; use 'auto' or 'float64'")
        precision = "float64"
        logp, bounds = fm.make_ffd_log_prob(points, ffd, tau=tau, priors=priors)
        model = ffd_contact_model(points, tuple(ffd), tau)
    options = {
        "noise": noise,
        "nu": None if nu is None else float(nu),
        "ffd": None if ffd is None else [int(k) for k in ffd],
        "ffd_tau": None if ffd is None else tau,
        "precision": precision,
        "init": init,
        "pose": None if pose is None else {"offset_sd": pose.offset_sd, "rank": int(pose.lead.shape[2])},
        "walkers": int(walkers),
        "seed": int(seed),
        "priors": {k: float(v) for k, v in priors._asdict().items()},
        # the coordinates chain.h5 holds (cm.to_sampling): a chain of another version's log-axis draws is not resumed
        "sampling": "log axes" if ffd is not None else "axes in metres",
        # a chain of an older version has its Euler angles anywhere, outside this version's windows
        "angles": "one period around the start",
    }
    data = {"points": points, "normals": normals, "free-space points": free}
    if pose is not None:  # the law itself: another law over the same points is another run
        data.update({"pose-error law": np.concatenate([pose.moved.ravel(), pose.lead.ravel(), pose.resid.ravel()])})
    fp = fingerprint("contact", data, options)
    prepare_run_folder(out, fp, resume=resume, overwrite=overwrite)

    def initial():
        if start is not None:
            lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
            ens = np.asarray(start, float)
            if ens.ndim == 2 and ens.shape == (walkers, 11) and len(sampled) > 11:
                # an 11-parameter ensemble (e.g. an exploration's): the likelihood's extra parameters start where a
                # fresh fit's do
                rng = np.random.default_rng([seed, 0xE7])
                extra = [_EXTRA_START[k] + _EXTRA_SCALE[k] * np.abs(rng.standard_normal(walkers)) for k in sampled[11:]]
                ens = np.column_stack([ens, *extra])
            if ens.shape != (walkers, len(sampled)):
                raise BadInput(f"start: expected an ensemble of shape ({walkers}, {len(sampled)}), got {ens.shape}")
            ens = np.clip(cm.wrap_angles(ens), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
            ens, _ = prune_stuck_walkers(ens, logp(ens), np.random.default_rng(seed))
            return np.clip(ens, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        if smc is not None:
            return smc_start
        t0_ = initial_theta(points, seed, priors) if theta0 is None else theta0
        return start_ball(t0_, bounds, walkers, np.random.default_rng(seed), sampled)

    # emcee moves the semi-axes in metres (cm.to_sampling: the ridge of an unseen axis is straight there); the FFD fit
    # keeps its own coordinates
    logp_s, monitor = logp, judged_quantities(model.names, model.natural)
    if ffd is None:
        logp_s, monitor = cm.sampling_log_prob(logp), _composed(monitor, cm.from_sampling)
    smc, moves, around = None, None, None
    if init == "smc" and start is None and ffd is None:
        if not resume:
            for name in ("smc.npz", OPTIMUM_FILE):
                (out / name).unlink(missing_ok=True)
        share = None if budget_s is None else SMC_BUDGET_SHARE * budget_s
        smc = smc_stage(logp, bounds, seed, out / "smc.npz", progress=progress, budget_s=share)
        post = np.asarray(smc["log_lik"]) + np.asarray(_prior_jit(jnp.asarray(smc["particles"]), bounds))
        # the optimum check of the run itself on a resume: searched again under another deadline, it could find
        # another optimum, and the resumed chain would continue with other angle windows and proposals
        opt = read_optimum(out / OPTIMUM_FILE) if resume else None
        if opt is None:
            left = None if budget_s is None else max(OPTIMUM_BUDGET_SHARE * budget_s - (time.perf_counter() - t0), 0.0)
            trimmed = []
            contaminated = contaminated_share(smc["particles"], sampled) >= TRIM_TRIGGER
            if contaminated:
                trimmed = trimmed_starts(
                    points, lambda sub, step: candidate_thetas(sub, seed + 101 + step, priors, TRIM_SEARCHES)[0]
                )
            opt = optimum_mode(
                points,
                logp if logp_exact is None else logp_exact,
                bounds,
                priors,
                seed,
                sampled,
                theta0,
                batch=walkers,
                budget_s=left,
                extra_starts=trimmed,
                anneal=contaminated,
            )
            opt["trimmed_starts"] = len(trimmed)
            save_stage(out / OPTIMUM_FILE, opt)
        best_particle = float(np.max(post))
        missed = opt["log_post"] - best_particle > MISSED_MODE_NATS
        smc["optimum_above_particles"] = opt["log_post"] - best_particle
        smc["trimmed_starts"] = int(opt["trimmed_starts"])
        # one compact cloud: the particles as the aliases nearest the best particle's (or the missed optimum's) frame
        aligned = align_particles(smc["particles"], post, opt["theta"] if missed else None)
        # one period of each Euler angle around the cloud (cm.angle_window): the mixture, the start and the missed
        # mode in the window the chain is held to (alignment leaves ψ, of period π, anywhere within π of the frame)
        around = cm.angle_centres(aligned)
        aligned = cm.shift_angles(aligned, around)
        positive = [i for i, name in enumerate(sampled) if name in POSITIVE_NEAR_ZERO]
        mode = _mode_for_sampling({**opt, "theta": cm.shift_angles(opt["theta"], around)}) if missed else None
        moves, smc_start = smc_moves(
            cm.to_sampling(aligned), walkers, seed, extra_mode=mode, logp=logp_s, log_columns=positive
        )
        smc_start = cm.from_sampling(smc_start)

    # the chain's start, made on a resume too (the same data, options and seed make the same one): the Euler angles
    # are held to one period around it, or around the SMC's particles (cm.angle_window), the run's own windows
    first = initial() if ffd is not None else cm.to_sampling(initial())
    around = cm.angle_centres(first) if around is None else around
    logp_s = cm.angle_window(logp_s, around)
    ch = sample(
        logp_s,
        cm.shift_angles(first, around),
        out / "chain.h5",
        walkers=walkers,
        ndim=len(sampled),
        seed=seed,
        steps=steps,
        resume=resume,
        budget_s=sampling_budget(budget_s, OUTPUT_SECONDS + OUTPUT_SECONDS_PER_POINT * len(points)),
        min_steps=MIN_CHAIN_STEPS,
        progress=progress,
        t0=t0,
        stop_when_converged=stop_when_converged,
        adapt=True,
        moves=moves,
        monitor=monitor,
    )
    if ffd is None:
        ch = _chain_from_sampling(ch)
    info = {**model.info, "precision": precision, "init": "start" if start is not None else init}
    if smc is not None:
        info["smc"] = {
            "particles": int(len(smc["particles"])),
            "stages": int(len(smc["betas"]) - 1),
            "complete": bool(smc["complete"]),
            "log_evidence": float(smc["log_evidence"]),
            "evaluations": int(smc["evaluations"]),
            "seconds": float(smc["seconds"]),
            # the polished evolutionary-search optimum's log-posterior above the best particle's (nats); above
            # MISSED_MODE_NATS its mode was added to the start and the proposals (optimum_mode)
            "optimum_above_particles": float(smc["optimum_above_particles"]),
            "missed_mode_added": bool(smc["optimum_above_particles"] > MISSED_MODE_NATS),
            "trimmed_starts": int(smc["trimmed_starts"]),
        }
    model = model._replace(info=info)
    summary = write_posterior(out, ch, model, seed=seed, t0=t0)
    if ffd is None:  # a lattice moves the surface off the n-ellipsoid the draws describe
        _write_occupancy(out, ch, summary, seed)
        if pose is None:  # a pose error correlates neighbouring residuals by design
            _report_misfit(summary, ch, points, seed)
        _report_noise_size(summary, ch)
        _report_reach(summary, ch, points, seed)
    summary = _report_modes(out, summary, ch, model, seed, smc)
    release_run_folder(out)
    return summary


def _composed(f, g):
    """x ↦ f(g(x))."""

    def h(x):
        return f(g(x))

    return h


def _mode_for_sampling(opt: dict) -> dict:
    """:func:`optimum_mode`'s Laplace approximation N(θ*, Σ) in :func:`bayestouch.inference.contact.to_sampling`'s
    coordinates: u* = u(θ*) and J Σ Jᵀ, J = du/dθ = diag(1, …, e^θ_axes, …, 1)."""
    theta = np.asarray(opt["theta"], float)
    jac = np.ones(len(theta))
    jac[list(cm.AXIS_COLUMNS)] = np.exp(theta[list(cm.AXIS_COLUMNS)])
    return {**opt, "theta": cm.to_sampling(theta), "cov": np.asarray(opt["cov"], float) * np.outer(jac, jac)}


def _chain_from_sampling(ch):
    """A :func:`~bayestouch.inference.sampler.sample` result in :func:`bayestouch.inference.contact.to_sampling`'s
    coordinates as θ: draws mapped back, log-posteriors of θ (the sampled density plus Σ log semi-axis)."""
    theta = cm.from_sampling(ch.kept)
    lp = np.asarray(ch.log_prob, float) + np.sum(theta[..., list(cm.AXIS_COLUMNS)], axis=-1)
    return ch._replace(kept=theta, log_prob=lp)


#: thinned draws the occupancy grid of a contact fit averages
OCCUPANCY_DRAWS = 400


def _write_occupancy(out: Path, ch, summary: dict, seed: int) -> None:
    """``occupancy.npz`` (:mod:`bayestouch.io.occupancy`) from thinned draws of the chain: the posterior probability
    that a point is inside the object, the same summary a parts fit writes."""
    flat = ch.kept.reshape(-1, ch.kept.shape[2])
    rng = np.random.default_rng([seed, 0x0CC])
    pick = rng.choice(len(flat), min(OCCUPANCY_DRAWS, len(flat)), replace=False)
    theta = np.column_stack([flat[pick, :10], np.zeros((len(pick), 3))])
    write_occupancy(out / OCCUPANCY_FILE, occupancy_grid(theta, 1))
    summary["files"] = [*summary["files"], OCCUPANCY_FILE]


def _report_misfit(summary: dict, ch, points, seed: int) -> None:
    """Add the residuals' neighbour correlation (:func:`bayestouch.inference.misfit.residual_structure`) to the
    summary's diagnostics, ``misfit`` and a warning when the shape leaves structure, not noise."""
    r = residual_structure(points, ch.kept.reshape(-1, ch.kept.shape[2]), seed)
    diag = summary["diagnostics"]
    diag["misfit"] = r["misfit"]
    diag["residual_neighbour_correlation"] = {k: r[k] for k in ("rho", "z", "pairs")}
    if r["misfit"]:
        diag["warnings"] = [
            *diag.get("warnings", []),
            f"misfit: neighbouring contacts' residuals correlate (rank rho {r['rho']:.2f}, {r['z']:.1f} sd above 0): "
            "the shape leaves structure, not noise (a mode that is not the data's, or an object outside the "
            "n-ellipsoid family); its intervals are not to be trusted",
        ]


#: posterior median of σ over the smallest semi-axis above which a contact fit warns: there the first-order
#: distance likelihood no longer describes 3-D contact noise (benchmarks/bench_sbc_users.py: above 5 % the truth
#: lies outside its own local mode in 58 % of sets, 90 % intervals cover 0.58 pooled; docs/sbc.md)
NOISE_SIZE_LIMIT = 0.05


def noise_to_size(draws) -> float:
    """Posterior median of σ over the smallest semi-axis (dimensionless) from draws ``(..., D)`` of θ (log semi-axes
    in columns 3–5, log σ in column 10)."""
    x = np.asarray(draws, float).reshape(-1, np.shape(draws)[-1])
    return float(np.median(np.exp(x[:, 10] - np.min(x[:, 3:6], axis=1))))


def _report_noise_size(summary: dict, ch) -> None:
    """Add :func:`noise_to_size` to the summary's diagnostics, ``noise_large`` and a warning above
    :data:`NOISE_SIZE_LIMIT`."""
    ratio = noise_to_size(ch.kept)
    diag = summary["diagnostics"]
    diag["noise_to_smallest_axis"] = ratio
    diag["noise_large"] = ratio > NOISE_SIZE_LIMIT
    if diag["noise_large"]:
        diag["warnings"] = [
            *diag.get("warnings", []),
            f"noise: σ is {100 * ratio:.0f} % of the smallest semi-axis (posterior median), above "
            f"{100 * NOISE_SIZE_LIMIT:.0f} %: the distance likelihood is a first-order approximation there and its "
            "intervals are too narrow (docs/sbc.md); more precise contacts or a larger object would help",
        ]


def _report_reach(summary: dict, ch, points, seed: int) -> None:
    """Add how far the surface reaches beyond the contacts (:func:`bayestouch.inference.reach.surface_reach`:
    posterior median and 5–95 % range) to the summary's diagnostics, ``extrapolated`` and a warning above
    :data:`~bayestouch.inference.reach.REACH_LIMIT`."""
    r = surface_reach(points, ch.kept.reshape(-1, ch.kept.shape[2]), seed)
    diag = summary["diagnostics"]
    if len(r) == 0:
        diag["reach"], diag["extrapolated"] = None, False
        return
    med = float(np.median(r))
    diag["reach"] = {"median": med, "q05": float(np.quantile(r, 0.05)), "q95": float(np.quantile(r, 0.95))}
    diag["extrapolated"] = med > REACH_LIMIT
    if diag["extrapolated"]:
        diag["warnings"] = [
            *diag.get("warnings", []),
            f"extrapolated: the surface runs up to {med:.1f} times the contacts' span from the nearest contact "
            "(posterior median): there the shape is the n-ellipsoid family's extension of the touched part, not "
            "the data's, and its intervals hold only if the object belongs to that family (a tapered, bent or "
            "composite object does not); touch the far side, or give free-space positions that bound it",
        ]


def surrounds(points, theta, fraction: float = SURROUND_FRACTION) -> bool:
    """Whether contact points ``points (M, 3)`` m surround the n-ellipsoid θ (≥ 10,): on each side of each of its
    principal axes (scaled principal coordinate beyond ±½) lie at least ``fraction`` of the points."""
    s = cm.shape_of(jnp.asarray(theta[:10]))
    q = (np.asarray(points) - np.asarray(s.centre)) @ np.asarray(s.rotation) / np.asarray(s.axes)
    return bool(np.all((q > 0.5).mean(axis=0) >= fraction) and np.all((q < -0.5).mean(axis=0) >= fraction))


def _report_modes(out: Path, summary: dict, ch, model: PosteriorModel, seed: int, smc) -> dict:
    """Add the posterior's separated modes (:func:`describe_modes`, from the kept draws) and, from the SMC
    particles, the modes the global stage found, to ``summary.json``; a multimodal posterior or an SMC stage that
    did not reach β = 1 is a warning, and a multimodal one is never reported as converged."""
    kept = ch.kept.reshape(-1, ch.kept.shape[2])
    nat = model.natural(kept)
    modes = describe_modes(nat, draw_volumes(nat), seed)
    diag = summary["diagnostics"]
    diag["modes"] = modes
    diag["multimodal"] = len(modes) > 1
    warnings = list(diag.get("warnings", []))
    if smc is not None:
        pn = model.natural(np.asarray(smc["particles"]))
        diag["smc_modes"] = describe_modes(pn, draw_volumes(pn), seed)
        if not smc["complete"]:
            warnings.append("tempering stopped before the posterior (beta < 1): the start is not a posterior sample")
        if len(diag["smc_modes"]) > 1 and len(modes) == 1:
            warnings.append(
                f"the tempered SMC found {len(diag['smc_modes'])} modes but the chain holds one: "
                "the chain may have lost a mode; see diagnostics.smc_modes"
            )
    if len(modes) > 1:
        desc = ", ".join(
            f"{m['weight']:.0%}: volume {m['volume_m3']['mean'] * 1e6:.3g} cm^3, n {m['n']['mean']:.2g}" for m in modes
        )
        warnings.append(
            f"multimodal posterior: {len(modes)} separated shapes ({desc}); the posterior mean describes none of "
            "them, see diagnostics.modes"
        )
    diag["warnings"] = warnings
    write_json(out / "summary.json", summary)
    return summary
