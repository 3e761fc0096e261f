"""Candidate strokes over the believed surface: arcs over the believed n-ellipsoid from spread start directions,
1–3 cm long at 1 cm/s, sampled at T points, pressing with a force inside the safety limits, each point with the ray
the finger approaches along (the rays of :mod:`bayestouch.planning.signal`).

:class:`Strokes` holds C strokes: paths, ray starts and directions (C, T, 3) (metres; unit), ray length ``t_max``
(m), lengths (m), forces (N) and durations (s), each (C,). How the arcs are drawn and the reach limit:
``docs/planning.md``.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import as_rng
from bayestouch.hardware.safety import Limits

__all__ = [
    "Strokes",
    "make_candidates",
    "fibonacci_sphere",
    "select",
    "random_rotation",
    "STROKE_SPEED",
    "DEFAULT_STANDOFF",
]

#: finger speed along the path, m/s (the paper's 1 cm/s strokes)
STROKE_SPEED = 0.01
#: distance of the ray starts outside the believed surface, metres (rays are twice as long)
DEFAULT_STANDOFF = 0.015


class Strokes(NamedTuple):
    """A batch of C strokes of T samples (NumPy arrays, SI units).

    Attributes
    ----------
    path : (C, T, 3) float, metres
        Path points on the believed surface.
    starts : (C, T, 3) float, metres
        Ray start points (path point + stand-off × outward normal).
    dirs : (C, T, 3) float
        Unit approach directions (believed inward normals).
    t_max : float, metres
        Ray length.
    length : (C,) float, metres
        Path length.
    force : (C,) float, newtons
        Pressing force.
    duration : (C,) float, seconds
        Stroke time (length / speed).
    """

    path: np.ndarray
    starts: np.ndarray
    dirs: np.ndarray
    t_max: float
    length: np.ndarray
    force: np.ndarray
    duration: np.ndarray


def select(strokes: Strokes, index) -> Strokes:
    """The strokes at ``index`` (an int keeps a batch of one)."""
    idx = np.atleast_1d(np.asarray(index))
    return Strokes(
        strokes.path[idx],
        strokes.starts[idx],
        strokes.dirs[idx],
        strokes.t_max,
        strokes.length[idx],
        strokes.force[idx],
        strokes.duration[idx],
    )


def fibonacci_sphere(count: int) -> np.ndarray:
    """``count`` nearly evenly spread unit vectors (count, 3) (the Fibonacci lattice; González 2010,
    Math. Geosci. 42:49)."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation matrix (3, 3) (QR of a Gaussian matrix, signs fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@partial(jax.jit, static_argnums=4)
def _walk(vec, p0, tan0, h, steps: int):
    """Walk T−1 steps of lengths ``h (C,)`` from surface points ``p0 (C, 3)`` along tangents ``tan0 (C, 3)``,
    re-projecting radially onto the surface after each step: (C, T, 3) path points and (C, T, 3) normals."""
    s = ne.from_vector(vec)

    def step(carry, _):
        p, tan = carry
        q = ne.project_to_surface(s, p + h[:, None] * tan)
        nq = ne.normals(s, q)
        new = q - p
        new = new - jnp.sum(new * nq, -1, keepdims=True) * nq  # keep heading, tangent at the new point
        new = new / jnp.sqrt(jnp.sum(new * new, -1, keepdims=True) + 1e-300)
        return (q, new), (q, nq)

    _, (ps, ns) = jax.lax.scan(step, (p0, tan0), None, length=steps)
    return ps, ns


def make_candidates(
    shape: ne.NEllipsoid,
    count: int = 64,
    *,
    points: int = 20,
    seed=None,
    length_range: tuple[float, float] = (0.01, 0.03),
    force_range: tuple[float, float] = (0.1, 0.5),
    standoff: float = DEFAULT_STANDOFF,
    speed: float = STROKE_SPEED,
    limits=None,
    max_polar: float = np.pi,
) -> Strokes:
    """Candidate strokes over the believed surface ``shape``.

    Parameters
    ----------
    shape : NEllipsoid
        The believed surface (the current point estimate), metres.
    count : int
        Number of candidates C.
    points : int
        Samples per stroke T (≥ 2).
    seed : int, np.random.Generator or None
        Rotation of the start lattice, travel directions, lengths and forces.
    length_range : (float, float), metres
        Path lengths, uniform.
    force_range : (float, float), newtons
        Pressing forces, uniform, capped at the safety limit ``limits.max_force``.
    standoff : float, metres
        Ray starts lie this far outside the believed surface; rays are 2 × standoff long.
    speed : float, m/s
        Finger speed (capped at ``limits.max_speed``).
    limits : Limits, optional
        Default :class:`bayestouch.hardware.safety.Limits` ().
    max_polar : float, radians
        Largest angle between a start direction and +z (π: anywhere).

    Returns
    -------
    Strokes
    """
    if count < 1 or points < 2:
        raise BadInput(f"candidates: expected count ≥ 1 and points ≥ 2, got count={count}, points={points}")
    if not (0 < length_range[0] <= length_range[1]) or not standoff > 0:
        raise BadInput(
            f"candidates: expected 0 < length_range[0] ≤ length_range[1] and standoff > 0 metres, got "
            f"{length_range}, {standoff}"
        )
    if limits is None:
        limits = Limits()
    rng = as_rng(seed)
    dirs = fibonacci_sphere(count) @ random_rotation(rng).T
    if max_polar < np.pi:  # map the lattice's polar angle [0, π] onto the reachable cap [0, max_polar]
        polar = np.arccos(np.clip(dirs[:, 2], -1, 1)) * (max_polar / np.pi)
        az = np.arctan2(dirs[:, 1], dirs[:, 0])
        dirs = np.column_stack([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az), np.cos(polar)])
    vec = ne.to_vector(shape)
    centre = np.asarray(shape.centre)
    p0 = ne.evaluate(ne.project_to_surface, shape, centre + dirs * float(np.max(np.asarray(shape.axes))))
    n0 = ne.evaluate(ne.normals, shape, p0)
    # a random tangent direction at each start
    ref = rng.normal(size=(count, 3))
    tan = ref - np.sum(ref * n0, axis=1, keepdims=True) * n0
    tan /= np.linalg.norm(tan, axis=1, keepdims=True)
    length = rng.uniform(*length_range, size=count)
    h = length / (points - 1)
    ps, ns = _walk(vec, jnp.asarray(p0), jnp.asarray(tan), jnp.asarray(h), points - 1)
    path = np.concatenate([p0[:, None], np.swapaxes(np.asarray(ps), 0, 1)], axis=1)
    nrm = np.concatenate([n0[:, None], np.swapaxes(np.asarray(ns), 0, 1)], axis=1)
    hi_force = min(force_range[1], limits.max_force)
    force = rng.uniform(min(force_range[0], hi_force), hi_force, size=count)
    v = min(speed, limits.max_speed)
    return Strokes(path, path + standoff * nrm, -nrm, 2.0 * standoff, length, force, length / v)
