"""The n-ellipsoid of eq. 4–6: the unit n-sphere |Y1|^n + |Y2|^n + |Y3|^n = 1 mapped by
y = u + R diag(a, b, c) Y, with R from eq. 2.

All functions are pure JAX functions of a :class:`NEllipsoid` (a NamedTuple, hence a pytree: it can
be batched with ``vmap`` and differentiated) and of point arrays in metres.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np
from jax.scipy.special import gammaln

from bayestouch.backend import jax, jnp, pad_pow2
from bayestouch.errors import BadInput, shown
from bayestouch.geometry.rotation import rotation_matrix

__all__ = [
    "NEllipsoid",
    "check_shape",
    "from_vector",
    "to_vector",
    "to_local",
    "to_world",
    "inside_outside",
    "radial_distance",
    "unit_nsphere",
    "surface_point",
    "project_to_surface",
    "normals",
    "first_order_distance",
    "ray_distances",
    "volume",
    "second_moment",
    "evaluate",
    "PARAM_NAMES",
]

_TINY = 1e-300

#: names of the ten geometric parameters d1..d10, in the order of :func:`to_vector`.
PARAM_NAMES = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n")


class NEllipsoid(NamedTuple):
    """Parameters of an n-ellipsoid (d1..d10 of the paper; p, q of eq. 3 live with J(I)).

    Attributes
    ----------
    centre : (3,) float, metres
        ``(x_G, y_G, z_G)``.
    axes : (3,) float, metres
        Semi-axes ``(a, b, c)``, all > 0.
    angles : (3,) float, radians
        Euler angles ``(xi, psi, zeta)``; R = R(z, ζ) R(x, ξ) R(z, ψ).
    n : float, dimensionless
        Exponent, > 0; 2 is an ellipsoid, n → ∞ a box.
    """

    centre: jax.Array
    axes: jax.Array
    angles: jax.Array
    n: jax.Array

    @property
    def rotation(self):
        """(3, 3) rotation matrix of eq. 2."""
        return rotation_matrix(self.angles)


def check_shape(s: NEllipsoid, where: str = "shape") -> None:
    """Refuse (:class:`~bayestouch.errors.BadInput` naming ``where``) an n-ellipsoid whose parameters are not
    numbers of the stated forms: centre (3,) finite metres, axes (3,) finite > 0 metres, angles (3,) finite
    radians, n finite > 0 (NaN or a negative axis gave NaN or inside-out meshes without a word)."""
    if not all(hasattr(s, f) for f in ("centre", "axes", "angles", "n")):
        raise BadInput(
            f"{where}: expected an NEllipsoid (centre, axes, angles, n; e.g. load_object(NAME).shape), got "
            f"{type(s).__name__} {s!r:.60}"
        )
    for name, shape, positive in (
        ("centre", (3,), False),
        ("axes", (3,), True),
        ("angles", (3,), False),
        ("n", (), True),
    ):
        raw = getattr(s, name)
        try:
            v = np.asarray(raw, dtype=float)
        except (TypeError, ValueError):  # text, a ragged nesting: "could not convert string to float"
            v = None
        if v is None or v.shape != shape or not np.all(np.isfinite(v)) or (positive and not np.all(v > 0)):
            count = f"{shape[0]} finite numbers" if shape else "one finite number"
            got = np.asarray(raw).tolist() if v is not None else shown(raw, 60)
            raise BadInput(f"{where}: {name} must be {count}{' > 0' if positive else ''}, got {got}")


def from_vector(v) -> NEllipsoid:
    """Build from the 10-vector ``(x_G, y_G, z_G, a, b, c, xi, psi, zeta, n)`` (SI units)."""
    v = jnp.asarray(v, dtype=jnp.float64)
    return NEllipsoid(v[..., 0:3], v[..., 3:6], v[..., 6:9], v[..., 9])


def to_vector(s: NEllipsoid):
    """The 10-vector of :func:`from_vector`."""
    return jnp.concatenate([s.centre, s.axes, s.angles, jnp.atleast_1d(s.n)], axis=-1)


def to_local(s: NEllipsoid, points):
    """World points (…, 3) in metres → the principal frame of ``s``: R^T (x − u)."""
    return (jnp.asarray(points) - s.centre) @ s.rotation


def to_world(s: NEllipsoid, local):
    """Principal-frame points (…, 3) in metres → world: u + R x'."""
    return jnp.asarray(local) @ s.rotation.T + s.centre


