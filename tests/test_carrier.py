"""Carrier strokes (issue "The finger's own physics moves the pad", items 1–2): a desired pad path turned into base
motion and wire currents through the inverse of the bending chain, checked on both sides, sent over the protocol
(revision 1.3), run by the virtual finger through its own chain, and recovered from a journal without them."""

from __future__ import annotations

import numpy as np
import pytest

from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.hardware import protocol as pr
from bayestouch.hardware.device import DeviceError, FingerDevice, strokes_from_journal, winkler_depth
from bayestouch.hardware.frame_models import ForwardModel, SyntheticModel
from bayestouch.hardware.safety import Limits, StrokePlan, UnsafePlan, check_carrier
from bayestouch.hardware.simulator import VirtualDevice, command_refusal
from bayestouch.physics import pose
from bayestouch.physics.virtual import load_finger
from bayestouch.planning.device_prober import PROBE_THRESHOLD, carrier_points
from bayestouch.scene.objects import SceneObject
from bayestouch.scene.strokes import random_strokes
from bayestouch.scene.surface import signed_distance

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def vf():
    return load_finger()


@pytest.fixture(scope="module")
def egg():
    """A smooth, untextured egg-like body (semi-axes 40/25/25 mm, n 2.5): the pad's closest point is unique."""
    shape = ne.NEllipsoid(np.zeros(3), np.array([0.04, 0.025, 0.025]), np.array([0.3, 0.2, 0.1]), 2.5)
    return SceneObject("smooth egg", shape)


@pytest.fixture(scope="module")
def path(egg):
    """One desired stroke over it: 5 s at 25 Hz and 4 mm/s (the wires' thermal time is seconds, so a bend
    commanded from cold develops during the stroke), 0.3 mm deep."""
    return random_strokes(egg, 1, seed=4, duration=5.0, speed=0.004, rate=25.0)[0]


def _program(vf, path, **kw):
    R = float(vf.finger.tip_radius)
    return pose.carrier_program(vf.wire, vf.rod, path.contact, path.normal, path.time, path.depth, R, **kw)


@pytest.mark.parametrize("curvature", [(0.0, 0.0), (6.0, -2.0)])
def test_the_program_puts_the_assumed_finger_on_the_desired_path(vf, egg, path, curvature):
    """Round trip through the chain: a finger with exactly the constants the program was made for touches at the
    desired contact points (to 1 µm) with the designed overlap (to 1 nm), the pad facing the surface; the wires carry
    the bend's currents. A finger drawn about those constants (the negative control: any real one) does not: its
    contacts are tenths of a millimetre away and its overlap another, where the rod bends (a cold straight rod has
    no bending constants to get wrong)."""
    prog = _program(vf, path, curvature=curvature)
    R_pad = float(vf.finger.tip_radius)
    surf = egg.surface()
    pad = pose.carrier_pad_path(vf.wire, vf.rod, prog)
    contact, _, _, depth = (np.asarray(a) for a in pose.chain_stroke_arrays(surf, pad, R_pad))
    assert np.max(np.linalg.norm(contact - path.contact, axis=1)) < 1e-6
    np.testing.assert_allclose(depth, path.depth, atol=1e-9)
    facing = pad.tangent[-1] @ -np.mean(path.normal, axis=0) / np.linalg.norm(np.mean(path.normal, axis=0))
    assert facing == pytest.approx(1.0, abs=1e-9)
    assert np.all(prog.currents == prog.currents[0]) and (np.any(prog.currents > 0.05) == any(curvature))

    w, r = pose.draw_finger(np.random.default_rng(2), vf.wire, vf.rod, pose.FingerSpread().widened(1.5))
    other = pose.carrier_pad_path(w, r, prog)
    c2, _, _, d2 = (np.asarray(a) for a in pose.chain_stroke_arrays(surf, other, R_pad))
    if any(curvature):
        assert np.median(np.linalg.norm(c2 - path.contact, axis=1)) > 1e-4
        assert np.max(np.abs(d2 - path.depth)) > 2e-5
    else:  # a cold, straight rod is as long whatever its stiffness and wires: no pose error to make
        assert np.max(np.linalg.norm(c2 - path.contact, axis=1)) < 1e-6


