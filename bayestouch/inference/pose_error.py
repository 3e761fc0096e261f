"""Contacts recorded where the host believes the pad was: the contact likelihood with each stroke's pose error
marginalised.

A real finger puts its pad where the bent rod takes it, and a host that computes the contact from the commanded
currents and its nominal constants is off by millimetres (``benchmarks/bench_pose.py``: a median 1.0 mm, 95th
percentile 5.3 mm), slowly varying along a stroke. The model here gives every stroke s one unknown offset
δ_s ~ N(0, τ² I₃) shared by its contacts. To first order contact i's residual moves by −n_i·δ_s (n_i the model
surface's unit normal), so a stroke's residuals r_s are Gaussian with covariance σ² I + τ² N_s N_sᵀ, and δ_s is
integrated out in closed form (Woodbury):

    r_sᵀ C⁻¹ r_s = (r_sᵀ r_s − b_sᵀ A_s⁻¹ b_s) / σ²,   log det C = m_s log σ² + log det(I₃ + (τ²/σ²) N_sᵀ N_s),

with b_s = N_sᵀ r_s and A_s = (σ²/τ²) I₃ + N_sᵀ N_s. θ is the contact level's 11 parameters (centre, log
semi-axes, Euler angles, log n, log σ) and log τ, whose prior is normal about the host's stated pose sd
(``tau_m``) with sd :data:`TAU_LOG_SD` (truncated to the box ``[TAU_MIN, TAU_MAX]``). Gaussian contact noise only:
no outlier component (a displaced contact is not a pose error).

A host that knows the commanded current programs can say more than one offset per stroke:
:func:`bayestouch.physics.pose.pose_error_ensemble` runs fingers drawn about the nominal constants through the same
programs and gives K draws e_k (M, 3) of the pose error at every contact, correlated along each stroke and across
strokes (the same finger runs them all). :func:`ensemble_model` turns them into a law: the contacts moved by their
mean μ; the :data:`RANK` leading principal components L of their covariance, shared by all contacts; what those
leave out, each contact's remaining covariance V_i, correlated between a stroke's contacts as exp(−|Δt|/ℓ) with ℓ
fitted to the ensemble (:func:`correlation_time`). :func:`make_ensemble_pose_log_prob` marginalises it: residuals
Gaussian with covariance s² B Bᵀ + D, B_ik = n_i·L_ik, D block-diagonal by stroke, D_s = σ² I + s² (a aᵀ ∘ ρ_s),
a_i² = n_iᵀ V_i n_i (Woodbury in the leading components, Cholesky per stroke), s a sampled scale (prior log-normal
about 1) for a finger further from nominal than the host's spread says. What the drawn fingers do not hold (the
carrier's calibration, the pad's mount, a finger outside the assumed family) enters as one more offset per stroke,
sd :data:`OFFSET_SD` (``offset_sd``; scaled by s as well): three more columns of L per stroke. Pose errors of
millimetres on surfaces curved over centimetres are not linear in the distance (a 3 mm tangential shift moves a
contact 0.2 mm off a 20 mm sphere), so the law is linearised again about the pose error's posterior mean
(:data:`RELINEARISE`).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.inference import contact as cm

__all__ = [
    "POSE_PARAM_NAMES",
    "TAU_MIN",
    "TAU_MAX",
    "TAU_LOG_SD",
    "pose_log_likelihood",
    "make_pose_log_prob",
    "ENSEMBLE_PARAM_NAMES",
    "SCALE_LOG_SD",
    "SCALE_MIN",
    "SCALE_MAX",
    "RANK",
    "RELINEARISE",
    "OFFSET_SD",
    "EnsembleModel",
    "principal_components",
    "ensemble_model",
    "correlation_time",
    "ensemble_log_likelihood",
    "make_ensemble_pose_log_prob",
]

POSE_PARAM_NAMES = cm.PARAM_NAMES + ("log_tau",)
#: box of the pose sd τ, metres
TAU_MIN = 1e-5
TAU_MAX = 0.02
#: sd of log τ about the stated pose sd (a factor e^0.3 ≈ 1.35 either way: the host knows its pose sd from a
#: calibration). A wider prior lets τ run to centimetres, where the strokes' free offsets take the shape over: at
#: 0.5 one benchmark scenario (benchmarks/bench_pose_fit.py, scenario 1, true pose errors 0.24 mm) put τ at 7.8 mm
#: with R-hat 1.22, against 0.75 mm and R-hat 1.02 at 0.3
TAU_LOG_SD = 0.3
_LOG_2PI = float(np.log(2 * np.pi))
ENSEMBLE_PARAM_NAMES = cm.PARAM_NAMES + ("log_pose_scale",)
#: prior sd of log s, the ensemble's scale: the drawn fingers' spread is an assumption (FingerSpread), so a finger
#: e^0.5 ≈ 1.6 times further from nominal is one sd away
SCALE_LOG_SD = 0.5
#: box of the ensemble's scale s
SCALE_MIN = 0.05
SCALE_MAX = 20.0
#: leading components of the ensemble's pose covariance kept as shared (low-rank) pose errors; what they leave out
#: is a remainder correlated along each stroke's time
RANK = 8
#: times the linearised law is linearised again about the pose error's posterior mean
RELINEARISE = 1
#: sd (metres) of the per-stroke offset beside the ensemble's law: a discrepancy term for pose errors the drawn
#: fingers do not produce. 1 mm was tried on benchmarks/bench_pose_fit.py's scenarios 0-19 before the benchmark
#: ran (docs/physics_notes.md); 0 turns it off
OFFSET_SD = 1e-3


def _labels(strokes, m: int) -> np.ndarray:
    s = np.asarray(strokes)
    if s.shape != (m,) or not np.all(np.isfinite(s.astype(float))) or np.any(s != np.round(s)):
        raise BadInput(f"strokes: expected one integer stroke label per contact ({m} values), got shape {s.shape}")
    _, inverse = np.unique(s.astype(np.int64), return_inverse=True)
    return inverse


def _stroke_log_lik(th, hom, onehot):
    """Log-likelihood (W,) of walkers ``th (W, 12)`` for homogeneous contacts ``hom (4, M)`` grouped by ``onehot
    (S, M)`` into strokes."""
    f = cm.principal_frame(th, hom)
    n = cm.frame_normals(f)  # (W, 3, M) outward unit normals
    d = f.d  # (W, M)
    s2 = jnp.exp(2.0 * th[:, 10])[:, None]  # (W, 1)
    t2 = jnp.exp(2.0 * th[:, 11])[:, None]
    rr = jnp.einsum("sm,wm->ws", onehot, d * d)  # (W, S)
    b = jnp.einsum("sm,wkm->wsk", onehot, n * d[:, None, :])  # (W, S, 3)
    ntn = jnp.einsum("sm,wim,wjm->wsij", onehot, n, n)  # (W, S, 3, 3)
    m_s = jnp.sum(onehot, axis=1)[None]  # (1, S)
    eye = jnp.eye(3)
    A = (s2 / t2)[:, :, None, None] * eye + ntn  # (W, S, 3, 3)
    quad = (rr - jnp.einsum("wsk,wsk->ws", b, jnp.linalg.solve(A, b[..., None])[..., 0])) / s2
    logdet = m_s * jnp.log(s2) + jnp.linalg.slogdet(eye + (t2 / s2)[:, :, None, None] * ntn)[1]
    return -0.5 * jnp.sum(quad + logdet + m_s * _LOG_2PI, axis=1)


_stroke_log_lik_jit = jax.jit(_stroke_log_lik)


def _homogeneous(p: np.ndarray):
    """Homogeneous coordinates (4, M) of points ``p (M, 3)`` in metres, as :func:`contact.principal_frame` takes."""
    return jnp.asarray(np.concatenate([p.T, np.ones((1, len(p)))], axis=0))


def _prepare(points, strokes):
    p = cm.check_points(points)[0]
    lab = _labels(strokes, len(p))
    onehot = (lab[None, :] == np.arange(lab.max() + 1)[:, None]).astype(float)
    return p, _homogeneous(p), jnp.asarray(onehot)


def pose_log_likelihood(thetas, points, strokes) -> np.ndarray:
    """Log-likelihood (W,) of walkers ``thetas (W, 12)`` (:data:`POSE_PARAM_NAMES`) for contacts ``points (M, 3)``
    in metres labelled by ``strokes (M,)`` (any integers; equal labels share a pose offset)."""
    _, hom, onehot = _prepare(points, strokes)
    th = jnp.asarray(np.atleast_2d(np.asarray(thetas, dtype=float)))
    if th.shape[1] != len(POSE_PARAM_NAMES):
        raise BadInput(f"thetas: expected (W, {len(POSE_PARAM_NAMES)}) parameter vectors, got shape {th.shape}")
    return np.asarray(_stroke_log_lik_jit(th, hom, onehot))


@jax.jit
def _log_prob(th, hom, onehot, bounds, tau_mu, tau_sd):
    lp = cm.log_prior(th, bounds)
    z = (th[:, 11] - tau_mu) / tau_sd
    ll = _stroke_log_lik(cm.clip_to_box(th, bounds), hom, onehot)
    out = jnp.where(jnp.isfinite(lp), lp - 0.5 * z * z + ll, -jnp.inf)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


def make_pose_log_prob(
    points, strokes, tau_m: float, priors: cm.PriorParams | None = None, tau_log_sd: float = TAU_LOG_SD
):
    """A walker-vectorised log-posterior ``f(thetas (W, 12)) → (W,)`` of the pose-error model, and its box.

    Parameters
    ----------
    points : (M, 3) float, metres
        Contacts where the host computed them.
    strokes : (M,) int
        Stroke of each contact.
    tau_m : float, metres
        The host's pose sd: the prior median of τ.
    priors : PriorParams, optional
        The contact level's priors (default :func:`bayestouch.inference.contact.load_priors`).
    tau_log_sd : float
        Prior sd of log τ (how well the host knows its pose sd, e.g. from a calibration).

    Returns
    -------
    f : callable
        NumPy in, NumPy out; −inf outside the prior, never NaN.
    bounds : Bounds
        The contact level's (:func:`bayestouch.inference.contact.bounds_for`) with log τ appended.
    """
    if not (np.isfinite(tau_m) and TAU_MIN <= tau_m <= TAU_MAX):
        raise BadInput(f"tau_m: expected a pose sd in metres within [{TAU_MIN:g}, {TAU_MAX:g}], got {tau_m!r}")
    p, hom, onehot = _prepare(points, strokes)
    priors = priors or cm.load_priors()
    b = cm.bounds_for(p, priors)
    bounds = b._replace(
        lower=jnp.concatenate([b.lower, jnp.asarray([np.log(TAU_MIN)])]),
        upper=jnp.concatenate([b.upper, jnp.asarray([np.log(TAU_MAX)])]),
    )
    if not (np.isfinite(tau_log_sd) and tau_log_sd > 0):
        raise BadInput(f"tau_log_sd: expected a positive sd of log τ, got {tau_log_sd!r}")
    mu = float(np.log(tau_m))

    def f(thetas):
        th = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
        if th.shape[1] != len(POSE_PARAM_NAMES):
            raise BadInput(f"thetas: expected (W, {len(POSE_PARAM_NAMES)}) parameter vectors, got shape {th.shape}")
        return np.asarray(_log_prob(jnp.asarray(th), hom, onehot, bounds, mu, float(tau_log_sd)))

    return f, bounds


class EnsembleModel(NamedTuple):
    """The pose-error law a host derives from an ensemble of drawn fingers (:func:`ensemble_model`).

    Attributes
    ----------
    moved : (M, 3) float, metres
        The contacts moved by the ensemble's mean error.
    lead : (3, M, r + 3S) float, metres
        Columns L of the pose error e = μ + L z, z ~ N(0, I): the ensemble's r leading components (shared by all
        contacts), then, when ``offset_sd`` > 0, three per stroke, ``offset_sd`` along each axis on its contacts
        and 0 elsewhere (none when ``offset_sd`` is 0).
    resid : (3, 3, M) float, m²
        Each contact's pose covariance that the leading components leave out.
    blocks : (S, m) int
        Contact indices of each stroke, padded with −1 to the longest stroke's m.
    corr : (S, m, m) float
        Correlation of the remainder between a stroke's contacts, exp(−|t_i − t_j| / ℓ); 0 across strokes.
    ell : float, seconds
        The remainder's correlation time ℓ (:func:`correlation_time`).
    offset_sd : float, metres
        The per-stroke offset's sd (0: none).
    """

    moved: np.ndarray
    lead: np.ndarray
    resid: np.ndarray
    blocks: np.ndarray
    corr: np.ndarray
    ell: float
    offset_sd: float = 0.0


def correlation_time(remainder, strokes, times) -> float:
    """The correlation time ℓ (seconds) of pose-error remainders along strokes: the ℓ whose exp(−|Δt|/ℓ) best fits,
    in least squares over every pair of contacts in the same stroke, the ensemble's correlation of the pair's
    normalised remainders (pooled over draws and axes).

    Parameters
    ----------
    remainder : (K, M, 3) float, metres
        Ensemble deviations with the leading components removed.
    strokes : (M,) int
        Stroke label of each contact.
    times : (M,) float, seconds
        When each contact was recorded.
    """
    r = np.asarray(remainder, dtype=float)
    lab, t = np.asarray(strokes), np.asarray(times, dtype=float)
    z = r / (np.sqrt(np.sum(r * r, axis=0, keepdims=True)) + 1e-300)  # unit norm over draws, per contact and axis
    same = (lab[:, None] == lab[None, :]) & ~np.eye(len(lab), dtype=bool)
    if not np.any(same):
        return 0.0
    i, j = np.nonzero(np.triu(same))
    c = np.mean(np.sum(z[:, i, :] * z[:, j, :], axis=0), axis=-1)  # (pairs,)
    dt = np.abs(t[i] - t[j])
    span = max(float(dt.max()), 1e-9)
    grid = np.geomspace(1e-3 * span, 1e3 * span, 400)
    err = [np.sum((c - np.exp(-dt / g)) ** 2) for g in grid]
    return float(grid[int(np.argmin(err))])


def principal_components(ensemble, rank: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An ensemble of K curves e_k (K, N, 3) as its mean (N, 3), its ``rank`` leading principal components
    (N, 3, rank), scaled so that z ~ N(0, I) in e = mean + lead z reproduces the ensemble's covariance in them, and
    each member's remainder outside them (K, N, 3), in the ensemble's units."""
    e = np.asarray(ensemble, dtype=float)
    K, N = e.shape[:2]
    mu = e.mean(axis=0)
    dev = (e - mu).reshape(K, 3 * N)
    _, sv, vt = np.linalg.svd(dev / np.sqrt(K - 1), full_matrices=False)
    lead = (vt[:rank].T * sv[:rank]).reshape(N, 3, rank)
    rem = (dev - (dev @ vt[:rank].T) @ vt[:rank]).reshape(K, N, 3)
    return mu, lead, rem


