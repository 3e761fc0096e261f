"""Earlier results are never written over (issue 24, fourth review): ``--overwrite`` sets them aside into
``replaced-<UTC>/``, a command refuses another command's results, and inputs are checked before a run folder is
touched; the Python API checks what the command line checks."""

from __future__ import annotations

import numpy as np
import pytest

import bayestouch as bt
from bayestouch.errors import BadInput
from bayestouch.params import MODELS

SPHERE_REC = MODELS.parent / "data" / "recordings" / "sphere.nc"


def _aside(folder, name):
    return [p / name for p in folder.glob("replaced-*") if (p / name).is_file()]


def test_simulate_and_calibrate_overwrite_set_the_earlier_file_aside(tmp_path):
    from bayestouch.api import calibrate, simulate

    out = tmp_path / "r.nc"
    simulate("sphere", strokes=1, out=out, progress=False)
    first = out.read_bytes()
    with pytest.raises(BadInput, match="already exists"):
        simulate("sphere", strokes=1, out=out, progress=False)
    simulate("sphere", strokes=1, seed=3, out=out, overwrite=True, progress=False)
    (kept,) = _aside(tmp_path, "r.nc")
    assert kept.read_bytes() == first and out.read_bytes() != first
    dev = tmp_path / "d.toml"
    calibrate(SPHERE_REC, "sphere", out=dev)
    text = dev.read_text()
    calibrate(SPHERE_REC, "sphere", out=dev, overwrite=True)
    assert [p.read_text() for p in _aside(tmp_path, "d.toml")] == [text]


def test_experiment_overwrite_sets_the_earlier_results_aside(tmp_path, monkeypatch):
    from bayestouch.planning import experiment as ex

    def fake(task):
        return [
            dict.fromkeys(ex.COLUMNS, 0.0)
            | {"planner": task["planner"], "trial": task["trial"], "object": task["object"], "stroke": s}
            | {"seed": task["seed"]}
            for s in range(task["budget"] + 1)
        ]

    monkeypatch.setattr(ex, "run_trial", fake)
    kw = dict(planners=("random",), objects=("sphere",), trials=2, budget=1, seed=0, workers=1, plot=False)
    ex.run_experiment(tmp_path, **kw, log=lambda m: None)
    first = (tmp_path / "results.csv").read_text()
    ex.run_experiment(tmp_path, **{**kw, "trials": 1}, overwrite=True, log=lambda m: None)
    (kept,) = _aside(tmp_path, "results.csv")
    assert kept.read_text() == first and (tmp_path / "results.csv").read_text() != first


def test_a_refused_calibration_leaves_the_run_folder_as_it_was(tmp_path):
    """fit REC --overwrite --calibration <a device file of the other taxel mode> set the finished run aside, then
    failed: the folder held only a run.json of a run that never started."""
    from bayestouch.io.device_file import DeviceCalibration, write_device_file

    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text('{"finished": true}')
    dev = write_device_file(
        tmp_path / "e.toml", DeviceCalibration(np.zeros(256), np.full(256, 1e-3), 1.0, "empirical", {})
    )
    with pytest.raises(BadInput, match="empirical taxel mode"):
        bt.fit(SPHERE_REC, run, calibration=dev, overwrite=True, progress=False)
    assert sorted(p.name for p in run.iterdir()) == ["summary.json"]


def test_device_run_refuses_random_stroke_options_beside_a_stroke_file():
    """--stroke-file with --depth (or --strokes, --object …) dropped them without a word; the table of those options
    holds the parser's own defaults, so an option left at its default is never taken as given."""
    from bayestouch.cli.device import RANDOM_STROKE_DEFAULTS
    from bayestouch.cli.main import build_parser

    args = build_parser().parse_args(["device", "run", "--port", "p", "--out", "r.nc"])
    assert {k: getattr(args, k) for k in RANDOM_STROKE_DEFAULTS} == RANDOM_STROKE_DEFAULTS


