"""``FingerDevice``: the pyserial client of the finger (real port, ``loop://``, ``socket://`` or a pty).

Commands are retried until answered, a lost port is reopened, missing frames are requested again, and everything
received is appended to a journal file as it arrives (:func:`read_journal`); every plan passes
:func:`~bayestouch.hardware.safety.check_plan` before any byte is written. Completed strokes are
:class:`StrokeData` / :class:`ProbeData` (per-frame arrays (T, ...), SI units). Retries, safety and guarded
strokes: ``docs/hardware.md``.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import serial
from tqdm.auto import tqdm

from bayestouch.errors import BadInput, check_bool, check_int, check_number, check_path, file_problem, shown
from bayestouch.hardware import protocol as pr
from bayestouch.hardware.safety import (
    FORCE_FACTOR,
    Limits,
    PlanCheck,
    StrokePlan,
    UnsafePlan,
    check_carrier,
    check_limits,
    check_plan,
    plan_from_stroke,
)
from bayestouch.io.recording import CURRENT_FLOOR_A, PHYSICAL_RANGES, build_dataset
from bayestouch.params import MODELS
from bayestouch.physics import bending
from bayestouch.physics import skin as sk

__all__ = [
    "FingerDevice",
    "DeviceError",
    "HeaterFault",
    "ForceAbort",
    "finger_of",
    "StrokeData",
    "read_journal",
    "JournalStrokes",
    "strokes_from_journal",
    "strokes_to_frames",
    "build_recording",
    "ProbePlan",
    "ProbeData",
    "CarrierData",
    "winkler_depth",
    "winkler_force",
    "pad_radius",
    "depth_for_force",
    "frame_problem",
    "AUTO_SEGMENT",
]

#: PART size (packet bytes) chosen when whole packets do not get through: with 28 bytes of framing per part it
#: carries the most data per byte sent at 0.5–2 % byte loss (48 / 76 of each part, 47 % of parts whole at 1 %)
AUTO_SEGMENT = 48


class DeviceError(RuntimeError):
    """The device did not do what was asked (no answer after the retries, a refusal, a fault)."""


class HeaterFault(DeviceError):
    """The device reports its heaters on although no stroke runs (stuck heater).

    The stroke itself was complete: ``data`` holds it (:class:`StrokeData` from :meth:`FingerDevice.run_stroke`,
    :class:`ProbeData` from :meth:`FingerDevice.run_probe`; None where the fault was raised before the stroke's
    frames became one), so a caller keeps it while it stops stroking."""

    def __init__(self, message: str, frames=None):
        super().__init__(message)
        self.frames = frames  # (frames, device times, stroke id) as _run collected them
        self.data = None


class ForceAbort(DeviceError):
    """The device stopped a stroke at its force limit: the pad pressed deeper than planned.

    The frames it sent up to and including the one over the limit are kept: ``data`` holds them where the command's
    result can be shortened (:class:`CarrierData` from :meth:`FingerDevice.run_carrier`, its program cut to those
    frames), else None, so a caller keeps what the stroke touched before it stopped."""

    def __init__(self, message: str, frames=None):
        super().__init__(message)
        self.frames = frames  # (frames, device times, stroke id): the contiguous frames received from the first
        self.data = None


class _Disconnected(Exception):
    pass


class StrokeData(NamedTuple):
    """One completed stroke.

    plan : StrokePlan
    frames : dict of (T, ...) arrays, keys of :data:`bayestouch.hardware.simulator.FRAME_KEYS`
    device_time : (T,) float, seconds (device clock)
    stroke_id : int
    """

    plan: StrokePlan
    frames: dict
    device_time: np.ndarray
    stroke_id: int


class ProbePlan(NamedTuple):
    """A guarded stroke (:class:`~bayestouch.hardware.protocol.ProbeStroke`).

    time : (T,) float, seconds
    start : (T, 3) float, metres
        Approach start points (outside the believed surface).
    normal : (T, 3) float
        Unit believed outward normals; the pad approaches along −normal.
    depth : float, metres
        Press beyond the touch (:func:`depth_for_force` of the planned force).
    hold_currents : (3,) float, amperes
    travel : float, metres
        Longest approach from each start.
    threshold : float, N
        Contact force that counts as the touch.
    """

    time: np.ndarray
    start: np.ndarray
    normal: np.ndarray
    depth: float
    hold_currents: np.ndarray
    travel: float
    threshold: float

    def stroke_plan(self) -> StrokePlan:
        """The :class:`StrokePlan` the safety check sees: the midpoints of the approach lines (for a planned
        stroke, the believed surface, where the touch is expected; their speed is the following's tangential
        speed), the depth and the currents."""
        mid = np.asarray(self.start, float) - 0.5 * float(self.travel) * np.asarray(self.normal, float)
        return StrokePlan(self.time, mid, self.normal, self.depth, self.hold_currents)


class ProbeData(NamedTuple):
    """One completed guarded stroke: :class:`StrokeData`'s fields plus, per waypoint, ``probe (T,)`` (keys of
    :data:`~bayestouch.hardware.protocol.PROBE_STATUS`), ``travel (T,)`` m and ``position (T, 3)`` m (the
    device's pose estimate of the pad centre at the threshold crossing, world frame)."""

    plan: ProbePlan
    frames: dict
    device_time: np.ndarray
    stroke_id: int
    probe: np.ndarray
    travel: np.ndarray
    position: np.ndarray


class CarrierData(NamedTuple):
    """One completed carrier stroke (protocol revision 1.3).

    plan : CarrierProgram
        What was commanded (:class:`~bayestouch.physics.pose.CarrierProgram`).
    frames : dict of (T, ...) arrays, keys of :data:`bayestouch.hardware.frame_models.FRAME_KEYS`
    device_time : (T,) float, seconds (device clock)
    stroke_id : int
    """

    plan: object
    frames: dict
    device_time: np.ndarray
    stroke_id: int

    def pad_centre(self) -> np.ndarray:
        """Where the host believes the pad centre was, (T, 3) metres, world frame: the commanded base pose × the
        tip position the finger sensed (the frames' ``finger_tip_position``, base frame). Its error is the pose
        error of the finger's sensing, not of the host's bending constants."""
        R = np.asarray(self.plan.base_rotation, float).reshape(3, 3)
        return np.asarray(self.plan.base_position, float) + np.asarray(self.frames["finger_tip_position"]) @ R.T


def _skin_and_radius(skin=None, tip_radius=None):
    skin = skin if skin is not None else sk.load_skin(MODELS / "skin.toml")
    if tip_radius is None:
        tip_radius = float(bending.load_rod(MODELS / "finger.toml").radius) + float(skin.h)
    return skin, float(tip_radius)


def winkler_depth(force, skin=None, tip_radius: float | None = None) -> np.ndarray:
    """Indentation (m) of the fingertip in a flat surface at normal ``force`` (N): the inverse of the thin-layer
    Winkler model :func:`bayestouch.physics.skin.winkler_sphere`, F = π M R δ² / h, so δ = √(F h / (π M R))."""
    skin, R = _skin_and_radius(skin, tip_radius)
    M = float(sk.bonded_layer_modulus(skin.E, skin.nu))
    return np.sqrt(np.maximum(np.asarray(force, float), 0.0) * float(skin.h) / (np.pi * M * R))


def winkler_force(depth, skin=None, tip_radius: float | None = None) -> np.ndarray:
    """Normal force (N) of the fingertip pressed ``depth`` (m) into a flat surface, the thin-layer Winkler model
    F = π M R δ² / h (:func:`winkler_depth`'s inverse); 0 where the pad is clear (depth ≤ 0)."""
    skin, R = _skin_and_radius(skin, tip_radius)
    M = float(sk.bonded_layer_modulus(skin.E, skin.nu))
    d = np.maximum(np.asarray(depth, float), 0.0)
    return np.pi * M * R * d * d / float(skin.h)


def pad_radius(skin=None) -> float:
    """Radius (m) of the pad's outer (skin) surface as ``models/`` state it: the rod's radius plus the skin's
    thickness."""
    return _skin_and_radius(skin)[1]


def depth_for_force(force: float, skin=None, tip_radius: float | None = None) -> float:
    """Pressing depth (m) for a planned normal ``force`` (N): the depth at which the safety check's conservative
    force estimate (:func:`~bayestouch.hardware.safety.predicted_force`: ``FORCE_FACTOR`` × Winkler) equals
    ``force``; the actual force is then at most the planned one (the forward model's force on the egg is 0.71 of
    that bound)."""
    return float(winkler_depth(float(force) / FORCE_FACTOR, skin, tip_radius))


def read_journal(path) -> list:
    """Messages of a journal file (the packets :class:`FingerDevice` wrote as they arrived), in order."""
    dec = pr.Decoder()
    return [m for _, m in dec.feed(Path(path).read_bytes())]


class JournalStrokes(NamedTuple):
    """What a journal holds (:func:`strokes_from_journal`).

    info : HelloReply or None
        The device's (last) handshake; None when the journal has none.
    strokes : list of StrokeData
        The complete plain strokes, in the order they were sent.
    incomplete : list of str
        One phrase per stroke sent but not complete in the journal (``"stroke id 7: 40 of 101 frames"``), and per
        stroke whose frames are there but whose command is not (a damaged packet).
    skipped : int
        Guarded strokes (protocol revision 1.1) and their frames, carrier strokes (1.3) and their frames, and frames
        with impossible contents (:func:`frame_problem`), left out.
    damaged : int
        Packets of the journal that failed their check (CRC, framing) and were dropped.
    """

    info: pr.HelloReply | None
    strokes: list
    incomplete: list
    skipped: int
    damaged: int = 0


def strokes_from_journal(path) -> JournalStrokes:
    """The complete strokes of a journal file: the plain stroke commands the client sent (each is journaled before
    it is sent) with every one of their frames, as :class:`FingerDevice` received them. A killed ``device run``
    (SIGKILL, a power cut) leaves them there; :func:`build_recording` of the result is the recording it would have
    written for them.

    A stroke is complete when all of its T frames (T = the command's waypoints) are there with possible contents
    (:func:`frame_problem` against the handshake). An incomplete stroke followed at once by a command of the same
    plan is one the client ran again under a new id (it counts once); any other incomplete stroke — cut short,
    aborted, the last one of a killed run, or one whose command packet is damaged — is listed in ``incomplete``. A
    journal does not record how many strokes were planned: one cut between two strokes looks finished.

    Parameters
    ----------
    path : path
        The journal (``OUT.journal`` of ``bayestouch device run``).

    Returns
    -------
    JournalStrokes

    Raises
    ------
    BadInput
        No such file, or no packet of the finger protocol in it.
    """
    check_path(path, "journal")
    if problem := file_problem(path):
        raise BadInput(f"journal {path}: {problem}; expected the OUT.journal file of bayestouch device run")
    dec = pr.Decoder()
    messages = [m for _, m in dec.feed(Path(path).read_bytes())]
    if not messages:
        raise BadInput(
            f"journal {path}: no packet of the finger protocol in it; expected the OUT.journal file of bayestouch "
            "device run"
        )
    info = None
    commands: dict[int, pr.StrokeCommand] = {}
    frames: dict[int, dict[int, pr.Frame]] = {}
    orphans: dict[int, set] = {}  # frames of a stroke whose command packet is not in the journal
    carriers: set[int] = set()  # carrier strokes (revision 1.3), left out with their frames
    skipped = 0
    for m in messages:
        if isinstance(m, pr.HelloReply):
            info = m
        elif isinstance(m, pr.StrokeCommand):
            carriers.discard(int(m.stroke_id))
            commands.pop(int(m.stroke_id), None)  # a stroke id used again is the later stroke, in its place
            commands[int(m.stroke_id)] = m
            frames[int(m.stroke_id)] = {}
        elif isinstance(m, pr.ProbeStroke | pr.ProbeFrame):
            skipped += 1
        elif isinstance(m, pr.CarrierStroke):  # its frames are plain FRAMEs: set aside by their stroke id
            carriers.add(int(m.stroke_id))
            frames.pop(int(m.stroke_id), None)
            commands.pop(int(m.stroke_id), None)
            skipped += 1
        elif isinstance(m, pr.Frame) and int(m.stroke_id) in carriers:
            skipped += 1
        elif isinstance(m, pr.Frame):
            if frame_problem(m, info) is not None:
                skipped += 1
            elif int(m.stroke_id) in frames:
                frames[int(m.stroke_id)].setdefault(int(m.index), m)
            else:
                orphans.setdefault(int(m.stroke_id), set()).add(int(m.index))
    if info is None and commands:
        raise BadInput(f"journal {path}: no handshake (HELLO_REPLY) in it, so its taxel layout is unknown")

    def same_plan(cmd) -> tuple:
        arrays = (np.asarray(getattr(cmd, k), float).tobytes() for k in ("time", "contact", "normal"))
        return (float(cmd.depth), *arrays)

    order = list(commands)
    strokes, incomplete = [], []
    for i, sid in enumerate(order):
        cmd = commands[sid]
        T = len(cmd.time)
        got = frames[sid]
        if any(j not in got for j in range(T)):
            redone = i + 1 < len(order) and same_plan(commands[order[i + 1]]) == same_plan(cmd)
            if not redone:  # a lost stroke the client ran again at once under a new id is not missing
                incomplete.append(f"stroke id {sid}: {sum(j in got for j in range(T))} of {T} frames")
            continue
        ordered = [got[i] for i in range(T)]
        arrays, dev_t = _frames_to_arrays(ordered)
        plan = StrokePlan(
            np.asarray(cmd.time, float),
            np.asarray(cmd.contact, float).reshape(T, 3),
            np.asarray(cmd.normal, float).reshape(T, 3),
            float(cmd.depth),
            np.asarray(cmd.hold_currents, float),
        )
        strokes.append(StrokeData(plan, arrays, dev_t, sid))
    incomplete += [f"stroke id {sid}: {len(idx)} frame(s), its command damaged" for sid, idx in orphans.items()]
    return JournalStrokes(info, strokes, incomplete, skipped, int(dec.bad))


def _frames_to_arrays(frames: list[pr.Frame]) -> tuple[dict, np.ndarray]:
    f = {
        "taxel_current": np.stack([x.taxel_current for x in frames]).astype(float),
        "wire_current": np.stack([x.wire_current for x in frames]).astype(float),
        "wire_temperature": np.stack([x.wire_temperature for x in frames]).astype(float),
        "skin_temperature": np.array([x.skin_temperature for x in frames], float),
        "finger_tip_position": np.stack([x.tip_position for x in frames]).astype(float),
        "finger_curvature": np.stack([x.curvature for x in frames]).astype(float),
        "contact_force": np.array([x.contact_force for x in frames], float),
    }
    return f, np.array([x.time for x in frames], float)


def strokes_to_frames(strokes: list[StrokeData]) -> dict[str, np.ndarray]:
    """Concatenate strokes into the per-frame arrays of :func:`bayestouch.physics.virtual.record_strokes` (the same
    keys, less the simulation-only ``taxel_current_clean``, ``pressure`` and ``friction_force``)."""
    cols: dict[str, list] = {}
    t0 = 0.0
    for i, s in enumerate(strokes):
        t = np.asarray(s.plan.time, float)
        n = len(t)
        dt = float(np.median(np.diff(t))) if n > 1 else 0.02
        add = {
            "time": t0 + t,
            "stroke_index": np.full(n, i),
            "pressing_depth": np.full(n, float(s.plan.depth)),
            "contact_point": np.asarray(s.plan.contact, float),
            "contact_normal": np.asarray(s.plan.normal, float),
            **s.frames,
        }
        t0 += float(t[-1]) + dt
        for k, v in add.items():
            cols.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in cols.items()}


