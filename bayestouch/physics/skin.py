"""The auxetic skin: indentation → pressure map → contact force, damping and friction (the paper's contact test of
eq. 14–15 made smooth, and its eq. 19–20), with Hertz, bonded-layer and Winkler closed forms as references.

Every function is a pure JAX function of arrays and of a :class:`SkinParams` (a NamedTuple, hence a pytree that can
be differentiated or batched). SI units throughout: metres, pascals, newtons, seconds. The chain and its sources:
``docs/physics_notes.md``.
"""

from __future__ import annotations

from typing import NamedTuple

from bayestouch.backend import jax, jnp
from bayestouch.params import MODELS, Spec, build

__all__ = [
    "SkinParams",
    "SKIN_SPECS",
    "load_skin",
    "penetration",
    "bonded_layer_modulus",
    "shear_modulus",
    "hertz",
    "winkler_sphere",
    "foam_stress",
    "blur_width",
    "gaussian_blur",
    "blur_kernel",
    "pressure_at_taxels",
    "pressure_map",
    "total_force",
    "cosserat_stiffening",
    "hunt_crossley",
    "kelvin_voigt",
    "damped_contact_force",
    "tangential_stiffness_ratio",
    "tangential_stiffness",
    "friction",
]

#: beyond this fraction of the densification strain the foam law is continued linearly (C¹), so the
#: pressure stays finite for any indentation an optimiser may try.
_DENSE_CAP = 0.9


class SkinParams(NamedTuple):
    """Constants of the auxetic skin (``[skin]`` of ``models/skin.toml``; sources are in that file).

    Attributes
    ----------
    E : float, Pa
        Young's modulus of the auxetic PU foam (100 kPa; 30–300 kPa, Choi & Lakes 1992 [A]).
    nu : float, 1
        Poisson's ratio (−0.185, measured at 10–25 % compressive strain; the paper §1).
    h : float, m
        Skin thickness (2 mm).
    rho : float, kg/m³
        Density (118 kg/m³; the paper §1).
    ell_b : float, m
        Cosserat characteristic length for bending ℓ_b (Lakes 1995); sets the blur width.
    N2 : float, 1
        Cosserat coupling number N² (Lakes 1986).
    hc_m : float, 1
        Hunt–Crossley exponent m (2 for a sphere on a Winkler layer, F ∝ δ²).
    hc_damping : float, s/m
        Hunt–Crossley damping per unit stiffness λ/K, so that F = Kδ^m (1 + (λ/K) δ̇).
    mu : float, 1
        Coulomb friction coefficient skin–object.
    s : float, m
        Softplus smoothing length of :func:`penetration` (1 µm).
    eps_d : float, 1
        Densification strain ε_D of the foam.
    k_d : float, 1
        Densification exponent; σ = Mε (1 − ε/ε_D)^(−k_d). ``k_d = 0`` is the linear Winkler layer.
    """

    E: float
    nu: float
    h: float
    rho: float
    ell_b: float
    N2: float
    hc_m: float
    hc_damping: float
    mu: float
    s: float
    eps_d: float
    k_d: float


#: unit and allowed range of every field of :class:`SkinParams` (``"1"`` = dimensionless)
SKIN_SPECS = {
    "E": Spec("Pa", 1e2, 1e9),
    "nu": Spec("1", -0.99, 0.49),
    "h": Spec("m", 1e-5, 0.02),
    "rho": Spec("kg/m^3", 1.0, 5000.0),
    "ell_b": Spec("m", 0.0, 0.02),
    "N2": Spec("1", 0.0, 1.0),
    "hc_m": Spec("1", 1.0, 3.0),
    "hc_damping": Spec("s/m", 0.0, 100.0),
    "mu": Spec("1", 0.0, 5.0),
    "s": Spec("m", 1e-10, 1e-3),
    "eps_d": Spec("1", 0.05, 1.0),
    "k_d": Spec("1", 0.0, 10.0),
}


def load_skin(path=None) -> SkinParams:
    """Read ``[skin]`` of a parameter file (default: the shipped ``models/skin.toml``).

    Raises
    ------
    bayestouch.errors.BadInput
        Missing file or constant, wrong unit, out-of-range value or missing source (one line).
    """
    return build(SkinParams, MODELS / "skin.toml" if path is None else path, "skin", SKIN_SPECS)


# ---------------------------------------------------------------- indentation


