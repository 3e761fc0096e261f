"""Contact-level model of an object made of parts: the union of K n-ellipsoids (a head and a body, a mug and its
handle, the two ends of a dumbbell), pure JAX.

θ (W, 10 K + 3) per walker: for each part k its 10 shape parameters in the layout of
:data:`bayestouch.inference.contact.PARAM_NAMES` (centre m, log semi-axes log m, Euler angles rad, log n), then
the shared noise: log σ (m) and the outlier fractions w_in, w_out of the two-sided outlier model
(:func:`bayestouch.inference.contact.outlier_terms`).

Surface. The union's signed distance is the minimum of the parts' signed distances (exact outside every part; a
point inside any part is inside the union), so a contact's residual is min_k d_k with d_k the first-order
distance to part k (:func:`bayestouch.inference.contact.principal_frame`), and a free-space position's term
Φ(min_k d_k / σ) says it lies outside every part.

Prior. Each part has the single n-ellipsoid's prior (:func:`bayestouch.inference.contact.bounds_for`: the centre
box, the log-normal size prior on every semi-axis, Haar rotations, n in its box), and the parts must form one
connected object: part i and part j touch when a point of the segment between their centres
(:data:`OVERLAP_SAMPLES` points) lies inside both, and the graph of touching parts must be connected. Without
that constraint a part could float anywhere the data do not see at almost no cost in evidence, and its volume
would be counted in the object's. The constraint truncates the product prior; :func:`sample_prior` draws the
truncated prior exactly (rejection), so a tempered SMC's evidence is that of the truncated prior and evidences of
different K compare.

The parts are exchangeable (the posterior has K! copies of every mode); summaries order them by volume
(:func:`canonical_order`).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.rotation import rotation_matrix
from bayestouch.inference import contact as cm
from bayestouch.io.occupancy import Occupancy

__all__ = [
    "PART_PARAMS",
    "NOISE_PARAMS",
    "MAX_PARTS",
    "OVERLAP_SAMPLES",
    "param_names",
    "angle_columns",
    "PartsPrior",
    "parts_prior",
    "log_prior",
    "sample_prior",
    "union_distance",
    "connected",
    "make_parts_log_prob",
    "part_volumes",
    "canonical_order",
    "inside_union",
    "bounding_boxes",
    "occupancy_grid",
]

#: parameters of one part (the first 10 of the single n-ellipsoid's layout)
PART_PARAMS = cm.PARAM_NAMES[:10]
#: the shared noise parameters after the parts
NOISE_PARAMS = ("log_sigma", "w_in", "w_out")
#: the most parts a fit considers
MAX_PARTS = 4
#: points of the segment between two centres tested for a common interior point (connectivity prior)
OVERLAP_SAMPLES = 17
_TINY = 1e-300


def _check_k(k) -> int:
    k = int(k)
    if not 1 <= k <= MAX_PARTS:
        raise BadInput(f"parts: expected a number of parts from 1 to {MAX_PARTS}, got {k}")
    return k


def param_names(k: int) -> tuple[str, ...]:
    """Names of θ's columns for ``k`` parts: ``x_G_0 … log_n_0, x_G_1 …, log_sigma, w_in, w_out``."""
    k = _check_k(k)
    return tuple(f"{name}_{j}" for j in range(k) for name in PART_PARAMS) + NOISE_PARAMS


def angle_columns(k: int) -> list[int]:
    """The columns of a ``k``-part θ (10 k + 3,) holding the parts' Euler angles: each part's
    :data:`~bayestouch.inference.contact.ANGLE_COLUMNS`, periodic (:data:`~bayestouch.inference.contact.ANGLE_PERIODS`
    each)."""
    return [10 * j + c for j in range(_check_k(k)) for c in cm.ANGLE_COLUMNS]


class PartsPrior(NamedTuple):
    """The prior of a K-part union for one data set: K, each part's
    :class:`~bayestouch.inference.contact.Bounds` (the single n-ellipsoid's first 10 entries) and the noise box."""

    k: int
    part: cm.Bounds
    noise_lower: jnp.ndarray
    noise_upper: jnp.ndarray

    @property
    def lower(self):
        """The box's lower corner (10 K + 3,) in θ's layout."""
        return jnp.concatenate([jnp.tile(self.part.lower, self.k), self.noise_lower])

    @property
    def upper(self):
        """The box's upper corner (10 K + 3,) in θ's layout."""
        return jnp.concatenate([jnp.tile(self.part.upper, self.k), self.noise_upper])