def _abs_pow(x, n):
    # |x|^n that is finite, with finite gradients in x and n, also at x = 0
    return jnp.exp(n * jnp.log(jnp.maximum(jnp.abs(x), _TINY)))


def inside_outside(s: NEllipsoid, points):
    """Inside–outside function F(x) = Σ |x'_i / a_i|^n.

    Parameters
    ----------
    s : NEllipsoid
    points : (..., 3) float, metres

    Returns
    -------
    (...,) float
        < 1 inside, 1 on the surface, > 1 outside.
    """
    loc = to_local(s, points) / s.axes
    return jnp.sum(_abs_pow(loc, s.n), axis=-1)


def radial_distance(s: NEllipsoid, points):
    """Signed radial distance to the surface along the ray from the centre, metres.

    d = |x − u| (1 − F^(−1/n)): exact for spheres and a close, smooth approximation of the Euclidean
    distance elsewhere (Jaklič, Leonardis & Solina 2000, §2.4). Positive outside, negative inside.

    Parameters
    ----------
    points : (..., 3) float, metres

    Returns
    -------
    (...,) float, metres
    """
    loc = to_local(s, points)
    r = jnp.sqrt(jnp.sum(loc * loc, axis=-1) + _TINY)
    u = loc / r[..., None]
    # radius of the surface along the unit direction u: (Σ |u_i/a_i|^n)^(-1/n)
    g = jnp.sum(_abs_pow(u / s.axes, s.n), axis=-1)
    rho = jnp.exp(-jnp.log(g) / s.n)
    return r - rho


def unit_nsphere(directions, n):
    """Project directions (…, 3) radially onto the unit n-sphere |Y1|^n + |Y2|^n + |Y3|^n = 1 (eq. 4)."""
    d = jnp.asarray(directions)
    g = jnp.sum(_abs_pow(d, n), axis=-1, keepdims=True)
    return d * jnp.exp(-jnp.log(g) / n)


def surface_point(s: NEllipsoid, Y):
    """Eq. 5–6: points Y (…, 3) of the unit n-sphere → world surface points, metres."""
    return to_world(s, jnp.asarray(Y) * s.axes)


def project_to_surface(s: NEllipsoid, points):
    """Move points (…, 3) in metres radially (through the centre) onto the surface."""
    loc = to_local(s, points) / s.axes
    return to_world(s, unit_nsphere(loc, s.n) * s.axes)


def normals(s: NEllipsoid, points):
    """Outward unit normals (…, 3): ∇F normalised, at (or near) the surface points given in metres."""
    loc = to_local(s, points)
    q = loc / s.axes
    g = s.n * jnp.sign(q) * _abs_pow(q, s.n - 1.0) / s.axes
    g = g @ s.rotation.T
    return g / jnp.sqrt(jnp.sum(g * g, axis=-1, keepdims=True) + _TINY)


