"""Contact-level model: probed contact points (M, 3) m against the n-ellipsoid surface. θ (W, 11) or more per
walker: centre m, log semi-axes log m, Euler angles rad, log n, log σ (m, the contact noise scale), then the
options' parameters in the order of :func:`param_names`; residuals are first-order distances (m) to the surface.
Priors, the batched log-probability (float64, or mixed precision) and the pointwise log-likelihood. The model, its
noise models, normals and precision: ``docs/contact_model.md``.
"""

from __future__ import annotations

import os
from typing import NamedTuple

import numpy as np
from jax.scipy.special import log_ndtr, ndtr
from scipy.special import gammaln
from scipy.stats import truncnorm

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput, shown
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.rotation import rotation_matrix
from bayestouch.params import MODELS, Spec, build

__all__ = [
    "check_points",
    "check_free",
    "check_priors",
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
    "wrap_angles",
    "AXIS_COLUMNS",
    "to_sampling",
    "from_sampling",
    "sampling_log_prob",
    "clip_to_box",
    "walkers_inside",
    "angle_centres",
    "shift_angles",
    "angle_window",
    "ANGLE_PERIODS",
    "ANGLE_COLUMNS",
    "sample_prior",
    "size_prior",
    "with_size_prior",
    "log_prob",
    "log_prob_batch",
    "make_log_prob",
    "padded_size",
    "pointwise_log_likelihood",
    "outlier_log_density",
    "outlier_terms",
    "side_weight",
    "free_space_terms",
    "OUTLIER_SCALE",
    "principal_frame",
    "frame_normals",
    "PrincipalFrame",
]

#: the 11 parameters of the default layout (no normals, Student-t or Gaussian noise)
PARAM_NAMES = ("x_G", "y_G", "z_G", "log_a", "log_b", "log_c", "xi", "psi", "zeta", "log_n", "log_sigma")

#: the noise models of the likelihood (``docs/contact_model.md``); ``"outlier"`` is the default of a fit
NOISE_MODELS = ("student", "multiplicative", "mixture", "outlier")

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
    "size_min": Spec("m", 1e-4, 10.0),
    "size_max": Spec("m", 1e-4, 10.0),
    "free_miss": Spec("1", 1e-9, 0.5),
    "outlier_scale": Spec("m", 1e-6, 1.0),
}

_TINY = 1e-300
#: default scale (m) of the outlier model's half-Cauchy displacement: ``models/priors.toml`` outlier_scale
OUTLIER_SCALE = 5e-3
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
    size_min: float
    size_max: float
    free_miss: float
    outlier_scale: float


def load_priors(path=None) -> PriorParams:
    """Read ``[priors]`` of ``models/priors.toml`` (or ``path``)."""
    p = build(PriorParams, MODELS / "priors.toml" if path is None else path, "priors", PRIOR_SPECS)
    return with_size_prior(p, p.size_min, p.size_max)


def with_size_prior(priors: PriorParams, size_min: float, size_max: float) -> PriorParams:
    """``priors`` with the size prior "objects ``size_min``–``size_max`` across" (metres).

    The full length 2a of each principal axis is log-normal with its central 95 % interval [size_min, size_max]
    (:func:`size_prior`); the interval must lie inside the box [2 axis_min, 2 axis_max].

    Raises
    ------
    BadInput
        ``size_min`` ≥ ``size_max``, or the interval outside the box.
    """
    lo, hi = float(size_min), float(size_max)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise BadInput(f"size prior: expected 0 < min < max metres (e.g. 0.01:0.1 for objects 1-10 cm), got {lo}:{hi}")
    if lo < 2 * priors.axis_min or hi > 2 * priors.axis_max:
        raise BadInput(
            f"size prior: {lo:g}:{hi:g} m must lie within the prior box of object sizes "
            f"{2 * priors.axis_min:g}:{2 * priors.axis_max:g} m (models/priors.toml axis_min, axis_max)"
        )
    return priors._replace(size_min=lo, size_max=hi)


def size_prior(priors: PriorParams) -> tuple[float, float]:
    """Mean and sd of the normal prior on each log semi-axis (log m): the central 95 % of 2a is
    [size_min, size_max]."""
    mu = 0.5 * (np.log(priors.size_min) + np.log(priors.size_max)) - np.log(2.0)
    return float(mu), float((np.log(priors.size_max) - np.log(priors.size_min)) / (2 * 1.959963984540054))


def _check_noise(noise: str) -> str:
    if noise not in NOISE_MODELS:
        raise BadInput(f"noise: unknown noise model {noise!r}; expected one of {', '.join(NOISE_MODELS)}")
    return noise


def param_names(normals: bool = False, noise: str = "student") -> tuple[str, ...]:
    """Names of θ's entries for a likelihood with (or without) ``normals`` and the ``noise`` model.

    The 11 names of :data:`PARAM_NAMES`, then ``log_kappa`` (vMF concentration, with normals),
    ``log_eps`` (``noise="multiplicative"``), ``w_outlier`` (``noise="mixture"``) or ``w_in, w_out``
    (``noise="outlier"``: the fractions of contacts displaced into the solid and out into free space), in that order.
    """
    _check_noise(noise)
    extra = (("log_kappa",) if normals else ()) + {
        "student": (),
        "multiplicative": ("log_eps",),
        "mixture": ("w_outlier",),
        "outlier": ("w_in", "w_out"),
    }[noise]
    return PARAM_NAMES + extra


