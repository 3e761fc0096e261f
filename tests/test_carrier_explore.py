"""Exploration with carrier strokes (issue "The finger's own physics moves the pad", item 2): a planned stroke becomes
base motion and wire currents through the inverse of the bending chain, corrected by a calibrated pose-error law; the
virtual finger runs it through its own chain; a stroke stopped at the force limit keeps the frames before the stop;
the contacts come from the pad's sensed pose."""

from __future__ import annotations

import numpy as np
import pytest

from bayestouch.errors import BadInput
from bayestouch.hardware.device import FingerDevice, ForceAbort, pad_radius, winkler_force
from bayestouch.hardware.frame_models import GuardedModel
from bayestouch.hardware.simulator import VirtualDevice
from bayestouch.physics import bending, pose, sma
from bayestouch.planning.candidates import make_candidates, select
from bayestouch.planning.device_prober import CARRIER_DEPTH, VirtualFingerProber, calibrate_bending
from bayestouch.planning.experiment import calibration_object, trial_finger
from bayestouch.planning.loop import ExploreSettings, explore
from bayestouch.scene.objects import load_object
from bayestouch.scene.surface import signed_distance

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

#: a trial finger whose held pose error is millimetres (1x the constants' spread)
SEED = 1


@pytest.fixture(scope="module")
def sphere():
    return calibration_object()


@pytest.fixture(scope="module")
def finger():
    return trial_finger(SEED, 1.0)


@pytest.fixture(scope="module")
def law(sphere, finger):
    with VirtualFingerProber(sphere, seed=SEED, finger=finger) as cal:
        return calibrate_bending(cal, sphere, seed=SEED).law


def _overlap(obj, constants, prog) -> np.ndarray:
    """The pad's overlap (F,) m with the true object where the finger of ``constants`` runs ``prog``."""
    pad = pose.carrier_pad_path(*constants, prog)
    return np.asarray(pose.chain_stroke_arrays(obj.surface(), pad, pad_radius())[3])


def test_a_calibrated_program_puts_a_drawn_finger_where_the_host_means(sphere, finger, law):
    """Over a known sphere (the believed surface is the true one), the carrier plan of a stroke puts the drawn
    finger's pad at the designed overlap along the path to 0.3 mm when the calibrated law corrects the base motion;
    the same plan without the law leaves it more than 1 mm off somewhere (the control). The nominal finger on the
    uncorrected plan is at the designed overlap to 50 µm: the inverse of its own chain."""
    from bayestouch.planning.device_prober import DeviceProber

    arcs = make_candidates(sphere.shape, 2, points=20, seed=5, standoff=0.025)
    nominal = (sma.load_wire(), bending.load_rod())
    worst = {"law": 0.0, "none": 0.0, "nominal": 0.0}
    for i in range(2):
        stroke = select(arcs, i)
        on_path = slice(-20, None)  # the path's frames, after the warm-up and the approach
        for name, prober_law, who in (("law", law, finger), ("none", None, finger), ("nominal", None, nominal)):
            prog, normals = DeviceProber(None, pose_law=prober_law, carrier=True).carrier_plan(stroke)
            assert normals.shape == (len(prog.time), 3) and prog.time[-20] >= pose.HELD_WARMUP
            d = _overlap(sphere, who, prog)
            worst[name] = max(worst[name], float(np.max(np.abs(d[on_path] - CARRIER_DEPTH))))
            assert np.all(d[: -20 - 5] < -5e-3)  # clear while the wires warm
    assert worst["law"] < 3e-4, worst
    assert worst["none"] > 1e-3, worst
    assert worst["nominal"] < 5e-5, worst


def test_a_stroke_stopped_at_the_force_limit_keeps_its_frames(sphere, tmp_path):
    """A carrier program that presses ever deeper is stopped by the device at 1 N: ForceAbort carries the frames up
    to the stop (the last over the limit, the others under it) and the program cut to them; a shallow program runs
    to its end (the control). The virtual finger's force is the Winkler force of its overlap."""
    nominal = (sma.load_wire(), bending.load_rod())
    arc = make_candidates(sphere.shape, 1, points=30, seed=2, standoff=0.025)
    path, n = np.asarray(arc.path[0]), -np.asarray(arc.dirs[0])
    t = np.linspace(0.0, 3.0, 30)
    R = pad_radius()
    deeper = path - np.linspace(0.0, 2e-3, 30)[:, None] * n  # "contact" sinking 2 mm under the surface
    steep = pose.carrier_program(*nominal, deeper, n, t, 3e-4, R, currents=np.zeros((30, 3)))
    shallow = pose.carrier_program(*nominal, path, n, t, 3e-4, R, currents=np.zeros((30, 3)))
    sim = VirtualDevice(GuardedModel(sphere, seed=0), speed=0.0).start()
    try:
        with FingerDevice(sim.port, timeout=0.5) as dev:
            with pytest.raises(ForceAbort, match="contact force over 1 N") as e:
                dev.run_carrier(steep)
            done = dev.run_carrier(shallow)
    finally:
        sim.close(timeout=5.0)
    data = e.value.data
    k = len(data.device_time)
    assert 5 < k < 30 and len(data.plan.time) == k and data.pad_centre().shape == (k, 3)
    force = data.frames["contact_force"]
    assert force[-1] > 1.0 and np.all(force[:-1] <= 1.0)
    np.testing.assert_allclose(force, winkler_force(_overlap(sphere, nominal, steep)[:k]), rtol=1e-4, atol=1e-9)
    assert len(done.device_time) == 30
    np.testing.assert_allclose(done.frames["contact_force"], float(winkler_force(3e-4)), rtol=0.02)


@pytest.mark.slow
def test_carrier_exploration_touches_the_true_surface(finger, law):
    """The loop on a drawn, calibrated finger with carrier strokes: the scout is guarded (its contacts moved by the
    law's mean), the planned strokes slide; every contact lies within 1.5 mm of the true surface (the encoders'
    0.3 mm per coordinate and what the law leaves of this finger's millimetres), the carrier ones within 0.1 mm
    (median: the pad's sensed pose); a pose-error law to marginalise is refused (the contacts are sensed)."""
    egg = load_object("egg")
    settings = ExploreSettings(candidates=8, draws=200, steps=80, init_steps=150)
    with VirtualFingerProber(egg, seed=SEED, finger=finger, pose_law=law, carrier=True) as prober:
        res = explore(egg, "eig", 2, seed=SEED, settings=settings, prober=prober)
        scouts, carriers, aborted = len(prober.probes), len(prober.carriers), prober.aborted
        with pytest.raises(BadInput, match="no pose-error law"):
            prober.pose_ensemble(4)
    assert scouts == 4 and carriers == 2 and aborted <= carriers
    d = np.abs(np.asarray(signed_distance(egg.surface(), res.points)))
    n_scout = res.records[0].n_points
    assert len(res.points) > n_scout
    assert np.max(d) < 1.5e-3 and np.median(d[n_scout:]) < 1e-4, (np.max(d), np.median(d[n_scout:]))
    with pytest.raises(BadInput, match="no pose-error law"):
        with VirtualFingerProber(egg, seed=SEED, carrier=True) as prober:
            explore(egg, "eig", 1, seed=SEED, settings=settings._replace(pose_draws=4), prober=prober)
