"""The virtual finger: a device on a pseudo-terminal that answers the wire protocol with a frame model.

:class:`VirtualDevice` serves the protocol of :mod:`bayestouch.hardware.protocol` on a pty from a thread, checks
each plan with :func:`~bayestouch.hardware.safety.check_plan`, and streams the frames of its frame model
(:mod:`bayestouch.hardware.frame_models`) in real time or faster, with optional injected faults (:class:`Faults`).
Frames are :data:`~bayestouch.hardware.frame_models.FRAME_KEYS` arrays (T, ...), SI units. Device-side safety and
the faults: ``docs/hardware.md``.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.errors import BadInput, check_path, shown
from bayestouch.hardware import protocol as pr
from bayestouch.hardware.frame_models import FRAME_KEYS, PROBE_KEYS
from bayestouch.hardware.safety import (
    Limits,
    StrokePlan,
    UnsafePlan,
    check_carrier,
    check_limits,
    check_plan,
)

__all__ = ["Faults", "VirtualDevice", "command_refusal"]


class Faults(NamedTuple):
    """Faults to inject.

    Attributes
    ----------
    drop : float
        Probability that a byte is dropped.
    corrupt : float
        Probability that a byte is replaced by a random different byte.
    delay : float, seconds
        Length of a stall of the outgoing stream ...
    delay_prob : float
        ... which starts before a packet with this probability.
    disconnect_after : int or None
        Close the pty after this many frames have been sent (once) and open a new one.
    stuck_heater : bool
        The wires stay powered at the last hold currents after a stroke ends or is aborted.
    inbound : bool
        Drop and corrupt the client's bytes too (by default only the device's outgoing stream).
    seed : int
        Seed of the fault draws.
    """

    drop: float = 0.0
    corrupt: float = 0.0
    delay: float = 0.0
    delay_prob: float = 0.05
    disconnect_after: int | None = None
    stuck_heater: bool = False
    inbound: bool = False
    seed: int = 0


def check_faults(faults: Faults) -> Faults:
    """``faults`` when every field has its stated form, else :class:`BadInput` naming the field (probabilities in
    [0, 1], a delay of ≥ 0 s, a count ≥ 1)."""
    for name in ("drop", "corrupt", "delay_prob"):
        v = getattr(faults, name)
        if not (isinstance(v, int | float) and 0.0 <= v <= 1.0):
            raise BadInput(f"Faults.{name}: expected a probability in [0, 1], got {v!r}")
    if not (isinstance(faults.delay, int | float) and np.isfinite(faults.delay) and faults.delay >= 0):
        raise BadInput(f"Faults.delay: expected a stall of ≥ 0 seconds, got {faults.delay!r}")
    n = faults.disconnect_after
    if n is not None and (isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1):
        raise BadInput(f"Faults.disconnect_after: expected a number of frames ≥ 1 or None, got {n!r}")
    return faults


#: what a frame model answers to besides being called (the handshake reports them)
MODEL_ATTRIBUTES = ("rows", "cols", "taxel_uv", "reference")


def check_model(model) -> None:
    """Refuse (one line naming ``model``) a frame model that is not callable or lacks :data:`MODEL_ATTRIBUTES`
    (:class:`VirtualDevice`'s ``model``; None: set later)."""
    if model is None:
        return
    missing = [a for a in MODEL_ATTRIBUTES if not hasattr(model, a)]
    if not callable(model) or missing:
        raise BadInput(
            "model: expected a frame model (bayestouch.hardware.frame_models: a callable (plan, index) -> frames "
            f"with {', '.join(MODEL_ATTRIBUTES)}) or None, got {type(model).__name__} {shown(model, 40)}"
        )


class VirtualDevice:
    """The virtual finger on a pseudo-terminal.

    Parameters
    ----------
    model : callable ``(StrokePlan, stroke_index) -> dict`` of :data:`FRAME_KEYS` arrays, with attributes
        ``rows``, ``cols``, ``taxel_uv (N, 2)`` m and ``reference (N,)``. May be set after :meth:`open`.
    limits : Limits or None
        The device's safety limits (default :class:`Limits`) (reported in the handshake, enforced).
    speed : float
        Real-time factor of the frame stream (1: real time; 0: as fast as possible).
    faults : Faults
    link : path or None
        A symbolic link kept pointing at the current pty (it survives injected disconnects).
    rate : float, Hz
        Nominal frame rate reported in the handshake.

    Use as a context manager, or call :meth:`open`, :meth:`start` and :meth:`close`. ``port`` is the slave's
    path; ``stats`` counts packets, frames and faults.
    """

    firmware = "bayestouch-virtual-1"

    def __init__(
        self,
        model=None,
        *,
        limits: Limits | None = None,
        speed: float = 1.0,
        faults: Faults | None = None,
        link: str | os.PathLike | None = None,
        rate: float = 50.0,
    ):
        check_model(model)
        limits = check_limits(limits)
        if link is not None:  # the path itself (a folder, a file of the user's) is checked by open()
            check_path(link, "link")
        if faults is not None and not isinstance(faults, Faults):
            raise BadInput(f"faults: expected a Faults or None, got {shown(faults)}")
        faults = check_faults(faults or Faults())
        if not (isinstance(speed, int | float) and np.isfinite(speed) and speed >= 0):
            raise BadInput(f"speed: expected a real-time factor ≥ 0 (0: as fast as possible), got {speed!r}")
        if not (isinstance(rate, int | float) and np.isfinite(rate) and 1 <= rate <= 2000):
            raise BadInput(f"rate: expected a frame rate in [1, 2000] Hz, got {rate!r}")
        self.model, self.limits, self.speed, self.faults, self.rate = (
            model,
            limits,
            float(speed),
            faults,
            rate,
        )
        self.link = Path(link) if link else None
        self._link_target: str | None = None  # where the link this device made points
        self.port: str | None = None
        self._master = self._slave = None
        self._rng = np.random.default_rng(faults.seed)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._workers: list[threading.Thread] = []
        self._dec = pr.Decoder()
        self._out = bytearray()
        self._stall_until = 0.0
        self._seq = 0
        self._segment = 0  # revision 1.2: PART size asked for by the host (0: whole packets)
        self._after_segment = False  # the last command was SEGMENT (a HELLO then keeps segment mode)
        self._frame_seq = np.zeros(0, np.int64)
        self._last_packet = b""
        self._last_reply = b""
        self._t0 = time.monotonic()
        self._last_rx = self._t0
        self.stats = {
            "rx_packets": 0,
            "rx_bad": 0,
            "tx_packets": 0,
            "tx_frames": 0,
            "dropped_bytes": 0,
            "corrupted_bytes": 0,
            "stalls": 0,
            "disconnects": 0,
            "watchdog_trips": 0,
            "resent_frames": 0,
            "overflow_bytes": 0,
        }
        self._disconnected_once = False
        # stroke state
        self.state = 0
        self.stroke_id = 0
        self._cmd: pr.StrokeCommand | None = None
        self._frames: dict | None = None
        self._n_sent = 0
        self._done = 255
        self._started = 0.0
        self._index = 0
        self.heater_on = False
        self.watchdog_tripped = False
        self._wire_current = np.zeros(3)
        self._wire_temperature = np.full(3, 293.15)
        self._result: tuple | None = None
        self._stamps = np.zeros(0)
        self._lock = threading.Lock()

    # ------------------------------------------------------------ pty

    def open(self) -> str:
        """Open the pseudo-terminal; returns the slave's path (what a client opens).

        With ``link``, the link is made (or moved to the new pty). A path that holds anything but a symbolic link
        this device made, a dangling one or one to a pty is refused with :class:`~bayestouch.errors.BadInput`
        (``"link PATH: ..."``) before the pty is opened: a file or folder of the user's is never replaced, and
        nothing else in the link's folder is touched."""
        if self.link is not None:
            self._check_link()
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.port = os.ttyname(slave)
        if self.link is not None:
            try:
                self._place_link(self.port)
            except BaseException:
                self._close_pty()
                raise
        return self.port

    def _link_replaceable(self) -> bool:
        """Whether ``link`` may be pointed elsewhere: it is the symbolic link this device made, a dangling one, or
        one to a pty (another virtual finger's)."""
        link = self.link
        if not link.is_symlink():
            return False
        target = os.readlink(link)
        if target == self._link_target or not link.exists():
            return True
        real = os.path.realpath(link)
        return real.startswith("/dev/pts/") or real == "/dev/ptmx"

    def _check_link(self) -> None:
        link = self.link
        parent = link.parent
        if not parent.is_dir():
            raise BadInput(f"link {link}: folder {parent} does not exist; expected a path in an existing folder")
        if link.is_symlink():
            if not self._link_replaceable():
                raise BadInput(
                    f"link {link} is a symbolic link to {os.readlink(link)}, not to a pty; expected a new path, a "
                    "dangling link or a link to a pty (it is not replaced)"
                )
        elif link.is_dir():
            raise BadInput(f"link {link} is a folder; expected a new path for the symbolic link (it is not replaced)")
        elif link.exists():
            raise BadInput(
                f"link {link} exists and is not a symbolic link; expected a new path (a file is never replaced)"
            )

    def _place_link(self, port: str) -> None:
        """Point ``link`` at ``port``: a new link made in place, an existing one replaced atomically through a
        uniquely named temporary link in the same folder (never a name another file could have)."""
        link = self.link
        try:
            if not link.is_symlink():
                os.symlink(port, link)  # fails, replacing nothing, if something appeared there meanwhile
            else:
                # 48 random bits and the process id: a name no other file has (os.symlink refuses one that exists)
                tmp = link.with_name(f".{link.name}.{os.getpid()}.{os.urandom(6).hex()}.tmp")
                os.symlink(port, tmp)
                try:
                    if not self._link_replaceable():  # checked again: it could have changed since
                        raise FileExistsError(f"{link} is no longer a link to a pty")
                    os.replace(tmp, link)
                except BaseException:
                    tmp.unlink(missing_ok=True)
                    raise
        except OSError as e:
            raise BadInput(
                f"link {link}: cannot make a symbolic link there ({e.strerror or e}); expected a new path in a "
                "writable folder"
            ) from None
        self._link_target = port

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def start(self) -> VirtualDevice:
        """Start serving (opens the pty first if needed); a device already serving is left as it is (a second
        thread would read the pty after the first one's close)."""
        if self.model is None:
            raise ValueError("VirtualDevice.start: no frame model set")
        check_model(self.model)  # one set after construction
        if self._thread is not None and self._thread.is_alive():
            return self
        if self._master is None:
            self.open()
        self._last_rx = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="virtual-finger", daemon=True)
        self._thread.start()
        return self

    def close(self, timeout: float = 60.0) -> None:
        """Stop serving, wait for the threads and close the pty (and remove ``link``)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
        for w in self._workers:
            w.join(timeout)
        self._workers.clear()
        self._close_pty()
        # the link is removed only while it is still the one this device made (a user's file is never deleted)
        if self.link is not None and self._link_target is not None and self.link.is_symlink():
            if os.readlink(self.link) == self._link_target:
                self.link.unlink(missing_ok=True)
            self._link_target = None

    def __enter__(self) -> VirtualDevice:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ bytes with faults

    def _faulty(self, data: bytes) -> bytes:
        f = self.faults
        if not (f.drop or f.corrupt) or not data:
            return data
        arr = np.frombuffer(data, np.uint8).copy()
        if f.corrupt:
            hit = self._rng.random(len(arr)) < f.corrupt
            arr[hit] ^= self._rng.integers(1, 256, hit.sum()).astype(np.uint8)
            self.stats["corrupted_bytes"] += int(hit.sum())
        if f.drop:
            keep = self._rng.random(len(arr)) >= f.drop
            self.stats["dropped_bytes"] += int((~keep).sum())
            arr = arr[keep]
        return arr.tobytes()

    def _send(self, msg, seq: int | None = None, whole: bool = False) -> bytes:
        """Send ``msg`` with the next sequence number (or ``seq``: a resent frame keeps its first one, so that its
        bytes and, in segment mode, its parts are those of the first transmission); returns its packet bytes.
        ``whole``: never split (a STATUS is made afresh for each request, so its parts could never combine)."""
        raw = pr.encode(msg, self._next_seq() if seq is None else seq)
        self.stats["tx_packets"] += 1
        if self.faults.delay > 0 and self._rng.random() < self.faults.delay_prob:
            self._stall_until = max(self._stall_until, time.monotonic() + self.faults.delay)
            self.stats["stalls"] += 1
        self._transmit(raw, whole)
        return raw

    def _next_seq(self) -> int:
        seq, self._seq = self._seq, (self._seq + 1) & 0xFFFF
        return seq

    def _transmit(self, raw: bytes, whole: bool = False) -> None:
        """Put one packet on the line: split into parts in segment mode (unless ``whole``), through the faults."""
        out = self._faulty(raw if whole else pr.split(raw, self._segment))
        if len(self._out) > 4_000_000:  # nobody reads: a real device's buffer overflows too
            self.stats["overflow_bytes"] += len(out)
        else:
            self._out += out

    def _flush(self) -> None:
        if not self._out or self._master is None or time.monotonic() < self._stall_until:
            return
        try:
            n = os.write(self._master, bytes(self._out[:65536]))
            del self._out[:n]
        except BlockingIOError:
            pass
        except OSError:  # the other side is gone
            self._out.clear()

    # ------------------------------------------------------------ protocol

    def _reply(self, packet: bytes, msg) -> None:
        self._last_packet, self._last_reply = packet, self._send(msg)

    def _handle(self, seq: int, msg, packet: bytes) -> None:
        now = time.monotonic()
        self._last_rx = now
        self.stats["rx_packets"] += 1
        if packet == self._last_packet and self._last_reply and not isinstance(msg, pr.Heartbeat | pr.StatusRequest):
            self._transmit(self._last_reply)  # a retried command: answer again, do not repeat it
            return
        after_segment, self._after_segment = self._after_segment, isinstance(msg, pr.Segment)
        if isinstance(msg, pr.Hello):
            if not after_segment:  # a new session (PROTOCOL.md §9): whole packets unless SEGMENT came just before
                self._segment = 0
            m = self.model
            L = self.limits
            self._reply(
                packet,
                pr.HelloReply(
                    seq,
                    pr.PROTOCOL_VERSION,
                    self.firmware + (f"; finger={m.finger}" if getattr(m, "finger", None) else ""),
                    m.rows,
                    m.cols,
                    self.rate,
                    L.max_current,
                    L.max_temperature,
                    L.max_force,
                    L.watchdog,
                    L.max_waypoints,
                    np.asarray(m.taxel_uv),
                    np.asarray(m.reference),
                ),
            )
        elif isinstance(msg, pr.StrokeCommand | pr.ProbeStroke | pr.CarrierStroke):
            if msg.stroke_id == self.stroke_id and self._cmd is not None:
                self._reply(packet, pr.Ack(seq))  # the stroke id makes the command idempotent: never run twice
                return
            if self.state in (1, 2):
                self._reply(packet, pr.Nak(seq, 3, f"busy with stroke {self.stroke_id}"))
                return
            probe = isinstance(msg, pr.ProbeStroke)
            carrier = isinstance(msg, pr.CarrierStroke)
            if probe and not hasattr(self.model, "probe"):
                self._reply(packet, pr.Nak(seq, 4, "this finger's frame model cannot run guarded strokes"))
                return
            if carrier and not hasattr(self.model, "carrier"):
                self._reply(packet, pr.Nak(seq, 4, "this finger's frame model cannot run carrier strokes"))
                return
            reason = command_refusal(msg, self.limits)
            if reason is not None:  # as a firmware must (PROTOCOL.md §6): refused before anything moves
                self._reply(packet, pr.Nak(seq, 2, reason))
                return
            if carrier:
                plan = msg
            else:
                points = msg.start if probe else msg.contact
                plan = StrokePlan(msg.time, points, msg.normal, msg.depth, msg.hold_currents)
            self._reply(packet, pr.Ack(seq))
            self.stroke_id, self._cmd, self._frames, self._n_sent, self._done = msg.stroke_id, msg, None, 0, 255
            self.state, self.heater_on, self.watchdog_tripped = 1, True, False
            self._wire_current = np.asarray(msg.currents[0] if carrier else msg.hold_currents, float)
            with self._lock:
                self._result = None
            index = self._index
            self._index += 1
            extra = "carrier" if carrier else (float(msg.travel), float(msg.threshold)) if probe else None
            w = threading.Thread(target=self._compute, args=(plan, index, msg.stroke_id, extra), daemon=True)
            self._workers = [t for t in self._workers if t.is_alive()] + [w]
            w.start()
        elif isinstance(msg, pr.Segment):
            if msg.size and msg.size < pr.MIN_SEGMENT:
                self._reply(packet, pr.Nak(seq, 6, f"segment size {msg.size}: expected 0 or ≥ {pr.MIN_SEGMENT} bytes"))
                return
            self._reply(packet, pr.Ack(seq))  # the ACK itself is short and goes whole
            self._segment = int(msg.size)
        elif isinstance(msg, pr.Abort):
            self._reply(packet, pr.Ack(seq))
            if self.state in (1, 2):
                self._end(1)
            self._heater_off()
        elif isinstance(msg, pr.StatusRequest):
            self._send(
                pr.Status(
                    seq,
                    self.state,
                    self.stroke_id,
                    self._n_sent,
                    self._done,
                    self.heater_on,
                    self.watchdog_tripped,
                    self._dec.bad,
                    self._wire_current,
                    self._wire_temperature,
                ),
                whole=True,
            )
        elif isinstance(msg, pr.Heartbeat):
            self._send(pr.Ack(seq))
        elif isinstance(msg, pr.Resend):
            if msg.stroke_id != self.stroke_id or self._frames is None:
                self._reply(packet, pr.Nak(seq, 5, f"stroke {msg.stroke_id} is not in the device's buffer"))
                return
            self._reply(packet, pr.Ack(seq))
            for i in range(msg.first, min(msg.first + msg.count, self._n_sent)):
                self._send_frame(i)
                self.stats["resent_frames"] += 1
        else:  # a reply type sent to the device
            self._send(pr.Nak(seq, 1, f"{type(msg).__name__} is not a command"))

    def _compute(self, plan, index, sid, probe=None) -> None:
        """The frames of a stroke (``probe`` None), a carrier stroke (``"carrier"``) or a guarded stroke (its
        ``(travel, threshold)``), or the exception that stopped the frame model."""
        try:
            if probe is None or probe == "carrier":
                res = self.model(plan, index) if probe is None else self.model.carrier(plan, index)
                res = {k: np.asarray(res[k], float) for k in FRAME_KEYS}
            else:
                res = self.model.probe(plan, *probe, index)
                res = {k: np.asarray(res[k], float) for k in (*FRAME_KEYS, *PROBE_KEYS)}
        except Exception as e:  # the device reports a fault instead of dying
            res = e
        with self._lock:
            # a stroke abandoned meanwhile (watchdog, abort) may finish after the stroke that replaced it: its late
            # result must not take the place of the current stroke's, which would then never be streamed
            if sid == self.stroke_id:
                self._result = (sid, res)

    def _send_frame(self, i: int) -> None:
        f = self._frames
        if i == self._n_sent:  # first transmission: stamp the sample time (a resent frame keeps its stamp and seq)
            self._stamps[i] = time.monotonic() - self._t0
            self._frame_seq[i] = self._next_seq()
        fields = (
            self.stroke_id,
            i,
            float(self._stamps[i]),
            f["taxel_current"][i],
            f["wire_current"][i],
            f["wire_temperature"][i],
            float(f["skin_temperature"][i]),
            f["finger_tip_position"][i],
            f["finger_curvature"][i],
            float(f["contact_force"][i]),
        )
        if isinstance(self._cmd, pr.ProbeStroke):
            msg = pr.ProbeFrame(*fields, int(f["probe"][i]), float(f["travel"][i]), f["position"][i])
        else:
            msg = pr.Frame(*fields)
        self._send(msg, seq=int(self._frame_seq[i]))

    def _heater_off(self) -> None:
        if not self.faults.stuck_heater:
            self.heater_on = False
            self._wire_current = np.zeros(3)

    def _end(self, reason: int) -> None:
        self._done = reason
        self.state = 0
        if self._frames is None:
            self._frames = {k: np.zeros((0,)) for k in FRAME_KEYS}
        self._send(pr.StrokeDone(self.stroke_id, self._n_sent, reason))
        self._heater_off()

    def _step_stroke(self, now: float) -> None:
        if self.state == 1:
            with self._lock:
                res, self._result = self._result, None
            if res is not None and res[0] == self.stroke_id:
                if isinstance(res[1], Exception):
                    self.state = 3
                    self._heater_off()
                    return
                self._frames, self.state, self._started = res[1], 2, now
                self._stamps = np.zeros(len(self._cmd.time))
                self._frame_seq = np.zeros(len(self._cmd.time), np.int64)
        if self.state != 2:
            return
        t = np.asarray(self._cmd.time)
        while self._n_sent < len(t):
            due = self._started + (t[self._n_sent] - t[0]) / self.speed if self.speed > 0 else now
            if due > now or len(self._out) > 262144:
                break
            i = self._n_sent
            self._wire_temperature = self._frames["wire_temperature"][i]
            self._wire_current = self._frames["wire_current"][i]
            self._send_frame(i)
            self._n_sent += 1
            self.stats["tx_frames"] += 1
            if self._frames["contact_force"][i] > min(self._cmd.max_force, self.limits.max_force):
                self._end(3)
                return
            if (
                self.faults.disconnect_after is not None
                and not self._disconnected_once
                and self.stats["tx_frames"] >= self.faults.disconnect_after
            ):
                self._disconnect()
                return
        if self._n_sent >= len(t):
            self._end(0)

    def _disconnect(self) -> None:
        self._disconnected_once = True
        self.stats["disconnects"] += 1
        self._out.clear()
        self._close_pty()
        self._dec = pr.Decoder()
        self._segment, self._after_segment = 0, False  # a new connection starts with whole packets
        try:
            self.open()
        except BadInput:  # something else took the link's place meanwhile: left alone, served without the link
            self.link, self._link_target = None, None
            self.open()

    def _run(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            wait = 0.002 if (self.state in (1, 2) or self._out) else 0.02
            try:
                r, _, _ = select.select([self._master], [], [], wait)
            except (OSError, ValueError):
                r = []
            if r:
                try:
                    data = os.read(self._master, 65536)
                except (BlockingIOError, OSError):
                    data = b""
                if data:
                    for seq, msg in self._dec.feed(self._faulty(data) if self.faults.inbound else data):
                        self._handle(seq, msg, pr.encode(msg, seq))
                    self.stats["rx_bad"] = self._dec.bad
            now = time.monotonic()
            if self.state in (1, 2) or self.heater_on:
                if now - self._last_rx > self.limits.watchdog and not self.watchdog_tripped:
                    self.watchdog_tripped = True
                    self.stats["watchdog_trips"] += 1
                    if self.state in (1, 2):
                        self._end(2)
                    self._heater_off()
            self._step_stroke(now)
            self._flush()


def _layout_problem(msg, probe: bool) -> str | None:
    """What is malformed in a STROKE or PROBE_STROKE's contents (None when nothing): waypoint arrays of one length T
    (time (T,), points and normals (T, 3)), three hold currents, finite numbers, max_force > 0 (a NaN max_force
    would disable the force abort) and a probe's travel in (0, 0.1] m (its approach midpoints are computed next)."""
    name = "start" if probe else "contact"
    t = np.asarray(msg.time, dtype=float)
    pts = np.asarray(getattr(msg, name), dtype=float)
    nrm = np.asarray(msg.normal, dtype=float)
    if t.ndim != 1 or len(t) < 2:
        return f"time: expected T ≥ 2 waypoint times, got shape {t.shape}"
    if pts.shape != (len(t), 3) or nrm.shape != (len(t), 3):
        return f"{name} {pts.shape} and normal {nrm.shape} must both be ({len(t)}, 3), one row per waypoint time"
    if np.shape(msg.hold_currents) != (3,):
        return f"hold_currents: expected 3 values, got shape {np.shape(msg.hold_currents)}"
    for k, a in (("time", t), (name, pts), ("normal", nrm), ("hold_currents", msg.hold_currents)):
        if not np.all(np.isfinite(np.asarray(a, dtype=float))):
            return f"{k}: expected finite numbers"
    scalars = {"max_force": msg.max_force, "depth": msg.depth}
    if probe:
        scalars.update(travel=msg.travel, threshold=msg.threshold)
    for k, v in scalars.items():
        if not np.isfinite(float(v)):
            return f"{k}: expected a finite number, got {v}"
    if not float(msg.max_force) > 0:
        return f"max_force: expected > 0 N, got {msg.max_force}"
    if probe and not 0 < float(msg.travel) <= 0.1:
        return f"travel: expected in (0, 0.1] m, got {msg.travel}"
    return None


