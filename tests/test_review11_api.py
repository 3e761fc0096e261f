"""Issue 24, eleventh review: functions of ``bayestouch.__all__`` given arguments of the wrong form replaced a
recording (``write_recording(..., overwrite="no")``), started fits that ran on (``run_parts_fit`` with ``steps=-1``,
``budget_s=-1``, ``walkers=-2``), ran nothing (``run_experiment(objects=())``), raised raw Python errors
(TypeError, ValueError, AttributeError) or took junk at construction (``VirtualDevice``, ``FingerDevice``); each now
refuses in one line naming the argument, before any work, and the right form passes (the control)."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import bayestouch as bt
from bayestouch.errors import BadInput


def _one_line(e) -> str:
    text = str(e.value)
    assert "\n" not in text, text
    return text


def _refused(call, needle: str) -> str:
    with pytest.raises(BadInput, match=needle) as e:
        call()
    return _one_line(e)


@pytest.fixture(scope="module")
def sphere():
    return bt.load_object("sphere")


@pytest.fixture(scope="module")
def points(sphere):
    return bt.sample_surface(sphere.shape, 40, seed=0)


def _recording(strokes: int) -> xr.Dataset:
    return xr.Dataset({"stroke_depth": ("stroke", np.full(strokes, 3e-4))})


_SWITCHES = [(k, v) for k in ("overwrite", "replace") for v in ("no", "False", 1)] + [("overwrite", None)]


@pytest.mark.parametrize("keyword,value", _SWITCHES)
def test_write_recording_switches_must_be_bools(tmp_path, keyword, value):
    """``overwrite="no"`` was truthy: the 5-stroke recording at the path was replaced by a 3-stroke one (as
    ``"False"``; ``replace``, overwrite's former name, the same)."""
    path = bt.write_recording(_recording(5), tmp_path / "w.nc")
    _refused(lambda: bt.write_recording(_recording(3), path, **{keyword: value}), f"{keyword}: expected True or False")
    assert bt.read_recording(path).sizes["stroke"] == 5  # kept, and nothing written beside it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.nc"]


def test_write_recording_controls(tmp_path):
    path = bt.write_recording(_recording(5), tmp_path / "w.nc")
    _refused(lambda: bt.write_recording(_recording(3), path, overwrite=False), "already exists and is kept")
    assert bt.read_recording(path).sizes["stroke"] == 5
    for kw in ({"overwrite": True}, {"replace": True}, {"overwrite": np.bool_(True)}):
        bt.write_recording(_recording(3), path, **kw)
        assert bt.read_recording(path).sizes["stroke"] == 3


_PARTS_JUNK = [
    ({"steps": -1}, "steps: expected an integer number of steps ≥ 1"),  # started tempering, ran on
    ({"steps": 0}, "steps: expected an integer number of steps ≥ 1"),
    ({"budget_s": -1}, "budget_s must be > 0 seconds or None"),
    ({"budget_s": float("nan")}, "budget_s must be > 0 seconds or None"),
    ({"budget_s": "60"}, "budget_s must be > 0 seconds or None"),
    ({"walkers": -2}, "walkers must be an even integer ≥ 24"),
    ({"walkers": 33}, "walkers must be an even integer ≥ 24"),
    ({"max_parts": "a"}, "max_parts: expected a number of parts from 1 to"),  # ValueError "invalid literal"
    ({"max_parts": 2.5}, "max_parts: expected a number of parts from 1 to"),
    ({"free": 5}, "free: expected free-space points as a finite \\(K, 3\\) array"),  # "cannot reshape"
    ({"free": "abc"}, "free: expected free-space points"),
    ({"priors": 5}, "priors: expected a PriorParams"),  # AttributeError _asdict
    ({"seed": -1}, "seed: expected an integer in \\[0, 2\\*\\*32\\)"),
    ({"progress": "no"}, "progress: expected True or False"),
    ({"resume": "no"}, "resume: expected True or False"),
]


@pytest.mark.parametrize(
    "kw,needle", _PARTS_JUNK, ids=[next(iter(kw)) + "=" + repr(v) for kw, _ in _PARTS_JUNK for v in kw.values()]
)
def test_run_parts_fit_refuses_bad_arguments_before_any_work(kw, needle, points, tmp_path):
    out = tmp_path / "parts"
    _refused(lambda: bt.run_parts_fit(points, out, **{"progress": False, **kw}), needle)
    assert not out.exists()  # no run.json, no smc_parts1.npz


def test_run_parts_fit_points_and_out(points, tmp_path):
    _refused(lambda: bt.run_parts_fit("abc", tmp_path / "p1"), "points: expected an \\(M, 3\\) array in metres")
    _refused(lambda: bt.run_parts_fit([["a", 1, 2]], tmp_path / "p1"), "points: expected a finite")
    _refused(lambda: bt.run_parts_fit(points, None), "out: expected a path")
    assert not (tmp_path / "p1").exists()


def test_run_parts_fit_control_good_arguments_pass_every_check(points, tmp_path):
    """Good values of every checked argument reach the last check (an impossible ``parts``), so none is refused."""
    from bayestouch.inference.contact import load_priors

    good = dict(
        seed=3,
        walkers=64,
        steps=10,
        budget_s=5.0,
        free=np.array([[0.1, 0.0, 0.0]]),
        priors=load_priors(),
        progress=False,
        resume=False,
        overwrite=False,
    )
    _refused(lambda: bt.run_parts_fit(points, tmp_path / "p", parts=99, **good), "parts: expected 'auto'")
    for free in (None, [], np.empty((0, 3))):  # no free-space points
        _refused(lambda free=free: bt.run_parts_fit(points, tmp_path / "p", parts=99, free=free), "parts:")
    for budget in (None, 1, np.float64(2.5)):
        _refused(lambda budget=budget: bt.run_parts_fit(points, tmp_path / "p", parts=99, budget_s=budget), "parts:")
    assert not (tmp_path / "p").exists()


def test_fit_and_run_contact_fit_share_the_budget_and_free_checks(points, tmp_path):
    """One home for each check: ``bt.fit``'s budget message (with 'auto'), and ``run_contact_fit``, which took
    ``budget_s=-1`` and gave a raw reshape error for ``free=5``."""
    from bayestouch.inference.contact import check_free
    from bayestouch.inference.run import check_budget

    _refused(lambda: bt.fit(points, budget_s=-1), "budget_s must be > 0 seconds, 'auto' or None")
    _refused(lambda: bt.run_contact_fit(points, tmp_path / "c", budget_s=-1), "budget_s must be > 0 seconds or None")
    _refused(
        lambda: bt.run_contact_fit(points, tmp_path / "c", free=5), "free: expected free-space points .* got int 5"
    )
    _refused(lambda: bt.fit(points, free=[[0, 0]]), "free: expected free-space points .* got shape \\(1, 2\\)")
    assert not (tmp_path / "c").exists()
    check_budget("auto", auto=True)  # controls
    check_budget(None)
    check_budget(30)
    _refused(lambda: check_budget("auto"), "budget_s must be > 0 seconds or None")
    assert check_free(None) is None and check_free([]).shape == (0, 3)
    assert check_free([[1, 2, 3]]).tolist() == [[1.0, 2.0, 3.0]]


def test_explore_refuses_callbacks_probers_truths_and_centres_of_the_wrong_form(sphere):
    for kw, needle in (
        ({"centre": "a"}, "centre must be a \\(3,\\) array .* of numbers, got str 'a'"),  # ValueError from float()
        ({"centre": (0.0, 0.0, "a")}, "centre must be a \\(3,\\) array"),
        ({"centre": (1.0, 2.0)}, "centre must be a \\(3,\\) array .*, got shape \\(2,\\)"),
        ({"centre": (0.0, 0.0, np.nan)}, "centre must be finite"),
        ({"on_stroke": 5}, "on_stroke: expected a function"),  # "'int' object is not callable" after the scout
        ({"prober": 5}, "prober: expected an object with a probe\\(stroke, rng\\) method"),  # AttributeError probe
        ({"truth": 5}, "truth: expected a Truth"),  # AttributeError mesh
    ):
        _refused(lambda kw=kw: bt.explore(sphere, "random", 1, **kw), needle)


def test_explore_control_good_callbacks_prober_and_truth_pass(sphere):
    """The right forms pass their checks: the call goes on to the centre's (given bad here, so nothing runs)."""
    from bayestouch.planning.loop import RayProber, truth_of

    good = dict(on_stroke=lambda rec: None, prober=RayProber(sphere, 1e-4), truth=truth_of(sphere))
    _refused(lambda: bt.explore(sphere, "random", 1, centre=(0.0, 0.0, "a"), **good), "centre must be")
    _refused(lambda: bt.explore(sphere, "random", 1, centre=[0.0, 0.0], **good), "centre must be")


def test_run_demo_refuses_sizes_and_out_before_any_work(tmp_path):
    from bayestouch.demo import QUICK

    for kw, needle in (
        ({"sizes": 5}, "sizes: expected a DemoSizes"),  # AttributeError budget, after the folder was made
        ({"sizes": QUICK._replace(budget=-1)}, "sizes.budget: expected an integer ≥ 1"),
        ({"sizes": QUICK._replace(fit_budget_s=0.0)}, "sizes.fit_budget_s: expected a number of seconds > 0"),
        ({"progress": "no"}, "progress: expected True or False"),
        ({"check_browser": "no"}, "check_browser: expected True or False"),
    ):
        _refused(lambda kw=kw: bt.run_demo(tmp_path / "demo", **kw), needle)
    assert not (tmp_path / "demo").exists()
    _refused(lambda: bt.run_demo(None), "out: expected a path")  # a TypeError from pathlib
    # control: QUICK passes, and the call goes on to the object (given bad here, so nothing runs)
    _refused(lambda: bt.run_demo(tmp_path / "demo2", sizes=QUICK, object_path=tmp_path / "none.toml"), "none.toml")


def test_run_experiment_objects_log_and_plot(tmp_path):
    for kw, needle in (
        ({"objects": 5}, "objects: expected object names or TOML paths"),  # "'int' object is not iterable"
        ({"objects": ()}, "objects: expected at least one object"),  # ran 0 and wrote an empty results.csv
        ({"objects": []}, "objects: expected at least one object"),
        ({"objects": ","}, "objects: expected at least one object"),
        ({"objects": [5]}, "objects: expected object names or TOML paths"),
        ({"planners": 5}, "planners: expected a list of planners"),
        ({"log": 5}, "log: expected a function"),  # "'int' object is not callable" once the trials ran
        ({"plot": "no"}, "plot: expected True or False"),  # taken as True
    ):
        _refused(lambda kw=kw: bt.run_experiment(tmp_path / "e", workers=1, **kw), needle)
    assert not (tmp_path / "e").exists()
    # controls: a list, a tuple or the command line's string of objects, a log function and plot=False pass every
    # check before the trials' (given bad here, so nothing runs)
    for objects in (["sphere"], ("sphere", "egg"), "sphere,egg"):
        _refused(
            lambda objects=objects: bt.run_experiment(
                tmp_path / "e", objects=objects, log=print, plot=False, trials=0, workers=1
            ),
            "trials: expected an integer ≥ 1",
        )
    assert not (tmp_path / "e").exists()


def test_paths_of_meshes_and_reports(tmp_path):
    import trimesh

    from bayestouch.io.meshes import write_spread_mesh

    _refused(lambda: bt.read_spread_mesh(5), "path: expected a path")  # TypeError from pathlib
    _refused(lambda: bt.read_spread_mesh(None), "path: expected a path")
    _refused(lambda: bt.read_spread_mesh(tmp_path), "is a folder, not a file")  # was "no such mesh file"
    _refused(lambda: bt.read_spread_mesh(tmp_path / "none.ply"), "no such file")
    _refused(lambda: bt.write_report(None, title="t", intro="x", sections=[]), "out: expected a path")
    mesh = trimesh.creation.box()  # controls
    path = write_spread_mesh(tmp_path / "m.ply", mesh, np.arange(len(mesh.vertices), dtype=float))
    assert bt.read_spread_mesh(str(path)).vertex_attributes["spread"].tolist() == list(range(len(mesh.vertices)))
    assert bt.write_report(tmp_path, title="t", intro="x", sections=[]).name == "report.html"


def test_virtual_device_checks_its_arguments_when_made(tmp_path):
    from bayestouch.hardware.frame_models import SyntheticModel
    from bayestouch.hardware.safety import Limits

    for args, kw, needle in (
        ((5,), {}, "model: expected a frame model"),
        ((lambda plan, index: {},), {}, "model: expected a frame model .* rows, cols, taxel_uv, reference"),
        ((None,), {"limits": 5}, "limits: expected a Limits"),
        ((None,), {"limits": Limits(max_force=-1.0)}, "limits.max_force: expected a finite number > 0"),
        ((None,), {"limits": Limits(max_waypoints=2.5)}, "limits.max_waypoints: expected an integer ≥ 1"),
        ((None,), {"link": 5}, "link: expected a path"),
        ((None,), {"faults": 5}, "faults: expected a Faults"),
    ):
        _refused(lambda args=args, kw=kw: bt.VirtualDevice(*args, **kw), needle)
    sim = bt.VirtualDevice(None)  # a model set later is checked when the device starts, before any pty opens
    sim.model = 5
    _refused(sim.start, "model: expected a frame model")
    assert sim.port is None
    # controls: made (no pty is opened until open or start)
    sim = bt.VirtualDevice(SyntheticModel(), limits=Limits(watchdog=0.3), link=tmp_path / "finger", speed=0.0)
    assert sim.limits.watchdog == 0.3 and sim.port is None and not (tmp_path / "finger").exists()
    assert bt.VirtualDevice(None).limits == Limits()


def test_finger_device_checks_its_arguments_when_made(tmp_path):
    from bayestouch.hardware.safety import Limits

    for args, kw, needle in (
        ((5,), {}, "--port: expected a serial port path or a pyserial URL .* got 5"),
        (("loop://",), {"retries": -1}, "retries: expected an integer number of sends ≥ 1"),
        (("loop://",), {"retries": "3"}, "retries: expected an integer"),
        (("loop://",), {"reconnects": -1}, "reconnects: expected an integer number of attempts ≥ 0"),
        (("loop://",), {"redo": 1.5}, "redo: expected an integer"),
        (("loop://",), {"baudrate": 0}, "baudrate: expected an integer number of bits per second ≥ 1"),
        (("loop://",), {"reconnect_wait": -1}, "reconnect_wait: expected a number of seconds ≥ 0"),
        (("loop://",), {"handshake": "no"}, "handshake: expected True or False"),
        (("loop://",), {"limits": 5}, "limits: expected a Limits"),
        (("loop://",), {"journal": tmp_path}, "journal .* is a folder; expected a file name"),
        (("loop://",), {"journal": 5}, "journal: expected a path"),
        (("loop://",), {"segment": "a"}, "--segment: expected 0 \\(whole packets\\)"),
    ):
        _refused(lambda args=args, kw=kw: bt.FingerDevice(*args, **kw), needle)
    dev = bt.FingerDevice(  # control: made, not connected
        "loop://",
        retries=1,
        reconnects=0,
        redo=0,
        baudrate=9600,
        reconnect_wait=0,
        handshake=False,
        limits=Limits(max_force=0.5),
        journal=tmp_path / "j.journal",
        segment=0,
    )
    assert dev.retries == 1 and dev.client_limits.max_force == 0.5 and not (tmp_path / "j.journal").exists()
    assert bt.FingerDevice("loop://").client_limits == Limits()


def test_refine_ffd_names_its_margin(sphere, points):
    for margin in (float("nan"), -0.1, "a", None):
        _refused(
            lambda margin=margin: bt.refine_ffd(sphere.shape, points, (2, 2, 2), margin=margin), "margin: expected"
        )
    fit, verts, faces = bt.refine_ffd(sphere.shape, points, (2, 2, 2), res=6, margin=0.0, max_iter=2)  # control
    assert verts.shape[1] == 3 and len(faces)


# every function of the review's finding 6, with one argument of the wrong form: a one-line BadInput
_JUNK = [
    ("write_recording", lambda o, t: bt.write_recording(_recording(1), t / "x.nc", overwrite="no")),
    ("run_parts_fit", lambda o, t: bt.run_parts_fit(bt.sample_surface(o.shape, 20, seed=0), t / "p", steps=-1)),
    ("explore", lambda o, t: bt.explore(o, "random", 1, on_stroke=5)),
    ("run_demo", lambda o, t: bt.run_demo(t / "d", sizes=5)),
    ("run_experiment", lambda o, t: bt.run_experiment(t / "e", objects=())),
    ("read_spread_mesh", lambda o, t: bt.read_spread_mesh(5)),
    ("write_report", lambda o, t: bt.write_report(None, title="t", intro="x", sections=[])),
    ("VirtualDevice", lambda o, t: bt.VirtualDevice(5)),
    ("FingerDevice", lambda o, t: bt.FingerDevice("loop://", retries=-1)),
    ("refine_ffd", lambda o, t: bt.refine_ffd(o.shape, np.zeros((5, 3)), (2, 2, 2), margin=float("nan"))),
]


@pytest.mark.parametrize("name,call", _JUNK, ids=[n for n, _ in _JUNK])
def test_every_listed_function_refuses_junk_in_one_line(name, call, sphere, tmp_path):
    assert name in bt.__all__
    with pytest.raises(BadInput) as e:
        call(sphere, tmp_path)
    _one_line(e)
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # refused before anything was written