class Bounds(NamedTuple):
    """The prior in θ space: the box ``lower``, ``upper`` (D,) and the density inside it.

    Inside the box the log-density is Σ_j −½((log a_j − size_mu)/size_sd)² (the size prior; flat for the default
    ``size_sd = inf``) + log |sin ξ| (Haar measure on rotations in the z-x-z Euler angles ξ, ψ, ζ), up to a constant.

    The Euler angles are periodic, not boxed: their box ξ ∈ [0, π], ψ ∈ [0, π), ζ ∈ [−π, π) is one fundamental
    domain of the surfaces' rotations (:func:`wrap_angles` maps any angles into it), and the density is the same at
    every alias of a surface. A box edge there would be a wall a sampler cannot cross although the surface on its
    other side is a continuation of the one on this side (a mode with ψ near 0 cut from its half near π), so the
    sampled θ moves freely through the angles and the summaries canonicalise. The semi-axes are not ordered for
    the same reason: at a = b the frame with the two axes swapped (ψ + π/2) is the same surface, and a ≥ b would be
    a wall through any mode whose two longest axes are not resolved by the data.
    """

    lower: jnp.ndarray
    upper: jnp.ndarray
    size_mu: float = 0.0
    size_sd: float = float("inf")


def bounds_for(points, priors: PriorParams, normals: bool = False, noise: str = "student") -> Bounds:
    """The prior for data ``points (M, 3)`` m: the box (the centre range is the data's bounding box grown by
    ``centre_margin`` times its largest span on every side) and the size prior of ``priors`` (:func:`size_prior`).

    Its length is that of :func:`param_names` ``(normals, noise)``.
    """
    p = np.asarray(points, float)
    lo, hi = p.min(axis=0), p.max(axis=0)
    # grown by the largest span in every direction: data from one side of an object can be thin along the
    # direction in which its centre lies beyond them
    span = max(float(np.max(hi - lo)), priors.axis_min)
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
    elif noise == "outlier":
        lower.append([0.0, 0.0])
        upper.append([0.5 * priors.outlier_max] * 2)
    mu, sd = size_prior(priors)
    return Bounds(jnp.asarray(np.concatenate(lower)), jnp.asarray(np.concatenate(upper)), mu, sd)


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
    """What the likelihood needs of the data, prepared once (JAX arrays). Free-space points (finger positions
    that touched nothing) follow the M contacts in ``hom``; ``free`` marks them."""

    hom: jnp.ndarray  # (4, M + K): x, y, z, 1
    normals: jnp.ndarray | None  # (3, M + K) unit measured normals (zeros on free-space rows)
    lever2: jnp.ndarray | None  # (3, M + K): (x_k − o_k)², m², for the multiplicative noise
    log_u: (
        jnp.ndarray | None
    )  # log outlier density: 1/(2D) ("mixture"); 2/(π s) at 0 ("outlier", half-Cauchy); log(1/m)
    free: jnp.ndarray | None  # (M + K,) 1 on free-space rows, 0 on contacts; None without free-space points
    log_miss: float = -np.inf  # log of the probability that a free-space point is mislabelled (priors free_miss)
    use: jnp.ndarray | None = None  # (M + K + P,) 1 on data, 0 on the P padding columns; None without padding
    out_inv: float = 0.0  # 1/s, 1/m: the half-Cauchy outlier displacement's inverse scale ("outlier")


def padded_size(count: int) -> int:
    """The number of columns ``count`` data points are padded to (:func:`make_log_prob`): the next of the sizes
    2^(j/4), rounded up to a multiple of 8 — at most 19 % padding, and data sets of similar sizes share one
    compiled log-density (in memory and in JAX's persistent compilation cache)."""
    if count <= 8:
        return 8
    size = 2.0 ** (np.ceil(4.0 * np.log2(count) - 1e-9) / 4.0)
    return int(8 * np.ceil(size / 8 - 1e-9))


def _prepare(
    points,
    normals=None,
    noise: str = "student",
    origin=None,
    free=None,
    free_miss: float = 1e-3,
    pad: bool = False,
    outlier_scale: float = OUTLIER_SCALE,
) -> _Data:
    # NumPy for concrete data, put on the device once at the end: eager jnp operations compile a small program for
    # every new data length (dozens per fit, ~30 ms each); traced data (inside a jitted caller) stay jnp
    traced = any(isinstance(a, jax.core.Tracer) for a in (points, normals, origin, free))
    xp = jnp if traced else np
    p = xp.asarray(points, dtype=xp.float64)
    m = p.shape[0]
    k = 0 if free is None else len(free)
    allp = p if k == 0 else xp.concatenate([p, xp.asarray(free, dtype=xp.float64)], axis=0)
    extra = padded_size(m + k) - (m + k) if pad else 0
    use = None
    if extra:  # copies of the first contact, masked out of every sum (finite terms and gradients, as the data's)
        allp = xp.concatenate([allp, xp.repeat(p[:1], extra, axis=0)], axis=0)
        use = xp.concatenate([xp.ones(m + k), xp.zeros(extra)])
    hom = xp.concatenate([allp.T, xp.ones((1, m + k + extra))], axis=0)
    nrm = None
    if normals is not None:
        nrm = xp.concatenate([xp.asarray(normals, dtype=xp.float64).T, xp.zeros((3, k + extra))], axis=1)
    lever2 = log_u = None
    out_inv = 0.0
    if noise == "multiplicative":
        o = xp.mean(p, axis=0) if origin is None else xp.asarray(origin, dtype=xp.float64)
        lever2 = ((allp - o) ** 2).T
    elif noise == "mixture":
        diag = xp.sqrt(xp.sum((xp.max(p, axis=0) - xp.min(p, axis=0)) ** 2))
        log_u = -xp.log(2.0 * xp.maximum(diag, 1e-9))
    elif noise == "outlier":
        if not (np.isfinite(outlier_scale) and outlier_scale > 0):
            raise BadInput(f"outlier_scale: expected a positive length in metres, got {outlier_scale!r}")
        log_u = xp.asarray(np.log(2.0 / (np.pi * outlier_scale)))
        out_inv = 1.0 / float(outlier_scale)
    mask = None if k == 0 else xp.concatenate([xp.zeros(m), xp.ones(k), xp.zeros(extra)])
    if not traced:
        hom, nrm, lever2, log_u, mask, use = (
            None if a is None else jax.device_put(np.asarray(a, dtype=np.float64))
            for a in (hom, nrm, lever2, log_u, mask, use)
        )
    return _Data(hom, nrm, lever2, log_u, mask, float(np.log(free_miss)), use, out_inv)


