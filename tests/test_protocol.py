"""The wire protocol: COBS and CRC known answers, message round-trips, and a fuzzed decoder."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayestouch.hardware import protocol as pr

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _messages(n_taxels: int = 256, T: int = 7) -> list:
    g = np.random.default_rng(0)
    return [
        pr.Hello(),
        pr.StrokeCommand(
            42,
            3e-4,
            1.0,
            np.array([0.15, 0.05, 0.05]),
            np.arange(T) * 0.02,
            g.normal(size=(T, 3)),
            g.normal(size=(T, 3)),
        ),
        pr.Abort(),
        pr.StatusRequest(),
        pr.Heartbeat(),
        pr.Resend(42, 3, 9),
        pr.HelloReply(
            7,
            1,
            "fw-ü 1.0",
            16,
            16,
            50.0,
            0.2,
            393.15,
            1.0,
            1.0,
            1000,
            g.normal(size=(n_taxels, 2)),
            (g.random(n_taxels) < 0.1).astype(np.uint8),
        ),
        pr.Ack(65535),
        pr.Nak(3, 2, "unsafe: wire current"),
        pr.Status(9, 2, 42, 17, 255, True, False, 3, np.array([0.15, 0.05, 0.0]), np.array([360.0, 300.0, 293.0])),
        pr.Frame(
            42,
            17,
            12.345678,
            g.normal(size=n_taxels) * 1e-7,
            g.random(3),
            300 + g.random(3),
            301.5,
            g.normal(size=3),
            g.normal(size=2),
            0.15,
        ),
        pr.StrokeDone(42, 101, 0),
        pr.ProbeStroke(
            43,
            2e-4,
            0.5,
            np.array([0.15, 0.05, 0.05]),
            np.arange(T) * 0.02,
            g.normal(size=(T, 3)),
            g.normal(size=(T, 3)),
            0.05,
            0.02,
        ),
        pr.ProbeFrame(
            43,
            5,
            1.25,
            g.normal(size=n_taxels) * 1e-7,
            g.random(3),
            300 + g.random(3),
            301.5,
            g.normal(size=3),
            g.normal(size=2),
            0.15,
            0,
            0.0123456789,
            g.normal(size=3) * 0.01,
        ),
        pr.Segment(48),
        pr.Part(0xDEADBEEF, 300, 48, np.arange(48, dtype=np.uint8)),
        pr.CarrierStroke(
            44, 0.9, np.arange(T) * 0.02, g.normal(size=(T, 3)), np.diag([1.0, -1.0, -1.0]), g.random((T, 3))
        ),
    ]


def _same(a, b) -> bool:
    if type(a) is not type(b):
        return False
    for x, y in zip(a, b, strict=True):
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not np.array_equal(np.asarray(x), np.asarray(y)):
                return False
        elif x != y:
            return False
    return True


def _as_sent(m):
    """What the receiver gets: float32 fields of a Frame are rounded to float32 on the wire."""
    if isinstance(m, pr.Frame):
        f32 = [np.asarray(v, np.float32).astype(float) for v in m[3:]]
        f32[3], f32[6] = float(f32[3]), float(f32[6])
        return pr.Frame(m.stroke_id, m.index, m.time, *f32)
    if isinstance(m, pr.ProbeFrame):  # the Frame part as float32, the probe part float64
        f32 = [np.asarray(v, np.float32).astype(float) for v in m[3:10]]
        f32[3], f32[6] = float(f32[3]), float(f32[6])
        return pr.ProbeFrame(m.stroke_id, m.index, m.time, *f32, *m[10:])
    return m


def test_crc_and_cobs_known_answers():
    # CRC-32/IEEE check value (Koopman's CRC catalogue): crc32(b"123456789") = 0xCBF43926
    assert zlib.crc32(b"123456789") == 0xCBF43926
    # COBS examples of Cheshire & Baker 1999 / the COBS literature
    assert pr.cobs_encode(b"\x00") == b"\x01\x01"
    assert pr.cobs_encode(b"\x11\x22\x00\x33") == b"\x03\x11\x22\x02\x33"
    assert pr.cobs_encode(bytes(range(1, 255))) == b"\xff" + bytes(range(1, 255)) + b"\x01"
    assert pr.cobs_decode(b"\x03\x11\x22\x02\x33") == b"\x11\x22\x00\x33"
    with pytest.raises(pr.ProtocolError):
        pr.cobs_decode(b"\x05\x11\x22")  # block longer than the packet


@given(st.binary(max_size=2000))
@FUZZ
def test_cobs_round_trip(data):
    enc = pr.cobs_encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + len(data) // 254 + 1  # the COBS overhead bound
    assert pr.cobs_decode(enc) == data


@pytest.mark.parametrize("msg", _messages(), ids=lambda m: type(m).__name__)
def test_message_round_trip(msg):
    raw = pr.encode(msg, 513)
    assert raw.endswith(b"\x00") and 0 not in raw[:-1]
    seq, back = pr.decode_packet(raw[:-1])
    assert seq == 513
    assert _same(back, _as_sent(msg))
    # negative control: a changed field does not come back equal
    if len(msg):
        assert not _same(back, _as_sent(msg._replace(**{msg._fields[0]: _bump(msg[0])})))


def _bump(v):
    return v + 1 if not isinstance(v, np.ndarray) else v + 1.0


def test_every_message_type_has_a_layout_and_code():
    assert {type(m) for m in _messages()} == set(pr.MESSAGE_TYPES)
    assert len(set(pr.MESSAGE_TYPES.values())) == len(pr.MESSAGE_TYPES)


def test_decode_rejects_tampering():
    raw = pr.encode(pr.Resend(1, 2, 3), 5)[:-1]
    body = bytearray(pr.cobs_decode(raw))
    for i in range(len(body)):  # any single changed byte of the packet is caught (CRC-32 catches bursts ≤ 32 bit)
        bad = bytearray(body)
        bad[i] ^= 0x5A
        with pytest.raises(pr.ProtocolError):
            pr.decode_packet(pr.cobs_encode(bytes(bad)))
    body[0] = 2  # another protocol version, with a valid CRC
    body[-4:] = zlib.crc32(bytes(body[:-4])).to_bytes(4, "little")
    with pytest.raises(pr.ProtocolError, match="version"):
        pr.decode_packet(pr.cobs_encode(bytes(body)))


def test_decoder_streams_split_packets_and_discards_overlong_garbage():
    msgs = [m for m in _messages() if not isinstance(m, pr.Part)]  # a lone part is held, not delivered
    stream = b"".join(pr.encode(m, i) for i, m in enumerate(msgs))
    dec = pr.Decoder()
    got = []
    for i in range(0, len(stream), 37):  # arbitrary chunking
        got += dec.feed(stream[i : i + 37])
    assert [s for s, _ in got] == list(range(len(msgs)))
    assert all(_same(m, _as_sent(x)) for (_, m), x in zip(got, msgs, strict=True))
    assert dec.bad == 0
    dec.feed(b"\x07" * (pr.MAX_PACKET + 1000))  # no delimiter for longer than any packet: discarded, counted once
    dec.feed(b"\x07" * 500)
    assert dec.bad == 1
    out = dec.feed(b"\x00" + pr.encode(pr.Ack(9), 1))
    assert [m for _, m in out] == [pr.Ack(9)] and dec.bad == 1


@given(st.binary(max_size=3000))
@FUZZ
def test_decoder_survives_garbage(data):
    dec = pr.Decoder()
    out = dec.feed(data) + dec.feed(b"\x00")
    for seq, m in out:  # anything accepted must re-encode to a packet found in the input
        assert pr.encode(m, seq)[:-1] in data
    assert dec.good == len(out)
    assert dec.bad + dec.good <= data.count(0) + 2


_SMALL = [pr.Ack(1), pr.Resend(5, 6, 7), pr.StrokeDone(1, 2, 0), pr.Nak(4, 1, "x"), _messages(16)[12], _messages(16)[1]]


@given(st.lists(st.sampled_from(range(len(_SMALL))), min_size=1, max_size=12), st.data())
@FUZZ
def test_decoder_rejects_and_counts_every_damaged_packet(kinds, data):
    packets = [pr.encode(_SMALL[k], i) for i, k in enumerate(kinds)]
    damaged = data.draw(st.sets(st.integers(0, len(packets) - 1)))
    stream = bytearray()
    for i, p in enumerate(packets):
        p = bytearray(p)
        if i in damaged:
            pos = data.draw(st.integers(0, len(p) - 2))  # any byte but the delimiter
            if data.draw(st.booleans()):
                del p[pos]  # a dropped byte
            else:
                p[pos] = data.draw(st.integers(1, 255).filter(lambda b, o=p[pos]: b != o))  # a corrupted byte
        stream += p
    dec = pr.Decoder()
    out = dec.feed(bytes(stream))
    assert [s for s, _ in out] == [i for i in range(len(packets)) if i not in damaged]
    assert dec.bad == len(damaged)
    assert all(_same(m, _as_sent(_SMALL[kinds[s]])) for s, m in out)


# ---------------------------------------------------------------- segmented packets (revision 1.2)


def _lossy(wire: bytes, rate: float, rng: np.random.Generator) -> bytes:
    keep = rng.random(len(wire)) >= rate
    return np.frombuffer(wire, np.uint8)[keep].tobytes()


def test_split_parts_reassemble_in_any_order_to_the_same_packet():
    frame = _messages()[10]
    wire = pr.encode(frame, 777)
    parts = pr.split(wire, 48)
    n = -(-len(pr.cobs_decode(wire[:-1])) // 48)
    assert parts.count(0) == n > 20  # a 1.1 kB frame in 48-byte parts
    assert pr.split(wire, 0) == wire and pr.split(pr.encode(pr.Ack(3), 1), 48) == pr.encode(pr.Ack(3), 1)
    packets = [p + b"\x00" for p in parts.split(b"\x00")[:-1]]
    rng = np.random.default_rng(0)
    dec = pr.Decoder()
    out = []
    for i in rng.permutation(len(packets)):
        out += dec.feed(packets[i])
    assert len(out) == 1 and out[0][0] == 777 and _same(out[0][1], _as_sent(frame))
    assert (dec.good, dec.parts, dec.bad) == (1, n, 0)
    # all but one part: nothing is delivered
    dec = pr.Decoder()
    assert dec.feed(b"".join(packets[:-1])) == [] and len(dec._partial) == 1


def test_parts_of_different_packets_have_different_keys():
    # the key is the packet's own CRC: a CRC-32 over a body that ends in its CRC is the constant residue, so a key
    # taken that way would let every frame complete every other one
    keys = set()
    for i in range(5):
        frame = _messages()[10]._replace(index=i)
        _, part = pr.decode_packet(pr.split(pr.encode(frame, i), 48).split(b"\x00")[0])
        keys.add(part.key)
    assert len(keys) == 5


def test_parts_of_several_lossy_transmissions_combine():
    # at 1 % byte loss a whole 1.1 kB frame arrives with probability 0.99^1124 ≈ 1e-5: never in 40 tries; its
    # 48-byte parts arrive with probability ≈ 0.47 each, so a few transmissions together bring every part
    frame = _messages()[10]
    wire = pr.encode(frame, 5)
    rng = np.random.default_rng(1)
    whole = pr.Decoder()
    assert not any(whole.feed(_lossy(wire, 0.01, rng)) for _ in range(40))
    dec = pr.Decoder()
    tries, out = 0, []
    while not out and tries < 40:
        out = dec.feed(_lossy(pr.split(wire, 48), 0.01, rng) + b"\x00")
        tries += 1
    assert out and 2 <= tries <= 20 and _same(out[0][1], _as_sent(frame))
    assert dec.bad > 0  # damaged parts were seen and dropped


def test_a_completed_packet_sent_again_is_delivered_again_once():
    # a command retried because its answer was lost must reach the device again, once per transmission
    wire = pr.split(pr.encode(_messages()[1], 9), 48)
    dec = pr.Decoder()
    assert len(dec.feed(wire)) == 1
    assert [s for s, _ in dec.feed(wire)] == [9]
    later = wire[wire.index(0) + 1 :]  # without its first part: the others alone deliver nothing
    assert dec.feed(later) == []


def test_decoder_rejects_malformed_parts():
    body = pr.cobs_decode(pr.encode(_messages()[1], 4)[:-1])
    (crc,) = np.frombuffer(body[-4:], "<u4")
    dec = pr.Decoder()
    bad = [
        pr.Part(int(crc), len(body), len(body) - 2, np.zeros(8, np.uint8)),  # runs past the packet's end
        pr.Part(int(crc), 5, 0, np.zeros(5, np.uint8)),  # shorter than header + CRC
        pr.Part(int(crc), pr.MAX_PACKET + 1, 0, np.zeros(8, np.uint8)),  # longer than any packet
        pr.Part(int(crc), len(body), 0, np.zeros(0, np.uint8)),  # empty
    ]
    assert dec.feed(b"".join(pr.encode(m, 1) for m in bad)) == [] and dec.bad == 4
    # complete, but not the packet its key names: rejected
    wrong = bytearray(body)
    wrong[8] ^= 1
    assert dec.feed(pr.encode(pr.Part(int(crc), len(wrong), 0, np.frombuffer(bytes(wrong), np.uint8)), 2)) == []
    assert dec.bad == 5
    # a part inside a part
    inner = pr.cobs_decode(pr.encode(bad[0], 3)[:-1])
    (ic,) = np.frombuffer(inner[-4:], "<u4")
    assert dec.feed(pr.encode(pr.Part(int(ic), len(inner), 0, np.frombuffer(inner, np.uint8)), 3)) == []
    assert dec.bad == 6 and "part inside a part" in dec.last_error
    # the good parts of the same packet still complete it
    assert len(dec.feed(pr.split(pr.encode(_messages()[1], 4), 32))) == 1


def test_decoder_holds_a_bounded_number_of_incomplete_packets():
    size = len(pr.cobs_decode(pr.encode(_messages()[10], 0)[:-1]))
    dec = pr.Decoder(max_partial_bytes=8 * size)
    for i in range(50):
        first = pr.split(pr.encode(_messages()[10]._replace(index=i), i), 48).split(b"\x00")[0] + b"\x00"
        dec.feed(first)
    assert len(dec._partial) == 8 and dec._held == 8 * size
    # a hostile stream of parts of the largest packets holds no more than the budget
    dec = pr.Decoder()
    for k in range(600):
        dec.feed(pr.encode(pr.Part(k, pr.MAX_PACKET, 0, np.zeros(16, np.uint8)), k))
    assert dec._held <= dec.max_partial_bytes and len(dec._partial) == dec.max_partial_bytes // pr.MAX_PACKET
    with pytest.raises(ValueError, match="segment size"):
        pr.split(pr.encode(_messages()[10], 1), 8)


def test_every_name_the_hardware_package_exports_resolves():
    """``bayestouch.hardware.__all__`` maps each name onto the module that defines it (the frame models were once
    mapped onto the simulator module, which only imports two constants from theirs: AttributeError)."""
    import bayestouch.hardware as hw

    for name in hw.__all__:
        assert getattr(hw, name) is not None, name
