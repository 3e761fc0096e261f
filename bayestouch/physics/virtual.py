"""The virtual experiment: strokes of the simulated finger over an object, recorded (NumPy edge).

Loads the finger's parameter files, draws strokes, drives the wires, runs the forward model for every
stroke and returns the per-frame arrays of :mod:`bayestouch.io.recording`.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
from tqdm.auto import tqdm

from bayestouch.backend import jax
from bayestouch.errors import BadInput, check_int, check_path, check_seed, shown
from bayestouch.io.recording import build_dataset
from bayestouch.params import MODELS
from bayestouch.physics import bending, noise, skin, sma, taxel
from bayestouch.physics import forward as fw
from bayestouch.physics.finger import drive
from bayestouch.physics.forward import make_finger

__all__ = [
    "check_strokes",
    "MAX_DEPTH_M",
    "VirtualFinger",
    "finger_name",
    "load_finger",
    "record_strokes",
    "recording_dataset",
]


class VirtualFinger(NamedTuple):
    """The simulated finger: forward-model pytree, wire and rod parameters, default taxel mode."""

    finger: object
    wire: object
    rod: object
    mode: str


def finger_name(seed: int) -> str:
    """The identity of the simulated finger whose fixed pattern ``seed`` draws, as its recordings and device files
    name it (the ``finger`` attribute; a real finger's would be its serial number)."""
    return f"virtual finger {int(seed)}"


def load_finger(models: Path = MODELS, seed: int = 0) -> VirtualFinger:
    """Read ``finger.toml``, ``skin.toml``, ``taxels.toml``, ``noise.toml`` from ``models``; ``seed`` draws the
    device's fixed pattern."""
    check_path(models, "models")
    models = Path(models)
    check_seed(seed, note=" (the finger's fixed pattern)")
    rod = bending.load_rod(models / "finger.toml")
    wire = sma.load_wire(models / "finger.toml")
    sk = skin.load_skin(models / "skin.toml")
    fg = make_finger(
        sk,
        taxel.load_taxels(models / "taxels.toml"),
        noise.load_noise(models / "noise.toml"),
        tip_radius=float(rod.radius) + float(sk.h),
        seed=seed,
    )
    return VirtualFinger(fg, wire, rod, taxel.load_taxel_mode(models / "taxels.toml"))


#: deepest pressing depth (m) a simulated stroke takes: the simulator's own limit (``simulate --depth``); at 5 mm
#: the forward model's pad force is ~1 kN, no finger's
MAX_DEPTH_M = 2e-3


def check_strokes(strokes, force_controlled: bool = False) -> None:
    """Refuse (:class:`BadInput` naming the stroke and field) strokes the forward model would turn into NaN or
    impossible readings: none at all, or not strokes; contact points that are not (T ≥ 2, 3) finite metres; normals
    that are not finite unit vectors; tangents of another shape; times that are not finite and increasing; a depth
    outside (0, :data:`MAX_DEPTH_M`] m (unless ``force_controlled``, where the depths are solved for)."""
    form = "a list of strokes (bt.random_strokes), each with contact, normal, tangent, time and depth"
    if isinstance(strokes, str | bytes) or not hasattr(strokes, "__iter__"):
        raise BadInput(f"strokes: expected {form}, got {type(strokes).__name__} {shown(strokes, 60)}")
    strokes = list(strokes)
    if not strokes:
        raise BadInput("strokes: expected at least one stroke, got none")
    for i, st in enumerate(strokes):
        if not all(hasattr(st, f) for f in ("contact", "normal", "tangent", "time", "depth")):
            raise BadInput(f"strokes: expected {form}; stroke {i} is {type(st).__name__} {shown(st, 60)}")
        try:
            c, n, tg, t = (np.asarray(v, dtype=float) for v in (st.contact, st.normal, st.tangent, st.time))
            depth = float(st.depth)
        except (TypeError, ValueError):  # text, a ragged nesting
            raise BadInput(f"stroke {i}: contact, normal, tangent, time and depth must be numbers (SI units)") from None
        if c.ndim != 2 or c.shape[1] != 3 or len(c) < 2 or not np.all(np.isfinite(c)):
            raise BadInput(f"stroke {i}: contact must be a (T ≥ 2, 3) array of finite metres, got shape {c.shape}")
        if n.shape != c.shape or not np.all(np.isfinite(n)) or not np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-3):
            raise BadInput(f"stroke {i}: normal must be ({len(c)}, 3) finite unit vectors")
        if tg.shape != c.shape or not np.all(np.isfinite(tg)):
            raise BadInput(
                f"stroke {i}: tangent must be ({len(c)}, 3) finite directions of motion, got shape {tg.shape}"
            )
        if t.shape != (len(c),) or not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
            raise BadInput(f"stroke {i}: time must be ({len(c)},) finite, strictly increasing seconds")
        if not force_controlled and not 0 < depth <= MAX_DEPTH_M:
            raise BadInput(f"stroke {i}: depth must be in (0, {MAX_DEPTH_M:g}] metres, got {st.depth!r}")


