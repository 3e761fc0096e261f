"""The exploration loop drives the finger: guarded strokes on the virtual finger over a pty (real pyserial I/O).

Noise model of the checks: the virtual finger reports the pad position at the force threshold with an isotropic
Gaussian pose error of ``POSE_SD`` per coordinate (:class:`~bayestouch.hardware.simulator.GuardedModel`); the
contact's distance from the sphere it touched is then N(0, POSE_SD²) to first order (the ray distance is exact to
2⁻⁴⁰ t_max and both sides subtract the same Winkler threshold indentation, so there is no bias).
"""

from __future__ import annotations

import functools
import json
import os

import numpy as np
import pytest

from bayestouch.hardware import protocol as pr
from bayestouch.hardware.device import DeviceError, FingerDevice, ProbePlan, read_journal
from bayestouch.hardware.frame_models import GuardedModel, SyntheticModel
from bayestouch.hardware.safety import Limits, UnsafePlan, check_plan
from bayestouch.hardware.simulator import VirtualDevice
from bayestouch.planning.candidates import make_candidates, select
from bayestouch.planning.device_prober import DeviceProber
from bayestouch.scene.objects import object_from_dict

R = 0.025
POSE_SD = 3e-4
#: samples per stroke (and 3 strokes per batch) everywhere: the surface walk and the ray march compile once
T = 16


def _ball(centre=(0.0, 0.0, 0.0)):
    return object_from_dict(
        {"object": {"name": "ball"}, "shape": {"centre_m": list(centre), "axes_m": [R, R, R], "n": 2.0}}
    )


def _sphere(centre, r):
    from bayestouch.backend import jnp
    from bayestouch.geometry import nellipsoid as ne

    return ne.NEllipsoid(jnp.asarray(centre, float), jnp.full(3, r), jnp.zeros(3), jnp.asarray(2.0))


@pytest.fixture
def finger(tmp_path):
    """``start(model, limits)`` → (VirtualDevice serving ``model`` on a pty, open FingerDevice with a journal)."""
    opened = []

    def start(model, limits=None):
        sim = VirtualDevice(model, speed=0.0, limits=limits).start()
        dev = FingerDevice(sim.port, journal=tmp_path / f"finger{len(opened)}.journal", timeout=0.5).open()
        opened.append((sim, dev))
        return sim, dev

    yield start
    for sim, dev in opened:
        dev.close()
        sim.close(timeout=5.0)


def _probe_all(dev, cands):
    prober = DeviceProber(dev)
    pts = [prober.probe(select(cands, i))[0] for i in range(len(cands.force))]
    return prober, np.concatenate(pts)


def test_guarded_strokes_find_the_true_surface_not_the_believed_one(finger):
    # belief: a 3 cm sphere 2 mm off; truth: the 2.5 cm ball at the origin
    cands = make_candidates(_sphere([0.002, 0.0, 0.0], 0.03), 3, points=T, seed=0, standoff=0.025)
    _, dev = finger(GuardedModel(_ball(), pose_sd=POSE_SD, seed=1))
    prober, pts = _probe_all(dev, cands)
    assert len(pts) == 3 * T  # every approach line meets the ball inside the belief
    d = np.linalg.norm(pts, axis=1) - R
    # on the true surface within the pose noise: mean within 4 standard errors, no point beyond 4.5 sd
    # (P ≈ 48 × 6.8e-6), and the spread is the pose noise (sd of a sample sd ≈ sd/√(2n) = 0.09 sd: ±3.3 of them)
    assert abs(d.mean()) < 4 * POSE_SD / np.sqrt(len(d))
    assert np.abs(d).max() < 4.5 * POSE_SD
    assert 0.7 * POSE_SD < d.std(ddof=1) < 1.3 * POSE_SD
    # negative control: nowhere near the believed surface (the belief is ~5 mm too large)
    d_belief = np.linalg.norm(pts - [0.002, 0.0, 0.0], axis=1) - 0.03
    assert np.all(d_belief < -3e-3)
    # the recording of the strokes holds exactly these points as the contact frames' points
    ds = prober.dataset()
    assert ds.sizes["frame"] == 3 * T and np.array_equal(ds["contact_point"].values, pts)
    assert np.all(ds["contact_force"].values > 0)


