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
"""

from __future__ import annotations

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


def _prepare(points, strokes):
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 1 or not np.all(np.isfinite(p)):
        raise BadInput(f"points: expected a finite (M ≥ 1, 3) array in metres, got shape {p.shape}")
    lab = _labels(strokes, len(p))
    onehot = (lab[None, :] == np.arange(lab.max() + 1)[:, None]).astype(float)
    hom = np.concatenate([p.T, np.ones((1, len(p)))], axis=0)
    return p, jnp.asarray(hom), jnp.asarray(onehot)


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
