"""The host's law of the pad's pose error in the exploration loop (issue "The finger's own physics moves the pad",
item 3): fingers drawn about the host's bending constants run the guarded strokes' held currents
(:func:`bayestouch.physics.pose.held_error_ensemble`), the prober turns their tip errors into errors at its
contacts (:meth:`bayestouch.planning.device_prober.DeviceProber.pose_ensemble`) and the loop marginalises them
(``ExploreSettings.pose_draws``)."""

from __future__ import annotations

import numpy as np
import pytest

from bayestouch.errors import BadInput
from bayestouch.hardware.device import ProbeData, ProbePlan, winkler_depth
from bayestouch.hardware.frame_models import GuardedModel
from bayestouch.hardware.safety import StrokePlan
from bayestouch.physics import pose
from bayestouch.physics.virtual import load_finger
from bayestouch.planning.device_prober import DeviceProber, probe_points
from bayestouch.planning.loop import ExploreSettings, explore
from bayestouch.scene.objects import object_from_dict
from bayestouch.scene.surface import signed_distance

R_BALL = 0.025
THRESHOLD = 0.02
TRAVEL = 0.03
HOLD = np.array([0.15, 0.05, 0.05])
SMALL = {"candidates": 16, "draws": 128, "steps": 100, "init_steps": 200, "scout": 3, "init_starts": 1}


def _ball():
    return object_from_dict(
        {"object": {"name": "ball"}, "shape": {"centre_m": [0.0, 0.0, 0.0], "axes_m": [R_BALL] * 3, "n": 2.0}}
    )


@pytest.fixture(scope="module")
def nominal():
    vf = load_finger()
    return vf.wire, vf.rod


def _plan(phi0: float, azimuth: float, T: int = 24, duration: float = 1.5) -> ProbePlan:
    """A guarded stroke over the ball: approaches along −normal from 1 cm outside, normals sweeping polar angle."""
    phi = np.linspace(phi0, phi0 + 0.8, T)
    normal = np.column_stack([np.sin(phi) * np.cos(azimuth), np.sin(phi) * np.sin(azimuth), np.cos(phi)])
    return ProbePlan(np.linspace(0.0, duration, T), (R_BALL + 0.01) * normal, normal, 3e-4, HOLD, TRAVEL, THRESHOLD)


def _probe(model: GuardedModel, plan: ProbePlan, index: int) -> ProbeData:
    """What a FingerDevice returns for ``plan`` run on ``model`` (without the serial line)."""
    out = model.probe(
        StrokePlan(plan.time, plan.start, plan.normal, plan.depth, plan.hold_currents), TRAVEL, THRESHOLD, index
    )
    frames = {k: v for k, v in out.items() if k not in ("probe", "travel", "position")}
    return ProbeData(plan, frames, plan.time.copy(), index, out["probe"], out["travel"], out["position"])


def test_held_ensemble_is_each_drawn_fingers_held_pose_error(nominal):
    """The ensemble's k-th member is the error of the k-th finger the same seed draws as the virtual finger itself
    computes it (:func:`held_pose_error`), for strokes of other durations and frame rates too (one compiled chain
    serves them, and the chain's step is its own, not the frames' interval)."""
    wire, rod = nominal
    spread = pose.FingerSpread()
    rng = np.random.default_rng(11)
    fingers = [pose.draw_finger(rng, wire, rod, spread) for _ in range(2)]
    for duration, T in ((1.5, 24), (2.3, 31)):
        t = np.linspace(0.0, duration, T)
        ens = pose.held_error_ensemble(wire, rod, HOLD, t, spread=spread, draws=2, seed=11)
        assert ens.shape == (2, T, 3)
        for k, f in enumerate(fingers):
            ref = pose.held_pose_error(f, (wire, rod), HOLD, t)
            size = np.max(np.linalg.norm(ref, axis=1))
            assert size > 5e-4  # a millimetre-scale error, not a trivially small one
            np.testing.assert_allclose(ens[k], ref, rtol=0, atol=1e-9)
        # the fingers differ from one another: the members are not one curve
        assert np.max(np.linalg.norm(ens[0] - ens[1], axis=1)) > 1e-4


def test_held_ensemble_of_a_spread_of_nothing_is_zero(nominal):
    """Fingers drawn with no spread are the nominal one: every error is zero (the host's own chain against itself)."""
    wire, rod = nominal
    none = pose.FingerSpread(0.0, (wire.prestrain, wire.prestrain), 0.0, (1.0, 1.0), 0.0)
    ens = pose.held_error_ensemble(wire, rod, HOLD, np.linspace(0.0, 1.5, 24), spread=none, draws=2)
    np.testing.assert_allclose(ens, 0.0, atol=1e-12)


