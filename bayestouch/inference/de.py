"""Differential evolution in JAX: the global search that starts the contact-level posterior.

One compiled program runs every generation of several independent populations (``lax.scan`` over generations,
``vmap`` over starts), so the search costs microseconds of Python per run instead of SciPy's milliseconds per
generation. The strategy is SciPy's default ``best1bin`` with ``updating="deferred"`` (Storn & Price 1997,
J. Global Optim. 11:341): mutant = best + F (x_r1 − x_r2) with F drawn per generation in [0.5, 1) (dither),
binomial crossover with CR = 0.7 and one coordinate always from the mutant, greedy selection; trial coordinates
outside the box are redrawn uniformly inside it.

The cost is the mean squared radial distance of the n-ellipsoid (the paper's, :func:`bayestouch.paper._cost_batch`),
weighted so that padded points count zero, or per start a robust Cauchy loss of it (contacts displaced millimetres
off the surface pull a squared cost into the wrong basin).
"""

from __future__ import annotations

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne

__all__ = ["radial_cost", "de_search"]

#: crossover probability and dither range of the mutation factor (SciPy's defaults)
CR = 0.7
F_RANGE = (0.5, 1.0)


def radial_cost(V, pts, wts, scale=None):
    """Weighted mean squared radial distance (S,) m² of the shapes V (S, 10) (``ne.to_vector`` layout) to the
    points ``pts (M, 3)`` m with weights ``wts (M,)`` (zero for padding); with ``scale`` (S,) m, for the rows
    where it is > 0 the robust Cauchy (Lorentzian) loss c² log(1 + r²/c²) instead, which a contact displaced
    many c off the surface moves only logarithmically (Holland & Welsch 1977)."""
    r = jax.vmap(lambda v: ne.radial_distance(ne.from_vector(v), pts))(V)
    r2 = r * r
    if scale is not None:
        c2 = jnp.where(scale > 0, scale, 1.0)[:, None] ** 2
        r2 = jnp.where(scale[:, None] > 0, c2 * jnp.log1p(r2 / c2), r2)
    return jnp.sum(wts * r2, axis=1) / jnp.sum(wts)


@jax.jit
def _search(init, r1, r2, f, u_cross, jrand, u_new, lower, upper, pts, wts, scales):
    """All starts at once (leading axis S); the random numbers come in as arrays (generations first), which keeps
    the compiled scan small: drawing them inside the loop made XLA's compile take ~13 s instead of ~1 s."""
    span = upper - lower
    s_, p_, d = init.shape
    pop = lower + span * init

    def cost_of(x):
        return radial_cost(x.reshape(s_ * p_, d), pts, wts, jnp.repeat(scales, p_)).reshape(s_, p_)

    def generation(carry, r):
        pop, cost = carry
        r1, r2, f, u_cross, jrand, u_new = r
        best = jnp.take_along_axis(pop, jnp.argmin(cost, axis=1)[:, None, None], axis=1)  # (S, 1, D)
        a = jnp.take_along_axis(pop, r1[:, :, None], axis=1)
        b = jnp.take_along_axis(pop, r2[:, :, None], axis=1)
        mutant = best + f[:, None, None] * (a - b)
        cross = (u_cross < CR) | (jnp.arange(d)[None, None, :] == jrand[:, :, None])
        trial = jnp.where(cross, mutant, pop)
        trial = jnp.where((trial < lower) | (trial > upper), lower + span * u_new, trial)
        tc = cost_of(trial)
        better = tc <= cost
        return (jnp.where(better[..., None], trial, pop), jnp.where(better, tc, cost)), None

    (pop, cost), _ = jax.lax.scan(generation, (pop, cost_of(pop)), (r1, r2, f, u_cross, jrand, u_new))
    i = jnp.argmin(cost, axis=1)
    return jnp.take_along_axis(pop, i[:, None, None], axis=1)[:, 0], jnp.take_along_axis(cost, i[:, None], axis=1)[:, 0]


def de_search(
    points,
    lower,
    upper,
    seed: int,
    *,
    starts: int = 3,
    popsize: int = 120,
    generations: int = 250,
    max_points: int = 256,
    robust_scale=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Independent differential-evolution searches for the n-ellipsoid closest to ``points`` in the radial sense.

    Parameters
    ----------
    points : (M, 3) float, metres
    lower, upper : (10,) float
        Search box in the ``ne.to_vector`` layout (centre m, semi-axes m, Euler angles rad, n).
    seed : int
        Seeds the subsample and every start.
    starts : int
        Independent populations.
    popsize, generations : int
        Population size and generations of each.
    max_points : int
        At most this many points enter the cost (a seeded random subsample beyond); fewer are padded to the next
        power of two (at least 64) with zero weight, so data sets of similar size share one compiled program.
    robust_scale : float or (starts,) float, metres, optional
        Per start, the scale c of the robust Cauchy loss (:func:`radial_cost`); 0 or None: squared distances.

    Returns
    -------
    best : (starts, 10) float
        The best member of each population.
    cost : (starts,) float, m²
        Its weighted mean squared radial distance (or robust loss).
    """
    pts = np.asarray(points, float)
    rng = np.random.default_rng([seed, 7])
    if len(pts) > max_points:
        pts = pts[rng.choice(len(pts), max_points, replace=False)]
    m = len(pts)
    size = max(64, 1 << max(m - 1, 0).bit_length())
    padded = np.empty((size, 3))
    padded[:m], padded[m:] = pts, pts[0]
    wts = np.zeros(size)
    wts[:m] = 1.0
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    d, g, s, p = lower.size, int(generations), int(starts), int(popsize)
    r1 = rng.integers(0, p, (g, s, p))
    r2 = (r1 + rng.integers(1, p, (g, s, p))) % p  # a second member, never the first
    best, cost = _search(
        rng.uniform(size=(s, p, d)),
        r1,
        r2,
        rng.uniform(*F_RANGE, (g, s)),
        rng.uniform(size=(g, s, p, d)),
        rng.integers(0, d, (g, s, p)),
        rng.uniform(size=(g, s, p, d)),
        jnp.asarray(lower),
        jnp.asarray(upper),
        jnp.asarray(padded),
        jnp.asarray(wts),
        jnp.broadcast_to(jnp.asarray(0.0 if robust_scale is None else robust_scale, dtype=jnp.float64), (s,)),
    )
    return np.asarray(best), np.asarray(cost)