def ensemble_model(
    points, ensemble, strokes, times, rank: int | None = None, offset_sd: float = OFFSET_SD
) -> EnsembleModel:
    """The pose-error law of :func:`make_ensemble_pose_log_prob` from K drawn fingers' errors.

    Parameters
    ----------
    points : (M, 3) float, metres
        Contacts where the host computed them.
    ensemble : (K, M, 3) float, metres
        K ≥ 2 draws of the pose error p_true − p_host at each contact
        (:func:`bayestouch.physics.pose.pose_error_ensemble`).
    strokes : (M,) int
        Stroke of each contact.
    times : (M,) float, seconds
        When each contact was recorded (any origin per stroke).
    rank : int, optional
        Leading components kept (default min(:data:`RANK`, K − 1)).
    offset_sd : float, metres
        sd of one more offset per stroke beside the ensemble's law (default :data:`OFFSET_SD`; 0: none).

    Returns
    -------
    EnsembleModel
    """
    p = cm.check_points(points)[0]
    e = np.asarray(ensemble, dtype=float)
    if e.ndim != 3 or e.shape[1:] != p.shape or e.shape[0] < 2 or not np.all(np.isfinite(e)):
        raise BadInput(
            f"ensemble: expected finite pose errors of shape (K ≥ 2, {len(p)}, 3) in metres, got shape {e.shape}"
        )
    lab = _labels(strokes, len(p))
    t = np.asarray(times, dtype=float)
    if t.shape != (len(p),) or not np.all(np.isfinite(t)):
        raise BadInput(f"times: expected one finite time in seconds per contact ({len(p)} values), got shape {t.shape}")
    if not (
        isinstance(offset_sd, int | float | np.integer | np.floating)
        and np.isfinite(offset_sd)
        and 0 <= offset_sd < 0.1
    ):
        raise BadInput(f"offset_sd: expected a per-stroke offset sd in metres in [0, 0.1), got {offset_sd!r}")
    K, M = e.shape[:2]
    r = min(RANK, K - 1) if rank is None else int(rank)
    if not 1 <= r <= K - 1:
        raise BadInput(f"rank: expected an integer in [1, {K - 1}] (the ensemble has {K} draws), got {rank!r}")
    mu, lead, rem = principal_components(e, r)
    resid = np.einsum("kmc,kme->cem", rem, rem) / (K - 1)
    ell = correlation_time(rem, lab, t)
    S = int(lab.max()) + 1
    m = int(np.bincount(lab).max())
    blocks = np.full((S, m), -1, dtype=np.int64)
    corr = np.zeros((S, m, m))
    for k in range(S):
        idx = np.nonzero(lab == k)[0]
        blocks[k, : len(idx)] = idx
        dt = np.abs(t[idx][:, None] - t[idx][None, :])
        corr[k, : len(idx), : len(idx)] = np.exp(-dt / ell) if ell > 0 else np.eye(len(idx))
    if offset_sd > 0:
        off = np.zeros((M, 3, 3 * S))
        for c in range(3):
            off[np.arange(M), c, 3 * lab + c] = offset_sd
        lead = np.concatenate([lead, off], axis=2)
    return EnsembleModel(p + mu, np.transpose(lead, (1, 0, 2)), resid, blocks, corr, ell, float(offset_sd))


