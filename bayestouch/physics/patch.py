"""The contact patch as an *output*: the superellipse (Lamé curve) of the paper's eq. 16–18, |x/a|^n + |y/b|^n = 1,
fitted to a pressure map (Pa on a taxel grid with coordinates in metres) and summarised by (a, b, n, angle,
centre) with :func:`fit_patch`, rather than prescribed (why: ``docs/physics_notes.md``).

:func:`superellipse` and the area formulas are pure JAX; :func:`fit_patch` is NumPy/SciPy at the edge of the model
(it thresholds, so it is not differentiable).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from jax.scipy.special import gammaln as lg
from scipy.optimize import least_squares

from bayestouch.backend import jnp
from bayestouch.errors import BadInput

__all__ = ["Patch", "superellipse", "superellipse_area", "superellipse_area_eq18", "fit_patch"]


class Patch(NamedTuple):
    """A fitted contact patch (SI units).

    Attributes
    ----------
    a : float, m
        Semi-axis along ``angle``; the larger one (a ≥ b).
    b : float, m
        Semi-axis across ``angle``.
    n : float, 1
        Superellipse exponent of eq. 16 (2: ellipse; → ∞: rectangle).
    angle : float, rad
        Direction of the a-axis from the map's x-axis, in (−π/2, π/2].
    centre : (2,) float, m
        (x, y) of the patch centre.
    """

    a: float
    b: float
    n: float
    angle: float
    centre: np.ndarray

    @property
    def area(self) -> float:
        """Area of the patch, m² (eq. 18)."""
        return float(superellipse_area(self.a, self.b, self.n))


def superellipse(a, b, n, x, y):
    """Level function of the Lamé curve of eq. 16: L = |x/a|^n + |y/b|^n.

    L < 1 inside the patch, = 1 on its boundary, > 1 outside.

    Parameters
    ----------
    a, b : float, m
        Semi-axes along x and y (the paper's half contact length and half width).
    n : float, 1
        Exponent, > 0.
    x, y : (...,) float, m
        Points in the patch frame (centred, rotated).

    Returns
    -------
    (...,) float, 1
    """
    x = jnp.asarray(x, dtype=jnp.float64)
    y = jnp.asarray(y, dtype=jnp.float64)
    return jnp.abs(x / a) ** n + jnp.abs(y / b) ** n


def superellipse_area(a, b, n):
    """Area of the superellipse |x/a|^n + |y/b|^n ≤ 1: A = 4ab Γ(1+1/n)² / Γ(1+2/n), m².

    The paper's eq. 18 writes the same area as 4^(1−1/n) ab √π Γ(1+1/n)/Γ(1/2+1/n)
    (:func:`superellipse_area_eq18`). The two are identical: Legendre's duplication formula
    Γ(z)Γ(z+½) = 2^(1−2z) √π Γ(2z) at z = ½ + 1/n gives Γ(1+2/n) = 4^(1/n) Γ(½+1/n) Γ(1+1/n)/√π.
    Checks: n = 2 → πab (ellipse), n = 1 → 2ab (rhombus), n → ∞ → 4ab (rectangle).

    Parameters
    ----------
    a, b : float or array, m
    n : float or array, 1 (> 0)

    Returns
    -------
    float or array, m²
    """
    n = jnp.asarray(n, dtype=jnp.float64)
    return 4.0 * a * b * jnp.exp(2.0 * lg(1.0 + 1.0 / n) - lg(1.0 + 2.0 / n))


def superellipse_area_eq18(a, b, n):
    """The paper's eq. 18 as printed: A = 4^(1−1/n) a b √π Γ(1+1/n) / Γ(1/2+1/n), m².

    Equal to :func:`superellipse_area` for every n > 0 (see there); kept to show the check.
    """
    n = jnp.asarray(n, dtype=jnp.float64)
    return 4.0 ** (1.0 - 1.0 / n) * a * b * jnp.sqrt(jnp.pi) * jnp.exp(lg(1.0 + 1.0 / n) - lg(0.5 + 1.0 / n))


# ---------------------------------------------------------------- fitting


def _boundary_points(p, xs, ys, threshold):
    """Sub-taxel points of the level set p = threshold: linear interpolation along every grid edge
    whose two ends lie on opposite sides of the threshold. Returns (K, 2) points (x, y)."""
    inside = p > threshold
    pts = []
    # along x (neighbours in a row)
    cross = inside[:, :-1] != inside[:, 1:]
    i, j = np.nonzero(cross)
    pa, pb = p[i, j], p[i, j + 1]
    t = np.clip((threshold - pa) / (pb - pa), 0.0, 1.0)
    pts.append(np.stack([xs[j] + t * (xs[j + 1] - xs[j]), ys[i]], axis=1))
    # along y (neighbours in a column)
    cross = inside[:-1, :] != inside[1:, :]
    i, j = np.nonzero(cross)
    pa, pb = p[i, j], p[i + 1, j]
    t = np.clip((threshold - pa) / (pb - pa), 0.0, 1.0)
    pts.append(np.stack([xs[j], ys[i] + t * (ys[i + 1] - ys[i])], axis=1))
    return np.concatenate(pts, axis=0)


def _radius(q, pts):
    """Homogeneous radius ρ = (|u/a|^n + |v/b|^n)^(1/n) of points in the frame of q = (cx, cy, θ, ln a,
    ln b, ln n); ρ = 1 on the curve. Computed with log-sum-exp so large n cannot overflow."""
    cx, cy, th, la, lb, ln = q
    n = math.exp(ln)
    dx, dy = pts[:, 0] - cx, pts[:, 1] - cy
    c, s = math.cos(th), math.sin(th)
    u = c * dx + s * dy
    v = -s * dx + c * dy
    with np.errstate(divide="ignore"):
        lu = n * (np.log(np.abs(u)) - la)
        lv = n * (np.log(np.abs(v)) - lb)
    return np.exp(np.logaddexp(lu, lv) / n)


def fit_patch(pressure, xs, ys, threshold) -> Patch:
    """Fit the superellipse of eq. 16 (a, b, n, orientation, centre) to a thresholded pressure map.

    1. The patch is {p > threshold}; its centroid and second moments give the centre, the orientation
       of the major axis and ellipse-equivalent semi-axes as a start.
    2. The boundary is located to sub-taxel accuracy by linear interpolation of p along the grid edges
       that cross the threshold.
    3. (centre, angle, ln a, ln b, ln n) minimise Σ(ρ − 1)² over those boundary points, with
       ρ = (|u/a|^n + |v/b|^n)^(1/n) the homogeneous radius (≈ relative radial distance), by
       ``scipy.optimize.least_squares`` from a few starts (n₀ = 2, 4; angle₀ and angle₀ + π/4, which
       covers near-square patches whose second moments do not fix the angle).

    Parameters
    ----------
    pressure : (H, W) float, Pa
        Pressure map; ``pressure[i, j]`` is at (xs[j], ys[i]).
    xs : (W,) float, m
        Increasing taxel x coordinates.
    ys : (H,) float, m
        Increasing taxel y coordinates.
    threshold : float, Pa
        Contact threshold (e.g. a few % of the peak, or the taxel noise floor).

    Returns
    -------
    Patch
        a ≥ b; angle of the a-axis in (−π/2, π/2].

    Raises
    ------
    BadInput
        Shapes that do not match, or fewer than 3 taxels / 6 boundary points above the threshold.
    """
    p = np.asarray(pressure, dtype=float)
    xs = np.asarray(xs, dtype=float)
    ys = np.asarray(ys, dtype=float)
    if p.ndim != 2 or xs.shape != (p.shape[1],) or ys.shape != (p.shape[0],):
        raise BadInput(
            f"fit_patch: pressure must be (H, W) with xs (W,) and ys (H,); got {p.shape}, {xs.shape}, {ys.shape}"
        )
    if not (np.all(np.isfinite(p)) and np.all(np.diff(xs) > 0) and np.all(np.diff(ys) > 0)):
        raise BadInput("fit_patch: pressure must be finite and xs, ys strictly increasing")
    inside = p > threshold
    if inside.sum() < 3:
        raise BadInput(
            f"fit_patch: {int(inside.sum())} taxel(s) above threshold {threshold:g} Pa; "
            "need a patch of at least 3 taxels (lower the threshold)"
        )
    pts = _boundary_points(p, xs, ys, threshold)
    if len(pts) < 6:
        raise BadInput(f"fit_patch: only {len(pts)} boundary points at threshold {threshold:g} Pa; need ≥ 6")

    X, Y = np.meshgrid(xs, ys)
    px, py = X[inside], Y[inside]
    cx, cy = px.mean(), py.mean()
    cov = np.cov(np.stack([px - cx, py - cy]), bias=True)
    lam, vec = np.linalg.eigh(cov)  # ascending
    th0 = math.atan2(vec[1, 1], vec[0, 1])
    a0 = 2.0 * math.sqrt(max(lam[1], 1e-30))
    b0 = 2.0 * math.sqrt(max(lam[0], 1e-30))
    # work in units of the patch size for conditioning
    L = math.sqrt(a0 * b0) or 1.0
    pts_n = (pts - [cx, cy]) / L

    def resid(q):
        return _radius(q, pts_n) - 1.0

    best = None
    lower = [-np.inf, -np.inf, -np.inf, -np.inf, -np.inf, math.log(0.3)]
    upper = [np.inf, np.inf, np.inf, np.inf, np.inf, math.log(50.0)]
    for n0 in (2.0, 4.0):
        for dth in (0.0, math.pi / 4):
            q0 = np.array([0.0, 0.0, th0 + dth, math.log(a0 / L), math.log(b0 / L), math.log(n0)])
            r = least_squares(resid, q0, bounds=(lower, upper), x_scale=1.0, xtol=1e-12, ftol=1e-12)
            if best is None or r.cost < best.cost:
                best = r
    qx, qy, th, la, lb, ln = best.x
    a, b, n = L * math.exp(la), L * math.exp(lb), math.exp(ln)
    if b > a:
        a, b, th = b, a, th + math.pi / 2
    th = math.pi / 2 - (math.pi / 2 - th) % math.pi  # wrap into (−π/2, π/2]
    return Patch(a, b, n, th, np.array([cx + L * qx, cy + L * qy]))