def penetration(sdf_values, s):
    """Smooth penetration depth δ = s·softplus(−φ/s) (physics.md §6 step 2).

    The paper finds contact by minimum distance (eq. 14) and an interference distance d (eq. 15); with
    the object's signed distance φ at a taxel (negative inside the object) the interference is
    max(−φ, 0), smoothed here so that gradients reach taxels just outside contact.

    Parameters
    ----------
    sdf_values : (...,) float, m
        Signed distance of the taxel positions to the object, negative inside.
    s : float, m
        Smoothing length (≈ 1 µm). δ → max(−φ, 0) as s → 0; δ(φ = 0) = s·ln 2.

    Returns
    -------
    (...,) float, m
        δ ≥ 0.
    """
    phi = jnp.asarray(sdf_values, dtype=jnp.float64)
    return s * jax.nn.softplus(-phi / s)


# ---------------------------------------------------------------- closed forms


def bonded_layer_modulus(E, nu):
    """Uniaxial-strain (P-wave) modulus M = E(1−ν)/((1+ν)(1−2ν)) of a thin layer bonded to a rigid base.

    A thin layer under a load of width a ≫ h is laterally confined, so p = Mδ/h (Johnson 1985 ch. 5).
    M/E = 1.061 at ν = −0.185, 1.346 at ν = 0.3 (physics.md §3).

    Parameters
    ----------
    E : float or array, Pa
    nu : float or array, 1 (−1 < ν < 0.5)

    Returns
    -------
    float or array, Pa
    """
    return E * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))


def shear_modulus(E, nu):
    """Isotropic shear modulus G = E/(2(1+ν)), Pa."""
    return E / (2.0 * (1.0 + nu))


def hertz(F, R, E, nu):
    """Hertz contact of a rigid sphere on an elastic half-space (Johnson 1985 §4.2).

    a = (3FR/4E*)^(1/3), p₀ = 3F/(2πa²), E* = E/(1−ν²) (the object is taken rigid). Valid for a ≪ h;
    on the 2 mm skin it is a reference, not the model (physics.md §3).

    Parameters
    ----------
    F : float or array, N
        Normal load ≥ 0.
    R : float or array, m
        Sphere radius.
    E, nu : Pa, 1
        Skin modulus and Poisson's ratio.

    Returns
    -------
    a : m
        Contact radius.
    p0 : Pa
        Peak (centre) pressure.
    """
    e_star = E / (1.0 - nu**2)
    a = jnp.cbrt(3.0 * F * R / (4.0 * e_star))
    p0 = 3.0 * F / (2.0 * jnp.pi * a**2)
    return a, p0


def winkler_sphere(delta0, R, params: SkinParams):
    """A rigid sphere pressed δ₀ into a thin bonded (Winkler) layer, linear foam (physics.md §3 [D]).

    With the parabolic gap δ(r) = δ₀ − r²/2R and p = Mδ/h: F = ∫p dA = πMRδ₀²/h and a = √(2Rδ₀);
    the peak pressure is Mδ₀/h. ``params.k_d`` (densification) is ignored here.

    Parameters
    ----------
    delta0 : float or array, m
        Indentation depth at the centre, ≥ 0.
    R : float or array, m
        Sphere radius.
    params : SkinParams

    Returns
    -------
    F : N
    a : m
    """
    delta0 = jnp.maximum(jnp.asarray(delta0, dtype=jnp.float64), 0.0)
    M = bonded_layer_modulus(params.E, params.nu)
    return jnp.pi * M * R * delta0**2 / params.h, jnp.sqrt(2.0 * R * delta0)


# ---------------------------------------------------------------- pressure map


def foam_stress(params: SkinParams, eps):
    """Compressive stress of the confined foam layer at strain ε = δ/h.

    σ = M ε (1 − ε/ε_D)^(−k_d): linear M·ε at small strain (Johnson 1985 ch. 5) stiffened towards the
    densification strain ε_D in the form of Gibson & Ashby (1997, elastomeric foams, ε_D/(ε_D − ε))
    [A: the measured σ(ε) of the auxetic foam should replace it, physics.md §3]. Beyond 0.9 ε_D the law
    is continued by its tangent (C¹), so σ stays finite and differentiable for any ε.

    Parameters
    ----------
    params : SkinParams
    eps : (...,) float, 1
        Compressive strain (≥ 0 in use).

    Returns
    -------
    (...,) float, Pa
    """
    M = bonded_layer_modulus(params.E, params.nu)
    eps = jnp.asarray(eps, dtype=jnp.float64)
    eps_c = _DENSE_CAP * params.eps_d
    e = jnp.minimum(eps, eps_c)
    base = M * e * (1.0 - e / params.eps_d) ** (-params.k_d)
    slope_c = M * (1.0 - _DENSE_CAP) ** (-params.k_d) * (1.0 + params.k_d * _DENSE_CAP / (1.0 - _DENSE_CAP))
    return base + slope_c * jnp.maximum(eps - eps_c, 0.0)


def blur_width(params: SkinParams):
    """Standard deviation w = √((h/2)² + ℓ_b²) of the Gaussian pressure blur, m (physics.md §3 [A])."""
    return jnp.sqrt((0.5 * params.h) ** 2 + params.ell_b**2)


