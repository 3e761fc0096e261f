"""Frame models of the virtual finger: what the device streams for a stroke plan.

:class:`ForwardModel` runs the physics of :func:`bayestouch.physics.virtual.record_strokes`;
:class:`SyntheticModel` is a fast stand-in for tests and benchmarks; :class:`GuardedModel` runs guarded strokes
(approach until contact) on a true object. Each is a callable ``(StrokePlan, stroke_index) -> dict`` of
:data:`FRAME_KEYS` arrays (T, ...) in SI units. Device-side safety and guarded strokes: ``docs/hardware.md``.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.hardware.device import pad_radius, winkler_depth, winkler_force
from bayestouch.hardware.safety import (
    StrokePlan,
    predicted_force,
    steady_wire_temperature,
)
from bayestouch.params import MODELS
from bayestouch.physics import bending, pose, sma
from bayestouch.physics import forward as fw
from bayestouch.physics.finger import skin_temperature
from bayestouch.physics.virtual import finger_name, load_finger, record_strokes
from bayestouch.scene.raycast import CONTACT, INSIDE, MISS, true_ray_distances
from bayestouch.scene.strokes import stroke_from_path

__all__ = ["FRAME_KEYS", "PROBE_KEYS", "SyntheticModel", "ForwardModel", "GuardedModel"]

#: per-frame arrays a frame model returns (T frames)
FRAME_KEYS = (
    "taxel_current",
    "wire_current",
    "wire_temperature",
    "skin_temperature",
    "finger_tip_position",
    "finger_curvature",
    "contact_force",
)


#: per-frame arrays a guarded stroke adds (:meth:`GuardedModel.probe`)
PROBE_KEYS = ("probe", "travel", "position")


def _grid(rows: int, cols: int, pitch: float = 8e-4):
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    uv = np.stack([c.ravel() * pitch, r.ravel() * pitch], axis=1)
    return uv - uv.mean(axis=0), (r.ravel() < 1).astype(np.uint8)


class SyntheticModel:
    """A fast stand-in for the forward model (tests, benchmarks): a Gaussian pressure spot under the pad
    centre whose height follows the depth, on a ``rows × cols`` grid; wire temperatures at their steady state.

    Deterministic given ``seed`` and the stroke index (small Gaussian noise on the currents).
    """

    def __init__(self, rows: int = 16, cols: int = 16, seed: int = 0):
        self.rows, self.cols, self.seed = int(rows), int(cols), int(seed)
        self.taxel_uv, self.reference = _grid(self.rows, self.cols)

    def __call__(self, plan: StrokePlan, index: int) -> dict[str, np.ndarray]:
        T = len(plan.time)
        g = np.random.default_rng([self.seed, index])
        r2 = np.sum(self.taxel_uv**2, axis=1)
        bump = np.exp(-r2 / (2 * 0.002**2)) * (plan.depth / 3e-4)
        phase = np.sin(2 * np.pi * np.asarray(plan.time) / 2.0)[:, None]
        cur = 1e-7 * (1.0 + 0.05 * bump[None, :] * (1 + 0.2 * phase)) * (1 + 1e-3 * g.normal(size=(T, len(r2))))
        temp = np.broadcast_to(steady_wire_temperature(plan.hold_currents), (T, 3))
        return {
            "taxel_current": cur,
            "wire_current": np.broadcast_to(np.asarray(plan.hold_currents, float), (T, 3)).copy(),
            "wire_temperature": temp.copy(),
            "skin_temperature": np.full(T, 293.15 + 0.03 * float(np.mean(temp[0] - 293.15))),
            "finger_tip_position": np.tile([0.0, 0.0, 0.06], (T, 1)),
            "finger_curvature": np.zeros((T, 2)),
            "contact_force": np.full(T, predicted_force(plan.depth) / 2.0),
        }


class ForwardModel:
    """The physics forward model (:func:`bayestouch.physics.virtual.record_strokes`) over a scene object.

    Parameters
    ----------
    obj : SceneObject
        What the virtual finger touches.
    models : Path
        Parameter folder (``finger.toml``, ``skin.toml``, ``taxels.toml``, ``noise.toml``).
    seed : int
        Fixed pattern of the device and, with the stroke index, the measurement noise.

    Guarded strokes (:meth:`probe`) find the contacts on ``obj`` (:class:`GuardedModel`; pose error ``pose_sd``,
    0.3 mm, an attribute). Carrier strokes (:meth:`carrier`) put the pad where this finger's bending chain takes it:
    the wire and rod constants are ``vf.wire`` and ``vf.rod`` (``models``'s; replace them, ``vf._replace``, for a
    finger whose constants are not the ones its pose estimate assumes, ``assumed``: its guarded strokes then carry
    that bending pose error too).
    """

    def __init__(self, obj, models: Path | None = None, seed: int = 0, mode: str | None = None):
        self.obj, self.seed, self.mode, self.pose_sd = obj, int(seed), mode, 3e-4
        self.vf = load_finger(Path(models or MODELS), seed=seed)
        self.assumed = (self.vf.wire, self.vf.rod)  # the constants its pose estimate uses
        self.finger = finger_name(seed)  # its identity, as simulated recordings of this finger name it
        grid = np.asarray(self.vf.finger.grid)
        self.rows, self.cols = grid.shape[:2]
        self.taxel_uv = grid.reshape(-1, 2)
        self.reference = np.asarray(self.vf.finger.reference).ravel().astype(np.uint8)
        self._lock = threading.Lock()

    def __call__(self, plan: StrokePlan, index: int) -> dict[str, np.ndarray]:
        st = stroke_from_path(plan.contact, plan.normal, plan.time, plan.depth)
        with self._lock:  # one compilation at a time
            rec = record_strokes(
                self.obj,
                [st],
                self.vf,
                self.seed * 100003 + index,
                hold_currents=tuple(np.asarray(plan.hold_currents, float)),
                mode=self.mode,
            )
        return {k: rec[k] for k in FRAME_KEYS}

    def carrier(self, program, index: int) -> dict[str, np.ndarray]:
        """A carrier stroke (protocol revision 1.3): the frames of the pad that this finger's bending chain
        (:func:`bayestouch.physics.pose.carrier_pad_path`, the wires cold at the start) puts where the base and the
        currents take it, touching the object where the pad overlaps it (:func:`~bayestouch.physics.pose
        .chain_stroke_arrays`; no force where it is clear), the skin warmed by the wires.

        Parameters
        ----------
        program : CarrierProgram or CarrierStroke
            ``time (T,)`` s (evenly spaced), ``base_position (T, 3)`` m, ``base_rotation (3, 3)``,
            ``currents (T, 3)`` A.
        index : int
            The stroke's index (seeds the measurement noise with ``seed``).

        Returns
        -------
        dict of :data:`FRAME_KEYS` arrays (T, ...); ``finger_tip_position`` and ``finger_curvature`` are the
        chain's own (what the finger senses of its bend, without sensor error).
        """
        vf = self.vf
        prog = _as_program(program)
        dt = pose.program_dt(prog.time)
        surf = self.obj.surface()
        with self._lock:  # one compilation at a time
            pad = pose.carrier_pad_path(vf.wire, vf.rod, prog)
            arrays = pose.chain_stroke_arrays(surf, pad, float(vf.finger.tip_radius))
            skin = skin_temperature(jnp.asarray(pad.tip.wire_temperature), vf.wire.ambient, dt)
            key = jax.random.PRNGKey(self.seed * 100003 + int(index))
            fr = fw.simulate_jit(surf, arrays, vf.finger, key, skin_temperature=skin, dt=dt, mode=self.mode or vf.mode)
        return {
            "taxel_current": np.asarray(fr.taxel_current, float),
            "wire_current": prog.currents.copy(),
            "wire_temperature": np.asarray(pad.tip.wire_temperature, float),
            "skin_temperature": np.asarray(skin, float),
            "finger_tip_position": np.asarray(pad.tip.tip_position, float),
            "finger_curvature": np.asarray(pad.tip.curvature, float),
            "contact_force": np.asarray(fr.force, float),
        }

    def probe(self, plan: StrokePlan, travel: float, threshold: float, index: int) -> dict[str, np.ndarray]:
        """A guarded stroke on this model's object (:meth:`GuardedModel.probe`, pose error ``pose_sd``; with the
        bending pose error of ``vf``'s constants where they are not ``assumed``)."""
        own = (self.vf.wire, self.vf.rod)
        same = own[0] is self.assumed[0] and own[1] is self.assumed[1]
        kw = {"finger": None if same else own, "assumed": self.assumed}
        guarded = GuardedModel(self.obj, self, pose_sd=self.pose_sd, seed=self.seed, **kw)
        return guarded.probe(plan, travel, threshold, index)


