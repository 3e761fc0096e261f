"""The exploration loop drives a finger: :class:`DeviceProber` runs planned strokes on a
:class:`~bayestouch.hardware.device.FingerDevice` as guarded strokes and turns what it reports into contact points
(K, 3) in metres and :class:`~bayestouch.inference.freespace.Free` observations (misses and starts inside); with
``carrier=True`` it runs them as carrier strokes (protocol revision 1.3): the pad slid along the believed surface by
base motion and wire currents from the inverse of the bending chain, corrected by a calibrated pose-error law, and
the contacts taken from the pad's sensed pose.

Every stroke's frames are kept (:attr:`DeviceProber.strokes`, rewritten to ``recording`` after each stroke when
given, with the schema of ``bayestouch simulate``). How a finger knows where it touched, and the errors of that
estimate: ``docs/hardware.md``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayestouch.errors import BadInput
from bayestouch.hardware.device import (
    CarrierData,
    FingerDevice,
    ForceAbort,
    HeaterFault,
    ProbeData,
    ProbePlan,
    StrokeData,
    build_recording,
    depth_for_force,
    pad_radius,
    winkler_depth,
)
from bayestouch.hardware.safety import StrokePlan, UnsafePlan
from bayestouch.inference import pose_error as pe
from bayestouch.inference.freespace import Free
from bayestouch.inference.held_law import (
    Conditioned,
    HeldLaw,
    condition_held_law,
    law_mean_at,
    law_members,
    prior_held_law,
)
from bayestouch.io.recording import write_recording
from bayestouch.physics import bending, pose, sma
from bayestouch.planning.candidates import Strokes, make_candidates, select

__all__ = [
    "DeviceProber",
    "VirtualFingerProber",
    "PROBE_THRESHOLD",
    "POSE_SD",
    "probe_points",
    "carrier_points",
    "calibrate_bending",
    "calibration_strokes",
    "CALIBRATION_STROKES",
    "CALIBRATION_TILT",
    "LAW_SPAN",
    "CARRIER_DEPTH",
]

#: contact force that counts as the touch, newtons (a fifth of the smallest planned force, 0.1 N)
PROBE_THRESHOLD = 0.02
#: wire hold currents of the planned strokes, amperes (those of ``bayestouch device run``)
HOLD_CURRENTS = (0.15, 0.05, 0.05)
#: pose-estimate error of the virtual finger's pad, metres per coordinate (:class:`VirtualFingerProber`)
POSE_SD = 3e-4
#: guarded strokes of a bending calibration (:func:`calibrate_bending`)
CALIBRATION_STROKES = 6
#: the longest stroke, seconds, a calibrated pose-error law covers (the planner's strokes take 1–3 s)
LAW_SPAN = 4.0
#: tilt of a calibration stroke's approaches from the surface normal, radians (:func:`calibration_strokes`)
CALIBRATION_TILT = 0.5
#: designed overlap of a carrier stroke's pad with the believed surface, metres: its Winkler force is 0.29 N, in
#: the middle of the window between the 0.02 N contact threshold (0.13 mm) and the 1 N abort (0.93 mm), so ±0.4 mm
#: of surface or pose error keeps a frame in contact and under the limit
CARRIER_DEPTH = 5e-4
#: a carrier stroke's lead-in: the pad held this far out along the first normal, metres, while the wires warm for
#: :data:`bayestouch.physics.pose.HELD_WARMUP` (the thermal state the held pose-error law assumes), then brought to
#: the path's start in :data:`CARRIER_APPROACH` seconds
CARRIER_STANDOFF = 0.015
CARRIER_APPROACH = 0.5


def probe_points(data: ProbeData, threshold_depth: float) -> tuple[np.ndarray, Free]:
    """Contact points (K, 3) m and :class:`~bayestouch.inference.freespace.Free` observations of one guarded stroke.

    Parameters
    ----------
    data : ProbeData
    threshold_depth : float, metres
        Skin indentation at the threshold force (subtracted along the approach direction).
    """
    u = -np.asarray(data.plan.normal, float)
    start = np.asarray(data.plan.start, float)
    hit, miss, inside = data.probe == 0, data.probe == 1, data.probe == 2
    pts = data.position[hit] - threshold_depth * u[hit]
    return pts, Free(start[miss], u[miss], float(data.plan.travel), start[inside])


def carrier_points(
    data: CarrierData, normal, tip_radius: float, *, threshold: float = PROBE_THRESHOLD
) -> tuple[np.ndarray, Free]:
    """Contact points (K, 3) m and :class:`~bayestouch.inference.freespace.Free` observations of one carrier stroke
    (protocol revision 1.3), from what the host knows: the pad centre it senses (``data.pad_centre()``: the
    commanded base pose × the sensed tip), the measured force, and the normal it believes.

    A frame whose force exceeds ``threshold`` touched: the contact is the sensed pad centre less the pad's radius
    minus its indentation at that force (:func:`~bayestouch.hardware.device.winkler_depth`) along the believed
    normal. A frame below it touched nothing: the pad's sphere was clear of the object, so the segment from its centre
    along −normal over ``tip_radius`` is free space (a ray that met nothing).

    Parameters
    ----------
    data : CarrierData
    normal : (T, 3) float
        Believed outward unit normals at the frames (those the stroke's path was planned on).
    tip_radius : float, metres
        Radius of the pad's outer (skin) surface.
    threshold : float, N

    Returns
    -------
    points : (K, 3) float, metres
    free : Free
        Rays of length ``tip_radius`` from the clear frames' pad centres; no starts inside.
    """
    centre = data.pad_centre()
    n = np.asarray(normal, float)
    if n.shape != centre.shape or not np.all(np.isfinite(n)):
        raise BadInput(f"normal: expected finite {centre.shape} unit normals, one per frame, got shape {n.shape}")
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    force = np.asarray(data.frames["contact_force"], float)
    touched = force > float(threshold)
    delta = np.asarray(winkler_depth(force[touched], tip_radius=float(tip_radius)))
    points = centre[touched] - (float(tip_radius) - delta)[:, None] * n[touched]
    free = Free(centre[~touched], -n[~touched], float(tip_radius), np.zeros((0, 3)))
    return points, free


class DeviceProber:
    """A prober (:mod:`bayestouch.planning.loop`) that runs each planned stroke on a finger (module docstring).

    Parameters
    ----------
    device : FingerDevice
        Open (handshake done).
    threshold : float, N
        Contact force that counts as the touch.
    hold_currents : (3,) float, amperes
    recording : path, optional
        A ``.nc`` file rewritten (atomically) after every stroke with all strokes so far.
    attrs : dict, optional
        Extra attributes of the recording.
    constants : (WireParams, RodParams), optional
        The bending constants the device's pose estimate uses, the centre of :meth:`pose_ensemble`'s law (default
        ``models/finger.toml``'s).
    pose_law : HeldLaw, optional
        This finger's held pose-error law, conditioned on a bending calibration
        (:func:`bayestouch.inference.held_law.condition_held_law`): :meth:`pose_ensemble` draws from it instead of
        drawing fingers about ``constants``, and carrier strokes are corrected by its mean (:meth:`carrier_plan`).
    carrier : bool
        Run each planned stroke as a carrier stroke (:meth:`carrier_plan`) instead of a guarded one; the contacts
        come from the pad's sensed pose (:func:`carrier_points`), so there is no pose-error law to marginalise.
    carrier_depth : float, metres
        Designed overlap of a carrier stroke's pad with the believed surface.

    Attributes
    ----------
    strokes : list of StrokeData
        Every completed stroke, its plan's ``contact`` the estimated contact points (the pad's pose estimate at
        the end of the travel for a miss, at the start for a start inside) and ``normal`` the approach normals.
    probes : list of ProbeData
    refused : list of str
        Why each refused stroke was refused (nothing was sent for them).
    carriers : list of CarrierData
        Every carrier stroke run, whole or up to a force abort.
    aborted : int
        Carrier strokes the device stopped at its force limit.
    """

    def __init__(
        self,
        device: FingerDevice,
        *,
        threshold: float = PROBE_THRESHOLD,
        hold_currents=HOLD_CURRENTS,
        recording=None,
        attrs: dict | None = None,
        constants=None,
        pose_law: HeldLaw | None = None,
        carrier: bool = False,
        carrier_depth: float = CARRIER_DEPTH,
    ):
        if not isinstance(carrier, bool):
            raise BadInput(f"carrier: expected True or False, got {carrier!r}")
        if not (isinstance(carrier_depth, int | float) and 0 < carrier_depth <= 2e-3):
            raise BadInput(f"carrier_depth: expected a designed overlap in (0, 0.002] m, got {carrier_depth!r}")
        self.carrier, self.carrier_depth = carrier, float(carrier_depth)
        self.carriers: list[CarrierData] = []
        self.aborted = 0
        self.device, self.threshold = device, float(threshold)
        self._held: dict = {}
        self.hold_currents = np.asarray(hold_currents, float)
        self.constants, self.pose_law = constants, pose_law
        if pose_law is not None and not np.allclose(pose_law.hold_currents, self.hold_currents, rtol=0, atol=1e-9):
            raise BadInput(
                f"pose_law: calibrated at hold currents {np.asarray(pose_law.hold_currents).tolist()} A, the strokes "
                f"hold {self.hold_currents.tolist()} A; calibrate at the currents the strokes use"
            )
        self.recording_path = Path(recording) if recording else None
        self.attrs = dict(attrs or {})
        self.threshold_depth = float(winkler_depth(self.threshold))
        self.strokes: list[StrokeData] = []
        self.probes: list[ProbeData] = []
        self.refused: list[str] = []

    def plan(self, stroke: Strokes) -> ProbePlan:
        """The guarded-stroke plan of ``stroke`` (a batch of one)."""
        T = stroke.starts.shape[1]
        return ProbePlan(
            np.linspace(0.0, float(stroke.duration[0]), T),
            np.asarray(stroke.starts[0], float),
            -np.asarray(stroke.dirs[0], float),
            depth_for_force(float(stroke.force[0])),
            self.hold_currents,
            float(stroke.t_max),
            self.threshold,
        )

    def carrier_plan(self, stroke: Strokes) -> tuple[pose.CarrierProgram, np.ndarray]:
        """The carrier program of ``stroke`` (a batch of one) and the believed outward normals (F, 3) of its frames.

        The wires hold :attr:`hold_currents` from the first frame, from cold. For
        :data:`~bayestouch.physics.pose.HELD_WARMUP` seconds the pad waits :data:`CARRIER_STANDOFF` out along the
        path's first normal (the state a guarded stroke's law assumes), comes in over :data:`CARRIER_APPROACH`
        seconds, then slides along the stroke's path over the believed surface, pressed :attr:`carrier_depth` into
        it, at the path's frame interval (its duration over its T − 1 intervals). The base motion comes from the
        inverse of the bending chain on the host's constants (:func:`bayestouch.physics.pose.carrier_program`); with
        :attr:`pose_law` the base also moves by −R μ(t), μ(t) the calibrated law's mean tip error in the base frame
        at t seconds after the warm-up (its value at 0 before), so that the finger's own pad, not the host's nominal
        one, follows the path.

        Raises
        ------
        UnsafePlan
            The path outlasts the calibrated law's grid (nothing is sent).
        """
        path = np.asarray(stroke.path[0], float)
        normal = -np.asarray(stroke.dirs[0], float)
        T = len(path)
        dt = float(stroke.duration[0]) / (T - 1)
        lead, approach = int(np.ceil(pose.HELD_WARMUP / dt)), int(np.ceil(CARRIER_APPROACH / dt))
        away = path[0] + CARRIER_STANDOFF * normal[0]
        come = np.linspace(1.0, 0.0, approach, endpoint=False)[:, None] * CARRIER_STANDOFF * normal[0] + path[0]
        contact = np.concatenate([np.tile(away, (lead, 1)), come, path])
        normals = np.concatenate([np.tile(normal[0], (lead + approach, 1)), normal])
        t = np.arange(len(contact)) * dt
        wire, rod = self.host_constants()
        held = np.tile(self.hold_currents, (len(t), 1))
        prog = pose.carrier_program(wire, rod, contact, normals, t, self.carrier_depth, pad_radius(), currents=held)
        if self.pose_law is not None:
            since = np.maximum(t - pose.HELD_WARMUP, 0.0)
            if since[-1] > self.pose_law.grid[-1] + 1e-9:
                raise UnsafePlan(
                    f"carrier plan: the path ends {since[-1]:.3g} s after the warm-up, the calibrated law covers "
                    f"{self.pose_law.grid[-1]:.3g} s; calibrate with a longer span"
                )
            mu = law_mean_at(self.pose_law, since)
            prog = prog._replace(base_position=prog.base_position - mu @ np.asarray(prog.base_rotation).T)
        return prog, normals

    def probe(self, stroke: Strokes, rng=None) -> tuple[np.ndarray, Free]:
        """Run ``stroke`` (a batch of one) on the finger: contact points (K, 3) m and
        :class:`~bayestouch.inference.freespace.Free` observations. ``rng`` is unused (the finger's noise is its own).
        As a carrier stroke (:attr:`carrier`): the frames over the force threshold are contacts, a stroke the device
        stopped at its force limit gives those before the stop, and the clear frames give no observation (free space
        is a guarded stroke's).

        Raises
        ------
        UnsafePlan
            Before anything is sent (recorded in :attr:`refused`).
        DeviceError
            The device failed; the strokes so far are kept (and in ``recording``).
        """
        return self._probe_carrier(stroke) if self.carrier else self._probe_guarded(stroke)

    def scout(self, stroke: Strokes, rng=None) -> tuple[np.ndarray, Free]:
        """A stroke that finds the object (the exploration loop's scout): always guarded, since a carrier stroke
        over a surface not yet known would press into it or slide past it. With :attr:`carrier` and
        :attr:`pose_law` its contacts are moved by the calibrated law's mean error, R_j μ(t_j) (the carrier loop
        marginalises no law); otherwise as :meth:`probe`."""
        pts, free = self._probe_guarded(stroke)
        if self.carrier and self.pose_law is not None and len(pts):
            p = self.probes[-1]
            hit = np.asarray(p.probe) == 0
            t = np.asarray(p.plan.time, float)[hit] - float(p.plan.time[0])
            mu = law_mean_at(self.pose_law, t)
            rot = np.array([pose.rotation_between([0.0, 0.0, 1.0], -n) for n in np.asarray(p.plan.normal)[hit]])
            pts = pts + np.einsum("mij,mj->mi", rot.reshape(-1, 3, 3), mu)
        return pts, free

    def _probe_guarded(self, stroke: Strokes) -> tuple[np.ndarray, Free]:
        plan = self.plan(stroke)
        try:
            data = self.device.run_probe(plan)
        except UnsafePlan as e:
            self.refused.append(str(e))
            raise
        except HeaterFault as e:  # the stroke is complete: kept (and written) before the fault stops the loop
            if e.data is not None:
                self._keep(plan, e.data)
            raise
        return self._keep(plan, data)

    def _probe_carrier(self, stroke: Strokes) -> tuple[np.ndarray, Free]:
        prog, normal = self.carrier_plan(stroke)
        none = Free(np.zeros((0, 3)), np.zeros((0, 3)), float(stroke.t_max), np.zeros((0, 3)))
        try:
            data = self.device.run_carrier(prog)
        except UnsafePlan as e:
            self.refused.append(str(e))
            raise
        except HeaterFault as e:
            if e.data is not None:
                self.carriers.append(e.data)
            raise
        except ForceAbort as e:  # the frames before the stop are contacts like any others
            self.aborted += 1
            if e.data is None:
                return np.zeros((0, 3)), none
            data = e.data
        self.carriers.append(data)
        pts, _ = carrier_points(data, normal[: len(data.device_time)], pad_radius(), threshold=self.threshold)
        return pts, none

    def _keep(self, plan: ProbePlan, data: ProbeData) -> tuple[np.ndarray, Free]:
        """Record one guarded stroke (and rewrite the recording); its contact points and free-space observations."""
        pts, free = probe_points(data, self.threshold_depth)
        est = data.position - self.threshold_depth * (-plan.normal) * (data.probe == 0)[:, None]
        self.probes.append(data)
        self.strokes.append(
            StrokeData(
                StrokePlan(plan.time, est, plan.normal, plan.depth, plan.hold_currents),
                data.frames,
                data.device_time,
                data.stroke_id,
            )
        )
        if self.recording_path is not None:
            write_recording(self.dataset(), self.recording_path, overwrite=True)  # this run's, after each stroke
        return pts, free

    def host_constants(self) -> tuple:
        """The bending constants (WireParams, RodParams) the device's pose estimate uses: ``constants``, or
        ``models/finger.toml``'s (loaded once)."""
        if self.constants is None:
            self.constants = (sma.load_wire(), bending.load_rod())
        return self.constants

    def contacts(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every contact so far as :meth:`probe` returned them (M, 3) m, with its approach direction (M, 3) (the
        pad moved along it), its stroke (M,) (index in :attr:`probes`) and its time since the stroke's start (M,) s:
        what a bending calibration reads (:func:`bayestouch.inference.held_law.condition_held_law`)."""
        pts, app, lab, tt = [np.zeros((0, 3))], [np.zeros((0, 3))], [np.zeros(0, int)], [np.zeros(0)]
        for s, p in enumerate(self.probes):
            hit = np.asarray(p.probe) == 0
            pts.append(probe_points(p, self.threshold_depth)[0])
            app.append(-np.asarray(p.plan.normal, float)[hit])
            lab.append(np.full(int(hit.sum()), s))
            tt.append(np.asarray(p.plan.time, float)[hit] - float(p.plan.time[0]))
        return np.concatenate(pts), np.concatenate(app), np.concatenate(lab), np.concatenate(tt)

    def pose_ensemble(
        self, draws: int = 24, *, seed: int = 0, spread: pose.FingerSpread | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The host's law of the pad's pose error at every contact so far, as ``draws`` fingers drawn about its
        constants say (:func:`bayestouch.physics.pose.held_error_ensemble`; the input of
        :func:`bayestouch.inference.pose_error.ensemble_model`).

        A guarded stroke holds :attr:`hold_currents`; the rod points along each approach (its base frame's +z
        turned onto −normal by the smallest rotation R_j, :func:`~bayestouch.physics.pose.rotation_between`), so a
        finger whose constants differ from the host's runs its pad on the approach line moved by R_j e(t_j), e the
        tip's error in the base frame at the waypoint's time. The same drawn fingers serve every stroke (one
        finger runs them all), so the law correlates strokes as well as a stroke's waypoints.

        Parameters
        ----------
        draws : int
            Drawn fingers K (≥ 2), or members of :attr:`pose_law` when it is given.
        seed : int
        spread : FingerSpread, optional
            How far the finger may be from the host's constants (default
            :class:`~bayestouch.physics.pose.FingerSpread`); unused with :attr:`pose_law`.

        Returns
        -------
        ensemble : (K, M, 3) float, metres
            Pose errors p_true − p_host of every drawn finger at the M contacts, in the order :meth:`probe`
            returned them.
        strokes : (M,) int
            Stroke of each contact (its index in :attr:`probes`).
        times : (M,) float, seconds
            Each contact's waypoint time in its stroke.
        """
        if self.carrier:
            raise BadInput(
                "pose_ensemble: carrier strokes take their contacts from the pad's sensed pose; there is no pose-error "
                "law to marginalise (use pose_draws 0)"
            )
        span = max((float(p.plan.time[-1] - p.plan.time[0]) for p in self.probes), default=0.0)
        if self.pose_law is not None:
            if span > self.pose_law.grid[-1] + 1e-9:
                raise BadInput(
                    f"pose_law: covers strokes of up to {self.pose_law.grid[-1]:.3g} s, a stroke took {span:.3g} s; "
                    "calibrate with a longer span"
                )
            grid, held = self.pose_law.grid, law_members(self.pose_law, int(draws), seed)
        else:
            wire, rod = self.host_constants()
            key = (int(draws), int(seed), spread, tuple(self.hold_currents))
            grid, held = self._held.get(key, (np.zeros(1), None))
            if held is None or grid[-1] < span:  # one chain run covers every stroke up to the next whole second
                grid = np.arange(0.0, np.ceil(span) + 1.0 + 0.5 * pose.HELD_DT, pose.HELD_DT)
                held = pose.held_error_ensemble(
                    wire, rod, self.hold_currents, grid, spread=spread, draws=draws, seed=seed
                )
                self._held[key] = (grid, held)
        _, approach, labels, times = self.contacts()
        e = pose.interp_grid(grid, held, times, axis=1)  # (K, M, 3)
        rot = np.array([pose.rotation_between([0.0, 0.0, 1.0], u) for u in approach]).reshape(-1, 3, 3)
        return np.einsum("mij,kmj->kmi", rot, e), labels, times

    def pose_model(self, points, draws: int = 24, *, offset_sd: float = 0.0) -> pe.EnsembleModel:
        """The pose-error law of :meth:`pose_ensemble` over ``points`` (M, 3) m, the contacts as :meth:`probe`
        returned them (:func:`bayestouch.inference.pose_error.ensemble_model`; ``offset_sd`` metres per stroke).

        Raises
        ------
        BadInput
            ``points`` are not this prober's contacts (another count).
        """
        ens, labels, times = self.pose_ensemble(draws)
        if ens.shape[1] != len(points):
            raise BadInput(
                f"prober: its pose law covers {ens.shape[1]} contacts, the loop holds {len(points)}; use a fresh "
                "prober per exploration"
            )
        return pe.ensemble_model(points, ens, labels, times, offset_sd=float(offset_sd))

    def dataset(self):
        """All strokes so far as the ``xarray.Dataset`` of :mod:`bayestouch.io.recording` (the schema of
        ``bayestouch simulate``; ``contact_point`` holds the estimated contact points)."""
        attrs = {
            "source": "bayestouch explore on a finger (guarded strokes)",
            "contact_point_note": "estimated from the pose at the force threshold minus the threshold indentation",
            "probe_threshold_N": self.threshold,
            **self.attrs,
        }
        return build_recording(self.strokes, self.device.info, attrs)


class VirtualFingerProber:
    """A prober that runs every stroke on an in-process virtual finger over the serial protocol: a
    :class:`~bayestouch.hardware.simulator.VirtualDevice` serving guarded strokes on the true object
    (:class:`~bayestouch.hardware.frame_models.GuardedModel`: the contact where the force crosses the threshold,
    reported with the pad's pose-estimate error ``pose_sd``; frames from the fast synthetic model) on a
    pseudo-terminal, a :class:`~bayestouch.hardware.device.FingerDevice` client and a :class:`DeviceProber`. What
    ``bayestouch experiment --prober finger`` runs each trial through. A context manager (the device and its thread
    are closed on exit).

    Parameters
    ----------
    obj : SceneObject
        The true object.
    seed : int
        Seeds the pose errors.
    pose_sd : float, metres
    finger : (WireParams, RodParams), optional
        The virtual finger's bending constants when they are not ``models/``'s: its pads then run where its bent rod
        puts them and are reported where the nominal constants say (``GuardedModel``'s ``finger``; for example
        :func:`bayestouch.physics.pose.draw_finger`).
    pose_law : HeldLaw, optional
        The :class:`DeviceProber`'s calibrated pose-error law (:func:`calibrate_bending`).
    carrier : bool
        The :class:`DeviceProber` runs carrier strokes (the virtual finger runs them through its own bending chain,
        :meth:`~bayestouch.hardware.frame_models.GuardedModel.carrier`).
    """

    def __init__(self, obj, *, seed: int = 0, pose_sd: float = POSE_SD, finger=None, pose_law=None, carrier=False):
        self.obj, self.seed, self.pose_sd, self.finger = obj, int(seed), float(pose_sd), finger
        self.pose_law, self.carrier = pose_law, carrier
        self._sim = self._dev = None

    def __enter__(self) -> DeviceProber:
        from bayestouch.hardware.frame_models import GuardedModel
        from bayestouch.hardware.simulator import VirtualDevice

        model = GuardedModel(self.obj, pose_sd=self.pose_sd, seed=self.seed, finger=self.finger)
        self._sim = VirtualDevice(model, speed=0.0).start()
        try:
            self._dev = FingerDevice(self._sim.port, timeout=0.5).open()
        except BaseException:
            self._sim.close(timeout=5.0)
            raise
        return DeviceProber(self._dev, pose_law=self.pose_law, carrier=self.carrier)

    def __exit__(self, *exc) -> None:
        if self._dev is not None:
            self._dev.close()
        if self._sim is not None:
            self._sim.close(timeout=5.0)


def calibration_strokes(obj, count: int, *, seed: int = 0, tilt: float = CALIBRATION_TILT, points: int = 20) -> Strokes:
    """Guarded strokes over a known object for a bending calibration: arcs over its true surface
    (:func:`~bayestouch.planning.candidates.make_candidates` on its shape) whose approaches are tilted from the
    inward normal by ``tilt`` radians, the tilt's direction turning a quarter turn from one waypoint to the next.

    Approaches along the normal of a sphere all aim at its centre: a pad moved sideways by the finger's bend then
    meets the sphere only (lateral offset)²/2R further along, the same for either side, and a lateral error of
    centimetres passes for an axial one. Tilted approaches meet the surface obliquely, so a sideways offset moves
    the contact along the approach at first order, in a direction that changes from waypoint to waypoint.

    Parameters
    ----------
    obj : SceneObject
        The known object.
    count : int
    seed : int
    tilt : float, radians
        In [0, 1.2].
    points : int
        Waypoints per stroke.

    Returns
    -------
    Strokes
        Starts 2.5 cm out along each approach from the arc's surface point, travel 5 cm.
    """
    if not (np.isfinite(tilt) and 0 <= tilt <= 1.2):
        raise BadInput(f"tilt: expected an approach tilt in [0, 1.2] radians, got {tilt!r}")
    standoff = 0.025
    arcs = make_candidates(obj.shape, int(count), points=int(points), seed=[int(seed), 0xCA1], standoff=standoff)
    n = -np.asarray(arcs.dirs, float)  # outward normals (C, T, 3)
    ahead = np.gradient(np.asarray(arcs.path, float), axis=1)
    a = ahead - np.sum(ahead * n, axis=-1, keepdims=True) * n
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.cross(n, a)
    phi = 0.5 * np.pi * np.arange(arcs.path.shape[1])[None, :, None]
    side = np.cos(phi) * a + np.sin(phi) * b
    u = -np.cos(tilt) * n + np.sin(tilt) * side
    return arcs._replace(starts=np.asarray(arcs.path) - standoff * u, dirs=u)


def calibrate_bending(
    prober: DeviceProber,
    obj,
    *,
    strokes: int = CALIBRATION_STROKES,
    seed: int = 0,
    draws: int = 64,
    span: float = LAW_SPAN,
    noise_sd: float = POSE_SD,
    spread: pose.FingerSpread | None = None,
) -> Conditioned:
    """A bending calibration: guarded strokes over a known object, and the held pose-error law they condition
    (:mod:`bayestouch.inference.held_law`).

    ``strokes`` arcs over the object's true surface with tilted approaches (:func:`calibration_strokes`) run as
    guarded strokes on ``prober``'s finger; their contacts, recorded where the finger's nominal constants put the
    pad, condition the law of ``draws`` fingers drawn about those constants. Strokes refused as unsafe are
    skipped.

    Parameters
    ----------
    prober : DeviceProber
        The finger (its strokes stay in :attr:`DeviceProber.probes`; use a fresh prober to explore).
    obj : SceneObject
        The calibration object, in the finger's world frame (e.g. a sphere of 2 cm radius).
    strokes : int
    seed : int
        Arcs and drawn fingers.
    draws : int
        Drawn fingers of the prior law.
    span : float, seconds
        Longest stroke the law covers.
    noise_sd : float, metres
        The contacts' own noise per coordinate (the encoders').
    spread : FingerSpread, optional

    Returns
    -------
    Conditioned
        Its ``law`` for :class:`DeviceProber` ``(pose_law=...)``; residuals before and after.
    """
    if not (isinstance(strokes, int | np.integer) and strokes >= 1):
        raise BadInput(f"strokes: expected an integer ≥ 1 calibration strokes, got {strokes!r}")
    arcs = calibration_strokes(obj, int(strokes), seed=seed)
    for i in range(int(strokes)):
        try:
            prober.probe(select(arcs, i))
        except UnsafePlan:
            continue
    pts, app, _, times = prober.contacts()
    if len(pts) < 12:
        raise BadInput(
            f"object: the calibration touched {len(pts)} points; is the object where its file says, within reach?"
        )
    wire, rod = prober.host_constants()
    law = prior_held_law(
        wire, rod, prober.hold_currents, max(float(span), float(times.max())), spread=spread, draws=draws, seed=seed
    )
    return condition_held_law(law, obj.surface(), pts, app, times, noise_sd)
