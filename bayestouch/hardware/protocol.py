"""The finger's wire protocol, version 1 (revision 1.1 adds guarded strokes, 1.2 segmented packets for lossy
links, 1.3 carrier strokes): pure encoding and decoding (bytes ↔ messages), no I/O.

The specification is ``PROTOCOL.md`` beside this file. In short: every packet is

``version u8 | type u8 | seq u16 | length u16 | payload | crc32 u32``  (little endian)

with the CRC-32 (IEEE 802.3, :func:`zlib.crc32`) over everything before it, COBS-encoded (Cheshire &
Baker 1999, IEEE/ACM Trans. Networking 7:159) and terminated by one zero byte. Payload fields are laid out
in the order of each message's NamedTuple fields; arrays carry a u32 count of rows first.

On a link that loses bytes, a long packet (a 16 × 16 FRAME is 1.1 kB) almost never arrives whole: at 1 % byte
loss one in 10⁵ does. :func:`split` cuts such a packet into PART packets of a few dozen bytes, each framed and
checked on its own and named by the CRC-32 of the whole packet, so that the parts of several transmissions of the
same packet combine; :class:`Decoder` reassembles them (PROTOCOL.md §9).
"""

from __future__ import annotations

import math
import struct
import zlib
from collections import OrderedDict
from typing import NamedTuple

import numpy as np

__all__ = [
    "PROTOCOL_VERSION",
    "MAX_PAYLOAD",
    "ProtocolError",
    "Decoder",
    "cobs_encode",
    "cobs_decode",
    "encode",
    "decode_packet",
    "split",
    "MIN_SEGMENT",
    "Hello",
    "StrokeCommand",
    "Abort",
    "StatusRequest",
    "Heartbeat",
    "Resend",
    "HelloReply",
    "Ack",
    "Nak",
    "Status",
    "Frame",
    "StrokeDone",
    "ProbeStroke",
    "ProbeFrame",
    "Segment",
    "Part",
    "CarrierStroke",
    "PROBE_STATUS",
    "MESSAGE_TYPES",
    "NAK_CODES",
    "DONE_REASONS",
    "STATES",
]

#: protocol version carried in every packet's first byte
PROTOCOL_VERSION = 1
#: largest payload (bytes) a packet may carry
MAX_PAYLOAD = 65535
_HEADER = struct.Struct("<BBHH")
_CRC = struct.Struct("<I")
#: largest packet (bytes, before COBS)
MAX_PACKET = _HEADER.size + MAX_PAYLOAD + _CRC.size

#: NAK reason codes
NAK_CODES = {
    1: "unknown message",
    2: "unsafe plan",
    3: "busy",
    4: "bad stroke",
    5: "no such stroke",
    6: "bad argument",
}
#: why a stroke ended
DONE_REASONS = {0: "complete", 1: "aborted", 2: "watchdog", 3: "over force", 4: "over temperature"}
#: device states
STATES = {0: "idle", 1: "computing", 2: "running", 3: "fault"}
#: what the guarded approach of one waypoint found (:class:`ProbeFrame` ``probe``)
PROBE_STATUS = {0: "contact", 1: "no contact within the travel", 2: "in contact at the approach start"}


#: smallest segment size (bytes of packet per PART) a SEGMENT command may ask for
MIN_SEGMENT = 16


class ProtocolError(ValueError):
    """A packet that cannot be decoded (bad COBS, CRC, version, type, length or payload)."""


# ---------------------------------------------------------------- messages: client → device


class Hello(NamedTuple):
    """Handshake request. ``protocol``: the client's protocol version."""

    protocol: int = PROTOCOL_VERSION


class StrokeCommand(NamedTuple):
    """Run a stroke: waypoints of the pad's contact point, pressed ``depth`` deep, wires at ``hold_currents``.

    Attributes
    ----------
    stroke_id : int
    depth : float, metres
    max_force : float, N
        The device aborts the stroke when the measured normal force exceeds it.
    hold_currents : (3,) float, amperes
    time : (T,) float, seconds from the stroke's start (speeds follow from the waypoints' spacing)
    contact : (T, 3) float, metres
    normal : (T, 3) float, unit outward surface normals
    """

    stroke_id: int
    depth: float
    max_force: float
    hold_currents: np.ndarray
    time: np.ndarray
    contact: np.ndarray
    normal: np.ndarray


