"""Adaptive tempered sequential Monte Carlo from the prior: the global stage of a fit on sparse data.

Sparse, one-sided or contaminated contact sets give posteriors with ridges along unseen directions, several
separated modes (exponents or axis lengths the data do not resolve, different contacts as the outliers) and heavy
tails; a local optimiser followed by an ensemble MCMC started in a small ball finds one mode and reports it with
confidence. Tempering from the prior finds all modes with prior mass in proportion and estimates the evidence.

The sampler (Del Moral, Doucet & Jasra 2006, JRSS B 68:411; adaptive temperatures by a conditional-ESS target,
Zhou, Johansen & Aston 2016, JCGS 25:701): particles drawn from the prior are moved through
π_β ∝ p(θ) L(θ)^β, β = 0 → 1. Each next β is the largest with conditional effective sample size ≥ ``ess_target``
· N (bisection), the particles are resampled (systematic) and moved by random-walk Metropolis steps targeting
π_β. Each particle's proposal is a Gaussian with the covariance of the k nearest neighbours of its nearest anchor
(one of a few hundred particles) in the population before resampling (fixed during the stage, so every particle's
kernel is a symmetric random walk that leaves
π_β invariant), scaled by 2.38²/D and adapted across stages towards an acceptance of ~25 %: separated modes and
curved ridges each get their own local scale, where one global covariance would be as wide as the gap between
modes. The number of steps per stage is set so that a particle moves at least once with probability 0.95 at the
previous stage's acceptance.

Pure in its inputs: the log-likelihood and log-prior are vectorised functions ``(N, D) -> (N,)`` (−inf outside
the prior), randomness comes from a ``np.random.Generator``.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from scipy.special import logsumexp

from bayestouch.inference.sampler import leapfrog

__all__ = [
    "SMCResult",
    "tempered_smc",
    "hmc_step",
    "tune_step_size",
    "local_covariances",
    "nearest_rows",
    "systematic_resample",
]


class SMCResult(NamedTuple):
    """Result of :func:`tempered_smc`.

    particles : (N, D) float
        Equally weighted draws of the posterior (β = 1), after the final moves.
    log_lik, log_prior : (N,) float
        Their log-likelihood and log-prior.
    log_evidence : float
        Estimate of log ∫ p(θ) L(θ) dθ (the prior's normalisation as given by ``sample_prior``; nats).
    betas : (T,) float
        The temperatures, 0 first and 1 last (unless stopped by the budget).
    acceptance : (T − 1,) float
        Mean acceptance of each stage's moves.
    steps : (T − 1,) int
        Metropolis steps of each stage.
    evaluations : int
        Log-likelihood evaluations (particles × calls).
    seconds : float
    complete : bool
        Reached β = 1 within the budget.
    eps : float
        The HMC step size adapted by the last stage (nan without ``gradients``).
    """

    particles: np.ndarray
    log_lik: np.ndarray
    log_prior: np.ndarray
    log_evidence: float
    betas: np.ndarray
    acceptance: np.ndarray
    steps: np.ndarray
    evaluations: int
    seconds: float
    complete: bool
    eps: float = float("nan")


def systematic_resample(weights, rng: np.random.Generator) -> np.ndarray:
    """Indices (N,) of a systematic resample of normalised ``weights (N,)`` (Kitagawa 1996)."""
    w = np.asarray(weights, float)
    n = len(w)
    c = np.cumsum(w)
    c[-1] = 1.0
    return np.searchsorted(c, (rng.random() + np.arange(n)) / n)


def local_covariances(x, k: int, centres=None, ridge: float = 1e-9) -> np.ndarray:
    """Covariance (C, D, D) of the ``k`` nearest neighbours (itself included) of each row ``centres (C,)`` (default
    every row) of a population ``x (N, D)``, neighbours found in coordinates standardised by the population's sd;
    a ridge of ``ridge`` × the population's variance keeps each one positive definite."""
    x = np.asarray(x, float)
    n, d = x.shape
    sd = x.std(axis=0) + 1e-300
    z = (x / sd).astype(np.float32)
    sq = np.sum(z * z, axis=1)
    k = int(min(max(k, d + 1), n))
    centres = np.arange(n) if centres is None else np.asarray(centres, int)
    out = np.empty((len(centres), d, d))
    for s in range(0, len(centres), 512):  # blocks keep the distance matrix small
        blk = centres[s : s + 512]
        dist = sq[blk, None] + sq[None, :] - 2.0 * z[blk] @ z.T
        nb = np.argpartition(dist, k - 1, axis=1)[:, :k]
        y = x[nb]  # (b, k, D)
        y = y - y.mean(axis=1, keepdims=True)
        out[s : s + len(blk)] = np.einsum("bki,bkj->bij", y, y) / (k - 1)
    return out + np.diag(ridge * sd**2 + 1e-300)[None]


def nearest_rows(x, centres) -> np.ndarray:
    """Index (N,) into ``centres (C,)`` of the centre row of ``x (N, D)`` nearest to each row (coordinates
    standardised by the population's sd)."""
    x = np.asarray(x, float)
    z = (x / (x.std(axis=0) + 1e-300)).astype(np.float32)
    za = z[np.asarray(centres, int)]
    return np.argmin(np.sum(za * za, axis=1)[None] - 2.0 * z @ za.T, axis=1)


def hmc_step(x, lp, ll, chol, beta: float, eps: float, steps: int, gradients, rng, cache: dict | None = None) -> int:
    """One HMC step of every particle in place (``x``, ``lp``, ``ll`` updated where accepted) for the target
    p(θ) L(θ)^β, momentum r ~ N(0, I) in coordinates whitened by ``chol (N, D, D)``, ``steps`` leapfrog steps of
    size ``eps``, ``gradients`` as :func:`tempered_smc`'s; returns the accepted count.

    ``cache``: a dict that carries ∇log p and ∇log L at ``x`` (keys ``"ga"``, ``"gb"``, (N, D) each) from one step
    to the next while nothing else moves the particles: the first leapfrog gradient is then read, not recomputed
    (the same numbers: each row's gradient depends on that row alone), and the cache is left holding the gradients
    at the particles after the step. An empty dict is filled."""
    n, d = x.shape
    start: dict = {}
    end: dict = {}

    def grad(y):
        if not start and cache and "ga" in cache:
            a, b, ga, gb = lp, ll, cache["ga"], cache["gb"]
        else:
            a, b, ga, gb = (np.asarray(v, float) for v in gradients(y))
        if not start:
            start["ga"], start["gb"] = ga, gb
        end["ga"], end["gb"] = ga, gb
        return (a, b), np.einsum("nji,nj->ni", chol, ga + beta * gb)  # Lᵀ ∇log π

    r0 = rng.standard_normal((n, d))
    y, r, (a, b) = leapfrog(x, r0, chol, eps, steps, grad)
    with np.errstate(invalid="ignore", over="ignore"):
        log_a = (a + beta * b - 0.5 * np.sum(r * r, axis=1)) - (lp + beta * ll - 0.5 * np.sum(r0 * r0, axis=1))
    acc = np.log(rng.random(n)) < np.where(np.isfinite(log_a), log_a, -np.inf)
    x[acc], lp[acc], ll[acc] = y[acc], a[acc], b[acc]
    if cache is not None:
        cache["ga"] = np.where(acc[:, None], end["ga"], start["ga"])
        cache["gb"] = np.where(acc[:, None], end["gb"], start["gb"])
    return int(acc.sum())


def tune_step_size(x, chol, gradients, rng, eps: float = 0.5, iterations: int = 40, target: float = 0.7):
    """A step size for :func:`hmc_step` at β = 1 with inverse mass matrices ``chol (N, D, D)``, from a pilot run:
    ``iterations`` HMC steps (4 leapfrog steps) of the walkers ``x (N, D)``, each followed by
    eps ← eps · exp(2 (acceptance − ``target``)). Returns (eps, the walkers after the pilot (N, D)): a warm-up,
    not part of any chain."""
    x = np.array(x, float)
    lp, ll, ga, gb = gradients(x)
    lp, ll = np.array(lp, float), np.array(ll, float)
    held = {"ga": np.asarray(ga, float), "gb": np.asarray(gb, float)}
    for _ in range(iterations):
        acc = hmc_step(x, lp, ll, chol, 1.0, eps, 4, gradients, rng, cache=held) / len(x)
        eps *= float(np.exp(2.0 * (acc - target)))
    return eps, x


def _next_beta(log_lik, beta: float, ess_target: float) -> float:
    """The largest β' ∈ (β, 1] whose incremental weights L^(β'−β) keep an ESS fraction ≥ ``ess_target``."""

    def ess(b):
        lw = (b - beta) * log_lik
        lw = lw - lw.max()
        w = np.exp(lw)
        return w.sum() ** 2 / (w * w).sum() / len(w)

    if ess(1.0) >= ess_target:
        return 1.0
    lo, hi = beta, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ess(mid) >= ess_target else (lo, mid)
    return max(lo, beta + 1e-12)


def tempered_smc(
    log_lik,
    log_prior,
    sample_prior,
    rng: np.random.Generator,
    *,
    particles: int = 2048,
    ess_target: float = 0.5,
    neighbours: int | None = None,
    anchors: int = 256,
    min_steps: int = 4,
    max_steps: int = 40,
    final_steps: int | None = None,
    max_stages: int = 500,
    budget_s: float | None = None,
    progress=None,
    gradients=None,
    hmc_steps: int = 3,
    leapfrog: int = 8,
) -> SMCResult:
    """Adaptive tempered SMC from the prior to the posterior (see the module docstring).

    Parameters
    ----------
    log_lik : callable
        ``(N, D) -> (N,)`` log-likelihood (finite wherever the prior is positive).
    log_prior : callable
        ``(N, D) -> (N,)`` log-prior density up to a constant, −inf outside its support.
    sample_prior : callable
        ``(count, rng) -> (count, D)`` independent prior draws.
    rng : np.random.Generator
    particles : int
    ess_target : float
        Conditional ESS fraction kept by each temperature step.
    neighbours : int, optional
        k of the local covariances (default max(4 D, 30)).
    anchors : int
        Particles whose neighbourhood covariances are computed each stage; every particle proposes with that of
        its nearest anchor (:func:`local_covariances`).
    min_steps, max_steps : int
        Bounds of the Metropolis steps per stage.
    final_steps : int, optional
        Steps at β = 1 after the last reweighting (default: as an ordinary stage).
    max_stages : int
    budget_s : float, seconds, optional
        Stop tempering after this long (the result then says ``complete=False``).
    progress : callable, optional
        Called as ``progress(beta, stage)`` after every stage.
    gradients : callable, optional
        ``(N, D) -> (log_prior (N,), log_lik (N,), ∇log_prior (N, D), ∇log_lik (N, D))``. With it each stage's
        moves are ``hmc_steps`` Hamiltonian Monte Carlo steps (Neal 2011) of 1 to ``leapfrog`` leapfrog steps
        (uniformly jittered) with each particle's local covariance as its inverse mass matrix and a step size
        adapted towards 65 % acceptance, before the random-walk steps: gradients follow the curved, strongly
        correlated ridges of a sparse-contact posterior that random walks cross slowly.

    Returns
    -------
    SMCResult
    """
    t0 = time.perf_counter()
    x = np.asarray(sample_prior(particles, rng), float)
    n, d = x.shape
    lp = np.asarray(log_prior(x), float)
    ll = np.asarray(log_lik(x), float)
    ll = np.where(np.isfinite(lp) & np.isfinite(ll), ll, -np.inf)
    evals = n
    k = neighbours or max(4 * d, 30)
    beta, log_z = 0.0, 0.0
    betas, accs, nsteps = [0.0], [], []
    scale = 2.38**2 / d
    acc_prev = 0.25
    eps = 0.5
    complete = False
    for _stage in range(max_stages):
        finite = np.isfinite(ll)
        if not finite.any():
            raise RuntimeError("tempered_smc: every particle has zero likelihood")
        ll_f = np.where(finite, ll, -1e300)
        nb = _next_beta(ll_f, beta, ess_target)
        lw = (nb - beta) * ll_f
        log_z += logsumexp(lw) - np.log(n)
        w = np.exp(lw - logsumexp(lw))
        # proposals from the population before resampling (diverse): each particle keeps its nearest anchor's
        anchor = rng.choice(n, min(anchors, n), replace=False)
        cov, near = local_covariances(x, k, anchor), nearest_rows(x, anchor)
        idx = systematic_resample(w, rng)
        x, lp, ll, near = x[idx], lp[idx], ll[idx], near[idx]
        beta = nb
        betas.append(beta)
        last = beta >= 1.0
        chol = np.linalg.cholesky(cov)[near]
        m = int(np.clip(np.ceil(np.log(0.05) / np.log(max(1.0 - acc_prev, 1e-3))), min_steps, max_steps))
        if last and final_steps is not None:
            m = int(final_steps)
        if gradients is not None:
            n_acc_h = 0
            held: dict = {}  # the gradients at the particles, from one HMC step to the next (none yet this stage)
            for i in range(hmc_steps):
                frogs = int(rng.integers(1, leapfrog + 1))
                n_acc_h += hmc_step(x, lp, ll, chol, beta, eps, frogs, gradients, rng, cache=held)
                evals += n * (frogs + (1 if i == 0 else 0))  # gradient calls: the first step's start, then 1 a frog
            acc_h = n_acc_h / (n * hmc_steps)
            eps *= float(np.exp(np.clip(acc_h - 0.65, -0.3, 0.3) * 3.0))
        n_acc = 0
        for _ in range(m):
            prop = x + np.sqrt(scale) * np.einsum("nij,nj->ni", chol, rng.standard_normal((n, d)))
            lp_p = np.asarray(log_prior(prop), float)
            # the whole batch (a fixed size: a jitted log-likelihood compiles once); outside the prior it is unused
            ll_p = np.where(np.isfinite(lp_p), np.asarray(log_lik(prop), float), -np.inf)
            evals += n
            log_a = (lp_p + beta * ll_p) - (lp + beta * ll)
            acc = np.log(rng.random(n)) < np.where(np.isfinite(log_a), log_a, -np.inf)
            x[acc], lp[acc], ll[acc] = prop[acc], lp_p[acc], ll_p[acc]
            n_acc += int(acc.sum())
        acc_prev = n_acc / (n * m) if m else acc_prev
        accs.append(acc_prev)
        nsteps.append(m)
        # Robbins–Monro-like step on the scale towards 25 % acceptance (the kernel of the next stage only)
        scale *= float(np.exp(np.clip(acc_prev - 0.25, -0.2, 0.2) * 4.0))
        if progress is not None:
            progress(beta, len(betas) - 1)
        if last:
            complete = True
            break
        if budget_s is not None and time.perf_counter() - t0 > budget_s:
            break
    return SMCResult(
        x,
        ll,
        lp,
        float(log_z),
        np.asarray(betas),
        np.asarray(accs),
        np.asarray(nsteps, int),
        evals,
        time.perf_counter() - t0,
        complete,
        eps if gradients is not None else float("nan"),
    )