def test_an_explicit_program_and_a_chosen_rotation_are_kept(vf, path):
    T = len(path.time)
    cur = np.zeros((T, 3))
    cur[T // 2 :, 1] = 0.17  # the wire switched on half way: the base compensates the nominal swing
    down = np.diag([1.0, -1.0, -1.0])
    prog = _program(vf, path, currents=cur, base_rotation=down)
    np.testing.assert_array_equal(prog.currents, cur)
    np.testing.assert_array_equal(prog.base_rotation, down)
    pad = pose.carrier_pad_path(vf.wire, vf.rod, prog)
    centre = path.contact + (float(vf.finger.tip_radius) - path.depth) * path.normal
    np.testing.assert_allclose(pad.centre, centre, atol=1e-12)
    tip = pose.tip_path(vf.wire, vf.rod, cur, pose.program_dt(path.time)).tip_position
    assert np.ptp(tip[:, :2], axis=0).max() > 1e-4  # the tip did swing, so the base had something to undo


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"time": np.r_[0.0, 0.02, 0.05, 0.06]}, "evenly spaced"),
        ({"time": np.r_[0.0]}, "time: expected T ≥ 2"),
        ({"depth": 0.0}, "depth: expected"),
        ({"depth": 6e-3}, "depth: expected"),
        ({"normal": "flipped"}, "normal: expected outward unit normals"),
        ({"currents": np.zeros((3, 3))}, r"currents: expected a \(4, 3\) program"),
        ({"currents": np.full((4, 3), 0.5)}, r"within \[0, 0.2\] A"),
        ({"curvature": (40.0, 40.0)}, "beyond the finger's reach"),
        ({"base_rotation": 2 * np.eye(3)}, "base_rotation: expected an orthonormal"),
    ],
)
def test_carrier_programs_refuse_bad_input(vf, change, needle):
    T = 4
    args = {
        "contact": np.column_stack([np.linspace(0, 0.003, T), np.zeros(T), np.full(T, 0.02)]),
        "normal": np.tile([0.0, 0.0, 1.0], (T, 1)),
        "time": np.arange(T) * 0.02,
        "depth": 3e-4,
    }
    kw = {}
    for k, v in change.items():
        if k == "normal":
            args["normal"] = 2 * args["normal"]
        elif k in args:
            args[k] = v
        else:
            kw[k] = v
    with pytest.raises(BadInput, match=needle):
        pose.carrier_program(
            vf.wire, vf.rod, args["contact"], args["normal"], args["time"], args["depth"], 0.0075, **kw
        )


def _simple_program(T=20, speed=0.01, currents=0.1):
    t = np.arange(T) * 0.02
    base = np.column_stack([speed * t, np.zeros(T), np.full(T, 0.1)])
    return pose.CarrierProgram(t, base, np.diag([1.0, -1.0, -1.0]), np.tile([currents, 0.0, 0.0], (T, 1)))


@pytest.mark.parametrize(
    ("mutate", "needle"),
    [
        (lambda p: p._replace(currents=p.currents + 0.15), r"outside \[0, 0.2\] A"),
        (lambda p: p._replace(currents=p.currents * 1.9), "wire temperature would reach"),
        (lambda p: p._replace(base_position=p.base_position * 10), "base speed"),
        (lambda p: p._replace(base_rotation=np.diag([1.0, 1.0, -1.0])), "determinant"),
        (lambda p: p._replace(time=p.time[::-1].copy()), "increase strictly"),
        (lambda p: p._replace(currents=p.currents[:5]), "expected, got shapes"),
        (lambda p: p._replace(base_position=np.where(p.base_position > 0.05, np.nan, p.base_position)), "finite"),
    ],
)
def test_unsafe_carrier_plans_are_refused_on_both_sides(mutate, needle):
    """The same check in the host (before a byte is sent) and in the device (NAK 2): over-current, a wire that would
    overheat, a base too fast, a mirror for a rotation, times running back, mismatched rows, NaN."""
    good = _simple_program()
    check = check_carrier(good, Limits())
    assert check.speed == pytest.approx(0.01) and check.peak_temperature < Limits().max_temperature
    assert command_refusal(pr.CarrierStroke(1, 1.0, *good), Limits()) is None
    bad = mutate(good)
    with pytest.raises(UnsafePlan, match=needle):
        check_carrier(bad, Limits())
    assert command_refusal(pr.CarrierStroke(1, 1.0, *bad), Limits()) is not None


