"""Contact-level posterior run: initialise, sample with emcee (HDF5 checkpoints, resumable), diagnose,
summarise (canonicalised draws), write the outputs. The stateful edge of the inference package.

Outputs in the run folder: ``chain.h5`` (emcee backend, the checkpoint), ``posterior.nc`` (ArviZ
InferenceData: posterior and observed data), ``summary.json`` and ``mean_shape.ply``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bayestouch._jax import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import contact as cm

__all__ = ["initial_theta", "run_contact_fit", "NATURAL_NAMES"]

#: summary names (natural units) of the 11 sampled parameters
NATURAL_NAMES = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n", "sigma")


def initial_theta(points, seed: int, priors: cm.PriorParams) -> np.ndarray:
    """A starting point: the evolutionary 10-parameter fit (symmetry-reduced angle ranges), σ from its RMS."""
    from bayestouch.paper import fit_nellipsoid_de

    de = fit_nellipsoid_de(points, seed, popsize=12, maxiter=250, n_bounds=(priors.n_min, priors.n_max))
    v = np.asarray(ne.to_vector(de.shape))
    sigma = float(np.clip(de.rms, priors.sigma_min * 2, priors.sigma_max / 2))
    return np.concatenate([v[:3], np.log(v[3:6]), v[6:9], [np.log(v[9])], [np.log(sigma)]])


def _walkers(theta0, bounds, n, rng) -> np.ndarray:
    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    scale = np.concatenate([np.full(3, 1e-4), np.full(3, 1e-3), np.full(3, 1e-3), [1e-3], [1e-2]])
    p = theta0 + scale * rng.normal(size=(n, theta0.size))
    return np.clip(p, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))


def _natural(flat: np.ndarray) -> np.ndarray:
    """θ draws (S, 11) → canonicalised natural parameters (S, 11): centre, a ≥ b ≥ c, angles, n, σ."""
    from bayestouch.geometry.compare import canonicalize_batch

    v = np.column_stack([flat[:, :3], np.exp(flat[:, 3:6]), flat[:, 6:9], np.exp(flat[:, 9])])
    return np.column_stack([canonicalize_batch(v), np.exp(flat[:, 10])])


def run_contact_fit(points, out: Path, *, seed: int = 0, walkers: int = 32, steps: int = 4000,
                    resume: bool = False, budget_s: float | None = None, progress: bool = True) -> dict:
    """Sample the contact-level posterior of ``points (M, 3)`` m and write the run folder ``out``.

    Parameters
    ----------
    seed : int
        Seeds the initial fit, the walkers and emcee's random state (checked after setting).
    walkers, steps : int
        Ensemble size and the total number of steps of the chain.
    resume : bool
        Continue the chain in ``out/chain.h5`` up to ``steps`` (nothing already sampled is lost).
    budget_s : float, seconds
        Stop sampling after this wall-clock time (the summary says so).

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    import arviz as az
    import emcee

    from bayestouch.io import write_json

    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    priors = cm.load_priors()
    logp, bounds = cm.make_log_prob(points, priors)
    ndim = 11
    backend = emcee.backends.HDFBackend(str(out / "chain.h5"))
    rng = np.random.default_rng(seed)
    if resume and (out / "chain.h5").exists() and backend.iteration > 0:
        if backend.shape != (walkers, ndim):
            raise BadInput(f"--resume: {out / 'chain.h5'} has {backend.shape[0]} walkers, not {walkers}")
        start = None
    else:
        backend.reset(walkers, ndim)
        theta0 = initial_theta(points, seed, priors)
        start = _walkers(theta0, bounds, walkers, rng)
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]  # strongly correlated shape params
    sampler = emcee.EnsembleSampler(walkers, ndim, logp, vectorize=True, backend=backend, moves=moves)
    state = np.random.RandomState(seed).get_state()
    sampler.random_state = state
    if not np.array_equal(sampler.random_state[1], state[1]):
        raise RuntimeError("emcee did not take the random state")
    todo = steps - backend.iteration
    stopped_by_budget = False
    if todo > 0:
        for _ in sampler.sample(start if start is not None else backend.get_last_sample(), iterations=todo,
                                progress=progress):
            if budget_s is not None and time.perf_counter() - t0 > budget_s:
                stopped_by_budget = True
                break
    chain = backend.get_chain()  # (steps, walkers, 11)
    n_done = chain.shape[0]
    try:
        tau = backend.get_autocorr_time(tol=0)
    except Exception:  # too short a chain
        tau = np.full(ndim, np.nan)
    tau_max = float(np.nanmax(tau)) if np.isfinite(tau).any() else float("nan")
    burn = int(min(n_done // 2, max(2 * tau_max, n_done // 4))) if np.isfinite(tau_max) else n_done // 2
    kept = chain[burn:]
    nat = _natural(kept.reshape(-1, ndim)).reshape(kept.shape)  # (draws, walkers, 11)
    post = {name: np.swapaxes(nat[..., i], 0, 1) for i, name in enumerate(NATURAL_NAMES)}
    idata = az.from_dict(posterior=post, observed_data={"points": np.asarray(points)})
    ess = az.ess(idata, method="bulk")
    rhat = az.rhat(idata)
    params = {}
    for i, name in enumerate(NATURAL_NAMES):
        x = nat[..., i].ravel()
        params[name] = {"mean": float(x.mean()), "sd": float(x.std(ddof=1)), "q05": float(np.quantile(x, 0.05)),
                        "q95": float(np.quantile(x, 0.95)), "r_hat": float(rhat[name]),
                        "ess_bulk": float(ess[name])}
    flat = nat.reshape(-1, ndim)
    thin = flat[np.random.default_rng(seed).choice(len(flat), min(400, len(flat)), replace=False)]
    shapes = [ne.from_vector(jnp.asarray(v[:10])) for v in thin]
    vols = np.array([float(ne.volume(s)) for s in shapes])
    from bayestouch.geometry.integrals import surface_integrals
    from bayestouch.geometry.mesh import nellipsoid_mesh

    areas = np.array([surface_integrals(*nellipsoid_mesh(s, 12)).area for s in shapes[:200]])

    def stats(x):
        return {"mean": float(x.mean()), "sd": float(x.std(ddof=1)), "q05": float(np.quantile(x, 0.05)),
                "q95": float(np.quantile(x, 0.95))}

    max_rhat = max(p["r_hat"] for p in params.values())
    min_ess = min(p["ess_bulk"] for p in params.values())
    converged = bool(max_rhat < 1.01 and min_ess > 400 and np.isfinite(tau_max) and n_done > 50 * tau_max)
    summary = {
        "parameters": params,
        "derived": {"volume_m3": stats(vols), "area_m2": stats(areas)},
        "diagnostics": {"converged": converged, "max_r_hat": max_rhat, "min_ess_bulk": min_ess,
                        "n_samples": int(flat.shape[0]), "seconds": time.perf_counter() - t0,
                        "steps": int(n_done), "burn_in": burn, "walkers": walkers,
                        "autocorr_time_max": tau_max, "acceptance": float(np.mean(sampler.acceptance_fraction))
                        if todo > 0 else None, "stopped_by_budget": stopped_by_budget},
        "model": {"level": "contact", "likelihood": f"Student-t, nu = {priors.student_nu:g}", "seed": seed,
                  "n_points": int(len(points))},
    }
    idata.to_netcdf(str(out / "posterior.nc"))
    mean = ne.from_vector(jnp.asarray(flat[:, :10].mean(axis=0)))
    from bayestouch.geometry.mesh import to_trimesh

    to_trimesh(*nellipsoid_mesh(mean, 32)).export(str(out / "mean_shape.ply"))
    write_json(out / "summary.json", summary)
    return summary
