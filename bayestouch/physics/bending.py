"""Three-wire bending of the finger and its constant-curvature pose: wire stresses → curvature vector u (2,) in 1/m
(closed form, or Newton with strain-dependent stresses) → tip position (3,) m and rotation (3, 3).

Pure JAX functions of arrays and the :class:`RodParams` pytree (``[rod]`` of ``models/finger.toml``; the wires'
constants from :mod:`bayestouch.physics.sma`); SI units (metres, radians, pascals). Geometry, equilibrium and pose
formulas: ``docs/physics_notes.md``.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS, Spec, build
from bayestouch.physics.sma import WireParams, quasi_static_strain, quasi_static_stress

__all__ = [
    "RodParams",
    "ROD_SPECS",
    "load_rod",
    "wire_angles",
    "wire_directions",
    "Curvature",
    "curvature_polar",
    "curvature_from_stresses",
    "wire_strains",
    "Equilibrium",
    "curvature_equilibrium",
    "bend_angle",
    "tip_pose",
    "backbone",
]


class RodParams(NamedTuple):
    """Constants of the finger's rod (``[rod]`` of ``models/finger.toml``; sources are in that file).

    Attributes
    ----------
    length : float, m
        Rod length L (6 cm, the paper §2).
    radius : float, m
        Rod radius (0.5 cm, the paper §2), for contact and heat only.
    wire_radius : float, m
        Radius r of the circle the three wires sit on (3 mm, physics.md §2).
    EI : float, N m²
        Effective bending stiffness EI_eff (physics.md §2 adjustment, 3e-4–1.5e-3 N m²).
    theta0 : float, rad
        Angle θ₀ of wire 1.
    wire_area : float, m²
        Cross-section A_w of each wire (π d²/4).
    """

    length: float
    radius: float
    wire_radius: float
    EI: float
    theta0: float
    wire_area: float


#: unit and allowed range of every field of :class:`RodParams`
ROD_SPECS = {
    "length": Spec("m", 1e-3, 1.0),
    "radius": Spec("m", 1e-4, 0.1),
    "wire_radius": Spec("m", 0.0, 0.1),
    "EI": Spec("N m^2", 1e-7, 1e3),
    "theta0": Spec("rad", -6.283185307179586, 6.283185307179586),
    "wire_area": Spec("m^2", 1e-12, 1e-4),
}


def load_rod(path=None) -> RodParams:
    """Read ``[rod]`` of a parameter file (default: the shipped ``models/finger.toml``).

    The wires must lie inside the rod (``wire_radius < radius``).

    Raises
    ------
    bayestouch.errors.BadInput
        Missing file or constant, wrong unit, out-of-range value, missing source, wires outside the rod.
    """
    path = MODELS / "finger.toml" if path is None else path
    rod = build(RodParams, path, "rod", ROD_SPECS)
    if not rod.wire_radius < rod.radius:
        raise BadInput(
            f"{path} [rod] wire_radius: {rod.wire_radius:g} m must be less than radius "
            f"{rod.radius:g} m (the wires sit inside the rod)"
        )
    return rod


def wire_angles(rod: RodParams):
    """Angles θ_i = θ₀ + 2π(i − 1)/3 of the three wires, (3,) radians (physics.md §2)."""
    return rod.theta0 + 2.0 * jnp.pi * jnp.arange(3) / 3.0


def wire_directions(rod: RodParams):
    """Unit directions n_i = (cos θ_i, sin θ_i) of the wires, (3, 2)."""
    th = wire_angles(rod)
    return jnp.stack([jnp.cos(th), jnp.sin(th)], axis=-1)


class Curvature(NamedTuple):
    """A curvature vector and its polar form.

    Attributes
    ----------
    u : (2,) array, 1/m
        u = κ (cos φ, sin φ).
    kappa : array, 1/m
        κ = |u| ≥ 0.
    phi : array, rad
        Bending direction φ (0 when κ = 0).
    """

    u: jax.Array
    kappa: jax.Array
    phi: jax.Array


def curvature_polar(u) -> Curvature:
    """Polar form of a curvature vector ``u (2,)`` in 1/m, with finite gradients at u = 0 (φ := 0 there)."""
    u = jnp.asarray(u, dtype=float)
    n2 = jnp.sum(u * u, axis=-1)
    nz = n2 > 0.0
    kappa = jnp.where(nz, jnp.sqrt(jnp.where(nz, n2, 1.0)), 0.0)
    phi = jnp.where(nz, jnp.arctan2(jnp.where(nz, u[..., 1], 0.0), jnp.where(nz, u[..., 0], 1.0)), 0.0)
    return Curvature(u, kappa, phi)


def curvature_from_stresses(rod: RodParams, stresses) -> Curvature:
    """Curvature for fixed wire stresses (physics.md §2 "Fixed forces").

    u = (r A_w/EI) Σ σ_i n_i, whose length is the closed form (r A_w/EI) √(Σσ_i² − σ₁σ₂ − σ₂σ₃ − σ₃σ₁)
    and whose angle is φ = atan2(Σσ_i sin θ_i, Σσ_i cos θ_i). The vector sum is used because it does not
    cancel catastrophically for nearly equal stresses.

    Parameters
    ----------
    rod : RodParams
    stresses : (3,) array, Pa
        Tensile stress in each wire.

    Returns
    -------
    Curvature
    """
    s = jnp.asarray(stresses, dtype=float)
    u = rod.wire_radius * rod.wire_area / rod.EI * (s @ wire_directions(rod))
    return curvature_polar(u)


def wire_strains(rod: RodParams, prestrain, u):
    """Wire strains ε_i = ε_pre − r (u · n_i), (..., 3), for curvatures ``u (..., 2)`` in 1/m (Camarillo et al.
    2008; physics.md §2)."""
    return prestrain - rod.wire_radius * (jnp.asarray(u) @ wire_directions(rod).T)


class Equilibrium(NamedTuple):
    """Result of :func:`curvature_equilibrium`.

    Attributes
    ----------
    u : (2,) array, 1/m
    kappa : array, 1/m
    phi : array, rad
    stress : (3,) array, Pa
        Wire stresses at equilibrium.
    strain : (3,) array, 1
        Wire strains at equilibrium.
    residual : (2,) array, N m
        EI u − r A_w Σ σ_i n_i at the returned u (≈ 0).
    """

    u: jax.Array
    kappa: jax.Array
    phi: jax.Array
    stress: jax.Array
    strain: jax.Array
    residual: jax.Array


def _moment_residual(u, rod, wire, temperatures, xi):
    """EI u − r A_w Σ σ_i n_i for u (..., 2); also the stresses and strains (..., 3)."""
    eps = wire_strains(rod, wire.prestrain, u)
    sig = quasi_static_stress(wire, eps, temperatures, xi)
    return rod.EI * u - rod.wire_radius * rod.wire_area * (sig @ wire_directions(rod)), sig, eps


_STEPS = jnp.array([1.0, 0.5, 0.25, 0.125, 0.0625])


def _tangent_stiffness(rod, wire, sig, temperatures, xi):
    """J = EI·I + r² A_w Σ k_i n_i n_iᵀ with the wires' tangent moduli k_i = dσ_i/dε_i = 1/(∂ε/∂σ)."""
    slope = jax.jvp(lambda s: quasi_static_strain(wire, s, temperatures, xi), (sig,), (jnp.ones_like(sig),))[1]
    n = wire_directions(rod)
    return rod.EI * jnp.eye(2) + rod.wire_radius**2 * rod.wire_area * (n.T / slope) @ n


