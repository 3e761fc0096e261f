"""Contact-level model: probed contact points against the n-ellipsoid surface.

Parameters θ (11,): centre (3, m), log semi-axes (3, log m), Euler angles ξ ∈ [0, π], ψ ∈ [0, π),
ζ ∈ [−π, π) (the symmetry-reduced ranges of :func:`bayestouch.paper.fit_nellipsoid_de`), log n, and
log σ (m, the contact noise scale).

Likelihood: the residual of each point is its first-order Euclidean distance to the surface,
r = (G − 1)/|∇G| with G = (Σ|y_i/a_i|^n)^(1/n) (exact to first order for any n, unlike the radial
distance near flat faces); r/σ is Student-t with ``nu`` degrees of freedom (robust to outliers), or
Gaussian when ``nu`` is infinite. Priors: uniform in the ranges of ``models/priors.toml`` (log-uniform for
axes, n and σ). The log-probability is −inf outside the prior and never NaN; it is a pure JAX function,
``jit``/``vmap``-able over walkers.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayestouch._jax import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.params import MODELS, Spec, build

__all__ = ["PriorParams", "load_priors", "Bounds", "bounds_for", "PARAM_NAMES", "shape_of", "residuals",
           "log_likelihood", "log_prior", "log_prob", "make_log_prob"]

PARAM_NAMES = ("x_G", "y_G", "z_G", "log_a", "log_b", "log_c", "xi", "psi", "zeta", "log_n", "log_sigma")

PRIOR_SPECS = {
    "centre_margin": Spec("1", 0.0, 10.0), "axis_min": Spec("m", 1e-6, 1.0), "axis_max": Spec("m", 1e-4, 10.0),
    "n_min": Spec("1", 0.5, 100.0), "n_max": Spec("1", 1.0, 1000.0), "sigma_min": Spec("m", 1e-9, 1.0),
    "sigma_max": Spec("m", 1e-7, 1.0), "student_nu": Spec("1", 0.5, 1e6),
}


class PriorParams(NamedTuple):
    """Prior settings (see ``models/priors.toml``)."""

    centre_margin: float
    axis_min: float
    axis_max: float
    n_min: float
    n_max: float
    sigma_min: float
    sigma_max: float
    student_nu: float


def load_priors(path=None) -> PriorParams:
    """Read ``[priors]`` of ``models/priors.toml`` (or ``path``)."""
    return build(PriorParams, MODELS / "priors.toml" if path is None else path, "priors", PRIOR_SPECS)


class Bounds(NamedTuple):
    """Box of the uniform prior in θ space: ``lower``, ``upper`` (11,)."""

    lower: jnp.ndarray
    upper: jnp.ndarray


def bounds_for(points, priors: PriorParams) -> Bounds:
    """Prior box for data ``points (M, 3)`` m (the centre range is relative to the data's bounding box)."""
    p = np.asarray(points, float)
    lo, hi = p.min(axis=0), p.max(axis=0)
    span = np.maximum(hi - lo, priors.axis_min)
    c_lo, c_hi = lo - priors.centre_margin * span, hi + priors.centre_margin * span
    la = np.log([priors.axis_min, priors.axis_max])
    lower = np.concatenate([c_lo, [la[0]] * 3, [0.0, 0.0, -np.pi], [np.log(priors.n_min), np.log(priors.sigma_min)]])
    upper = np.concatenate([c_hi, [la[1]] * 3, [np.pi, np.pi, np.pi], [np.log(priors.n_max), np.log(priors.sigma_max)]])
    return Bounds(jnp.asarray(lower), jnp.asarray(upper))


def shape_of(theta) -> ne.NEllipsoid:
    """The n-ellipsoid of a parameter vector θ (…, 11)."""
    theta = jnp.asarray(theta)
    return ne.NEllipsoid(theta[..., 0:3], jnp.exp(theta[..., 3:6]), theta[..., 6:9], jnp.exp(theta[..., 9]))


def residuals(theta, points):
    """First-order signed distances (M,) m of ``points (M, 3)`` to the surface of θ (> 0 outside)."""
    s = shape_of(theta)
    y = (points - s.centre) @ s.rotation  # principal frame
    return ne.first_order_distance(s, y)[0]


def log_likelihood(theta, points, nu: float):
    """Σ log Student-t(r/σ; ν) − M log σ (Gaussian for ν = inf)."""
    r = residuals(theta, points)
    sigma = jnp.exp(theta[10])
    z2 = (r / sigma) ** 2
    m = points.shape[0]
    if np.isinf(nu):
        return -0.5 * jnp.sum(z2) - m * (theta[10] + 0.5 * jnp.log(2 * jnp.pi))
    from jax.scipy.special import gammaln

    c = gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * jnp.log(nu * jnp.pi)
    return m * (c - theta[10]) - 0.5 * (nu + 1) * jnp.sum(jnp.log1p(z2 / nu))


def log_prior(theta, bounds: Bounds):
    """0 inside the prior box (uniform in θ: log-uniform axes, n, σ), −inf outside."""
    inside = jnp.all((theta >= bounds.lower) & (theta <= bounds.upper))
    return jnp.where(inside, 0.0, -jnp.inf)


def log_prob(theta, points, bounds: Bounds, nu: float):
    """Log-posterior (unnormalised): −inf outside the prior, never NaN."""
    lp = log_prior(theta, bounds)
    ll = log_likelihood(jnp.clip(theta, bounds.lower, bounds.upper), points, nu)
    out = jnp.where(jnp.isfinite(lp), lp + ll, -jnp.inf)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


def make_log_prob(points, priors: PriorParams | None = None, nu: float | None = None):
    """A jitted, walker-vectorised log-probability ``f(thetas (W, 11)) → (W,)`` for ``emcee(vectorize=True)``.

    Returns
    -------
    f : callable
        NumPy in, NumPy out.
    bounds : Bounds
    """
    priors = priors or load_priors()
    nu = float(priors.student_nu if nu is None else nu)
    pts = jnp.asarray(points, dtype=jnp.float64)
    bounds = bounds_for(points, priors)
    batched = jax.jit(jax.vmap(lambda t: log_prob(t, pts, bounds, nu)))

    def f(thetas):
        return np.asarray(batched(jnp.asarray(np.atleast_2d(thetas), dtype=jnp.float64)))

    return f, bounds