class Abort(NamedTuple):
    """Stop the running stroke and switch the heaters off."""


class StatusRequest(NamedTuple):
    """Ask for a :class:`Status`."""


class Heartbeat(NamedTuple):
    """Keep-alive: without one (or any valid packet) for ``watchdog`` seconds the device stops heating."""


class Resend(NamedTuple):
    """Send frames ``first`` … ``first + count − 1`` of stroke ``stroke_id`` again."""

    stroke_id: int
    first: int
    count: int


class Segment(NamedTuple):
    """Revision 1.2: from now on send every packet longer than ``size`` bytes as PARTs (0 = whole packets again).

    Attributes
    ----------
    size : int, bytes
        Packet bytes per PART: 0, or at least :data:`MIN_SEGMENT`.
    """

    size: int


class Part(NamedTuple):
    """Revision 1.2, both directions: bytes ``offset`` … ``offset + len(data) − 1`` of a packet (its body: header,
    payload and CRC, before COBS) that was too long to send whole.

    Attributes
    ----------
    key : int
        The whole packet's CRC-32 (its last four bytes): the parts of every transmission of the same packet share
        it.
    total : int, bytes
        Length of the whole packet body.
    offset : int, bytes
    data : (n,) uint8
    """

    key: int
    total: int
    offset: int
    data: np.ndarray


# ---------------------------------------------------------------- messages: device → client


class HelloReply(NamedTuple):
    """Handshake answer: firmware, taxel layout, frame rate and the device's safety limits.

    Attributes
    ----------
    ack : int
        Sequence number of the :class:`Hello` answered.
    protocol : int
    firmware : str
    rows, cols : int
        Taxel array size (N = rows · cols taxels, frames list them row-major).
    rate : float, Hz
        Taxel frame rate.
    max_current : float, amperes
    max_temperature : float, K
    max_force : float, N
    watchdog : float, seconds
    max_waypoints : int
    taxel_uv : (N, 2) float, metres
        Pad coordinates of the taxels.
    reference : (N,) uint8
        1 for unloaded reference taxels.
    """

    ack: int
    protocol: int
    firmware: str
    rows: int
    cols: int
    rate: float
    max_current: float
    max_temperature: float
    max_force: float
    watchdog: float
    max_waypoints: int
    taxel_uv: np.ndarray
    reference: np.ndarray


class Ack(NamedTuple):
    """Command ``ack`` (its sequence number) accepted."""

    ack: int


class Nak(NamedTuple):
    """Command ``ack`` refused with a code of :data:`NAK_CODES` and a one-line reason."""

    ack: int
    code: int
    reason: str


class Status(NamedTuple):
    """Device status.

    Attributes
    ----------
    ack : int
    state : int
        Key of :data:`STATES`.
    stroke_id : int
        Last stroke accepted (0: none yet).
    frames : int
        Frames of that stroke produced so far.
    done : int
        Reason code of :data:`DONE_REASONS` when the stroke ended, 255 while it runs or before any stroke.
    heater_on : bool
    watchdog_tripped : bool
    rx_bad : int
        Packets the device rejected (CRC, framing) since it started.
    wire_current : (3,) float, amperes
    wire_temperature : (3,) float, K
    """

    ack: int
    state: int
    stroke_id: int
    frames: int
    done: int
    heater_on: bool
    watchdog_tripped: bool
    rx_bad: int
    wire_current: np.ndarray
    wire_temperature: np.ndarray


