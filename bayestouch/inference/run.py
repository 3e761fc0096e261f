"""The contact-level fit: the initial estimate of the n-ellipsoid from contact points (m), the walkers' start, the
canonicalised natural parameters of draws, the contact level's :class:`~bayestouch.inference.posterior.PosteriorModel`
(Student-t, multiplicative, mixture or FFD-marginalised likelihood) and :func:`run_contact_fit`, which samples it
and writes the run folder (:func:`bayestouch.inference.posterior.write_posterior`).

θ (11,) or more is the contact level's sampled vector (:mod:`bayestouch.inference.contact`); points are (M, 3) m.
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.symmetry import canonicalize_batch
from bayestouch.inference import contact as cm
from bayestouch.inference import ffd_marginal as fm
from bayestouch.inference.de import de_search
from bayestouch.inference.posterior import PosteriorModel, vmf_sample, write_posterior
from bayestouch.inference.sampler import prune_stuck_walkers, sample

__all__ = [
    "initial_theta",
    "run_contact_fit",
    "contact_model",
    "ffd_contact_model",
    "NATURAL_NAMES",
    "natural_draws",
    "start_ball",
]

#: summary names (natural units) of the 11 sampled contact-level parameters
NATURAL_NAMES = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n", "sigma")


@jax.jit
@partial(jax.vmap, in_axes=(0, None))
def _foot_and_normal(theta, pts):
    s = cm.shape_of(theta)
    foot = ne.project_to_surface(s, pts)
    return foot, ne.normals(s, foot)


# module level, data as arguments: one compiled program per number of points, shared by every initial fit
_neg_log_post_and_grad = jax.jit(
    jax.value_and_grad(lambda t, pts, bounds, nu: -cm.log_prob(t, pts, bounds, nu)), static_argnums=3
)


def initial_theta(points, seed: int, priors: cm.PriorParams, starts: int = 3) -> np.ndarray:
    """A starting point that respects the symmetries and resists outliers.

    ``starts`` independent differential-evolution searches of the 10 shape parameters on the radial cost
    (:func:`bayestouch.inference.de.de_search`, one compiled program, at most 128 points; symmetry-reduced angle
    ranges; centre within the data centroid ± half the data's span, semi-axes up to 1.2 × the data's radius), each
    polished by L-BFGS-B on the robust (Student-t) log-posterior the sampler uses, on all points and inside the same
    search box; the start with the highest log-posterior wins. σ starts from the search's RMS.

    The box is deliberate: on data covering one side of an object, a wider search (or an unconstrained robust
    polish) runs off to surfaces several times too large whose local curvature matches the touched patch — the
    likelihood cannot tell them apart, and the sampler explores that ridge from a sensible start instead.
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
    found, cost = de_search(pts, de_lo, de_hi, seed, starts=starts, max_points=128)
    pj = jnp.asarray(pts)
    nu = float(priors.student_nu)

    def fg(t):
        v, g = _neg_log_post_and_grad(jnp.asarray(t), pj, bounds, nu)
        return float(v), np.asarray(g)

    best, best_val = None, np.inf
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
        v0 = fg(t0)[0]
        res = minimize(
            fg, t0, jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi, strict=True)), options={"maxiter": 500}
        )
        t, val = (res.x, res.fun) if np.isfinite(res.fun) and res.fun <= v0 else (t0, v0)
        if val < best_val:
            best, best_val = t, val
    return best


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
    p = np.clip(theta0, lo, hi) + scale * rng.normal(size=(n, theta0.size))
    return np.clip(p, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))


#: natural names and transforms of the optional contact-level parameters (after σ)
_EXTRA_NATURAL = {"log_kappa": ("kappa", np.exp), "log_eps": ("epsilon", np.exp), "w_outlier": ("w_outlier", None)}


def natural_draws(flat: np.ndarray, sampled: tuple = cm.PARAM_NAMES) -> np.ndarray:
    """θ draws (S, D) with parameter names ``sampled`` → canonicalised natural parameters (S, D): centre,
    a ≥ b ≥ c, angles, n, σ, then the optional parameters (κ, ε, w) in natural units."""
    v = np.column_stack([flat[:, :3], np.exp(flat[:, 3:6]), flat[:, 6:9], np.exp(flat[:, 9])])
    extra = [np.exp(flat[:, 10])]
    for j, name in enumerate(sampled[11:], start=11):
        fn = _EXTRA_NATURAL[name][1]
        extra.append(fn(flat[:, j]) if fn is not None else flat[:, j])
    return np.column_stack([canonicalize_batch(v), *extra])