def first_order_distance(s: NEllipsoid, local):
    """First-order Euclidean distance to the surface, for points given in the principal frame.

    d = (G − 1)/|∇G| with G = (Σ|y_i/a_i|^n)^(1/n), which is homogeneous of degree 1: exact to first order
    near the surface for any n (Taubin 1991), unlike :func:`radial_distance`, which overstates distances
    near the flat faces of box-like shapes. Written with one log and one exp per coordinate (|q|^n and
    |q|^(n−1) = |q|^n/|q|) plus one of each per point, as it sits in the likelihood's inner loop.

    Parameters
    ----------
    local : (..., 3) float, metres
        Points in the principal frame (:func:`to_local`).

    Returns
    -------
    d : (...,) float, metres
        Signed, positive outside.
    grad : (..., 3) float, 1/metres
        ∇G in the principal frame (the outward normal direction); the foot point is y − (d/|∇G|) ∇G.
    gnorm : (...,) float, 1/metres
        |∇G|, floored at 1/|a| = 1/√(a² + b² + c²), which only the centre reaches: ∇G is homogeneous of degree 0,
        so |∇G(y)| = 1/h at the surface point y/G(y), h ≤ |a| its support distance (the n-ellipsoid lies in the box
        of half-sides a). A floor at 1/max(a, b, c) was active over the flat faces of box-like shapes (n > 2, where
        h exceeds the largest semi-axis: up to 24 % at n = 5 over a quarter of the surface) and shrank their
        distances, and its max made the likelihood kink where the two largest semi-axes are equal.
    """
    q = local / s.axes
    aq = jnp.abs(q) + _TINY
    t = jnp.exp(s.n * jnp.log(aq))  # |q_i|^n
    S = jnp.sum(t, axis=-1) + _TINY
    G = jnp.exp(jnp.log(S) / s.n)
    # ∂G/∂y_i = S^(1/n − 1) |q_i|^(n−1) sign(q_i) / a_i, with S^(1/n − 1) = G/S; the norm is taken
    # before the per-point factor G/S and the signs (fewer operations in the hot path, where only d is used)
    w = t / (aq * s.axes)
    ss = jnp.sum(w * w, axis=-1)
    pos = ss > 0.0  # 0 only at the very centre; the double where keeps the gradient finite there
    gnorm = jnp.where(pos, G / S * jnp.sqrt(jnp.where(pos, ss, 1.0)), 0.0)
    gnorm = jnp.maximum(gnorm, 1.0 / jnp.sqrt(jnp.sum(s.axes * s.axes, axis=-1)))
    grad = (G / S)[..., None] * w * jnp.sign(q)
    return (G - 1.0) / gnorm, grad, gnorm


# G − 1 above which the last Newton iterate of :func:`ray_distances` counts as off the surface (a miss)
_RAY_CONVERGED = 1e-4


def ray_distances(shape: NEllipsoid, starts, dirs, t_max: float, iters: int = 10, t_init=0.0, dtype=jnp.float64):
    """Distance along rays to the first crossing of the n-ellipsoid surface, metres (pure JAX).

    Solves G(x0 + t d) = 1 with G = (Σ|y_i/a_i|^n)^(1/n) in the principal frame by Newton's method. For n ≥ 1, G
    is a norm of the scaled local coordinates, so g(t) = G − 1 is convex along a line, and the tangent of g lies
    below it: from any start, one Newton step lands at or before the first root, and from there the iterates
    increase monotonically to it. A start inside (g < 0) thus steps back; a step below 0 is clipped to 0, and a
    ray that starts inside the surface reads 0. A step with g' ≥ 0 while g > 0 means the ray passes beside the
    surface (or the start is beyond its far side): a miss, as is a ray still outside (G − 1 > 1e-4) at the last
    step (creeping towards the minimum of g beside the surface, or grazing it). Misses read ``t_max``; every
    result lies in [0, t_max].

    Parameters
    ----------
    shape : NEllipsoid
    starts : (..., 3) float, metres
        Ray start points x0.
    dirs : (..., 3) float
        Unit ray directions d.
    t_max : float, metres
        Ray length (how far the finger travels).
    iters : int
        Newton steps. Newton converges quadratically: from the believed surface (``t_init`` = the stand-off) and
        shapes within a few mm of it, 5 steps reach ~1e-9 m; from t = 0, 10 steps reach ~1e-12 m for rays within
        ~80° of the surface normal.
    t_init : float or (...,) float, metres
        Starting guess (0, or the stand-off of the believed surface).
    dtype : jnp dtype
        float32 halves the cost on CPU; its rounding (~6e-8 of G) moves t by ~1e-9 m for centimetre shapes,
        far below contact noise.

    Returns
    -------
    (...,) float, metres
        In [0, t_max].
    """
    R = shape.rotation
    q0 = (((jnp.asarray(starts) - shape.centre) @ R) / shape.axes).astype(dtype)
    qd = ((jnp.asarray(dirs) @ R) / shape.axes).astype(dtype)
    n = jnp.asarray(shape.n).astype(dtype)
    tiny = jnp.finfo(dtype).tiny

    def g_and_slope(t):
        q = q0 + t[..., None] * qd
        aq = jnp.abs(q) + tiny
        p = jnp.exp(n * jnp.log(aq))  # |q_i|^n
        S = jnp.sum(p, axis=-1) + tiny
        G = jnp.exp(jnp.log(S) / n)
        # dG/dt = (G/S) Σ |q_i|^(n−1) sign(q_i) qd_i, with |q|^(n−1) sign(q) = |q|^n / q
        dG = G / S * jnp.sum(p / aq * jnp.sign(q) * qd, axis=-1)
        return G - 1.0, dG

    t_max = jnp.asarray(t_max, dtype)
    t0 = jnp.broadcast_to(jnp.asarray(t_init, dtype), q0.shape[:-1])

    def step(_, carry):
        t, miss, _g = carry
        g, dg = g_and_slope(t)
        away = (dg >= 0.0) & (g > 0.0)
        t_new = jnp.maximum(t - g / jnp.where(dg < 0.0, dg, -1.0), 0.0)
        miss = miss | away | (t_new > t_max)
        return jnp.where(miss, t, t_new), miss, g

    t, miss, g_last = jax.lax.fori_loop(0, iters, step, (t0, jnp.zeros(t0.shape, bool), jnp.zeros_like(t0)))
    # g at the last step's start: quadratic convergence makes the final t ~(1e-4)² closer still
    miss = miss | (g_last > _RAY_CONVERGED)
    return jnp.where(miss, t_max, jnp.clip(t, 0.0, t_max)).astype(jnp.float64)


