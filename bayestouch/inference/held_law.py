"""The law of a finger's pad-pose error while it holds its currents, and that law conditioned on guarded strokes
over a known object (a bending calibration).

A finger that holds wire currents through a guarded stroke bends as its own constants say; a host that computes
the pad's pose with its nominal constants is off by the tip's error e(t) (finger-base frame, t the time since the
stroke's start; :func:`bayestouch.physics.pose.held_pose_error`), millimetres that hardly change along a stroke and
shift every contact along its approach by e's axial part: the same for every stroke, so contacts alone cannot tell
it from a larger object. :func:`prior_held_law` draws fingers about the nominal constants
(:func:`bayestouch.physics.pose.held_error_ensemble`) and writes their errors on a time grid as a Gaussian in
their leading components plus each member's remainder:

    e_k(t) = μ(t) + L(t) z_k + ρ_k(t),    z ~ N(m, P)  (the prior: m = 0, P = I).

Touches of an object whose surface is known (a calibration sphere in its fixture) observe e: the contact the host
recorded at p_i on approach u_i (the rod turned by R_i onto u_i) was truly at p_i + R_i e(t_i), on the surface.
:func:`condition_held_law` finds the posterior of z by Gauss–Newton on the signed distances φ(p_i + R_i e(t_i))
(Gaussian noise of sd σ plus, per contact, the remainders' variance along its normal) and its Laplace covariance
P = (Jᵀ W J + I)⁻¹. :func:`law_members` draws members of the (conditioned) law for the loop's marginalisation
(:meth:`bayestouch.planning.device_prober.DeviceProber.pose_ensemble`). Lengths in metres, times in seconds.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.inference.pose_error import principal_components
from bayestouch.physics import bending as bd
from bayestouch.physics import pose, sma
from bayestouch.scene.surface import Surface, signed_distance

__all__ = [
    "HeldLaw",
    "HELD_RANK",
    "HELD_GRID_DT",
    "prior_held_law",
    "law_at",
    "law_members",
    "law_mean_at",
    "condition_held_law",
    "Conditioned",
]

#: leading components of the held law (the rest is each member's remainder)
HELD_RANK = 8
#: spacing of the law's time grid, seconds
HELD_GRID_DT = 0.05


class HeldLaw(NamedTuple):
    """e(t) = mean + lead z + remainder_k, z ~ N(z_mean, z_chol z_cholᵀ) (module docstring).

    Attributes
    ----------
    hold_currents : (3,) float, amperes
    grid : (N,) float, seconds
        Times since the stroke's start.
    mean : (N, 3) float, metres
    lead : (N, 3, r) float, metres
        The members' r leading principal components (scaled: z ~ N(0, I) reproduces their covariance).
    remainder : (K, N, 3) float, metres
        Each member's deviation outside the leading components.
    z_mean : (r,) float
    z_chol : (r, r) float
        Lower Cholesky factor of z's covariance.
    """

    hold_currents: np.ndarray
    grid: np.ndarray
    mean: np.ndarray
    lead: np.ndarray
    remainder: np.ndarray
    z_mean: np.ndarray
    z_chol: np.ndarray


def prior_held_law(
    wire: sma.WireParams,
    rod: bd.RodParams,
    hold_currents,
    span: float,
    *,
    spread: pose.FingerSpread | None = None,
    draws: int = 64,
    seed: int = 0,
    rank: int = HELD_RANK,
) -> HeldLaw:
    """The held law of ``draws`` fingers drawn about the nominal constants (module docstring).

    Parameters
    ----------
    wire, rod : WireParams, RodParams
        The host's nominal constants.
    hold_currents : (3,) float, amperes
    span : float, seconds
        The longest stroke the law covers (its grid runs from 0 to ``span`` in :data:`HELD_GRID_DT`).
    spread : FingerSpread, optional
        How far the finger may be from nominal (default :class:`~bayestouch.physics.pose.FingerSpread`).
    draws : int
        Drawn fingers K (> ``rank``).
    seed : int
    rank : int
        Leading components r kept.

    Returns
    -------
    HeldLaw
        With z ~ N(0, I).
    """
    if not (isinstance(span, int | float | np.floating) and np.isfinite(span) and 0 <= span <= 600):
        raise BadInput(f"span: expected the longest stroke in seconds, in [0, 600], got {span!r}")
    if not (isinstance(rank, int | np.integer) and 1 <= rank < int(draws)):
        raise BadInput(f"rank: expected an integer in [1, draws) (draws {draws}), got {rank!r}")
    grid = np.arange(0.0, float(span) + 1.5 * HELD_GRID_DT, HELD_GRID_DT)
    e = pose.held_error_ensemble(wire, rod, hold_currents, grid, spread=spread, draws=draws, seed=seed)
    mu, lead, rem = principal_components(e, rank)
    return HeldLaw(np.asarray(hold_currents, float).reshape(3), grid, mu, lead, rem, np.zeros(rank), np.eye(rank))


def law_at(law: HeldLaw, times) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The law's mean (M, 3), leading components (M, 3, r) and remainders (K, M, 3) at ``times`` (M,) seconds since
    each stroke's start (linear interpolation on the grid; refused beyond it)."""
    t = np.asarray(times, dtype=float).reshape(-1)
    if not np.all(np.isfinite(t)) or np.any(t < -1e-9) or np.any(t > law.grid[-1] + 1e-9):
        raise BadInput(
            f"times: expected times since a stroke's start within the law's [0, {law.grid[-1]:.3g}] s, got "
            f"{float(np.min(t)) if t.size else 'none'} to {float(np.max(t)) if t.size else 'none'} s"
        )
    return (
        pose.interp_grid(law.grid, law.mean, t),
        pose.interp_grid(law.grid, law.lead, t),
        pose.interp_grid(law.grid, law.remainder, t, axis=1),
    )


