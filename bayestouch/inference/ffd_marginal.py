"""FFD lattice displacements at the contact level, marginalised analytically (DESIGN.md §3.6).

The surface is the n-ellipsoid of θ deformed by a Bernstein lattice (paper eq. 8, X = B P) whose control points
are displaced by δP from the uniform lattice P₀ (which reproduces the undeformed surface exactly). The lattice
box is aligned with the n-ellipsoid's principal axes and spans ±(1 + margin)·(a, b, c), so the lattice moves
with the shape.

Linearisation. Moving the surface by the displacement field u(y) = Σ_k B_k(y) δP_k changes the signed distance
of a data point y (principal frame) by −n̂(y)·u(y) to first order, so the residual vector is

    r(θ, δP) = r(θ) − A(θ) δp,   A_i = n̂_iᵀ ⊗ B(y_i)  (M × 3K),

with r(θ) the first-order distances of :func:`bayestouch.inference.contact.residuals` and δp = vec(δP).

Marginalisation. Under a Gaussian prior δp ~ N(0, τ² I) and Gaussian contact noise σ, δp integrates out:

    r(θ) ~ N(0, C),  C = σ² I + τ² A Aᵀ,
    log det C = 2M log σ + log det(I + (τ/σ)² AᵀA),
    rᵀC⁻¹r = σ⁻² (rᵀr − bᵀ (σ²/τ² I + AᵀA)⁻¹ b),  b = Aᵀr    (Woodbury),

one (3K × 3K) Cholesky per evaluation: O(M (3K)²). The conditional posterior of δp given θ is Gaussian with
mean (σ²/τ² I + AᵀA)⁻¹ b, which gives the refined surface of a draw.

Why marginalise rather than sample (measured in ``benchmarks/bench_ffd.py``): emcee's affine-invariant and
differential-evolution moves need a number of walkers and an autocorrelation time that grow with the dimension;
a 4×4×4 lattice adds 192 dimensions to the 11 shape parameters, beyond what an ensemble sampler mixes in any
useful time, while the marginal keeps the sampled dimension at 11 for the cost of one small Cholesky. The price:
the noise must be Gaussian here (the Student-t of the default model is not conjugate) — use the Student-t level
for data with outliers.
"""

from __future__ import annotations

from math import comb

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import contact as cm
from bayestouch.params import MODELS, Spec, build

__all__ = [
    "design_matrix",
    "marginal_log_likelihood",
    "conditional_lattice",
    "make_ffd_log_prob",
    "deformed_points",
    "DEFAULT_TAU",
    "DEFAULT_MARGIN",
    "load_ffd_priors",
]


def load_ffd_priors(path=None) -> dict[str, float]:
    """Read ``[ffd_priors]`` of ``models/priors.toml`` (or ``path``): tau, metres."""
    return build(dict, MODELS / "priors.toml" if path is None else path, "ffd_priors", {"tau": Spec("m", 1e-7, 0.1)})


#: prior sd of each control-point displacement, metres (``[ffd_priors] tau`` of ``models/priors.toml``)
DEFAULT_TAU = float(load_ffd_priors()["tau"])
#: relative margin of the lattice box beyond the semi-axes (as :func:`bayestouch.paper.refine_ffd`)
DEFAULT_MARGIN = 0.15


def _bernstein(degree: int, s):
    """Bernstein basis (N, degree + 1) at s (N,) ∈ [0, 1] (JAX)."""
    i = np.arange(degree + 1)
    c = jnp.asarray([comb(degree, int(k)) for k in i], dtype=jnp.float64)
    s = s[:, None]
    return c * s**i * (1.0 - s) ** (degree - i)


def _lattice_basis(local, axes, dims, margin):
    half = axes * (1.0 + margin)
    s = jnp.clip((local + half) / (2.0 * half), 0.0, 1.0)
    l, m, k = dims
    bu, bv, bw = _bernstein(l - 1, s[:, 0]), _bernstein(m - 1, s[:, 1]), _bernstein(k - 1, s[:, 2])
    return jnp.einsum("ni,nj,nk->nijk", bu, bv, bw).reshape(local.shape[0], l * m * k)


