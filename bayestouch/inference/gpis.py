"""A Gaussian-process implicit surface (GPIS): the field's standard non-parametric shape from contact points, used as
a baseline (``benchmarks/bench_user_sets.py``) and by the planner's ``gpis`` policy (touch where the surface is most
uncertain, :mod:`bayestouch.planning.policies`).

Williams & Fitzgibbon (2007), "Gaussian process implicit surfaces", Gaussian Processes in Practice workshop,
Bletchley Park: an implicit function f : ℝ³ → ℝ is given a Gaussian-process prior with the three-dimensional
thin-plate covariance

    k(r) = 2 r³ − 3 R r² + R³,        r = ‖x − x'‖,

with R the largest distance between two training points, and is conditioned on points *on* the surface
(f = 0) and on points off it (f < 0 inside, f > 0 outside); the surface estimate is the zero level set of the
posterior mean. The covariance has no amplitude parameter: with f in metres, k is read in m² (an implicit
amplitude of 1 m⁻¹), and the posterior mean does not depend on that amplitude when there is no noise term.

How the baseline is set up here (:func:`fit_gpis`):

* **Training points.** Each contact p_i at f = 0; for each contact one point ``p_i − d n_i`` at f = −d (inside)
  and one ``p_i + d n_i`` at f = +d (outside), so f approximates the signed distance near the data. Default
  d = :data:`OFFSET_M` = 4 mm: small enough that ``p − d n`` lies inside any solid of half-thickness ≥ 6 mm
  (the benchmark's objects have semi-axes ≥ 12 mm) even when n is 40° off the true normal, large enough (13×
  the 0.3 mm contact noise) that the offsets are not lost in it. And, as Williams & Fitzgibbon's exterior
  constraints, a cage of points on the faces of the grid box (:data:`EXTERIOR_PER_EDGE` × as many per face,
  152 points by default) at f = their distance to the nearest contact, an upper bound of their distance to the
  surface. Without the cage (``exterior=0``) the zero-mean GP is "on the surface" (f = 0) a priori wherever the
  data say nothing, and on sparse strokes its negative region escapes through the gaps between the strokes to
  whatever box closes it: on sets 0–11 of :mod:`benchmarks.bench_user_sets`, at the default settings, it reached
  the box in 10 of 12 and the median volume error |V̂/V − 1| was 6.8 (it grows with the box; the true normals
  do not help); with the cage it reached the box in none and the median volume error was 0.21.
* **Normals** (:func:`contact_normals`): the direction from the centroid of the contacts to the contact,
  with its component along the local tangent t_i removed, t_i being the principal direction of the contact's
  :data:`NEIGHBOURS` nearest contacts. Not a local plane fit (PCA normal): on stroke data a contact's
  nearest neighbours lie on its own stroke, a curve, whose points span the stroke's *plane*, and the PCA normal
  of that plane is tangent to the surface. The stroke's tangent, however, is well defined, and the true normal
  is perpendicular to it; the centroid fixes the sign (outward for a convex solid). Where the centroid
  direction is almost along t_i (the projection keeps less than :data:`MIN_NORMAL_COMPONENT` of it) the
  centroid direction is used as it is.
* **Noise.** A nugget (``noise_m``)² on the diagonal, (0.3 mm)² by default, the contacts' noise; against
  k(0) = R³ ≈ 10⁻⁴–10⁻³ m³ it keeps the solve well conditioned and the mean practically interpolating.
* **Grid.** The posterior mean on a grid over a cube centred on the training points' bounding box, of side
  (1 + 2 ``margin``) × its longest side (default ``margin`` ½: twice the data's extent, so that an object seen
  from one side, whose data are thin along the approach, still fits), with ``resolution`` (default 64) nodes
  along each side. R, the largest distance between two training points, is then the cube's diagonal (the cage's
  corners), so every query lies within R of every training point, where k decreases monotonically (Williams &
  Fitzgibbon's R is the largest distance in the domain). The outer layer of nodes is set to "outside" (+ one
  cell) so that the zero level set is closed by the box wherever the GP's solid reaches it;
  :attr:`GPISFit.touches_box` says when that happened (the estimate is then the solid clipped by the box).
* **Surface and volume.** ``skimage.measure.marching_cubes`` at level 0, triangles oriented outward; the
  volume is the mesh's (``trimesh``), the sum over all closed components (spurious blobs included: they are
  part of the estimate). scikit-image is needed for :func:`fit_gpis` only (imported there).
* **Mean and variance anywhere** (:func:`condition`, :func:`predict`): the same training set and cage, the
  LU factors of K kept; the latent field's posterior variance is R³ − k(q, X) K⁻¹ k(X, q) (m², with the
  covariance's implicit amplitude of 1 m⁻¹ as above).

All lengths are metres.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "GPIS",
    "condition",
    "predict",
    "predict_mean",
    "thin_plate_covariance",
    "contact_normals",
    "training_set",
    "gp_mean",
    "fit_gpis",
    "GPISFit",
    "OFFSET_M",
    "RESOLUTION",
    "MARGIN",
    "NEIGHBOURS",
    "NOISE_M",
    "EXTERIOR_PER_EDGE",
    "exterior_cage",
]

#: distance d of the inside (f = −d) and outside (f = +d) training points from each contact, metres
OFFSET_M = 4e-3
#: grid nodes along each side of the grid cube
RESOLUTION = 64
#: the grid cube's side is (1 + 2 MARGIN) × the longest side of the training points' bounding box
MARGIN = 0.5
#: exterior training points per edge of each face of the grid cube (0: none)
EXTERIOR_PER_EDGE = 6
#: contacts (the point itself included) whose principal direction is the local tangent in :func:`contact_normals`
NEIGHBOURS = 6
#: nugget of the GP, metres (the contacts' noise sd)
NOISE_M = 3e-4
#: below this norm the tangent-free centroid direction is discarded for the centroid direction itself
MIN_NORMAL_COMPONENT = 0.3
#: query points per block in :func:`gp_mean` (memory: block × training points × 8 bytes)
_BLOCK = 16384


class GPISFit(NamedTuple):
    """A GPIS estimate.

    Attributes
    ----------
    vertices : (V, 3) float, metres
        The zero level set of the posterior mean, marching cubes.
    faces : (F, 3) int
        Outward-oriented triangles.
    volume : float, m³
        Enclosed volume of the mesh (nan when the mean has no zero crossing on the grid).
    normals : (M, 3) float
        The unit normals used for the off-surface training points.
    offset : float, metres
        d.
    R : float, metres
        The thin-plate covariance's R: the largest distance between two training points (exterior cage included).
    spacing : float, metres
        Grid cell size.
    touches_box : bool
        Whether the estimated solid reaches the grid box (closed there by the box).
    """

    vertices: np.ndarray
    faces: np.ndarray
    volume: float
    normals: np.ndarray
    offset: float
    R: float
    spacing: float
    touches_box: bool


def thin_plate_covariance(r, R: float):
    """Thin-plate covariance k(r) = 2 r³ − 3 R r² + R³ (Williams & Fitzgibbon 2007), m³ read as m².

    Parameters
    ----------
    r : array_like, metres
        Distances ≥ 0.
    R : float, metres
        Its scale: k(0) = R³, k(R) = k'(R) = 0; for r > R it is (r − R)²(2r + R) > 0.

    Returns
    -------
    ndarray, same shape as ``r``
    """
    r = np.asarray(r, dtype=np.float64)
    return 2.0 * r**3 - 3.0 * R * r**2 + R**3


def _pairwise(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (A, B) between points a (A, 3) and b (B, 3)."""
    d2 = np.sum(a * a, axis=1)[:, None] + np.sum(b * b, axis=1)[None, :] - 2.0 * a @ b.T
    return np.sqrt(np.maximum(d2, 0.0))


