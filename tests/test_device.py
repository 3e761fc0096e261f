"""The hardware adapter end to end over real pyserial I/O: the virtual finger on a pty, the client, faults,
safety refusals, the watchdog and the ``device`` command."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import numpy as np
import pytest

from bayestouch.errors import BadInput
from bayestouch.hardware import protocol as pr
from bayestouch.hardware.device import DeviceError, FingerDevice, HeaterFault, read_journal
from bayestouch.hardware.frame_models import FRAME_KEYS, SyntheticModel
from bayestouch.hardware.safety import Limits, StrokePlan, UnsafePlan, check_plan, load_limits
from bayestouch.hardware.simulator import Faults, VirtualDevice

WIRE_KEYS = {
    "taxel_current": "taxel_current",
    "wire_current": "wire_current",
    "wire_temperature": "wire_temperature",
    "skin_temperature": "skin_temperature",
    "finger_tip_position": "finger_tip_position",
    "finger_curvature": "finger_curvature",
    "contact_force": "contact_force",
}


class Recorded(SyntheticModel):
    """The synthetic frame model, remembering what it produced for each stroke index."""

    def __init__(self):
        super().__init__(seed=3)
        self.out: dict[int, dict] = {}

    def __call__(self, plan, index):
        r = super().__call__(plan, index)
        self.out[index] = r
        return r


def make_plan(T: int = 60, currents=(0.15, 0.05, 0.05), depth: float = 3e-4, speed: float = 0.01) -> StrokePlan:
    t = np.arange(T) * 0.02
    contact = np.stack([speed * t, np.zeros(T), np.full(T, 0.02)], axis=1)
    return StrokePlan(t, contact, np.tile([0.0, 0.0, 1.0], (T, 1)), depth, np.asarray(currents, float))


@pytest.fixture(scope="module", autouse=True)
def _warm_imports():
    check_plan(make_plan(), Limits())  # import the physics once, outside the timed exchanges


@pytest.fixture
def device(tmp_path):
    started = []

    def start(faults=None, speed=0.0, limits=None, **client):
        sim = VirtualDevice(Recorded(), speed=speed, faults=faults, limits=limits, link=tmp_path / "finger")
        sim.start()
        started.append(sim)
        dev = FingerDevice(str(tmp_path / "finger"), journal=tmp_path / "rec.journal", **client)
        started.append(dev)
        return sim, dev.open()

    yield start
    for obj in reversed(started):
        obj.close()


def _stroke_file(path, plans, currents: bool = False):
    """A ``device run --stroke-file`` JSON of ``plans`` (with their hold currents when ``currents``)."""
    rows = [
        {
            "time": p.time.tolist(),
            "contact": p.contact.tolist(),
            "normal": p.normal.tolist(),
            "depth": p.depth,
            **({"hold_currents": p.hold_currents.tolist()} if currents else {}),
        }
        for p in plans
    ]
    path.write_text(json.dumps({"strokes": rows}))
    return path


def _matches_model(data, model_out) -> bool:
    """Every frame equals what the device's model produced (float32 on the wire)."""
    return all(
        np.array_equal(data.frames[k], np.asarray(model_out[WIRE_KEYS[k]], np.float32).astype(float))
        for k in FRAME_KEYS
    )


def test_handshake_stroke_and_status(device, tmp_path):
    sim, dev = device()
    info = dev.info
    assert (info.rows, info.cols, info.protocol) == (16, 16, pr.PROTOCOL_VERSION)
    assert np.array_equal(info.taxel_uv, sim.model.taxel_uv) and np.array_equal(info.reference, sim.model.reference)
    assert (info.max_current, info.max_temperature, info.watchdog) == (0.2, 393.15, 1.0)
    plan = make_plan()
    data = dev.run_stroke(plan)
    assert data.frames["taxel_current"].shape == (60, 256)
    assert _matches_model(data, sim.model.out[0])
    assert np.all(np.diff(data.device_time) >= 0)
    st = dev.status()
    assert (st.state, st.stroke_id, st.frames, st.done, st.heater_on) == (0, data.stroke_id, 60, 0, False)
    # the journal holds the handshake, the command and every frame as received
    j = read_journal(tmp_path / "rec.journal")
    frames = [m for m in j if isinstance(m, pr.Frame)]
    assert isinstance(j[0], pr.HelloReply) and isinstance(j[1], pr.StrokeCommand)
    assert sorted(f.index for f in frames) == list(range(60))
    # negative control: another stroke index gives other currents, so the comparison can fail
    assert not _matches_model(data, sim.model(plan, 1))


# byte-fault rates: a 1.1 kB frame survives 3e-4 per byte with probability e^-0.33 ≈ 0.72, so ~30 of 100 frames
# need a resend (the check that the fault was exercised cannot fail by chance)
FAULTS = {
    "dropped": (Faults(drop=3e-4, seed=1), {}, lambda s, d: d.stats["bad_packets"] > 0 < d.stats["resend_requests"]),
    "corrupted": (Faults(corrupt=3e-4, seed=2), {}, lambda s, d: d.stats["bad_packets"] > 0),
    "delayed": (Faults(delay=0.4, delay_prob=0.1, seed=3), {}, lambda s, d: s.stats["stalls"] > 0),
    "disconnect": (Faults(disconnect_after=45), {}, lambda s, d: d.stats["reconnects"] == 1 == s.stats["disconnects"]),
    # 1 % of bytes dropped or corrupted and a disconnect: the 4.5 kB handshake reply comes through only in parts
    # after many tries, and the reconnect's handshake must be given as long (it was given 2 s and failed)
    "lossy-disconnect": (
        Faults(drop=0.01, corrupt=0.01, disconnect_after=45, seed=4),
        {"timeout": 0.3},
        lambda s, d: d.stats["reconnects"] >= 1 <= s.stats["disconnects"] and d.stats.get("segmented", 0) > 0,
    ),
    # reconnecting slower than the 0.3 s watchdog, 0.8 s of real-time stroke left: the device abandons the stroke,
    # the client runs it again
    "disconnect-redo": (
        Faults(disconnect_after=20),
        {"limits": Limits(watchdog=0.3), "reconnect_wait": 0.6, "speed": 1.0},
        lambda s, d: d.stats["redone_strokes"] == 1 == s.stats["watchdog_trips"],
    ),
}