class PrincipalFrame(NamedTuple):
    """Per-walker, per-point quantities of the scaled principal frame (:func:`principal_frame`)."""

    d: jax.Array  # (W, M) m, first-order distance
    q: jax.Array  # (W, 3, M) 1, scaled principal coordinates (x − c) R / a
    v: jax.Array  # (W, 3, M) 1/m, |q_j|^(n−1)/a_j (∂G/∂y_j = (G/S) sign(q_j) v_j)
    ss: jax.Array  # (W, M) 1/m², Σ_j v_j²
    R: jax.Array  # (W, 3, 3) rotation, columns = principal directions
    a: jax.Array  # (W, 3) m, semi-axes


def principal_frame(th, hom) -> PrincipalFrame:
    """The batched n-ellipsoid kernel: first-order distances of the homogeneous points ``hom (4, M)`` (or one set
    per walker, ``(W, 4, M)``) to the surfaces of walkers ``th (W, ≥ 10)`` and the intermediate values other terms
    reuse (:class:`PrincipalFrame`)."""
    a = jnp.exp(th[:, 3:6])
    n = jnp.exp(th[:, 9])[:, None]
    R = jax.vmap(rotation_matrix)(th[:, 6:9])  # (W, 3, 3), columns = principal directions
    Ra = R / a[:, None, :]
    # q = (x − c) R / a for all points at once: one (W, 3, 4) @ (4, M) product
    B = jnp.concatenate([jnp.swapaxes(Ra, 1, 2), -jnp.einsum("wk,wkj->wj", th[:, 0:3], Ra)[:, :, None]], axis=2)
    q = jnp.einsum("wjk,km->wjm", B, hom) if hom.ndim == 2 else jnp.einsum("wjk,wkm->wjm", B, hom)
    aq = jnp.abs(q) + _TINY
    t = jnp.exp(n[:, :, None] * jnp.log(aq))  # |q_j|^n
    S = jnp.sum(t, axis=1) + _TINY
    v = t / (aq * a[:, :, None])  # |q_j|^(n−1)/a_j: ∂G/∂y_j = (G/S) sign(q_j) v_j
    ss = jnp.sum(v * v, axis=1)
    gi = jnp.exp(-jnp.log(S) / n)  # 1/G
    rmax = jnp.sqrt(jnp.sum(a * a, axis=1))[:, None]
    # (G − 1)/|∇G| with |∇G| = (G/S)√ss floored at 1/|a| (first_order_distance: never active off the centre),
    # written with one division
    d = (1.0 - gi) * S / jnp.maximum(jnp.sqrt(ss), S * gi / rmax)
    return PrincipalFrame(d, q, v, ss, R, a)


def frame_normals(f: PrincipalFrame):
    """The model surface's outward unit normals (W, 3, M) in the world frame at the points of a
    :func:`principal_frame` (the gradient of G, normalised)."""
    g = jnp.einsum("wkj,wjm->wkm", f.R, jnp.sign(f.q) * f.v)
    return g / jnp.sqrt(jnp.sum(g * g, axis=1, keepdims=True) + _TINY)


def _geometry(th, hom, want_normals: bool):
    """Residuals (W, M) m of the homogeneous points ``hom (4, M)`` for walkers ``th (W, D)``, and the model's
    outward unit normals in the world frame (W, 3, M) when ``want_normals``."""
    f = principal_frame(th, hom)
    return f.d, frame_normals(f) if want_normals else None


def _student_const(nu: float) -> float:
    return float(gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * np.log(nu * np.pi))


def outlier_log_density(d, log_u, inv_scale):
    """Log-density (1/m) of a displaced contact at signed distance ``d`` (m) on its side of the surface:
    half-Cauchy of scale s, log(2/(π s)) − log(1 + (d/s)²), with ``log_u`` = log(2/(π s)) and ``inv_scale`` = 1/s
    (any float dtype). Heavy-tailed, so a contact displaced centimetres is still an outlier rather than a reason
    to move the surface; its scale (``models/priors.toml`` outlier_scale) puts the mass at the millimetres by which
    real contacts are displaced, where a density uniform over the data's extent was ~10× too thin and let a
    wrong surface through a few displaced contacts win."""
    x = d * inv_scale
    return log_u - jnp.log1p(x * x)


def side_weight(z, w_in, w_out):
    """The outlier fraction on a contact's side of the surface at z = d/σ (any float dtype): w_in inside, w_out
    outside, switching smoothly across the surface as w_in + (w_out − w_in) Φ(z).

    Within a few σ of the surface the Gaussian core outweighs the outliers' density by far, so the switch's width
    changes the likelihood negligibly; a jump (w_in for d < 0, w_out for d > 0) made it discontinuous in θ wherever
    a contact lies on the surface, and L-BFGS and HMC stopped at those kinks (``docs/contact_model.md``)."""
    return w_in + (w_out - w_in) * ndtr(z)


def outlier_terms(d, ls, w_in, w_out, log_u, inv_scale):
    """Per-point log-likelihood of the two-sided outlier model (any float dtype): Gaussian core of sd e^ls, and
    contacts displaced into the solid (d < 0, fraction w_in) or out into free space (d > 0, fraction w_out), each
    half-Cauchy on its side (:func:`outlier_log_density`), the fraction switching across the surface as
    :func:`side_weight`."""
    log_core = -0.5 * d * d * jnp.exp(-2.0 * ls) - ls - 0.5 * _LOG_2PI
    log_w = jnp.log(jnp.maximum(side_weight(d * jnp.exp(-ls), w_in, w_out), _TINY_W))
    return jnp.logaddexp(jnp.log1p(-(w_in + w_out)) + log_core, log_w + outlier_log_density(d, log_u, inv_scale))


