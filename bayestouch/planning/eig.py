"""Expected information gain (EIG) of whole strokes: from posterior draws (shape) and over discrete hypotheses.

Gaussian approximation (the planner's estimator). With the signal y = f(θ, stroke) + ε, ε ~ N(0, σ² I) of the
T readings of a stroke, and the predicted signal f(θ, ·) over the posterior approximated as Gaussian with the
draws' covariance C (T × T), the mutual information between θ and y is

    EIG = ½ log det(I + C / σ²)

(the linear-Gaussian closed form; Lindley 1956, Ann. Math. Stat. 27:986; Chaloner & Verdinelli 1995, Stat. Sci.
10:273, eq. 3 with a linearised model). It is taken over the *whole* stroke's signal: readings of one stroke are
strongly correlated (the same few shape parameters move them all), and a sum of per-reading gains
½ Σ_t log(1 + C_tt / σ²) (:func:`eig_per_point`, kept as a negative control) counts that shared information once
per reading and prefers long, redundant strokes.

Touch, miss and collision are events (:func:`eig_events`). A ray that misses reads t_max and one that starts inside
reads 0: where the draws disagree on which of these happens, the predicted reading is not a Gaussian but a mixture of
an atom and a spread, and the Gaussian formula, seeing a variance of order p(1 − p) (t_max − t)², credits a reading
that only tells touch from no touch with ½ log(1 + p(1 − p) Δt²/σ²) nats (about 2.8 nats for Δt = 10 mm, σ =
0.3 mm), where the most such an outcome can tell is its entropy, log 2 = 0.69 nats. Given θ the events are
deterministic (a miss is detected, not measured with noise), so with e the stroke's pattern of events,

    I(θ; y) = I(θ; e) + I(θ; t | e) = H(e) + Σ_e p(e) I(θ; t | e),

the first term the entropy of the draws' event patterns (plug-in, exact for the draws), the second the Gaussian EIG
of the draws that share each pattern (their constant readings carry nothing), weighted by the pattern's share. A
stroke on which all draws agree gets exactly :func:`eig_gaussian`'s value.

Contrastive re-check (:func:`eig_pce`). When the draws look multimodal (:func:`looks_multimodal`, on the draws'
volumes), the Gaussian approximation can misjudge a stroke that separates modes; the best few are re-scored
with the prior contrastive estimator (PCE; Foster et al. 2020, AISTATS, eq. 5), a lower bound on the EIG that
uses the other draws as contrasts: PCE = mean_i [log p(y_i | θ_i) − log (1/N) Σ_l p(y_i | θ_l)], y_i drawn
from θ_i. It is bounded above by log N (6.9 nats for 1000 draws), so it ranks strokes only below that.

Discrete hypotheses (:func:`eig_pairwise`, texture identification): the pairwise-distance lower bound of the
mutual information between a discrete k and a Gaussian observation (Kolchinsky & Tracey 2017, Entropy 19:361).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import logsumexp
from scipy.stats import kurtosis, skew

from bayestouch.backend import jax, jnp
from bayestouch.geometry.mesh import as_rng

__all__ = [
    "eig_gaussian",
    "eig_events",
    "reading_events",
    "eig_per_point",
    "eig_pce",
    "looks_multimodal",
    "EIGDecision",
    "decide",
    "bimodality_coefficient",
    "eig_pairwise",
]


@jax.jit
def _eig_gaussian(signals, noise_sd):
    n = signals.shape[0]
    dev = signals - jnp.mean(signals, axis=0)  # (N, C, T)
    cov = jnp.einsum("nct,ncs->cts", dev, dev) / (n - 1)  # (C, T, T)
    eye = jnp.eye(signals.shape[2])
    L = jnp.linalg.cholesky(eye + cov / noise_sd**2)  # symmetric positive definite: always succeeds
    return jnp.sum(jnp.log(jnp.diagonal(L, axis1=1, axis2=2)), axis=1)  # ½ log det = Σ log diag(L)


def eig_gaussian(signals, noise_sd: float) -> np.ndarray:
    """Gaussian EIG ½ log det(I + Cov/σ²) of each candidate's whole signal, nats.

    Parameters
    ----------
    signals : (N, C, T) float, metres
        Predicted signals of N posterior draws for C candidates of T readings.
    noise_sd : float, metres
        Reading noise σ (i.i.d. Gaussian).

    Returns
    -------
    (C,) float, nats
    """
    s = np.asarray(signals, dtype=np.float64)
    if s.ndim == 2:
        s = s[:, None]
    return np.asarray(_eig_gaussian(jnp.asarray(s), jnp.float64(noise_sd)))


#: relative tolerance of a predicted reading at t_max (a miss; the planner predicts in float32)
MISS_RTOL = 1e-5


def reading_events(signals, t_max: float) -> np.ndarray:
    """The event of each predicted reading: 0 the ray starts inside (reads 0), 1 it touches, 2 it misses (reads
    t_max, to :data:`MISS_RTOL`).

    Parameters
    ----------
    signals : (..., T) float, metres
    t_max : float, metres

    Returns
    -------
    (..., T) int8
    """
    s = np.asarray(signals, dtype=np.float64)
    ev = np.ones(s.shape, dtype=np.int8)
    ev[s <= 0.0] = 0
    ev[s >= t_max * (1.0 - MISS_RTOL)] = 2
    return ev


def eig_events(signals, noise_sd: float, t_max: float) -> np.ndarray:
    """EIG of each candidate with touch, miss and start-inside as the discrete events they are (module docstring):
    the entropy of the draws' event patterns plus the pattern-weighted Gaussian EIG of the readings within each.

    Parameters
    ----------
    signals : (N, C, T) or (N, T) float, metres
        Predicted signals (:func:`bayestouch.planning.signal.predict_signals`: t_max for a miss, 0 inside).
    noise_sd : float, metres
        Reading noise σ of a touch.
    t_max : float, metres
        The rays' length.

    Returns
    -------
    (C,) float, nats; equal to :func:`eig_gaussian` for a candidate on which every draw predicts the same events.
    """
    s = np.asarray(signals, dtype=np.float64)
    if s.ndim == 2:
        s = s[:, None]
    n = s.shape[0]
    out = np.array(eig_gaussian(s, noise_sd))
    ev = reading_events(s, t_max)
    eye = np.eye(s.shape[2])
    for c in np.flatnonzero(np.any(ev != ev[:1], axis=(0, 2))):
        _, group, counts = np.unique(ev[:, c], axis=0, return_inverse=True, return_counts=True)
        group = np.ravel(group)
        p = counts / n
        gain = 0.0
        for g in np.flatnonzero(counts > 1):  # NumPy: one compiled program per group size would cost more
            cov = np.atleast_2d(np.cov(s[group == g, c], rowvar=False))
            gain += p[g] * 0.5 * np.linalg.slogdet(eye + cov / noise_sd**2)[1]
        out[c] = float(-np.sum(p * np.log(p))) + gain
    return out


def eig_per_point(signals, noise_sd: float) -> np.ndarray:
    """Sum of per-reading gains ½ Σ_t log(1 + Var_t/σ²), nats (C,): double counts correlated readings; kept
    as the negative control of the tests, never used to plan."""
    s = np.asarray(signals, dtype=np.float64)
    if s.ndim == 2:
        s = s[:, None]
    return 0.5 * np.sum(np.log1p(s.var(axis=0, ddof=1) / noise_sd**2), axis=-1)


@jax.jit
def _pce(signals, noise, noise_sd):
    # signals (N, T), noise (N, T): y_i = f_i + ε_i; log p(y_i | θ_l) up to a constant shared by all terms
    y = signals + noise
    d2 = jnp.sum(y * y, 1)[:, None] - 2.0 * y @ signals.T + jnp.sum(signals * signals, 1)[None, :]
    logp = -0.5 * d2 / noise_sd**2  # (N, N)
    own = -0.5 * jnp.sum(noise * noise, 1) / noise_sd**2
    n = signals.shape[0]
    return jnp.mean(own - (jax.scipy.special.logsumexp(logp, axis=1) - jnp.log(n)))


def eig_pce(signals, noise_sd: float, seed=None) -> np.ndarray:
    """Prior contrastive estimate (lower bound) of the EIG of each candidate, nats, using all N draws both as the
    outer samples and as the contrasts (the own draw included, Foster et al. 2020, eq. 5).

    Parameters
    ----------
    signals : (N, C, T) or (N, T) float, metres
    noise_sd : float, metres
    seed : int, np.random.Generator or None
        The simulated reading noise.

    Returns
    -------
    (C,) float, nats; each ≤ log N.
    """
    s = np.asarray(signals, dtype=np.float64)
    if s.ndim == 2:
        s = s[:, None]
    rng = as_rng(seed)
    out = []
    for c in range(s.shape[1]):
        eps = noise_sd * rng.standard_normal(s[:, c].shape)
        out.append(float(_pce(jnp.asarray(s[:, c]), jnp.asarray(eps), jnp.float64(noise_sd))))
    return np.array(out)


def bimodality_coefficient(x) -> float:
    """Sarle's bimodality coefficient (g² + 1) / (k + 3 (n − 1)² / ((n − 2)(n − 3))) of samples ``x`` (n,), g the
    sample skewness and k the excess kurtosis (SAS Institute 1990; Pfister et al. 2013, Front. Psychol. 4:700);
    above 5/9 (its value for a uniform distribution) suggests more than one mode."""
    x = np.asarray(x, float)
    n = len(x)
    if n < 4 or np.std(x) == 0:
        return 0.0
    g, k = skew(x, bias=False), kurtosis(x, bias=False)
    return float((g * g + 1.0) / (k + 3.0 * (n - 1) ** 2 / ((n - 2) * (n - 3))))


def looks_multimodal(values) -> bool:
    """Whether draws of a scalar (e.g. the volume) look multimodal: bimodality coefficient > 5/9."""
    return bimodality_coefficient(values) > 5.0 / 9.0


class EIGDecision(NamedTuple):
    """The planner's choice: ``best`` index, Gaussian ``eig`` (C,) nats, the PCE re-check (``checked`` indices
    and their ``pce`` nats, empty unless multimodal), and the ``utility`` (C,) that was maximised."""

    best: int
    eig: np.ndarray
    utility: np.ndarray
    checked: np.ndarray
    pce: np.ndarray


def decide(
    signals,
    noise_sd: float,
    *,
    durations=None,
    multimodal: bool = False,
    recheck: int = 3,
    seed=None,
    t_max: float | None = None,
) -> EIGDecision:
    """Pick the candidate of highest EIG (or EIG per second of stroke when ``durations`` (C,) s are given).

    With ``t_max`` (metres, the rays' length) the EIG treats touch, miss and start-inside as events
    (:func:`eig_events`); without it every reading is Gaussian (:func:`eig_gaussian`). When ``multimodal``, the
    ``recheck`` best are re-scored with :func:`eig_pce` and the best of those by PCE wins (ties to the first order).
    """
    eig = eig_gaussian(signals, noise_sd) if t_max is None else eig_events(signals, noise_sd, t_max)
    util = eig if durations is None else eig / np.asarray(durations, float)
    best = int(np.argmax(util))
    checked = np.array([], int)
    pce = np.array([])
    if multimodal and recheck > 1:
        checked = np.argsort(-util)[:recheck]
        pce = eig_pce(np.asarray(signals)[:, checked], noise_sd, seed)
        score = pce if durations is None else pce / np.asarray(durations, float)[checked]
        best = int(checked[int(np.argmax(score))])
    return EIGDecision(best, eig, util, checked, pce)


def eig_pairwise(post, means, sd) -> float:
    """Lower bound (nats) of the mutual information between k ~ ``post`` and y = μ_k + N(0, diag sd²).

    I ≥ −Σ_i p_i log Σ_j p_j exp(−D_B(i, j)), with D_B = ‖(μ_i − μ_j) / sd‖² / 8 the Bhattacharyya distance of
    equal-covariance Gaussians (Kolchinsky & Tracey 2017, "Estimating mixture entropy with pairwise distances",
    Entropy 19:361). It is H(k) for fully separable means and 0 for identical ones or a certain k.

    Parameters
    ----------
    post : (K,) float
        Probabilities.
    means : (K, D) float
        Noise-free predictions (units of ``sd``).
    sd : (D,) float
        Noise sd of each reading.

    Returns
    -------
    float, nats
    """
    p = np.asarray(post, float)
    m = np.asarray(means, float) / np.asarray(sd, float)
    d2 = np.sum((m[:, None, :] - m[None, :, :]) ** 2, axis=-1)
    keep = p > 0
    lp = np.log(np.where(keep, p, 1.0))
    inner = logsumexp(lp[None, :] - d2 / 8.0, axis=1, b=keep[None, :].astype(float))
    return float(-np.sum(np.where(keep, p * inner, 0.0)))