@pytest.mark.parametrize(
    "call,needle",
    [
        (lambda p: bt.fit(p * 1000), "span"),  # millimetres: was a scipy "upper bound less than lower bound"
        (lambda p: bt.fit(p + 1e-3j), "complex"),
        (lambda p: bt.fit(np.column_stack([p[:, :2], np.full(len(p), 0.01)])), "one plane"),
        (lambda p: bt.fit(p, seed=-1), "seed"),
        (lambda p: bt.fit(p, seed=1.7), "seed"),
        (lambda p: bt.fit(p, steps=-5), "steps"),
        (lambda p: bt.fit(p, steps=0), "steps"),
        (lambda p: bt.fit(p, budget_s=True), "budget_s"),
    ],
)
def test_the_api_fit_checks_what_the_cli_checks(call, needle):
    d = np.random.default_rng(1).normal(size=(60, 3))
    pts = np.array([0.03, 0.02, 0.015]) * d / np.linalg.norm(d, axis=1, keepdims=True)
    with pytest.raises(BadInput, match=needle):
        call(pts)


def test_a_damaged_summary_is_named_when_a_fit_is_loaded(tmp_path):
    """Fit.load on a truncated summary.json raised a bare JSONDecodeError, on {} its repr a KeyError."""
    for text, needle in [
        ('{"derived": {', "cannot be read as JSON"),
        ("{}", "not the summary of a fit"),
        ("[1]", "not"),
    ]:
        (tmp_path / "summary.json").write_text(text)
        with pytest.raises(BadInput, match=needle):
            bt.Fit.load(tmp_path)


def test_damaged_posterior_and_occupancy_files_are_named(tmp_path):
    """A truncated posterior.nc gave a raw HDF5 OSError; an occupancy grid of NaN was accepted and answered NaN;
    NaN query points were answered NaN (fourth review)."""
    from bayestouch.io.occupancy import Occupancy, load_occupancy, write_occupancy

    (tmp_path / "summary.json").write_text('{"derived": {}, "diagnostics": {}, "model": {}}')
    fit = bt.Fit.load(tmp_path)
    with pytest.raises(BadInput, match="no such file"):
        fit.idata  # noqa: B018
    (tmp_path / "posterior.nc").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 40)
    with pytest.raises(BadInput, match="cannot be read as the posterior"):
        fit.idata  # noqa: B018
    axis = np.linspace(-0.01, 0.01, 4)
    good = Occupancy(axis, axis, axis, np.full((4, 4, 4), 0.5), 10)
    write_occupancy(tmp_path / "occupancy.npz", good)
    occ = load_occupancy(tmp_path)
    assert np.allclose(occ.at(np.zeros((2, 3))), 0.5)
    for bad, needle in [(np.full((2, 3), np.nan), "NaN"), (np.zeros((2, 2)), "shape")]:
        with pytest.raises(BadInput, match=needle):
            occ.at(bad)
    write_occupancy(tmp_path / "occupancy.npz", good._replace(probability=np.full((4, 4, 4), np.nan)))
    with pytest.raises(BadInput, match="outside \\[0, 1\\]"):
        load_occupancy(tmp_path)


def test_record_strokes_refuses_strokes_the_forward_model_turns_into_nan():
    """bt.record_strokes with a NaN depth, a NaN contact, zero normals or a 5 mm depth returned NaN currents or a
    1 kN force without a word (fourth review); each is one line naming the stroke and field. Negative control: the
    stroke as drawn records finite currents."""
    egg = bt.load_object("egg")
    finger = bt.load_finger()
    st = bt.random_strokes(egg, 1, seed=0, duration=0.2)[0]
    ok = bt.record_strokes(egg, [st], finger, seed=0)
    assert np.all(np.isfinite(ok["taxel_current"]))
    c = st.contact.copy()
    c[1] = np.nan
    for bad, needle in [
        ([st._replace(depth=np.nan)], "depth"),
        ([st._replace(depth=5e-3)], "depth"),
        ([st._replace(contact=c)], "contact"),
        ([st._replace(normal=np.zeros_like(st.normal))], "normal"),
        ([st._replace(time=st.time[::-1])], "time"),
        ([], "at least one stroke"),
    ]:
        with pytest.raises(BadInput, match=needle):
            bt.record_strokes(egg, bad, finger, seed=0)