def test_a_displaced_object_gives_points_off_the_original_surface(finger):
    cands = make_candidates(_sphere([0.0, 0.0, 0.0], 0.03), 3, points=T, seed=0, standoff=0.025)
    shift = np.array([0.004, 0.0, 0.0])
    _, dev = finger(GuardedModel(_ball(shift), pose_sd=POSE_SD, seed=1))
    _, pts = _probe_all(dev, cands)
    on_moved = np.linalg.norm(pts - shift, axis=1) - R
    on_original = np.linalg.norm(pts, axis=1) - R
    assert np.abs(on_moved).max() < 4.5 * POSE_SD  # where the device's object is
    # were they on the original surface, their RMS distance would be POSE_SD (± 9 %); a 4 mm shift gives
    # ≈ 4 mm × RMS(cos) ≈ 7 POSE_SD
    assert np.sqrt(np.mean(on_original**2)) > 3 * POSE_SD


def test_guarded_strokes_survive_a_disconnect_and_dropped_bytes_with_nothing_lost(tmp_path):
    from bayestouch.hardware.simulator import Faults

    cands = make_candidates(_sphere([0.0, 0.0, 0.0], 0.03), 3, points=T, seed=0, standoff=0.025)
    got = {}
    for name, faults in [("clean", None), ("faulty", Faults(drop=2e-4, disconnect_after=20, seed=3))]:
        link = tmp_path / f"finger-{name}"
        with VirtualDevice(GuardedModel(_ball(), seed=1), speed=0.0, faults=faults, link=link) as sim:
            with FingerDevice(str(link), journal=tmp_path / f"{name}.journal", timeout=0.3) as dev:
                prober, pts = _probe_all(dev, cands)
                got[name] = (pts, dict(dev.stats), dict(sim.stats))
    (clean, _, _), (faulty, dstats, sstats) = got["clean"], got["faulty"]
    assert sstats["disconnects"] == 1 and dstats["reconnects"] == 1  # the fault happened ...
    assert dstats["redone_strokes"] == 0
    np.testing.assert_array_equal(faulty, clean)  # ... and the same frames arrived: the same points
    # the journal holds every guarded frame received
    frames = [m for m in read_journal(tmp_path / "faulty.journal") if isinstance(m, pr.ProbeFrame)]
    assert len({(m.stroke_id, m.index) for m in frames}) == 3 * T


def test_unsafe_strokes_are_refused_before_anything_is_sent(finger, tmp_path):
    cands = make_candidates(_sphere([0.0, 0.0, 0.0], R), 3, points=T, seed=4, standoff=0.025)
    # the device's own limit (from the handshake) is tighter than the 0.1–0.5 N the planner draws
    sim, dev = finger(GuardedModel(_ball(), seed=1), limits=Limits(max_force=0.3))
    prober = DeviceProber(dev)
    before = dict(sim.stats)
    with pytest.raises(UnsafePlan, match="force"):
        prober.probe(select(cands._replace(force=np.array([0.45, 0.2, 0.2])), 0))
    assert sim.stats["rx_packets"] == before["rx_packets"] and len(prober.refused) == 1
    assert not any(isinstance(m, pr.ProbeStroke) for m in read_journal(dev.journal_path))
    # the next stroke runs (negative control: the same path at a safe force is sent and answered)
    pts, _ = prober.probe(select(cands._replace(force=np.array([0.45, 0.2, 0.2])), 1))
    assert len(pts) > 0 and sim.stats["rx_packets"] > before["rx_packets"]
    assert sum(isinstance(m, pr.ProbeStroke) for m in read_journal(dev.journal_path)) == 1
    # the device refuses on its own too (NAK 2), and a finger without guarded strokes answers NAK 4
    plan = prober.plan(select(cands, 1))
    bad = pr.ProbeStroke(1, 4e-3, 1.0, plan.hold_currents, plan.time, plan.start, plan.normal, 0.05, 0.02)
    rep = dev._command(bad)
    assert isinstance(rep, pr.Nak) and rep.code == 2
    _, plain = finger(SyntheticModel(rows=4, cols=4))
    with pytest.raises(DeviceError, match="guarded"):
        DeviceProber(plain).probe(select(cands, 1))