def parts_prior(points, k: int, priors: cm.PriorParams | None = None) -> PartsPrior:
    """The prior of ``k`` parts for contacts ``points (M, 3)`` m (the single n-ellipsoid's per part, module
    docstring)."""
    priors = priors or cm.load_priors()
    b = cm.bounds_for(points, priors, noise="outlier")
    part = cm.Bounds(b.lower[:10], b.upper[:10], b.size_mu, b.size_sd)
    return PartsPrior(_check_k(k), part, jnp.asarray(b.lower[10:]), jnp.asarray(b.upper[10:]))


def _split(theta, k: int):
    """Parts (…, K, 10) and noise (…, 3) of θ (…, 10 K + 3)."""
    return theta[..., : 10 * k].reshape(*theta.shape[:-1], k, 10), theta[..., 10 * k :]


def _gauge(part, points):
    """Σ_j |q_j|^n (…, T) of points (…, T, 3) m in the scaled principal frames of parts (…, 10): ≤ 1 inside."""
    R = jnp.vectorize(rotation_matrix, signature="(3)->(3,3)")(part[..., 6:9])
    q = jnp.einsum("...tk,...kj->...tj", points - part[..., None, 0:3], R) / jnp.exp(part[..., None, 3:6])
    return jnp.sum(jnp.exp(jnp.exp(part[..., None, 9:10]) * jnp.log(jnp.abs(q) + _TINY)), axis=-1)


def connected(theta, k: int):
    """Whether the parts of θ (…, 10 K + 3) form one connected object (module docstring): (…,) bool."""
    k = _check_k(k)
    if k == 1:
        return jnp.ones(theta.shape[:-1], bool)
    parts, _ = _split(theta, k)
    c = parts[..., 0:3]
    t = jnp.linspace(0.0, 1.0, OVERLAP_SAMPLES)[:, None]
    adj = []
    for i in range(k):
        row = []
        for j in range(k):
            if i == j:
                row.append(jnp.ones(theta.shape[:-1], bool))
                continue
            seg = c[..., i, None, :] + t * (c[..., j, None, :] - c[..., i, None, :])  # (…, T, 3)
            both = (_gauge(parts[..., i, :], seg) <= 1.0) & (_gauge(parts[..., j, :], seg) <= 1.0)
            row.append(jnp.any(both, axis=-1))
        adj.append(jnp.stack(row, axis=-1))
    a = jnp.stack(adj, axis=-2).astype(jnp.float64)  # (…, K, K), symmetric
    reach = a
    for _ in range(k - 2):
        reach = jnp.minimum(reach @ a, 1.0)
    return jnp.all(reach > 0, axis=(-2, -1))


def log_prior(theta, prior: PartsPrior):
    """Log prior density (…,) of θ (…, 10 K + 3), up to a constant: each part's
    (:func:`bayestouch.inference.contact.log_prior`), the noise box, −inf for parts that do not connect."""
    parts, noise = _split(theta, prior.k)
    lp = jnp.sum(cm.log_prior(parts, prior.part), axis=-1)
    box = jnp.all((noise >= prior.noise_lower) & (noise <= prior.noise_upper), axis=-1)
    ok = box & connected(theta, prior.k)
    return jnp.where(ok, lp, -jnp.inf)


def sample_prior(prior: PartsPrior, count: int, rng: np.random.Generator, batch: int | None = None) -> np.ndarray:
    """``count`` independent draws (count, 10 K + 3) of the truncated prior (:func:`log_prior`), by rejection from
    the product of the parts' priors (:func:`bayestouch.inference.contact.sample_prior`).

    Raises
    ------
    RuntimeError
        When fewer than one draw in 10⁵ connects (a prior box far wider than the parts).
    """
    k, count = prior.k, int(count)
    batch = int(batch or max(4 * count, 1024))
    lo, hi = np.asarray(prior.noise_lower, float), np.asarray(prior.noise_upper, float)
    kept, tried = [], 0
    while sum(len(x) for x in kept) < count:
        parts = cm.sample_prior(prior.part, batch * k, rng).reshape(batch, 10 * k)
        noise = lo + (hi - lo) * rng.random((batch, lo.size))
        x = np.concatenate([parts, noise], axis=1)
        kept.append(x[np.asarray(_connected_jit(jnp.asarray(x), k))])
        tried += batch
        if tried >= 100_000 and sum(len(x) for x in kept) < tried * 1e-5:
            raise RuntimeError(f"sample_prior: {k} parts drawn from the prior box almost never connect")
    return np.concatenate(kept)[:count]


_connected_jit = jax.jit(connected, static_argnums=1)