def free_space_terms(d, ls, log_miss):
    """Log-probability that a finger position with first-order distance ``d`` (m) lies outside the object:
    Φ(d/σ), floored by the probability ``e^log_miss`` that the position is mislabelled."""
    return jnp.logaddexp(log_miss, jnp.log1p(-jnp.exp(log_miss)) + log_ndtr(d * jnp.exp(-ls)))


_TINY_W = 1e-30


def _log_lik_terms(th, data: _Data, noise: str, nu: float):
    """Log-likelihood of each observation (W, M + K): walkers ``th (W, D)``, the options' terms added per point;
    free-space rows (``data.free``) carry the free-space term instead."""
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
            out = ll - 0.5 * z2 - (ls + 0.5 * _LOG_2PI)
        else:
            out = ll + (_student_const(nu) - ls) - 0.5 * (nu + 1) * jnp.log1p(z2 / nu)
    elif noise == "multiplicative":
        eps2 = jnp.exp(2.0 * th[:, k])[:, None]
        var = jnp.exp(2.0 * ls) + eps2 / 3.0 * jnp.sum(nw * nw * data.lever2[None], axis=1)
        out = ll - 0.5 * (d * d / var + jnp.log(var)) - 0.5 * _LOG_2PI
    elif noise == "outlier":
        out = ll + outlier_terms(d, ls, th[:, k][:, None], th[:, k + 1][:, None], data.log_u, data.out_inv)
    else:
        w = th[:, k][:, None]
        log_n = -0.5 * d * d * jnp.exp(-2.0 * ls) - ls - 0.5 * _LOG_2PI
        log_w = jnp.log(jnp.maximum(w, _TINY))
        out = ll + jnp.logaddexp(jnp.log1p(-w) + log_n, log_w + data.log_u)
    if data.free is None:
        return out
    return jnp.where(data.free[None] > 0, free_space_terms(d, ls, data.log_miss), out)


def _log_lik_batch(th, data: _Data, noise: str, nu: float):
    terms = _log_lik_terms(th, data, noise, nu)
    if data.use is not None:
        terms = jnp.where(data.use[None] > 0, terms, 0.0)
    return jnp.sum(terms, axis=1)


_F32 = jnp.float32
# floor of |q| in float32: |q|^(n−1)/(|q| a) stays below float32's overflow (a ≥ 1e-3 m gives ≤ 1e15, squared 1e30);
# it alters t = |q|^n only for points within 1e-12 axis lengths of the centre
_Q_FLOOR32 = 1e-12


def _log_lik_mixed(th, data: _Data, noise: str, nu: float):
    """Student-t (Gaussian for ν = inf) or two-sided outlier log-likelihood (W,) of walkers ``th (W, D)``, free-space
    points included, mixed precision.

    The affine map q = (x − c) R / a is float64 (no cancellation reaches float32: q is cast once, relative
    error 6e-8 per point, independent between points); the per-point transcendentals are float32, written
    overflow-free (powers relative to the largest of the three, so any |q| and n of the prior stay finite);
    each point's term is cast to float64 before the sum over points.
    """
    hom = data.hom
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
    rmax = jnp.sqrt(jnp.sum(a * a, axis=1)).astype(_F32)[:, None]
    # (G − 1)/|∇G| = (1 − 1/G)/(|∇G|/G), |∇G| floored at 1/|a| as in _geometry
    d = one_m_gi / jnp.maximum(jnp.sqrt(jnp.sum(u * u, axis=1)), (1.0 - one_m_gi) / rmax)
    # per-walker constants stay float64, added once per contact after the sum (a float32 −log σ per point would
    # bias the sum by ~M · 6e-8 · |log σ|)
    z = d * jnp.exp(-ls).astype(_F32)[:, None]
    if noise == "outlier":
        c = -(ls + 0.5 * _LOG_2PI)  # (W,) float64
        w_in, w_out = th[:, 11].astype(_F32)[:, None], th[:, 12].astype(_F32)[:, None]
        log_w = jnp.log(jnp.maximum(side_weight(z, w_in, w_out), _F32(_TINY_W)))
        log_o = outlier_log_density(d, (data.log_u - c).astype(_F32)[:, None], _F32(data.out_inv))
        rel = jnp.logaddexp(jnp.log1p(-(w_in + w_out)) - 0.5 * z * z, log_w + log_o)
    elif np.isinf(nu):
        c = -(ls + 0.5 * _LOG_2PI)
        rel = -0.5 * z * z
    else:
        c = _student_const(nu) - ls
        rel = _F32(-0.5 * (nu + 1)) * jnp.log1p(z * z * _F32(1.0 / nu))
    if data.free is None and data.use is None:
        return jnp.sum(rel.astype(jnp.float64), axis=1) + hom.shape[1] * c
    use = jnp.ones(hom.shape[1]) if data.use is None else data.use
    free = jnp.zeros(hom.shape[1]) if data.free is None else data.free
    contact = (1.0 - free) * use  # 1 on the contacts, 0 on free-space and padding columns
    contacts = jnp.sum(jnp.where(contact[None] > 0, rel, _F32(0)).astype(jnp.float64), axis=1) + jnp.sum(contact) * c
    if data.free is None:
        return contacts
    is_free = (free * use)[None] > 0
    ft = free_space_terms(d, ls.astype(_F32)[:, None], _F32(data.log_miss))
    return contacts + jnp.sum(jnp.where(is_free, ft, _F32(0)).astype(jnp.float64), axis=1)


_log_lik_terms_jit = jax.jit(_log_lik_terms, static_argnums=(2, 3))


