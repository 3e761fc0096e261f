"""The forward model: object surface + stroke + finger → taxel currents, frame by frame (pad geometry, contact,
skin pressure and force, taxel currents with their lag, noise).

Pure JAX: ``jit``-able, ``vmap``-able over surfaces, differentiable in the surface. A stroke is T frames (contact
points and normals (T, 3) m, a pressing depth in m); SI units throughout. The chain step by step:
``docs/physics_notes.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.physics import noise as nz
from bayestouch.physics import skin as sk
from bayestouch.physics import taxel as tx
from bayestouch.scene.surface import Surface, signed_distance

__all__ = [
    "Finger",
    "Frames",
    "pad_points",
    "contact_frame",
    "simulate",
    "clean_currents",
    "friction_force",
    "make_finger",
    "stroke_arrays",
    "depths_for_force",
    "elastic_force",
    "pressure_from_distance",
    "current_from_distance",
    "log_current_from_distance",
    "P_MAX",
]


class Finger(NamedTuple):
    """Everything about the finger the forward model needs (a pytree).

    skin : SkinParams
    taxels : TaxelParams
    noise : NoiseParams
    grid : (H, W, 2) float, metres
        Pad coordinates (u, v) of the taxels; u along the stroke direction.
    reference : (H, W) bool
        Unloaded reference taxels (drift compensation).
    gains : (H·W,) float
        Fixed-pattern gains of this device.
    tip_radius : float, metres
        Radius of the fingertip's outer (skin) surface.
    kernel : (N, N) float
        Pressure blur between taxels (:func:`~bayestouch.physics.skin.blur_kernel`; any layout).
    cell_area : float, m²
        Skin area per taxel: force = Σ p · cell_area.
    """

    skin: sk.SkinParams
    taxels: tx.TaxelParams
    noise: nz.NoiseParams
    grid: jnp.ndarray
    reference: jnp.ndarray
    gains: jnp.ndarray
    tip_radius: jnp.ndarray
    kernel: jnp.ndarray
    cell_area: jnp.ndarray


class Frames(NamedTuple):
    """Output of :func:`simulate` (T frames, N = H·W taxels).

    taxel_current : (T, N) float, amperes
        Measured (lagged, noisy, quantised) currents.
    clean_current : (T, N) float, amperes
        Lagged currents without noise.
    pressure : (T, H, W) float, pascals
    penetration : (T, H, W) float, metres
    force : (T,) float, newtons
        Normal contact force (elastic + Hunt–Crossley damping).
    taxel_position : (T, N, 3) float, metres
    friction : (T,) float, newtons
        Tangential force resisting the motion (eq. 20 with the smooth Coulomb cap): the skin shears by the
        distance slid since the stroke started, k_t = G A_c / h, capped at μ F_n.
    """

    taxel_current: jnp.ndarray
    clean_current: jnp.ndarray
    pressure: jnp.ndarray
    penetration: jnp.ndarray
    force: jnp.ndarray
    taxel_position: jnp.ndarray
    friction: jnp.ndarray


def make_finger(
    skin: sk.SkinParams, taxels: tx.TaxelParams, noise: nz.NoiseParams, *, tip_radius: float, seed: int = 0
) -> Finger:
    """Assemble a :class:`Finger` (NumPy edge): taxel grid from ``taxels``, fixed pattern from ``seed``.

    Parameters
    ----------
    tip_radius : float, metres
    seed : int
        Draws this device's fixed-pattern gains.
    """
    lay = tx.layout(taxels)
    grid = lay.positions.reshape(lay.rows, lay.cols, 2)
    ref = lay.reference.reshape(lay.rows, lay.cols)
    gains = nz.fixed_pattern(jax.random.PRNGKey(seed), noise, lay.rows * lay.cols)
    area = tx.cell_area(taxels)
    kernel = sk.blur_kernel(lay.positions, sk.blur_width(skin), area)
    return Finger(
        skin,
        taxels,
        noise,
        jnp.asarray(grid),
        jnp.asarray(ref),
        jnp.asarray(gains),
        jnp.asarray(float(tip_radius)),
        kernel,
        jnp.asarray(area),
    )


def elastic_force(finger: Finger, pressure):
    """Normal force (...,) N of a pressure map (..., H, W) Pa: Σ p · cell_area."""
    return jnp.sum(pressure, axis=(-2, -1)) * finger.cell_area


def pad_points(finger: Finger, contact, normal, tangent, depth):
    """Taxel positions (H, W, 3) in metres for one frame.

    Parameters
    ----------
    contact : (3,) float, metres
        Where the pad centre touches the (undeformed) surface.
    normal : (3,) float
        Outward unit surface normal there.
    tangent : (3,) float
        Direction of motion.
    depth : float, metres
        Pressing depth of the pad centre.
    """
    n = normal / jnp.linalg.norm(normal)
    t = tangent - jnp.dot(tangent, n) * n
    e1 = t / jnp.sqrt(jnp.sum(t * t) + 1e-30)
    e2 = jnp.cross(n, e1)
    R = finger.tip_radius
    centre = contact + (R - depth) * n
    u, v = finger.grid[..., 0], finger.grid[..., 1]
    rho = jnp.sqrt(u * u + v * v + 1e-30)
    th = rho / R
    side = (u[..., None] * e1 + v[..., None] * e2) / rho[..., None]
    return centre + R * (-jnp.cos(th)[..., None] * n + jnp.sin(th)[..., None] * side)


#: pressure cap, Pa, of the likelihoods' chain: far beyond the skin's densification (tens of kPa), it only keeps
#: absurd shapes finite
P_MAX = 1e6


def pressure_from_distance(skin: sk.SkinParams, sdf, kernel, p_max=None):
    """Contact (eq. 14–15) and skin: signed distances → penetration δ = s·softplus(−φ/s) → blurred pressure.

    Parameters
    ----------
    skin : SkinParams
    sdf : (..., J) float, metres
        Signed distances of the J taxels that may touch the object.
    kernel : (M, J) float
        Pressure blur from those J taxels onto the M modelled ones.
    p_max : float, Pa, optional
        Cap on the pressure (:data:`P_MAX` in the likelihoods; none in the simulator).

    Returns
    -------
    (penetration (..., J) m, pressure (..., M) Pa)
    """
    delta = sk.penetration(sdf, skin.s)
    p = sk.pressure_at_taxels(skin, delta, kernel)
    return delta, (p if p_max is None else jnp.minimum(p, p_max))


def current_from_distance(finger: Finger, sdf, kernel, temperature, mode: str):
    """Taxel currents (F, M) A before the response lag: signed distance → penetration → pressure (≤
    :data:`P_MAX`) → current (the arguments as :func:`log_current_from_distance`'s)."""
    _, p = pressure_from_distance(finger.skin, sdf, kernel, P_MAX)
    return tx.taxel_current(finger.taxels, p, jnp.asarray(temperature)[:, None], mode=mode)


def log_current_from_distance(finger: Finger, sdf, kernel, temperature, start, lag_weights, mode: str):
    """The forward chain of the likelihoods: signed distance → penetration → pressure (≤ :data:`P_MAX`) → taxel
    current → response lag on coarse frames → ln I (dimensionless, I in A).

    Parameters
    ----------
    finger : Finger
    sdf : (F, J) float, metres
        Signed distances of the penetrating taxels on F frames.
    kernel : (M, J) float
        Pressure blur onto the M modelled taxels.
    temperature : (F,) float, kelvin
        Skin temperature.
    start : (F,) bool
        First frame of a stroke (the lag restarts at steady state).
    lag_weights : (3,) float
        :func:`~bayestouch.physics.taxel.coarse_lag_weights`.
    mode : {"physics", "empirical"}
        Taxel response (static).

    Returns
    -------
    (F, M) float
    """
    cur = current_from_distance(finger, sdf, kernel, temperature, mode)
    return jnp.log(tx.coarse_lag(cur, jnp.asarray(start), jnp.asarray(lag_weights)))


def contact_frame(surf: Surface, finger: Finger, contact, normal, tangent, depth):
    """One frame of contact: (taxel positions (H, W, 3) m, penetration (H, W) m, pressure (H, W) Pa)."""
    x = pad_points(finger, contact, normal, tangent, depth)
    sdf = signed_distance(surf, x)
    delta, p = pressure_from_distance(finger.skin, sdf.reshape(-1), finger.kernel)
    return x, delta.reshape(sdf.shape), p.reshape(sdf.shape)


def clean_currents(surf: Surface, finger: Finger, stroke_arrays, skin_temperature, dt: float, mode: str):
    """Noise-free part of :func:`simulate`: (lagged currents (T, N) A, pressure, penetration, force, x)."""
    contact, normal, tangent, depth = stroke_arrays
    depth = jnp.broadcast_to(jnp.asarray(depth), contact.shape[:1])
    x, delta, p = jax.vmap(lambda c, n, t, d: contact_frame(surf, finger, c, n, t, d))(contact, normal, tangent, depth)
    p = jnp.where(finger.reference, 0.0, p)
    f_el = elastic_force(finger, p)
    d_centre = jnp.max(delta, axis=(-2, -1))
    d_dot = jnp.gradient(d_centre, dt) if d_centre.shape[0] > 1 else jnp.zeros_like(d_centre)
    force = sk.damped_contact_force(f_el, finger.skin.hc_damping, d_dot)
    nT = p.shape[0]
    temp = jnp.broadcast_to(jnp.asarray(skin_temperature), (nT,))[:, None]
    cur = tx.taxel_current(finger.taxels, p.reshape(nT, -1), temp, mode=mode)
    cur = tx.first_order_lag(cur, dt, finger.taxels.lag)
    return cur, p, delta, force, x.reshape(nT, -1, 3)


def friction_force(finger: Finger, stroke_arrays, force, delta):
    """Tangential force (T,) N of a stroke: eq. 20's smooth Coulomb cap on the skin's shear spring."""
    contact = stroke_arrays[0]
    step = jnp.sqrt(jnp.sum(jnp.diff(contact, axis=0) ** 2, axis=-1) + 1e-30)
    slid = jnp.concatenate([jnp.zeros(1), jnp.cumsum(step)])
    area = jnp.sum(jax.nn.sigmoid((delta - 2 * finger.skin.s) / finger.skin.s), axis=(-2, -1)) * finger.cell_area
    kt = sk.tangential_stiffness(finger.skin, area)
    return sk.friction(finger.skin.mu, jnp.maximum(force, 1e-12), kt, slid)


def simulate(
    surf: Surface,
    stroke_arrays,
    finger: Finger,
    key,
    *,
    skin_temperature=300.0,
    dt: float = 0.02,
    mode: str = "physics",
    noise: bool = True,
) -> Frames:
    """The whole chain for one stroke.

    Parameters
    ----------
    surf : Surface
        The object (shape, FFD, texture, defects): what inference is about.
    stroke_arrays : tuple (contact (T, 3) m, normal (T, 3), tangent (T, 3), depth m or (T,) m)
        From a :class:`~bayestouch.scene.strokes.Stroke` (see :func:`stroke_arrays`).
    finger : Finger
    key : JAX PRNG key
        Noise draws.
    skin_temperature : float or (T,) float, kelvin
    dt : float, seconds
        Frame interval.
    mode : {"physics", "empirical"}
        Taxel response (static).
    noise : bool
        Add the noise model (static).

    Returns
    -------
    Frames
    """
    cur, p, delta, force, x = clean_currents(surf, finger, stroke_arrays, skin_temperature, dt, mode)
    meas = nz.add_noise(key, finger.noise, cur, dt, finger.gains) if noise else cur
    return Frames(meas, cur, p, delta, force, x, friction_force(finger, stroke_arrays, force, delta))


@jax.jit
def depths_for_force(surf: Surface, finger: Finger, stroke_arrays, force, max_depth=1.5e-3):
    """Per-frame pressing depths (T,) m that make the elastic normal force equal ``force`` (N, scalar or
    (T,)): force control, by 40 bisection steps per frame (vectorised, differentiable only through the
    final midpoint). Frames where even ``max_depth`` cannot reach the force get ``max_depth``."""
    contact, normal, tangent, _ = stroke_arrays
    target = jnp.broadcast_to(jnp.asarray(force, dtype=float), contact.shape[:1])

    def f_el(c, n, t, d):
        _, _, p = contact_frame(surf, finger, c, n, t, d)
        return elastic_force(finger, jnp.where(finger.reference, 0.0, p))

    def one(c, n, t, F):
        def body(_, lh):
            lo, hi = lh
            mid = 0.5 * (lo + hi)
            below = f_el(c, n, t, mid) < F
            return jnp.where(below, mid, lo), jnp.where(below, hi, mid)

        lo, hi = jax.lax.fori_loop(0, 40, body, (jnp.asarray(0.0), jnp.asarray(max_depth)))
        return 0.5 * (lo + hi)

    return jax.vmap(one)(contact, normal, tangent, target)


def stroke_arrays(stroke) -> tuple:
    """JAX arrays of a :class:`~bayestouch.scene.strokes.Stroke` for :func:`simulate`."""
    return (
        jnp.asarray(stroke.contact),
        jnp.asarray(stroke.normal),
        jnp.asarray(stroke.tangent),
        jnp.asarray(float(stroke.depth)),
    )


simulate_jit = jax.jit(simulate, static_argnames=("mode", "noise", "dt"))


def frame_rate_dt(stroke) -> float:
    """Frame interval (s) of a stroke's samples."""
    t = np.asarray(stroke.time)
    return float(np.median(np.diff(t))) if len(t) > 1 else 0.02
