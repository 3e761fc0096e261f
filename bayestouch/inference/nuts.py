"""A NUTS cross-check of the contact-level posterior (numpyro; Hoffman & Gelman 2014) on the very log-density
that emcee samples (:func:`bayestouch.inference.contact.log_prob`).

NUTS needs an unconstrained space: each θ_i in its prior box [l_i, u_i] is reached from u_i ∈ ℝ by the
logistic map θ_i = l_i + (u_i − l_i)·s(u_i), s the logistic sigmoid, and the potential is
−[log p(θ(u) | x) + Σ_i log |dθ_i/du_i|] with log |dθ_i/du_i| = log(u_i − l_i) + log s(u_i) + log s(−u_i),
so the posterior of θ is unchanged (change of variables). numpyro is imported lazily.
"""

from __future__ import annotations

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.inference import contact as cm
from bayestouch.inference.run import NATURAL_NAMES, initial_theta

__all__ = ["to_unconstrained", "from_unconstrained", "make_potential", "nuts_contact"]


def from_unconstrained(u, bounds: cm.Bounds):
    """θ (…, 11) in the prior box from u (…, 11) ∈ ℝ¹¹ by the logistic map."""
    return bounds.lower + (bounds.upper - bounds.lower) * jax.nn.sigmoid(u)


def to_unconstrained(theta, bounds: cm.Bounds):
    """Inverse of :func:`from_unconstrained` (θ strictly inside the box; clipped 1e-12 of its width inside)."""
    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)
    p = np.clip((np.asarray(theta, float) - lo) / (hi - lo), 1e-12, 1 - 1e-12)
    return np.log(p) - np.log1p(-p)


def make_potential(points, priors: cm.PriorParams | None = None, nu: float | None = None):
    """Potential energy U(u) = −log p(θ(u) | x) − log|J(u)| of the contact-level posterior, and its bounds.

    Parameters
    ----------
    points : (M, 3) float, metres
    priors, nu
        As :func:`bayestouch.inference.contact.make_log_prob` (defaults: ``models/priors.toml``).

    Returns
    -------
    potential : callable
        Pure JAX ``(11,) -> ()``, differentiable.
    bounds : contact.Bounds
    """
    priors = priors or cm.load_priors()
    nu = float(priors.student_nu if nu is None else nu)
    pts = jnp.asarray(points, dtype=jnp.float64)
    bounds = cm.bounds_for(points, priors)
    log_width = jnp.log(bounds.upper - bounds.lower)

    def potential(u):
        theta = from_unconstrained(u, bounds)
        log_jac = jnp.sum(log_width + jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u))
        return -(cm.log_prob(theta, pts, bounds, nu) + log_jac)

    return potential, bounds


def nuts_contact(
    points,
    *,
    seed: int,
    num_warmup: int,
    num_samples: int,
    num_chains: int = 1,
    init=None,
    priors: cm.PriorParams | None = None,
    nu: float | None = None,
    dense_mass: bool = True,
    progress: bool = False,
) -> dict:
    """Sample the contact-level posterior of ``points`` with numpyro's NUTS.

    Parameters
    ----------
    points : (M, 3) float, metres
    seed : int
        Seeds the JAX PRNG key of the run (and the initial fit when ``init`` is None).
    num_warmup, num_samples, num_chains : int
        Chains run one after the other (``chain_method="sequential"``).
    init : (11,) or (num_chains, 11) float, optional
        Starting θ; default :func:`bayestouch.inference.run.initial_theta` (the evolutionary fit).
    priors, nu
        As :func:`bayestouch.inference.contact.make_log_prob`.
    dense_mass : bool
        Adapt a dense mass matrix (the shape parameters are strongly correlated).
    progress : bool

    Returns
    -------
    dict
        ``theta`` (num_chains, num_samples, 11) draws of θ; the natural parameters
        (``run.NATURAL_NAMES``: centre m, semi-axes a, b, c m, angles rad, n, σ m; not canonicalised),
        each (num_chains, num_samples); ``diverging`` (num_chains, num_samples) bool.
    """
    from numpyro.infer import MCMC, NUTS

    priors = priors or cm.load_priors()
    potential, bounds = make_potential(points, priors, nu)
    theta0 = initial_theta(points, seed, priors) if init is None else np.asarray(init, float)
    u0 = to_unconstrained(np.broadcast_to(theta0, (num_chains, 11)), bounds)
    mcmc = MCMC(
        NUTS(potential_fn=potential, dense_mass=dense_mass),
        num_warmup=num_warmup,
        num_samples=num_samples,
        num_chains=num_chains,
        chain_method="sequential",
        progress_bar=progress,
    )
    mcmc.run(
        jax.random.PRNGKey(seed), init_params=jnp.asarray(u0 if num_chains > 1 else u0[0]), extra_fields=("diverging",)
    )
    u = np.asarray(mcmc.get_samples(group_by_chain=True))
    theta = np.asarray(from_unconstrained(jnp.asarray(u), bounds))
    nat = np.concatenate([theta[..., :3], np.exp(theta[..., 3:6]), theta[..., 6:9], np.exp(theta[..., 9:11])], -1)
    out = {"theta": theta, **{k: nat[..., i] for i, k in enumerate(NATURAL_NAMES)}}
    out["diverging"] = np.asarray(mcmc.get_extra_fields(group_by_chain=True)["diverging"])
    return out