def pointwise_log_likelihood(
    thetas,
    points,
    nu: float = np.inf,
    *,
    normals=None,
    noise: str = "student",
    origin=None,
    free=None,
    free_miss: float = 1e-3,
    outlier_scale: float = OUTLIER_SCALE,
) -> np.ndarray:
    """Log-likelihood of each observation (W, M + K) for walkers ``thetas (W, D)``: the M contact points, then the
    K free-space points (NumPy edge; the ArviZ ``log_likelihood`` group). Arguments as :func:`log_prob_batch`;
    the sum over observations is the log-likelihood that :func:`make_log_prob` samples."""
    fr = _free_or_none(free)
    data = _prepare(points, normals, _check_noise(noise), origin, fr, free_miss, pad=True, outlier_scale=outlier_scale)
    count = len(points) + (0 if fr is None else len(fr))  # the padding columns (copies of a contact) cut off
    return np.asarray(_log_lik_terms_jit(jnp.asarray(thetas, dtype=jnp.float64), data, noise, float(nu)))[:, :count]


#: the Euler angles' columns of θ (periodic: no box, :func:`wrap_angles`)
ANGLE_COLUMNS = (6, 7, 8)
_ANGLE_MASK = np.isin(np.arange(32), ANGLE_COLUMNS)  # long enough for any parameter set


#: the columns of θ holding the log semi-axes (log m), which the contact fit's emcee stage moves in metres
AXIS_COLUMNS = (3, 4, 5)


def to_sampling(theta) -> np.ndarray:
    """θ (..., D) in the coordinates the contact fit's emcee stage moves: the semi-axes (:data:`AXIS_COLUMNS`) in
    metres instead of log metres, every other column as it is.

    Why: contacts on one side of an object bound an unseen semi-axis on that side only, and the centre and that axis
    then trade along the line x_G − a e = (the touched side), e the axis's direction. In metres the ridge is straight,
    which the affine-invariant moves and the t-mixture proposals follow; in log metres it is curved, and the chain
    crawled along it (``docs/contact_model.md``, "Sampling coordinates")."""
    u = np.array(theta, dtype=float)
    u[..., AXIS_COLUMNS] = np.exp(u[..., AXIS_COLUMNS])
    return u


def from_sampling(u) -> np.ndarray:
    """θ (..., D) from the sampling coordinates of :func:`to_sampling` (semi-axes in metres, > 0)."""
    theta = np.array(u, dtype=float)
    theta[..., AXIS_COLUMNS] = np.log(theta[..., AXIS_COLUMNS])
    return theta


def sampling_log_prob(logp):
    """The log-density in :func:`to_sampling`'s coordinates of a log-posterior ``logp`` over θ ((W, D) → (W,)):
    log p(θ(u)) + log|dθ/du| = log p(θ) − Σ log(semi-axis), −∞ where a semi-axis is not positive. The posterior is
    the same; only the coordinates the sampler moves in change, so θ-space draws follow by :func:`from_sampling` and
    their log-posterior by adding back Σ log(semi-axis)."""

    def logp_u(u):
        u = np.asarray(u, dtype=float)
        ok = np.all(u[:, AXIS_COLUMNS] > 0, axis=1)
        theta = from_sampling(np.where(ok[:, None], u, 1.0))
        with np.errstate(invalid="ignore"):
            lp = np.asarray(logp(theta), dtype=float) - np.sum(theta[:, AXIS_COLUMNS], axis=1)
        return np.where(ok, lp, -np.inf)

    return logp_u


def wrap_angles(theta) -> np.ndarray:
    """θ (…, D) with its Euler angles mapped into the box ξ ∈ [0, π], ψ ∈ [0, π), ζ ∈ [−π, π): the same surface.

    R = R(z, ζ) R(x, ξ) R(z, ψ); R(x, −ξ) = R(z, π) R(x, ξ) R(z, π), so (ξ, ψ, ζ) ≡ (−ξ, ψ + π, ζ + π); and the
    n-ellipsoid is symmetric under R(z, π) in its own frame, so ψ ≡ ψ + π.
    """
    th = np.array(theta, dtype=float, copy=True)
    xi = np.mod(th[..., 6], 2 * np.pi)
    flip = xi > np.pi
    th[..., 6] = np.where(flip, 2 * np.pi - xi, xi)
    th[..., 7] = np.mod(th[..., 7], np.pi)
    th[..., 8] = np.mod(th[..., 8] + np.where(flip, np.pi, 0.0) + np.pi, 2 * np.pi) - np.pi
    return th


def log_prior(theta, bounds: Bounds):
    """Log prior density of θ (…, D), up to a constant: −inf outside the box (the Euler angles are periodic and
    never outside it); inside, the size prior on the log semi-axes and the Haar measure on rotations (log |sin ξ|)
    of :class:`Bounds`, uniform in every other coordinate (log n, log σ, log ε, log κ, outlier fractions)."""
    boxed = (theta >= bounds.lower) & (theta <= bounds.upper)
    inside = jnp.all(jnp.where(_ANGLE_MASK[: theta.shape[-1]], True, boxed), axis=-1)
    z = (theta[..., 3:6] - bounds.size_mu) / bounds.size_sd
    dens = -0.5 * jnp.sum(z * z, axis=-1) + jnp.log(jnp.maximum(jnp.abs(jnp.sin(theta[..., 6])), 1e-300))
    return jnp.where(inside, dens, -jnp.inf)


def clip_to_box(theta, bounds: Bounds):
    """θ (…, D) clipped into the prior box except in its Euler angles, which are periodic and pass unchanged (the
    likelihood is periodic in them; clipping them would give every angle beyond the box the likelihood of the box
    edge, a plateau on which the posterior is improper)."""
    mask = _ANGLE_MASK[: theta.shape[-1]]
    return jnp.where(mask, theta, jnp.clip(theta, bounds.lower, bounds.upper))


#: periods of the Euler angles (ξ, ψ, ζ) as separate coordinates: the surface is the same after a whole turn of ξ or
#: ζ and after half a turn of ψ (the n-ellipsoid's symmetry under R(z, π) in its own frame; :func:`wrap_angles`)
ANGLE_PERIODS = (2 * np.pi, np.pi, 2 * np.pi)


