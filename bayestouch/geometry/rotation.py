"""Rotations of eq. 2 of the paper: R = R(z, ζ) R(x, ξ) R(z, ψ).

Angles are in radians and stored in the paper's order ``(xi, psi, zeta)`` (d7, d8, d9).
"""

from __future__ import annotations

from bayestouch.backend import jnp

__all__ = ["rot_x", "rot_z", "rotation_matrix", "euler_from_matrix"]


def rot_z(t):
    """Rotation about z by ``t`` radians, eq. 2's R(z, ·); ``(3, 3)``."""
    c, s = jnp.cos(t), jnp.sin(t)
    z, o = jnp.zeros_like(t), jnp.ones_like(t)
    return jnp.array([[c, -s, z], [s, c, z], [z, z, o]])


def rot_x(t):
    """Rotation about x by ``t`` radians, eq. 2's R(x, ·); ``(3, 3)``."""
    c, s = jnp.cos(t), jnp.sin(t)
    z, o = jnp.zeros_like(t), jnp.ones_like(t)
    return jnp.array([[o, z, z], [z, c, -s], [z, s, c]])


def rotation_matrix(angles):
    """R = R(z, ζ) R(x, ξ) R(z, ψ) (eq. 2 with θ → ξ, φ → ζ, as eq. 6 prescribes).

    Parameters
    ----------
    angles : (3,) float, radians
        ``(xi, psi, zeta)``.

    Returns
    -------
    (3, 3) float
        Columns are the n-ellipsoid's principal directions in world coordinates.
    """
    xi, psi, zeta = angles[0], angles[1], angles[2]
    return rot_z(zeta) @ rot_x(xi) @ rot_z(psi)


def euler_from_matrix(R):
    """Inverse of :func:`rotation_matrix` for a proper rotation.

    Returns ``(xi, psi, zeta)`` with ξ ∈ [0, π] and ψ, ζ ∈ (−π, π]. At the gimbal poles (ξ = 0 or π)
    only ψ ± ζ is defined; ψ is then set to 0.
    """
    R = jnp.asarray(R)
    xi = jnp.arccos(jnp.clip(R[2, 2], -1.0, 1.0))
    s = jnp.sin(xi)
    regular = s > 1e-9
    # R[2,0] = sin ξ sin ψ, R[2,1] = sin ξ cos ψ, R[0,2] = sin ζ sin ξ, R[1,2] = −cos ζ sin ξ
    psi_r = jnp.arctan2(R[2, 0], R[2, 1])
    zeta_r = jnp.arctan2(R[0, 2], -R[1, 2])
    # pole: R = R_z(ζ ± ψ) up to the sign of the z row; put everything into ζ
    zeta_p = jnp.arctan2(R[1, 0], R[0, 0])
    psi = jnp.where(regular, psi_r, 0.0)
    zeta = jnp.where(regular, zeta_r, zeta_p)
    return jnp.stack([xi, psi, zeta])