class Frame(NamedTuple):
    """One streamed frame (float32 on the wire).

    Attributes
    ----------
    stroke_id, index : int
        Stroke and frame number within it (0-based).
    time : float, seconds
        Device clock when the frame was sampled.
    taxel_current : (N,) float, amperes
    wire_current : (3,) float, amperes
    wire_temperature : (3,) float, K
    skin_temperature : float, K
    tip_position : (3,) float, metres (finger-base frame)
    curvature : (2,) float, 1/metres
    contact_force : float, N
    """

    stroke_id: int
    index: int
    time: float
    taxel_current: np.ndarray
    wire_current: np.ndarray
    wire_temperature: np.ndarray
    skin_temperature: float
    tip_position: np.ndarray
    curvature: np.ndarray
    contact_force: float


class StrokeDone(NamedTuple):
    """Stroke ``stroke_id`` ended after ``frames`` frames, for reason ``reason`` (:data:`DONE_REASONS`)."""

    stroke_id: int
    frames: int
    reason: int


class ProbeStroke(NamedTuple):
    """Revision 1.1: a guarded stroke. At each waypoint the pad approaches from ``start`` along −``normal`` until
    the contact force crosses ``threshold`` (at most ``travel`` metres), then presses ``depth`` deeper and follows;
    the device answers with :class:`ProbeFrame` s instead of :class:`Frame` s.

    Attributes
    ----------
    stroke_id : int
    depth : float, metres
        Press beyond the first touch (the planned force's depth).
    max_force : float, N
    hold_currents : (3,) float, amperes
    time : (T,) float, seconds from the stroke's start
    start : (T, 3) float, metres
        Approach start points (outside the believed surface).
    normal : (T, 3) float
        Unit vectors; the approach runs along −normal (the believed outward surface normals).
    travel : float, metres
        Longest approach from each start.
    threshold : float, N
        Contact force that counts as the touch.
    """

    stroke_id: int
    depth: float
    max_force: float
    hold_currents: np.ndarray
    time: np.ndarray
    start: np.ndarray
    normal: np.ndarray
    travel: float
    threshold: float


class CarrierStroke(NamedTuple):
    """Revision 1.3: a stroke as the finger executes it. The carrier moves the finger base through
    ``base_position`` with the rotation ``base_rotation`` while the wires follow ``currents``; the pad goes where
    the bent rod puts it, and touches wherever that meets the object. The device answers with :class:`Frame` s
    (their ``tip_position`` and ``curvature`` are what the finger senses of its bend).

    Attributes
    ----------
    stroke_id : int
    max_force : float, N
        The device aborts the stroke when the measured normal force exceeds it.
    time : (T,) float, seconds from the stroke's start (one frame each)
    base_position : (T, 3) float, metres (world frame)
    base_rotation : (3, 3) float
        World-from-base rotation, rows in order (the rod leaves the base along the base frame's +z).
    currents : (T, 3) float, amperes
        Each wire's current from each frame's time to the next.
    """

    stroke_id: int
    max_force: float
    time: np.ndarray
    base_position: np.ndarray
    base_rotation: np.ndarray
    currents: np.ndarray


class ProbeFrame(NamedTuple):
    """Revision 1.1: a :class:`Frame` of a :class:`ProbeStroke` with what the waypoint's approach found.

    Attributes
    ----------
    stroke_id … contact_force
        As :class:`Frame`.
    probe : int
        Key of :data:`PROBE_STATUS`: 0 the force crossed the threshold within the travel, 1 it did not, 2 it
        was above the threshold at the start already.
    travel : float, metres
        Approach distance from the start at the threshold crossing (NaN when ``probe`` is 1, 0 when 2).
    position : (3,) float, metres (world frame)
        The device's pose estimate of the pad centre at the threshold crossing (at the end of the travel when
        ``probe`` is 1, at the start when 2).
    """

    stroke_id: int
    index: int
    time: float
    taxel_current: np.ndarray
    wire_current: np.ndarray
    wire_temperature: np.ndarray
    skin_temperature: float
    tip_position: np.ndarray
    curvature: np.ndarray
    contact_force: float
    probe: int
    travel: float
    position: np.ndarray


