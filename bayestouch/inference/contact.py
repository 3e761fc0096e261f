"""Contact-level model: probed contact points (M, 3) m against the n-ellipsoid surface. θ (W, 11) or more per
walker: centre m, log semi-axes log m, Euler angles rad, log n, log σ (m, the contact noise scale), then the
options' parameters in the order of :func:`param_names`; residuals are first-order distances (m) to the surface.
Priors, the batched log-probability (float64, or mixed precision) and the pointwise log-likelihood. The model, its
noise models, normals and precision: ``docs/contact_model.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import gammaln

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.rotation import rotation_matrix
from bayestouch.params import MODELS, Spec, build

__all__ = [
    "PriorParams",
    "load_priors",
    "Bounds",
    "bounds_for",
    "PARAM_NAMES",
    "NOISE_MODELS",
    "param_names",
    "shape_of",
    "residuals",
    "log_likelihood",
    "log_prior",
    "log_prob",
    "log_prob_batch",
    "make_log_prob",
    "pointwise_log_likelihood",
    "principal_frame",
    "PrincipalFrame",
]

#: the 11 parameters of the default layout (no normals, Student-t or Gaussian noise)
PARAM_NAMES = ("x_G", "y_G", "z_G", "log_a", "log_b", "log_c", "xi", "psi", "zeta", "log_n", "log_sigma")

#: the noise models of the likelihood (``docs/contact_model.md``)
NOISE_MODELS = ("student", "multiplicative", "mixture")

PRIOR_SPECS = {
    "centre_margin": Spec("1", 0.0, 10.0),
    "axis_min": Spec("m", 1e-6, 1.0),
    "axis_max": Spec("m", 1e-4, 10.0),
    "n_min": Spec("1", 0.5, 100.0),
    "n_max": Spec("1", 1.0, 1000.0),
    "sigma_min": Spec("m", 1e-9, 1.0),
    "sigma_max": Spec("m", 1e-7, 1.0),
    "student_nu": Spec("1", 0.5, 1e6),
    "kappa_min": Spec("1", 1e-3, 1e6),
    "kappa_max": Spec("1", 1e-2, 1e8),
    "eps_min": Spec("1", 1e-12, 1.0),
    "eps_max": Spec("1", 1e-9, 1.0),
    "outlier_max": Spec("1", 1e-3, 0.99),
}

_TINY = 1e-300
_LOG_2PI = float(np.log(2 * np.pi))


class PriorParams(NamedTuple):
    """Prior settings (see ``models/priors.toml``)."""

    centre_margin: float
    axis_min: float
    axis_max: float
    n_min: float
    n_max: float
    sigma_min: float
    sigma_max: float
    student_nu: float
    kappa_min: float
    kappa_max: float
    eps_min: float
    eps_max: float
    outlier_max: float


def load_priors(path=None) -> PriorParams:
    """Read ``[priors]`` of ``models/priors.toml`` (or ``path``)."""
    return build(PriorParams, MODELS / "priors.toml" if path is None else path, "priors", PRIOR_SPECS)


def _check_noise(noise: str) -> str:
    if noise not in NOISE_MODELS:
        raise BadInput(f"noise: unknown noise model {noise!r}; expected one of {', '.join(NOISE_MODELS)}")
    return noise


def param_names(normals: bool = False, noise: str = "student") -> tuple[str, ...]:
    """Names of θ's entries for a likelihood with (or without) ``normals`` and the ``noise`` model.

    The 11 names of :data:`PARAM_NAMES`, then ``log_kappa`` (vMF concentration, with normals),
    ``log_eps`` (``noise="multiplicative"``) or ``w_outlier`` (``noise="mixture"``), in that order.
    """
    _check_noise(noise)
    extra = (("log_kappa",) if normals else ()) + {
        "student": (),
        "multiplicative": ("log_eps",),
        "mixture": ("w_outlier",),
    }[noise]
    return PARAM_NAMES + extra


class Bounds(NamedTuple):
    """Box of the uniform prior in θ space: ``lower``, ``upper`` (D,)."""

    lower: jnp.ndarray
    upper: jnp.ndarray


def bounds_for(points, priors: PriorParams, normals: bool = False, noise: str = "student") -> Bounds:
    """Prior box for data ``points (M, 3)`` m (the centre range is relative to the data's bounding box).

    Its length is that of :func:`param_names` ``(normals, noise)``.
    """
    p = np.asarray(points, float)
    lo, hi = p.min(axis=0), p.max(axis=0)
    span = np.maximum(hi - lo, priors.axis_min)
    c_lo, c_hi = lo - priors.centre_margin * span, hi + priors.centre_margin * span
    la = np.log([priors.axis_min, priors.axis_max])
    lower = [c_lo, [la[0]] * 3, [0.0, 0.0, -np.pi], [np.log(priors.n_min), np.log(priors.sigma_min)]]
    upper = [c_hi, [la[1]] * 3, [np.pi, np.pi, np.pi], [np.log(priors.n_max), np.log(priors.sigma_max)]]
    if normals:
        lower.append([np.log(priors.kappa_min)])
        upper.append([np.log(priors.kappa_max)])
    if _check_noise(noise) == "multiplicative":
        lower.append([np.log(priors.eps_min)])
        upper.append([np.log(priors.eps_max)])
    elif noise == "mixture":
        lower.append([0.0])
        upper.append([priors.outlier_max])
    return Bounds(jnp.asarray(np.concatenate(lower)), jnp.asarray(np.concatenate(upper)))


def shape_of(theta) -> ne.NEllipsoid:
    """The n-ellipsoid of a parameter vector θ (…, D ≥ 10)."""
    theta = jnp.asarray(theta)
    return ne.NEllipsoid(theta[..., 0:3], jnp.exp(theta[..., 3:6]), theta[..., 6:9], jnp.exp(theta[..., 9]))


def residuals(theta, points):
    """First-order signed distances (M,) m of ``points (M, 3)`` to the surface of θ (> 0 outside).

    The plain single-θ form (:func:`~bayestouch.geometry.nellipsoid.first_order_distance`); the likelihood
    uses the batched form of :func:`log_prob_batch`, equal to it to rounding.
    """
    s = shape_of(theta)
    y = (points - s.centre) @ s.rotation  # principal frame
    return ne.first_order_distance(s, y)[0]


class _Data(NamedTuple):
    """What the likelihood needs of the data, prepared once (JAX arrays)."""

    hom: jnp.ndarray  # (4, M): x, y, z, 1
    normals: jnp.ndarray | None  # (3, M) unit measured normals
    lever2: jnp.ndarray | None  # (3, M): (x_k − o_k)², m², for the multiplicative noise
    log_u: jnp.ndarray | None  # log of the outlier density 1/(2D), log(1/m)


def _prepare(points, normals=None, noise: str = "student", origin=None) -> _Data:
    p = jnp.asarray(points, dtype=jnp.float64)
    hom = jnp.concatenate([p.T, jnp.ones((1, p.shape[0]))], axis=0)
    nrm = None if normals is None else jnp.asarray(normals, dtype=jnp.float64).T
    lever2 = log_u = None
    if noise == "multiplicative":
        o = jnp.mean(p, axis=0) if origin is None else jnp.asarray(origin, dtype=jnp.float64)
        lever2 = ((p - o) ** 2).T
    elif noise == "mixture":
        diag = jnp.sqrt(jnp.sum((jnp.max(p, axis=0) - jnp.min(p, axis=0)) ** 2))
        log_u = -jnp.log(2.0 * jnp.maximum(diag, 1e-9))
    return _Data(hom, nrm, lever2, log_u)


class PrincipalFrame(NamedTuple):
    """Per-walker, per-point quantities of the scaled principal frame (:func:`principal_frame`)."""

    d: jax.Array  # (W, M) m, first-order distance
    q: jax.Array  # (W, 3, M) 1, scaled principal coordinates (x − c) R / a
    v: jax.Array  # (W, 3, M) 1/m, |q_j|^(n−1)/a_j (∂G/∂y_j = (G/S) sign(q_j) v_j)
    ss: jax.Array  # (W, M) 1/m², Σ_j v_j²
    R: jax.Array  # (W, 3, 3) rotation, columns = principal directions
    a: jax.Array  # (W, 3) m, semi-axes


def principal_frame(th, hom) -> PrincipalFrame:
    """The batched n-ellipsoid kernel: first-order distances of the homogeneous points ``hom (4, M)`` to the
    surfaces of walkers ``th (W, ≥ 10)`` and the intermediate values other terms reuse (:class:`PrincipalFrame`)."""
    a = jnp.exp(th[:, 3:6])
    n = jnp.exp(th[:, 9])[:, None]
    R = jax.vmap(rotation_matrix)(th[:, 6:9])  # (W, 3, 3), columns = principal directions
    Ra = R / a[:, None, :]
    # q = (x − c) R / a for all points at once: one (W, 3, 4) @ (4, M) product
    B = jnp.concatenate([jnp.swapaxes(Ra, 1, 2), -jnp.einsum("wk,wkj->wj", th[:, 0:3], Ra)[:, :, None]], axis=2)
    q = jnp.einsum("wjk,km->wjm", B, hom)
    aq = jnp.abs(q) + _TINY
    t = jnp.exp(n[:, :, None] * jnp.log(aq))  # |q_j|^n
    S = jnp.sum(t, axis=1) + _TINY
    v = t / (aq * a[:, :, None])  # |q_j|^(n−1)/a_j: ∂G/∂y_j = (G/S) sign(q_j) v_j
    ss = jnp.sum(v * v, axis=1)
    gi = jnp.exp(-jnp.log(S) / n)  # 1/G
    amax = jnp.max(a, axis=1)[:, None]
    # (G − 1)/|∇G| with |∇G| = (G/S)√ss floored at 1/max(a): written with one division
    d = (1.0 - gi) * S / jnp.maximum(jnp.sqrt(ss), S * gi / amax)
    return PrincipalFrame(d, q, v, ss, R, a)


def _geometry(th, hom, want_normals: bool):
    """Residuals (W, M) m of the homogeneous points ``hom (4, M)`` for walkers ``th (W, D)``, and the model's
    outward unit normals in the world frame (W, 3, M) when ``want_normals``."""
    f = principal_frame(th, hom)
    if not want_normals:
        return f.d, None
    g = jnp.einsum("wkj,wjm->wkm", f.R, jnp.sign(f.q) * f.v)
    return f.d, g / jnp.sqrt(jnp.sum(g * g, axis=1, keepdims=True) + _TINY)


def _student_const(nu: float) -> float:
    return float(gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * np.log(nu * np.pi))


def _log_lik_terms(th, data: _Data, noise: str, nu: float):
    """Log-likelihood of each observation (W, M): walkers ``th (W, D)``, the options' terms added per point."""
    want = data.normals is not None or noise == "multiplicative"
    d, nw = _geometry(th, data.hom, want)
    ls = th[:, 10][:, None]
    k = 11
    ll = 0.0
    if data.normals is not None:
        kappa = jnp.exp(th[:, k])[:, None]
        cos = jnp.sum(nw * data.normals[None], axis=1)
        ll = th[:, k][:, None] - _LOG_2PI - jnp.log1p(-jnp.exp(-2.0 * kappa)) + kappa * (cos - 1.0)
        k += 1
    if noise == "student":
        z2 = d * d * jnp.exp(-2.0 * ls)
        if np.isinf(nu):
            return ll - 0.5 * z2 - (ls + 0.5 * _LOG_2PI)
        return ll + (_student_const(nu) - ls) - 0.5 * (nu + 1) * jnp.log1p(z2 / nu)
    if noise == "multiplicative":
        eps2 = jnp.exp(2.0 * th[:, k])[:, None]
        var = jnp.exp(2.0 * ls) + eps2 / 3.0 * jnp.sum(nw * nw * data.lever2[None], axis=1)
        return ll - 0.5 * (d * d / var + jnp.log(var)) - 0.5 * _LOG_2PI
    w = th[:, k][:, None]
    log_n = -0.5 * d * d * jnp.exp(-2.0 * ls) - ls - 0.5 * _LOG_2PI
    log_w = jnp.log(jnp.maximum(w, _TINY))
    return ll + jnp.logaddexp(jnp.log1p(-w) + log_n, log_w + data.log_u)


def _log_lik_batch(th, data: _Data, noise: str, nu: float):
    return jnp.sum(_log_lik_terms(th, data, noise, nu), axis=1)


_F32 = jnp.float32
# floor of |q| in float32: |q|^(n−1)/(|q| a) stays below float32's overflow (a ≥ 1e-3 m gives ≤ 1e15, squared 1e30);
# it alters t = |q|^n only for points within 1e-12 axis lengths of the centre
_Q_FLOOR32 = 1e-12


def _log_lik_mixed(th, hom, nu: float):
    """Student-t (Gaussian for ν = inf) log-likelihood (W,) of walkers ``th (W, 11)``, mixed precision.

    The affine map q = (x − c) R / a is float64 (no cancellation reaches float32: q is cast once, relative
    error 6e-8 per point, independent between points); the per-point transcendentals are float32, written
    overflow-free (powers relative to the largest of the three, so any |q| and n of the prior stay finite);
    each point's term is cast to float64 before the sum over points.
    """
    a = jnp.exp(th[:, 3:6])
    n = jnp.exp(th[:, 9])
    ls = th[:, 10]
    R = jax.vmap(rotation_matrix)(th[:, 6:9])
    Ra = R / a[:, None, :]
    B = jnp.concatenate([jnp.swapaxes(Ra, 1, 2), -jnp.einsum("wk,wkj->wj", th[:, 0:3], Ra)[:, :, None]], axis=2)
    q = jnp.einsum("wjk,km->wjm", B, hom).astype(_F32)  # (W, 3, M), float64 product cast once
    n32 = n.astype(_F32)[:, None, None]
    aq = jnp.maximum(jnp.abs(q), _F32(_Q_FLOOR32))
    L = n32 * jnp.log(aq)  # log |q_j|^n
    Lm = jnp.max(L, axis=1, keepdims=True)
    tp = jnp.exp(L - Lm)  # |q_j|^n / max_j |q_j|^n ∈ (0, 1]
    Sp = jnp.sum(tp, axis=1)  # S / max_j |q_j|^n ∈ [1, 3]
    log_g = (Lm[:, 0] + jnp.log(Sp)) / n32[:, 0]  # log G
    one_m_gi = -jnp.expm1(-log_g)  # 1 − 1/G without cancellation
    u = tp / (Sp[:, None] * aq * a.astype(_F32)[:, :, None])  # |∂G/∂y_j| / G
    amax = jnp.max(a, axis=1).astype(_F32)[:, None]
    # (G − 1)/|∇G| = (1 − 1/G)/(|∇G|/G), |∇G| floored at 1/max(a) as in _geometry
    d = one_m_gi / jnp.maximum(jnp.sqrt(jnp.sum(u * u, axis=1)), (1.0 - one_m_gi) / amax)
    z = d * jnp.exp(-ls).astype(_F32)[:, None]
    m = hom.shape[1]
    if np.isinf(nu):
        return -0.5 * jnp.sum((z * z).astype(jnp.float64), axis=1) - m * (ls + 0.5 * _LOG_2PI)
    s = jnp.sum(jnp.log1p(z * z * _F32(1.0 / nu)).astype(jnp.float64), axis=1)
    return m * (_student_const(nu) - ls) - 0.5 * (nu + 1) * s


_log_lik_terms_jit = jax.jit(_log_lik_terms, static_argnums=(2, 3))


def pointwise_log_likelihood(
    thetas, points, nu: float = np.inf, *, normals=None, noise: str = "student", origin=None
) -> np.ndarray:
    """Log-likelihood of each contact point (W, M) for walkers ``thetas (W, D)`` (NumPy edge; the ArviZ
    ``log_likelihood`` group). Arguments as :func:`log_prob_batch`; the sum over points is the log-likelihood
    that :func:`make_log_prob` samples."""
    data = _prepare(points, normals, _check_noise(noise), origin)
    return np.asarray(_log_lik_terms_jit(jnp.asarray(thetas, dtype=jnp.float64), data, noise, float(nu)))


def log_prior(theta, bounds: Bounds):
    """0 inside the prior box (uniform in θ: log-uniform axes, n, σ, ε, κ), −inf outside; θ (…, D)."""
    inside = jnp.all((theta >= bounds.lower) & (theta <= bounds.upper), axis=-1)
    return jnp.where(inside, 0.0, -jnp.inf)


def _log_prob_batch(thetas, data: _Data, bounds: Bounds, noise: str, nu: float, precision: str = "float64"):
    lp = log_prior(thetas, bounds)
    th = jnp.clip(thetas, bounds.lower, bounds.upper)
    ll = _log_lik_mixed(th, data.hom, nu) if precision == "mixed" else _log_lik_batch(th, data, noise, nu)
    out = jnp.where(jnp.isfinite(lp), lp + ll, -jnp.inf)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


# data passed as arguments (not closed over): one compiled program per (W, M, options), shared by every
# make_log_prob of the same sizes
_log_prob_jit = jax.jit(_log_prob_batch, static_argnums=(3, 4, 5))


def log_prob_batch(
    thetas, points, bounds: Bounds, nu: float = np.inf, *, normals=None, noise: str = "student", origin=None
):
    """Log-posterior (unnormalised) of a batch of walkers, pure JAX.

    Parameters
    ----------
    thetas : (W, D) float
        Parameter vectors in the layout of :func:`param_names` ``(normals is not None, noise)``.
    points : (M, 3) float, metres
    bounds : Bounds
        From :func:`bounds_for` with the same options.
    nu : float
        Student-t degrees of freedom (``noise="student"``; inf is Gaussian).
    normals : (M, 3) float, optional
        Measured unit outward normals.
    noise : {"student", "multiplicative", "mixture"}
    origin : (3,) float, metres, optional
        Centre of the multiplicative perturbation (default: the data centroid, as :func:`bayestouch.paper.perturb`).

    Returns
    -------
    (W,) float
        −inf outside the prior, never NaN.
    """
    data = _prepare(points, normals, _check_noise(noise), origin)
    return _log_prob_batch(jnp.asarray(thetas), data, bounds, noise, float(nu))


def log_likelihood(theta, points, nu: float):
    """Σ log Student-t(r/σ; ν) − M log σ (Gaussian for ν = inf) for one θ (11,)."""
    return _log_lik_batch(jnp.asarray(theta)[None], _prepare(points), "student", float(nu))[0]


def log_prob(theta, points, bounds: Bounds, nu: float, *, normals=None, noise: str = "student", origin=None):
    """Log-posterior (unnormalised) of one θ (D,): −inf outside the prior, never NaN; differentiable inside.

    The one-walker case of :func:`log_prob_batch` (same arguments).
    """
    return log_prob_batch(jnp.asarray(theta)[None], points, bounds, nu, normals=normals, noise=noise, origin=origin)[0]


def _check_points(points, normals):
    p = np.asarray(points, dtype=float) if np.ndim(points) else np.empty((0,))
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 1 or not np.all(np.isfinite(p)):
        raise BadInput(f"points: expected a finite (M ≥ 1, 3) array in metres, got shape {p.shape}")
    if normals is None:
        return p, None
    nrm = np.asarray(normals, dtype=float)
    if nrm.shape != p.shape or not np.all(np.isfinite(nrm)):
        raise BadInput(f"normals: expected a finite ({len(p)}, 3) array like the points, got shape {nrm.shape}")
    length = np.linalg.norm(nrm, axis=1, keepdims=True)
    if np.any(length < 1e-12):
        raise BadInput("normals: every normal needs a non-zero length (unit outward normals nx, ny, nz)")
    return p, nrm / length


def make_log_prob(
    points,
    priors: PriorParams | None = None,
    nu: float | None = None,
    *,
    normals=None,
    noise: str = "student",
    origin=None,
    precision: str = "float64",
):
    """A jitted, walker-vectorised log-probability ``f(thetas (W, D)) → (W,)`` for ``emcee(vectorize=True)``.

    Parameters
    ----------
    points : (M, 3) float, metres
    priors : PriorParams, optional
        Default :func:`load_priors`.
    nu : float, optional
        Student-t degrees of freedom for ``noise="student"`` (default ``priors.student_nu``; inf is Gaussian).
    normals : (M, 3) float, optional
        Measured outward normals (normalised here); adds the vMF term and ``log_kappa``.
    noise : {"student", "multiplicative", "mixture"}
    origin : (3,) float, metres, optional
        Centre of the multiplicative perturbation (default the data centroid).
    precision : {"float64", "mixed"}
        ``"mixed"``: float32 per-point transcendentals, float64 affine map and sum (``noise="student"`` without
        normals only; about 1.5x faster, log-probability error ~1e-7·(a/σ)·√M nats, see ``docs/contact_model.md``).

    Returns
    -------
    f : callable
        NumPy in, NumPy out; D = ``len(param_names(normals is not None, noise))`` (11 by default).
    bounds : Bounds
    """
    _check_noise(noise)
    if precision not in ("float64", "mixed"):
        raise BadInput(f"precision: expected 'float64' or 'mixed', got {precision!r}")
    if precision == "mixed" and (noise != "student" or normals is not None):
        raise BadInput("precision: 'mixed' is implemented for noise='student' without normals; use 'float64'")
    if nu is not None and noise != "student":
        raise BadInput(f"nu: applies to noise='student' only, got nu={nu} with noise={noise!r}")
    p, nrm = _check_points(points, normals)
    priors = priors or load_priors()
    nu = float(priors.student_nu if nu is None else nu)
    if not nu > 0:
        raise BadInput(f"nu: Student-t degrees of freedom must be > 0 (inf for Gaussian), got {nu}")
    data = _prepare(p, nrm, noise, origin)
    bounds = bounds_for(p, priors, nrm is not None, noise)
    dim = len(bounds.lower)

    def f(thetas):
        th = np.asarray(thetas, dtype=np.float64)
        if th.ndim == 1:
            th = th[None]
        if th.ndim != 2 or th.shape[1] != dim:
            raise BadInput(f"thetas: expected a (W, {dim}) array of parameter vectors, got shape {th.shape}")
        return np.asarray(_log_prob_jit(th, data, bounds, noise, nu, precision))

    return f, bounds