def walkers_inside(theta, bounds: Bounds, margin: float = 1e-9) -> np.ndarray:
    """Walkers θ (W, D) made a sound warm start for a density whose box may have moved with new data (NumPy): moved
    just inside the box (``margin`` of its width from each edge) in every non-angle column; each Euler angle shifted
    by whole periods (:data:`ANGLE_PERIODS`, the same surface) to within half a period of the walkers' circular mean.

    The angles are neither clipped nor wrapped into the box: clipping put every walker beyond an edge at the same
    value (an ensemble near ξ = 0 with its walkers at ξ < 0 lost its spread in ξ), and wrapping splits an ensemble
    near a box edge between the two ends. Left alone they drift without bound (a periodic likelihood): one chain's
    ψ and ζ had walkers a million radians apart. Either way emcee refuses the start.

    Parameters
    ----------
    theta : (W, D) float
    bounds : Bounds
    margin : float
        Fraction of the box's width kept from each edge.

    Returns
    -------
    (W, D) float
    """
    th = np.array(theta, dtype=float, copy=True)
    lo, hi = np.asarray(bounds.lower, float), np.asarray(bounds.upper, float)
    box = ~_ANGLE_MASK[: th.shape[-1]]
    th[..., box] = np.clip(th[..., box], (lo + margin * (hi - lo))[box], (hi - margin * (hi - lo))[box])
    return shift_angles(th, angle_centres(th))


def angle_centres(theta, columns=ANGLE_COLUMNS, periods=ANGLE_PERIODS) -> np.ndarray:
    """The circular mean (A,) of each Euler angle over the rows of ``theta (W, D)``, each on its own period,
    radians, written as the value nearest the rows' median: a window around it (:func:`shift_angles`) leaves a
    compact cloud where it is, so proposals fitted to the cloud stay in it.

    ``columns`` (A,) and ``periods`` (A,) name the angles (default the contact level's ξ, ψ, ζ:
    :data:`ANGLE_COLUMNS`, :data:`ANGLE_PERIODS`; a K-part θ passes each part's)."""
    th = np.asarray(theta, dtype=float).reshape(-1, np.shape(theta)[-1])
    out = np.zeros(len(columns))
    for j, (col, period) in enumerate(zip(columns, periods, strict=True)):
        phase = np.exp(2j * np.pi * np.mod(th[:, col], period) / period)
        c = np.angle(np.mean(phase)) * period / (2 * np.pi)
        out[j] = c + period * np.round((np.median(th[:, col]) - c) / period)
    return out


def shift_angles(theta, centres, columns=ANGLE_COLUMNS, periods=ANGLE_PERIODS) -> np.ndarray:
    """θ (…, D) with each Euler angle shifted by whole periods into its window [c − P/2, c + P/2) around
    ``centres (A,)`` (radians; ``columns`` and ``periods`` as :func:`angle_centres`'s): the same surfaces."""
    th = np.array(theta, dtype=float, copy=True)
    for col, period, c in zip(columns, periods, np.asarray(centres, float), strict=True):
        th[..., col] = c + np.mod(th[..., col] - c + 0.5 * period, period) - 0.5 * period
    return th


def angle_window(logp, centres, columns=ANGLE_COLUMNS, periods=ANGLE_PERIODS):
    """``logp`` ((W, D) → (W,)) restricted to one period of each Euler angle: −∞ where an angle lies outside its
    window [c − P/2, c + P/2) around ``centres (A,)`` (radians; ``columns`` and ``periods`` as
    :func:`angle_centres`'s).

    The posterior is periodic in the angles, so each surface has exactly one θ in the windows and the restricted
    density is the same posterior over surfaces. Unrestricted, an ensemble sampler's chain is improper in them: a
    move that lands a walker a whole period away is accepted as readily as one that stays, differential-evolution
    steps between walkers a period apart are then periods long, and the mixture refitted to such draws proposes
    over many periods. In one 60-s fit of ``benchmarks/bench_sbc_users.py`` (seed 8) ψ's walkers spread over
    ±7·10⁵ rad after 20,000 steps, the acceptance fell to 1.4 % and τ rose to ~1,000 steps. Centre the windows on
    the starting ensemble (:func:`angle_centres`, the start shifted into them by :func:`shift_angles`), where the
    mass is, so the windows' edges lie half a period from it."""
    c = np.asarray(centres, float)
    lo = c - 0.5 * np.asarray(periods, float)
    hi = c + 0.5 * np.asarray(periods, float)
    cols = list(columns)

    def windowed(x):
        x = np.asarray(x, dtype=float)
        a = x[:, cols]
        inside = np.all((a >= lo) & (a < hi), axis=1)
        # every row evaluated (periodic, finite beyond the window): one batch shape, one compiled program
        return np.where(inside, np.asarray(logp(x), dtype=float), -np.inf)

    return windowed


