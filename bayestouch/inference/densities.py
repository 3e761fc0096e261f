"""Robust reading densities shared by the likelihoods: the Student-t log-density and its Gaussian-fit scale."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from jax.scipy.special import gammaln
from scipy.optimize import brentq

from bayestouch.backend import jnp

__all__ = ["student_t_logpdf", "t_scale_factor"]


def student_t_logpdf(r, scale, nu):
    """Log-density of a Student-t(ν) with location 0 and ``scale`` at residuals ``r`` (same unit as ``scale``;
    pure JAX, broadcasting)."""
    c = gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * jnp.log(nu * jnp.pi)
    return c - jnp.log(scale) - 0.5 * (nu + 1) * jnp.log1p((r / scale) ** 2 / nu)


@lru_cache(maxsize=8)
def t_scale_factor(nu: float) -> float:
    """c_ν (dimensionless): the scale, in units of σ, of the Student-t(ν) that fits N(0, σ²) readings best (it
    maximises E[ln t_ν], i.e. E[(ν + 1)u²/(ν + u²)] = 1 for u = z/c_ν, z ~ N(0, 1)); 0.831 for ν = 4, → 1 as ν → ∞.

    The raw likelihood's t scale is c_ν times the modelled sd, so that for Gaussian residuals the noise multiplier
    k estimates their sd over the modelled one (≈ 1 when the model fits) and the roughness σ_r its RMS, instead of
    both coming out c_ν too small; the heavy tails still take the ADC glitches."""
    x, w = np.polynomial.hermite_e.hermegauss(160)
    w = w / w.sum()
    nu = float(nu)

    def excess(c):
        u2 = (x / c) ** 2
        return float(np.sum(w * (nu + 1.0) * u2 / (nu + u2))) - 1.0

    return 1.0 if np.isinf(nu) else float(brentq(excess, 0.05, 1.5, xtol=1e-14))
