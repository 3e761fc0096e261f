"""One stroke of the simulated finger over a textured test plate, with the nuisances of texture identification.

The truth of texture identification (``docs/texture_identification.md``): the full forward model
(:func:`bayestouch.physics.forward.simulate`, all noise sources, the device's fixed-pattern gains) along a
:class:`~bayestouch.scene.textures.StrokeSpec` whose start is displaced ``shift`` metres along the stroke, with a
skin-temperature offset (kelvin) on top of the drive's modelled skin temperature. The recorded frames carry the
commanded (known) path, not the displaced one. Unlike :func:`bayestouch.physics.virtual.record_strokes` (one
seed split over many strokes, no nuisances) each stroke draws its own noise key from a NumPy generator.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.physics import forward as fw
from bayestouch.physics.finger import drive
from bayestouch.physics.virtual import VirtualFinger
from bayestouch.scene.objects import SceneObject
from bayestouch.scene.textures import StrokeSpec, plate_stroke

__all__ = ["PlateRecording", "record_plate_stroke", "known_finger", "quiet_device", "nominal_skin_temperature"]

_HOLD_CURRENTS = (0.15, 0.05, 0.05)  # wire hold currents (A) of the strokes' drive
_DRIVE_CACHE: dict = {}


class PlateRecording(NamedTuple):
    """One recorded plate stroke.

    frames : dict of str → array
        T frames of :func:`bayestouch.io.recording.build_dataset`: ``time`` (T,) s, ``stroke_index`` (T,),
        ``taxel_current`` (T, N) A, ``contact_point`` and ``contact_normal`` (T, 3) of the commanded path (m),
        ``pressing_depth`` (T,) m, ``skin_temperature`` (T,) K (the modelled one, without the truth's offset).
    tangent : (3,) float
        Unit direction of the stroke (world frame).
    shift : float, metres
        The truth's start-phase error.
    """

    frames: dict
    tangent: np.ndarray
    shift: float


def nominal_skin_temperature(vf: VirtualFinger, n: int, dt: float) -> np.ndarray:
    """Modelled skin temperature (n,) K of a stroke of ``n`` frames ``dt`` seconds apart.

    The wires hold (0.15, 0.05, 0.05) A from rest (:func:`bayestouch.physics.finger.drive`); cached per wire, ``n``
    and ``dt``.
    """
    key = (id(vf.wire), n, dt)
    if key not in _DRIVE_CACHE:
        _DRIVE_CACHE[key] = np.asarray(drive(vf.wire, vf.rod, _HOLD_CURRENTS, n, dt).skin_temperature)
    return _DRIVE_CACHE[key]


def known_finger(vf: VirtualFinger, noise: bool = True):
    """The simulated finger itself: ``vf.finger``, with unit fixed-pattern gains when ``noise`` is off (the truth's
    device; an identifier reads with a host's device, :func:`bayestouch.inference.raw.host_device`)."""
    f = vf.finger
    return f if noise else f._replace(gains=jnp.ones_like(f.gains))


def quiet_device(finger):
    """``finger`` with every noise source zeroed and a 32-bit ADC (quantisation ≤ 5e-16 A).

    With the noise off the truth is simulated with this device, so the same compiled
    :func:`~bayestouch.physics.forward.simulate` serves both cases; the identifier keeps the real noise model for
    its reading sd.
    """
    quiet = finger.noise._replace(
        bandwidth=0.0,
        flicker=0.0,
        drift_common=0.0,
        drift_local=0.0,
        offset=0.0,
        outlier_probability=0.0,
        adc_bits=32.0,
    )
    return finger._replace(noise=quiet)


def record_plate_stroke(
    obj: SceneObject,
    spec: StrokeSpec,
    vf: VirtualFinger,
    rng: np.random.Generator,
    *,
    shift_range: float,
    temperature_sd: float,
    mode: str,
    noise: bool = True,
) -> PlateRecording:
    """Simulate one stroke over the textured ``obj`` with the truth's start-phase error and temperature offset.

    Parameters
    ----------
    obj : SceneObject
        The object with its true texture.
    spec : StrokeSpec
        The commanded stroke.
    vf : VirtualFinger
        :func:`bayestouch.physics.virtual.load_finger`.
    rng : numpy Generator
        Draws, in this order, the shift ~ U(−``shift_range``, ``shift_range``), the temperature offset
        ~ N(0, ``temperature_sd``²) and the noise key.
    shift_range : float, metres
    temperature_sd : float, kelvin
    mode : {"empirical", "physics"}
        Taxel response mode.
    noise : bool
        False: simulate with :func:`quiet_device` of the unit-gain :func:`known_finger`.

    Returns
    -------
    PlateRecording
    """
    finger = known_finger(vf, noise)
    shift = float(rng.uniform(-shift_range, shift_range))
    cmd = plate_stroke(obj, spec, 0.0)
    true = plate_stroke(obj, spec, shift)
    dt = 1.0 / spec.rate
    n = len(cmd.time)
    temp_nominal = nominal_skin_temperature(vf, n, dt)
    temp_true = temp_nominal + rng.normal(0.0, temperature_sd)
    key = jax.random.PRNGKey(int(rng.integers(2**31)))
    fr = fw.simulate_jit(
        obj.surface(),
        fw.stroke_arrays(true),
        finger if noise else quiet_device(finger),
        key,
        skin_temperature=jnp.asarray(temp_true),
        dt=dt,
        mode=mode,
    )
    frames = {
        "time": cmd.time,
        "stroke_index": np.zeros(n, int),
        "taxel_current": np.asarray(fr.taxel_current),
        "contact_point": cmd.contact,
        "contact_normal": cmd.normal,
        "pressing_depth": np.full(n, cmd.depth),
        "skin_temperature": temp_nominal,
    }
    return PlateRecording(frames, np.asarray(cmd.tangent[0]), shift)