def _as_program(program) -> pose.CarrierProgram:
    """A CarrierProgram or a CarrierStroke message as a :class:`~bayestouch.physics.pose.CarrierProgram` of float
    arrays."""
    return pose.CarrierProgram(
        np.asarray(program.time, float),
        np.asarray(program.base_position, float),
        np.asarray(program.base_rotation, float).reshape(3, 3),
        np.asarray(program.currents, float),
    )


class GuardedModel:
    """A frame model that can run guarded strokes on a TRUE object (what a real finger with a force-controlled
    approach does).

    At waypoint j the pad starts at ``start_j`` and moves along ``u_j = −normal_j``. Where the ray
    ``start_j + t u_j`` first meets the true object (:func:`bayestouch.scene.raycast.true_ray_distances`:
    the scene object's signed distance, texture and defects included) at t_j ≤ ``travel``, the skin touches;
    the contact force crosses ``threshold`` once the pad centre is the Winkler indentation
    δ_th = :func:`~bayestouch.hardware.device.winkler_depth` ``(threshold)`` further in, at
    ``start_j + (t_j + δ_th) u_j``. That is reported with the device's pose-estimate error, a Gaussian of
    ``pose_sd`` metres in each coordinate (seeded by ``seed`` and the stroke index): the kinematic chain of a real
    finger (stage encoders, the bending model of the rod) knows its pad position only that well. No contact within
    the travel: probe status 1 (the pad at the end of the travel); a start already inside the object: status 2.

    The frames come from the wrapped ``frames`` model (default :class:`SyntheticModel`) on the path the pad
    actually followed: the true contact points with the true object's normals (the radial projection of the
    start for status 2, the end of the travel with no force for status 1), pressed to the plan's depth.

    With ``finger`` (the bending constants of this finger, which are not the ones its pose estimate assumes,
    ``assumed``) the pad's own pose error joins in: the rod points along the approach (its base frame's +z turned
    onto u_j by the smallest rotation R_j), holds the plan's currents as :func:`~bayestouch.physics.pose
    .held_pose_error` says, and so the pad runs along ``start_j + R_j e_j + t u_j`` while the device believes it on
    the commanded line. The crossing is found on the true line and reported on the believed one: millimetres of
    error, correlated along the stroke, where the bend is strong (``docs/physics_notes.md``).

    Parameters
    ----------
    obj : SceneObject
        The true object.
    frames : frame model, optional
        :class:`SyntheticModel` (default) or :class:`ForwardModel` (of the same object).
    pose_sd : float, metres
        Pose-estimate error of the pad centre, per coordinate (the stage's encoders and the sensing).
    seed : int
    finger : (WireParams, RodParams), optional
        This finger's bending constants (default: no bending error).
    assumed : (WireParams, RodParams), optional
        The constants the device's pose estimate uses (default ``models/finger.toml``'s).
    """

    def __init__(self, obj, frames=None, *, pose_sd: float = 3e-4, seed: int = 0, finger=None, assumed=None):
        self.obj, self.frames, self.pose_sd, self.seed = obj, frames or SyntheticModel(seed=seed), float(pose_sd), seed
        self.rows, self.cols = self.frames.rows, self.frames.cols
        self.taxel_uv, self.reference = self.frames.taxel_uv, self.frames.reference
        if finger is not None and assumed is None:
            assumed = (sma.load_wire(), bending.load_rod())
        self.finger, self.assumed = finger, assumed

    def __call__(self, plan: StrokePlan, index: int) -> dict[str, np.ndarray]:
        """An ordinary stroke: the wrapped model's frames."""
        return self.frames(plan, index)

    def carrier(self, program, index: int) -> dict[str, np.ndarray]:
        """A carrier stroke (protocol revision 1.3) through this finger's bending chain: the pad goes where the
        base and this finger's constants (``finger``, else ``assumed``) put it (:func:`~bayestouch.physics.pose
        .carrier_pad_path`, the wires cold at the start); its force is the Winkler force of its overlap with the true
        object (:func:`~bayestouch.physics.pose.chain_stroke_arrays`, :func:`~bayestouch.hardware.device
        .winkler_force`; none where it is clear). The finger senses its own bend (``finger_tip_position``,
        ``finger_curvature`` are the chain's). The taxel currents come from the wrapped model on the path the pad
        met (cosmetic for the synthetic model).

        Parameters
        ----------
        program : CarrierProgram or CarrierStroke
        index : int

        Returns
        -------
        dict of :data:`FRAME_KEYS` arrays (T, ...)
        """
        wire, rod = self.finger if self.finger is not None else (self.assumed or (sma.load_wire(), bending.load_rod()))
        prog = _as_program(program)
        pad = pose.carrier_pad_path(wire, rod, prog)
        R = pad_radius()
        contact, normal, _, depth = (np.asarray(a, float) for a in pose.chain_stroke_arrays(self.obj.surface(), pad, R))
        touched = depth > 0
        met = StrokePlan(
            prog.time, contact, normal, float(np.median(depth[touched])) if touched.any() else 3e-4, prog.currents[0]
        )
        out = {k: np.array(v, float) for k, v in self.frames(met, index).items()}
        out["contact_force"] = np.asarray(winkler_force(depth, tip_radius=R), float)
        out["wire_current"] = prog.currents.copy()
        out["wire_temperature"] = np.asarray(pad.tip.wire_temperature, float)
        out["finger_tip_position"] = np.asarray(pad.tip.tip_position, float)
        out["finger_curvature"] = np.asarray(pad.tip.curvature, float)
        return out

    def probe(self, plan: StrokePlan, travel: float, threshold: float, index: int) -> dict[str, np.ndarray]:
        """A guarded stroke (``plan.contact`` holds the approach starts): :data:`FRAME_KEYS` arrays plus
        ``probe (T,)``, ``travel (T,)`` m and ``position (T, 3)`` m (see the class docstring)."""
        believed = np.asarray(plan.contact, float)
        u = -np.asarray(plan.normal, float)
        start = believed
        if self.finger is not None:  # the pad runs on the line the bent rod puts it on
            err = pose.held_pose_error(self.finger, self.assumed, plan.hold_currents, plan.time)
            rot = np.stack([pose.rotation_between([0.0, 0.0, 1.0], uj) for uj in u])
            start = believed + np.einsum("tij,tj->ti", rot, err)
        t, status = true_ray_distances(self.obj, start, u, float(travel))
        hit, miss, inside = status == CONTACT, status == MISS, status == INSIDE
        d_th = float(winkler_depth(threshold))
        g = np.random.default_rng([self.seed, index, 7])
        # where the device believes the pad was: on the commanded line, at the travel it measured
        pad = np.where(hit[:, None], believed + (t + d_th)[:, None] * u, believed)
        pad = np.where(miss[:, None], believed + float(travel) * u, pad)
        position = pad + self.pose_sd * g.standard_normal(pad.shape)
        # the path the pad followed, for the frames: true surface points and normals
        shape = self.obj.shape
        surf = np.where(hit[:, None], start + t[:, None] * u, start)
        if inside.any():
            surf[inside] = ne.evaluate(ne.project_to_surface, shape, jnp.asarray(start[inside]))
        nrm = np.where(miss[:, None], -u, 0.0)
        touched = ~miss
        if touched.any():
            nrm[touched] = ne.evaluate(ne.normals, shape, jnp.asarray(surf[touched]))
        followed = StrokePlan(plan.time, surf, nrm, plan.depth, plan.hold_currents)
        out = {k: np.array(v, float) for k, v in self.frames(followed, index).items()}
        out["contact_force"][miss] = 0.0
        out["probe"] = np.select([hit, miss], [0, 1], 2).astype(int)
        out["travel"] = np.where(hit, t + d_th, np.where(miss, np.nan, 0.0))
        out["position"] = position
        return out
