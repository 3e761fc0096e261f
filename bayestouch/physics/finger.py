"""The finger's actuation during a stroke: wire currents → wire temperatures and martensite fraction
(:mod:`bayestouch.physics.sma`) → rod curvature and tip pose (:mod:`bayestouch.physics.bending`) → skin
temperature seen by the taxels.

The stroke itself is position-controlled: an arm carries the finger base so that the pad presses the
requested depth at each contact point, and the wires hold a bend set by the hold currents. Two things of
the actuation reach the measurement: the tip pose (recorded) and the heat the wires leak into the skin,
which shifts every taxel's current by ~6–11 %/K (physics.md §0 finding 2). The skin temperature is a
first-order state driven towards T_amb + coupling · mean(T_wire − T_amb).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.physics import bending as bd
from bayestouch.physics import sma

__all__ = ["Drive", "SkinThermal", "SKIN_THERMAL", "drive", "skin_temperature"]


class SkinThermal(NamedTuple):
    """Heat path from the wires to the taxels.

    coupling : float, 1
        Fraction of the mean wire over-temperature that reaches the skin in steady state (assumption:
        0.03, the wires thermally isolated as physics.md §1 "Embedding" recommends).
    tau : float, seconds
        Time constant of the skin temperature (assumption: 5 s for a 2 mm foam layer on the rod).
    """

    coupling: float = 0.03
    tau: float = 5.0


SKIN_THERMAL = SkinThermal()


class Drive(NamedTuple):
    """Actuation history of one stroke (T frames).

    wire_current : (T, 3) float, amperes
    wire_temperature : (T, 3) float, kelvin
    martensite : (T, 3) float, 1
    curvature : (T, 2) float, 1/metres
    tip_position : (T, 3) float, metres (in the finger-base frame)
    skin_temperature : (T,) float, kelvin
    """

    wire_current: np.ndarray
    wire_temperature: np.ndarray
    martensite: np.ndarray
    curvature: np.ndarray
    tip_position: np.ndarray
    skin_temperature: np.ndarray


def skin_temperature(wire_temperature, ambient, dt, thermal: SkinThermal = SKIN_THERMAL, T0=None):
    """Skin temperature (T,) K from wire temperatures (T, 3) K by the first-order heat path."""
    target = ambient + thermal.coupling * (jnp.mean(wire_temperature, axis=-1) - ambient)
    a = 1.0 - jnp.exp(-dt / thermal.tau)

    def step(T, x):
        T = T + a * (x - T)
        return T, T

    _, out = jax.lax.scan(step, jnp.asarray(ambient if T0 is None else T0, dtype=float), target)
    return out


def drive(
    wire: sma.WireParams,
    rod: bd.RodParams,
    hold_currents,
    n_frames: int,
    dt: float,
    *,
    warmup: float = 5.0,
    thermal: SkinThermal = SKIN_THERMAL,
) -> Drive:
    """Simulate the wires holding ``hold_currents`` for a stroke of ``n_frames`` frames of ``dt`` seconds.

    The wires are switched on ``warmup`` seconds before the stroke starts (the bend settles first).

    Parameters
    ----------
    hold_currents : (3,) float, amperes
        Must lie within [0, ``wire.max_current``].
    n_frames : int
    dt : float, seconds

    Returns
    -------
    Drive
    """
    I = np.asarray(hold_currents, float).reshape(-1)
    if I.shape != (3,) or np.any(I < 0) or np.any(I > wire.max_current):
        raise BadInput(f"wire currents must be three values in [0, {wire.max_current:g}] A, got {I.tolist()}")
    n_warm = int(round(warmup / dt))
    cur = jnp.broadcast_to(jnp.asarray(I), (n_warm + n_frames, 3))
    trace = sma.simulate_wire(wire, cur, dt)
    temps = trace.temperature
    skin = skin_temperature(temps, wire.ambient, dt, thermal)[n_warm:]
    temps, xi = temps[n_warm:], trace.xi[n_warm:]
    # the bend follows the wire temperatures quasi-statically; evaluate it on a coarse time grid
    idx = np.unique(np.linspace(0, n_frames - 1, min(n_frames, 8)).astype(int))
    eq = jax.vmap(lambda T, x: bd.curvature_equilibrium(rod, wire, T, x))(temps[idx], xi[idx])
    u = np.stack([np.interp(np.arange(n_frames), idx, np.asarray(eq.u)[:, k]) for k in range(2)], axis=1)
    tip = np.asarray(jax.vmap(lambda uu: bd.tip_pose(rod, uu)[0])(jnp.asarray(u)))
    return Drive(np.asarray(cur[n_warm:]), np.asarray(temps), np.asarray(xi), u, tip, np.asarray(skin))