def _blur_matrix(n: int, w, pitch):
    """(n, n) Toeplitz matrix of the 1-D Gaussian kernel g(kΔ) = exp(−(kΔ)²/2w²)/Z on n taxels.

    Z sums g over every offset the grid can hold (|k| ≤ n − 1), so the kernel has unit mass and the
    blur conserves Σp wherever the load is farther than a few w from the grid edge.
    """
    k = jnp.arange(n, dtype=jnp.float64)
    g = jnp.exp(-0.5 * ((k[:, None] - k[None, :]) * pitch / w) ** 2)
    offsets = jnp.arange(-(n - 1), n, dtype=jnp.float64) * pitch
    return g / jnp.sum(jnp.exp(-0.5 * (offsets / w) ** 2))


@jax.jit
def gaussian_blur(p, w, pitch):
    """Force-conserving separable Gaussian blur of a map on a square taxel grid.

    The convolution along each axis is written as a product with a symmetric Toeplitz matrix, so the
    shapes are static while ``w`` and ``pitch`` may be traced (differentiated or fitted). Load that
    reaches past the grid edge is lost (zero padding), as on a real finite sensor.

    Parameters
    ----------
    p : (..., H, W) float
        Map, e.g. pressure in Pa.
    w : float, m
        Gaussian standard deviation (> 0).
    pitch : float, m
        Taxel spacing along both axes.

    Returns
    -------
    (..., H, W) float
        Σ p_out = Σ p_in to the tail mass of the kernel beyond the edges.
    """
    p = jnp.asarray(p, dtype=jnp.float64)
    gy = _blur_matrix(p.shape[-2], w, pitch)
    gx = _blur_matrix(p.shape[-1], w, pitch)
    return jnp.einsum("ij,...jk,lk->...il", gy, p, gx)


@jax.jit
def pressure_map(params: SkinParams, delta, pitch):
    """Contact pressure on the taxel grid from the penetration map (physics.md §6 step 3).

    p = blur_w(σ_foam(δ/h)): the local Winkler pressure of :func:`foam_stress`, then the force-conserving
    Gaussian blur of :func:`gaussian_blur` with w = :func:`blur_width`.

    Parameters
    ----------
    params : SkinParams
    delta : (..., H, W) float, m
        Penetration depth at each taxel (≥ 0, from :func:`penetration`).
    pitch : float, m
        Taxel spacing (square grid).

    Returns
    -------
    (..., H, W) float, Pa
        ``total_force(p, pitch)`` is the normal force.
    """
    delta = jnp.asarray(delta, dtype=jnp.float64)
    return gaussian_blur(foam_stress(params, delta / params.h), blur_width(params), pitch)


def total_force(pressure, pitch):
    """Normal force Σ p·pitch² of a pressure map (..., H, W) in Pa on a grid of spacing ``pitch`` m → N."""
    return jnp.sum(jnp.asarray(pressure), axis=(-2, -1)) * pitch**2


def cosserat_stiffening(params: SkinParams, a, c=1.0):
    """Surrogate Cosserat size effect on the layer modulus: min(1.4, 1 + c N² (ℓ_b/a)²) (physics.md §3 [A]).

    Foam size effects are at most ×1.4 (Lakes 1986, 1995); ``a`` (m) is the contact radius and ``c`` an
    O(1) constant to calibrate against FE. Multiply the pressure map (or M) by it when a ~ ℓ_b.
    """
    return jnp.minimum(1.4, 1.0 + c * params.N2 * (params.ell_b / a) ** 2)


# ---------------------------------------------------------------- normal force and damping


def hunt_crossley(K, m, lam, delta, delta_dot):
    """Hunt–Crossley (1975) contact force F = Kδ^m + λ δ^m δ̇, clipped at F ≥ 0 (no adhesion).

    Relation to the paper's eq. 19, F_c = kδ + b̃δ̇ (a Kelvin–Voigt spring-dashpot, see
    :func:`kelvin_voigt`): at m = 1 Hunt–Crossley *is* eq. 19 with k = K and b̃ = λδ, i.e. a damping
    coefficient proportional to the indentation. That dependence removes eq. 19's force jump b̃δ̇ at first
    touch (δ = 0) and its sticky tension when the finger lifts off. For this skin F ∝ δ² (a sphere on a
    Winkler layer, :func:`winkler_sphere`), so m = 2 is the shipped exponent (physics.md §3).

    Parameters
    ----------
    K : float or array, N/m^m
        Stiffness.
    m : float, 1
        Exponent (≥ 1).
    lam : float or array, N·s/m^(m+1)
        Damping; λ = K·``SkinParams.hc_damping``.
    delta : (...,) float, m
        Indentation (negative values count as 0).
    delta_dot : (...,) float, m/s
        Indentation rate (> 0 while pressing in).

    Returns
    -------
    (...,) float, N
    """
    dm = jnp.maximum(jnp.asarray(delta, dtype=jnp.float64), 0.0) ** m
    return jnp.maximum(K * dm + lam * dm * delta_dot, 0.0)