#: starting values of the optional parameters: κ = 100 (normals good to ~6°), ε = 10⁻³ (the paper's), w = 5 %
_EXTRA_START = {"log_kappa": np.log(100.0), "log_eps": np.log(1e-3), "w_outlier": 0.05}
_EXTRA_SCALE = {"log_kappa": 1e-2, "log_eps": 1e-2, "w_outlier": 1e-3}


def contact_model(points, priors: cm.PriorParams, nu: float, *, normals=None, noise: str = "student") -> PosteriorModel:
    """The contact level as a :class:`~bayestouch.inference.posterior.PosteriorModel`: pointwise log-likelihood of
    each point (:func:`~bayestouch.inference.contact.pointwise_log_likelihood`); replicated points are surface points
    of each draw displaced along the normal by noise of the model's scale (Student-t or Gaussian σ; σ_i for the
    multiplicative model; the mixture's outliers are drawn uniformly along the normal within the data's extent);
    with measured ``normals``, replicated normals are von Mises–Fisher (κ of the draw) about the draw's normal
    (:func:`~bayestouch.inference.posterior.vmf_sample`), and the observed group holds the normalised measured
    normals too."""
    pts = jnp.asarray(points, dtype=jnp.float64)
    m = len(points)
    sampled = cm.param_names(normals is not None, noise)
    names = NATURAL_NAMES + tuple(_EXTRA_NATURAL[k][0] for k in sampled[11:])
    lo, hi = np.asarray(points).min(axis=0), np.asarray(points).max(axis=0)
    half_diag = 0.5 * float(np.linalg.norm(hi - lo))
    lever = np.asarray(points) - np.asarray(points).mean(axis=0)

    def predictive(thetas, rng):
        foot, nrm = (np.asarray(a) for a in _foot_and_normal(jnp.asarray(thetas[:, :11]), pts))
        shape = (len(thetas), m)
        sigma = np.exp(thetas[:, 10])[:, None]
        if noise == "student":
            e = sigma * (rng.standard_normal(shape) if np.isinf(nu) else rng.standard_t(nu, shape))
        elif noise == "multiplicative":
            k = sampled.index("log_eps")
            var = sigma**2 + np.exp(2 * thetas[:, k])[:, None] / 3 * np.einsum("wmk,mk->wm", nrm**2, lever**2)
            e = np.sqrt(var) * rng.standard_normal(shape)
        else:
            w = thetas[:, sampled.index("w_outlier")][:, None]
            e = np.where(
                rng.random(shape) < w, rng.uniform(-half_diag, half_diag, shape), sigma * rng.standard_normal(shape)
            )
        rep = {"points": foot + e[..., None] * nrm}
        if normals is not None:  # measured normals: vMF about the draw's normal at its replicated foot point
            rep["normals"] = vmf_sample(nrm, np.exp(thetas[:, sampled.index("log_kappa")])[:, None], rng)
        return rep

    def ll(thetas):
        return cm.pointwise_log_likelihood(thetas, points, nu, normals=normals, noise=noise)

    likelihood = {
        "student": "Gaussian" if np.isinf(nu) else f"Student-t, nu = {nu:g}",
        "multiplicative": "Gaussian with the paper's multiplicative (1 + r) perturbation",
        "mixture": "Gaussian + uniform outlier mixture",
    }[noise]
    if normals is not None:
        likelihood += "; normals: von Mises-Fisher"
    observed = {"points": np.asarray(points)}
    if normals is not None:
        nn = np.asarray(normals, float)
        observed["normals"] = nn / np.linalg.norm(nn, axis=1, keepdims=True)
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
            "parameters_sampled": list(sampled),
        },
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
        return np.asarray(conditional(jnp.asarray(thetas))[0])

    def predictive(thetas, rng):
        foot = np.asarray(conditional(jnp.asarray(thetas))[1])
        return {"points": foot + np.exp(thetas[:, 10])[:, None, None] * rng.standard_normal(foot.shape)}

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
        {"points": np.asarray(points)},
        {
            "level": "contact",
            "likelihood": "Gaussian, FFD lattice marginalised",
            "ffd_size": "x".join(map(str, dims)),
            "ffd_tau_m": tau,
            "n_points": int(m),
            "parameters_sampled": list(cm.PARAM_NAMES),
        },
        refine,
    )


