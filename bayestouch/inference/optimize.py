"""Local optimisation of sharp posteriors: a finite-difference Hessian, Hessian-diagonal scaling, a scaled and
restarted L-BFGS-B, and the Laplace approximation with walkers drawn from it.

Every function takes the objective as ``fn(θ) → (value, gradient)`` (e.g. a jitted ``jax.value_and_grad`` of a
negative log-posterior, θ (D,) float64 in the sampled parametrisation) and a box [lo, hi] (D,) in the same units;
variables with lo = hi are held fixed. Scales (D,) are in the units of θ.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from bayestouch.backend import jnp

__all__ = ["fd_hessian", "diag_scale", "scaled_lbfgs", "laplace", "laplace_ball"]


def fd_hessian(fn, th, steps, lo, hi) -> np.ndarray:
    """Hessian of ``fn`` by central differences of its gradient.

    Parameters
    ----------
    fn : callable
        θ (D,) → (value, gradient (D,)).
    th : (D,) float
        Where the Hessian is taken.
    steps : (D,) float
        Step of each column, units of θ: column j from ±``steps[j]``, the points clipped into [lo, hi].
    lo, hi : (D,) float
        The box; columns of fixed variables (lo = hi) are zero.

    Returns
    -------
    (D, D) float
    """
    H = np.zeros((th.size, th.size))
    for j in np.flatnonzero(hi > lo):
        e = np.zeros(th.size)
        e[j] = steps[j]
        gp = np.asarray(fn(jnp.asarray(np.clip(th + e, lo, hi)))[1])
        gm = np.asarray(fn(jnp.asarray(np.clip(th - e, lo, hi)))[1])
        H[:, j] = (gp - gm) / (2 * steps[j])
    return H


def diag_scale(fn, th, lo, hi, scale) -> np.ndarray:
    """Variable scales (D,) 1/√H_jj, units of θ, from the diagonal of the Hessian of ``fn`` (value and gradient) at
    ``th`` (:func:`fd_hessian`, steps of 1e-3 ``scale``), clipped to [1e-4, 1e4] × ``scale``; ``scale`` where that
    fails or the variable is fixed."""
    out = np.asarray(scale, float).copy()
    hjj = np.diag(fd_hessian(fn, th, 1e-3 * out, lo, hi))
    ok = (hi > lo) & np.isfinite(hjj) & (hjj > 0)
    out[ok] = np.clip(1.0 / np.sqrt(hjj[ok]), 1e-4 * out[ok], 1e4 * out[ok])
    return out


def scaled_lbfgs(fn, th, lo, hi, scale, maxiter: int = 3000, rounds: int = 3, rescale: bool = True):
    """L-BFGS-B of ``fn`` (value and gradient) from ``th`` (D,) inside [lo, hi], in variables scaled by the diagonal
    of the Hessian (:func:`diag_scale`, ``scale`` (D,) where it fails).

    A posterior as sharp as the raw level's (centre sd ~50 nm, log-axes ~1e-6) leaves L-BFGS-B under a fixed scaling
    thousands of nats uphill after its first steps, after which it stops on its relative-reduction test. Up to
    ``rounds`` restarts (rescaled at the new point) until one gains < 1e-3 in ``fn``. ``rescale=False`` uses
    ``scale`` as it is.

    Returns
    -------
    theta : (D,) float
        The optimum found (``th`` when no round improves on it).
    value : float
        ``fn``'s value there.
    """
    best = float(fn(jnp.asarray(th))[0])
    for _ in range(rounds):
        sc = diag_scale(fn, th, lo, hi, scale) if rescale else np.asarray(scale, float)
        t1 = th.copy()

        def obj(z, t1=t1, sc=sc):
            v, g = fn(jnp.asarray(t1 + z * sc))
            v, g = float(v), np.asarray(g) * sc
            if not (np.isfinite(v) and np.all(np.isfinite(g))):
                return 1e30, np.zeros_like(z)
            return v, g

        zb = list(zip((lo - t1) / sc, (hi - t1) / sc, strict=True))
        res = minimize(
            obj,
            np.zeros(t1.size),
            jac=True,
            method="L-BFGS-B",
            bounds=zb,
            options={"maxiter": maxiter, "ftol": 1e-15, "gtol": 1e-6},
        )
        if not res.fun < best:
            break
        th, gain = np.clip(t1 + res.x * sc, lo, hi), best - float(res.fun)
        best = float(res.fun)
        if gain < 1e-3:
            break
    return th, best


def laplace(neg_log_post, theta, lo, hi, scale) -> tuple[np.ndarray, np.ndarray]:
    """The Laplace approximation N(θ̂, H⁻¹) at the optimum ``theta`` (D,) of ``neg_log_post``.

    H is :func:`fd_hessian` of ``neg_log_post`` (value and gradient, as for :func:`scaled_lbfgs`) in the variables
    scaled by ``scale`` (D,) (steps of 1e-3 scaled units), symmetrised, with its eigenvalues floored at 1e-6 of the
    largest. On the raw level's standard scenario its sds are within 4 % of the sampled posterior's and its mean
    within 0.02 sd.

    Returns
    -------
    mean : (D,) float
    cov : (D, D) float
        Units of θ squared.
    """
    th = np.asarray(theta, float)
    H = scale[:, None] * fd_hessian(neg_log_post, th, 1e-3 * scale, lo, hi) * scale[None, :]  # scaled variables
    H = 0.5 * (H + H.T)
    w, V = np.linalg.eigh(H)
    w = np.maximum(w, 1e-6 * max(w.max(), 1e-300))
    cov = (V / w) @ V.T * scale[:, None] * scale[None, :]
    return th, 0.5 * (cov + cov.T)


def laplace_ball(moments, lo, hi, walkers: int, rng: np.random.Generator) -> np.ndarray:
    """Walkers (W, D) drawn from the Laplace approximation ``moments`` = (mean (D,), cov (D, D)) of :func:`laplace`,
    clipped into the prior box [lo, hi]. Starting at the posterior's scale matters for a sharp posterior: the raw
    level's is ~100× narrower than any fixed ball (centre sd ~50 nm), and a ball too wide costs thousands of steps
    of burn-in."""
    mean, cov = moments
    w, V = np.linalg.eigh(cov)
    z = rng.normal(size=(walkers, len(mean))) * np.sqrt(np.maximum(w, 0.0))
    p = mean + z @ V.T
    return np.clip(p, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