def law_mean_at(law: HeldLaw, times) -> np.ndarray:
    """The law's posterior-mean tip error (M, 3) metres, finger-base frame, at ``times`` (M,) seconds since each
    stroke's start: mean + lead z_mean (the remainders average to about zero)."""
    mean, lead, _ = law_at(law, times)
    return mean + lead @ np.asarray(law.z_mean, float)


def law_members(law: HeldLaw, count: int, seed: int = 0) -> np.ndarray:
    """``count`` members (count, N, 3) metres of the law on its grid: mean + lead (z_mean + z_chol ξ) + the
    remainder of a member drawn with replacement, ξ ~ N(0, I) (seeded)."""
    if not (isinstance(count, int | np.integer) and count >= 2):
        raise BadInput(f"count: expected an integer ≥ 2 members, got {count!r}")
    rng = np.random.default_rng(seed)
    z = law.z_mean + rng.standard_normal((int(count), len(law.z_mean))) @ law.z_chol.T
    pick = rng.integers(0, len(law.remainder), int(count))
    return law.mean[None] + np.einsum("ncr,kr->knc", law.lead, z) + law.remainder[pick]


class Conditioned(NamedTuple):
    """A held law conditioned on touches of a known object (:func:`condition_held_law`).

    Attributes
    ----------
    law : HeldLaw
        The law with z's posterior.
    residual_rms : float, metres
        RMS of the contacts' signed distances after correction by the posterior mean.
    residual_rms_prior : float, metres
        The same with the prior mean (what the host's nominal constants leave).
    contacts : int
    iterations : int
    """

    law: HeldLaw
    residual_rms: float
    residual_rms_prior: float
    contacts: int
    iterations: int


@jax.jit
def _phi_and_normal(surf: Surface, x):
    """Signed distances (M,) m and unit gradients (M, 3) of the true surface at ``x (M, 3)``."""
    phi = signed_distance(surf, x)
    g = jax.vmap(jax.grad(lambda y: signed_distance(surf, y[None])[0]))(x)
    return phi, g / jnp.linalg.norm(g, axis=-1, keepdims=True)


def condition_held_law(
    law: HeldLaw,
    surf: Surface,
    points,
    approach,
    times,
    noise_sd: float,
    *,
    iterations: int = 8,
) -> Conditioned:
    """The held law's posterior given contacts on a known surface (module docstring).

    Parameters
    ----------
    law : HeldLaw
        The prior (:func:`prior_held_law`).
    surf : Surface
        The touched object's true surface, in the world frame of ``points``
        (:meth:`bayestouch.scene.objects.SceneObject.surface`).
    points : (M, 3) float, metres
        Contacts where the host computed them.
    approach : (M, 3) float
        Unit approach directions (the pad moved along them; −the plan's normal).
    times : (M,) float, seconds
        Each contact's time since its stroke's start.
    noise_sd : float, metres
        The contacts' own noise (encoders, threshold) per coordinate.
    iterations : int
        Gauss–Newton steps (stopped early when the step is below 1e-6 in z).

    Returns
    -------
    Conditioned
    """
    p = np.asarray(points, dtype=float)
    u = np.asarray(approach, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3 or not np.all(np.isfinite(p)):
        raise BadInput(f"points: expected finite (M ≥ 3, 3) contacts in metres, got shape {p.shape}")
    if u.shape != p.shape or not np.all(np.isfinite(u)) or np.any(np.linalg.norm(u, axis=1) < 0.5):
        raise BadInput(f"approach: expected {p.shape} unit approach directions, got shape {u.shape}")
    if not (np.isfinite(noise_sd) and noise_sd > 0):
        raise BadInput(f"noise_sd: expected a positive contact noise in metres, got {noise_sd!r}")
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    mu, lead, rem = law_at(law, times)
    rot = np.stack([pose.rotation_between([0.0, 0.0, 1.0], ui) for ui in u])  # (M, 3, 3)
    lead_w = np.einsum("mij,mjr->mir", rot, lead)  # world frame
    base = p + np.einsum("mij,mj->mi", rot, mu)
    rem_w = np.einsum("mij,kmj->kmi", rot, rem)
    r = lead.shape[2]

    def linearised(z):
        """Signed distances (M,) at the contacts moved by z, their Jacobian in z (M, r) and weights (M,)."""
        phi, nrm = (np.asarray(a) for a in _phi_and_normal(surf, jnp.asarray(base + lead_w @ z)))
        var = noise_sd**2 + np.mean(np.einsum("mi,kmi->km", nrm, rem_w) ** 2, axis=0)
        return phi, np.einsum("mi,mir->mr", nrm, lead_w), 1.0 / var

    z = np.zeros(r)
    done = 0
    while done < int(iterations):
        done += 1
        phi, J, W = linearised(z)
        step = np.linalg.solve(J.T @ (W[:, None] * J) + np.eye(r), J.T @ (W * phi) + z)
        z = z - step
        if np.max(np.abs(step)) < 1e-6:
            break
    phi, J, W = linearised(z)
    cov = np.linalg.inv(J.T @ (W[:, None] * J) + np.eye(r))
    chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    phi0 = np.asarray(_phi_and_normal(surf, jnp.asarray(base))[0])
    return Conditioned(
        law._replace(z_mean=z, z_chol=chol),
        float(np.sqrt(np.mean(phi**2))),
        float(np.sqrt(np.mean(phi0**2))),
        len(p),
        done,
    )
