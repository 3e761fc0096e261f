"""The texture indicator of eq. 3, J(I) = ∫_Γ w(X)^p |∇I(X)|^q dS, on a triangulated surface.

I is piecewise linear on the mesh (one value per vertex, (V,)), the misfit weight w piecewise constant (one value
per triangle, (F,), dimensionless); vertices in metres. :func:`indicator_energy` is a pure JAX function
(differentiable in vertices, w and I); the solve for I, constrained at the probed points, runs in SciPy at this
edge. The discretisation and the solve: ``docs/geometry.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from bayestouch.backend import jnp
from bayestouch.errors import BadInput, as_array, check_int, check_number
from bayestouch.geometry.integrals import check_mesh

__all__ = [
    "TextureIndicator",
    "triangle_gradients",
    "indicator_energy",
    "misfit_weights",
    "indicator_seeds",
    "solve_indicator",
    "texture_indicator",
]


class TextureIndicator(NamedTuple):
    """Result of :func:`texture_indicator`.

    Attributes
    ----------
    J : float
        J(I) of eq. 3 (units m^(2−q) times the dimensionless w^p; p, q as given).
    I : (V,) float
        The partition indicator at the vertices, in [0, 1].
    weights : (F,) float
        w per triangle (dimensionless).
    seeds : (V,) int
        −1 free, 0 on-surface seed, 1 off-surface seed.
    iterations : int
        Reweighting iterations used (1 for q = 2).
    """

    J: float
    I: np.ndarray
    weights: np.ndarray
    seeds: np.ndarray
    iterations: int


def triangle_gradients(vertices, faces):
    """Gradients of the three P1 hat functions on each triangle, and the triangle areas.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int

    Returns
    -------
    grads : (F, 3, 3) float, 1/metres
        ``grads[t, k]`` is ∇φ of the triangle's k-th corner.
    areas : (F,) float, m²
    """
    v = jnp.asarray(vertices)
    f = jnp.asarray(faces)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    nrm = jnp.cross(b - a, c - a)
    dbl = jnp.linalg.norm(nrm, axis=1)
    unit = nrm / dbl[:, None]
    # ∇φ_k = (n̂ × e_k) / (2A), e_k the edge opposite corner k, oriented counter-clockwise
    ga = jnp.cross(unit, c - b) / dbl[:, None]
    gb = jnp.cross(unit, a - c) / dbl[:, None]
    gc = jnp.cross(unit, b - a) / dbl[:, None]
    return jnp.stack([ga, gb, gc], axis=1), 0.5 * dbl


def indicator_energy(vertices, faces, weights, indicator, p: float = 1.0, q: float = 2.0):
    """J(I) = Σ_T w_T^p |∇I_T|^q A_T (eq. 3), exact for a P1 indicator and piecewise-constant w.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    weights : (F,) float
        w ≥ 0 per triangle.
    indicator : (V,) float
        I at the vertices.
    p, q : float
        The exponents d₁₁, d₁₂ of the 12-parameter model (q ≥ 1).

    Returns
    -------
    J : scalar float
    """
    g, area = triangle_gradients(vertices, faces)
    I = jnp.asarray(indicator)[jnp.asarray(faces)]
    grad = jnp.einsum("tk,tkd->td", I, g)
    gnorm = jnp.sqrt(jnp.sum(grad**2, axis=1))
    w = jnp.asarray(weights)
    return jnp.sum(w**p * gnorm**q * area)


def misfit_weights(vertices, faces, data, residuals, *, k: int = 8, scale: float | None = None) -> np.ndarray:
    """w per triangle: |residual| of the data interpolated to triangle centroids, over the data scale.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    data : (M, 3) float, metres
    residuals : (M,) float, metres
        Signed distance of each data point to the model surface.
    k : int
        Nearest data points used in the inverse-distance interpolation.
    scale : float, metres
        Normalisation; default the RMS distance of the data from their centroid.

    Returns
    -------
    (F,) float, dimensionless, ≥ 0
    """
    v = np.asarray(vertices, float)
    d = np.asarray(data, float)
    r = np.abs(np.asarray(residuals, float))
    cent = v[np.asarray(faces)].mean(axis=1)
    k = min(k, len(d))
    dist, idx = cKDTree(d).query(cent, k=k)
    if k == 1:
        dist, idx = dist[:, None], idx[:, None]
    wt = 1.0 / np.maximum(dist, 1e-12) ** 2
    w = np.sum(wt * r[idx], axis=1) / np.sum(wt, axis=1)
    if scale is None:
        scale = float(np.sqrt(np.mean(np.sum((d - d.mean(axis=0)) ** 2, axis=1))))
    return w / scale


def indicator_seeds(vertices, data, residuals, tol: float) -> np.ndarray:
    """Seed labels at the vertices from the probed points (eq. 3's constraint).

    Parameters
    ----------
    vertices : (V, 3) float, metres
    data : (M, 3) float, metres
    residuals : (M,) float, metres
    tol : float, metres
        A point belongs to the surface when |residual| ≤ tol.

    Returns
    -------
    (V,) int
        −1 free, 0 on-surface, 1 off-surface (off-surface wins on a shared vertex).
    """
    _, nearest = cKDTree(np.asarray(vertices, float)).query(np.asarray(data, float))
    off = np.abs(np.asarray(residuals, float)) > tol
    seeds = np.full(len(vertices), -1, dtype=np.int64)
    seeds[nearest[~off]] = 0
    seeds[nearest[off]] = 1
    return seeds


def _stiffness(grads, areas, faces, coef, nv) -> sp.csr_matrix:
    """Σ_T coef_T A_T ∇φ_i·∇φ_j assembled as a sparse (V, V) matrix."""
    local = np.einsum("tid,tjd->tij", grads, grads) * (coef * areas)[:, None, None]
    rows = np.repeat(faces, 3, axis=1).ravel()
    cols = np.tile(faces, (1, 3)).ravel()
    return sp.csr_matrix((local.ravel(), (rows, cols)), shape=(nv, nv))


def solve_indicator(
    vertices,
    faces,
    weights,
    seeds,
    p: float = 1.0,
    q: float = 2.0,
    *,
    max_iter: int = 50,
    rtol: float = 1e-6,
    floor: float = 1e-9,
) -> tuple[np.ndarray, int]:
    """Minimise J(I) over the free vertices with the seeds fixed.

    q = 2 is one sparse linear solve; q ≠ 2 uses iteratively reweighted least squares with the
    per-triangle factor (|∇I|² + δ²)^((q−2)/2), δ = ``floor`` / mean edge length.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    weights : (F,) float
    seeds : (V,) int
        From :func:`indicator_seeds`.
    p, q : float
        Exponents of eq. 3; q ≥ 1.

    Returns
    -------
    I : (V,) float in [0, 1]
    iterations : int
    """
    if q < 1:
        raise ValueError(f"q must be ≥ 1 for J(I) to be convex, got {q}")
    faces = np.asarray(faces)
    seeds = np.asarray(seeds)
    nv = len(vertices)
    I = np.where(seeds == 1, 1.0, 0.0)
    fixed = seeds >= 0
    if not fixed.any() or (seeds[fixed] == seeds[fixed][0]).all():
        # one label only: the constant field is the minimiser (J = 0)
        return np.full(nv, float(seeds[fixed][0]) if fixed.any() else 0.0), 0
    g, area = triangle_gradients(vertices, faces)
    g, area = np.asarray(g), np.asarray(area)
    wp = np.asarray(weights, float) ** p
    free = ~fixed
    edge = float(np.mean(np.linalg.norm(np.asarray(vertices)[faces[:, 1]] - np.asarray(vertices)[faces[:, 0]], axis=1)))
    delta2 = (floor / edge) ** 2
    coef = wp.copy()
    it = 0
    for it in range(1, max_iter + 1):
        K = _stiffness(g, area, faces, np.maximum(coef, 1e-300), nv)
        Kff = K[free][:, free]
        rhs = -K[free][:, fixed] @ I[fixed]
        # tiny diagonal shift keeps components without a seed (and zero-weight islands) solvable
        shift = 1e-12 * max(float(np.abs(Kff.diagonal()).max()), 1e-300)
        new = spla.spsolve((Kff + shift * sp.identity(Kff.shape[0])).tocsc(), rhs)
        change = np.max(np.abs(new - I[free])) if it > 1 else np.inf
        I[free] = np.clip(new, 0.0, 1.0)
        if q == 2.0 or change < rtol:
            break
        grad = np.einsum("tk,tkd->td", I[faces], g)
        coef = wp * (np.sum(grad**2, axis=1) + delta2) ** ((q - 2.0) / 2.0)
    return I, it


def texture_indicator(
    vertices, faces, data, residuals, p: float = 1.0, q: float = 2.0, *, tol: float, k: int = 8
) -> TextureIndicator:
    """J(I) of eq. 3 for a model surface and probed data.

    Parameters
    ----------
    vertices : (V, 3) float, metres
        The model surface X (n-ellipsoid or FFD-refined mesh).
    faces : (F, 3) int
    data : (M, 3) float, metres
        The probed points P_i.
    residuals : (M,) float, metres
        Signed distance of each P_i to the model surface.
    p, q : float
        Exponents of eq. 3.
    tol : float, metres
        Points with |residual| ≤ tol belong to the surface (I = 0).
    k : int
        Neighbours in the weight interpolation.

    Returns
    -------
    TextureIndicator

    Raises
    ------
    BadInput
        A mesh, data or residuals of the wrong form (text, wrong shapes, NaN, face indices out of range), ``p``,
        ``q`` or ``tol`` not finite numbers > 0, ``k`` not an integer ≥ 1.
    """
    vertices, faces = check_mesh(vertices, faces)
    data = as_array(data, "data", (None, 3), "an (M, 3) array (metres)")
    if not len(data):
        raise BadInput("data: expected at least one probed point, got an empty (0, 3) array")
    residuals = as_array(residuals, "residuals", (len(data),), f"a ({len(data)},) array (metres), one per point")
    for name, value in (("p", p), ("q", q), ("tol", tol)):
        check_number(value, name, 0, above=True)
    check_int(k, "k", 1, None, "an integer number of neighbours")
    w = misfit_weights(vertices, faces, data, residuals, k=k)
    seeds = indicator_seeds(vertices, data, residuals, tol)
    I, it = solve_indicator(vertices, faces, w, seeds, p, q)
    J = float(indicator_energy(vertices, faces, w, I, p, q))
    return TextureIndicator(J, I, w, seeds, it)
