"""Does the fitted shape leave only noise? A misfit check of a contact-level posterior from its residuals' spatial
structure.

Under the contact model every contact's signed distance to the true surface is independent noise (or an
independent outlier), so the residuals of two neighbouring contacts are uncorrelated. A shape that does not fit
(a mode that is not the data's: a wrong exponent or orientation the sampler settled in; an object outside the
n-ellipsoid family) leaves a smooth error surface, and neighbouring contacts share it: their residuals correlate.
:func:`residual_structure` measures that as the rank (Spearman) correlation ρ between each contact's residual and
its nearest other contact's (neighbours on the surface: :func:`surface_feet`), at posterior draws, against its
permutation null (residuals shuffled over the contacts), and flags a misfit when ρ is both large and many null sds
above 0. Ranks keep displaced contacts from dominating. Thresholds and what they were measured on:
``docs/contact_model.md`` (Misfit).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import rankdata

from bayestouch.backend import jax, pad_pow2
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import contact as cm

__all__ = [
    "MISFIT_RHO",
    "MISFIT_Z",
    "MISFIT_DRAWS",
    "PERMUTATIONS",
    "MIN_PAIRS",
    "neighbour_pairs",
    "surface_feet",
    "rank_correlation",
    "residual_structure",
]

#: a misfit is flagged when the median neighbour correlation of the residuals exceeds MISFIT_RHO and lies more than
#: MISFIT_Z permutation sds above 0 (one-sided p ≈ 0.001 under the null). Measured (``docs/contact_model.md``):
#: correct posteriors 0.02–0.03; a mode 213 nats below the truth's 0.63 (z 5.7); n 3 taken for 2 0.70–0.75
MISFIT_RHO = 0.3
MISFIT_Z = 3.0
#: posterior draws the residuals are computed at, and the permutations of the null
MISFIT_DRAWS = 32
PERMUTATIONS = 200
#: fewer neighbour pairs than this: no verdict (the null's sd is too wide to tell)
MIN_PAIRS = 12


def neighbour_pairs(points) -> np.ndarray:
    """Unordered index pairs (P, 2) joining each of ``points (M, 3)`` m to its nearest other point (each pair once;
    exact duplicates of a point count as its neighbours)."""
    p = np.asarray(points, float)
    if len(p) < 2:
        return np.zeros((0, 2), int)
    _, nn = cKDTree(p).query(p, k=2)
    i = np.arange(len(p))
    j = np.where(nn[:, 1] == i, nn[:, 0], nn[:, 1])
    return np.unique(np.sort(np.stack([i, j], axis=1), axis=1), axis=0)


def surface_feet(theta, points) -> np.ndarray:
    """The points (M, 3) m moved along the surface normal of θ (≥ 10,) by their first-order distance: where on the
    surface each contact lies. Neighbours are taken among these, not among the contacts themselves: a contact
    displaced millimetres off the surface is otherwise nearest to other displaced ones, and their shared large
    residuals would read as structure."""
    p = np.asarray(points, float)
    d, nrm = _residuals_and_normals(theta, p)
    return p - d[:, None] * nrm


@jax.jit
def _residuals_normals_jit(theta, pts):
    return cm.residuals(theta, pts), ne.normals(cm.shape_of(theta), pts)


def _residuals_and_normals(theta, points) -> tuple[np.ndarray, np.ndarray]:
    """First-order residuals (M,) m of ``points (M, 3)`` m under θ (≥ 10,) and the unit normals (M, 3) there: one
    compiled program per power-of-two point count (:func:`~bayestouch.backend.pad_pow2`), not one per data set and
    none of the dozens of single operations an eager call compiles for each new length."""
    m = len(points)
    d, nrm = _residuals_normals_jit(
        jax.device_put(np.asarray(theta, float)[:10]), jax.device_put(pad_pow2(np.asarray(points, float)))
    )
    return np.asarray(d)[:m], np.asarray(nrm)[:m]


def rank_correlation(values, pairs) -> float:
    """Pearson correlation of the ranks of ``values (M,)`` between the two members of ``pairs (P, 2)``."""
    r = rankdata(np.asarray(values, float))
    a, b = r[pairs[:, 0]], r[pairs[:, 1]]
    if np.std(a) == 0 or np.std(b) == 0:
        return 0.0
    return float(np.corrcoef(a, b)[0, 1])


def residual_structure(points, thetas, seed: int = 0) -> dict:
    """The misfit check of contacts ``points (M, 3)`` m under posterior draws ``thetas (N, ≥ 10)`` (the sampled
    parametrisation of :func:`bayestouch.inference.contact.shape_of`: centre m, log semi-axes, Euler angles rad,
    log n).

    Returns
    -------
    dict
        ``rho`` (median over :data:`MISFIT_DRAWS` draws of the neighbour rank correlation of the residuals), ``z``
        (ρ over the sd of its permutation null), ``pairs`` (P), ``misfit`` (bool: ρ > :data:`MISFIT_RHO` and
        z > :data:`MISFIT_Z`); ``rho``/``z`` None and ``misfit`` False with fewer than :data:`MIN_PAIRS` pairs.
    """
    p = np.asarray(points, float)
    th = np.asarray(thetas, float)
    rng = np.random.default_rng([seed, 0x3F17])
    pick = rng.choice(len(th), min(MISFIT_DRAWS, len(th)), replace=False)
    pairs = neighbour_pairs(surface_feet(th[pick[0]], p))
    if len(pairs) < MIN_PAIRS:
        return {"rho": None, "z": None, "pairs": int(len(pairs)), "misfit": False}
    rhos, last = [], None
    for t in th[pick]:
        last = _residuals_and_normals(t, p)[0]
        rhos.append(rank_correlation(last, pairs))
    rho = float(np.median(rhos))
    null = [rank_correlation(rng.permutation(last), pairs) for _ in range(PERMUTATIONS)]
    sd = float(np.std(null))
    z = rho / sd if sd > 0 else 0.0
    return {"rho": rho, "z": float(z), "pairs": int(len(pairs)), "misfit": bool(rho > MISFIT_RHO and z > MISFIT_Z)}