def union_distance(theta, hom, k: int):
    """First-order signed distances (W, M) m of homogeneous points ``hom (4, M)`` to the union of the K parts of
    walkers θ (W, 10 K + 3): the minimum over the parts (> 0 outside every part)."""
    d = [cm.principal_frame(theta[:, 10 * j : 10 * j + 10], hom).d for j in range(k)]
    return jnp.min(jnp.stack(d), axis=0)


def _log_lik(theta, hom, free, k: int, log_u: float, inv_scale: float, log_miss: float):
    d = union_distance(theta, hom, k)
    ls = theta[:, 10 * k][:, None]
    w_in, w_out = theta[:, 10 * k + 1][:, None], theta[:, 10 * k + 2][:, None]
    terms = cm.outlier_terms(d, ls, w_in, w_out, log_u, inv_scale)
    terms = jnp.where(free[None] > 0, cm.free_space_terms(d, ls, log_miss), terms)
    return jnp.sum(terms, axis=1)


def _clip(theta, prior: PartsPrior):
    """θ clipped into the prior box except the parts' Euler angles (periodic)."""
    mask = np.zeros(10 * prior.k + 3, bool)
    mask[angle_columns(prior.k)] = True
    return jnp.where(mask, theta, jnp.clip(theta, prior.lower, prior.upper))


def make_parts_log_prob(points, k: int, priors: cm.PriorParams | None = None, free=None):
    """A jitted, walker-vectorised log-posterior ``f(thetas (W, 10 K + 3)) → (W,)`` of the K-part union with the
    two-sided outlier noise (NumPy in and out; −inf outside the prior, never NaN), and its prior.

    Parameters
    ----------
    points : (M, 3) float, metres
    k : int
        Number of parts, 1 … :data:`MAX_PARTS`.
    priors : PriorParams, optional
    free : (K_f, 3) float, metres, optional
        Free-space finger positions.

    Returns
    -------
    f : callable
        With ``f.parts(thetas)`` → (log-prior, log-likelihood, their gradients), as
        :func:`bayestouch.inference.contact.make_log_prob`'s.
    prior : PartsPrior
    """
    k = _check_k(k)
    priors = priors or cm.load_priors()
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 1 or not np.all(np.isfinite(p)):
        raise BadInput(f"points: expected a finite (M ≥ 1, 3) array in metres, got shape {p.shape}")
    fr = np.zeros((0, 3)) if free is None else np.asarray(free, float).reshape(-1, 3)
    if not np.all(np.isfinite(fr)):
        raise BadInput("free: free-space points must be finite (K, 3) metres")
    allp = np.concatenate([p, fr])
    hom = jnp.asarray(np.concatenate([allp.T, np.ones((1, len(allp)))]))
    mask = jnp.asarray(np.r_[np.zeros(len(p)), np.ones(len(fr))])
    prior = parts_prior(p, k, priors)
    log_u = float(np.log(2.0 / (np.pi * priors.outlier_scale)))
    inv = 1.0 / float(priors.outlier_scale)
    log_miss = float(np.log(priors.free_miss))

    def lik(t):
        ll = _log_lik(_clip(t, prior), hom, mask, k, log_u, inv, log_miss)
        return jnp.where(jnp.isnan(ll), -jnp.inf, ll)

    def post(t):
        lp = log_prior(t, prior)
        out = jnp.where(jnp.isfinite(lp), lp + lik(t), -jnp.inf)
        return jnp.where(jnp.isnan(out), -jnp.inf, out)

    def pieces(t):
        def prior_sum(x):
            lp = log_prior(x, prior)
            return jnp.sum(jnp.where(jnp.isfinite(lp), lp, 0.0)), lp

        def lik_sum(x):
            ll = lik(x)
            return jnp.sum(jnp.where(jnp.isfinite(ll), ll, 0.0)), ll

        (_, lp), g_lp = jax.value_and_grad(prior_sum, has_aux=True)(t)
        (_, ll), g_ll = jax.value_and_grad(lik_sum, has_aux=True)(t)
        return lp, ll, g_lp, g_ll

    post_jit, pieces_jit = jax.jit(post), jax.jit(pieces)
    dim = 10 * k + 3

    def f(thetas):
        th = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
        if th.shape[1] != dim:
            raise BadInput(f"thetas: expected a (W, {dim}) array of parameter vectors, got shape {th.shape}")
        return np.asarray(post_jit(jnp.asarray(th)))

    def parts(thetas):
        """(log-prior (W,), log-likelihood (W,), their gradients (W, D) each) of walkers (W, D)."""
        return tuple(np.asarray(o) for o in pieces_jit(jnp.asarray(thetas, dtype=jnp.float64)))

    prior_jit = jax.jit(lambda t: log_prior(t, prior))
    f.parts = parts
    f.log_prior = lambda thetas: np.asarray(prior_jit(jnp.asarray(thetas, dtype=jnp.float64)))
    return f, prior