def contact_normals(points, neighbours: int = NEIGHBOURS) -> np.ndarray:
    """Outward unit normals (M, 3) of contacts on a convex-ish solid: centroid direction minus its tangent part.

    For each contact p_i: u_i = (p_i − p̄)/‖p_i − p̄‖ with p̄ the centroid of all contacts; t_i the principal
    eigenvector of the covariance of its ``neighbours`` nearest contacts (itself included), which along a stroke
    is the stroke's tangent; n_i = u_i − (u_i·t_i) t_i, normalised, or u_i itself where ‖u_i − (u_i·t_i) t_i‖ <
    :data:`MIN_NORMAL_COMPONENT`.

    Parameters
    ----------
    points : (M, 3) float, metres
    neighbours : int
        Contacts in each local neighbourhood, ≥ 2 (fewer than M).

    Returns
    -------
    (M, 3) float, unit vectors
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    u = p - p.mean(axis=0)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    k = int(min(max(neighbours, 2), len(p)))
    _, idx = cKDTree(p).query(p, k=k)
    nb = p[idx] - p[idx].mean(axis=1, keepdims=True)  # (M, k, 3)
    _, vec = np.linalg.eigh(np.einsum("mki,mkj->mij", nb, nb))
    t = vec[:, :, -1]  # largest eigenvalue's eigenvector
    n = u - np.sum(u * t, axis=1, keepdims=True) * t
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm >= MIN_NORMAL_COMPONENT, n / np.maximum(norm, 1e-300), u)


def exterior_cage(lower, upper, per_edge: int = EXTERIOR_PER_EDGE) -> np.ndarray:
    """Points (P, 3) m on the faces of the box [lower, upper]: a ``per_edge`` × ``per_edge`` grid on each face,
    shared edge and corner points once (P = 6 k² − 12 k + 8 for k = ``per_edge`` ≥ 2)."""
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    t = np.linspace(0.0, 1.0, int(per_edge))
    g = np.stack(np.meshgrid(t, t, t, indexing="ij"), axis=-1).reshape(-1, 3)
    on_face = np.any((g == 0.0) | (g == 1.0), axis=1)
    return lower + g[on_face] * (upper - lower)


def training_set(points, normals, offset: float = OFFSET_M) -> tuple[np.ndarray, np.ndarray]:
    """Training inputs and targets of the GPIS: contacts at 0, ``p − d n`` at −d and ``p + d n`` at +d.

    Parameters
    ----------
    points : (M, 3) float, metres
    normals : (M, 3) float, unit outward normals
    offset : float, metres
        d.

    Returns
    -------
    X : (3M, 3) float, metres
    y : (3M,) float, metres
    """
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    m = len(p)
    X = np.concatenate([p, p - offset * n, p + offset * n])
    y = np.concatenate([np.zeros(m), np.full(m, -offset), np.full(m, offset)])
    return X, y


def gp_mean(X, y, query, R: float | None = None, noise_m: float = 0.0) -> np.ndarray:
    """Posterior mean of the thin-plate GP at ``query``: k(Q, X) (K + σ² I)⁻¹ y, zero prior mean.

    Parameters
    ----------
    X : (N, 3) float, metres
        Training inputs.
    y : (N,) float, metres
        Training targets.
    query : (Q, 3) float, metres
    R : float, optional, metres
        The covariance's scale (default: the largest distance between two training inputs).
    noise_m : float, metres
        Nugget σ; 0 interpolates.

    Returns
    -------
    (Q,) float, metres
    """
    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    D = _pairwise(X, X)
    R = float(D.max()) if R is None else float(R)
    K = thin_plate_covariance(D, R) + noise_m**2 * np.eye(len(X))
    return _mean_at(X, np.linalg.solve(K, y), R, query)


def _mean_at(X: np.ndarray, alpha: np.ndarray, R: float, query) -> np.ndarray:
    """k(Q, X) α (Q,) at ``query (Q, 3)`` metres, in blocks of :data:`_BLOCK` queries."""
    q = np.asarray(query, dtype=np.float64).reshape(-1, 3)
    # k(Q, X) α = 2 Σ_j α_j r_j³ − 3R Σ_j α_j r_j² + R³ Σ_j α_j, and Σ_j α_j r_j² = |q|² Σα + Σ α|x|² − 2 q·Σ α x
    # is closed-form: only the r³ term needs the distances (two element-wise passes per block)
    sa, sax2, sax = alpha.sum(), alpha @ np.sum(X * X, axis=1), alpha @ X
    x2 = np.sum(X * X, axis=1)
    out = np.empty(len(q))
    for i in range(0, len(q), _BLOCK):
        b = q[i : i + _BLOCK]
        b2 = np.sum(b * b, axis=1)
        d2 = b @ (-2.0 * X.T)
        d2 += b2[:, None]
        d2 += x2[None, :]
        np.maximum(d2, 0.0, out=d2)
        r3 = np.sqrt(d2)
        r3 *= d2
        quad = b2 * sa + sax2 - 2.0 * b @ sax
        out[i : i + _BLOCK] = 2.0 * (r3 @ alpha) - 3.0 * R * quad + R**3 * sa
    return out


class GPIS(NamedTuple):
    """A GPIS conditioned on contacts (:func:`condition`).

    Attributes
    ----------
    X : (N, 3) float, metres
        Training inputs (contacts, their inside and outside offsets, the exterior cage).
    y : (N,) float, metres
        Targets.
    R : float, metres
        The covariance's scale.
    lu : tuple
        LU factorisation of K + σ² I (``scipy.linalg.lu_factor``; K is positive definite in exact arithmetic but
        too ill-conditioned for a Cholesky factor at small nuggets).
    alpha : (N,) float
        (K + σ² I)⁻¹ y.
    lower, upper : (3,) float, metres
        The box the cage lies on.
    normals : (M, 3) float
        The unit normals of the off-surface training points.
    """

    X: np.ndarray
    y: np.ndarray
    R: float
    lu: tuple
    alpha: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    normals: np.ndarray


def condition(
    points,
    *,
    offset: float = OFFSET_M,
    margin: float = MARGIN,
    neighbours: int = NEIGHBOURS,
    noise_m: float = NOISE_M,
    exterior: int = EXTERIOR_PER_EDGE,
    normals=None,
) -> GPIS:
    """Condition the thin-plate GP on contact points (M ≥ 2, metres): the training set of :func:`fit_gpis`
    (contacts, normal offsets, the cage on a box of side (1 + 2 ``margin``) × the data's extent) and its LU
    factorisation."""
    from scipy.linalg import lu_factor, lu_solve
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) < 2:
        raise ValueError(f"GPIS: need at least 2 contact points, got {len(p)}")
    if exterior == 1 or exterior < 0:
        raise ValueError(f"GPIS: exterior must be 0 or at least 2 points per edge, got {exterior}")
    nrm = contact_normals(p, neighbours) if normals is None else np.asarray(normals, dtype=np.float64)
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    X, y = training_set(p, nrm, offset)
    lo, hi = X.min(axis=0), X.max(axis=0)
    side = (1.0 + 2.0 * margin) * float((hi - lo).max())
    lo = 0.5 * (lo + hi) - 0.5 * side
    hi = lo + side
    if exterior:
        cage = exterior_cage(lo, hi, exterior)
        X = np.concatenate([X, cage])
        y = np.concatenate([y, cKDTree(p).query(cage)[0]])
    D = _pairwise(X, X)
    R = float(D.max())
    lu = lu_factor(thin_plate_covariance(D, R) + noise_m**2 * np.eye(len(X)))
    return GPIS(X, y, R, lu, lu_solve(lu, y), lo, hi, nrm)


def predict_mean(gp: GPIS, query) -> np.ndarray:
    """Posterior mean (Q,) m of the latent field at ``query (Q, 3)`` metres (as :func:`gp_mean`, with ``gp``'s
    weights: no new solve)."""
    return _mean_at(gp.X, gp.alpha, gp.R, query)


def predict(gp: GPIS, query) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean (Q,) m and variance (Q,) m² of the latent field at ``query (Q, 3)`` metres."""
    from scipy.linalg import lu_solve

    q = np.asarray(query, dtype=np.float64).reshape(-1, 3)
    mean, var = np.empty(len(q)), np.empty(len(q))
    for i in range(0, len(q), _BLOCK // 4):
        b = q[i : i + _BLOCK // 4]
        k = thin_plate_covariance(_pairwise(b, gp.X), gp.R)  # (B, N)
        mean[i : i + len(b)] = k @ gp.alpha
        v = lu_solve(gp.lu, k.T)  # (N, B)
        var[i : i + len(b)] = np.maximum(gp.R**3 - np.sum(k.T * v, axis=0), 0.0)
    return mean, var


def fit_gpis(
    points,
    *,
    offset: float = OFFSET_M,
    resolution: int = RESOLUTION,
    margin: float = MARGIN,
    neighbours: int = NEIGHBOURS,
    noise_m: float = NOISE_M,
    exterior: int = EXTERIOR_PER_EDGE,
    normals=None,
) -> GPISFit:
    """GPIS estimate of a solid from contact points: training set, GP mean on a grid, marching cubes, volume.

    See the module docstring for the choices (normals, d, exterior cage, nugget, grid, closing by the box).

    Parameters
    ----------
    points : (M, 3) float, metres
        Contact points, M ≥ 2.
    offset : float, metres
        d of the off-surface training points.
    resolution : int
        Grid nodes along each side of the grid cube (≥ 8).
    margin : float
        The grid cube's side is (1 + 2 ``margin``) × the longest side of the training points' bounding box.
    neighbours : int
        Neighbourhood of the tangent estimate (:func:`contact_normals`).
    noise_m : float, metres
        Nugget σ of the GP.
    exterior : int
        Exterior points per edge of each face of the grid cube (:func:`exterior_cage`); 0: none (normal offsets
        only).
    normals : (M, 3) float, optional
        Outward normals to use instead of :func:`contact_normals` (e.g. measured ones).

    Returns
    -------
    GPISFit
        With an empty mesh and a nan volume when the mean has no zero crossing on the grid.

    Raises
    ------
    ValueError
        On fewer than 2 points, a resolution below 8 or ``exterior`` 1.
    """
    import trimesh
    from skimage.measure import marching_cubes

    if resolution < 8:
        raise ValueError(f"fit_gpis: resolution must be at least 8, got {resolution}")
    gp = condition(
        points, offset=offset, margin=margin, neighbours=neighbours, noise_m=noise_m, exterior=exterior, normals=normals
    )
    nrm, R, lo, hi = gp.normals, gp.R, gp.lower, gp.upper
    side = float((hi - lo)[0])
    h = side / (resolution - 1)
    axis = lo[:, None] + h * np.arange(resolution)[None, :]
    grid = np.stack(np.meshgrid(*axis, indexing="ij"), axis=-1).reshape(-1, 3)
    shape = (resolution,) * 3
    f = predict_mean(gp, grid).reshape(shape)

    inner = f[1:-1, 1:-1, 1:-1]
    border = np.ones(shape, bool)
    border[2:-2, 2:-2, 2:-2] = False
    touches = bool((f[border] < 0).any())
    empty = GPISFit(np.empty((0, 3)), np.empty((0, 3), int), float("nan"), nrm, offset, R, h, touches)
    if not ((inner < 0).any() and (inner > 0).any()):
        return empty
    f[0], f[-1], f[:, 0], f[:, -1], f[:, :, 0], f[:, :, -1] = (h,) * 6  # outside at the box
    verts, faces, _, _ = marching_cubes(f, level=0.0, spacing=(h, h, h))
    verts = verts + lo
    vol = float(trimesh.Trimesh(vertices=verts, faces=faces, process=False).volume)
    if vol < 0:  # orient outward
        faces = faces[:, ::-1]
        vol = -vol
    return GPISFit(verts, np.ascontiguousarray(faces), vol, nrm, offset, R, h, touches)