def command_refusal(msg, limits: Limits) -> str | None:
    """Why a device with ``limits`` refuses a STROKE, PROBE_STROKE or CARRIER_STROKE with NAK 2 (PROTOCOL.md §6,
    §10), or None when it runs it: malformed contents first, then the safety check
    (:func:`~bayestouch.hardware.safety.check_plan`, a guarded stroke along the midpoints of its approach lines, as
    ``ProbePlan.stroke_plan``; :func:`~bayestouch.hardware.safety.check_carrier` for a carrier stroke) under the
    tighter of ``limits`` and the command's max_force, and a probe's
    threshold in (0, max_force)."""
    if isinstance(msg, pr.CarrierStroke):
        if not (np.isfinite(float(msg.max_force)) and float(msg.max_force) > 0):
            return f"max_force: expected > 0 N, got {msg.max_force}"
        try:
            check_carrier(msg, limits)
        except BadInput as e:  # UnsafePlan is one
            return str(e)
        return None
    probe = isinstance(msg, pr.ProbeStroke)
    problem = _layout_problem(msg, probe)
    if problem is not None:
        return problem
    lim = limits._replace(max_force=min(limits.max_force, float(msg.max_force)))
    contact = np.asarray(msg.start) - 0.5 * float(msg.travel) * np.asarray(msg.normal) if probe else msg.contact
    try:
        check_plan(StrokePlan(msg.time, contact, msg.normal, msg.depth, msg.hold_currents), lim)
    except UnsafePlan as e:
        return str(e)
    if probe and not 0 < msg.threshold < lim.max_force:
        return f"probe plan: threshold {msg.threshold:g} N must be in (0, {lim.max_force:g})"
    return None