@pytest.mark.parametrize("name", list(FAULTS))
def test_faults_survived_with_nothing_lost(device, tmp_path, name):
    faults, kw, exercised = FAULTS[name]
    sim, dev = device(faults, **kw)
    plans = [make_plan(60), make_plan(40, depth=2e-4)]
    got = [dev.run_stroke(p) for p in plans]
    assert exercised(sim, dev), (sim.stats, dev.stats)
    assert len(sim.model.out) == len(plans) + dev.stats["redone_strokes"]  # no stroke was ever run twice
    # each returned stroke is complete and equal to what the device produced for it (a redone stroke uses the
    # model's later index, so compare against the last index whose length matches)
    for data, plan in zip(got, plans, strict=True):
        idx = max(i for i, r in sim.model.out.items() if len(r["taxel_current"]) == len(plan.time))
        assert _matches_model(data, sim.model.out[idx])
    # and every frame returned is also in the journal, written as it arrived
    logged = {(m.stroke_id, m.index) for m in read_journal(tmp_path / "rec.journal") if isinstance(m, pr.Frame)}
    assert all((d.stroke_id, i) in logged for d in got for i in range(len(d.plan.time)))


def test_an_unanswered_status_on_a_slow_link_waits_for_the_frames(device, monkeypatch):
    """A link that stalls for longer than a status request's retries wait (its answer comes after the client gave
    up): the stroke waits for its frames until its own time-out instead of failing at the first unanswered status
    request (before, that DeviceError escaped and `device run` aborted with every frame still on its way). The
    first status request during the stroke is made unanswered; 1.5 s stalls make the client ask."""
    sim, dev = device(Faults(delay=1.5, delay_prob=0.1, seed=1))
    real, calls = dev.status, []

    def slow_status():
        calls.append(1)
        if len(calls) == 1:
            raise DeviceError(f"{dev.url}: no answer to StatusRequest after {dev.retries} tries")
        return real()

    monkeypatch.setattr(dev, "status", slow_status)
    plan = make_plan(60)
    data = dev.run_stroke(plan)
    assert calls and sim.stats["stalls"] > 0
    assert _matches_model(data, sim.model.out[max(sim.model.out)])


@pytest.mark.parametrize("unanswered", [1, 3])
def test_an_unanswered_status_after_the_frames(device, monkeypatch, unanswered):
    """The heater check after a stroke's frames arrived: one status request left unanswered by a slow link is asked
    again and the stroke is kept; three unanswered ones leave the heaters' state unknown, which is a DeviceError
    that says so (never a stroke reported as fine)."""
    sim, dev = device(Faults(seed=2))
    real_status, real_collect = dev.status, dev._collect
    state = {"collected": False, "failed": 0}

    def collect(sid, T):
        got = real_collect(sid, T)
        state["collected"] = got is not None
        return got

    def status():
        if state["collected"] and state["failed"] < unanswered:
            state["failed"] += 1
            raise DeviceError(f"{dev.url}: no answer to StatusRequest after {dev.retries} tries")
        return real_status()

    monkeypatch.setattr(dev, "_collect", collect)
    monkeypatch.setattr(dev, "status", status)
    plan = make_plan(20)
    if unanswered < 3:
        data = dev.run_stroke(plan)
        assert state["failed"] == unanswered
        assert _matches_model(data, sim.model.out[max(sim.model.out)])
    else:
        with pytest.raises(DeviceError, match="heaters' state is unknown"):
            dev.run_stroke(plan)


def test_inbound_faults_survived(device):
    # the device's decoder rejects damaged commands and the client retries them; 1e-4 per byte on a 1.1 kB
    # command fails ~20 % of tries (8 tries: ~1e-6 of giving up); strokes are repeated until the device has
    # rejected a packet (expected ~0.2 damaged packets per stroke: P(none in 60) ≈ e^-12)
    sim, dev = device(Faults(drop=5e-5, corrupt=5e-5, inbound=True, seed=4))
    n = 0
    while sim.stats["rx_bad"] == 0 and n < 60:
        plan = make_plan(20, depth=1e-4 * (1 + n % 4))
        data = dev.run_stroke(plan)
        idx = max(sim.model.out)
        assert _matches_model(data, sim.model.out[idx])
        n += 1
    assert sim.stats["rx_bad"] > 0
    assert len(sim.model.out) == n + dev.stats["redone_strokes"]


def test_one_percent_byte_loss_both_ways_survived_in_segment_mode(device, tmp_path):
    # at 1 % byte loss a whole 16 × 16 frame (1.1 kB) arrives with probability 1e-5 and the 4.4 kB HELLO_REPLY
    # never: the client finds whole packets do not get through, asks for 48-byte parts (revision 1.2), and the
    # parts of repeated transmissions (retried commands, resent frames) combine
    sim, dev = device(Faults(drop=0.01, inbound=True, seed=5))
    plans = [make_plan(30), make_plan(20, depth=2e-4)]
    got = [dev.run_stroke(p) for p in plans]
    assert dev.stats["segmented"] == 48 == sim._segment
    assert dev.stats["bad_packets"] > 100 and sim.stats["rx_bad"] > 0 and sim.stats["dropped_bytes"] > 1000
    assert len(sim.model.out) == 2  # no stroke run twice
    for i, data in enumerate(got):
        assert _matches_model(data, sim.model.out[i])
    logged = [m for m in read_journal(tmp_path / "rec.journal") if isinstance(m, pr.Frame)]
    assert sorted(m.index for m in logged) == sorted([*range(30), *range(20)])