@partial(jax.jit, static_argnames=("n_iter",))
def curvature_equilibrium(rod: RodParams, wire: WireParams, temperatures, xi=None, n_iter=20) -> Equilibrium:
    """Solve EI u = r A_w Σ σ_i(ε_i, T_i) n_i for the curvature u (physics.md §2).

    Each wire's stress comes from the quasi-static Brinson loading curve
    (:func:`bayestouch.physics.sma.quasi_static_stress`) at its strain ε_i = ε_pre − r u·n_i and
    temperature T_i: the heated wire shortens as it turns to austenite, the cold antagonists stretch along
    the detwinning plateau. The solve is ``n_iter`` Newton steps from u = 0 with the tangent stiffness
    J = EI·I + r²A_w Σ (dσ_i/dε_i) n_i n_iᵀ (symmetric positive definite), each with a backtracking choice
    of step among 1, ½, …, 1/16 minimising |residual|. Derivatives are implicit: the iterations run on
    stop-gradient inputs and one final Newton step u* − J⁻¹ g(u*; θ) carries dθ, which gives
    du/dθ = −J⁻¹ ∂g/∂θ exactly at the root.

    Parameters
    ----------
    rod : RodParams
    wire : WireParams
        The three wires' constants (same for all three; ``wire.prestrain`` is ε_pre).
    temperatures : (3,) array, K
    xi : (3,) array or None, 1
        Martensite fractions (e.g. the last sample of :func:`bayestouch.physics.sma.simulate_wire`, which
        carries the hysteresis); ``None`` uses the major heating branch from cold.
    n_iter : int
        Newton iterations (static).

    Returns
    -------
    Equilibrium
    """
    temperatures = jnp.asarray(temperatures, dtype=float)
    sg = jax.lax.stop_gradient
    c_rod, c_wire, c_T, c_xi = sg(rod), sg(wire), sg(temperatures), None if xi is None else sg(xi)

    def newton(_, u):
        r, sig, _ = _moment_residual(u, c_rod, c_wire, c_T, c_xi)
        d = -jnp.linalg.solve(_tangent_stiffness(c_rod, c_wire, sig, c_T, c_xi), r)
        res = _moment_residual(u + _STEPS[:, None] * d, c_rod, c_wire, c_T, c_xi)[0]
        return u + _STEPS[jnp.argmin(jnp.sum(res * res, axis=-1))] * d

    u = jax.lax.fori_loop(0, n_iter, newton, jnp.zeros(2))
    _, sig, _ = _moment_residual(u, c_rod, c_wire, c_T, c_xi)
    J = _tangent_stiffness(c_rod, c_wire, sig, c_T, c_xi)
    r, _, _ = _moment_residual(u, rod, wire, temperatures, xi)
    u = u - jnp.linalg.solve(J, r)
    res, sig, eps = _moment_residual(u, rod, wire, temperatures, xi)
    c = curvature_polar(u)
    return Equilibrium(u, c.kappa, c.phi, sig, eps, res)