def test_public_geometry_simulate_and_explore_refuse_malformed_arguments():
    """NaN or negative semi-axes gave NaN or inside-out meshes, a negative or fractional count numpy errors, and
    simulate/explore settings raw TypeErrors, IndexErrors or emcee errors (fourth review); each is one BadInput
    naming the argument. Negative control: the well-formed shape meshes."""
    from bayestouch.geometry.nellipsoid import NEllipsoid

    good = NEllipsoid(np.zeros(3), np.array([0.03, 0.02, 0.01]), np.zeros(3), 2.5)
    v, _ = bt.nellipsoid_mesh(good, 8)
    assert np.all(np.isfinite(v))
    cases = [
        (lambda: bt.nellipsoid_mesh(good._replace(axes=np.array([np.nan, 0.02, 0.01]))), "axes"),
        (lambda: bt.nellipsoid_mesh(good._replace(axes=np.array([-0.03, 0.02, 0.01]))), "axes"),
        (lambda: bt.nellipsoid_mesh(good._replace(n=np.nan)), "n must be"),
        (lambda: bt.compare_shapes(good._replace(centre=np.array([np.nan, 0, 0])), good), "a: centre"),
        (lambda: bt.sample_surface(good, -1), "count"),
        (lambda: bt.sample_surface(good, 2.5), "count"),
        (lambda: bt.simulate(seed=-1), "seed"),
        (lambda: bt.simulate(hold_currents=0.1), "hold_currents"),
        (lambda: bt.simulate(force="0.07"), "force"),
        (lambda: bt.explore(bt.load_object("egg"), "random", 1, settings=bt.ExploreSettings(draws=0)), "draws"),
        (lambda: bt.explore(bt.load_object("egg"), "random", 1, settings=bt.ExploreSettings(steps=-1)), "steps"),
        (lambda: bt.explore(bt.load_object("egg"), "random", 1, target_volume_sd=float("nan")), "target_volume"),
    ]
    for call, needle in cases:
        with pytest.raises(BadInput, match=needle):
            call()


def test_experiment_refuses_a_folder_holding_another_commands_results(tmp_path, capsys):
    """Issue 24, ninth review: ``experiment --out`` wrote its results.csv beside a fit's summary.json and
    posterior.nc (every other command refused such a folder). Refused in one line, exit 2, nothing touched;
    ``--overwrite`` sets the other results aside (kept, not deleted) before anything runs."""
    from bayestouch.cli.explore import _check_foreign_results
    from bayestouch.cli.main import main

    out = tmp_path / "fit"
    out.mkdir()
    (out / "summary.json").write_text('{"fit": true}')
    (out / "posterior.nc").write_bytes(b"posterior")
    argv = ["experiment", "--out", str(out), "--trials", "1", "--budget", "1", "--planners", "random"]
    assert main([*argv, "--objects", "egg"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "results of another command (posterior.nc, summary.json)" in err
    assert sorted(p.name for p in out.iterdir()) == ["posterior.nc", "summary.json"]
    _check_foreign_results(out, overwrite=True)
    assert _aside(out, "summary.json") and not (out / "summary.json").exists()
    _check_foreign_results(tmp_path / "new", overwrite=False)  # the control: a new folder passes


def test_a_recording_of_presses_in_place_is_refused_before_the_run_folder(tmp_path):
    """Issue 24, ninth review: strokes whose waypoints are one point (a press in place, which ``device run``
    accepts) or a contact_point of zeros made the fit's bounds collapse: exit 1, "internal error", run.json left
    behind. Refused in one line naming the span, the folder untouched. Control: the recording as shipped passes
    the same check."""
    from bayestouch.inference.raw import run_raw_fit
    from bayestouch.inference.raw.data import check_contact_motion
    from bayestouch.io.recording import read_recording

    ds = read_recording(SPHERE_REC)
    check_contact_motion(ds, "sphere.nc")
    pressed = ds.assign(contact_point=ds.contact_point * 0 + ds.contact_point.isel(frame=0))
    with pytest.raises(BadInput, match=r"span 0 m \(the strokes press in place\)"):
        run_raw_fit(pressed, tmp_path / "fit", texture="off", progress=False)
    assert not (tmp_path / "fit").exists()