def test_the_device_refuses_uneven_frame_times_and_a_bad_force_limit():
    good = _simple_program()
    uneven = good._replace(time=good.time * np.linspace(1.0, 1.2, len(good.time)))
    assert "evenly spaced" in command_refusal(pr.CarrierStroke(1, 1.0, *uneven), Limits())
    assert "max_force" in command_refusal(pr.CarrierStroke(1, float("nan"), *good), Limits())


def test_carrier_stroke_round_trips_through_the_wire_format():
    prog = _simple_program(T=7)
    msg = pr.CarrierStroke(77, 0.8, *prog)
    seq, back = pr.decode_packet(pr.encode(msg, 513)[:-1])
    assert seq == 513 and isinstance(back, pr.CarrierStroke) and back.stroke_id == 77 and back.max_force == 0.8
    for name in ("time", "base_position", "base_rotation", "currents"):
        np.testing.assert_array_equal(
            getattr(back, name), np.asarray(getattr(prog, name)).reshape(getattr(back, name).shape)
        )
    assert back.base_rotation.shape == (3, 3) and back.currents.shape == (7, 3)
    assert pr.MESSAGE_TYPES[pr.CarrierStroke] == 0x09


class SyntheticCarrier(SyntheticModel):
    """The synthetic frame model with carrier strokes: the tip where the base frame's z axis ends, 60 mm out."""

    def carrier(self, program, index):
        T = len(program.time)
        plan = type("P", (), {"time": program.time, "depth": 3e-4, "hold_currents": np.asarray(program.currents)[0]})
        out = self(plan, index)
        out["wire_current"] = np.asarray(program.currents, float)
        out["finger_tip_position"] = np.tile([0.001 * index, 0.0, 0.06], (T, 1))
        return out


def _session(tmp_path, model):
    sim = VirtualDevice(model, speed=0.0, link=tmp_path / "finger").start()
    dev = FingerDevice(str(tmp_path / "finger"), journal=tmp_path / "rec.journal", timeout=0.3, retries=4).open()
    return sim, dev


def test_carrier_strokes_over_the_virtual_finger_and_the_journal(tmp_path):
    """A carrier stroke's frames arrive complete with the program's currents; the host's believed pad centre is the
    commanded base pose × the sensed tip. A frame model without carrier strokes answers NAK 4 (bad stroke). The
    journal's recovery keeps the plain strokes and sets the carrier strokes aside with their frames (they hold no
    contact points a recording could take)."""
    from tests.test_device import make_plan

    sim, dev = _session(tmp_path, SyntheticCarrier(seed=1))
    try:
        prog = _simple_program()
        data = dev.run_carrier(prog)
        plain = dev.run_stroke(make_plan(T=30))
        data2 = dev.run_carrier(prog)
    finally:
        dev.close()
        sim.close()
    np.testing.assert_allclose(data.frames["wire_current"], prog.currents, atol=1e-6)
    assert len(data.device_time) == len(prog.time) and data2.stroke_id == plain.stroke_id + 1
    expected = prog.base_position + data.frames["finger_tip_position"] @ prog.base_rotation.T
    np.testing.assert_allclose(data.pad_centre(), expected)
    assert data.pad_centre()[0, 2] == pytest.approx(0.1 - 0.06, abs=1e-6)  # the rod points down from 10 cm
    rec = strokes_from_journal(tmp_path / "rec.journal")
    assert [s.stroke_id for s in rec.strokes] == [plain.stroke_id] and not rec.incomplete
    assert rec.skipped == 2 * (1 + len(prog.time))

    (tmp_path / "b").mkdir()
    sim, dev = _session(tmp_path / "b", SyntheticModel())
    try:
        with pytest.raises(DeviceError, match="cannot run carrier strokes"):
            dev.run_carrier(prog)
    finally:
        dev.close()
        sim.close()