def _kappa_smooth(u, eps):
    return jnp.sqrt(jnp.sum(u * u, axis=-1) + eps * eps)


_SINC_SERIES = 0.02


def _sinc(x):
    """sin(x)/x = ``jnp.sinc(x/π)`` (physics.md §2), switched to its Maclaurin series 1 − x²/6 + x⁴/120 −
    x⁶/5040 for |x| < 0.02 (truncation < 1e-19): autodiff of sin(x)/x loses all digits of the derivative
    near 0 by cancellation, which would spoil gradients and Hessians at small curvature."""
    small = jnp.abs(x) < _SINC_SERIES
    x2 = x * x
    series = 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0))
    return jnp.where(small, series, jnp.sinc(jnp.where(small, 1.0, x) / jnp.pi))


def bend_angle(rod: RodParams, u):
    """Tip bend angle κL in radians for a curvature ``u (2,)`` in 1/m."""
    return rod.length * curvature_polar(u).kappa


def _skew(w):
    z = jnp.zeros_like(w[0])
    return jnp.array([[z, -w[2], w[1]], [w[2], z, -w[0]], [-w[1], w[0], z]])


def _pose_at(s, u, eps):
    """Position (3,) and rotation (3, 3) at arc length s for curvature u."""
    u = jnp.asarray(u, dtype=float)
    th = s * _kappa_smooth(u, eps)
    S = _sinc(0.5 * th)
    p = jnp.stack([u[0] * 0.5 * s * s * S * S, u[1] * 0.5 * s * s * S * S, s * _sinc(th)])
    K = _skew(s * jnp.stack([-u[1], u[0], jnp.zeros_like(u[0])]))
    R = jnp.eye(3) + _sinc(th) * K + 0.5 * S * S * (K @ K)
    return p, R


@jax.jit
def tip_pose(rod: RodParams, u, eps=1e-9):
    """Tip position and orientation of a constant-curvature rod (Webster & Jones 2010; physics.md §2).

    The base is at the origin with the rod along +z; the tip frame is the base frame transported along
    the arc, R = R_z(φ) R_y(κL) R_z(−φ), so R e_z is the tip tangent.

    Parameters
    ----------
    rod : RodParams
    u : (2,) array, 1/m
        Curvature vector κ (cos φ, sin φ).
    eps : float, 1/m
        Smoothing of κ = √(|u|² + ε²); keeps κ → 0 finite and differentiable.

    Returns
    -------
    p : (3,) array, m
    R : (3, 3) array
    """
    return _pose_at(rod.length, u, eps)


@jax.jit
def backbone(rod: RodParams, u, s, eps=1e-9):
    """Points of the rod's centre line at arc lengths ``s (K,)`` in metres, (K, 3) metres.

    Same constant-curvature formula as :func:`tip_pose` with L replaced by s; for plotting and contact.
    """
    s = jnp.asarray(s, dtype=float)
    return jax.vmap(lambda si: _pose_at(si, u, eps)[0])(s)