def test_held_ensemble_refuses_bad_input_naming_the_field(nominal):
    wire, rod = nominal
    for kw, needle in (
        ({"time": np.array([0.0, 1.0, 0.5])}, "time"),
        ({"time": np.zeros((2, 2))}, "time"),
        ({"draws": 1}, "draws"),
        ({"dt": 0.5}, "dt"),
        ({"hold_currents": [0.15, 0.05, 9.0]}, "current"),
    ):
        args = {"time": np.linspace(0.0, 1.0, 5), "hold_currents": HOLD, **kw}
        with pytest.raises(BadInput, match=needle) as e:
            pose.held_error_ensemble(wire, rod, args.pop("hold_currents"), args.pop("time"), **args)
        assert "\n" not in str(e.value)


def test_the_probers_law_holds_the_fingers_own_error_at_its_contacts(nominal):
    """A virtual finger whose constants are the k-th that the law draws (no encoder noise): its recorded contacts
    moved by the law's k-th member lie on the true ball to 1 µm, while as recorded they are a millimetre and more
    off (the negative control), and moved by any other member they stay off. Contacts, labels and times line up with
    what ``probe`` returned, stroke after stroke, a miss contributing nothing."""
    wire, rod = nominal
    ball, surf = _ball(), _ball().surface()
    draws, seed, k = 6, 5, 4
    rng = np.random.default_rng(seed)
    finger = [pose.draw_finger(rng, wire, rod) for _ in range(draws)][k]
    model = GuardedModel(ball, pose_sd=0.0, finger=finger, assumed=nominal)
    prober = DeviceProber(device=None, constants=nominal)
    plans = [_plan(0.1, 0.0), _plan(0.9, 2.0, T=18, duration=2.4), _plan(0.5, 4.0)]
    plans[2] = plans[2]._replace(start=plans[2].start + 0.2)  # far off: every approach misses
    points = []
    for i, plan in enumerate(plans):
        data = _probe(model, plan, i)
        prober.probes.append(data)
        points.append(probe_points(data, float(winkler_depth(THRESHOLD)))[0])
    pts = np.concatenate(points)
    assert len(points[2]) == 0 and len(points[0]) == 24 and len(points[1]) == 18
    ens, labels, times = prober.pose_ensemble(draws, seed=seed)
    assert ens.shape == (draws, len(pts), 3)
    np.testing.assert_array_equal(labels, np.repeat([0, 1], [24, 18]))
    np.testing.assert_allclose(times, np.concatenate([plans[0].time, plans[1].time]))
    off = np.abs(np.asarray(signed_distance(surf, pts)))
    fixed = np.abs(np.asarray(signed_distance(surf, pts + ens[k])))
    others = [np.median(np.abs(np.asarray(signed_distance(surf, pts + e)))) for j, e in enumerate(ens) if j != k]
    assert np.median(off) > 1e-3
    assert np.max(fixed) < 1e-6
    assert min(others) > 1e-5