def _linear_gaussian(th, hom, shift, lead, resid, blocks, corr):
    """The pose-error law linearised about the contacts moved by ``shift (W, 3, M)`` (metres, beyond the ensemble's
    mean): the log-density (W,) of the residuals r_i = d_i − n_i·shift_i, and the posterior mean (W, 3, M) of the
    deviation from the ensemble's mean given them (s L ẑ + n η̂)."""
    f = cm.principal_frame(th, hom[None] + jnp.concatenate([shift, jnp.zeros_like(shift[:, :1])], axis=1))
    n = cm.frame_normals(f)  # (W, 3, M)
    d = f.d - jnp.einsum("wcm,wcm->wm", n, shift)  # (W, M)
    M = d.shape[1]
    s = jnp.exp(th[:, 11])  # (W,) scale
    a = jnp.sqrt(jnp.einsum("wcm,cem,wem->wm", n, resid, n) + 1e-30)  # (W, M)
    B = jnp.einsum("wcm,cmk->wmk", n, lead) * s[:, None, None]  # (W, M, r)
    valid = blocks >= 0  # (S, m)
    idx = jnp.where(valid, blocks, 0)
    ab = jnp.where(valid, a[:, idx], 0.0)  # (W, S, m)
    db = jnp.where(valid, d[:, idx], 0.0)
    Bb = jnp.where(valid[None, :, :, None], B[:, idx, :], 0.0)  # (W, S, m, r)
    eye = jnp.eye(blocks.shape[1])
    R = (s * s)[:, None, None, None] * ab[..., :, None] * ab[..., None, :] * corr  # remainder along the normals
    both = valid[None, :, :, None] & valid[None, :, None, :]
    Ds = jnp.where(both, jnp.exp(2.0 * th[:, 10])[:, None, None, None] * eye + R, eye)  # padding: unit diagonal
    cD = jnp.linalg.cholesky(Ds)  # (W, S, m, m)
    solve = jax.scipy.linalg.solve_triangular
    yd = solve(cD, db[..., None], lower=True)[..., 0]  # (W, S, m) = cD⁻¹ d
    yB = solve(cD, Bb, lower=True)  # (W, S, m, r)
    A = jnp.eye(lead.shape[-1]) + jnp.einsum("wsmk,wsml->wkl", yB, yB)
    cA = jnp.linalg.cholesky(A)
    v = jnp.einsum("wsmk,wsm->wk", yB, yd)
    y = solve(cA, v[..., None], lower=True)[..., 0]
    quad = jnp.sum(yd * yd, axis=(1, 2)) - jnp.sum(y * y, axis=1)
    logdet = 2.0 * jnp.sum(jnp.log(jnp.diagonal(cD, axis1=-2, axis2=-1)), axis=(1, 2))
    logdet = logdet + 2.0 * jnp.sum(jnp.log(jnp.diagonal(cA, axis1=1, axis2=2)), axis=1)
    ll = -0.5 * (quad + logdet + M * _LOG_2PI)
    # posterior means given n·u + noise = −d, u = s L z + n η: with w = C⁻¹(−d) (Woodbury, C = D + B Bᵀ),
    # ẑ = Bᵀ w and η̂ = R w, so the pose error's posterior mean is s L ẑ + n η̂
    x = solve(cA, y[..., None], lower=True, trans=1)[..., 0]  # A⁻¹ v
    w_blk = -(solve(cD, (yd - jnp.einsum("wsmk,wk->wsm", yB, x))[..., None], lower=True, trans=1)[..., 0])
    z = jnp.einsum("wsmk,wsm->wk", Bb, w_blk)  # (W, r): Bᵀ w
    eta = jnp.einsum("wsij,wsj->wsi", R, w_blk)  # (W, S, m)
    eta_m = jnp.zeros_like(d).at[:, idx].add(jnp.where(valid, eta, 0.0))  # back to contact order
    u = jnp.einsum("cmk,wk->wcm", lead, z * s[:, None]) + n * eta_m[:, None, :]
    return ll, u


