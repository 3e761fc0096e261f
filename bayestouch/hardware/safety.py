"""Safety limits of the finger and the checks every stroke plan passes before a byte is sent.

The same :func:`check_plan` (:func:`check_carrier` for a carrier stroke) runs on both sides: in the client
(:class:`~bayestouch.hardware.device.FingerDevice` refuses an unsafe plan before writing anything) and in the device
(the virtual finger answers an unsafe :class:`~bayestouch.hardware.protocol.StrokeCommand` with a NAK). The device
also stops heating when heartbeats stop (``watchdog``) and aborts a stroke whose measured force exceeds the plan's
limit. DESIGN.md §7.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.errors import BadInput, check_int, check_number, shown
from bayestouch.params import MODELS
from bayestouch.physics import bending, sma
from bayestouch.physics import skin as sk
from bayestouch.physics.pose import program_dt

__all__ = [
    "Limits",
    "StrokePlan",
    "PlanCheck",
    "UnsafePlan",
    "load_limits",
    "check_limits",
    "plan_from_stroke",
    "check_plan",
    "CarrierCheck",
    "check_carrier",
    "predicted_force",
    "steady_wire_temperature",
    "FORCE_FACTOR",
]


class UnsafePlan(BadInput):
    """A stroke plan that would exceed a safety limit (or is malformed); nothing was sent."""


class Limits(NamedTuple):
    """Safety limits.

    Attributes
    ----------
    max_current : float, amperes
        Per-wire current (``models/finger.toml`` ``max_current``: the vendor's ~200 mA for 100 µm Flexinol).
    max_temperature : float, K
        Per-wire temperature (``models/finger.toml`` ``max_temperature``).
    max_force : float, N
        Normal contact force of the pad. Assumption: 1 N, 7× the ~0.15 N of the default 0.3 mm strokes and
        below the 2 N ``simulate --force`` accepts.
    watchdog : float, seconds
        The device switches the heaters off and aborts the stroke after this long without a valid packet.
    max_speed : float, m/s
        Fastest waypoint-to-waypoint speed (assumption: 5 cm/s, five times the paper's 1 cm/s).
    max_waypoints : int
        Longest stroke plan (20 s at 50 Hz).
    max_depth : float, metres
        Deepest press (the 5 mm of :func:`bayestouch.scene.strokes.stroke_from_path`).
    """

    max_current: float = 0.2
    max_temperature: float = 393.15
    max_force: float = 1.0
    watchdog: float = 1.0
    max_speed: float = 0.05
    max_waypoints: int = 1000
    max_depth: float = 0.005


def check_limits(limits, name: str = "limits") -> Limits:
    """``limits``, or the default :class:`Limits` for None; a one-line refusal naming ``name`` (or the field) when it
    is not a :class:`Limits` of finite numbers > 0 (``max_waypoints`` an integer ≥ 1)."""
    if limits is None:
        return Limits()
    if not isinstance(limits, Limits):
        raise BadInput(f"{name}: expected a Limits (bayestouch.hardware.safety.Limits) or None, got {shown(limits)}")
    for field, value in limits._asdict().items():
        if field == "max_waypoints":
            check_int(value, f"{name}.{field}", 1)
        else:
            check_number(value, f"{name}.{field}", 0, above=True)
    return limits


class StrokePlan(NamedTuple):
    """What the device is asked to do.

    Attributes
    ----------
    time : (T,) float, seconds, increasing from the stroke's start
    contact : (T, 3) float, metres
        Contact point of the pad centre on the surface.
    normal : (T, 3) float
        Outward unit surface normals (the pad presses along −normal).
    depth : float, metres
    hold_currents : (3,) float, amperes
    """

    time: np.ndarray
    contact: np.ndarray
    normal: np.ndarray
    depth: float
    hold_currents: np.ndarray


class PlanCheck(NamedTuple):
    """What :func:`check_plan` predicted for an accepted plan.

    peak_temperature : float, K (steady state of the hottest wire)
    force : float, N (upper bound of the contact force)
    speed : float, m/s (fastest waypoint-to-waypoint speed)
    """

    peak_temperature: float
    force: float
    speed: float


def load_limits(models: Path | None = None, *, max_force: float = 1.0, watchdog: float = 1.0) -> Limits:
    """Limits from ``models/finger.toml`` (wire current and temperature) plus the force and watchdog settings."""
    wire = sma.load_wire(Path(models or MODELS) / "finger.toml")
    return Limits(float(wire.max_current), float(wire.max_temperature), float(max_force), float(watchdog))


def plan_from_stroke(stroke, hold_currents=(0.15, 0.05, 0.05)) -> StrokePlan:
    """A :class:`StrokePlan` from a :class:`~bayestouch.scene.strokes.Stroke` and three hold currents (A)."""
    return StrokePlan(
        np.asarray(stroke.time, float),
        np.asarray(stroke.contact, float),
        np.asarray(stroke.normal, float),
        float(stroke.depth),
        np.asarray(hold_currents, float),
    )


def steady_wire_temperature(hold_currents, wire=None) -> np.ndarray:
    """Steady-state temperature (K) of each wire at its hold current, austenite resistivity (the higher one,
    so an upper bound for any stroke length): :func:`bayestouch.physics.sma.steady_state_temperature`."""
    wire = wire if wire is not None else sma.load_wire()
    return np.asarray(sma.steady_state_temperature(wire, np.asarray(hold_currents, float), 0.0))


#: margin on the thin-layer force estimate: the forward model's force on the egg at 0.3 mm (0.149 N, foam
#: densification and damping included) is 1.42× the Winkler value (0.105 N); 2 covers it
FORCE_FACTOR = 2.0


def predicted_force(depth: float, skin=None, tip_radius: float | None = None) -> float:
    """Conservative estimate (N) of the pad's contact force at ``depth`` (m): :data:`FORCE_FACTOR` × the
    fingertip pressed into a flat surface (the largest contact of convex objects) by the thin-layer Winkler
    model, :func:`bayestouch.physics.skin.winkler_sphere`."""
    skin = skin if skin is not None else sk.load_skin(MODELS / "skin.toml")
    if tip_radius is None:
        tip_radius = float(bending.load_rod(MODELS / "finger.toml").radius) + float(skin.h)
    return FORCE_FACTOR * float(sk.winkler_sphere(float(depth), float(tip_radius), skin)[0])


def check_plan(plan: StrokePlan, limits: Limits, *, wire=None, skin=None, tip_radius=None) -> PlanCheck:
    """Refuse (raise :class:`UnsafePlan`) a plan that is malformed or would exceed a limit.

    Checks: waypoint shapes and finiteness, time increasing, count ≤ ``max_waypoints``, speed ≤ ``max_speed``,
    0 ≤ hold currents ≤ ``max_current``, steady-state wire temperature ≤ ``max_temperature`` (thermal model),
    0 < depth ≤ ``max_depth`` and predicted force ≤ ``max_force``.
    """
    t = np.asarray(plan.time, float)
    c = np.asarray(plan.contact, float)
    n = np.asarray(plan.normal, float)
    if t.ndim != 1 or len(t) < 2 or c.shape != (len(t), 3) or n.shape != (len(t), 3):
        raise UnsafePlan(
            f"stroke plan: time (T ≥ 2,), contact (T, 3) m and normal (T, 3) expected, got shapes "
            f"{t.shape}, {c.shape}, {n.shape}"
        )
    if len(t) > limits.max_waypoints:
        raise UnsafePlan(f"stroke plan: {len(t)} waypoints exceed the limit of {limits.max_waypoints}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(c)) and np.all(np.isfinite(n))):
        raise UnsafePlan("stroke plan: waypoints must be finite numbers")
    if t[0] < 0 or np.any(np.diff(t) <= 0):
        raise UnsafePlan("stroke plan: waypoint times must start at ≥ 0 s and increase strictly")
    if t[-1] > 1e6 or np.any(np.abs(c) > 10.0) or np.any(np.abs(n) > 10.0):
        raise UnsafePlan("stroke plan: times beyond 1e6 s, waypoints beyond ±10 m or normals far from unit length")
    if np.any(np.abs(np.linalg.norm(n, axis=1) - 1.0) > 1e-3):
        raise UnsafePlan("stroke plan: normals must be unit vectors")
    with np.errstate(over="ignore"):  # times 1e-300 s apart: an infinite speed, refused below
        speed = float(np.max(np.linalg.norm(np.diff(c, axis=0), axis=1) / np.diff(t)))
    if speed > limits.max_speed:
        raise UnsafePlan(f"stroke plan: speed {speed:.3g} m/s exceeds the limit of {limits.max_speed:g} m/s")
    I = np.asarray(plan.hold_currents, float).reshape(-1)
    if I.shape != (3,) or not np.all(np.isfinite(I)):
        raise UnsafePlan(f"stroke plan: hold_currents must be three numbers in amperes, got {I.tolist()}")
    if np.any(I < 0) or np.any(I > limits.max_current):
        raise UnsafePlan(f"stroke plan: wire currents {I.tolist()} A outside [0, {limits.max_current:g}] A")
    temp = float(np.max(steady_wire_temperature(I, wire)))
    if temp > limits.max_temperature:
        raise UnsafePlan(
            f"stroke plan: wire temperature would reach {temp:.1f} K, above the limit of "
            f"{limits.max_temperature:.1f} K (lower the hold currents)"
        )
    d = float(plan.depth)
    if not (0 < d <= limits.max_depth):
        raise UnsafePlan(f"stroke plan: depth must be in (0, {limits.max_depth:g}] m, got {d:g}")
    force = predicted_force(d, skin, tip_radius)
    if force > limits.max_force:
        raise UnsafePlan(
            f"stroke plan: contact force up to {force:.3g} N at depth {d:g} m exceeds the limit of "
            f"{limits.max_force:g} N"
        )
    return PlanCheck(temp, force, speed)


class CarrierCheck(NamedTuple):
    """What :func:`check_carrier` predicted for an accepted carrier stroke.

    peak_temperature : float, K (steady state of the hottest wire at its largest current)
    speed : float, m/s (fastest frame-to-frame speed of the finger base)
    """

    peak_temperature: float
    speed: float


def check_carrier(program, limits: Limits, *, wire=None) -> CarrierCheck:
    """Refuse (raise :class:`UnsafePlan`) a carrier stroke that is malformed or would exceed a limit.

    ``program`` has ``time (T,)`` s, ``base_position (T, 3)`` m, ``base_rotation (3, 3)`` and ``currents (T, 3)`` A
    (a :class:`~bayestouch.physics.pose.CarrierProgram` or a :class:`~bayestouch.hardware.protocol.CarrierStroke`).
    Checks: shapes and finiteness, T ≥ 2 and ≤ ``max_waypoints``, times from ≥ 0 s strictly increasing and evenly
    spaced (:func:`~bayestouch.physics.pose.program_dt`), base within
    ±10 m and its speed ≤ ``max_speed``, an orthonormal right-handed rotation, every current in [0, ``max_current``]
    and the steady-state temperature of each wire at its largest current ≤ ``max_temperature`` (an upper bound for
    the program). Where the pad meets the object, and so its force, follows from the bend and is not known before
    the stroke: the device's force abort bounds it.
    """
    try:
        t = np.asarray(program.time, float)
        b = np.asarray(program.base_position, float)
        R = np.asarray(program.base_rotation, float)
        I = np.asarray(program.currents, float)
    except (AttributeError, TypeError, ValueError):
        raise UnsafePlan(
            "carrier plan: expected time (T,) s, base_position (T, 3) m, base_rotation (3, 3) and currents (T, 3) A"
        ) from None
    T = len(t) if t.ndim == 1 else -1
    if T < 2 or b.shape != (T, 3) or R.size != 9 or I.shape != (T, 3):
        raise UnsafePlan(
            f"carrier plan: time (T ≥ 2,), base_position (T, 3) m, base_rotation (3, 3) and currents (T, 3) A "
            f"expected, got shapes {t.shape}, {b.shape}, {R.shape}, {I.shape}"
        )
    R = R.reshape(3, 3)
    if T > limits.max_waypoints:
        raise UnsafePlan(f"carrier plan: {T} frames exceed the limit of {limits.max_waypoints}")
    if not all(np.all(np.isfinite(a)) for a in (t, b, R, I)):
        raise UnsafePlan("carrier plan: times, base positions, rotation and currents must be finite numbers")
    if t[0] < 0 or np.any(np.diff(t) <= 0) or t[-1] > 1e6:
        raise UnsafePlan("carrier plan: frame times must start at ≥ 0 s, increase strictly and stay below 1e6 s")
    try:
        program_dt(t)  # each current is held one frame interval: the frames must be evenly spaced
    except BadInput as e:
        raise UnsafePlan(f"carrier plan: {e}") from None
    if np.any(np.abs(b) > 10.0):
        raise UnsafePlan("carrier plan: base positions beyond ±10 m")
    if np.max(np.abs(R)) > 2.0 or np.max(np.abs(R @ R.T - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0:
        raise UnsafePlan("carrier plan: base_rotation must be a rotation matrix (orthonormal, determinant +1)")
    with np.errstate(over="ignore"):
        speed = float(np.max(np.linalg.norm(np.diff(b, axis=0), axis=1) / np.diff(t)))
    if speed > limits.max_speed:
        raise UnsafePlan(f"carrier plan: base speed {speed:.3g} m/s exceeds the limit of {limits.max_speed:g} m/s")
    if np.any(I < 0) or np.any(I > limits.max_current):
        raise UnsafePlan(
            f"carrier plan: wire currents from {I.min():.4g} to {I.max():.4g} A outside [0, {limits.max_current:g}] A"
        )
    temp = float(np.max(steady_wire_temperature(I.max(axis=0), wire)))
    if temp > limits.max_temperature:
        raise UnsafePlan(
            f"carrier plan: wire temperature would reach {temp:.1f} K, above the limit of "
            f"{limits.max_temperature:.1f} K (lower the currents)"
        )
    return CarrierCheck(temp, speed)