def test_whole_packets_do_not_survive_one_percent_byte_loss(tmp_path):
    # negative control for the test above: the same link with segment mode switched off never hands shakes
    sim = VirtualDevice(Recorded(), speed=0.0, faults=Faults(drop=0.01, seed=5), link=tmp_path / "finger")
    sim.start()
    try:
        with pytest.raises(DeviceError, match="no answer to Hello"):
            FingerDevice(str(tmp_path / "finger"), segment=0, connect_timeout=3.0).open()
    finally:
        sim.close()


class Revision11(VirtualDevice):
    """A revision 1.1 finger: SEGMENT is an unknown type to it, dropped without an answer."""

    def _handle(self, seq, msg, packet):
        if not isinstance(msg, pr.Segment):
            super()._handle(seq, msg, packet)


def test_segment_mode_with_an_older_device_and_a_new_session(tmp_path):
    link = tmp_path / "finger"
    with Revision11(Recorded(), speed=0.0, link=link):
        dev = FingerDevice(str(link)).open()  # automatic: a clean link never asks for parts
        assert _matches_model(dev.run_stroke(make_plan(10)), Recorded()(make_plan(10), 0))
        assert dev.stats["segmented"] == 0
        dev.close()
        with pytest.raises(DeviceError, match="does not answer SEGMENT"):
            FingerDevice(str(link), segment=64, timeout=0.05).open()
    with VirtualDevice(Recorded(), speed=0.0, link=link) as sim:
        dev = FingerDevice(str(link), segment=64).open()
        dev.run_stroke(make_plan(10))
        assert sim._segment == 64 and dev._dec.parts > 0
        dev.close()
        # the next session (a host that never sends SEGMENT) gets whole packets again: HELLO resets the mode
        dev = FingerDevice(str(link), segment=0).open()
        assert sim._segment == 0 and dev.info.rows == 16
        dev.close()


def test_stuck_heater_detected_after_the_stroke_is_saved(device, tmp_path):
    sim, dev = device(Faults(stuck_heater=True))
    with pytest.raises(HeaterFault, match="heaters still on"):
        dev.run_stroke(make_plan(30))
    assert sim.heater_on
    logged = [m for m in read_journal(tmp_path / "rec.journal") if isinstance(m, pr.Frame)]
    assert sorted(m.index for m in logged) == list(range(30))


@pytest.mark.parametrize("stuck", [False, True])
def test_watchdog_stops_heating_when_heartbeats_stop(device, stuck):
    lim = Limits(watchdog=0.3)
    sim, dev = device(Faults(stuck_heater=stuck), speed=1.0, limits=lim)
    plan = make_plan(150)  # 3 s in real time
    cmd = pr.StrokeCommand(7, plan.depth, 1.0, plan.hold_currents, plan.time, plan.contact, plan.normal)
    assert isinstance(dev._command(cmd), pr.Ack)  # start it, then stay silent: no heartbeats
    assert sim.heater_on
    t0 = time.monotonic()
    while sim.stats["watchdog_trips"] == 0 and time.monotonic() - t0 < 3.0:
        time.sleep(0.02)
    waited = time.monotonic() - t0
    assert sim.stats["watchdog_trips"] == 1 and waited < 1.0  # 0.3 s watchdog plus loop slack
    assert sim.heater_on is stuck  # a stuck heater is the fault the client must detect
    st = dev.status()
    assert st.done == 2 and st.frames < 150 and st.watchdog_tripped


def test_unsafe_plans_refused_before_any_byte(monkeypatch):
    dev = FingerDevice("loop://", handshake=False, timeout=0.05, retries=1).open()
    try:
        written = []
        orig = dev._ser.write
        monkeypatch.setattr(dev._ser, "write", lambda b: written.append(bytes(b)) or orig(b))
        unsafe = {
            "current": make_plan(currents=(0.25, 0.0, 0.0)),
            "temperature": make_plan(currents=(0.19, 0.0, 0.0)),  # ≤ 0.2 A but its steady state > 393 K
            "force": make_plan(depth=1e-3),
            "speed": make_plan(speed=0.2),
            "shape": make_plan()._replace(normal=np.ones((5, 3))),
        }
        for why, plan in unsafe.items():
            with pytest.raises(UnsafePlan):
                dev.run_stroke(plan)
            assert written == [] and dev._ser.in_waiting == 0, why
        # negative control: a safe plan is sent (loop:// only echoes it, so no ACK comes, and the client says so)
        with pytest.raises(DeviceError, match="sends back every packet written to it"):
            dev.run_stroke(make_plan())
        assert written and pr.Decoder().feed(written[0])[0][1].stroke_id > 0
    finally:
        dev.close()


def test_device_refuses_what_its_own_limits_forbid(device):
    # the client is misconfigured with looser limits; the device's check answers NAK "unsafe plan"
    sim, dev = device(limits=Limits(max_current=0.1))
    dev.info = dev.info._replace(max_current=0.2)
    with pytest.raises(UnsafePlan, match="device refused"):
        dev.run_stroke(make_plan(currents=(0.15, 0.0, 0.0)))
    assert not sim.heater_on and sim.stats["tx_frames"] == 0


def test_plan_check_values():
    lim = load_limits()
    chk = check_plan(make_plan(), lim)
    assert chk.speed == pytest.approx(0.01)
    assert 293.15 < chk.peak_temperature < lim.max_temperature
    assert 0 < chk.force < lim.max_force


def _parser():
    from bayestouch.cli.device import add_device_parser

    p = argparse.ArgumentParser()
    add_device_parser(p.add_subparsers(dest="command"))
    return p


