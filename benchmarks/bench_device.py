"""Hardware adapter: frame throughput at 16 × 16 taxels over a pseudo-terminal, command round-trip latency, the
pure protocol's encode/decode rate, and strokes delivered whole over a link that loses bytes (whole packets
against segment mode, PROTOCOL.md §9).

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
from bayestouch.hardware.device import DeviceError, FingerDevice
from bayestouch.hardware.frame_models import FRAME_KEYS, SyntheticModel
from bayestouch.hardware.safety import StrokePlan
from bayestouch.hardware.simulator import Faults, VirtualDevice
from benchmarks.bench_user_sets import bootstrap_median, wilson_interval
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


#: byte-loss probabilities (each byte, both directions) of the lossy-link benchmark
LOSS_RATES = (0.0, 1e-3, 5e-3, 1e-2, 2e-2)
LOSS_RUNS = 5  # sessions per rate and mode (fault seeds 0 … 4)
LOSS_STROKES, LOSS_T = 3, 50  # strokes per session, frames per stroke


class _Kept(SyntheticModel):
    """The synthetic model, keeping what it produced for each stroke (the truth a delivered stroke must equal)."""

    def __init__(self):
        super().__init__(16, 16, seed=1)
        self.out: dict[int, dict] = {}

    def __call__(self, plan, index):
        self.out[index] = r = super().__call__(plan, index)
        return r


def _session(rate: float, segment: int | None, seed: int) -> dict:
    """One session over a lossy link: handshake and LOSS_STROKES strokes; whether every stroke came back whole
    and equal to what the device produced, and the wall time."""
    with tempfile.TemporaryDirectory() as tmp:
        link = Path(tmp) / "finger"
        faults = Faults(drop=rate, inbound=True, seed=seed)
        t0 = time.perf_counter()
        with VirtualDevice(_Kept(), speed=0.0, faults=faults, link=link) as sim:
            dev = FingerDevice(str(link), segment=segment, connect_timeout=10.0, stroke_timeout=60.0)
            try:
                dev.open()
                got = [dev.run_stroke(_plan(LOSS_T)) for _ in range(LOSS_STROKES)]
                ok = len(sim.model.out) == LOSS_STROKES and all(
                    np.array_equal(g.frames[k], np.asarray(sim.model.out[i][k], np.float32).astype(float))
                    for i, g in enumerate(got)
                    for k in FRAME_KEYS
                )
                error = "" if ok else "a stroke differs from what the device produced"
            except DeviceError as e:
                ok, error = False, str(e)
            finally:
                dev.close()
        return {"ok": ok, "seconds": time.perf_counter() - t0, "error": error, "segmented": dev.stats["segmented"]}


def bench_link_loss():
    out = []
    for rate in LOSS_RATES:
        for mode, segment in (("whole packets", 0), ("automatic segment mode", None)):
            runs = [_session(rate, segment, seed) for seed in range(LOSS_RUNS)]
            k = sum(r["ok"] for r in runs)
            lo, hi = wilson_interval(k, LOSS_RUNS)
            secs = [r["seconds"] / LOSS_STROKES if r["ok"] else np.inf for r in runs]
            med, mlo, mhi = (v if np.isfinite(v) else None for v in bootstrap_median(secs))  # None: failed runs
            print(f"  loss {rate:g}, {mode}: {k}/{LOSS_RUNS} sessions whole, median {med} s/stroke", flush=True)
            out.append(
                {
                    "metric": f"sessions delivered whole at {rate:g} byte loss each way, {mode}",
                    "value": k / LOSS_RUNS,
                    "unit": "fraction",
                    "ci95": [lo, hi],
                    "sessions": LOSS_RUNS,
                    "strokes_per_session": LOSS_STROKES,
                    "frames_per_stroke": LOSS_T,
                    "taxels": 256,
                    "loss_per_byte": rate,
                    "segment": "auto" if segment is None else segment,
                    "segmented_sessions": sum(bool(r["segmented"]) for r in runs),
                    "seconds_per_stroke_median": med,  # a failed session counts as infinitely slow
                    "seconds_per_stroke_ci95": [mlo, mhi],
                    "errors": sorted({r["error"] for r in runs if r["error"]}),
                    "transport": "pty, same process, device speed 0 (as fast as the line allows)",
                }
            )
    return out