def record_strokes(
    obj,
    strokes,
    vf: VirtualFinger,
    seed: int,
    *,
    hold_currents=(0.15, 0.05, 0.05),
    mode: str | None = None,
    force: float | None = None,
    progress: bool = False,
) -> dict[str, np.ndarray]:
    """Simulate ``strokes`` over ``obj`` and collect the recording arrays (frames of all strokes in order).

    With ``force`` (N) the strokes are force-controlled: each frame's depth is solved for that normal force
    (the strokes' own depths are ignored); otherwise they are pressed to their depth.

    Parameters
    ----------
    obj : SceneObject
    strokes : sequence of Stroke
        :func:`bayestouch.scene.strokes.random_strokes` or strokes of the same form (:func:`check_strokes`).
    vf : VirtualFinger
        :func:`load_finger`.
    seed : int
        Seeds the noise, in [0, 2**63).

    Returns
    -------
    dict of str to ndarray
        The recording's arrays, frames of all strokes in order.
    """
    if not isinstance(vf, VirtualFinger):
        raise BadInput(f"vf: expected the VirtualFinger of bt.load_finger(), got {type(vf).__name__} {shown(vf, 60)}")
    if not callable(getattr(obj, "surface", None)):
        raise BadInput(f"obj: expected a SceneObject (load_object(NAME)), got {type(obj).__name__} {shown(obj, 60)}")
    check_int(seed, "seed", 0, 2**63 - 1, "an integer seed of the noise")  # JAX's key takes a 64-bit integer
    mode = mode or vf.mode
    if mode not in ("physics", "empirical"):
        raise BadInput(f"--mode must be physics or empirical, got {mode!r}")
    check_strokes(strokes, force is not None)
    strokes = list(strokes)
    surf = obj.surface()
    keys = jax.random.split(jax.random.PRNGKey(seed), len(strokes))
    cols: dict[str, list] = {
        k: []
        for k in (
            "time",
            "stroke_index",
            "taxel_current",
            "taxel_current_clean",
            "pressure",
            "contact_force",
            "friction_force",
            "contact_point",
            "contact_normal",
            "wire_current",
            "wire_temperature",
            "skin_temperature",
            "finger_tip_position",
            "finger_curvature",
            "pressing_depth",
        )
    }
    t0 = 0.0
    for i, st in enumerate(tqdm(strokes, desc="strokes", unit="stroke", disable=not progress)):
        dt = fw.frame_rate_dt(st)
        dr = drive(vf.wire, vf.rod, hold_currents, len(st.time), dt)
        arrs = fw.stroke_arrays(st)
        if force is not None:
            arrs = (*arrs[:3], fw.depths_for_force(surf, vf.finger, arrs, force))
        fr = fw.simulate_jit(surf, arrs, vf.finger, keys[i], skin_temperature=dr.skin_temperature, dt=dt, mode=mode)
        n = len(st.time)
        cols["time"].append(t0 + st.time)
        t0 += float(st.time[-1]) + dt
        cols["stroke_index"].append(np.full(n, i))
        cols["taxel_current"].append(np.asarray(fr.taxel_current))
        cols["taxel_current_clean"].append(np.asarray(fr.clean_current))
        cols["pressure"].append(np.asarray(fr.pressure).reshape(n, -1))
        cols["contact_force"].append(np.asarray(fr.force))
        cols["friction_force"].append(np.asarray(fr.friction))
        cols["pressing_depth"].append(np.broadcast_to(np.asarray(arrs[3]), (n,)).copy())
        cols["contact_point"].append(st.contact)
        cols["contact_normal"].append(st.normal)
        cols["wire_current"].append(dr.wire_current)
        cols["wire_temperature"].append(dr.wire_temperature)
        cols["skin_temperature"].append(dr.skin_temperature)
        cols["finger_tip_position"].append(dr.tip_position)
        cols["finger_curvature"].append(dr.curvature)
    return {k: np.concatenate(v) for k, v in cols.items()}


def recording_dataset(obj, strokes, vf: VirtualFinger, seed: int, *, mode: str | None = None, attrs=None, **kw):
    """:func:`record_strokes` as a recording (``xarray.Dataset``, :func:`bayestouch.io.recording.build_dataset`):
    the finger's taxel layout, each stroke's depth (m) and ``attrs`` (the taxel ``mode`` always among them);
    ``kw`` go to :func:`record_strokes`."""
    mode = mode or vf.mode
    rec = record_strokes(obj, strokes, vf, seed, mode=mode, **kw)
    g = np.asarray(vf.finger.grid).reshape(-1, 2)
    ref = np.asarray(vf.finger.reference).ravel()
    return build_dataset(rec, g[:, 0], g[:, 1], ref, [s.depth for s in strokes], {**(attrs or {}), "mode": mode})