def finger_of(firmware: str) -> str | None:
    """The unit a device names in its HELLO_REPLY firmware string (``"...; finger=ID"``, PROTOCOL.md §4), or None."""
    m = re.search(r";\s*finger=(.+)$", str(firmware))
    return m.group(1).strip() or None if m else None


def build_recording(strokes: list[StrokeData], info: pr.HelloReply, attrs: dict | None = None):
    """The ``xarray.Dataset`` of :mod:`bayestouch.io.recording` (the schema of ``bayestouch simulate``); the finger the
    device names in its handshake is the recording's ``finger`` attribute."""
    uv = np.asarray(info.taxel_uv, float)
    named = finger_of(info.firmware)
    a = {
        "device_firmware": info.firmware,
        "protocol_version": info.protocol,
        **({"finger": named} if named else {}),
        **(attrs or {}),
    }
    return build_dataset(
        strokes_to_frames(strokes), uv[:, 0], uv[:, 1], np.asarray(info.reference), [s.plan.depth for s in strokes], a
    )


class FingerDevice:
    """Client of the finger over ``serial.serial_for_url``.

    Parameters
    ----------
    url : str
        A port path (``/dev/ttyUSB0``, ``/dev/pts/3``) or a pyserial URL (``loop://``, ``socket://host:port``).
    timeout : float, seconds
        Wait for one answer before a retry.
    retries : int
        Sends of one command before giving up.
    connect_timeout : float, seconds
        How long the handshake may take (a device may still be booting).
    stroke_timeout : float, seconds
        Longest silence of a running stroke (the device may compute before it streams).
    reconnects : int
        Attempts to reopen a lost port, with back-off from ``reconnect_wait`` seconds.
    redo : int
        How often a stroke the device lost is run again.
    journal : path or None
        File to which every received packet is appended as it arrives.
    limits : Limits
        The client's own limits; the tighter of these and the device's apply.
    handshake : bool
        Send HELLO on :meth:`open` (off: only for tests of what is written before any handshake).
    segment : int or None, bytes
        Segmented packets (protocol revision 1.2, PROTOCOL.md §9) for a link that loses bytes: None (default)
        switches to PARTs of :data:`AUTO_SEGMENT` bytes when whole packets do not get through (a handshake that
        fails with damaged packets arriving, or a stroke whose frames are still missing after ``retries`` rounds
        of RESEND); 0 never; a size ≥ :data:`~bayestouch.hardware.protocol.MIN_SEGMENT` from the handshake on.
    """

    def __init__(
        self,
        url: str,
        *,
        timeout: float = 0.3,
        retries: int = 8,
        connect_timeout: float = 60.0,
        stroke_timeout: float = 300.0,
        reconnects: int = 5,
        reconnect_wait: float = 0.1,
        redo: int = 2,
        journal=None,
        limits: Limits | None = None,
        handshake: bool = True,
        baudrate: int = 921600,
        segment: int | None = None,
    ):
        if url is None or (isinstance(url, str) and not url):
            raise BadInput("--port: expected a serial port path or a pyserial URL like loop://, got nothing")
        if not isinstance(url, str | os.PathLike):  # 5 was taken as the port "5"
            raise BadInput(f"--port: expected a serial port path or a pyserial URL like loop://, got {shown(url)}")
        if segment is not None and (
            isinstance(segment, bool)
            or not isinstance(segment, int | np.integer)
            or segment < 0
            or 0 < segment < pr.MIN_SEGMENT
            or segment > pr.MAX_PACKET
        ):
            raise BadInput(
                f"--segment: expected 0 (whole packets) or {pr.MIN_SEGMENT}–{pr.MAX_PACKET} bytes, got {segment!r}"
            )
        check_int(retries, "retries", 1, None, "an integer number of sends")
        check_int(reconnects, "reconnects", 0, None, "an integer number of attempts")
        check_int(redo, "redo", 0, None, "an integer number of reruns")
        check_int(baudrate, "baudrate", 1, None, "an integer number of bits per second")
        check_number(reconnect_wait, "reconnect_wait", 0, what="a number of seconds")
        check_bool(handshake, "handshake")
        limits = check_limits(limits)
        if journal is not None and journal != "":  # "" (as None): no journal
            check_path(journal, "journal")
            if os.path.isdir(journal):  # the first packet failed there, mid-handshake
                raise BadInput(f"journal {journal} is a folder; expected a file name for the journal")
        for name, value in (
            ("timeout", timeout),
            ("connect_timeout", connect_timeout),
            ("stroke_timeout", stroke_timeout),
        ):
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                # -1 failed later as "no answer to Hello after 184 tries", nan as a ValueError
                raise BadInput(f"--{name.replace('_', '-')}: expected a positive number of seconds, got {value!r}")
        self.segment = segment
        self._segment = 0  # the PART size in use (0: whole packets)
        self.url, self.timeout, self.retries = str(url), float(timeout), int(retries)
        self.connect_timeout, self.stroke_timeout = float(connect_timeout), float(stroke_timeout)
        self._hello_s = 0.0  # the longest handshake so far (s): a reconnect's handshake may take as long
        self.reconnects, self.reconnect_wait, self.redo = int(reconnects), float(reconnect_wait), int(redo)
        self.journal_path = Path(journal) if journal else None
        self.client_limits = limits
        self.handshake, self.baudrate = handshake, baudrate
        self.info: pr.HelloReply | None = None
        self._ser = None
        self._journal = None
        self._dec = pr.Decoder()
        self._seq = int(np.random.default_rng().integers(0, 1 << 16))
        self._sid = int(time.time()) & 0xFFFFFF
        self._inbox: list = []
        self._echoed: set[int] = set()  # sequence numbers of our own commands that came back
        self._replies: dict[int, object] = {}
        self.stats = {
            "retries": 0,
            "reconnects": 0,
            "resend_requests": 0,
            "redone_strokes": 0,
            "bad_packets": 0,
            "frames": 0,
            "duplicate_frames": 0,
            "bad_frames": 0,
            "segmented": 0,
        }

    # ------------------------------------------------------------ connection

    @property
    def limits(self) -> Limits:
        """The tighter of the client's and the device's limits."""
        c, i = self.client_limits, self.info
        if i is None:
            return c
        return c._replace(
            max_current=min(c.max_current, i.max_current),
            max_temperature=min(c.max_temperature, i.max_temperature),
            max_force=min(c.max_force, i.max_force),
            watchdog=min(c.watchdog, i.watchdog),
            max_waypoints=min(c.max_waypoints, i.max_waypoints),
        )

    def _open_port(self) -> None:
        try:
            self._ser = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.01, write_timeout=5.0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise DeviceError(
                f"cannot open the port {self.url} ({e}); expected a serial port path or a pyserial URL"
            ) from None
        self._dec = pr.Decoder()

    def open(self) -> FingerDevice:
        """Open the port and do the handshake (the journal is made when the first packet arrives: a port that
        cannot be opened or never answers leaves no file behind)."""
        self._open_port()
        if self.handshake:
            try:
                self.hello(self.connect_timeout)
            except BaseException:
                self.close()
                raise
        return self

    def close(self) -> None:
        """Close the port and the journal."""
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # closing a dead port
                pass
            self._ser = None
        if self._journal is not None:
            self._journal.close()
            self._journal = None

    def __enter__(self) -> FingerDevice:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def _reconnect(self) -> None:
        self.stats["reconnects"] += 1
        if self._ser is not None:
            try:
                self._ser.close()
            except (serial.SerialException, OSError):
                pass
            self._ser = None
        wait = self.reconnect_wait
        last = ""
        for _ in range(self.reconnects):
            time.sleep(wait)
            wait *= 2
            try:
                self._open_port()
                # as long as the first handshake took, twice over: on a lossy link its long reply comes in parts
                # after many tries (25 at 1 % byte faults), and a reconnect given 2 s never got it through
                self.hello(max(5 * self.timeout, 2.0, 2.0 * self._hello_s), reconnect=False)
                return
            except (DeviceError, _Disconnected) as e:
                last = str(e)
                if self._ser is not None:
                    self._ser.close()
                    self._ser = None
        raise DeviceError(
            f"lost the device at {self.url} and could not reconnect ({self.reconnects} attempts"
            f"{': ' + last if last else ''})"
        )

    # ------------------------------------------------------------ bytes

    def _write(self, raw: bytes) -> None:
        if self._ser is None:
            raise _Disconnected("port closed")
        try:
            self._ser.write(raw)
        except (serial.SerialException, OSError) as e:
            raise _Disconnected(str(e)) from None

    def _packet(self, msg) -> tuple[int, bytes]:
        """The next sequence number and ``msg``'s bytes under it (as parts in segment mode)."""
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFFFF
        return seq, pr.split(pr.encode(msg, seq), self._segment)

    def _send(self, msg) -> tuple[int, bytes]:
        seq, raw = self._packet(msg)
        self._write(raw)
        return seq, raw

    def _log(self, msg) -> None:
        if self.journal_path is None:
            return
        if self._journal is None:
            self.journal_path.parent.mkdir(parents=True, exist_ok=True)
            self._journal = open(self.journal_path, "ab")  # closed in close()
        self._journal.write(pr.encode(msg, 0))
        self._journal.flush()

    def _pump(self, timeout: float) -> None:
        """Read for up to ``timeout`` seconds (less once something arrived); sort what arrives."""
        if self._ser is None:
            raise _Disconnected("port closed")
        end = time.monotonic() + timeout
        got = False
        while True:
            try:
                n = self._ser.in_waiting
                data = self._ser.read(n or 1)
            except (serial.SerialException, OSError, TypeError) as e:
                raise _Disconnected(str(e)) from None
            if data:
                before = self._dec.bad
                for seq, m in self._dec.feed(data):
                    got = True
                    if isinstance(m, pr.Frame | pr.ProbeFrame | pr.StrokeDone):
                        self._inbox.append(m)
                    elif hasattr(m, "ack"):
                        self._replies[m.ack] = m
                    else:  # a command: the port echoes what is sent (loop://, a terminal), no finger answers
                        self._echoed.add(seq)
                self.stats["bad_packets"] += self._dec.bad - before
            try:
                idle = got and not self._ser.in_waiting
            except (serial.SerialException, OSError, TypeError) as e:
                raise _Disconnected(str(e)) from None
            if idle or time.monotonic() >= end:
                return

    def _command(self, msg, *, reconnect: bool = True, timeout: float | None = None, tries: int | None = None):
        """Send ``msg`` until its answer (ACK, NAK, HELLO reply or STATUS) arrives; returns the answer.

        A long command that gets no answer as a whole packet is sent again as PARTs when ``segment`` is None and
        the device agrees to segment mode (PROTOCOL.md §9)."""
        seq, raw = self._send_safe(msg, reconnect)
        tries = tries or self.retries
        whole = raw.count(0) == 1
        rep = self._await(seq, raw, tries if whole else 4 * tries, reconnect, timeout)
        if rep is None and whole and self.segment is None and not self._segment and len(raw) > 2 * AUTO_SEGMENT:
            if self._use_segments(AUTO_SEGMENT, reconnect):
                raw = pr.split(raw, self._segment)
                self._write_safe(raw, reconnect)
                rep = self._await(seq, raw, 4 * tries, reconnect, timeout)
        if rep is None:
            raise DeviceError(f"{self.url}: no answer to {type(msg).__name__} after {tries} tries")
        return rep

    def _await(self, seq: int, raw: bytes, tries: int, reconnect: bool, timeout: float | None):
        """Wait for the answer to ``seq``, writing ``raw`` (already sent once) again before each further try;
        None when ``tries`` waits pass without it. Parts sent again complete more of the packet on the device:
        each try of a command sent as parts counts."""
        for attempt in range(tries):
            if attempt:
                self.stats["retries"] += 1
                self._write_safe(raw, reconnect)
            end = time.monotonic() + (timeout or self.timeout)
            while time.monotonic() < end:
                try:
                    self._pump(min(0.05, max(end - time.monotonic(), 0.0)))
                except _Disconnected:
                    if not reconnect:
                        raise
                    self._reconnect()
                    break
                if seq in self._replies:
                    return self._replies.pop(seq)
            if seq in self._echoed:
                raise DeviceError(
                    f"{self.url}: the port sends back every packet written to it (a loopback such as loop://, or a "
                    "terminal) and nothing answers; expected the port of a finger"
                )
        return None

    def _write_safe(self, raw: bytes, reconnect: bool) -> None:
        try:
            self._write(raw)
        except _Disconnected:
            if not reconnect:
                raise
            self._reconnect()
            self._write(raw)

    def _send_safe(self, msg, reconnect: bool):
        seq, raw = self._packet(msg)
        self._write_safe(raw, reconnect)
        return seq, raw

    # ------------------------------------------------------------ commands

    def hello(self, timeout: float | None = None, *, reconnect: bool = True) -> pr.HelloReply:
        """Handshake: firmware, layout, rate and limits (stored as ``info``)."""
        timeout = self.connect_timeout if timeout is None else timeout
        tries = max(1, int(np.ceil(timeout / max(self.timeout, 0.05))))
        began = time.perf_counter()
        size = self._segment or self.segment
        if size:  # SEGMENT just before HELLO keeps the device in segment mode (PROTOCOL.md §9)
            self._segment = 0
            self._use_segments(size, reconnect)
        if self.segment is None and not self._segment and tries > 2 * self.retries:
            try:
                rep = self._command(pr.Hello(), reconnect=reconnect, tries=self.retries)
            except DeviceError:  # a lossy link (the reply is long), or a device still booting
                self._use_segments(AUTO_SEGMENT, reconnect)
                rep = self._command(pr.Hello(), reconnect=reconnect, tries=tries - 2 * self.retries)
        else:
            rep = self._command(pr.Hello(), reconnect=reconnect, tries=tries)
        if not isinstance(rep, pr.HelloReply):
            raise DeviceError(f"{self.url}: handshake answered with {type(rep).__name__}")
        if rep.protocol != pr.PROTOCOL_VERSION:
            raise DeviceError(f"{self.url}: device speaks protocol {rep.protocol}, this client {pr.PROTOCOL_VERSION}")
        self.info = rep
        self._hello_s = max(self._hello_s, time.perf_counter() - began)
        self._log(rep)
        return rep

    def _use_segments(self, size: int, reconnect: bool = True) -> bool:
        """Ask the device for PARTs of ``size`` bytes (SEGMENT) and send PARTs too once it agrees; returns whether
        it did (a revision < 1.2 device does not answer; a NAK leaves whole packets)."""
        try:
            rep = self._command(pr.Segment(size), reconnect=reconnect)
        except DeviceError:
            if self.segment:
                raise DeviceError(f"{self.url}: the device does not answer SEGMENT (protocol revision < 1.2)") from None
            return False
        if isinstance(rep, pr.Ack):
            self._segment = size
            self.stats["segmented"] = size
            return True
        if self.segment:
            raise DeviceError(f"{self.url}: the device refused segment size {size}: {getattr(rep, 'reason', rep)}")
        return False

    def status(self) -> pr.Status:
        """The device's :class:`~bayestouch.hardware.protocol.Status`."""
        # on a link lossy enough for segment mode a STATUS (sent whole, fresh for each request) needs more tries
        rep = self._command(pr.StatusRequest(), tries=self.retries * (4 if self._segment else 1))
        if not isinstance(rep, pr.Status):
            raise DeviceError(f"{self.url}: status request answered with {type(rep).__name__}")
        return rep

    def heartbeat(self) -> None:
        """One acknowledged heartbeat."""
        self._command(pr.Heartbeat())

    def abort(self) -> None:
        """Stop any stroke and switch the heaters off."""
        self._command(pr.Abort())

    def check(self, plan: StrokePlan) -> PlanCheck:
        """:func:`~bayestouch.hardware.safety.check_plan` with this connection's limits (raises UnsafePlan)."""
        return check_plan(plan, self.limits)

    def run_stroke(self, plan: StrokePlan) -> StrokeData:
        """Run one stroke and return its frames, complete and in order.

        Raises
        ------
        UnsafePlan
            Before anything is sent, if the plan breaks a limit (or the device refuses it).
        HeaterFault
            The heaters stayed on after the stroke (the stroke's data are journaled first, and are the exception's
            ``data``).
        DeviceError
            The device aborted for over-force or fault, or stayed silent past the retries.
        """
        self.check(plan)

        def command(sid):
            return pr.StrokeCommand(
                sid,
                float(plan.depth),
                float(self.limits.max_force),
                np.asarray(plan.hold_currents, float),
                np.asarray(plan.time, float),
                np.asarray(plan.contact, float),
                np.asarray(plan.normal, float),
            )

        def result(got, dev_t, sid):
            return StrokeData(plan, _frames_to_arrays(got)[0], dev_t, sid)

        return self._run_to(command, len(plan.time), result)

    def run_probe(self, plan: ProbePlan) -> ProbeData:
        """Run one guarded stroke (protocol revision 1.1) and return its frames and what each approach found.

        Raises
        ------
        UnsafePlan
            Before anything is sent, if ``plan.stroke_plan()`` breaks a limit, the threshold is not in
            (0, max_force) N or the travel not in (0, 0.1] m (or the device refuses it).
        HeaterFault
            As :meth:`run_stroke` (the complete guarded stroke is the exception's ``data``).
        DeviceError
            As :meth:`run_stroke`; also when the device does not know guarded strokes (a revision 1.0 device
            drops the unknown command: no answer).
        """
        self.check(plan.stroke_plan())
        if not (0 < float(plan.threshold) < self.limits.max_force):
            raise UnsafePlan(
                f"probe plan: threshold must be in (0, {self.limits.max_force:g}) N, got {float(plan.threshold):g}"
            )
        if not (0 < float(plan.travel) <= 0.1):
            raise UnsafePlan(f"probe plan: travel must be in (0, 0.1] m, got {float(plan.travel):g}")

        def command(sid):
            return pr.ProbeStroke(
                sid,
                float(plan.depth),
                float(self.limits.max_force),
                np.asarray(plan.hold_currents, float),
                np.asarray(plan.time, float),
                np.asarray(plan.start, float),
                np.asarray(plan.normal, float),
                float(plan.travel),
                float(plan.threshold),
            )

        def probe_data(got, dev_t, sid) -> ProbeData:
            if not all(isinstance(f, pr.ProbeFrame) for f in got):
                raise DeviceError(f"{self.url}: guarded stroke {sid} answered with plain frames")
            return ProbeData(
                plan,
                _frames_to_arrays(got)[0],
                dev_t,
                sid,
                np.array([f.probe for f in got], int),
                np.array([f.travel for f in got], float),
                np.stack([np.asarray(f.position, float).reshape(3) for f in got]),
            )

        unknown = (pr.ProbeStroke, "guarded strokes (protocol revision 1.1)")
        return self._run_to(command, len(plan.time), probe_data, unknown=unknown)

    def run_carrier(self, program) -> CarrierData:
        """Run one carrier stroke (protocol revision 1.3): the finger base along ``program.base_position`` while the
        wires follow ``program.currents``; the pad touches wherever the bent rod puts it
        (:func:`bayestouch.physics.pose.carrier_program` makes a program for a desired pad path).

        Parameters
        ----------
        program : CarrierProgram
            ``time (T,)`` s, evenly spaced; ``base_position (T, 3)`` m; ``base_rotation (3, 3)``;
            ``currents (T, 3)`` A.

        Returns
        -------
        CarrierData

        Raises
        ------
        UnsafePlan
            Before anything is sent, if the program breaks a limit or its frame times are not evenly spaced
            (:func:`~bayestouch.hardware.safety.check_carrier`), or the device refuses it.
        HeaterFault
            As :meth:`run_stroke` (the complete stroke is the exception's ``data``).
        DeviceError
            As :meth:`run_stroke`; also when the device does not know carrier strokes (a revision < 1.3 device
            drops the unknown command: no answer).
        """
        check_carrier(program, self.limits)

        def command(sid):
            return pr.CarrierStroke(
                sid,
                float(self.limits.max_force),
                np.asarray(program.time, float),
                np.asarray(program.base_position, float),
                np.asarray(program.base_rotation, float).reshape(3, 3),
                np.asarray(program.currents, float),
            )

        def result(got, dev_t, sid):
            k = len(got)  # all frames, or those up to a force abort
            cut = program._replace(
                time=np.asarray(program.time)[:k],
                base_position=np.asarray(program.base_position)[:k],
                currents=np.asarray(program.currents)[:k],
            )
            return CarrierData(cut, _frames_to_arrays(got)[0], dev_t, sid)

        unknown = (pr.CarrierStroke, "carrier strokes (protocol revision 1.3)")
        return self._run_to(command, len(program.time), result, unknown=unknown, partial=True)

    def _run_to(self, command, T: int, result, unknown: tuple[type, str] | None = None, partial: bool = False):
        """:meth:`_run`, its frames made into ``result(frames, device_time, stroke_id)``. A stroke complete but for
        heaters left on goes with the :class:`HeaterFault` as its ``data``; with ``partial`` (``result`` takes fewer
        frames than T) a stroke stopped at the force limit goes with the :class:`ForceAbort`; ``unknown`` (the
        command's message type, what to call it) names a command the device never answers (a device of an earlier
        revision drops the type)."""
        try:
            got, dev_t, sid = self._run(command, T)
        except HeaterFault as e:  # the stroke is complete: it goes with the fault
            e.data = result(*e.frames)
            raise
        except ForceAbort as e:
            if partial and e.frames is not None and len(e.frames[0]):
                e.data = result(*e.frames)
            raise
        except DeviceError as e:
            if unknown is not None and f"no answer to {unknown[0].__name__}" in str(e):
                fw = self.info.firmware if self.info else "?"
                raise DeviceError(f"{self.url}: the device ({fw}) does not answer {unknown[1]}") from None
            raise
        return result(got, dev_t, sid)

    def _run(self, command, T: int):
        """Send the stroke command ``command(stroke_id)`` and collect its T frames (redone with a new id when the
        device lost it); returns (frames, device times (T,) s, stroke id)."""
        if self._ser is None:
            raise DeviceError(f"{self.url}: not open")
        for attempt in range(self.redo + 1):
            if attempt:
                self.stats["redone_strokes"] += 1
            self._sid = (self._sid + 1) & 0xFFFFFFFF
            sid = self._sid
            cmd = command(sid)
            self._log(cmd)
            rep = self._command(cmd)
            if isinstance(rep, pr.Nak):
                if rep.code == 2:
                    raise UnsafePlan(f"the device refused the stroke plan: {rep.reason}")
                raise DeviceError(f"{self.url}: stroke refused ({pr.NAK_CODES.get(rep.code, rep.code)}): {rep.reason}")
            got = self._collect(sid, T)
            if got is None:
                continue
            dev_t = np.array([x.time for x in got], float)
            st = self._status_after(sid)
            if st.heater_on and st.state == 0:
                raise HeaterFault(
                    f"{self.url}: heaters still on after the stroke ended (wire currents "
                    f"{np.round(st.wire_current, 4).tolist()} A; the device's stroke id {sid}); switch the finger off",
                    frames=(got, dev_t, sid),
                )
            return got, dev_t, sid
        raise DeviceError(f"{self.url}: stroke lost {self.redo + 1} times (watchdog or disconnects)")

    def _status_after(self, sid: int, tries: int = 3) -> pr.Status:
        """The status after stroke ``sid`` delivered its frames (the heater check). A slow link may leave one
        request unanswered after its retries while the answer is still on its way: ``tries`` requests are made
        before the heaters' state is declared unknown (DeviceError)."""
        for _ in range(tries):
            try:
                return self.status()
            except DeviceError as e:
                last = e
        raise DeviceError(
            f"{self.url}: no status after stroke {sid} in {tries} requests; the heaters' state is unknown, "
            "switch the finger off"
        ) from last

    def _collect(self, sid: int, T: int) -> list[pr.Frame] | None:
        frames: dict[int, pr.Frame] = {}
        total = reason = None
        now = time.monotonic()
        hb_every = self.limits.watchdog / 4
        next_hb, last_activity, last_resend, silent_since = now, now, 0.0, now
        resends = 0
        while True:
            now = time.monotonic()
            try:
                if now >= next_hb:
                    self._send(pr.Heartbeat())
                    next_hb = now + hb_every
                self._pump(0.02)
            except _Disconnected:
                self._reconnect()
                st = self.status()
                if st.stroke_id != sid or (st.done not in (0, 255)):
                    return None
                if st.done == 0:
                    total, reason = st.frames, 0
                last_activity = time.monotonic()
                continue
            inbox, self._inbox = self._inbox, []
            for m in inbox:
                if m.stroke_id != sid:
                    continue
                if isinstance(m, pr.Frame | pr.ProbeFrame):
                    if m.index in frames:
                        self.stats["duplicate_frames"] += 1
                        continue
                    if m.index >= T:
                        continue
                    if frame_problem(m, self.info) is not None:
                        # well-formed packet, impossible contents: journaled, never recorded; requested again
                        self.stats["bad_frames"] += 1
                        self._log(m)
                        continue
                    frames[m.index] = m
                    self.stats["frames"] += 1
                    self._log(m)
                else:
                    total, reason = m.frames, m.reason
                    self._log(m)
                last_activity = silent_since = time.monotonic()
            self._replies.clear()
            now = time.monotonic()
            if total is not None:
                if reason == 3:
                    k = 0
                    while k < min(total, T) and k in frames:
                        k += 1
                    got = [frames[i] for i in range(k)]
                    raise ForceAbort(
                        f"{self.url}: stroke {sid} aborted by the device: contact force over "
                        f"{self.limits.max_force:g} N (the pad pressed deeper than planned: is the object where the "
                        "plan says, and does each normal point out of it?)",
                        frames=(got, np.array([x.time for x in got], float), sid),
                    )
                if reason != 0:
                    return None  # watchdog or abort: the stroke is incomplete, run it again
                missing = [i for i in range(min(total, T)) if i not in frames]
                if not missing:
                    return [frames[i] for i in range(T)] if total == T else None
                if now - last_activity > 0.5 * self.timeout and now - last_resend > 0.5 * self.timeout:
                    resends += 1
                    if resends == self.retries and self.segment is None and not self._segment:
                        try:  # whole frames do not get through: smaller packets (PROTOCOL.md §9)
                            self._use_segments(AUTO_SEGMENT)
                        except _Disconnected:
                            pass
                    if resends > 10 * self.retries:
                        raise DeviceError(f"{self.url}: {len(missing)} frames of stroke {sid} still missing")
                    for first, count in _runs(missing):
                        self.stats["resend_requests"] += 1
                        try:
                            self._send(pr.Resend(sid, first, count))
                        except _Disconnected:
                            break
                    last_resend = now
            elif now - last_activity > max(3 * self.timeout, 3 * hb_every):
                try:
                    st = self.status()
                except _Disconnected:
                    continue
                except DeviceError:
                    # a slow link (answers later than the retries wait): frames may still come; the stroke's own
                    # time-out below decides, not one unanswered status request
                    last_activity = time.monotonic()
                    continue
                if st.stroke_id != sid:
                    return None
                if st.done != 255:
                    total, reason = st.frames, st.done
                elif st.state == 3:
                    raise DeviceError(f"{self.url}: the device reports a fault while preparing stroke {sid}")
                last_activity = time.monotonic()
                if st.state == 2 and st.frames == len(frames):
                    silent_since = last_activity
            if time.monotonic() - silent_since > self.stroke_timeout:
                raise DeviceError(f"{self.url}: stroke {sid}: no frames for {self.stroke_timeout:g} s")

    def record_strokes(
        self, strokes, *, hold_currents=(0.15, 0.05, 0.05), progress: bool = False
    ) -> dict[str, np.ndarray]:
        """Run ``strokes`` (:class:`~bayestouch.scene.strokes.Stroke`) on the device; the per-frame arrays of
        :func:`bayestouch.physics.virtual.record_strokes` (so the exploration loop can drive the device instead)."""
        return strokes_to_frames(self.run_strokes([plan_from_stroke(s, hold_currents) for s in strokes], progress))

    def run_strokes(self, plans, progress: bool = False) -> list[StrokeData]:
        """Check every plan first (nothing is sent if any is unsafe), then run them in order."""
        for p in plans:
            self.check(p)
        return [self.run_stroke(p) for p in tqdm(plans, desc="strokes", unit="stroke", disable=not progress)]