def _ensemble_log_lik(th, hom, lead, resid, blocks, corr, relinearise=1):
    """Log-likelihood (W,) of walkers ``th (W, 12)`` for homogeneous contacts ``hom (4, M)`` (moved by the
    ensemble's mean) under :class:`EnsembleModel`'s law: covariance D + s² B Bᵀ, B_ik = n_i·L_ik, D block-diagonal
    by stroke with D_s = σ² I + s² (a aᵀ ∘ corr_s), a_i² = n_iᵀ resid_i n_i. The distances are linear in the pose
    error only near the contacts, so the law is linearised again about the posterior mean of the pose error
    ``relinearise`` times (an iterated Laplace approximation of the integral over pose errors)."""
    shift = jnp.zeros((th.shape[0], 3, hom.shape[1]))
    ll, u = _linear_gaussian(th, hom, shift, lead, resid, blocks, corr)
    for _ in range(relinearise):
        ll, u = _linear_gaussian(th, hom, jax.lax.stop_gradient(u), lead, resid, blocks, corr)
    return ll


_ensemble_log_lik_jit = jax.jit(_ensemble_log_lik, static_argnames=("relinearise",))


def _arrays(model: EnsembleModel):
    return (
        _homogeneous(model.moved),
        jnp.asarray(model.lead),
        jnp.asarray(model.resid),
        jnp.asarray(model.blocks),
        jnp.asarray(model.corr),
    )