@pytest.mark.slow
def test_explore_port_drives_the_finger_and_writes_the_recording(finger, tmp_path, monkeypatch, capsys):
    from bayestouch.cli import main
    from bayestouch.io.contacts import load_contact_points
    from bayestouch.io.recording import UNITS, read_recording
    from bayestouch.planning import loop

    # 3 scout arcs and 1 planned stroke of 16 samples: 48 and 64 points, one compiled size of the log-density
    small = {"init_steps": 80, "scout": 3, "init_starts": 1, "walkers": 24, "points": T}
    monkeypatch.setattr(loop, "ExploreSettings", functools.partial(loop.ExploreSettings, **small))
    device_limits = Limits(max_force=0.3)  # about half the planned forces are unsafe on this finger
    sim, _ = finger(GuardedModel(_ball(), pose_sd=POSE_SD, seed=2), limits=device_limits)
    out = tmp_path / "explore"
    argv = ["explore", "--port", sim.port, "--centre", "0.001,0,0", "--planner", "random", "--budget", "1"]
    argv += ["--candidates", "3", "--draws", "64", "--steps", "30", "--seed", "1", "--out", str(out)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "errors unknown (no truth)" in err and "refused" in err
    assert "note: the pad's pose error is not modelled" in err  # said once, and in every summary
    assert err.count("pose error is not modelled") == 1
    hist = json.loads((out / "explore.json").read_text())
    strokes = hist["strokes"]
    assert [s["stroke"] for s in strokes] == [0, 1] and hist["object"] == "unknown (device)"
    assert all(s["chamfer"] is None and s["volume_error"] is None for s in strokes)  # NaN: no truth
    assert sum(s["refused"] for s in strokes) >= 1  # unsafe candidates met and replaced: the loop went on
    s0 = json.loads((out / "summary_0.json").read_text())
    assert "no truth" in s0["errors_note"] and s0["object"].startswith("unknown")
    assert s0["pose_error"].startswith("not modelled")
    # a second exploration into the folder is refused (its stroke summaries would mix with these)
    assert main(argv) == 2 and "already holds results" in capsys.readouterr().err
    assert json.loads((out / "summary_0.json").read_text()) == s0
    # the contacts lie on the TRUE ball (the scout's belief was a sphere of 2.5 cm 1 mm off)
    pts = load_contact_points(out / "points.csv").points
    assert len(pts) == strokes[-1]["n_points"]
    d = np.linalg.norm(pts, axis=1) - R
    assert np.abs(d).max() < 4.5 * POSE_SD  # P(any of ≤ 64 beyond 4.5 sd) ≈ 4e-4
    # nothing unsafe was ever sent: every STROKE the journal holds passes the device's limits
    sent = [m for m in read_journal(out / "device.journal") if isinstance(m, pr.ProbeStroke)]
    for m in sent:
        plan = ProbePlan(m.time, m.start, m.normal, m.depth, m.hold_currents, m.travel, m.threshold)
        check_plan(plan.stroke_plan(), device_limits)
    # the recording: the schema of `bayestouch simulate` (less its simulation-only variables), round-tripped
    ds = read_recording(out / "recording.nc")
    assert ds.sizes["stroke"] == len(sent) == 3 + 1  # the scout's three arcs and the planned stroke
    assert ds.sizes["frame"] == T * len(sent) and np.array_equal(np.unique(ds["stroke_index"]), np.arange(len(sent)))
    expected = set(UNITS) - {"taxel_current_clean", "pressure", "friction_force"}
    assert set(ds.data_vars) | (set(ds.coords) & set(UNITS)) == expected
    assert all(ds[k].attrs["units"] == UNITS[k] for k in expected)
    cp = ds["contact_point"].values
    touched = np.abs(np.linalg.norm(cp, axis=1) - R) < 5 * POSE_SD
    np.testing.assert_allclose(cp[touched], pts, rtol=0, atol=1e-9)
    depths = np.array([m.depth for m in sent])
    np.testing.assert_array_equal(ds["stroke_depth"].values, depths)


def test_explore_port_bad_inputs_are_one_line(tmp_path, capsys):
    from bayestouch.cli import main

    plain = tmp_path / "port"
    plain.write_text("")
    port = os.devnull  # a character device: the checks after the port's are reached
    cases = [
        (["--port", str(tmp_path / "nope")], "--port"),
        (["--port", str(plain)], "is a plain file, not a serial device"),
        (["--port", str(port)], "--centre"),
        (["--port", str(port), "--centre", "0,0"], "--centre"),
        (["--port", str(port), "--centre", "0,0,0", "--planner", "oracle"], "--planner"),
    ]
    for extra, field in cases:
        assert main(["explore", *extra, "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and field in err


def test_a_stuck_heater_keeps_the_guarded_stroke_it_completed(tmp_path):
    """A finger whose wires stay powered after a guarded stroke: the prober raises the heater fault (the
    exploration stops) but keeps the complete stroke, its points and its frames, in the recording it writes (before,
    the stroke was in the journal only)."""
    from bayestouch.hardware.device import HeaterFault
    from bayestouch.hardware.simulator import Faults
    from bayestouch.io.recording import read_recording

    cands = make_candidates(_sphere([0.0, 0.0, 0.0], 0.03), 2, points=T, seed=0, standoff=0.025)
    sim = VirtualDevice(GuardedModel(_ball(), pose_sd=POSE_SD, seed=1), speed=0.0, faults=Faults(stuck_heater=True))
    sim.start()
    dev = FingerDevice(sim.port, journal=tmp_path / "j.journal", timeout=0.5).open()
    try:
        prober = DeviceProber(dev, recording=tmp_path / "rec.nc")
        with pytest.raises(HeaterFault, match="heaters still on") as e:
            prober.probe(select(cands, 0))
        assert e.value.data is not None and len(e.value.data.probe) == T
        assert len(prober.strokes) == 1
        ds = read_recording(tmp_path / "rec.nc")
        assert ds.sizes["frame"] == T
        hit = e.value.data.probe == 0
        assert hit.any() and np.all(np.abs(np.linalg.norm(ds["contact_point"].values[hit], axis=1) - R) < 5 * POSE_SD)
    finally:
        dev.close()
        sim.close(timeout=5.0)


def test_explore_refuses_a_folder_holding_a_finger_recording(tmp_path, capsys):
    """A folder holding only an earlier finger run's recording and journal (its summaries gone) is an exploration
    too: refused without --overwrite, its files untouched (before, only summary_*.json counted)."""
    from bayestouch.cli import main

    out = tmp_path / "x"
    out.mkdir()
    (out / "recording.nc").write_bytes(b"frames")
    (out / "device.journal").write_bytes(b"packets")
    assert main(["explore", "--object", "sphere", "--strokes", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "already holds results" in err and "recording.nc" in err and "\n" not in err
    assert (out / "recording.nc").read_bytes() == b"frames" and (out / "device.journal").read_bytes() == b"packets"


@pytest.mark.slow
def test_explore_overwrite_moves_an_earlier_recording_aside(tmp_path, capsys):
    """--overwrite replaces the derived outputs and moves the earlier finger data aside (nothing recorded lost, and
    no stale recording beside the new run's results)."""
    from bayestouch.cli import main

    out = tmp_path / "x"
    out.mkdir()
    (out / "recording.nc").write_bytes(b"frames")
    (out / "device.journal").write_bytes(b"packets")
    (out / "summary_7.json").write_text("{}")
    argv = ["explore", "--object", "sphere", "--strokes", "1", "--candidates", "3", "--draws", "64"]
    assert main([*argv, "--steps", "30", "--out", str(out), "--overwrite"]) == 0
    assert not (out / "recording.nc").exists() and not (out / "device.journal").exists()
    assert not (out / "summary_7.json").exists() and (out / "summary_0.json").is_file()
    (aside,) = out.glob("replaced-*")
    assert (aside / "recording.nc").read_bytes() == b"frames" and (aside / "device.journal").read_bytes() == b"packets"
    assert (aside / "summary_7.json").read_text() == "{}"  # set aside too, never deleted
    assert "moved to" in capsys.readouterr().err
