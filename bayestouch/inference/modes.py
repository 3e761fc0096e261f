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

__all__ = [
    "find_modes",
    "gaussian_mixture",
    "MAX_MODES",
    "MIN_WEIGHT",
    "SEPARATION",
    "MAX_DRAWS",
    "MAX_COMPONENTS",
]

MAX_MODES = 4
MIN_WEIGHT = 0.03
SEPARATION = 4.0
MAX_DRAWS = 2000
#: most components :func:`gaussian_mixture` tries
MAX_COMPONENTS = 6
#: EM of :func:`gaussian_mixture`: ridge on each standardised covariance, iterations, tolerance on the mean
#: log-likelihood per draw, random starts per component count
_EM_RIDGE = 1e-6
_EM_ITERATIONS = 100
_EM_TOL = 1e-4
_EM_STARTS = 2


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


def _log_gauss(z, means, covs):
    """log N(z_i | means_k, covs_k) (N, K) of rows ``z (N, D)``, and whether every covariance is positive definite
    (all K components at once: batched Cholesky factors and triangular inverses)."""
    n, d = z.shape
    try:
        chol = np.linalg.cholesky(covs)  # (K, D, D)
    except np.linalg.LinAlgError:
        return np.empty((n, len(means))), False
    y = (z[None] - means[:, None]) @ np.swapaxes(np.linalg.inv(chol), 1, 2)  # (K, N, D): L⁻¹ (z − μ) per row
    half_log_det = np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)
    return (-0.5 * np.sum(y * y, axis=2) - half_log_det[:, None] - 0.5 * d * np.log(2 * np.pi)).T, True


def _em(z, labels, k):
    """EM from the hard assignment ``labels (N,)`` in 0 … k − 1: (log-likelihood, weights, means, covs), or None
    when a component collapses (fewer than D + 1 draws' worth of weight)."""
    n, d = z.shape
    resp = np.eye(k)[labels]
    ll_old = -np.inf
    for _ in range(_EM_ITERATIONS):
        nk = resp.sum(axis=0)
        if nk.min() < d + 1:
            return None
        means = (resp.T @ z) / nk[:, None]
        zc = z[None] - means[:, None]  # (K, N, D)
        covs = (np.swapaxes(zc * resp.T[:, :, None], 1, 2) @ zc) / nk[:, None, None]
        covs += _EM_RIDGE * np.eye(d)[None]
        weights = nk / n
        lg, ok = _log_gauss(z, means, covs)
        if not ok:
            return None
        joint = lg + np.log(weights)[None]
        norm = np.logaddexp.reduce(joint, axis=1)
        ll = float(norm.sum())
        resp = np.exp(joint - norm[:, None])
        if ll - ll_old < _EM_TOL * n:
            break
        ll_old = ll
    return ll, weights, means, covs


def _kmeanspp(z, k, rng):
    """Hard assignment (N,) to ``k`` centres chosen by k-means++ seeding (Arthur & Vassilvitskii 2007)."""
    centres = [z[rng.integers(len(z))]]
    for _ in range(1, k):
        d2 = np.min(((z[:, None, :] - np.array(centres)[None]) ** 2).sum(axis=2), axis=1)
        centres.append(z[rng.choice(len(z), p=d2 / d2.sum())])
    return np.argmin(((z[:, None, :] - np.array(centres)[None]) ** 2).sum(axis=2), axis=1)


def gaussian_mixture(x, rng: np.random.Generator, max_components: int = MAX_COMPONENTS):
    """A Gaussian mixture fitted to draws ``x (N, D)`` by EM (Dempster, Laird & Rubin 1977), the number of
    components K ≤ ``max_components`` chosen by the Bayesian information criterion (Schwarz 1978).

    The mixture describes a posterior's shape beyond its separated modes: a skewed or curved mode takes several
    overlapping components. EM runs in coordinates standardised by each column's sd (a ridge of :data:`_EM_RIDGE`
    keeps every covariance positive definite), from :data:`_EM_STARTS` k-means++ starts per K; a K whose
    components collapse is skipped.

    Parameters
    ----------
    x : (N, D) float
        Draws, N > D + 1.
    rng : np.random.Generator
        Seeds the starts.
    max_components : int
        Largest K tried (at most N // (D + 1)).

    Returns
    -------
    weights : (K,) float
        Component probabilities, summing to 1, heaviest first.
    means : (K, D) float
    covs : (K, D, D) float
        In the units of ``x``.
    """
    x = np.asarray(x, float)
    n, d = x.shape
    if n <= d + 1:
        raise ValueError(f"gaussian_mixture: x needs more than D + 1 = {d + 1} draws, got {n}")
    loc, scale = x.mean(axis=0), x.std(axis=0) + 1e-300
    z = (x - loc) / scale
    best, best_bic = None, np.inf
    for k in range(1, max(1, min(int(max_components), n // (d + 1))) + 1):
        starts = 1 if k == 1 else _EM_STARTS
        fits = [_em(z, np.zeros(n, int) if k == 1 else _kmeanspp(z, k, rng), k) for _ in range(starts)]
        fits = [f for f in fits if f is not None]
        if not fits:
            continue
        ll, w, mu, cov = max(fits, key=lambda f: f[0])
        bic = -2.0 * ll + (k - 1 + k * d + k * d * (d + 1) / 2) * np.log(n)
        if bic < best_bic:
            best, best_bic = (w, mu, cov), bic
    w, mu, cov = best
    order = np.argsort(-w)
    return w[order], loc + mu[order] * scale, cov[order] * np.outer(scale, scale)[None]