_FRAME_RANGES = {
    "taxel_current": PHYSICAL_RANGES["taxel_current"],
    "wire_current": PHYSICAL_RANGES["wire_current"],
    "wire_temperature": PHYSICAL_RANGES["wire_temperature"],
    "skin_temperature": PHYSICAL_RANGES["skin_temperature"],
    "tip_position": PHYSICAL_RANGES["finger_tip_position"],
    "contact_force": PHYSICAL_RANGES["contact_force"],
    "curvature": (-1e4, 1e4),  # 1/m: a bend radius under 0.1 mm is no rod's
}


def frame_problem(frame, info=None) -> str | None:
    """What is impossible in a decoded frame (None when nothing): taxel count other than the handshake's
    rows × cols (``info``, a HELLO_REPLY), a non-finite value, a value outside the physical ranges of a recording
    (:data:`bayestouch.io.recording.PHYSICAL_RANGES`) or a non-zero taxel current below
    :data:`~bayestouch.io.recording.CURRENT_FLOOR_A`. A frame with such contents passed the packet's CRC, so it is
    the device's data that is wrong; the client rejects it rather than record it."""
    if info is not None and np.size(frame.taxel_current) != info.rows * info.cols:
        return f"{np.size(frame.taxel_current)} taxel currents, the handshake says {info.rows} × {info.cols}"
    for name, (lo, hi) in _FRAME_RANGES.items():
        v = np.asarray(getattr(frame, name), dtype=float)
        if not np.all(np.isfinite(v)):
            return f"{name}: non-finite value"
        if np.any((v < lo) | (v > hi)):
            return f"{name}: outside [{lo:g}, {hi:g}]"
    i = np.abs(np.asarray(frame.taxel_current, dtype=float))
    if np.any((i > 0) & (i < CURRENT_FLOOR_A)):
        return f"taxel_current: non-zero below {CURRENT_FLOOR_A:g} A"
    if not np.isfinite(frame.time):
        return "time: non-finite"
    return None


def _runs(idx: list[int]) -> list[tuple[int, int]]:
    out = []
    start = prev = idx[0]
    for i in idx[1:]:
        if i != prev + 1:
            out.append((start, prev - start + 1))
            start = i
        prev = i
    out.append((start, prev - start + 1))
    return out
