"""The emcee engine shared by every likelihood level: seeded, checkpointed, resumable, budgeted sampling and
honest convergence diagnostics. The stateful edge of the inference package (the log-density is pure).

A model plugs in as a vectorised log-probability ``logp(thetas (W, D)) -> (W,)`` (NumPy in and out, −inf
outside the prior, never NaN) and a start ensemble; :func:`sample` returns the chain after burn-in and the
numbers a summary needs.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.errors import BadInput

__all__ = ["Chain", "sample", "default_moves", "convergence", "R_HAT_MAX", "ESS_MIN", "TAU_FACTOR"]

#: convergence thresholds (Vehtari et al. 2021 for R-hat and bulk ESS; emcee's docs for N > 50 τ)
R_HAT_MAX = 1.01
ESS_MIN = 400.0
TAU_FACTOR = 50.0


class Chain(NamedTuple):
    """Result of :func:`sample`.

    kept : (S, W, D) float
        Draws after burn-in (steps, walkers, parameters), in the sampled parametrisation.
    log_prob : (S, W) float
        Log-posterior of the kept draws.
    steps : int
        Steps in the chain file (burn-in included).
    burn : int
        Steps discarded as burn-in.
    tau_max : float
        Largest integrated autocorrelation time (steps), NaN when it cannot be estimated.
    acceptance : float or None
        Mean acceptance fraction of this call's steps (None when nothing was sampled now).
    stopped_by_budget : bool
    seconds : float
        Wall-clock time of this call.
    """

    kept: np.ndarray
    log_prob: np.ndarray
    steps: int
    burn: int
    tau_max: float
    acceptance: float | None
    stopped_by_budget: bool
    seconds: float


def default_moves():
    """Differential-evolution moves: the shape parameters are strongly correlated (ter Braak 2006; emcee docs)."""
    import emcee

    return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]


def sample(logp, start, chain_path, *, walkers: int, ndim: int, seed: int, steps: int, resume: bool = False,
           budget_s: float | None = None, progress: bool = True, moves=None, t0: float | None = None) -> Chain:
    """Run (or continue) an emcee ensemble with an HDF5 checkpoint.

    Parameters
    ----------
    logp : callable
        ``(W, D) -> (W,)`` log-posterior, vectorised over walkers.
    start : (W, D) float, or a callable returning it
        Initial ensemble; a callable is called only when a new chain starts (not on resume).
    walkers, ndim : int
        Ensemble size W and dimension D; a resumed chain must have the same.
    chain_path : path or None
        emcee HDF5 backend; written every step (about 10 ms a step), so a killed run loses at most the step in
        flight. None samples in memory (no checkpoint, no resume).
    seed : int
        Seeds emcee's random state (checked to have taken effect).
    steps : int
        Total chain length; a resumed chain continues up to it.
    resume : bool
        Continue the chain in ``chain_path`` when it holds one (else start a new chain).
    budget_s : float, seconds, optional
        Stop sampling once this much wall-clock time has passed since ``t0``.
    moves : emcee moves, optional
        Default :func:`default_moves`.
    t0 : float, optional
        ``time.perf_counter()`` at the start of the whole run (default: now).
    """
    import emcee

    t0 = time.perf_counter() if t0 is None else t0
    if chain_path is None:  # in memory: short runs for which a checkpoint costs more than it saves
        backend = emcee.backends.Backend()
        resume = False
    else:
        chain_path = Path(chain_path)
        backend = emcee.backends.HDFBackend(str(chain_path))
    if resume and chain_path.exists():
        try:
            done = backend.iteration
        except (OSError, KeyError) as e:  # a file that is not an emcee chain, or one damaged mid-write
            raise BadInput(f"--resume: {chain_path} cannot be read as an emcee chain ({type(e).__name__}); "
                           "remove it to start afresh") from None
    if resume and chain_path.exists() and done > 0:
        if tuple(backend.shape) != (walkers, ndim):
            raise BadInput(f"--resume: {chain_path} has {backend.shape[0]} walkers × {backend.shape[1]} parameters, "
                           f"not {walkers} × {ndim}")
        start = None
    else:
        start = np.asarray(start() if callable(start) else start, dtype=float)
        if start.shape != (walkers, ndim):
            raise ValueError(f"start ensemble has shape {start.shape}, expected {(walkers, ndim)}")
        backend.reset(walkers, ndim)
    sampler = emcee.EnsembleSampler(walkers, ndim, logp, vectorize=True, backend=backend,
                                    moves=moves or default_moves())
    # A resumed run continues from a fresh stream of the same seed offset by the steps already done, so the
    # whole chain is reproducible given (seed, where it was interrupted).
    state = np.random.RandomState([seed, backend.iteration]).get_state()
    sampler.random_state = state
    if not np.array_equal(sampler.random_state[1], state[1]):
        raise RuntimeError("emcee did not take the random state")
    todo = steps - backend.iteration
    stopped = False
    if todo > 0:
        for _ in sampler.sample(start if start is not None else backend.get_last_sample(), iterations=todo,
                                progress=progress):
            if budget_s is not None and time.perf_counter() - t0 > budget_s:
                stopped = True
                break
    chain = backend.get_chain()
    lp = backend.get_log_prob()
    n_done = chain.shape[0]
    try:
        tau = backend.get_autocorr_time(tol=0)
    except Exception:  # emcee raises on chains too short for any estimate
        tau = np.full(ndim, np.nan)
    tau_max = float(np.nanmax(tau)) if np.isfinite(tau).any() else float("nan")
    burn = int(min(n_done // 2, max(2 * tau_max, n_done // 4))) if np.isfinite(tau_max) else n_done // 2
    acc = float(np.mean(sampler.acceptance_fraction)) if todo > 0 and sampler.iteration > 0 else None
    return Chain(chain[burn:], lp[burn:], int(n_done), burn, tau_max, acc, stopped, time.perf_counter() - t0)


def convergence(r_hat, ess_bulk, chain: Chain) -> dict:
    """Diagnostics of a run: converged only when every R-hat < 1.01, every bulk ESS > 400 and the chain is longer
    than 50 autocorrelation times (never claimed otherwise)."""
    max_rhat = float(np.max(r_hat))
    min_ess = float(np.min(ess_bulk))
    converged = bool(max_rhat < R_HAT_MAX and min_ess > ESS_MIN and np.isfinite(chain.tau_max)
                     and chain.steps > TAU_FACTOR * chain.tau_max)
    return {"converged": converged, "max_r_hat": max_rhat, "min_ess_bulk": min_ess,
            "n_samples": int(chain.kept.shape[0] * chain.kept.shape[1]), "steps": chain.steps,
            "burn_in": chain.burn, "walkers": int(chain.kept.shape[1]), "autocorr_time_max": chain.tau_max,
            "acceptance": chain.acceptance, "stopped_by_budget": chain.stopped_by_budget}
