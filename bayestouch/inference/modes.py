"""Separated modes of a shape posterior: which distinct shapes the data leave possible, and their weights.

A posterior over an n-ellipsoid from sparse contacts can hold several shapes the data cannot tell apart (an unseen
axis short or long, a rounded or a boxy exponent). Its mean then describes none of them, and the summary must say
so. The draws' canonical log semi-axes (largest first) and log n are clustered (Ward's hierarchical clustering in
coordinates standardised by their overall sd, on at most :data:`MAX_DRAWS` draws); the largest k ≤
:data:`MAX_MODES` is kept whose clusters all hold at least :data:`MIN_WEIGHT` of the draws and are pairwise
separated by more than :data:`SEPARATION` pooled within-cluster sds along the line joining their means (two equal
Gaussians show two peaks beyond 2 sds; 4 keeps a skewed or curved single mode from being split). Aliases of one
surface (axis permutations, rotation symmetries) are one mode: the features are canonical.
"""

from __future__ import annotations

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage

__all__ = ["find_modes", "MAX_MODES", "MIN_WEIGHT", "SEPARATION", "MAX_DRAWS"]

MAX_MODES = 4
MIN_WEIGHT = 0.03
SEPARATION = 4.0
MAX_DRAWS = 2000


def _separation(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between the means of clusters ``a`` and ``b`` (n, F) in units of their pooled within-cluster sd
    along the line joining the means."""
    delta = a.mean(axis=0) - b.mean(axis=0)
    norm = float(np.linalg.norm(delta))
    if norm == 0.0:
        return 0.0
    u = delta / norm
    pa, pb = a @ u, b @ u
    pooled = ((len(pa) - 1) * pa.var(ddof=1) + (len(pb) - 1) * pb.var(ddof=1)) / max(len(pa) + len(pb) - 2, 1)
    return norm / np.sqrt(max(pooled, 1e-300))


def find_modes(features, rng: np.random.Generator) -> np.ndarray:
    """Labels (N,) of the separated modes of draws ``features (N, F)`` (module docstring), 0 for the heaviest.

    Parameters
    ----------
    features : (N, F) float
        e.g. canonical log semi-axes and log n of each draw.
    rng : np.random.Generator
        Picks the draws clustered when there are more than :data:`MAX_DRAWS`; the others take the label of the
        nearest cluster mean (standardised coordinates).

    Returns
    -------
    (N,) int
        Mode of each draw, modes numbered by decreasing weight; all 0 for a unimodal posterior.
    """
    x = np.asarray(features, float)
    n = len(x)
    if n < 20:
        return np.zeros(n, int)
    z = (x - x.mean(axis=0)) / (x.std(axis=0) + 1e-300)
    pick = rng.choice(n, MAX_DRAWS, replace=False) if n > MAX_DRAWS else np.arange(n)
    tree = linkage(z[pick], method="ward")
    best = np.zeros(len(pick), int)
    for k in range(2, MAX_MODES + 1):
        lab = fcluster(tree, k, criterion="maxclust") - 1
        ks = np.unique(lab)
        if len(ks) < k or min(np.mean(lab == j) for j in ks) < MIN_WEIGHT:
            continue
        groups = [z[pick][lab == j] for j in ks]
        if all(_separation(groups[i], groups[j]) > SEPARATION for i in range(k) for j in range(i + 1, k)):
            best = lab
    if n > len(pick):
        centres = np.array([z[pick][best == j].mean(axis=0) for j in range(best.max() + 1)])
        full = np.argmin(((z[:, None, :] - centres[None]) ** 2).sum(axis=2), axis=1)
    else:
        full = best
    order = np.argsort(-np.bincount(full))
    return np.argsort(order)[full]