def test_the_virtual_finger_touches_where_its_own_chain_puts_the_pad(vf, egg, path, tmp_path):
    """End to end through the physics: a program made for the nominal constants, run by virtual fingers whose
    constants are drawn about them (spread × 1.5). The finger senses its own bend, so the host's believed pad centre
    (base × sensed tip) is the true one, millimetres from where the program meant it; the taxels feel the pad where
    the true chain put it (force only where the true overlap is). A finger that bends further presses millimetres
    deeper than planned, and the device's force abort stops it. The nominal finger on the same program presses as
    the plain stroke over the same path does. The host's contact points from the sensed pad centre and the force
    (``carrier_points``) are where the pad touched; from the program's intent alone it would have put contacts at
    frames where its pad was millimetres away and clear of the object."""
    prog = _program(vf, path, curvature=(8.0, 0.0))
    spread = pose.FingerSpread().widened(1.5)
    w, r = pose.draw_finger(np.random.default_rng(2), vf.wire, vf.rod, spread)
    deep = pose.draw_finger(np.random.default_rng(1), vf.wire, vf.rod, spread)
    model = ForwardModel(egg, seed=0, mode="empirical")
    sim, dev = _session(tmp_path, model)
    try:
        model.vf = model.vf._replace(wire=deep[0], rod=deep[1])
        with pytest.raises(DeviceError, match="contact force over 1 N"):
            dev.run_carrier(prog)
        model.vf = model.vf._replace(wire=w, rod=r)
        data = dev.run_carrier(prog)
    finally:
        dev.close()
        sim.close()
    true_pad = pose.carrier_pad_path(w, r, prog)
    np.testing.assert_allclose(data.pad_centre(), true_pad.centre, atol=1e-6)  # f4 frames
    meant = path.contact + (float(vf.finger.tip_radius) - path.depth) * path.normal
    assert np.median(np.linalg.norm(data.pad_centre() - meant, axis=1)) > 1e-3
    R_pad = float(vf.finger.tip_radius)
    depth = np.asarray(pose.chain_stroke_arrays(egg.surface(), true_pad, R_pad)[3])
    force = data.frames["contact_force"]
    assert np.any(depth > 1e-4) and np.any(depth < -2e-4)
    assert np.all(force[depth < -2e-4] < 1e-6) and np.all(force[depth > 1e-4] > 0.01)

    # the host's contacts from what it senses (pad centre, force) and believes (the planned normals): where the true
    # chain touched, to 0.15 mm
    true_contact = np.asarray(pose.chain_stroke_arrays(egg.surface(), true_pad, R_pad)[0])
    points, free = carrier_points(data, path.normal, R_pad)
    touched = force > PROBE_THRESHOLD
    assert len(points) == touched.sum() > 10 and len(free.starts) == (~touched).sum() > 10
    assert np.max(np.linalg.norm(points - true_contact[touched], axis=1)) < 1.5e-4
    # without the sensing the host would have put a contact on its path at every frame: at the clear ones its pad
    # was millimetres from there
    assert np.median(np.linalg.norm(data.pad_centre()[~touched] - meant[~touched], axis=1)) > 1e-3
    ends = free.starts + free.t_max * free.dirs  # the clear pad's front: outside, up to the threshold's indentation
    assert np.all(np.asarray(signed_distance(egg.surface(), ends)) > -float(winkler_depth(PROBE_THRESHOLD)) - 1e-6)

    fm = ForwardModel(egg, seed=0, mode="empirical")
    nominal = fm.carrier(prog, 0)
    plain = fm(StrokePlan(path.time, path.contact, path.normal, path.depth, prog.currents[0]), 0)
    assert np.median(plain["contact_force"]) > 0.05
    np.testing.assert_allclose(nominal["contact_force"], plain["contact_force"], rtol=0.05)


class OldDevice(VirtualDevice):
    """A device of revision 1.0: it drops the later commands as unknown types and never answers them."""

    def _handle(self, seq, msg, packet):
        if isinstance(msg, pr.CarrierStroke | pr.ProbeStroke):
            return
        super()._handle(seq, msg, packet)


def test_a_device_that_never_answers_the_newer_strokes_is_named(tmp_path):
    from bayestouch.hardware.device import ProbePlan

    sim = OldDevice(SyntheticCarrier(), speed=0.0, link=tmp_path / "finger").start()
    dev = FingerDevice(str(tmp_path / "finger"), timeout=0.1, retries=2).open()
    try:
        with pytest.raises(DeviceError, match=r"does not answer carrier strokes \(protocol revision 1.3\)"):
            dev.run_carrier(_simple_program())
        T = 10
        start = np.column_stack([np.linspace(0, 0.002, T), np.zeros(T), np.full(T, 0.05)])
        plan = ProbePlan(np.arange(T) * 0.02, start, np.tile([0.0, 0.0, 1.0], (T, 1)), 3e-4, np.zeros(3), 0.02, 0.02)
        with pytest.raises(DeviceError, match=r"does not answer guarded strokes \(protocol revision 1.1\)"):
            dev.run_probe(plan)
    finally:
        dev.close()
        sim.close()