def part_volumes(theta, k: int) -> np.ndarray:
    """Closed-form volumes (N, K) m³ (paper eq. 11) of each part of draws θ (N, 10 K + 3); overlaps counted twice."""
    parts, _ = _split(np.asarray(theta, float), k)
    flat = parts.reshape(-1, 10)
    nat = np.column_stack([flat[:, :3], np.exp(flat[:, 3:6]), flat[:, 6:9], np.exp(flat[:, 9])])
    vol = jax.vmap(lambda v: ne.volume(ne.from_vector(v)))(jnp.asarray(nat))
    return np.asarray(vol).reshape(len(parts), k)


def canonical_order(theta, k: int) -> np.ndarray:
    """Draws θ (N, 10 K + 3) with each draw's parts reordered by volume, largest first (one labelling of the K!
    exchangeable copies)."""
    th = np.asarray(theta, float)
    parts, noise = _split(th, k)
    order = np.argsort(-part_volumes(th, k), axis=1, kind="stable")
    parts = np.take_along_axis(parts, order[:, :, None], axis=1)
    return np.concatenate([parts.reshape(len(th), 10 * k), noise], axis=1)


def _inside(theta, k: int, pts):
    """(N, P) bool: points ``pts`` (N, P, 3) m inside the union of each draw θ (N, 10 K + 3) (JAX arrays)."""
    parts, _ = _split(theta, k)
    return jnp.any(jnp.stack([_gauge(parts[:, j, :], pts) for j in range(k)]) <= 1.0, axis=0)


def inside_union(theta, k: int, points) -> np.ndarray:
    """Whether points lie inside the union of each draw θ (N, 10 K + 3): ``points`` (P, 3) m shared by every
    draw, or (N, P, 3) m, each draw its own; (N, P) bool."""
    th = jnp.asarray(theta, dtype=jnp.float64)
    pts = jnp.asarray(points, dtype=jnp.float64)
    if pts.ndim == 2:
        pts = jnp.broadcast_to(pts, (th.shape[0], *pts.shape))
    return np.asarray(_inside(th, k, pts))


@partial(jax.jit, static_argnums=1)
def _weighted_inside(theta, k: int, grid, weight):
    """Σ over draws of ``weight`` (N,) × [grid point inside the draw's union]: (P,), one compiled program per block
    shape (the occupancy grid's blocks are padded to one size)."""
    pts = jnp.broadcast_to(grid, (theta.shape[0], *grid.shape))
    return weight @ _inside(theta, k, pts).astype(grid.dtype)


def bounding_boxes(theta, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes (N, 3) lo, hi (m) holding each draw's union: per part centre ± |R| a (n ≥ 1)."""
    lo, hi = [], []
    for j in range(k):
        p = theta[:, 10 * j : 10 * j + 10]
        R = np.asarray(jnp.vectorize(rotation_matrix, signature="(3)->(3,3)")(jnp.asarray(p[:, 6:9])))
        half = np.einsum("nij,nj->ni", np.abs(R), np.exp(p[:, 3:6]))
        lo.append(p[:, :3] - half)
        hi.append(p[:, :3] + half)
    return np.min(lo, axis=0), np.max(hi, axis=0)


def occupancy_grid(theta, k: int, res: int = 40, chunk: int = 20) -> Occupancy:
    """The posterior occupancy grid of draws θ (N, 10 K + 3) of a K-part union (K = 1: the single n-ellipsoid,
    its first 10 parameters): the fraction of the draws inside which each of ``res``³ grid points lies, on the box
    from the 1 % quantile of the draws' lower bounds to the 99 % quantile of their upper bounds, grown by 5 %."""
    theta = np.asarray(theta, float)
    lo, hi = bounding_boxes(theta, k)
    a, b = np.quantile(lo, 0.01, axis=0), np.quantile(hi, 0.99, axis=0)
    pad = 0.05 * (b - a)
    axes = [np.linspace(a[i] - pad[i], b[i] + pad[i], res) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    g, count = jnp.asarray(grid), np.zeros(len(grid))
    for s in range(0, len(theta), chunk):
        blk = theta[s : s + chunk]
        weight = np.zeros(chunk)
        weight[: len(blk)] = 1.0
        blk = np.concatenate([blk, np.repeat(blk[-1:], chunk - len(blk), axis=0)])  # the last block padded
        count += np.asarray(_weighted_inside(jnp.asarray(blk), k, g, jnp.asarray(weight)))
    return Occupancy(*axes, (count / len(theta)).reshape(res, res, res), int(len(theta)))
