"""Stroke-choice policies: ``eig`` (the planner), and the baselines ``random``, ``coverage``, ``gpis`` and ``oracle``.

``eig``
    Highest expected information gain of the whole stroke (:func:`bayestouch.planning.eig.decide`), with the PCE
    re-check of the best three when the posterior's volume draws look multimodal; optionally per second.
``random``
    A uniformly random candidate.
``coverage``
    The candidate whose path lies farthest from everything touched so far.
``gpis``
    The field's standard baseline (Yi et al. 2016, "Active tactile object exploration with Gaussian processes",
    IROS; Driess et al. 2017, "Active learning with query paths for tactile object shape exploration", IROS): a
    Gaussian-process implicit surface conditioned on the contacts so far (:mod:`bayestouch.inference.gpis`), and
    the candidate whose rays meet it where it is most uncertain (:func:`gpis_scores`). It uses the contacts only,
    not the n-ellipsoid posterior.
``oracle``
    Knows the truth (a reference for reports, not a planner): one-step lookahead (:func:`oracle_scores`).

Candidates are :class:`~bayestouch.planning.candidates.Strokes`; posterior draws (N, 10) n-ellipsoid vectors
(metres, radians). How coverage and the oracle score: ``docs/planning.md``.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_mesh
from bayestouch.inference import gpis
from bayestouch.planning import eig as eig_mod
from bayestouch.planning.candidates import Strokes
from bayestouch.planning.signal import predict_signals
from bayestouch.scene.raycast import true_ray_distances

__all__ = ["POLICIES", "Decision", "choose", "check_policy", "gpis_scores", "oracle_scores"]

POLICIES = ("eig", "random", "coverage", "gpis", "oracle")
#: points along each ray at which the gpis policy looks for the GPIS surface
GPIS_RAY_POINTS = 32
#: contacts the gpis policy needs to condition a GPIS (with fewer it chooses at random)
GPIS_MIN_CONTACTS = 10


class Decision(NamedTuple):
    """A policy's choice: candidate ``index``, the ``score`` (C,) it maximised (None for random), the Gaussian EIG
    (C,) nats of every candidate when computed (else None) and the decision time ``seconds``."""

    index: int
    score: np.ndarray | None
    eig: np.ndarray | None
    seconds: float


def check_policy(name: str) -> str:
    """``name`` if it is a known policy, else :class:`BadInput`."""
    if name not in POLICIES:
        raise BadInput(f"planner: unknown planner {name!r}; expected one of {', '.join(POLICIES)}")
    return name


def choose(
    policy: str,
    strokes: Strokes,
    shape_vectors,
    *,
    noise_sd: float,
    rng: np.random.Generator,
    touched=None,
    obj=None,
    volumes=None,
    per_second: bool = False,
    standoff: float | None = None,
) -> Decision:
    """Choose the next stroke among the candidates.

    Parameters
    ----------
    policy : {"eig", "random", "coverage", "gpis", "oracle"}
    strokes : Strokes
        C candidates.
    shape_vectors : (N, 10) float
        Posterior draws as n-ellipsoid vectors (metres, radians).
    noise_sd : float, metres
        Contact noise along the ray.
    rng : np.random.Generator
    touched : (M, 3) float, metres
        Contact points so far (``coverage``, ``gpis``).
    obj : SceneObject
        The truth (``oracle`` only).
    volumes : (N,) float, m³, optional
        Volumes of the draws: the multimodality check of ``eig``.
    per_second : bool
        ``eig``: maximise EIG per second of stroke.
    standoff : float, metres, optional
        Newton's starting guess along the rays (default t_max / 2, the believed surface).

    Returns
    -------
    Decision
    """
    check_policy(policy)
    t0 = time.perf_counter()
    C = len(strokes.length)
    if policy == "random":
        return Decision(int(rng.integers(C)), None, None, time.perf_counter() - t0)
    if policy == "coverage":
        if touched is None or len(touched) == 0:
            return Decision(int(rng.integers(C)), None, None, time.perf_counter() - t0)
        d, _ = cKDTree(np.asarray(touched)).query(strokes.path.reshape(-1, 3))
        score = d.reshape(C, -1).mean(axis=1)
        return Decision(int(np.argmax(score)), score, None, time.perf_counter() - t0)
    if policy == "gpis":
        if touched is None or len(touched) < GPIS_MIN_CONTACTS:
            return Decision(int(rng.integers(C)), None, None, time.perf_counter() - t0)
        score = gpis_scores(strokes, touched)
        return Decision(int(np.argmax(score)), score, None, time.perf_counter() - t0)
    t_init = 0.5 * strokes.t_max if standoff is None else standoff
    sig = predict_signals(
        shape_vectors, strokes.starts, strokes.dirs, strokes.t_max, t_init=t_init, iters=6, single=True
    )
    if policy == "eig":
        multi = volumes is not None and eig_mod.looks_multimodal(volumes)
        dec = eig_mod.decide(
            sig,
            noise_sd,
            durations=strokes.duration if per_second else None,
            multimodal=multi,
            seed=rng,
            t_max=strokes.t_max,
        )
        return Decision(dec.best, dec.utility, dec.eig, time.perf_counter() - t0)
    if obj is None:
        raise BadInput("oracle: the oracle planner needs the true object (simulation only)")
    score = oracle_scores(obj, strokes, shape_vectors, sig, noise_sd)
    return Decision(int(np.argmin(score)), score, eig_mod.eig_gaussian(sig, noise_sd), time.perf_counter() - t0)


def gpis_scores(strokes: Strokes, touched) -> np.ndarray:
    """The gpis policy's score (C,) m² of each candidate: the mean over its rays of the GPIS's posterior variance
    where the ray first enters the GPIS mean's solid (the predicted contact), or, for a ray that never does, where
    it comes closest (smallest |mean|). Ray points are clamped to the GP's box, outside which the thin-plate
    covariance is not one. Higher is more uncertain.

    Parameters
    ----------
    strokes : Strokes
        C candidates of T rays.
    touched : (M, 3) float, metres
        Contacts so far (M ≥ 2).
    """
    gp = gpis.condition(np.asarray(touched, dtype=float))
    t = np.linspace(0.0, float(strokes.t_max), GPIS_RAY_POINTS)
    q = strokes.starts[:, :, None, :] + t[None, None, :, None] * strokes.dirs[:, :, None, :]  # (C, T, K, 3)
    q = np.clip(q, gp.lower, gp.upper)
    C, T, K, _ = q.shape
    mean = gpis.predict_mean(gp, q.reshape(-1, 3)).reshape(C, T, K)
    inside = mean <= 0.0
    at = np.where(inside.any(axis=2), np.argmax(inside, axis=2), np.argmin(np.abs(mean), axis=2))  # (C, T)
    chosen = np.take_along_axis(q, at[:, :, None, None], axis=2)[:, :, 0, :]  # (C, T, 3)
    _, var = gpis.predict(gp, chosen.reshape(-1, 3))
    return var.reshape(C, T).mean(axis=1)


@jax.jit
def _rms_distances(vectors, pts):
    def rms(vec):
        sh = ne.from_vector(vec)
        d = ne.first_order_distance(sh, ne.to_local(sh, pts))[0]
        return jnp.sqrt(jnp.mean(d * d))

    return jax.vmap(rms)(vectors)


def _draw_errors(obj, shape_vectors, count: int = 256) -> np.ndarray:
    """RMS first-order distance (N,) m of ``count`` true-surface points (area-uniform, fixed seed) to each draw's
    surface."""
    v, f = obj.mesh(32)
    pts = jnp.asarray(sample_mesh(v, f, count, 0)[0])
    return np.asarray(_rms_distances(jnp.asarray(shape_vectors, dtype=jnp.float64), pts))


def oracle_scores(obj, strokes: Strokes, shape_vectors, signals, noise_sd: float) -> np.ndarray:
    """The oracle's expected surface error (C,) m after each candidate: one-step lookahead with the truth.

    The candidate's true, noise-free reading y* (:func:`true_ray_distances`, misses at t_max as in the planner's
    signal) reweights the current draws by their likelihood exp(−|y* − f(θ_i)|²/2σ²) (importance reweighting of
    the posterior, the update the stroke would cause to first order); the score is the reweighted mean of each
    draw's RMS distance to the true surface (:func:`_draw_errors`). Lower is better.
    """
    truth, _ = true_ray_distances(obj, strokes.starts, strokes.dirs, strokes.t_max)
    err = _draw_errors(obj, shape_vectors)
    logw = -0.5 * np.sum((np.asarray(signals) - truth[None]) ** 2, axis=2) / noise_sd**2  # (N, C)
    w = np.exp(logw - logw.max(axis=0))
    return (w * err[:, None]).sum(axis=0) / w.sum(axis=0)