def ensemble_log_likelihood(thetas, model: EnsembleModel, relinearise: int = RELINEARISE) -> np.ndarray:
    """Log-likelihood (W,) of walkers ``thetas (W, 12)`` (:data:`ENSEMBLE_PARAM_NAMES`) under the pose-error law
    ``model`` (:func:`ensemble_model`), linearised again ``relinearise`` times about the pose error's posterior
    mean (0: linear about the ensemble's mean)."""
    th = jnp.asarray(np.atleast_2d(np.asarray(thetas, dtype=float)))
    if th.shape[1] != len(ENSEMBLE_PARAM_NAMES):
        raise BadInput(f"thetas: expected (W, {len(ENSEMBLE_PARAM_NAMES)}) parameter vectors, got shape {th.shape}")
    return np.asarray(_ensemble_log_lik_jit(th, *_arrays(model), relinearise=_check_relinearise(relinearise)))


def _check_relinearise(k) -> int:
    if not (isinstance(k, int | np.integer) and 0 <= k <= 10):
        raise BadInput(f"relinearise: expected an integer in [0, 10], got {k!r}")
    return int(k)


@partial(jax.jit, static_argnames=("relinearise",))
def _ensemble_log_prob(th, hom, lead, resid, blocks, corr, bounds, scale_sd, relinearise):
    lp = cm.log_prior(th, bounds)
    z = th[:, 11] / scale_sd
    ll = _ensemble_log_lik(cm.clip_to_box(th, bounds), hom, lead, resid, blocks, corr, relinearise)
    out = jnp.where(jnp.isfinite(lp), lp - 0.5 * z * z + ll, -jnp.inf)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