# field kinds: a struct code, "str" (u16 length + UTF-8), or (dtype, trailing shape) for an array with a
# u32 leading count
_F8 = ("<f8", ())
_F4 = ("<f4", ())
_LAYOUT: dict[type, tuple] = {
    Hello: ("B",),
    StrokeCommand: ("I", "d", "d", _F8, _F8, ("<f8", (3,)), ("<f8", (3,))),
    Abort: (),
    StatusRequest: (),
    Heartbeat: (),
    Resend: ("I", "I", "I"),
    HelloReply: ("H", "B", "str", "H", "H", "d", "d", "d", "d", "d", "I", ("<f8", (2,)), ("u1", ())),
    Ack: ("H",),
    Nak: ("H", "B", "str"),
    Status: ("H", "B", "I", "I", "B", "?", "?", "I", _F8, _F8),
    Frame: ("I", "I", "d", _F4, _F4, _F4, "f", _F4, _F4, "f"),
    StrokeDone: ("I", "I", "B"),
    ProbeStroke: ("I", "d", "d", _F8, _F8, ("<f8", (3,)), ("<f8", (3,)), "d", "d"),
    ProbeFrame: ("I", "I", "d", _F4, _F4, _F4, "f", _F4, _F4, "f", "B", "d", _F8),
    Segment: ("H",),
    Part: ("I", "I", "I", ("u1", ())),
    CarrierStroke: ("I", "d", _F8, ("<f8", (3,)), ("<f8", (3,)), ("<f8", (3,))),
}
#: wire type code of every message class
MESSAGE_TYPES: dict[type, int] = {
    Hello: 0x01,
    StrokeCommand: 0x02,
    Abort: 0x03,
    StatusRequest: 0x04,
    Heartbeat: 0x05,
    Resend: 0x06,
    HelloReply: 0x81,
    Ack: 0x82,
    Nak: 0x83,
    Status: 0x84,
    Frame: 0x85,
    StrokeDone: 0x86,
    ProbeStroke: 0x07,
    ProbeFrame: 0x87,
    Segment: 0x08,
    Part: 0x40,
    CarrierStroke: 0x09,
}
_BY_CODE = {v: k for k, v in MESSAGE_TYPES.items()}
_STRUCTS = {k: struct.Struct("<" + k) for k in "BHIdf?"}


# ---------------------------------------------------------------- COBS


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: ``data`` without zero bytes (at most 1 byte per 254 added)."""
    out = bytearray()
    for chunk in bytes(data).split(b"\x00"):
        while len(chunk) >= 254:
            out.append(255)
            out += chunk[:254]
            chunk = chunk[254:]
        out.append(len(chunk) + 1)
        out += chunk
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`ProtocolError` on a malformed block."""
    data = bytes(data)
    if 0 in data:
        raise ProtocolError("COBS: zero byte inside a packet")
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        end = i + code
        if end > n:
            raise ProtocolError("COBS: block runs past the packet end")
        out += data[i + 1 : end]
        i = end
        if code < 255 and i < n:
            out.append(0)
    return bytes(out)


# ---------------------------------------------------------------- packets


def _pack_fields(msg) -> bytes:
    parts = []
    for kind, value in zip(_LAYOUT[type(msg)], msg, strict=True):
        if kind == "str":
            raw = str(value).encode()
            parts.append(struct.pack("<H", len(raw)) + raw)
        elif isinstance(kind, tuple):
            dtype, trailing = kind
            arr = np.ascontiguousarray(np.asarray(value, dtype=dtype).reshape((-1, *trailing)))
            parts.append(struct.pack("<I", arr.shape[0]) + arr.tobytes())
        else:
            parts.append(struct.pack("<" + kind, value))
    return b"".join(parts)


