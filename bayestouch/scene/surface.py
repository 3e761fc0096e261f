"""The true surface of an object as a pure JAX pytree, and its signed distance (contact, eq. 14–15).

surface = n-ellipsoid (eq. 4–6) ∘ FFD lattice (X = B P, eq. 8) + height field along the normal (texture grating +
roughness + defects). :func:`signed_distance` φ(x) of points (..., 3) in metres is positive outside, in metres; a
taxel at x touches when φ(x) ≤ 0, with penetration −φ(x). How φ is built: ``docs/geometry.md``.
"""

from __future__ import annotations

from typing import NamedTuple

from jax.scipy.special import gammaln

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne

__all__ = ["Texture", "Defects", "Surface", "height", "defect_height", "signed_distance", "ffd_displacement"]


class Texture(NamedTuple):
    """Texture height field in the object's principal frame.

    amplitude : float, metres
        Of the grating A sin(2π k·y / λ).
    wavelength : float, metres
    orientation : float, radians
        Direction of k in the principal x–y plane.
    roughness : float, metres
        RMS of the random part (a fixed sum of cosines; directions and phases in ``rough_k``, ``rough_phase``).
    rough_k : (K, 3) float, 1/metres
        Wave vectors of the roughness cosines.
    rough_phase : (K,) float, radians
    """

    amplitude: jnp.ndarray
    wavelength: jnp.ndarray
    orientation: jnp.ndarray
    roughness: jnp.ndarray
    rough_k: jnp.ndarray
    rough_phase: jnp.ndarray


class Defects(NamedTuple):
    """Defects as arrays (D of them). ``sign`` +1 bump, −1 shallow or crack; ``segment`` 1 for cracks.

    centre, end : (D, 3) float, metres (world frame; ``end`` = ``centre`` for bumps and shallows)
    radius, depth : (D,) float, metres
    """

    sign: jnp.ndarray
    segment: jnp.ndarray
    centre: jnp.ndarray
    end: jnp.ndarray
    radius: jnp.ndarray
    depth: jnp.ndarray


class Surface(NamedTuple):
    """Everything that defines the true surface (a pytree: jit, vmap and grad go through it).

    shape : NEllipsoid
    lower, upper : (3,) float, metres
        FFD box in the principal frame.
    displacement : (l, m, k, 3) float, metres
        Control-point displacements from the identity lattice (zeros: no deformation; shape (1, 1, 1, 3):
        no lattice at all, which skips the FFD inversion).
    texture : Texture
    defects : Defects
    """

    shape: ne.NEllipsoid
    lower: jnp.ndarray
    upper: jnp.ndarray
    displacement: jnp.ndarray
    texture: Texture
    defects: Defects


def _bernstein(deg: int, s):
    i = jnp.arange(deg + 1)
    logc = gammaln(deg + 1.0) - gammaln(i + 1.0) - gammaln(deg - i + 1.0)
    s = jnp.clip(s, 0.0, 1.0)[..., None]
    return jnp.exp(logc) * s**i * (1.0 - s) ** (deg - i)


def ffd_displacement(surf: Surface, y):
    """FFD displacement D(y) = Σ B(y) ΔP at principal-frame points ``y (..., 3)`` metres → (..., 3)."""
    l, m, k, _ = surf.displacement.shape
    if min(l, m, k) < 2:
        return jnp.zeros_like(y)
    s = (y - surf.lower) / (surf.upper - surf.lower)
    bu, bv, bw = _bernstein(l - 1, s[..., 0]), _bernstein(m - 1, s[..., 1]), _bernstein(k - 1, s[..., 2])
    return jnp.einsum("...i,...j,...k,ijkd->...d", bu, bv, bw, surf.displacement)


def height(surf: Surface, foot_local):
    """Height (...,) in metres, outward positive, at base-surface points given in the principal frame."""
    t = surf.texture
    d = jnp.stack([jnp.cos(t.orientation), jnp.sin(t.orientation), 0.0])
    h = t.amplitude * jnp.sin(2.0 * jnp.pi * (foot_local @ d) / t.wavelength)
    kk = t.rough_k.shape[0]
    if kk:
        h = h + t.roughness * jnp.sqrt(2.0 / kk) * jnp.sum(jnp.cos(foot_local @ t.rough_k.T + t.rough_phase), -1)
    if surf.defects.sign.shape[0]:
        h = h + defect_height(surf.defects, ne.to_world(surf.shape, foot_local))
    return h


def defect_height(df: Defects, y):
    """Summed height (...,) in metres, outward positive, of the defects at world points ``y (..., 3)`` m:
    Gaussian bumps and shallows around their centre, cracks around their segment."""
    y = y[..., None, :]  # (..., 1, 3) against (D, 3)
    seg = df.end - df.centre
    tt = jnp.sum((y - df.centre) * seg, -1) / jnp.maximum(jnp.sum(seg * seg, -1), 1e-30)
    tt = jnp.clip(tt, 0.0, 1.0) * df.segment
    r2 = jnp.sum((y - (df.centre + tt[..., None] * seg)) ** 2, -1)
    return jnp.sum(df.sign * df.depth * jnp.exp(-0.5 * r2 / df.radius**2), -1)


def signed_distance(surf: Surface, x, ffd_steps: int = 6):
    """Signed distance φ (...,) in metres of world points ``x (..., 3)`` to the true surface (> 0 outside)."""
    xl = ne.to_local(surf.shape, x)
    if min(surf.displacement.shape[:3]) < 2:  # no lattice (static shape): nothing to invert
        y = xl
    else:

        def step(y, _):
            return xl - ffd_displacement(surf, y), None

        y, _ = jax.lax.scan(step, xl, None, length=ffd_steps)
    dist, grad, gnorm = ne.first_order_distance(surf.shape, y)
    foot = y - (dist / gnorm)[..., None] * grad
    return dist - height(surf, foot)