def make_ensemble_pose_log_prob(
    model: EnsembleModel,
    priors: cm.PriorParams | None = None,
    scale_log_sd: float = SCALE_LOG_SD,
    relinearise: int = RELINEARISE,
):
    """A walker-vectorised log-posterior ``f(thetas (W, 12)) → (W,)`` of the ensemble pose-error law, and its box.

    Parameters
    ----------
    model : EnsembleModel
        The contacts and their pose-error law (:func:`ensemble_model`).
    priors : PriorParams, optional
        The contact level's priors (default :func:`bayestouch.inference.contact.load_priors`); the centre's box
        comes from the contacts moved by the ensemble's mean.
    scale_log_sd : float
        Prior sd of log s, the scale of the ensemble's spread (median 1).
    relinearise : int
        Times the law is linearised again about the pose error's posterior mean (0: once, about the ensemble's
        mean).

    Returns
    -------
    f : callable
        NumPy in, NumPy out; −inf outside the prior, never NaN.
    bounds : Bounds
        The contact level's box with log s appended.
    """
    if not (np.isfinite(scale_log_sd) and scale_log_sd > 0):
        raise BadInput(f"scale_log_sd: expected a positive sd of log s, got {scale_log_sd!r}")
    priors = priors or cm.load_priors()
    b = cm.bounds_for(model.moved, priors)
    bounds = b._replace(
        lower=jnp.concatenate([b.lower, jnp.asarray([np.log(SCALE_MIN)])]),
        upper=jnp.concatenate([b.upper, jnp.asarray([np.log(SCALE_MAX)])]),
    )
    arrays = _arrays(model)
    k = _check_relinearise(relinearise)

    def f(thetas):
        th = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
        if th.shape[1] != len(ENSEMBLE_PARAM_NAMES):
            raise BadInput(f"thetas: expected (W, {len(ENSEMBLE_PARAM_NAMES)}) parameter vectors, got shape {th.shape}")
        return np.asarray(_ensemble_log_prob(jnp.asarray(th), *arrays, bounds, float(scale_log_sd), k))

    return f, bounds