def run_contact_fit(
    points,
    out: Path,
    *,
    seed: int = 0,
    walkers: int = 32,
    steps: int = 20000,
    resume: bool = False,
    budget_s: float | None = None,
    progress: bool = True,
    normals=None,
    noise: str = "student",
    nu: float | None = None,
    ffd: tuple[int, int, int] | None = None,
    ffd_tau: float | None = None,
    stop_when_converged: bool = True,
    start=None,
    precision: str = "auto",
) -> dict:
    """Sample the contact-level posterior of ``points (M, 3)`` m and write the run folder ``out``.

    Parameters
    ----------
    seed : int
        Seeds the initial fit, the walkers and emcee's random state (checked after setting).
    walkers, steps : int
        Ensemble size and the largest number of steps of the chain.
    resume : bool
        Continue the chain in ``out/chain.h5`` up to ``steps`` (nothing already sampled is lost).
    budget_s : float, seconds
        Stop sampling after this wall-clock time (the summary says so).
    stop_when_converged : bool
        Stop before ``steps`` once the chain is longer than 50 autocorrelation times, τ is stable and R-hat and
        the bulk ESS pass (:func:`bayestouch.inference.sampler.sample`).

        Sampling is adaptive (``sample(..., adapt=True)``): differential-evolution moves for the first 100 steps,
        then mostly independence proposals from a multivariate t fitted to the draws so far (refitted at steps
        200, 400, …), which on a near-Gaussian posterior cuts τ from ~45 steps to ~5.
    normals : (M, 3) float, optional
        Measured outward normals: adds the von Mises-Fisher term (and κ).
    noise : {"student", "multiplicative", "mixture"}
        Residual model (:mod:`bayestouch.inference.contact`); ``nu`` is Student-t's degrees of freedom
        (default from ``models/priors.toml``; inf is Gaussian).
    ffd : (l, m, k) int, optional
        Refine the n-ellipsoid with an FFD lattice of this size, marginalised analytically (Gaussian noise);
        ``ffd_tau`` (m) is the prior sd of the control-point displacements. Not combined with normals or another
        noise model.
    start : (walkers, D) float, optional
        A starting ensemble in θ (e.g. the last ensemble of an exploration's posterior): replaces the evolutionary
        initial fit; walkers are clipped into the prior box, and walkers stuck far below the best are replaced
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
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    priors = cm.load_priors()
    sampled = cm.PARAM_NAMES
    if ffd is None:
        if precision not in ("auto", "float64", "mixed"):
            raise BadInput(f"precision: expected 'auto', 'float64' or 'mixed', got {precision!r}")
        if precision == "auto":
            precision = "mixed" if noise == "student" and normals is None else "float64"
        logp, bounds = cm.make_log_prob(
            points, priors, nu if noise == "student" else None, normals=normals, noise=noise, precision=precision
        )
        sampled = cm.param_names(normals is not None, noise)
        model = contact_model(
            points, priors, float(priors.student_nu if nu is None else nu), normals=normals, noise=noise
        )
    else:
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

    def initial():
        if start is not None:
            lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
            ens = np.asarray(start, float)
            if ens.shape != (walkers, len(sampled)):
                raise BadInput(f"start: expected an ensemble of shape ({walkers}, {len(sampled)}), got {ens.shape}")
            ens = np.clip(ens, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
            ens, _ = prune_stuck_walkers(ens, logp(ens), np.random.default_rng(seed))
            return np.clip(ens, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        theta0 = initial_theta(points, seed, priors)
        return start_ball(theta0, bounds, walkers, np.random.default_rng(seed), sampled)

    ch = sample(
        logp,
        initial,
        out / "chain.h5",
        walkers=walkers,
        ndim=len(sampled),
        seed=seed,
        steps=steps,
        resume=resume,
        budget_s=budget_s,
        progress=progress,
        t0=t0,
        stop_when_converged=stop_when_converged,
        adapt=True,
        monitor=model.natural,
    )
    model = model._replace(info={**model.info, "precision": precision})
    return write_posterior(out, ch, model, seed=seed, t0=t0)
