"""Semantic fuzzing of the wire protocol's two ends: well-formed packets with hostile contents.

A packet that passes framing and CRC can still carry NaN, infinities, huge or negative numbers, or arrays whose
lengths disagree. :func:`hostile_command` draws such STROKE and PROBE_STROKE commands, :func:`hostile_carrier`
CARRIER_STROKE commands (revision 1.3) and :func:`hostile_frame` such frames; the virtual finger must answer every
command with ACK or NAK 2 and keep answering (the decision is
:func:`~bayestouch.hardware.simulator.command_refusal`, the one the virtual finger makes), and the client must
reject every impossible frame (:func:`~bayestouch.hardware.device.frame_problem`) without raising. The suite runs
a few thousand cases; ``python -m bayestouch.hardware.fuzz N`` runs N (10⁵ in about 15 s) without a device in
the loop.
"""

from __future__ import annotations

import sys

import numpy as np

from bayestouch.hardware import protocol as pr
from bayestouch.hardware.device import frame_problem
from bayestouch.hardware.safety import Limits
from bayestouch.hardware.simulator import command_refusal

__all__ = ["hostile_command", "hostile_carrier", "hostile_frame", "fuzz"]

_HOSTILE = (np.nan, np.inf, -np.inf, 0.0, -1.0, 1e300, -1e300, 1e-300, 3e38)


def _value(rng: np.random.Generator, good: float) -> float:
    """A hostile scalar one time in three, else a plausible one near ``good``."""
    return float(rng.choice(_HOSTILE)) if rng.random() < 1 / 3 else float(good * rng.uniform(0.5, 1.5))


def _array(rng: np.random.Generator, good: np.ndarray) -> np.ndarray:
    """``good`` with, one time in three each, a hostile entry, a changed length or a scaled copy."""
    a = np.array(good, dtype=float)
    u = rng.random()
    if u < 1 / 3 and a.size:
        a.flat[rng.integers(a.size)] = rng.choice(_HOSTILE)
    elif u < 2 / 3:
        n = int(rng.integers(0, 2 * len(a) + 2))
        a = np.resize(a, (n, *a.shape[1:]))
    return a


def hostile_command(rng: np.random.Generator, stroke_id: int):
    """A STROKE or PROBE_STROKE (equal odds) whose every field may be hostile (module docstring)."""
    t_n = int(rng.integers(2, 40))
    t = np.arange(t_n) * 0.02
    pts = np.column_stack([0.01 * t, np.zeros(t_n), np.full(t_n, 0.02)])
    nrm = np.tile([0.0, 0.0, 1.0], (t_n, 1))
    currents = _array(rng, np.array([0.1, 0.05, 0.05]))
    args = (stroke_id, _value(rng, 3e-4), _value(rng, 1.0), currents, _array(rng, t), _array(rng, pts))
    if rng.random() < 0.5:
        return pr.StrokeCommand(*args, _array(rng, nrm))
    return pr.ProbeStroke(*args, _array(rng, nrm), _value(rng, 0.01), _value(rng, 0.05))


def hostile_carrier(rng: np.random.Generator, stroke_id: int) -> pr.CarrierStroke:
    """A CARRIER_STROKE whose every field may be hostile (a rotation may be scaled, mirrored or hold NaN)."""
    t_n = int(rng.integers(2, 40))
    t = np.arange(t_n) * 0.02
    base = np.column_stack([0.01 * t, np.zeros(t_n), np.full(t_n, 0.1)])
    rot = np.diag([1.0, -1.0, -1.0])
    u = rng.random()
    if u < 0.1:
        rot = -rot  # a mirror: determinant −1
    elif u < 0.2:
        rot = 1.5 * rot
    currents = np.tile([0.1, 0.05, 0.05], (t_n, 1))
    return pr.CarrierStroke(
        stroke_id, _value(rng, 1.0), _array(rng, t), _array(rng, base), _array(rng, rot), _array(rng, currents)
    )


def hostile_frame(rng: np.random.Generator, taxels: int = 256) -> pr.Frame:
    """A frame whose every field may be hostile."""
    return pr.Frame(
        1,
        int(rng.integers(0, 100)),
        _value(rng, 1.0),
        _array(rng, np.full(taxels, 2e-7)),
        _array(rng, np.array([0.1, 0.05, 0.05])),
        _array(rng, np.array([320.0, 300.0, 300.0])),
        _value(rng, 293.0),
        _array(rng, np.array([0.0, 0.0, 0.05])),
        _array(rng, np.array([1.0, 0.0])),
        _value(rng, 0.1),
    )


def fuzz(cases: int, seed: int = 0) -> dict:
    """``cases`` hostile commands judged and ``cases`` hostile frames checked; returns the counts. Raises whatever
    an end raises on a hostile input (the failure a fuzz run looks for), and AssertionError when an accepted
    command or frame holds a non-finite number."""
    rng = np.random.default_rng(seed)
    lim = Limits()
    out = {"commands": 0, "ack": 0, "nak": 0, "carriers": 0, "carrier_ack": 0, "frames": 0, "bad_frames": 0}
    for i in range(cases):
        msg = hostile_command(rng, i)
        verdict = "nak" if command_refusal(msg, lim) is not None else "ack"
        out[verdict] += 1
        out["commands"] += 1
        if verdict == "ack":
            arrays = [
                msg.time,
                msg.normal,
                msg.hold_currents,
                msg.start if isinstance(msg, pr.ProbeStroke) else msg.contact,
            ]
            assert all(np.all(np.isfinite(np.asarray(a, float))) for a in arrays) and np.isfinite(msg.max_force)
        carrier = hostile_carrier(rng, i)
        out["carriers"] += 1
        if command_refusal(carrier, lim) is None:
            out["carrier_ack"] += 1
            arrays = [carrier.time, carrier.base_position, carrier.base_rotation, carrier.currents]
            assert all(np.all(np.isfinite(np.asarray(a, float))) for a in arrays) and carrier.max_force > 0
            assert np.linalg.det(np.asarray(carrier.base_rotation).reshape(3, 3)) > 0
        f = hostile_frame(rng)
        problem = frame_problem(f)
        out["frames"] += 1
        out["bad_frames"] += problem is not None
        if problem is None:
            assert all(np.all(np.isfinite(np.asarray(getattr(f, k), float))) for k in f._fields[2:])
    return out


if __name__ == "__main__":  # pragma: no cover - the long run
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 100_000
    print(fuzz(n, seed=int(sys.argv[2]) if len(sys.argv) > 2 else 0))