def _dirichlet(alpha, n):
    # ∫ over the positive octant of the unit n-ball of Π x_i^(α_i − 1) dx  (Dirichlet's integral)
    alpha = jnp.asarray(alpha, dtype=jnp.float64)
    return jnp.exp(jnp.sum(gammaln(alpha / n)) - gammaln(1.0 + jnp.sum(alpha) / n)) / n**3


def volume(s: NEllipsoid):
    """Closed-form volume 8abc Γ(1+1/n)³ / Γ(1+3/n), m³ (eq. 11 for the undeformed surface)."""
    return 8.0 * jnp.prod(s.axes) * _dirichlet(jnp.array([1.0, 1.0, 1.0]), s.n)


def second_moment(s: NEllipsoid):
    """Closed-form I_ij = ∫_V y_i y_j dV about the world origin (eq. 13), m⁵; (3, 3).

    Eq. 13's boundary integral (1/5)∮ y_i y_j y_k n_k dS equals this volume integral by the
    divergence theorem, since ∂_k(y_i y_j y_k) = 5 y_i y_j.
    """
    a = s.axes
    m = jnp.stack(
        [
            8.0 * a[0] ** 3 * a[1] * a[2] * _dirichlet(jnp.array([3.0, 1.0, 1.0]), s.n),
            8.0 * a[0] * a[1] ** 3 * a[2] * _dirichlet(jnp.array([1.0, 3.0, 1.0]), s.n),
            8.0 * a[0] * a[1] * a[2] ** 3 * _dirichlet(jnp.array([1.0, 1.0, 3.0]), s.n),
        ]
    )
    R = s.rotation
    return (R * m) @ R.T + volume(s) * jnp.outer(s.centre, s.centre)


@partial(jax.jit, static_argnums=0)
def _evaluate(fn, vec, pts):
    return fn(from_vector(vec), pts)


def evaluate(fn, s: NEllipsoid, points, min_size: int = 256) -> np.ndarray:
    """NumPy edge: ``fn(s, points)`` compiled once per power-of-two batch size.

    Point arrays of varying length (finger paths, data sets) are padded to the next power of two, so
    repeated calls reuse a handful of compiled programs instead of tracing every new length.

    Parameters
    ----------
    fn : callable
        A pure function of this module taking ``(s, points)``, e.g. :func:`normals`.
    s : NEllipsoid
    points : (N, 3) float, metres

    Returns
    -------
    np.ndarray
        ``fn``'s output for the N points.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.asarray(_evaluate(fn, to_vector(s), jnp.asarray(pad_pow2(p, min_size=min_size))))[: len(p)]
