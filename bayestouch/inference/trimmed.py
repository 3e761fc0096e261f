"""Starts for a fit whose contacts are heavily contaminated: find which contacts are displaced before fitting.

When a third or more of the contacts are displaced millimetres off the surface and the rest carry micrometres of
noise, the posterior's dominant mode is needle-thin: it fits the undisplaced contacts to their noise. A tempered SMC
and evolutionary searches on all contacts settle in coarse modes of other shapes that call a different third the
outliers, tens of nats below it (``benchmarks/bench_sbc_missed.py``). Fitted to the undisplaced contacts alone, the
same search lands in the dominant mode's basin. This module finds such a subset without labels:

1. :func:`local_plane_scores`: each contact's distance to the plane through three of its nearest neighbours that
   the neighbours' median distance favours (least median of squares, Rousseeuw 1984): small on the surface that
   most neighbours share, large for a contact displaced off it;
2. :func:`trimmed_starts`: concentration steps of least trimmed squares (Rousseeuw & Van Driessen 2006): fit the
   best-scored fraction, keep the same number of contacts nearest that fit, fit again.

The fits themselves are the caller's (any function of a contact subset returning a shape θ); what comes out are
only starting points, polished and judged on the full posterior.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
from scipy.spatial import cKDTree

from bayestouch.inference import contact as cm

__all__ = ["NEIGHBOURS", "KEEP", "STEPS", "MIN_KEPT", "local_plane_scores", "trimmed_starts"]

#: neighbours of each contact the local plane is chosen among (all C(k, 3) triples are tried)
NEIGHBOURS = 8
#: fraction of the contacts kept in each fit (a set with up to half displaced still has a clean half)
KEEP = 0.5
#: concentration steps (fits) after the screening
STEPS = 3
#: fewest contacts a trimmed fit is made on (the shape has 10 parameters)
MIN_KEPT = 20

_TRIPLES = np.array(list(combinations(range(NEIGHBOURS), 3)))


def local_plane_scores(points, neighbours: int = NEIGHBOURS) -> np.ndarray:
    """Each contact's distance (M,) m to its neighbourhood's least-median plane.

    Parameters
    ----------
    points : (M, 3) float, metres
        Contacts, M > ``neighbours``.
    neighbours : int
        Nearest other contacts k; the plane is the one through three of them whose median distance to all k is
        least (triples that are nearly collinear, as along one stroke, are skipped when others exist).

    Returns
    -------
    (M,) float, metres
        |distance| of each contact to its plane; infinite where no triple spans a plane.
    """
    p = np.asarray(points, float)
    k = int(neighbours)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) <= k:
        raise ValueError(f"points: expected (M, 3) metres with M > {k}, got shape {p.shape}")
    triples = _TRIPLES if k == NEIGHBOURS else np.array(list(combinations(range(k), 3)))
    _, nn = cKDTree(p).query(p, k=k + 1)
    nb = p[nn[:, 1:]]  # (M, k, 3): the contact itself excluded (nn[:, 0], or its exact duplicate: distance 0)
    a, b, c = (nb[:, triples[:, j]] for j in range(3))  # (M, T, 3)
    nrm = np.cross(b - a, c - a)
    size = np.linalg.norm(nrm, axis=-1)
    span = np.max(np.linalg.norm(nb - nb.mean(axis=1, keepdims=True), axis=-1), axis=1)  # (M,)
    ok = size > 1e-6 * span[:, None] ** 2
    unit = nrm / np.where(ok, size, 1.0)[..., None]
    dist = np.abs(np.einsum("mtj,mkj->mtk", unit, nb) - np.einsum("mtj,mtj->mt", unit, a)[..., None])
    med = np.where(ok, np.median(dist, axis=-1), np.inf)
    best = np.argmin(med, axis=1)
    rows = np.arange(len(p))
    u, o = unit[rows, best], a[rows, best]
    score = np.abs(np.einsum("mj,mj->m", p - o, u))
    return np.where(ok[rows, best], score, np.inf)


def trimmed_starts(points, fit, keep: float = KEEP, steps: int = STEPS) -> list[np.ndarray]:
    """Shapes fitted to the least displaced contacts (module docstring), one per concentration step.

    Parameters
    ----------
    points : (M, 3) float, metres
    fit : callable
        ``fit(subset (h, 3) metres, step int) -> θ (≥ 10,)``: a shape in the contact model's parametrisation
        (:func:`bayestouch.inference.contact.shape_of`), fitted to the subset.
    keep : float
        Fraction of the contacts in every fit, in (0, 1].
    steps : int
        Fits made, ≥ 1.

    Returns
    -------
    list of θ
        The fits in order (empty when fewer than :data:`MIN_KEPT` contacts would be kept, or M ≤ :data:`NEIGHBOURS`).
    """
    p = np.asarray(points, float)
    if not 0.0 < keep <= 1.0 or steps < 1:
        raise ValueError(f"keep in (0, 1] and steps >= 1 expected, got keep={keep}, steps={steps}")
    h = int(np.ceil(keep * len(p)))
    if h < MIN_KEPT or len(p) <= NEIGHBOURS:
        return []
    chosen = np.argsort(local_plane_scores(p), kind="stable")[:h]
    out = []
    for step in range(int(steps)):
        theta = np.asarray(fit(p[np.sort(chosen)], step), float)
        out.append(theta)
        d = np.abs(np.asarray(cm.residuals(theta[:10], p)))
        chosen = np.argsort(np.where(np.isfinite(d), d, np.inf), kind="stable")[:h]
    return out