def kelvin_voigt(k, b_tilde, delta, delta_dot):
    """The paper's eq. 19 as written, F_c = kδ + b̃δ̇ (k in N/m, b̃ in N·s/m), unclipped; a reference."""
    return k * jnp.asarray(delta, dtype=jnp.float64) + b_tilde * delta_dot


def damped_contact_force(F_elastic, damping, delta_dot):
    """Hunt–Crossley damping applied to an elastic force taken from the pressure map.

    F = F_el (1 + (λ/K) δ̇), clipped at ≥ 0: the form of :func:`hunt_crossley` with Kδ^m replaced by
    F_el = :func:`total_force` of :func:`pressure_map`, which is Kδ^m for a power-law contact.

    Parameters
    ----------
    F_elastic : (...,) float, N
    damping : float, s/m
        λ/K (``SkinParams.hc_damping``).
    delta_dot : (...,) float, m/s

    Returns
    -------
    (...,) float, N
    """
    return jnp.maximum(F_elastic * (1.0 + damping * delta_dot), 0.0)


# ---------------------------------------------------------------- tangential force


def tangential_stiffness_ratio(nu):
    """k_t/k_n = G/M = (1−2ν)/(2(1−ν)) of a thin bonded layer (physics.md §3 [D]).

    0.578 at ν = −0.185 against 0.286 at ν = 0.3: the auxetic skin is twice as stiff in shear per unit
    normal stiffness.
    """
    return (1.0 - 2.0 * nu) / (2.0 * (1.0 - nu))


def tangential_stiffness(params: SkinParams, area):
    """Tangential stiffness k_t = G A_c / h of a bonded layer under a contact of area ``area`` m², N/m."""
    return shear_modulus(params.E, params.nu) * area / params.h


def friction(mu, Fn, kt, delta_t):
    """Tangential force with a smooth Coulomb cap: F_t = μF_n tanh(k_t δ_t / μF_n) (physics.md §3).

    For |k_t δ_t| ≪ μF_n it is the paper's sticking law, eq. 20, F_t = k_t δ_t (Johnson 1985); for large
    δ_t it saturates at ±μF_n (sliding). With no normal load (μF_n ≤ 0) it is 0, with finite gradients.

    Parameters
    ----------
    mu : float, 1
        Friction coefficient.
    Fn : (...,) float, N
        Normal force (negative counts as 0).
    kt : float or array, N/m
        Tangential stiffness, e.g. :func:`tangential_stiffness`.
    delta_t : (...,) float, m
        Tangential displacement of the contact (one component; apply to |δ_t| along its direction for
        a vector).

    Returns
    -------
    (...,) float, N
    """
    cap = mu * jnp.maximum(jnp.asarray(Fn, dtype=jnp.float64), 0.0)
    ok = cap > 0.0
    safe = jnp.where(ok, cap, 1.0)
    return jnp.where(ok, safe * jnp.tanh(kt * delta_t / safe), 0.0)


def blur_kernel(positions, w, cell_area):
    """Dense Gaussian blur matrix (N, N) for taxels at arbitrary ``positions (N, 2)`` m (e.g. hexagonal pores).

    K_ij = A_cell/(2π w²) · exp(−|x_i − x_j|²/2w²): the continuous unit-mass Gaussian sampled on the array,
    each taxel standing for ``cell_area`` m² of skin. Σ_i K_ij = 1 to within the lattice-sum error (< 1e-9 for
    w > pitch) for loads a few w inside the array, so the blur conserves force there, as
    :func:`gaussian_blur` does on a square grid.

    Parameters
    ----------
    positions : (N, 2) float, m
    w : float, m
        Gaussian standard deviation (:func:`blur_width`).
    cell_area : float, m²
        Skin area per taxel.
    """
    x = jnp.asarray(positions, dtype=jnp.float64)
    d2 = jnp.sum((x[:, None, :] - x[None, :, :]) ** 2, axis=-1)
    return cell_area / (2.0 * jnp.pi * w**2) * jnp.exp(-0.5 * d2 / w**2)


def pressure_at_taxels(params: SkinParams, delta, kernel):
    """Contact pressure (..., N) Pa at taxels from penetrations ``delta (..., N)`` m: the foam law, then the
    blur ``kernel`` of :func:`blur_kernel`. Force = Σ p · cell_area."""
    local = foam_stress(params, jnp.asarray(delta, dtype=jnp.float64) / params.h)
    return jnp.einsum("ij,...j->...i", kernel, local)