def sample_prior(bounds: Bounds, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` independent draws (count, D) of :func:`log_prior`: uniform in the box, log semi-axes normal
    (truncated to the box) and ξ from the Haar measure (cos ξ uniform).

    Parameters
    ----------
    bounds : Bounds
    count : int
    rng : np.random.Generator

    Returns
    -------
    (count, D) float
    """
    lo, hi = np.asarray(bounds.lower, float), np.asarray(bounds.upper, float)
    x = lo + (hi - lo) * rng.random((count, lo.size))
    if np.isfinite(bounds.size_sd):
        mu, sd = float(bounds.size_mu), float(bounds.size_sd)
        a, b = (lo[3:6] - mu) / sd, (hi[3:6] - mu) / sd
        x[:, 3:6] = truncnorm.rvs(a, b, loc=mu, scale=sd, size=(count, 3), random_state=rng)
    c_lo, c_hi = np.cos(hi[6]), np.cos(lo[6])
    x[:, 6] = np.arccos(np.clip(c_lo + (c_hi - c_lo) * rng.random(count), -1.0, 1.0))
    return np.clip(x, lo, hi)


def _free_or_none(free):
    if free is None:
        return None
    f = np.asarray(free, dtype=float).reshape(-1, 3)
    return f if len(f) else None


def _log_prob_batch(thetas, data: _Data, bounds: Bounds, noise: str, nu: float, precision: str = "float64"):
    lp = log_prior(thetas, bounds)
    th = clip_to_box(thetas, bounds)
    ll = _log_lik_mixed(th, data, noise, nu) if precision == "mixed" else _log_lik_batch(th, data, noise, nu)
    out = jnp.where(jnp.isfinite(lp), lp + ll, -jnp.inf)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


def _tempering_parts(thetas, data: _Data, bounds: Bounds, noise: str, nu: float, precision: str):
    """Log-prior and log-likelihood (W,) each, and their gradients (W, D); non-finite values count 0 in the
    gradients (a walker outside the box has log-prior −inf and zero gradient)."""

    def prior_sum(t):
        lp = log_prior(t, bounds)
        return jnp.sum(jnp.where(jnp.isfinite(lp), lp, 0.0)), lp

    def lik_sum(t):
        th = clip_to_box(t, bounds)
        ll = _log_lik_mixed(th, data, noise, nu) if precision == "mixed" else _log_lik_batch(th, data, noise, nu)
        ll = jnp.where(jnp.isnan(ll), -jnp.inf, ll)
        return jnp.sum(jnp.where(jnp.isfinite(ll), ll, 0.0)), ll

    (_, lp), g_lp = jax.value_and_grad(prior_sum, has_aux=True)(thetas)
    (_, ll), g_ll = jax.value_and_grad(lik_sum, has_aux=True)(thetas)
    return lp, ll, g_lp, g_ll


#: rows per block of the tempering terms and gradients: the SMC's 2048 particles in one program took 27.7 ms per
#: call here, in two 1024-row blocks 12 ms (the value-only program scales linearly; the gradient's does not)
TEMPERING_BLOCK = 1024


def _tempering_blocked(thetas, data: _Data, bounds: Bounds, noise: str, nu: float, precision: str):
    """:func:`_tempering_parts` over blocks of :data:`TEMPERING_BLOCK` rows (``lax.map``) when the rows divide
    into them; the same numbers."""
    w = thetas.shape[0]
    if w <= TEMPERING_BLOCK or w % TEMPERING_BLOCK:
        return _tempering_parts(thetas, data, bounds, noise, nu, precision)
    out = jax.lax.map(
        lambda t: _tempering_parts(t, data, bounds, noise, nu, precision),
        thetas.reshape(-1, TEMPERING_BLOCK, thetas.shape[-1]),
    )
    return tuple(o.reshape(w, *o.shape[2:]) for o in out)


_tempering_jit = jax.jit(_tempering_blocked, static_argnums=(3, 4, 5))


# data passed as arguments (not closed over): one compiled program per (W, M, options), shared by every
# make_log_prob of the same sizes
_log_prob_jit = jax.jit(_log_prob_batch, static_argnums=(3, 4, 5))


def log_prob_batch(
    thetas,
    points,
    bounds: Bounds,
    nu: float = np.inf,
    *,
    normals=None,
    noise: str = "student",
    origin=None,
    free=None,
    free_miss: float = 1e-3,
    outlier_scale: float = OUTLIER_SCALE,
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
    noise : {"student", "multiplicative", "mixture", "outlier"}
    origin : (3,) float, metres, optional
        Centre of the multiplicative perturbation (default: the data centroid, as :func:`bayestouch.paper.perturb`).
    free : (K, 3) float, metres, optional
        Free-space points: finger positions that touched nothing (outside the object).
    free_miss : float
        Probability that a free-space point is mislabelled (``models/priors.toml`` free_miss).
    outlier_scale : float, metres
        Scale of the half-Cauchy displacement of the outlier model's displaced contacts (``models/priors.toml``
        outlier_scale; :func:`outlier_log_density`).

    Returns
    -------
    (W,) float
        −inf outside the prior, never NaN.
    """
    data = _prepare(
        points, normals, _check_noise(noise), origin, _free_or_none(free), free_miss, outlier_scale=outlier_scale
    )
    return _log_prob_batch(jnp.asarray(thetas), data, bounds, noise, float(nu))


def log_likelihood(theta, points, nu: float):
    """Σ log Student-t(r/σ; ν) − M log σ (Gaussian for ν = inf) for one θ (11,)."""
    return _log_lik_batch(jnp.asarray(theta)[None], _prepare(points), "student", float(nu))[0]


def log_prob(theta, points, bounds: Bounds, nu: float, *, normals=None, noise: str = "student", origin=None):
    """Log-posterior (unnormalised) of one θ (D,): −inf outside the prior, never NaN; differentiable inside.

    The one-walker case of :func:`log_prob_batch` (same arguments).
    """
    return log_prob_batch(jnp.asarray(theta)[None], points, bounds, nu, normals=normals, noise=noise, origin=origin)[0]


def check_free(value) -> np.ndarray | None:
    """Free-space points (finger positions that touched nothing) as a finite (K, 3) array of metres (an empty one
    of any shape: (0, 3)), None staying None, or a one-line refusal naming ``free`` (text, a number, a ragged
    nesting, another shape: the check of :func:`bayestouch.fit` and the fitting functions)."""
    if value is None:
        return None
    expected = "expected free-space points as a finite (K, 3) array of numbers in metres"
    try:
        a = np.asarray(value)
        if a.dtype.kind not in "iufO":  # text, complex, bools …
            raise TypeError(a.dtype)
        a = a.astype(float)
    except (TypeError, ValueError):  # also a ragged nesting
        raise BadInput(f"free: {expected}, got {type(value).__name__} {shown(value)}") from None
    if a.size == 0:
        return np.empty((0, 3))
    if a.ndim != 2 or a.shape[1] != 3:
        got = f"{type(value).__name__} {shown(value)}" if a.ndim == 0 else f"shape {a.shape}"
        raise BadInput(f"free: {expected}, got {got}")
    if not np.isfinite(a).all():
        raise BadInput(f"free: {expected}; it holds NaN or infinite values")
    return a


def check_priors(priors) -> PriorParams:
    """``priors``, or the defaults of ``models/priors.toml`` for None; a one-line refusal naming ``priors`` when it
    is not a :class:`PriorParams` (:func:`load_priors`)."""
    if priors is None:
        return load_priors()
    if not isinstance(priors, PriorParams):
        raise BadInput(
            f"priors: expected a PriorParams (bayestouch.inference.contact.load_priors()) or None, got {shown(priors)}"
        )
    return priors


def check_points(points, normals=None):
    """Contact points (and normals) as arrays, or a one-line refusal naming ``points`` or ``normals``: a path (the
    fitting functions take arrays; :func:`bayestouch.fit` reads files), text, points that are not a finite
    (M ≥ 1, 3) array of metres, normals that are not finite, of non-zero length and one per point.

    Returns
    -------
    points : (M, 3) float, metres
    normals : (M, 3) float unit vectors, or None
    """
    if isinstance(points, str | bytes | os.PathLike):
        raise BadInput(
            f"points: expected an (M, 3) array in metres, not a path ({points!r:.60}); use bt.fit(PATH) or "
            "bt.load_contact_points(PATH).points"
        )
    try:
        p = np.asarray(points, dtype=float) if np.ndim(points) else np.empty((0,))
    except (TypeError, ValueError):  # text, a ragged nesting
        raise BadInput(
            f"points: expected a finite (M ≥ 1, 3) array of numbers in metres, got {type(points).__name__}"
        ) from None
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 1 or not np.all(np.isfinite(p)):
        raise BadInput(f"points: expected a finite (M ≥ 1, 3) array in metres, got shape {p.shape}")
    if normals is None:
        return p, None
    try:
        nrm = np.asarray(normals, dtype=float)
    except (TypeError, ValueError):
        raise BadInput(
            f"normals: expected a finite ({len(p)}, 3) array like the points, got {type(normals).__name__}"
        ) from None
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
    free=None,
):
    """A jitted, walker-vectorised log-probability ``f(thetas (W, D)) → (W,)`` for ``emcee(vectorize=True)``.

    The data are padded to :func:`padded_size` columns masked out of the sums, so fits of similar sizes share
    one compiled program.

    Parameters
    ----------
    points : (M, 3) float, metres
    priors : PriorParams, optional
        Default :func:`load_priors`.
    nu : float, optional
        Student-t degrees of freedom for ``noise="student"`` (default ``priors.student_nu``; inf is Gaussian).
    normals : (M, 3) float, optional
        Measured outward normals (normalised here); adds the vMF term and ``log_kappa``.
    noise : {"student", "multiplicative", "mixture", "outlier"}
    origin : (3,) float, metres, optional
        Centre of the multiplicative perturbation (default the data centroid).
    free : (K, 3) float, metres, optional
        Free-space points (finger positions that touched nothing): each adds log(ε + (1 − ε) Φ(d/σ)), d its
        first-order distance outside the surface, ε = ``priors.free_miss``.
    precision : {"float64", "mixed"}
        ``"mixed"``: float32 per-point transcendentals, float64 affine map and sum (``noise="student"`` or
        ``"outlier"`` without normals only; about 1.5x faster, log-probability error
        ~1e-7·(a/σ)·√M nats, see ``docs/contact_model.md``).

    Returns
    -------
    f : callable
        NumPy in, NumPy out; D = ``len(param_names(normals is not None, noise))`` (11 by default). ``f.parts``
        maps walkers (W, D) to (log-prior, log-likelihood, their gradients): the pieces a tempered sampler needs.
    bounds : Bounds
    """
    _check_noise(noise)
    if precision not in ("float64", "mixed"):
        raise BadInput(f"precision: expected 'float64' or 'mixed', got {precision!r}")
    if precision == "mixed" and (noise not in ("student", "outlier") or normals is not None):
        raise BadInput(
            "precision: 'mixed' is implemented for noise='student' or 'outlier' without normals; use 'float64'"
        )
    if nu is not None and noise != "student":
        raise BadInput(f"nu: applies to noise='student' only, got nu={nu} with noise={noise!r}")
    p, nrm = check_points(points, normals)
    priors = priors or load_priors()
    nu = float(priors.student_nu if nu is None else nu)
    if not nu > 0:
        raise BadInput(f"nu: Student-t degrees of freedom must be > 0 (inf for Gaussian), got {nu}")
    fr = _free_or_none(free)
    if fr is not None and not np.all(np.isfinite(fr)):
        raise BadInput("free: free-space points must be finite (K, 3) metres")
    data = _prepare(p, nrm, noise, origin, fr, priors.free_miss, pad=True, outlier_scale=priors.outlier_scale)
    bounds = bounds_for(p, priors, nrm is not None, noise)
    dim = len(bounds.lower)

    def f(thetas):
        th = np.asarray(thetas, dtype=np.float64)
        if th.ndim == 1:
            th = th[None]
        if th.ndim != 2 or th.shape[1] != dim:
            raise BadInput(f"thetas: expected a (W, {dim}) array of parameter vectors, got shape {th.shape}")
        return np.asarray(_log_prob_jit(th, data, bounds, noise, nu, precision))

    def parts(thetas):
        """(log-prior (W,), log-likelihood (W,), their gradients (W, D) each) of walkers (W, D): what a tempered
        sampler with gradients needs."""
        out = _tempering_jit(jnp.asarray(thetas, dtype=jnp.float64), data, bounds, noise, nu, precision)
        return tuple(np.asarray(o) for o in out)

    f.parts = parts
    return f, bounds
