"""The virtual finger's guarded strokes with the pad's own pose error (issue "The finger's own physics moves the
pad"): a finger whose bending constants are not those its pose estimate assumes runs its approach lines where the
bent rod puts them and reports the crossings on the lines it believes."""

from __future__ import annotations

import numpy as np
import pytest

from bayestouch.hardware.device import winkler_depth
from bayestouch.hardware.frame_models import GuardedModel
from bayestouch.hardware.safety import StrokePlan
from bayestouch.physics import pose
from bayestouch.physics.virtual import load_finger
from bayestouch.scene.objects import object_from_dict
from bayestouch.scene.surface import signed_distance

R_BALL = 0.03
THRESHOLD = 0.02
TRAVEL = 0.03


@pytest.fixture(scope="module")
def setting():
    ball = object_from_dict(
        {"object": {"name": "ball"}, "shape": {"centre_m": [0.0, 0.0, 0.0], "axes_m": [R_BALL] * 3, "n": 2.0}}
    )
    T = 40
    phi = np.linspace(0.2, 1.0, T)
    normal = np.column_stack([np.sin(phi), np.zeros(T), np.cos(phi)])
    plan = StrokePlan(np.arange(T) * 0.02, (R_BALL + 0.01) * normal, normal, 3e-4, np.array([0.15, 0.05, 0.05]))
    vf = load_finger()
    return ball, plan, vf


def test_a_finger_with_its_assumed_constants_reports_what_the_plain_model_does(setting):
    ball, plan, vf = setting
    plain = GuardedModel(ball, seed=3).probe(plan, TRAVEL, THRESHOLD, 0)
    same = GuardedModel(ball, seed=3, finger=(vf.wire, vf.rod)).probe(plan, TRAVEL, THRESHOLD, 0)
    np.testing.assert_array_equal(same["position"], plain["position"])
    np.testing.assert_array_equal(same["probe"], plain["probe"])


def test_a_finger_that_bends_otherwise_touches_off_the_believed_line(setting):
    """With no encoder error (pose_sd 0), the reported crossing moved by the chain's pose error R_j e_j lies on the
    true surface to 1 µm once the threshold's indentation is taken off: the crossing was found on the true line and
    reported on the believed one. The reported contacts themselves are a millimetre or more off the surface, with an
    error that changes little from one waypoint to the next (correlated along the stroke, unlike an encoder's noise:
    the negative control, whose points are off by the 0.3 mm sd in no order)."""
    ball, plan, vf = setting
    finger = pose.draw_finger(np.random.default_rng(4), vf.wire, vf.rod, pose.FingerSpread())
    out = GuardedModel(ball, pose_sd=0.0, finger=finger).probe(plan, TRAVEL, THRESHOLD, 0)
    assert np.all(out["probe"] == 0)
    u = -np.asarray(plan.normal)
    d_th = float(winkler_depth(THRESHOLD))
    err = pose.held_pose_error(finger, (vf.wire, vf.rod), plan.hold_currents, plan.time)
    rot = np.stack([pose.rotation_between([0.0, 0.0, 1.0], uj) for uj in u])
    moved = out["position"] + np.einsum("tij,tj->ti", rot, err) - d_th * u
    surf = ball.surface()
    assert np.max(np.abs(np.asarray(signed_distance(surf, moved)))) < 1e-6

    reported = out["position"] - d_th * u
    miss = np.linalg.norm(reported - R_BALL * plan.normal, axis=1)
    assert np.median(miss) > 1e-3
    step = np.linalg.norm(np.diff(reported - R_BALL * plan.normal, axis=0), axis=1)
    assert np.median(step) < 0.1 * np.median(miss)
    noisy = GuardedModel(ball, pose_sd=3e-4, seed=1).probe(plan, TRAVEL, THRESHOLD, 0)
    e_noise = noisy["position"] - d_th * u - R_BALL * plan.normal
    noise_step = np.median(np.linalg.norm(np.diff(e_noise, axis=0), axis=1))
    assert noise_step > 0.5 * np.median(np.linalg.norm(e_noise, axis=1))


def test_the_forward_models_guarded_strokes_carry_its_own_bending_error(setting, monkeypatch):
    """``ForwardModel`` with its ``vf`` constants replaced (what ``device simulate --bend-spread`` does) reports
    guarded strokes off by the chain's pose error; with the models' constants it reports what the plain guarded model
    does (the same crossings, the same encoder noise). Its frames are the synthetic model's here: what is checked is
    where the crossings are reported, not the taxels."""
    from bayestouch.hardware.frame_models import ForwardModel, SyntheticModel

    monkeypatch.setattr(ForwardModel, "__call__", lambda self, plan, index: SyntheticModel()(plan, index))
    ball, plan, vf = setting
    model = ForwardModel(ball, seed=3)
    plain = GuardedModel(ball, seed=3).probe(plan, TRAVEL, THRESHOLD, 0)
    same = model.probe(plan, TRAVEL, THRESHOLD, 0)
    np.testing.assert_array_equal(same["position"], plain["position"])
    finger = pose.draw_finger(np.random.default_rng(4), vf.wire, vf.rod, pose.FingerSpread())
    model.vf = model.vf._replace(wire=finger[0], rod=finger[1])
    bent = model.probe(plan, TRAVEL, THRESHOLD, 0)
    assert np.median(np.linalg.norm(bent["position"] - plain["position"], axis=1)) > 1e-3


def test_device_simulate_refuses_a_bend_spread_out_of_range(capsys):
    from bayestouch.cli.main import main

    assert main(["device", "simulate", "--bend-spread", "4", "--for", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--bend-spread must be in [0, 3]" in err[0]