def _unpack_fields(cls, payload: bytes):
    vals, pos = [], 0
    try:
        for kind in _LAYOUT[cls]:
            if kind == "str":
                (n,) = struct.unpack_from("<H", payload, pos)
                pos += 2
                if pos + n > len(payload):
                    raise ProtocolError("string runs past the payload")
                vals.append(payload[pos : pos + n].decode())
                pos += n
            elif isinstance(kind, tuple):
                dtype, trailing = kind
                (rows,) = struct.unpack_from("<I", payload, pos)
                pos += 4
                size = np.dtype(dtype).itemsize
                item = size * math.prod(trailing)
                if rows * item > len(payload) - pos:
                    raise ProtocolError("array runs past the payload")
                arr = np.frombuffer(payload, dtype=dtype, count=rows * item // size, offset=pos)
                vals.append(arr.reshape((rows, *trailing)).astype(np.dtype(dtype).newbyteorder("=")))
                pos += rows * item
            else:
                s = _STRUCTS[kind]
                (v,) = s.unpack_from(payload, pos)
                vals.append(v)
                pos += s.size
    except (struct.error, UnicodeDecodeError) as e:
        raise ProtocolError(f"{cls.__name__}: bad payload ({e})") from None
    if pos != len(payload):
        raise ProtocolError(f"{cls.__name__}: {len(payload) - pos} trailing payload bytes")
    return cls(*vals)


def _body(msg, seq: int) -> bytes:
    """One message → its packet body (header, payload, CRC), before COBS."""
    if type(msg) not in MESSAGE_TYPES:
        raise TypeError(f"not a protocol message: {type(msg).__name__}")
    payload = _pack_fields(msg)
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"{type(msg).__name__}: payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = _HEADER.pack(PROTOCOL_VERSION, MESSAGE_TYPES[type(msg)], seq & 0xFFFF, len(payload)) + payload
    return body + _CRC.pack(zlib.crc32(body))


def encode(msg, seq: int) -> bytes:
    """One message → the bytes on the wire (COBS-encoded packet plus the 0x00 delimiter).

    Parameters
    ----------
    msg : one of the message NamedTuples
    seq : int
        Sequence number, taken modulo 2¹⁶.
    """
    return cobs_encode(_body(msg, seq)) + b"\x00"


def split(wire: bytes, size: int) -> bytes:
    """The bytes of one encoded packet (as :func:`encode` returns them) as PART packets of at most ``size``
    packet bytes each, or unchanged when the packet is not longer than ``size`` (or ``size`` is 0).

    Every part carries the packet's ``seq``, its CRC-32 as ``key``, the body's length and the part's offset;
    sending the same packet again gives the same parts (PROTOCOL.md §9).

    Parameters
    ----------
    wire : bytes
        One packet with its 0x00 delimiter.
    size : int, bytes
        0, or at least :data:`MIN_SEGMENT`.
    """
    if size and size < MIN_SEGMENT:
        raise ValueError(f"segment size {size}: expected 0 or at least {MIN_SEGMENT} bytes")
    if not size or not wire:
        return wire
    body = cobs_decode(wire[:-1])
    if len(body) <= size:
        return wire
    (seq,) = struct.unpack_from("<H", body, 2)
    (key,) = _CRC.unpack_from(body, len(body) - _CRC.size)
    return b"".join(
        encode(Part(key, len(body), off, np.frombuffer(body[off : off + size], np.uint8)), seq)
        for off in range(0, len(body), size)
    )


def _decode_body(body: bytes) -> tuple[int, object]:
    if len(body) < _HEADER.size + _CRC.size:
        raise ProtocolError(f"packet of {len(body)} bytes is shorter than header + CRC")
    (crc,) = _CRC.unpack_from(body, len(body) - _CRC.size)
    if zlib.crc32(body[: -_CRC.size]) != crc:
        raise ProtocolError("CRC mismatch")
    version, code, seq, length = _HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        raise ProtocolError(f"protocol version {version}, expected {PROTOCOL_VERSION}")
    if code not in _BY_CODE:
        raise ProtocolError(f"unknown message type 0x{code:02x}")
    if length != len(body) - _HEADER.size - _CRC.size:
        raise ProtocolError(f"length field {length} does not match the packet")
    return seq, _unpack_fields(_BY_CODE[code], body[_HEADER.size : -_CRC.size])


def decode_packet(packet: bytes) -> tuple[int, object]:
    """One COBS-encoded packet (without its 0x00 delimiter) → ``(seq, message)``.

    Raises
    ------
    ProtocolError
        On any defect: COBS, length, CRC, version, unknown type or a payload that does not parse.
    """
    return _decode_body(cobs_decode(bytes(packet)))


class Decoder:
    """Incremental stream decoder: feed bytes as they arrive, get ``(seq, message)`` pairs.

    Bad packets are dropped and counted (``bad``, with the last reason in ``last_error``); a run of bytes
    longer than any valid packet without a delimiter is discarded and counted once. PART packets (revision 1.2)
    are reassembled and the whole packet is returned once every byte of it has arrived, from any number of
    transmissions; incomplete packets of at most ``max_partial_bytes`` bytes together are held (the oldest is
    dropped first: 16 MiB hold 14 000 incomplete 16 × 16 frames). A packet
    completed recently (one of the last 64) is delivered again when the first part of another transmission of it
    arrives, so that a retried command is seen and answered again. No I/O.
    """

    def __init__(self, max_partial_bytes: int = 1 << 24) -> None:
        self._buf = bytearray()
        self._overflow = False
        self.bad = 0
        self.good = 0
        self.parts = 0
        self.last_error = ""
        self.max_partial_bytes = int(max_partial_bytes)
        self._held = 0  # bytes of the incomplete packets held
        self._partial: OrderedDict[tuple[int, int], tuple[bytearray, np.ndarray]] = OrderedDict()
        self.max_completed = 64
        self._completed: OrderedDict[tuple[int, int], bytes] = OrderedDict()

    def _reassembled(self, part: Part) -> tuple[int, object] | None:
        """Store one part; the whole packet's ``(seq, message)`` once every byte of it has arrived."""
        total, offset, data = int(part.total), int(part.offset), bytes(np.asarray(part.data, np.uint8))
        if not _HEADER.size + _CRC.size <= total <= MAX_PACKET or not data or offset + len(data) > total:
            raise ProtocolError(f"part of {len(data)} bytes at {offset} does not fit a packet of {total}")
        key = (int(part.key), total)
        if key in self._completed:
            # a packet sent again (a command retried because its answer was lost): delivered again once per
            # transmission, on its first part, so that the receiver can answer it again
            return _decode_body(self._completed[key]) if offset == 0 else None
        if key not in self._partial:
            while self._partial and self._held + total > self.max_partial_bytes:
                self._held -= len(self._partial.popitem(last=False)[1][0])
            self._partial[key] = (bytearray(total), np.zeros(total, bool))
            self._held += total
        body, have = self._partial[key]
        body[offset : offset + len(data)] = data
        have[offset : offset + len(data)] = True
        if not have.all():
            return None
        del self._partial[key]
        self._held -= total
        if _CRC.unpack_from(body, total - _CRC.size)[0] != key[0]:
            raise ProtocolError("reassembled packet does not carry its key as CRC")
        body = bytes(body)
        seq, msg = _decode_body(body)
        if isinstance(msg, Part):
            raise ProtocolError("a part inside a part")
        self._completed[key] = body  # only a packet that decoded is remembered
        if len(self._completed) > self.max_completed:
            self._completed.popitem(last=False)
        return seq, msg

    def feed(self, data: bytes) -> list[tuple[int, object]]:
        """Decode every complete packet in the bytes received so far."""
        out = []
        self._buf += data
        if 0 not in data:
            parts = []
        else:
            *parts, rest = bytes(self._buf).split(b"\x00")
            self._buf = bytearray(rest)
        for packet in parts:
            if self._overflow:  # the tail of a discarded over-long run
                self._overflow = False
                continue
            if not packet:
                continue  # an idle delimiter (senders may flush with one)
            try:
                seq, msg = decode_packet(packet)
                if isinstance(msg, Part):
                    self.parts += 1
                    whole = self._reassembled(msg)
                    if whole is None:
                        continue
                    seq, msg = whole
                out.append((seq, msg))
                self.good += 1
            except ProtocolError as e:
                self.bad += 1
                self.last_error = str(e)
        limit = MAX_PACKET + MAX_PACKET // 254 + 2
        if len(self._buf) > limit:
            self._buf.clear()
            if not self._overflow:
                self.bad += 1
                self.last_error = "packet too long (no delimiter)"
            self._overflow = True
        return out
