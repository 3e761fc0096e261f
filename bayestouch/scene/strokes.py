"""Strokes: a finger path over the surface at a speed, pressed to a depth.

A stroke is what the planner chooses and the device executes: where the fingertip's contact point goes
(on the true surface, metres), when (seconds), with which surface normal and direction of motion, and
how deep the pad is pressed into the surface (metres; the force then follows from the skin model).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayestouch.errors import BadInput
from bayestouch.geometry.mesh import as_rng
from bayestouch.scene.objects import SceneObject
from bayestouch.scene.paths import check_offset, check_random_sections, section_path

__all__ = ["Stroke", "stroke_from_path", "random_strokes"]


class Stroke(NamedTuple):
    """A stroke.

    Attributes
    ----------
    contact : (T, 3) float, metres
        Contact point of the pad centre on the true surface.
    normal : (T, 3) float
        Outward unit normal of the base surface there (the pad presses along −normal).
    tangent : (T, 3) float
        Unit direction of motion.
    time : (T,) float, seconds
    depth : float, metres
        Pressing depth of the pad centre below the surface.
    """

    contact: np.ndarray
    normal: np.ndarray
    tangent: np.ndarray
    time: np.ndarray
    depth: float


def _tangents(points: np.ndarray) -> np.ndarray:
    d = np.gradient(points, axis=0) if len(points) > 1 else np.array([[1.0, 0.0, 0.0]])
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.where(n > 0, n, 1.0)


def stroke_from_path(points, normals, time, depth: float) -> Stroke:
    """Build a :class:`Stroke` from sampled contact points (T, 3) m, normals (T, 3), times (T,) s, depth m."""
    pts = np.asarray(points, float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
        raise BadInput(f"stroke: contact points must be a (T ≥ 2, 3) array in metres, got shape {pts.shape}")
    if not 0 < depth < 0.005:
        raise BadInput(f"stroke: depth must be in (0, 5 mm), given in metres; got {depth:g}")
    nrm = np.asarray(normals, float)
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    return Stroke(pts, nrm, _tangents(pts), np.asarray(time, float), float(depth))


def random_strokes(
    obj: SceneObject,
    count: int,
    seed=None,
    *,
    duration: float = 2.0,
    speed: float = 0.01,
    rate: float = 50.0,
    depth: float = 3e-4,
    max_offset: float = 0.3,
) -> list[Stroke]:
    """``count`` strokes along random plane sections of ``obj``.

    Parameters
    ----------
    obj : SceneObject
    count : int
        Number of strokes, 1 to :data:`~bayestouch.scene.paths.MAX_PATHS`.
    seed : int, np.random.Generator or None
    duration : float, seconds
        Length of each stroke in time (the path length is ``speed * duration``), at most one loop around the
        object along its section (longer is refused: it was cut to one loop without a word).
    speed : float, m/s
        The paper's 1 cm/s by default.
    rate : float, Hz
        Frame rate of the taxel array.
    depth : float, metres
        Pressing depth.
    max_offset : float
        Largest distance of a section's plane from the centre, a fraction in [0, 1) of the smallest semi-axis.

    Returns
    -------
    list of Stroke
    """
    check_random_sections(
        obj, count, "strokes", duration=(duration, "seconds"), speed=(speed, "m/s"), rate=(rate, "Hz")
    )
    check_offset(max_offset)
    if isinstance(depth, bool) or not isinstance(depth, int | float | np.integer | np.floating):
        raise BadInput(f"depth: expected a pressing depth in (0, 5 mm), given in metres; got {depth!r:.60}")
    rng = as_rng(seed)
    amin = float(np.min(np.asarray(obj.shape.axes)))
    out = []
    for _ in range(count):
        nrm = rng.normal(size=3)
        off = rng.uniform(-max_offset, max_offset) * amin
        path = section_path(obj, nrm, off, rng.uniform(0, 2 * np.pi), 2 * np.pi, speed, rate)
        if duration > path.time[-1] + 1.5 / rate:  # the stroke would end after one loop round the section
            raise BadInput(
                f"duration: {duration:g} s is longer than one loop around {obj.name} along a random section "
                f"({path.time[-1]:.1f} s at {speed:g} m/s); a stroke covers at most one loop, so give at most "
                f"about {path.time[-1]:.0f} s (or more strokes)"
            )
        keep = path.time <= duration + 1e-12
        out.append(stroke_from_path(path.points[keep], path.normals[keep], path.time[keep], depth))
    return out
