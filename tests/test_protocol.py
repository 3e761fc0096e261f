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
    msgs = _messages()
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


_SMALL = [pr.Ack(1), pr.Resend(5, 6, 7), pr.StrokeDone(1, 2, 0), pr.Nak(4, 1, "x"), _messages(16)[-2], _messages(16)[1]]


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