def test_cli_run_writes_the_simulate_schema(device, tmp_path):
    from bayestouch.cli.device import run_device
    from bayestouch.io.recording import read_recording

    sim, dev = device()
    dev.close()
    plans = [make_plan(30), make_plan(20)]
    f = _stroke_file(tmp_path / "strokes.json", plans)
    out = tmp_path / "dev.nc"
    args = _parser().parse_args(
        ["device", "run", "--port", str(tmp_path / "finger"), "--stroke-file", str(f), "--out", str(out), "--quiet"]
    )
    assert run_device(args) == 0
    ds = read_recording(out)
    need = {
        "time",
        "stroke_index",
        "taxel_current",
        "contact_force",
        "pressing_depth",
        "contact_point",
        "contact_normal",
        "wire_current",
        "wire_temperature",
        "skin_temperature",
        "finger_tip_position",
        "finger_curvature",
        "taxel_u",
        "taxel_v",
        "taxel_reference",
        "stroke_depth",
    }
    assert need <= set(ds.variables)
    assert ds["taxel_current"].shape == (50, 256) and ds["taxel_current"].attrs["units"] == "A"
    assert np.array_equal(ds["contact_point"].values, np.concatenate([p.contact for p in plans]))
    assert np.array_equal(ds["stroke_index"].values, np.repeat([0, 1], [30, 20]))
    assert not (tmp_path / "dev.nc.journal").exists()  # removed after success
    # random strokes planned on the object model, as `bayestouch simulate` draws them
    out2 = tmp_path / "rand.nc"
    argv = ["device", "run", "--port", str(tmp_path / "finger"), "--strokes", "2", "--duration", "0.5"]
    assert run_device(_parser().parse_args([*argv, "--out", str(out2), "--quiet"])) == 0
    ds2 = read_recording(out2)
    assert ds2["taxel_current"].shape == (52, 256) and np.array_equal(np.unique(ds2["stroke_index"]), [0, 1])
    # nothing recorded is lost: an existing recording is refused without --overwrite, and an earlier failed run's
    # journal is kept under a new name rather than deleted
    recorded = out2.read_bytes()
    with pytest.raises(BadInput, match="already exists.*--overwrite"):
        run_device(_parser().parse_args([*argv, "--out", str(out2), "--quiet"]))
    assert out2.read_bytes() == recorded
    out3 = tmp_path / "again.nc"
    (tmp_path / "again.nc.journal").write_bytes(b"frames of a failed run")
    assert run_device(_parser().parse_args([*argv, "--out", str(out3), "--quiet"])) == 0
    kept = [p for p in tmp_path.iterdir() if p.name.startswith("again.nc.journal.")]
    assert len(kept) == 1 and kept[0].read_bytes() == b"frames of a failed run"
    first = out3.read_bytes()
    assert run_device(_parser().parse_args([*argv, "--out", str(out3), "--overwrite", "--quiet"])) == 0
    # --overwrite sets the earlier recording aside (never deleted), as fit's --overwrite does
    aside = [p for p in tmp_path.glob("replaced-*") if (p / "again.nc").is_file()]
    assert len(aside) == 1 and (aside[0] / "again.nc").read_bytes() == first and out3.read_bytes() != first


def test_cli_bad_input(tmp_path):
    from bayestouch.cli.device import run_device

    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    unsafe = tmp_path / "unsafe.json"
    p = make_plan()
    unsafe.write_text(
        json.dumps(
            {
                "strokes": [
                    {
                        "time": p.time.tolist(),
                        "contact": p.contact.tolist(),
                        "normal": p.normal.tolist(),
                        "depth": p.depth,
                        "hold_currents": [0.5, 0, 0],
                    }
                ]
            }
        )
    )
    cases = {
        "cannot be read": ["--stroke-file", str(bad)],
        "outside": ["--stroke-file", str(unsafe)],
        "expected a netCDF": ["--out", str(tmp_path / "x.txt")],
        "empty string": ["--port", " "],
        "no such device": [],
    }
    for msg, extra in cases.items():
        port = str(tmp_path / "no-such-port") if msg == "no such device" else "loop://"
        argv = ["device", "run", "--port", port, "--out", str(tmp_path / "x.nc"), *extra]
        with pytest.raises(BadInput, match=msg):
            run_device(_parser().parse_args(argv))
    with pytest.raises(BadInput, match="subcommand"):
        run_device(_parser().parse_args(["device"]))