def design_matrix(theta, points, dims: tuple[int, int, int], margin: float = DEFAULT_MARGIN):
    """Residuals r (M,) m and the linear map A (M, 3K) of lattice displacements (principal frame) to residuals.

    Parameters
    ----------
    theta : (11,) float
        Contact-level parameters (:data:`bayestouch.inference.contact.PARAM_NAMES`).
    points : (M, 3) float, metres
    dims : (l, m, k) int, static
        Control points along the principal axes a, b, c.
    """
    s = cm.shape_of(theta)
    y = (points - s.centre) @ s.rotation
    d, grad, _ = ne.first_order_distance(s, y)
    nrm = grad / jnp.sqrt(jnp.sum(grad * grad, axis=-1, keepdims=True) + 1e-300)
    B = _lattice_basis(y, s.axes, dims, margin)  # (M, K)
    A = (nrm[:, :, None] * B[:, None, :]).reshape(points.shape[0], -1)  # column index = axis * K + control point
    return d, A


def _woodbury(theta, points, dims, margin, tau):
    r, A = design_matrix(theta, points, dims, margin)
    sigma2 = jnp.exp(2.0 * theta[10])
    n = A.shape[1]
    H = A.T @ A + (sigma2 / tau**2) * jnp.eye(n)
    L = jnp.linalg.cholesky(H)
    b = A.T @ r
    z = jax.scipy.linalg.solve_triangular(L, b, lower=True)
    return r, A, sigma2, L, b, z


def marginal_log_likelihood(theta, points, dims, margin: float = DEFAULT_MARGIN, tau: float = DEFAULT_TAU):
    """log N(r(θ); 0, σ² I + τ² A Aᵀ): the Gaussian contact likelihood with the lattice integrated out.

    For τ → 0 it is the Gaussian contact log-likelihood (:func:`bayestouch.inference.contact.log_likelihood`
    with ν = ∞).
    """
    r, _, sigma2, L, _, z = _woodbury(theta, points, dims, margin, tau)
    m, n = r.shape[0], L.shape[0]
    quad = (jnp.sum(r * r) - jnp.sum(z * z)) / sigma2
    # log det(I + τ²/σ² AᵀA) = log det H − n log(σ²/τ²)
    logdet = 2.0 * jnp.sum(jnp.log(jnp.diag(L))) - n * jnp.log(sigma2 / tau**2) + m * jnp.log(sigma2)
    return -0.5 * (quad + logdet + m * jnp.log(2.0 * jnp.pi))


def conditional_lattice(theta, points, dims, margin: float = DEFAULT_MARGIN, tau: float = DEFAULT_TAU):
    """Posterior mean (K, 3) m and covariance (3K, 3K) m² of the control-point displacements given θ.

    Displacements are along the principal axes (columns x, y, z of the principal frame).
    """
    _, _, sigma2, L, b, _ = _woodbury(theta, points, dims, margin, tau)
    mean = jax.scipy.linalg.cho_solve((L, True), b)
    cov = sigma2 * jax.scipy.linalg.cho_solve((L, True), jnp.eye(L.shape[0]))
    K = L.shape[0] // 3
    return mean.reshape(3, K).T, cov


def deformed_points(theta, dP, local_points, dims, margin: float = DEFAULT_MARGIN):
    """World positions (N, 3) m of principal-frame points ``local_points`` of the n-ellipsoid of θ moved by the
    lattice displacements ``dP (K, 3)`` m."""
    s = cm.shape_of(theta)
    B = _lattice_basis(local_points, s.axes, dims, margin)
    return (local_points + B @ dP) @ s.rotation.T + s.centre


def make_ffd_log_prob(points, dims, *, tau: float = DEFAULT_TAU, margin: float = DEFAULT_MARGIN, priors=None):
    """Walker-vectorised log-posterior ``f(thetas (W, 11)) → (W,)`` of the n-ellipsoid with the lattice
    marginalised (NumPy in and out, −inf outside the prior box of the contact level, never NaN).

    Returns
    -------
    f : callable
    bounds : :class:`~bayestouch.inference.contact.Bounds`
    """
    priors = priors or cm.load_priors()
    dims = tuple(int(d) for d in dims)
    if len(dims) != 3 or min(dims) < 2:
        raise ValueError(f"dims must be three lattice sizes ≥ 2, got {dims}")
    if not tau > 0:
        raise ValueError(f"tau must be > 0 metres, got {tau}")
    pts = jnp.asarray(points, dtype=jnp.float64)
    bounds = cm.bounds_for(points, priors)

    def one(t):
        lp = cm.log_prior(t, bounds)
        ll = marginal_log_likelihood(jnp.clip(t, bounds.lower, bounds.upper), pts, dims, margin, tau)
        out = jnp.where(jnp.isfinite(lp), lp + ll, -jnp.inf)
        return jnp.where(jnp.isnan(out), -jnp.inf, out)

    batched = jax.jit(jax.vmap(one))

    def f(thetas):
        return np.asarray(batched(jnp.asarray(np.atleast_2d(thetas), dtype=jnp.float64)))

    return f, bounds
