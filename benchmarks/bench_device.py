"""Hardware adapter: frame throughput at 16 × 16 taxels over a pseudo-terminal, command round-trip latency, and
the pure protocol's encode/decode rate.

The virtual finger serves frames as fast as it can (``speed = 0``, the synthetic frame model, so the forward
model's cost is not in the numbers); the client is :class:`~bayestouch.hardware.device.FingerDevice` with real
pyserial I/O. Both run in this one process (the device in a thread), so they share the interpreter lock: a
real device on the other end of the line would leave the client more time.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from bayestouch.hardware import protocol as pr
from bayestouch.hardware.device import FingerDevice
from bayestouch.hardware.frame_models import SyntheticModel
from bayestouch.hardware.safety import StrokePlan
from bayestouch.hardware.simulator import VirtualDevice
from benchmarks.harness import best_of

T = 1000  # frames per stroke (the protocol's longest stroke plan)


def _plan(n: int) -> StrokePlan:
    t = np.arange(n) * 0.02
    c = np.stack([0.01 * t, np.zeros(n), np.full(n, 0.02)], axis=1)
    return StrokePlan(t, c, np.tile([0.0, 0.0, 1.0], (n, 1)), 3e-4, np.array([0.15, 0.05, 0.05]))


def bench_device_pty():
    with (
        tempfile.TemporaryDirectory() as tmp,
        VirtualDevice(SyntheticModel(16, 16), speed=0.0, link=Path(tmp) / "finger") as sim,
        FingerDevice(str(Path(tmp) / "finger"), journal=Path(tmp) / "rec.journal") as dev,
    ):
        dev.run_stroke(_plan(50))  # warm up (imports, first compile of the plan check)
        rates = []
        for _ in range(3):
            t0 = time.perf_counter()
            data = dev.run_stroke(_plan(T))
            rates.append(T / (time.perf_counter() - t0))
            assert data.frames["taxel_current"].shape == (T, 256)
        lat = []
        for _ in range(200):
            t0 = time.perf_counter()
            dev.heartbeat()
            lat.append(time.perf_counter() - t0)
        lat = np.array(lat) * 1e3
        stats = dict(dev.stats)
        sim_stats = dict(sim.stats)
    frame_bytes = len(
        pr.encode(pr.Frame(1, 1, 0.0, np.zeros(256), np.zeros(3), np.zeros(3), 0.0, np.zeros(3), np.zeros(2), 0.0), 1)
    )
    base = {"taxels": 256, "transport": "pty, same process", "frame_bytes_on_wire": frame_bytes}
    return [
        {
            "metric": "stroke frames/s over the pty (16x16, command to last frame, journaled)",
            "value": float(np.median(rates)),
            "unit": "1/s",
            "frames": T,
            **base,
            "retries": stats["retries"],
            "bad_packets": stats["bad_packets"],
            "device_tx_frames": sim_stats["tx_frames"],
        },
        {
            "metric": "command round-trip latency (heartbeat -> ack), median",
            "value": float(np.median(lat)),
            "unit": "ms",
            "p95_ms": float(np.percentile(lat, 95)),
            "max_ms": float(lat.max()),
            "n": len(lat),
            **base,
        },
    ]


def bench_protocol_pure():
    g = np.random.default_rng(0)
    frame = pr.Frame(
        1, 2, 0.5, g.normal(size=256) * 1e-7, g.random(3), 300 + g.random(3), 300.0, g.random(3), g.random(2), 0.1
    )
    raw = pr.encode(frame, 7)
    n = 200
    stream = raw * n
    enc = best_of(lambda: [pr.encode(frame, i) for i in range(n)], repeat=5) / n
    dec = best_of(lambda: pr.Decoder().feed(stream), repeat=5) / n
    return [
        {"metric": "FRAME encode (16x16), frames/s", "value": 1 / enc, "unit": "1/s", "bytes": len(raw)},
        {"metric": "FRAME stream decode (16x16), frames/s", "value": 1 / dec, "unit": "1/s", "bytes": len(raw)},
    ]