def test_pose_draws_settings_and_misuse_are_refused_in_one_line(tmp_path, capsys):
    """pose_draws is 0 or ≥ 2 fingers; the offset is a sd in metres; a prober without a pose law (the simulated
    rays) is refused by the loop, the experiment and the CLI."""
    from bayestouch.cli.main import main
    from bayestouch.planning.experiment import run_experiment

    for kw, needle in (
        ({"pose_draws": 1}, "settings.pose_draws"),
        ({"pose_draws": -2}, "settings.pose_draws"),
        ({"pose_draws": 2.5}, "settings.pose_draws"),
        ({"pose_offset_sd": -1e-3}, "settings.pose_offset_sd"),
        ({"pose_offset_sd": float("nan")}, "settings.pose_offset_sd"),
    ):
        with pytest.raises(BadInput, match=needle) as e:
            ExploreSettings(**kw)
        assert "\n" not in str(e.value)
    with pytest.raises(BadInput, match="settings.pose_draws: the prober \\(RayProber\\)"):
        explore(_ball(), "eig", 1, settings=ExploreSettings(pose_draws=4))
    with pytest.raises(BadInput, match="use it with prober 'finger'"):
        run_experiment(
            tmp_path / "x", planners=("eig",), objects=("sphere",), trials=1, budget=1, settings={"pose_draws": 4}
        )
    assert not (tmp_path / "x").exists()
    for argv, needle in (
        (["explore", "--pose-draws", "8"], "--pose-draws applies to a finger on --port"),
        (["explore", "--pose-draws", "1"], "--pose-draws must be 0 or an integer from 2"),
        (["explore", "--pose-offset-sd", "0.001"], "--pose-offset-sd applies with --pose-draws"),
        (["experiment", "--pose-draws", "8"], "use it with prober 'finger'"),
    ):
        assert main([*argv, "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], err


@pytest.mark.slow
def test_the_loop_with_the_pose_law_covers_a_finger_that_bends_otherwise():
    """Exploration through a virtual finger whose constants are drawn at the host's stated spread: the loop that
    marginalises the law holds the true volume within 1.645 of its sds; the same strokes fitted with the encoder's
    noise only (the negative control) put it many sds away. Ball, eig, 2 planned strokes."""
    from bayestouch.planning.device_prober import VirtualFingerProber
    from bayestouch.planning.loop import truth_of

    wire, rod = load_finger().wire, load_finger().rod
    ball = _ball()
    truth = truth_of(ball)
    finger = pose.draw_finger(np.random.default_rng(3), wire, rod)
    z = {}
    for draws in (0, 16):
        with VirtualFingerProber(ball, seed=3, finger=finger) as prober:
            res = explore(ball, "eig", 2, seed=3, settings=ExploreSettings(**SMALL, pose_draws=draws), prober=prober)
        last = res.records[-1]
        z[draws] = (last.volume_mean - truth.volume) / last.volume_sd
        assert res.ensemble.shape[1] == (12 if draws else 11)
        if draws:
            assert "pose_scale" in last.summary["parameters"]
    assert abs(z[16]) < 1.645
    assert abs(z[0]) > 4


@pytest.fixture(scope="module")
def posterior_law(nominal):
    """A small prior law (12 fingers, 4 components, 1 s) given a posterior of its components."""
    from bayestouch.inference.held_law import prior_held_law

    law = prior_held_law(*nominal, HOLD, 1.0, draws=12, seed=3, rank=4)
    chol = np.array([[0.5, 0, 0, 0], [0.2, 0.3, 0, 0], [0, 0.1, 0.4, 0], [0.1, 0, 0, 0.2]])
    return law._replace(z_mean=np.array([0.8, -0.4, 0.2, 0.0]), z_chol=chol)


def test_calibration_approaches_are_tilted_from_the_normal_in_turning_directions():
    """Every approach of a calibration stroke meets the known sphere at its arc point, tilted by the set angle from
    the inward normal, and the tilt's direction turns along the stroke (not one side throughout)."""
    from bayestouch.planning.device_prober import calibration_strokes

    ball = _ball()
    s = calibration_strokes(ball, 3, seed=2, tilt=0.5)
    n = s.path / np.linalg.norm(s.path, axis=-1, keepdims=True)  # the ball's outward normals
    np.testing.assert_allclose(np.sum(-s.dirs * n, axis=-1), np.cos(0.5), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(s.starts + 0.025 * s.dirs - s.path, axis=-1), 0.0, atol=1e-12)
    side = s.dirs + np.cos(0.5) * n
    turn = np.sum(side[:, 1:] * side[:, :-1], axis=-1) / np.sin(0.5) ** 2
    assert np.max(np.abs(turn)) < 0.2  # a quarter turn between waypoints
    with pytest.raises(BadInput, match="tilt"):
        calibration_strokes(ball, 1, tilt=2.0)


def test_law_members_follow_the_laws_posterior(posterior_law):
    """Members drawn from a conditioned law have the law's mean and covariance in its leading components (to the
    Monte Carlo error of 4000 members: means to 0.1 sd, variances to 10 %)."""
    from bayestouch.inference.held_law import law_members

    law = posterior_law
    m = law_members(law, 4000, seed=1)
    assert m.shape == (4000, len(law.grid), 3)
    L = law.lead.reshape(-1, law.lead.shape[2])
    dev = (m - law.mean).reshape(len(m), -1)
    z = np.linalg.lstsq(L, dev.T, rcond=None)[0].T
    cov = law.z_chol @ law.z_chol.T
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(z.mean(axis=0) - law.z_mean) < 0.1 * sd)
    np.testing.assert_allclose(np.var(z, axis=0), np.diag(cov), rtol=0.1)


def test_a_calibrated_law_is_refused_where_it_does_not_apply(posterior_law):
    """A law calibrated at other hold currents, or strokes longer than its span, are refused in one line; an
    experiment asked to calibrate without marginalising the law is refused before anything runs."""
    from bayestouch.planning.experiment import run_experiment

    law = posterior_law
    with pytest.raises(BadInput, match="pose_law: calibrated at hold currents"):
        DeviceProber(device=None, hold_currents=(0.1, 0.1, 0.1), pose_law=law)
    prober = DeviceProber(device=None, pose_law=law)
    long = _plan(0.1, 0.0, duration=law.grid[-1] + 1.0)
    prober.probes.append(_probe(GuardedModel(_ball(), pose_sd=0.0), long, 0))
    with pytest.raises(BadInput, match="pose_law: covers strokes of up to"):
        prober.pose_ensemble(8)
    with pytest.raises(BadInput, match="bend_calibration: the calibrated pose-error law needs settings pose_draws"):
        run_experiment("unused", planners=("eig",), objects=("sphere",), prober="finger", bend_calibration=True)
