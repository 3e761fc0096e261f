"""Finger paths over an object: plane sections of the surface walked at constant speed.

A path is the curve where a plane cuts the object, followed from a start angle over a given arc, sampled
at ``rate`` samples per second while the finger moves at ``speed`` (the paper's 1 cm/s).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp, pad_pow2
from bayestouch.errors import BadInput, check_number, shown
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import as_rng
from bayestouch.scene.objects import SceneObject

__all__ = ["Path", "ray_hits", "section_path", "random_paths", "check_random_sections", "check_offset", "MAX_PATHS"]

#: most paths (or strokes) one call of :func:`random_paths` or :func:`bayestouch.scene.strokes.random_strokes`
#: makes: each walks a section round the object (~10 ms), so 10,000 take about two minutes (10⁹ ran for days)
MAX_PATHS = 10_000


class Path(NamedTuple):
    """A sampled finger path.

    Attributes
    ----------
    points : (N, 3) float, metres
        Contact points on the true (displaced) surface.
    time : (N,) float, seconds
    normals : (N, 3) float
        Outward normals of the base surface at the contacts.
    """

    points: np.ndarray
    time: np.ndarray
    normals: np.ndarray


@jax.jit
def _ray_t(vec, origin, dirs):
    s = ne.from_vector(vec)
    # the origin is inside a convex body, so F(origin + t d) − 1 has one root in t > 0: bisection
    hi = jnp.full(dirs.shape[0], 4.0 * jnp.max(s.axes))
    lo = jnp.zeros(dirs.shape[0])

    def body(_, lh):
        lo, hi = lh
        mid = 0.5 * (lo + hi)
        out = ne.inside_outside(s, origin + mid[:, None] * dirs) > 1.0
        return jnp.where(out, lo, mid), jnp.where(out, mid, hi)

    lo, hi = jax.lax.fori_loop(0, 60, body, (lo, hi))
    return 0.5 * (lo + hi)


def ray_hits(shape: ne.NEllipsoid, origin, dirs) -> np.ndarray:
    """Points (N, 3), metres, where rays from ``origin`` (inside the shape) along ``dirs (N, 3)`` leave it."""
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    pad = pad_pow2(dirs, min_size=256)  # a few compiled sizes, not one per path length
    t = np.asarray(_ray_t(ne.to_vector(shape), jnp.asarray(origin, dtype=jnp.float64), jnp.asarray(pad)))[: len(dirs)]
    return np.asarray(origin, dtype=np.float64) + t[:, None] * dirs


def section_path(
    obj: SceneObject,
    normal,
    offset: float = 0.0,
    start: float = 0.0,
    arc: float = 2 * np.pi,
    speed: float = 0.01,
    rate: float = 20.0,
) -> Path:
    """The finger path along the section of ``obj`` by a plane.

    Parameters
    ----------
    obj : SceneObject
    normal : (3,) float
        Normal of the cutting plane, in the object's principal frame.
    offset : float, metres
        Distance of the plane from the object's centre (must stay inside the object).
    start, arc : float, radians
        Start angle and angular extent of the walk around the section.
    speed : float, m/s
        Finger speed along the surface (the paper: 1 cm/s).
    rate : float, Hz
        Samples per second.
    """
    s = obj.shape
    R = np.asarray(s.rotation)
    nrm = np.asarray(normal, float)
    nrm = nrm / np.linalg.norm(nrm)
    e1 = np.cross(nrm, [0.0, 0.0, 1.0] if abs(nrm[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(nrm, e1)
    origin_local = offset * nrm
    phi = start + np.linspace(0.0, arc, 2048)
    dirs_local = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    origin = np.asarray(s.centre) + R @ origin_local
    fine = ray_hits(s, origin, dirs_local @ R.T)
    seg = np.linalg.norm(np.diff(fine, axis=0), axis=1)
    arclen = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.arange(0.0, arclen[-1] / speed, 1.0 / rate)
    at = t * speed
    base = np.stack([np.interp(at, arclen, fine[:, i]) for i in range(3)], axis=1)
    # back onto the surface along rays from the plane's origin, so the points stay in the section plane
    dirs = base - origin
    base = ray_hits(s, origin, dirs / np.linalg.norm(dirs, axis=1, keepdims=True))
    normals = ne.evaluate(ne.normals, s, base)
    return Path(obj.displace(base), t, normals)


def check_random_sections(obj, count, what: str, **positive) -> None:
    """Refuse (one line naming the argument) what :func:`random_paths` and
    :func:`~bayestouch.scene.strokes.random_strokes` cannot walk: ``obj`` that is not a scene object, ``count`` that
    is not an integer from 1 to :data:`MAX_PATHS` (``what``: "paths" or "strokes"), and any of ``positive``
    (name → (value, unit), e.g. ``speed=(0.01, "m/s")``) that is not a finite number > 0 (a negative rate or speed
    gave empty paths without a word)."""
    if not hasattr(getattr(obj, "shape", None), "axes"):
        raise BadInput(f"obj: expected a SceneObject (load_object(NAME)), got {type(obj).__name__} {shown(obj, 60)}")
    if isinstance(count, bool | np.bool_) or not isinstance(count, int | np.integer) or not 1 <= count <= MAX_PATHS:
        raise BadInput(
            f"count: expected an integer number of {what} ≥ 1 (at most {MAX_PATHS:,} in one call), got {shown(count)}"
        )
    for name, (value, unit) in positive.items():
        check_number(value, name, 0, above=True, unit=unit)


def check_offset(max_offset) -> None:
    """Refuse a ``max_offset`` that is not a number in [0, 1) (a fraction of the smallest semi-axis: a plane at 1 or
    beyond misses the object)."""
    if isinstance(max_offset, bool) or not isinstance(max_offset, int | float) or not 0 <= max_offset < 1:
        raise BadInput(f"max_offset: expected a fraction in [0, 1) of the smallest semi-axis, got {shown(max_offset)}")


def random_paths(
    obj: SceneObject,
    count: int,
    seed=None,
    *,
    arc: float = 2 * np.pi,
    speed: float = 0.01,
    rate: float = 20.0,
    max_offset: float = 0.3,
) -> list[Path]:
    """``count`` section paths with random plane orientations and offsets (a fraction of the smallest
    semi-axis), as the paper's "arbitrary paths".

    Parameters
    ----------
    obj : SceneObject
    count : int
        Number of paths, 1 to :data:`MAX_PATHS`.
    seed : int, np.random.Generator or None
    arc : float, radians
        Angular extent of each walk round its section, > 0.
    speed : float, m/s
    rate : float, Hz
        Samples per second.
    max_offset : float
        Largest distance of a cutting plane from the centre, as a fraction in [0, 1) of the smallest semi-axis.

    Returns
    -------
    list of Path
    """
    check_random_sections(obj, count, "paths", arc=(arc, "radians"), speed=(speed, "m/s"), rate=(rate, "Hz"))
    check_offset(max_offset)
    rng = as_rng(seed)
    out = []
    amin = float(np.min(np.asarray(obj.shape.axes)))
    for _ in range(count):
        nrm = rng.normal(size=3)
        off = rng.uniform(-max_offset, max_offset) * amin
        out.append(section_path(obj, nrm, off, rng.uniform(0, 2 * np.pi), arc, speed, rate))
    return out
