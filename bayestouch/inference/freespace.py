"""The free-space (no-contact) likelihood: what strokes said without a contact point.

A ray that met nothing over its length, and a ray start found inside the object, are data too; the contact-level
likelihood (:mod:`bayestouch.inference.contact`) has terms for contact points only. This module adds probit terms
for them to a contact-level log-density over walkers θ (W, 11) of :func:`bayestouch.inference.contact.shape_of`
(log axes, log n, log σ). Rays: starts and unit directions (K, 3), lengths in metres; starts inside (J, 3) metres.
The terms and why they matter: ``docs/planning.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jax.scipy.stats import norm

from bayestouch.backend import jax, jnp, pad_pow2
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import contact as cm

__all__ = ["Free", "free_log_lik", "with_free"]


class Free(NamedTuple):
    """What strokes said without a contact point.

    Attributes
    ----------
    starts : (K, 3) float, metres
        Starts of the rays that met nothing over their length.
    dirs : (K, 3) float
        Their unit directions.
    t_max : float, metres
        The rays' length.
    inside : (J, 3) float, metres
        Ray starts found inside the object.
    """

    starts: np.ndarray
    dirs: np.ndarray
    t_max: float
    inside: np.ndarray

    def add(self, other: Free) -> Free:
        """Both sets of observations, ``self``'s first (``t_max`` is ``self``'s).

        Parameters
        ----------
        other : Free

        Returns
        -------
        Free
        """
        return Free(
            np.concatenate([self.starts, other.starts]),
            np.concatenate([self.dirs, other.dirs]),
            self.t_max,
            np.concatenate([self.inside, other.inside]),
        )


@jax.jit
def free_log_lik(thetas, starts, dirs, t_max, inside, w_ray, w_in):
    """Log-likelihood of :class:`Free` observations for many walkers (pure JAX, compiled).

    A ray that met nothing over its length t_max has probability Φ((t_θ − t_max)/σ) (the contact, had there been
    one, would have read t_θ + noise > t_max; t_θ is the ray distance under θ,
    :func:`~bayestouch.geometry.nellipsoid.ray_distances` traced to 4 t_max), and a start found inside has
    probability Φ(−d_θ/σ) (d_θ its first-order signed distance, > 0 outside); σ is the walker's contact noise.

    Parameters
    ----------
    thetas : (W, 11) float
        Walkers: centre (m), log semi-axes (log m), Euler angles (rad), log n, log σ (log m).
    starts, dirs : (K, 3) float
        Ray starts (metres) and unit directions.
    t_max : float, metres
    inside : (J, 3) float, metres
        Starts found inside.
    w_ray : (K,) float
        1 for real rays, 0 for padding rows.
    w_in : (J,) float
        1 for real starts inside, 0 for padding rows.

    Returns
    -------
    (W,) float
        Log-likelihood, nats.
    """

    def one(th):
        s = cm.shape_of(th)
        sigma = jnp.exp(th[10])
        t = ne.ray_distances(s, starts, dirs, 4.0 * t_max)
        lm = jnp.sum(w_ray * norm.logcdf((t - t_max) / sigma))
        d = ne.first_order_distance(s, ne.to_local(s, inside))[0]
        return lm + jnp.sum(w_in * norm.logcdf(-d / sigma))

    return jax.vmap(one)(thetas)


def with_free(logp, bounds, free: Free):
    """A log-density plus the :class:`Free` observations' log-likelihood (:func:`free_log_lik`).

    The observations are padded to powers of two (few compiled sizes) and the walkers clipped into ``bounds`` for
    the extra term; −inf stays −inf and NaN becomes −inf.

    Parameters
    ----------
    logp : callable
        ``(W, 11) -> (W,)`` log-density (NumPy edge), e.g. of :func:`bayestouch.inference.contact.make_log_prob`.
    bounds : Bounds
        The prior box (``lower``, ``upper`` (11,)) of ``logp``.
    free : Free

    Returns
    -------
    callable
        ``(W, 11) -> (W,)``; ``logp`` itself when there are no observations.
    """
    if len(free.starts) == 0 and len(free.inside) == 0:
        return logp
    k, j = len(free.starts), len(free.inside)
    starts = pad_pow2(free.starts if k else np.zeros((1, 3)), min_size=8)
    dirs = pad_pow2(free.dirs if k else np.array([[0.0, 0.0, 1.0]]), min_size=8)
    inside = pad_pow2(free.inside if j else np.zeros((1, 3)), min_size=8)
    w_ray = (np.arange(len(starts)) < k).astype(float)
    w_in = (np.arange(len(inside)) < j).astype(float)
    args = [jnp.asarray(a) for a in (starts, dirs)] + [
        jnp.float64(free.t_max),
        jnp.asarray(inside),
        jnp.asarray(w_ray),
        jnp.asarray(w_in),
    ]

    def f(thetas):
        th = np.asarray(thetas, dtype=np.float64)
        base = logp(th)
        extra = np.asarray(free_log_lik(cm.clip_to_box(jnp.asarray(th), bounds), *args))
        out = np.where(np.isfinite(base), base + extra, -np.inf)
        return np.where(np.isnan(out), -np.inf, out)

    return f