def test_cli_simulate_process_prints_its_pty_and_exits_cleanly(tmp_path):
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bayestouch.cli",
            "device",
            "simulate",
            "--print-port",
            "--model",
            "synthetic",
            "--speed",
            "0",
            "--for",
            "60",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/pts/")
        with FingerDevice(port, connect_timeout=30) as dev:
            data = dev.run_stroke(make_plan(20))
        assert data.frames["taxel_current"].shape == (20, 256)
        proc.terminate()
        assert proc.wait(20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


@pytest.mark.slow
def test_virtual_finger_streams_the_forward_model(tmp_path):
    """The physics behind the protocol: frames equal record_strokes for the same stroke and seed."""
    from bayestouch.hardware.frame_models import ForwardModel
    from bayestouch.hardware.safety import plan_from_stroke
    from bayestouch.params import MODELS
    from bayestouch.physics.virtual import record_strokes
    from bayestouch.scene.objects import load_object
    from bayestouch.scene.strokes import random_strokes

    obj = load_object(MODELS / "objects" / "egg.toml")
    model = ForwardModel(obj, seed=2)
    st = random_strokes(obj, 1, seed=5, duration=0.5)[0]
    with (
        VirtualDevice(model, speed=0.0, link=tmp_path / "finger"),
        FingerDevice(str(tmp_path / "finger"), stroke_timeout=300) as dev,
    ):
        data = dev.run_stroke(plan_from_stroke(st))
    ref = record_strokes(obj, [st], model.vf, 2 * 100003 + 0)  # the device's first stroke: index 0
    for k in FRAME_KEYS:
        assert np.array_equal(data.frames[k], np.asarray(ref[k], np.float32).astype(float)), k
    assert data.frames["contact_force"].max() > 0.01  # the pad touched the egg
    ref_other = record_strokes(obj, [st], model.vf, 1)  # negative control: other noise, other currents
    assert not np.array_equal(data.frames["taxel_current"], np.asarray(ref_other["taxel_current"], np.float32))


class Spike(Recorded):
    """A collision in the middle of the stroke: the measured force jumps to 5 N at frame 10."""

    def __call__(self, plan, index):
        r = dict(super().__call__(plan, index))
        r["contact_force"] = np.where(np.arange(len(plan.time)) == 10, 5.0, r["contact_force"])
        return r


def test_device_aborts_on_over_force(tmp_path):
    with (
        VirtualDevice(Spike(), speed=0.0, link=tmp_path / "finger") as sim,
        FingerDevice(str(tmp_path / "finger")) as dev,
    ):
        with pytest.raises(DeviceError, match="contact force over .*does each normal point out of it"):
            dev.run_stroke(make_plan(40))
        st = dev.status()
        assert (st.done, st.frames, st.heater_on) == (3, 11, False)
        assert sim.stats["tx_frames"] == 11


def test_record_strokes_drives_the_device_like_the_simulator(device):
    from bayestouch.params import MODELS
    from bayestouch.scene.objects import load_object
    from bayestouch.scene.strokes import random_strokes

    sim, dev = device()
    strokes = random_strokes(load_object(MODELS / "objects" / "egg.toml"), 2, seed=1, duration=0.4)
    rec = dev.record_strokes(strokes)
    sim_only = {"taxel_current_clean", "pressure", "friction_force"}
    expect = {"time", "stroke_index", "pressing_depth", "contact_point", "contact_normal", *FRAME_KEYS}
    assert set(rec) == expect and not sim_only & set(rec)
    n = sum(len(s.time) for s in strokes)
    assert all(len(v) == n for v in rec.values())
    assert np.array_equal(rec["contact_point"], np.concatenate([s.contact for s in strokes]))


def test_virtual_finger_refuses_malformed_commands_and_keeps_answering(tmp_path):
    """As PROTOCOL.md §6 says a firmware must: a PROBE_STROKE whose normals are fewer than its start points, and a
    STROKE whose max_force is NaN (which would disable the force abort), are refused with NAK 2, and the device
    still answers afterwards (before, the first killed the device thread and the second was run at 5 N)."""
    from bayestouch.hardware.frame_models import GuardedModel
    from bayestouch.params import MODELS
    from bayestouch.scene.objects import load_object

    sim = VirtualDevice(GuardedModel(load_object(MODELS / "objects" / "sphere.toml")), link=tmp_path / "finger")
    sim.start()
    dev = FingerDevice(str(tmp_path / "finger"), journal=tmp_path / "j.journal").open()
    try:
        p = make_plan(20)
        short = pr.ProbeStroke(41, p.depth, 1.0, p.hold_currents, p.time, p.contact, p.normal[:10], 0.01, 0.05)
        rep = dev._command(short)
        assert isinstance(rep, pr.Nak) and rep.code == 2 and "normal" in rep.reason
        nan_force = pr.StrokeCommand(42, p.depth, float("nan"), p.hold_currents, p.time, p.contact, p.normal)
        rep = dev._command(nan_force)
        assert isinstance(rep, pr.Nak) and rep.code == 2 and "max_force" in rep.reason
        assert isinstance(dev._command(pr.StatusRequest()), pr.Status)  # still alive
        assert not sim.heater_on and sim.stats["tx_frames"] == 0
        # negative control: the well-formed stroke is accepted
        assert isinstance(dev._command(nan_force._replace(stroke_id=43, max_force=1.0)), pr.Ack)
    finally:
        dev.close()
        sim.close()


def test_cli_run_keeps_the_good_strokes_when_the_device_refuses_a_later_one(device, tmp_path, capsys):
    """One safe stroke, then one the device's own (stricter) limits forbid (the client learns them at the handshake
    and refuses the stroke): `device run` exits 2 naming the limit and writes the good stroke as an incomplete
    recording (before, nothing was written: the good stroke survived only in the journal)."""
    from bayestouch.cli.device import run_device
    from bayestouch.io.recording import read_recording

    sim, dev = device(limits=Limits(max_current=0.1))
    dev.close()
    plans = [make_plan(30, currents=(0.08, 0.0, 0.0)), make_plan(20, currents=(0.15, 0.0, 0.0))]
    f = _stroke_file(tmp_path / "strokes.json", plans, currents=True)
    out = tmp_path / "dev.nc"
    argv = ["device", "run", "--port", str(tmp_path / "finger"), "--stroke-file", str(f), "--out", str(out)]
    assert run_device(_parser().parse_args([*argv, "--quiet"])) == 2
    err = capsys.readouterr().err
    assert "outside [0, 0.1] A" in err and "1 complete stroke(s)" in err
    ds = read_recording(out)
    assert ds.attrs["incomplete"] == "true" and ds["taxel_current"].shape[0] == 30


def test_frames_with_impossible_contents_are_rejected_never_recorded(tmp_path):
    """A device whose frame 5 holds a NaN taxel current (a well-formed packet: the CRC passes) and whose frame 7
    holds a 1e-46 A current: the client counts and journals them as bad frames, asks for them again, and gives up
    with a DeviceError rather than return a stroke holding them (before, both were recorded as data). Negative
    control: frame_problem passes the device's good frames."""
    from bayestouch.hardware.device import frame_problem

    class Damaged(SyntheticModel):
        def __call__(self, plan, index):
            r = super().__call__(plan, index)
            r["taxel_current"] = np.array(r["taxel_current"], dtype=float)
            r["taxel_current"][5, 0] = np.nan
            r["taxel_current"][7, 3] = 1e-46
            return r

    sim = VirtualDevice(Damaged(seed=3), link=tmp_path / "finger")
    sim.start()
    dev = FingerDevice(str(tmp_path / "finger"), journal=tmp_path / "j.journal", retries=2, timeout=0.1).open()
    try:
        with pytest.raises(DeviceError, match="still missing"):
            dev.run_stroke(make_plan(20))
        assert dev.stats["bad_frames"] >= 2
        logged = [m for m in read_journal(tmp_path / "j.journal") if isinstance(m, pr.Frame)]
        good = [m for m in logged if m.index not in (5, 7)]
        assert good and all(frame_problem(m, dev.info) is None for m in good)
        assert any(m.index == 5 and frame_problem(m, dev.info) == "taxel_current: non-finite value" for m in logged)
    finally:
        dev.close()
        sim.close()


def test_cli_run_with_a_stuck_heater_keeps_the_stroke_it_completed(device, tmp_path, capsys):
    """A finger whose wires stay powered after the first stroke: `device run` stops there (no second stroke is
    sent to a finger that is still heating), says so in one line with exit 2 (exit 1 is an internal error), and
    the first stroke, complete, is in the .nc, marked incomplete (before, the .nc was not written: the stroke
    survived only in the journal)."""
    from bayestouch.cli.device import run_device
    from bayestouch.io.recording import read_recording

    sim, dev = device(Faults(stuck_heater=True))
    dev.close()
    f = _stroke_file(tmp_path / "strokes.json", [make_plan(30), make_plan(20)])
    out = tmp_path / "dev.nc"
    argv = ["device", "run", "--port", str(tmp_path / "finger"), "--stroke-file", str(f), "--out", str(out)]
    assert run_device(_parser().parse_args([*argv, "--quiet"])) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "heaters still on" in err[0] and "1 complete stroke(s) written" in err[0]
    assert "error: stroke 1 of 2: " in err[0] and "after the stroke ended" in err[0]  # the user's numbering
    ds = read_recording(out)
    assert ds.attrs["incomplete"] == "true" and ds["taxel_current"].shape[0] == 30
    assert len(sim.model.out) == 1  # the second stroke was never sent


def _interrupt_second_stroke(monkeypatch) -> None:
    """Make ``FingerDevice.run_stroke`` raise KeyboardInterrupt (Ctrl-C) when the second stroke starts."""
    real, calls = FingerDevice.run_stroke, []

    def stroke_then_interrupt(self, plan):
        calls.append(plan)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(self, plan)

    monkeypatch.setattr(FingerDevice, "run_stroke", stroke_then_interrupt)


def test_cli_run_interrupted_with_overwrite_keeps_the_earlier_recording(device, tmp_path, capsys, monkeypatch):
    """--overwrite over a complete recording, then Ctrl-C after one stroke: the partial run is written, and the
    earlier recording is set aside whole (before, the one complete stroke replaced it)."""
    from bayestouch.cli.device import run_device
    from bayestouch.io.recording import read_recording

    sim, dev = device()
    dev.close()
    f = _stroke_file(tmp_path / "strokes.json", [make_plan(30), make_plan(20)])
    out = tmp_path / "dev.nc"
    argv = ["device", "run", "--port", str(tmp_path / "finger"), "--stroke-file", str(f), "--out", str(out)]
    assert run_device(_parser().parse_args([*argv, "--quiet"])) == 0
    complete = out.read_bytes()
    _interrupt_second_stroke(monkeypatch)
    assert run_device(_parser().parse_args([*argv, "--overwrite", "--quiet"])) == 130
    assert read_recording(out)["taxel_current"].shape[0] == 30
    (aside,) = tmp_path.glob("replaced-*")
    assert (aside / "dev.nc").read_bytes() == complete


def test_stroke_file_with_a_byte_order_mark_is_read(tmp_path):
    from bayestouch.cli.device import load_stroke_file

    f = _stroke_file(tmp_path / "s.json", [make_plan(10)])
    bom = tmp_path / "bom.json"
    bom.write_bytes(b"\xef\xbb\xbf" + f.read_bytes())
    a, b = load_stroke_file(f, [0.1, 0.05, 0.05]), load_stroke_file(bom, [0.1, 0.05, 0.05])
    assert len(a) == len(b) == 1 and np.array_equal(a[0].contact, b[0].contact)


def test_cli_run_interrupted_keeps_the_complete_strokes(device, tmp_path, capsys, monkeypatch):
    """Ctrl-C (or SIGTERM, handled alike) after a complete stroke: the stroke is written to the .nc, marked
    incomplete, and the interrupt goes on (exit 130 from the CLI); before, only the journal held it."""
    from bayestouch.cli.device import run_device
    from bayestouch.io.recording import read_recording

    sim, dev = device()
    dev.close()
    _interrupt_second_stroke(monkeypatch)
    f = _stroke_file(tmp_path / "strokes.json", [make_plan(30), make_plan(20)])
    out = tmp_path / "dev.nc"
    argv = ["device", "run", "--port", str(tmp_path / "finger"), "--stroke-file", str(f), "--out", str(out)]
    assert run_device(_parser().parse_args([*argv, "--quiet"])) == 130
    err = capsys.readouterr().err
    assert "interrupted; 1 complete stroke(s) written" in err and "journal" in err
    assert err.count(": interrupted") == 1  # said once (the ninth review saw two lines)
    ds = read_recording(out)
    assert ds.attrs["incomplete"] == "true" and ds["taxel_current"].shape[0] == 30


def test_cli_run_writes_each_complete_stroke_and_survives_a_hangup(device, tmp_path, capsys, monkeypatch):
    """Issue 24, ninth review: a SIGKILL or SIGHUP (a closed terminal, a dropped ssh) during ``device run`` left no
    recording, only the journal. Now the complete strokes are on disk as a recording marked incomplete before the
    next stroke starts (what a SIGKILL at that moment leaves), and SIGHUP is handled like Ctrl-C: exit 130, the
    strokes kept. Control: the file is not there before the first stroke ends."""
    import os
    import signal

    from bayestouch.cli.device import run_device
    from bayestouch.io.recording import read_recording

    sim, dev = device()
    dev.close()
    out = tmp_path / "dev.nc"
    real, seen = FingerDevice.run_stroke, []

    def stroke(self, plan):
        seen.append(read_recording(out)["taxel_current"].shape[0] if out.exists() else 0)
        if len(seen) == 3:
            os.kill(os.getpid(), signal.SIGHUP)
        return real(self, plan)

    monkeypatch.setattr(FingerDevice, "run_stroke", stroke)
    f = _stroke_file(tmp_path / "strokes.json", [make_plan(30), make_plan(20), make_plan(25)])
    argv = ["device", "run", "--port", str(tmp_path / "finger"), "--stroke-file", str(f), "--out", str(out)]
    prev = signal.signal(signal.SIGHUP, signal.SIG_DFL)  # a terminal's default (under nohup it is ignored, and kept so)
    try:
        assert run_device(_parser().parse_args([*argv, "--quiet"])) == 130
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_DFL  # the handler put back
    finally:
        signal.signal(signal.SIGHUP, prev)
    assert seen[:2] == [0, 30]  # on disk after the first stroke, before the second started
    err = capsys.readouterr().err
    assert "interrupted; 2 complete stroke(s) written" in err
    ds = read_recording(out)
    assert ds.attrs["incomplete"] == "true" and ds["taxel_current"].shape[0] == 50


def test_the_virtual_finger_names_its_unit_in_the_handshake(tmp_path):
    """A model that knows its finger (ForwardModel: "virtual finger N") is named in HELLO_REPLY's firmware
    string, and the client reads it back; a model without one (the control) leaves the plain firmware name."""
    from bayestouch.hardware.device import finger_of

    for name in ("virtual finger 9", None):
        model = Recorded()
        if name:
            model.finger = name
        link = tmp_path / f"finger{name is None}"
        with VirtualDevice(model, speed=0.0, link=link) as sim:
            assert sim.start() is sim and sim.stats is not None  # a second start serves on, without a second thread
            dev = FingerDevice(str(link), journal=tmp_path / f"j{name is None}").open()
            try:
                assert finger_of(dev.info.firmware) == name
            finally:
                dev.close()


def test_stroke_file_times_and_sizes_are_checked_before_anything_is_sent(tmp_path):
    """Issue 24, ninth review: a stroke file with times in milliseconds was run (a 2000 s stroke, 33 minutes of
    heated wires), refused only by the fit of its recording; 2000 strokes passed the 1000-stroke cap. Now each is
    refused by ``load_stroke_file``, before a port is opened. Control: the same plans in seconds load."""
    from bayestouch.cli.device import MAX_DEVICE_STROKES, load_stroke_file

    currents = [0.15, 0.05, 0.05]
    plan = make_plan(100)
    assert len(load_stroke_file(_stroke_file(tmp_path / "s.json", [plan]), currents)) == 1
    ms = plan._replace(time=plan.time * 1000)
    with pytest.raises(BadInput, match=r"stroke 0: 'time' puts the frames 20 s apart.*milliseconds"):
        load_stroke_file(_stroke_file(tmp_path / "ms.json", [ms]), currents)
    long = make_plan(9001, speed=1e-6)
    long = long._replace(time=np.arange(9001) * 0.1)  # 10 Hz for 900 s
    with pytest.raises(BadInput, match=r"stroke 0 lasts 900 s; at most 600 s"):
        load_stroke_file(_stroke_file(tmp_path / "long.json", [long]), currents)
    with pytest.raises(BadInput, match=rf"{MAX_DEVICE_STROKES + 1} strokes; at most {MAX_DEVICE_STROKES}"):
        load_stroke_file(_stroke_file(tmp_path / "many.json", [make_plan(2)] * (MAX_DEVICE_STROKES + 1)), currents)


def test_stroke_file_with_a_key_given_twice_is_refused(tmp_path):
    """Issue 24, ninth review: a key given twice in a stroke file silently kept the last. Control: the file
    without the repeat loads."""
    from bayestouch.cli.device import load_stroke_file

    good = _stroke_file(tmp_path / "s.json", [make_plan(10)])
    assert len(load_stroke_file(good, [0.1, 0.05, 0.05])) == 1
    text = good.read_text()
    twice = tmp_path / "twice.json"
    twice.write_text(text.replace('"depth":', '"depth": 0.0001, "depth":', 1))
    with pytest.raises(BadInput, match="the key 'depth' appears twice"):
        load_stroke_file(twice, [0.1, 0.05, 0.05])


def test_cli_recover_rebuilds_the_recording_from_a_journal(device, tmp_path, capsys):
    """Issue 24, ninth review: a killed `device run` (SIGKILL, a power cut) left its frames only in the journal,
    and nothing turned a journal into a recording. `device recover` writes the recording of the journal's complete
    strokes: on a whole journal it equals the run's own recording, variable by variable; a journal cut in the
    second stroke gives the first, marked incomplete, naming the cut one; a journal cut in the first stroke, a file
    that is no journal, and an existing --out are refused in one line (exit 2 from the CLI)."""
    from bayestouch.cli.device import run_device
    from bayestouch.hardware.device import strokes_from_journal
    from bayestouch.io.recording import read_recording

    sim, dev = device()
    dev.close()
    f = _stroke_file(tmp_path / "strokes.json", [make_plan(30), make_plan(20, depth=4e-4)])
    out, journal = tmp_path / "dev.nc", tmp_path / "kept.journal"
    argv = ["device", "run", "--port", str(tmp_path / "finger"), "--stroke-file", str(f), "--out", str(out)]
    assert run_device(_parser().parse_args([*argv, "--journal", str(journal), "--quiet"])) == 0
    rec = tmp_path / "rec.nc"
    assert run_device(_parser().parse_args(["device", "recover", str(journal), "--out", str(rec)])) == 0
    assert "2 stroke(s), 50 frames" in capsys.readouterr().out
    a, b = read_recording(out), read_recording(rec)
    assert set(a.variables) == set(b.variables)
    for name in a.variables:
        assert np.array_equal(a[name].values, b[name].values), name
    assert "incomplete" not in b.attrs and b.attrs["recovered_from"] == str(journal)
    # cut in the second stroke: the first stroke is recovered, the second named
    data = journal.read_bytes()
    frames = [m for m in read_journal(journal) if isinstance(m, pr.Frame)]
    assert len(frames) == 50
    cut = tmp_path / "cut.journal"
    cut.write_bytes(data[: int(len(data) * 0.8)])
    got = strokes_from_journal(cut)
    assert len(got.strokes) == 1 and len(got.incomplete) == 1 and "of 20 frames" in got.incomplete[0]
    rec2 = tmp_path / "rec2.nc"
    assert run_device(_parser().parse_args(["device", "recover", str(cut), "--out", str(rec2)])) == 0
    b2 = read_recording(rec2)
    assert b2.attrs["incomplete"] == "true"
    assert np.array_equal(b2["taxel_current"].values, a["taxel_current"].values[:30])
    # refusals
    (tmp_path / "first.journal").write_bytes(data[: int(len(data) * 0.3)])
    (tmp_path / "junk.journal").write_bytes(b"not a journal at all\n" * 10)
    for bad, needle in (
        (["first.journal", "r3.nc"], "no complete stroke"),
        (["junk.journal", "r4.nc"], "no packet of the finger protocol"),
        (["kept.journal", "rec.nc"], "already exists"),
        (["kept.journal", "rec.txt"], "ending in .nc"),
        (["missing.journal", "r5.nc"], "no such file"),
    ):
        with pytest.raises(BadInput, match=needle):
            run_device(
                _parser().parse_args(["device", "recover", str(tmp_path / bad[0]), "--out", str(tmp_path / bad[1])])
            )
    assert read_recording(rec)["taxel_current"].shape[0] == 50  # the existing recording untouched


def test_recover_names_every_stroke_it_leaves_out(device, tmp_path):
    """Issue 24, eleventh review: an incomplete stroke whose plan repeats an earlier complete one was taken for a
    retry and dropped without a word, and a damaged stroke command dropped its frames with exit 0. Now only a
    stroke followed at once by a command of its own plan counts as retried; a repeated stroke cut short, and the
    frames of a damaged command, are named, and the recording is marked incomplete."""
    from bayestouch.cli.device import run_device
    from bayestouch.hardware.device import strokes_from_journal
    from bayestouch.io.recording import read_recording

    sim, dev = device()
    dev.close()
    plan = make_plan(30)
    f = _stroke_file(tmp_path / "strokes.json", [plan, plan, plan])  # a repeatability run: one stroke three times
    journal = tmp_path / "kept.journal"
    argv = ["device", "run", "--port", str(tmp_path / "finger"), "--stroke-file", str(f), "--out"]
    assert (
        run_device(_parser().parse_args([*argv, str(tmp_path / "dev.nc"), "--journal", str(journal), "--quiet"])) == 0
    )
    data = journal.read_bytes()
    assert len(strokes_from_journal(journal).strokes) == 3  # the control: the whole journal
    cut = tmp_path / "cut.journal"
    cut.write_bytes(data[: int(len(data) * 0.55)])  # within the second of three equal strokes
    got = strokes_from_journal(cut)
    assert len(got.strokes) == 1 and len(got.incomplete) == 1 and "of 30 frames" in got.incomplete[0]
    # one damaged byte inside the second stroke's command: its frames arrive without it
    sids = [m.stroke_id for m in read_journal(journal) if isinstance(m, pr.StrokeCommand)]
    at = (
        data.index(
            pr.encode(
                next(m for m in read_journal(journal) if isinstance(m, pr.StrokeCommand) and m.stroke_id == sids[1]), 0
            )
        )
        + 40
    )
    damaged = tmp_path / "damaged.journal"
    damaged.write_bytes(data[:at] + bytes([data[at] ^ 0xFF]) + data[at + 1 :])
    got = strokes_from_journal(damaged)
    assert len(got.strokes) == 2 and got.damaged >= 1
    assert any("its command damaged" in x for x in got.incomplete)
    out = tmp_path / "rec.nc"
    assert run_device(_parser().parse_args(["device", "recover", str(damaged), "--out", str(out)])) == 0
    assert read_recording(out).attrs["incomplete"] == "true"


def test_a_late_result_of_an_abandoned_stroke_does_not_take_the_current_strokes_place():
    """A stroke abandoned while its frames were being computed (the watchdog tripped: a loaded machine paused the
    host for over a second) is redone under a new id while the first computation still runs; when that one ends
    last, its result must be dropped, else the redone stroke's frames are lost and the host waits out its stroke
    time-out (a CI run hung 300 s this way). White-box: the order of the two worker threads cannot be forced
    through the pty, so the device's result slot is read directly."""
    sim = VirtualDevice(Recorded())
    plan = make_plan()
    sim.stroke_id = 8  # the redone stroke is the current one
    sim._compute(plan, 1, 8)  # its frames are ready first
    sim._compute(plan, 0, 7)  # then the abandoned stroke's computation ends
    sid, res = sim._result
    assert sid == 8 and np.array_equal(res["taxel_current"], sim.model.out[1]["taxel_current"])
    sim._result = None
    sim._compute(plan, 2, 8)  # control: the current stroke's own result is kept
    assert sim._result[0] == 8
