"""The bending chain that places the pad: wire-current programs → wire temperatures and martensite fractions (lumped
thermal model + Brinson kinetics, which carry the NiTi hysteresis) → rod curvature (three-wire moment equilibrium) →
tip pose in the finger-base frame → pad pose in the world (base pose × tip pose) → where the pad meets the object.

Pure functions of arrays and the :class:`~bayestouch.physics.sma.WireParams` and
:class:`~bayestouch.physics.bending.RodParams` pytrees; SI units (metres, kelvin, seconds, amperes, pascals). The
equations and their simplifications: ``docs/physics_notes.md`` § "The bending chain".
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np
from scipy.optimize import minimize
from tqdm.auto import tqdm

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.physics import bending as bd
from bayestouch.physics import sma
from bayestouch.scene.surface import Surface, signed_distance

__all__ = [
    "TipPath",
    "tip_path",
    "PadPath",
    "pad_path",
    "pad_contact",
    "chain_stroke_arrays",
    "currents_for_bend",
    "CarrierProgram",
    "program_dt",
    "carrier_program",
    "carrier_pad_path",
    "rotation_between",
    "held_pose_error",
    "BEND_TEMPERATURE_MARGIN",
    "HysteresisLoop",
    "hysteresis_loop",
    "FingerSpread",
    "draw_finger",
    "BENDING_CONSTANTS",
    "with_constants",
    "pose_error_ensemble",
    "held_error_ensemble",
    "HELD_DT",
    "HELD_BUCKET",
    "interp_grid",
]


class TipPath(NamedTuple):
    """The rod's state over T frames (the finger-base frame: the rod leaves the base along +z).

    Attributes
    ----------
    wire_temperature : (T, 3) float, kelvin
    martensite : (T, 3) float, 1
        Martensite fraction ξ of each wire (its history is the hysteresis).
    stress : (T, 3) float, pascals
        Wire stresses at the bend's equilibrium.
    curvature : (T, 2) float, 1/metres
        Curvature vector u = κ (cos φ, sin φ).
    tip_position : (T, 3) float, metres
    tip_rotation : (T, 3, 3) float
        Tip frame in the base frame; its third column is the rod's tangent at the tip.
    """

    wire_temperature: np.ndarray
    martensite: np.ndarray
    stress: np.ndarray
    curvature: np.ndarray
    tip_position: np.ndarray
    tip_rotation: np.ndarray


def _check_currents(wire: sma.WireParams, currents) -> np.ndarray:
    cur = np.asarray(currents, dtype=float)
    if cur.ndim != 2 or cur.shape[1] != 3 or len(cur) < 1:
        raise BadInput(f"wire currents: expected an array of shape (T, 3) in amperes, got shape {cur.shape}")
    if not np.all(np.isfinite(cur)) or np.any(cur < 0) or np.any(cur > wire.max_current):
        raise BadInput(f"wire currents must be finite and within [0, {wire.max_current:g}] A")
    return cur


def _check_times(time) -> np.ndarray:
    """``time`` as a (T ≥ 2,) float array of finite, strictly increasing seconds; :class:`BadInput` naming ``time``
    otherwise."""
    t = np.asarray(time, dtype=float)
    if t.ndim != 1 or len(t) < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise BadInput(f"time: expected T ≥ 2 finite, strictly increasing frame times in seconds, got shape {t.shape}")
    return t


def _orthonormal(R) -> bool:
    """Whether every 3 × 3 matrix of ``R (..., 3, 3)`` is finite and orthonormal (to 1e-6)."""
    R = np.asarray(R, dtype=float)
    return bool(np.all(np.isfinite(R)) and np.max(np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3))) <= 1e-6)


@partial(jax.jit, static_argnames=("substeps",))
def _chain(wire, rod, currents, dt, T0, xi0, substeps):
    """The causal scan of :func:`tip_path`: (temperatures, martensite, stresses (T, 3), curvatures (T, 2))."""
    cold = bd.curvature_equilibrium(rod, wire, jnp.full(3, wire.ambient), jnp.ones(3))
    state = sma.wire_state_init(wire, T0, xi0, cold.stress)

    def step(carry, current):
        st, sig = carry
        st = sma.wire_step(wire, st, current, sig, dt, substeps)
        eq = bd.curvature_equilibrium(rod, wire, st.temperature, st.brinson.xi)
        return (st, eq.stress), (st.temperature, st.brinson.xi, eq.stress, eq.u)

    _, out = jax.lax.scan(step, (state, cold.stress), currents)
    return out


def tip_path(
    wire: sma.WireParams,
    rod: bd.RodParams,
    currents,
    dt: float,
    *,
    T0=None,
    xi0=1.0,
    substeps: int = 10,
) -> TipPath:
    """Wire currents → the rod's curvature and tip pose, frame by frame.

    Each frame, every wire's temperature and martensite fraction advance by one sample of the lumped thermal model
    and the Brinson kinetics (:func:`bayestouch.physics.sma.wire_step`) under the stress the wire carried at the
    previous frame's bend; then the curvature is the three-wire moment equilibrium
    (:func:`bayestouch.physics.bending.curvature_equilibrium`) at the new temperatures and fractions, which gives
    the stresses for the next frame. The coupling is causal: the Brinson branch memory (the hysteresis) sees the
    stresses in the order they happen (a fixed point over the whole program instead flips between a bent and a
    straight end state, because a cooling wire transforms back only under the high stress of the bend).

    Parameters
    ----------
    wire : WireParams
    rod : RodParams
    currents : (T, 3) float, amperes
        Current program of the three wires, held for ``dt`` per frame.
    dt : float, seconds
        Frame interval (keep ``dt / substeps`` ≲ 10 ms inside the transformation windows).
    T0 : float or (3,) float, kelvin, optional
        Initial wire temperatures (default ambient).
    xi0 : float or (3,) float, 1
        Initial martensite fractions (default 1: cold, as after a long rest).
    substeps : int
        Thermal integration steps per frame.

    Returns
    -------
    TipPath
    """
    cur = _check_currents(wire, currents)
    if not (np.isfinite(dt) and dt > 0):
        raise BadInput(f"dt: expected a positive frame interval in seconds, got {dt}")
    T0 = jnp.broadcast_to(jnp.asarray(wire.ambient if T0 is None else T0, dtype=float), (3,))
    xi0 = jnp.broadcast_to(jnp.asarray(xi0, dtype=float), (3,))
    temps, xi, stress, u = (np.asarray(a) for a in _chain(wire, rod, jnp.asarray(cur), float(dt), T0, xi0, substeps))
    p, R = _poses(rod, jnp.asarray(u))
    return TipPath(temps, xi, stress, u, np.asarray(p), np.asarray(R))


_poses = jax.jit(jax.vmap(bd.tip_pose, in_axes=(None, 0)))


class FingerSpread(NamedTuple):
    """How far a finger's bending constants may lie from the nominal ones (``models/finger.toml``) when nothing has
    calibrated them. Assumptions, not measurements (``docs/physics_notes.md`` § "Pose error"):

    Attributes
    ----------
    EI_log_sd : float, 1
        Bending stiffness EI × exp(N(0, EI_log_sd²)) (physics.md §2 puts EI_eff anywhere in 3e-4–1.5e-3 N m²).
    prestrain : (float, float), 1
        Pre-strain uniform on this range (Flexinol's 3–5 % stroke).
    shift_sd : float, kelvin
        The four transformation temperatures shifted together by N(0, shift_sd²) (alloy batches).
    convection : (float, float), 1
        Film coefficient × uniform on this range (still air against a draught).
    ambient : float, kelvin
        Ambient temperature + uniform on [−ambient, ambient].
    """

    EI_log_sd: float = 0.2
    prestrain: tuple = (0.035, 0.045)
    shift_sd: float = 3.0
    convection: tuple = (0.8, 1.25)
    ambient: float = 3.0

    def widened(self, factor: float) -> FingerSpread:
        """The spread with every sd and half-width × ``factor`` (ranges about their centres; the convection range
        in log space)."""
        if not (np.isfinite(factor) and factor > 0):
            raise BadInput(f"factor: expected a positive number, got {factor!r}")
        mid, half = 0.5 * (self.prestrain[0] + self.prestrain[1]), 0.5 * (self.prestrain[1] - self.prestrain[0])
        lc = np.log(self.convection)
        cmid, chalf = 0.5 * (lc[0] + lc[1]), 0.5 * (lc[1] - lc[0])
        return FingerSpread(
            self.EI_log_sd * factor,
            (mid - factor * half, mid + factor * half),
            self.shift_sd * factor,
            (float(np.exp(cmid - factor * chalf)), float(np.exp(cmid + factor * chalf))),
            self.ambient * factor,
        )


def draw_finger(
    rng: np.random.Generator, wire: sma.WireParams, rod: bd.RodParams, spread: FingerSpread | None = None
) -> tuple[sma.WireParams, bd.RodParams]:
    """A finger's wire and rod constants drawn about the nominal ``wire`` and ``rod`` as ``spread`` says (default
    :class:`FingerSpread`); only the five constants of the spread change."""
    sp = FingerSpread() if spread is None else spread
    shift = float(rng.normal(0.0, sp.shift_sd))
    prestrain = float(rng.uniform(*sp.prestrain))
    convection = float(rng.uniform(*sp.convection))
    ambient = float(rng.uniform(-sp.ambient, sp.ambient))
    EI = float(np.exp(rng.normal(0.0, sp.EI_log_sd)))
    return with_constants(wire, rod, (EI, prestrain, shift, convection, ambient))


#: the five bending constants a finger's spread covers (:class:`FingerSpread`), as :func:`with_constants` takes them
BENDING_CONSTANTS = ("EI_factor", "prestrain", "transformation_shift_K", "convection_factor", "ambient_shift_K")


def with_constants(wire: sma.WireParams, rod: bd.RodParams, values) -> tuple[sma.WireParams, bd.RodParams]:
    """``wire`` and ``rod`` with the five constants of :data:`BENDING_CONSTANTS` set from ``values``: EI × factor,
    the pre-strain (1), the four transformation temperatures + shift (K), the film coefficient × factor, the ambient
    temperature + shift (K)."""
    v = np.asarray(values, dtype=float).reshape(-1)
    if v.shape != (5,) or not np.all(np.isfinite(v)) or v[0] <= 0 or v[3] <= 0 or not 0 < v[1] < 0.2:
        raise BadInput(
            f"values: expected the five {', '.join(BENDING_CONSTANTS)} (factors > 0, a pre-strain in (0, 0.2)), "
            f"got {v.tolist()}"
        )
    EI, prestrain, shift, convection, ambient = (float(x) for x in v)
    w = wire._replace(
        prestrain=prestrain,
        M_f=wire.M_f + shift,
        M_s=wire.M_s + shift,
        A_s=wire.A_s + shift,
        A_f=wire.A_f + shift,
        convection=wire.convection * convection,
        ambient=wire.ambient + ambient,
    )
    return w, rod._replace(EI=rod.EI * EI)


def pose_error_ensemble(
    wire: sma.WireParams,
    rod: bd.RodParams,
    programs,
    dt: float,
    frames,
    *,
    spread: FingerSpread | None = None,
    draws: int = 64,
    seed: int = 0,
    rotations=None,
    substeps: int = 10,
    progress: bool = False,
) -> np.ndarray:
    """What a host that knows only the nominal constants and their spread can say about its pad-pose error: the
    errors p_finger − p_nominal of ``draws`` fingers drawn about the nominal one (:func:`draw_finger`), each run
    through the commanded programs, at the frames where contacts were recorded.

    Parameters
    ----------
    wire, rod : WireParams, RodParams
        The host's nominal constants.
    programs : sequence of S (T_s, 3) float arrays, amperes
        Each stroke's wire-current program (every stroke starts cold, as :func:`tip_path` does by default).
    dt : float, seconds
        Frame interval.
    frames : sequence of S (F_s,) int arrays
        The frames of each stroke at which contacts were recorded.
    spread : FingerSpread, optional
        How far the finger may be from nominal (default :class:`FingerSpread`).
    draws : int
        Number of fingers K (≥ 2).
    seed : int
        Seed of the drawn fingers (the same fingers run every stroke).
    rotations : (S, 3, 3) float, optional
        World-from-base rotation of each stroke (default identity): errors are returned in world axes.
    substeps : int
        Thermal integration steps per frame (:func:`tip_path`).
    progress : bool
        Show a progress bar over the K × S chain runs.

    Returns
    -------
    (K, Σ F_s, 3) float, metres
        Pose errors of every drawn finger at every recorded contact, strokes concatenated in order.
    """
    if int(draws) < 2:
        raise BadInput(f"draws: expected at least 2 drawn fingers, got {draws!r}")
    if not (np.isfinite(dt) and dt > 0):
        raise BadInput(f"dt: expected a positive frame interval in seconds, got {dt}")
    progs = [_check_currents(wire, c) for c in programs]
    frs = [np.asarray(f) for f in frames]
    if len(frs) != len(progs):
        raise BadInput(f"frames: expected one array of frame indices per program ({len(progs)}), got {len(frs)}")
    for c, f in zip(progs, frs, strict=True):
        if f.ndim != 1 or f.dtype.kind not in "iu" or np.any(f < 0) or np.any(f >= len(c)):
            raise BadInput(f"frames: expected integer frame indices within [0, {len(c)}) for each program")
    rots = np.broadcast_to(np.eye(3), (len(progs), 3, 3)) if rotations is None else np.asarray(rotations, float)
    if rots.shape != (len(progs), 3, 3) or not _orthonormal(rots):
        raise BadInput(f"rotations: expected ({len(progs)}, 3, 3) rotation matrices, got shape {rots.shape}")
    rng = np.random.default_rng(seed)
    fingers = [draw_finger(rng, wire, rod, spread) for _ in range(int(draws))]
    out = []
    bar = tqdm(total=len(progs) * len(fingers), desc="drawn fingers", unit="run", disable=not progress)
    for c, f, R in zip(progs, frs, rots, strict=True):
        nominal = tip_path(wire, rod, c, dt, substeps=substeps).tip_position[f]
        tips = []
        for w, r in fingers:
            tips.append(tip_path(w, r, c, dt, substeps=substeps).tip_position[f])
            bar.update()
        out.append((np.stack(tips) - nominal) @ R.T)
    bar.close()
    return np.concatenate(out, axis=1)


class PadPath(NamedTuple):
    """Where the pad is in the world over T frames.

    Attributes
    ----------
    centre : (T, 3) float, metres
        Centre of the fingertip's spherical pad (the rod's tip).
    tangent : (T, 3) float
        Unit tangent of the rod at the tip (the direction the pad faces).
    tip : TipPath
        The rod's state in the base frame.
    """

    centre: np.ndarray
    tangent: np.ndarray
    tip: TipPath


def pad_path(
    wire: sma.WireParams,
    rod: bd.RodParams,
    currents,
    dt: float,
    base_position,
    base_rotation=None,
    **kw,
) -> PadPath:
    """The pad's path in the world: the carrier's base pose × the bent rod's tip pose (:func:`tip_path`).

    Parameters
    ----------
    currents : (T, 3) float, amperes
    dt : float, seconds
    base_position : (T, 3) or (3,) float, metres
        The finger base's position in the world (where the stage or arm carries it).
    base_rotation : (T, 3, 3) or (3, 3) float, optional
        World-from-base rotation (default identity: the rod leaves the base along world +z).
    **kw
        Passed to :func:`tip_path`.

    Returns
    -------
    PadPath
    """
    tip = tip_path(wire, rod, currents, dt, **kw)
    T = len(tip.tip_position)
    pos = np.broadcast_to(np.asarray(base_position, dtype=float), (T, 3))
    rot = np.eye(3) if base_rotation is None else np.asarray(base_rotation, dtype=float)
    rot = np.broadcast_to(rot, (T, 3, 3))
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(rot))):
        raise BadInput("base_position, base_rotation: expected finite metres and rotation matrices")
    if not _orthonormal(rot):
        raise BadInput("base_rotation: expected orthonormal 3 × 3 rotation matrices")
    centre = pos + np.einsum("tij,tj->ti", rot, tip.tip_position)
    tangent = np.einsum("tij,tj->ti", rot, tip.tip_rotation[:, :, 2])
    return PadPath(centre, tangent, tip)


#: closest-point refinements of :func:`pad_contact` (each contracts the foot's error by about the pad centre's
#: distance over the surface's radius of curvature: 16 take a pad 7 mm off a 2 cm radius to well under a micrometre)
REFINE_STEPS = 16


@jax.jit
def _foot(surf: Surface, x):
    """Foot point on the surface, outward normal and signed distance of points ``x (T, 3)`` in metres: three
    projections along the signed distance's gradient, then :data:`REFINE_STEPS` steps that make the foot's normal
    pass through the point (the closest point's condition); the distance is the Euclidean one to the foot, with the
    sign of the point's signed distance."""

    phi_and_grad = jax.value_and_grad(lambda q: signed_distance(surf, q))

    def one(p):
        def step(q, _):
            phi, g = phi_and_grad(q)
            return q - phi * g / jnp.linalg.norm(g), phi

        foot, phis = jax.lax.scan(step, p, None, length=3)
        side = jnp.sign(phis[0])

        def refine(q, _):
            # the closest point's normal passes through p: step from p along the foot's normal by its distance,
            # then project that point (now micrometres from the surface, where the first order is exact) again
            _, g = phi_and_grad(q)
            x = p - side * jnp.linalg.norm(p - q) * g / jnp.linalg.norm(g)
            return step(x, None)[0], None

        foot, _ = jax.lax.scan(refine, foot, None, length=REFINE_STEPS)
        _, g = phi_and_grad(foot)
        # the distance to the foot, signed as the point's side: the signed distance itself is first order, off by
        # tens of micrometres at a pad centre millimetres from a curved surface
        return foot, g / jnp.linalg.norm(g), side * jnp.linalg.norm(p - foot)

    return jax.vmap(one)(x)


def pad_contact(surf: Surface, centre, tip_radius: float):
    """Where a spherical pad of radius ``tip_radius`` centred at ``centre`` meets the object.

    The pad touches the surface at the foot of its centre (the nearest surface point), pressed by the overlap
    ``depth = tip_radius − φ(centre)``; a negative depth is a pad clear of the object (no contact). The result feeds
    :func:`bayestouch.physics.forward.simulate` in place of a stroke's commanded contact points: its pad is then
    centred exactly at ``centre`` (``contact + (R − depth) n``).

    Parameters
    ----------
    surf : Surface
    centre : (T, 3) float, metres
    tip_radius : float, metres

    Returns
    -------
    contact : (T, 3) float, metres
    normal : (T, 3) float
        Outward unit normal at the contact.
    depth : (T,) float, metres
    """
    foot, normal, phi = _foot(surf, jnp.asarray(centre, dtype=float))
    return np.asarray(foot), np.asarray(normal), float(tip_radius) - np.asarray(phi)


class HysteresisLoop(NamedTuple):
    """A quasi-static current sweep of one wire up and down.

    Attributes
    ----------
    current : (K,) float, amperes
    deflection : (K,) float, metres
        Lateral tip deflection √(x² + y²) in the base frame.
    temperature : (K,) float, kelvin
        The swept wire's temperature.
    martensite : (K,) float, 1
        The swept wire's martensite fraction.
    heating : (K,) bool
        True on the rising half of the sweep.
    """

    current: np.ndarray
    deflection: np.ndarray
    temperature: np.ndarray
    martensite: np.ndarray
    heating: np.ndarray


def hysteresis_loop(
    wire: sma.WireParams,
    rod: bd.RodParams,
    *,
    wire_index: int = 0,
    peak: float | None = None,
    sweep_s: float = 120.0,
    dt: float = 0.05,
) -> HysteresisLoop:
    """Tip deflection against the current of one wire, swept 0 → ``peak`` → 0 in ``sweep_s`` seconds each way (the
    other two wires unpowered): slow against the wire's thermal time constant, so the loop is the NiTi hysteresis
    and not the thermal lag.

    Parameters
    ----------
    wire_index : int
        The swept wire (0, 1, 2).
    peak : float, amperes, optional
        Top of the sweep (default :func:`bayestouch.physics.sma.max_steady_current`, the most current the wire
        carries in steady state within its temperature limit).
    sweep_s : float, seconds
    dt : float, seconds

    Returns
    -------
    HysteresisLoop
    """
    if wire_index not in (0, 1, 2):
        raise BadInput(f"wire_index: expected 0, 1 or 2, got {wire_index}")
    peak = float(sma.max_steady_current(wire)) if peak is None else float(peak)
    n = max(2, int(round(sweep_s / dt)))
    up = np.linspace(0.0, peak, n)
    I = np.concatenate([up, up[::-1]])
    cur = np.zeros((2 * n, 3))
    cur[:, wire_index] = I
    path = tip_path(wire, rod, cur, dt)
    defl = np.linalg.norm(path.tip_position[:, :2], axis=1)
    heating = np.arange(2 * n) < n
    return HysteresisLoop(I, defl, path.wire_temperature[:, wire_index], path.martensite[:, wire_index], heating)


def chain_stroke_arrays(surf: Surface, pad: PadPath, tip_radius: float) -> tuple:
    """The stroke that the pad's path makes on the object, as :func:`bayestouch.physics.forward.simulate` takes it:
    contact points and normals where the pad meets the surface (:func:`pad_contact`), the direction of motion of
    the pad centre, and the per-frame overlap as the pressing depth (negative: clear of the object, no pressure).

    Parameters
    ----------
    surf : Surface
    pad : PadPath
    tip_radius : float, metres
        Radius of the pad's outer (skin) surface (``Finger.tip_radius``).

    Returns
    -------
    tuple (contact (T, 3) m, normal (T, 3), tangent (T, 3), depth (T,) m) of JAX arrays
    """
    contact, normal, depth = pad_contact(surf, pad.centre, tip_radius)
    move = np.gradient(pad.centre, axis=0) if len(pad.centre) > 1 else np.zeros_like(pad.centre)
    # a pad that does not move (or moves along the normal) slides nowhere: any tangent direction serves
    fallback = np.cross(normal, [0.0, 0.0, 1.0])
    fallback = np.where(np.linalg.norm(fallback, axis=1, keepdims=True) > 1e-6, fallback, [1.0, 0.0, 0.0])
    along = move - np.sum(move * normal, axis=1, keepdims=True) * normal
    tangent = np.where(np.linalg.norm(along, axis=1, keepdims=True) > 1e-12, along, fallback)
    tangent = tangent / np.linalg.norm(tangent, axis=1, keepdims=True)
    return jnp.asarray(contact), jnp.asarray(normal), jnp.asarray(tangent), jnp.asarray(depth)


#: margin (K) below the wire's temperature limit that :func:`currents_for_bend` keeps
BEND_TEMPERATURE_MARGIN = 5.0


@jax.jit
def _bend_cost(x, wire, rod, target, scale, lam):
    """Squared curvature miss (relative to ``scale``) plus ``lam`` × the squared heating, for temperatures
    ``ambient + x`` (K); the major heating branch from cold."""
    u = bd.curvature_equilibrium(rod, wire, wire.ambient + x).u
    return jnp.sum(((u - target) / scale) ** 2) + lam * jnp.sum((x / 100.0) ** 2)


_bend_cost_and_grad = jax.jit(jax.value_and_grad(_bend_cost))


def currents_for_bend(wire: sma.WireParams, rod: bd.RodParams, curvature, *, tolerance: float = 0.02):
    """The steady wire currents that bend the rod to ``curvature``, approached by heating from cold: the inverse of
    the bending chain on its major heating branch, the least heating among the solutions.

    The three wire temperatures (between ambient and the limit less :data:`BEND_TEMPERATURE_MARGIN`) minimise the
    curvature miss plus a small penalty on heating; each current is the steady current of its temperature at the
    martensite fraction of the equilibrium (:func:`bayestouch.physics.sma.steady_state_current`). A finger that
    has been hotter since it was cold sits on a cooling branch and bends further for the same currents
    (:func:`hysteresis_loop`): the host must then cool it first, or correct with the sensed curvature.

    Parameters
    ----------
    curvature : (2,) float, 1/metres
        Target curvature vector u = κ (cos φ, sin φ) (φ from the base frame's x axis).
    tolerance : float
        Largest accepted miss |u − target| as a fraction of |target| (or of 1 m⁻¹ for a straight target).

    Returns
    -------
    currents : (3,) float, amperes
    temperatures : (3,) float, kelvin
    reached : (2,) float, 1/metres
        The curvature of the returned temperatures.

    Raises
    ------
    bayestouch.errors.BadInput
        A target the wires cannot reach within their temperature limit.
    """
    target = np.asarray(curvature, dtype=float).reshape(-1)
    if target.shape != (2,) or not np.all(np.isfinite(target)):
        raise BadInput(f"curvature: expected two finite values in 1/m, got {np.asarray(curvature).tolist()}")
    scale = max(float(np.linalg.norm(target)), 1.0)
    top = float(wire.max_temperature - BEND_TEMPERATURE_MARGIN - wire.ambient)
    n = np.asarray(bd.wire_directions(rod))
    best = None
    for start in (0.3, 0.7):  # from partly and from mostly transformed: the branch's flat ends stall a gradient
        x0 = np.clip(start * top * np.maximum(n @ target / scale, 0.0) + 1.0, 0.0, top)
        res = minimize(
            lambda x: tuple(np.asarray(v, float) for v in _bend_cost_and_grad(x, wire, rod, target, scale, 1e-4)),
            x0,
            jac=True,
            method="L-BFGS-B",
            bounds=[(0.0, top)] * 3,
        )
        if best is None or res.fun < best.fun:
            best = res
    temps = wire.ambient + best.x
    eq = bd.curvature_equilibrium(rod, wire, jnp.asarray(temps))
    reached = np.asarray(eq.u)
    miss = float(np.linalg.norm(reached - target))
    if miss > tolerance * scale:
        kappa = float(np.linalg.norm(target))
        raise BadInput(
            f"curvature: {kappa:.4g} 1/m at {np.degrees(np.arctan2(target[1], target[0])):.0f}° is beyond the "
            f"finger's reach within its {wire.max_temperature - BEND_TEMPERATURE_MARGIN:.0f} K limit (closest "
            f"{float(np.linalg.norm(reached)):.4g} 1/m)"
        )
    xi = sma.quasi_static_fraction(wire, eq.stress, jnp.asarray(temps))
    currents = np.asarray(sma.steady_state_current(wire, jnp.asarray(temps), xi))
    return currents, temps, reached


class CarrierProgram(NamedTuple):
    """A stroke as a finger executes it: the carrier (stage or arm) moves the finger base, the wires follow their
    current programs, and the pad goes wherever the bent rod puts it.

    Attributes
    ----------
    time : (T,) float, seconds
        Frame times from the stroke's start, evenly spaced (each current is held for one frame interval).
    base_position : (T, 3) float, metres
        The finger base's position in the world at each frame.
    base_rotation : (3, 3) float
        World-from-base rotation, held for the stroke (the rod leaves the base along the base frame's +z).
    currents : (T, 3) float, amperes
        The three wires' current program.
    """

    time: np.ndarray
    base_position: np.ndarray
    base_rotation: np.ndarray
    currents: np.ndarray


def program_dt(time) -> float:
    """The frame interval (s) of evenly spaced frame times ``time (T ≥ 2,)`` s; :class:`BadInput` naming ``time``
    for fewer than two, non-finite, non-increasing or unevenly spaced times (a current program holds each value for
    one interval, so the chain needs one interval)."""
    d = np.diff(_check_times(time))
    dt = float(np.median(d))
    if np.max(np.abs(d - dt)) > 0.01 * dt:
        raise BadInput(
            f"time: expected evenly spaced frame times (a current program holds each value for one frame interval); "
            f"the intervals run from {d.min():.4g} to {d.max():.4g} s"
        )
    return dt


def rotation_between(a, b) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector ``a (3,)`` to unit vector ``b (3,)`` (a half turn about an
    axis normal to both when they are opposite)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c < -1.0 + 1e-12:
        axis = np.cross(a, [1.0, 0.0, 0.0])
        axis = axis if np.linalg.norm(axis) > 1e-6 else np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def carrier_program(
    wire: sma.WireParams,
    rod: bd.RodParams,
    contact,
    normal,
    time,
    depth: float,
    tip_radius: float,
    *,
    curvature=(0.0, 0.0),
    currents=None,
    base_rotation=None,
    substeps: int = 10,
) -> CarrierProgram:
    """The base motion and wire currents that put the pad of a finger with the constants ``wire``, ``rod`` on a
    desired path: the pad centre at ``contact + (tip_radius − depth) normal`` at each frame, pressed ``depth`` into
    a surface through ``contact`` with outward ``normal`` (the inverse of :func:`pad_path`).

    The currents are ``currents`` as given, or the steady currents of the bend ``curvature``
    (:func:`currents_for_bend`) held from the first frame; the rod starts cold (as :func:`tip_path`), so it bends
    during the stroke, and the base follows the pad path less the tip's position on these constants frame by
    frame, its bend transient included. A finger whose constants are not these (every real one) puts its pad
    elsewhere by its pose error (:func:`pose_error_ensemble`); what the finger senses (the frames' tip position) is
    what a host can correct with.

    Parameters
    ----------
    wire, rod : WireParams, RodParams
        The constants the host assumes (nominal: ``models/finger.toml``).
    contact : (T, 3) float, metres
        Desired contact points of the pad on the surface.
    normal : (T, 3) float
        Outward unit surface normals there.
    time : (T,) float, seconds
        Evenly spaced frame times (:func:`program_dt`).
    depth : float, metres
        Designed overlap of the pad with the surface, in (0, 5 mm].
    tip_radius : float, metres
        Radius of the pad's outer (skin) surface.
    curvature : (2,) float, 1/metres
        Bend to hold when ``currents`` is None (default straight: no current).
    currents : (T, 3) float, amperes, optional
        An explicit current program.
    base_rotation : (3, 3) float, optional
        World-from-base rotation; default the smallest rotation that turns the rod's tangent at the tip, at the
        program's last frame, against the path's mean normal (the pad faces the surface).
    substeps : int
        Thermal integration steps per frame (:func:`tip_path`).

    Returns
    -------
    CarrierProgram
    """
    t = np.asarray(time, dtype=float)
    dt = program_dt(t)
    T = len(t)
    c = np.asarray(contact, dtype=float)
    n = np.asarray(normal, dtype=float)
    if c.shape != (T, 3) or n.shape != (T, 3) or not (np.all(np.isfinite(c)) and np.all(np.isfinite(n))):
        raise BadInput(
            f"contact, normal: expected finite ({T}, 3) arrays (metres; unit normals), got {c.shape}, {n.shape}"
        )
    if np.any(np.abs(np.linalg.norm(n, axis=1) - 1.0) > 1e-3):
        raise BadInput("normal: expected outward unit normals")
    if not (np.isfinite(depth) and 0.0 < depth <= 5e-3):
        raise BadInput(f"depth: expected a designed overlap in (0, 0.005] m, got {depth!r}")
    if not (np.isfinite(tip_radius) and tip_radius > depth):
        raise BadInput(f"tip_radius: expected the pad's radius in metres (> depth), got {tip_radius!r}")
    if currents is None:
        u = np.asarray(curvature, dtype=float).reshape(-1)
        if u.shape != (2,) or not np.all(np.isfinite(u)):
            raise BadInput(f"curvature: expected two finite values in 1/m, got {np.asarray(curvature).tolist()}")
        held = np.zeros(3) if not np.any(u) else currents_for_bend(wire, rod, u)[0]
        cur = np.tile(held, (T, 1))
    else:
        cur = _check_currents(wire, currents)
        if cur.shape != (T, 3):
            raise BadInput(f"currents: expected a ({T}, 3) program in amperes, one row per frame, got {cur.shape}")
    tip = tip_path(wire, rod, cur, dt, substeps=substeps)
    if base_rotation is None:
        face = -np.mean(n, axis=0)
        if np.linalg.norm(face) < 1e-6:
            raise BadInput("normal: the path's normals cancel out; pass base_rotation to choose how the base faces")
        R = rotation_between(tip.tip_rotation[-1][:, 2], face / np.linalg.norm(face))
    else:
        R = np.asarray(base_rotation, dtype=float)
        if R.shape != (3, 3) or not _orthonormal(R):
            raise BadInput("base_rotation: expected an orthonormal 3 × 3 rotation matrix")
    centre = c + (float(tip_radius) - float(depth)) * n
    base = centre - tip.tip_position @ R.T
    return CarrierProgram(t, base, R, cur)


def carrier_pad_path(wire: sma.WireParams, rod: bd.RodParams, program: CarrierProgram, **kw) -> PadPath:
    """Where a finger with the constants ``wire``, ``rod`` puts its pad under ``program``: :func:`pad_path` of the
    program's currents, frame interval, base positions and rotation (``**kw`` to :func:`tip_path`: T0, xi0,
    substeps)."""
    return pad_path(
        wire, rod, program.currents, program_dt(program.time), program.base_position, program.base_rotation, **kw
    )


#: the chain's step (seconds) and the length granularity (frames) of :func:`held_pose_error` and
#: :func:`held_error_ensemble`: one compilation serves every stroke whose warm-up and duration fit the same multiple
HELD_DT = 0.05
HELD_BUCKET = 32
#: seconds the wires hold their currents before a guarded stroke's first frame (from cold), in the device and in
#: :func:`held_pose_error` and :func:`held_error_ensemble`
HELD_WARMUP = 5.0


@partial(jax.jit, static_argnums=(4,))
def _held_tips(wires, rods, currents, dt, substeps):
    """Tip positions (K, N, 3) of K fingers (stacked pytrees, each started cold at its own ambient temperature)
    through one current program (N, 3)."""

    def one(w, r):
        u = _chain(w, r, currents, dt, jnp.full(3, w.ambient), jnp.ones(3), substeps)[3]
        return jax.vmap(lambda c: bd.tip_pose(r, c)[0])(u)

    return jax.vmap(one)(wires, rods)


def interp_grid(grid, values, times, axis: int = 0) -> np.ndarray:
    """``values`` sampled on ``grid`` (N ≥ 2,) seconds along ``axis``, linearly interpolated at ``times`` (M,)
    seconds (held at the end values beyond the grid, as :func:`numpy.interp`): the same array with that axis of
    length M."""
    g, t = np.asarray(grid, dtype=float), np.asarray(times, dtype=float).reshape(-1)
    v = np.asarray(values, dtype=float)
    idx = np.clip(np.searchsorted(g, t, side="right") - 1, 0, len(g) - 2)
    shape = [1] * v.ndim
    shape[axis] = len(t)
    w = np.clip((t - g[idx]) / (g[idx + 1] - g[idx]), 0.0, 1.0).reshape(shape)
    return (1 - w) * np.take(v, idx, axis=axis) + w * np.take(v, idx + 1, axis=axis)


def _held_tips_at(fingers, hold_currents, time, warmup: float, dt: float) -> np.ndarray:
    """Tip positions (K, T, 3) metres of K fingers ((wire, rod) pairs) holding ``hold_currents`` from cold,
    switched on ``warmup`` seconds before ``time[0]``, on a chain of step ``dt`` whose length is rounded up to a
    multiple of :data:`HELD_BUCKET`, interpolated linearly at ``time``."""
    t = np.asarray(time, dtype=float)
    cur = _check_currents(fingers[0][0], np.asarray(hold_currents, dtype=float).reshape(1, 3))
    wires = jax.tree.map(lambda *xs: jnp.asarray(xs, dtype=float), *[f[0] for f in fingers])
    rods = jax.tree.map(lambda *xs: jnp.asarray(xs, dtype=float), *[f[1] for f in fingers])
    span = warmup + float(t[-1] - t[0])
    n = -(-(int(np.ceil(span / dt)) + 2) // HELD_BUCKET) * HELD_BUCKET
    tips = np.asarray(_held_tips(wires, rods, jnp.asarray(np.tile(cur, (n, 1))), float(dt), 10))
    grid = -warmup + dt * np.arange(1, n + 1)  # the chain's frame k holds the state after k + 1 steps
    return interp_grid(grid, tips, t - t[0], axis=1)


def held_pose_error(
    finger: tuple[sma.WireParams, bd.RodParams],
    assumed: tuple[sma.WireParams, bd.RodParams],
    hold_currents,
    time,
    *,
    warmup: float = HELD_WARMUP,
) -> np.ndarray:
    """The tip's error (T, 3) metres, finger-base frame, of a finger holding ``hold_currents`` through a stroke, as
    a host that assumes other constants sees it: tip(finger) − tip(assumed), both wires switched on ``warmup``
    seconds before the stroke's first frame from cold (as :func:`bayestouch.physics.finger.drive`).

    The chain runs at its own step :data:`HELD_DT`, whatever the frames' interval (the bend of a real finger does
    not depend on how often it reports; the chain's frame-lagged stress made it depend on the step by up to 10 % at
    steps of 0.1 s), and the tip is interpolated linearly at the frame times.

    Parameters
    ----------
    finger, assumed : (WireParams, RodParams)
        The finger's true constants and the ones the host computes its pose with.
    hold_currents : (3,) float, amperes
    time : (T,) float, seconds
        Frame times, evenly spaced.
    warmup : float, seconds

    Returns
    -------
    (T, 3) float, metres
    """
    _check_times(time)
    tips = _held_tips_at([finger, assumed], hold_currents, time, warmup, HELD_DT)
    return tips[0] - tips[1]


def held_error_ensemble(
    wire: sma.WireParams,
    rod: bd.RodParams,
    hold_currents,
    time,
    *,
    spread: FingerSpread | None = None,
    draws: int = 24,
    seed: int = 0,
    warmup: float = HELD_WARMUP,
    dt: float = HELD_DT,
) -> np.ndarray:
    """What a host that knows only the nominal constants and their spread can say about the pad's error while the
    finger holds ``hold_currents`` through a stroke (the guarded strokes of
    :class:`~bayestouch.hardware.frame_models.GuardedModel`): :func:`held_pose_error` of ``draws`` fingers drawn
    about the nominal one (:func:`draw_finger`) against the nominal one.

    All fingers run at once on a chain of step ``dt`` from ``warmup`` seconds before the first frame (the wires
    switched on from cold), its length rounded up to a multiple of :data:`HELD_BUCKET` frames so that strokes of
    different durations share a compilation; the tip is interpolated linearly at the frame times. The same ``seed``
    draws the same fingers for every stroke (one finger runs them all).

    Parameters
    ----------
    wire, rod : WireParams, RodParams
        The host's nominal constants.
    hold_currents : (3,) float, amperes
    time : (T,) float, seconds
        Frame times of the stroke (evenly spaced or not; the first is the stroke's start).
    spread : FingerSpread, optional
        How far the finger may be from nominal (default :class:`FingerSpread`).
    draws : int
        Drawn fingers K (≥ 2).
    seed : int
    warmup : float, seconds
    dt : float, seconds
        The chain's step (keep it ≲ 0.1 s: the wires' thermal time constant is about a second).

    Returns
    -------
    (K, T, 3) float, metres
        Tip errors in the finger-base frame.
    """
    t = np.asarray(time, dtype=float)
    if t.ndim != 1 or len(t) < 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise BadInput(f"time: expected non-decreasing finite frame times in seconds, shape (T,), got shape {t.shape}")
    if int(draws) < 2:
        raise BadInput(f"draws: expected at least 2 drawn fingers, got {draws!r}")
    if not (np.isfinite(dt) and 0 < dt <= 0.1) or not (np.isfinite(warmup) and warmup >= 0):
        raise BadInput(f"dt, warmup: expected a chain step in (0, 0.1] s and a warm-up ≥ 0 s, got {dt!r}, {warmup!r}")
    rng = np.random.default_rng(seed)
    fingers = [(wire, rod)] + [draw_finger(rng, wire, rod, spread) for _ in range(int(draws))]
    tips = _held_tips_at(fingers, hold_currents, t, warmup, dt)
    return tips[1:] - tips[0]
