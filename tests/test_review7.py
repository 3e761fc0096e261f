"""Fixes from the seventh adversarial review of issue 24 (nothing lost, nothing silently wrong): an interrupted
run's tempering, a command's own inputs in its output folder, an existing contact file, two device runs into one
recording, an experiment's switches and settings, a stroke longer than one loop."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bayestouch.cli.args import check_out
from bayestouch.errors import BadInput
from bayestouch.io.contacts import load_contact_points, save_contact_points
from bayestouch.io.runfolder import fingerprint, locked_output_file, prepare_run_folder, release_run_folder
from bayestouch.planning.experiment import run_experiment
from bayestouch.scene.objects import load_object
from bayestouch.scene.strokes import random_strokes


def test_an_interrupted_runs_tempering_is_a_run(tmp_path):
    """A folder holding only run.json and smc.npz (a fit killed after its SMC) is refused without --resume or
    --overwrite (a fresh start deleted smc.npz without a word); --overwrite sets it aside."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "smc.npz").write_bytes(b"finished tempering")
    fp = fingerprint("contact", {"points": np.zeros((3, 3))}, {"seed": 0})
    with pytest.raises(BadInput, match=r"already holds a run \(smc.npz\)"):
        prepare_run_folder(out, fp, resume=False)
    release_run_folder(out)
    assert (out / "smc.npz").read_bytes() == b"finished tempering"
    prepare_run_folder(out, fp, resume=False, overwrite=True)
    release_run_folder(out)
    assert not (out / "smc.npz").exists()
    (aside,) = out.glob("replaced-*")
    assert (aside / "smc.npz").read_bytes() == b"finished tempering"


def test_overwrite_leaves_the_commands_own_inputs_in_place(tmp_path):
    """texture-id --library or reproduce-paper --object kept in --out: --overwrite sets the earlier results aside
    but not the input the new run reads."""
    out = tmp_path / "t"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    (out / "results.csv").write_text("a\n1\n")
    (out / "lib.toml").write_text("# library")
    check_out(out, True, "texture-id", inputs=(out / "lib.toml", None))
    assert (out / "lib.toml").read_text() == "# library"
    assert not (out / "summary.json").exists() and not (out / "results.csv").exists()
    (aside,) = out.glob("replaced-*")
    assert sorted(p.name for p in aside.iterdir()) == ["results.csv", "summary.json"]


def test_an_existing_contact_file_is_not_replaced_without_overwrite(tmp_path):
    path = save_contact_points(tmp_path / "mine.csv", np.arange(60.0).reshape(20, 3) * 1e-3)
    before = path.read_bytes()
    with pytest.raises(BadInput, match="already exists; pass overwrite=True"):
        save_contact_points(path, np.zeros((20, 3)))
    assert path.read_bytes() == before
    with pytest.raises(BadInput, match="overwrite: expected True or False"):
        save_contact_points(path, np.zeros((20, 3)), overwrite="yes")
    save_contact_points(path, np.ones((20, 3)) * 1e-3 * np.arange(20)[:, None], overwrite=True)
    assert len(load_contact_points(path).points) == 20 and path.read_bytes() != before


def test_a_second_writer_of_one_recording_is_refused(tmp_path):
    """Another process holding the output file (a device run) refuses this one in one line naming its pid; the
    lock file goes when the holder ends, and the file is free again."""
    out = tmp_path / "cc.nc"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from bayestouch.io.runfolder import locked_output_file\n"
            f"with locked_output_file({str(out)!r}):\n    print('held', flush=True); time.sleep(30)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(BadInput, match=rf"being written by another bayestouch run \(pid {holder.pid}\)"):
            with locked_output_file(out):
                pass
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    time.sleep(0.1)
    with locked_output_file(out):  # a killed holder's lock goes with it
        pass
    assert not any(p.name.endswith(".bayestouch.lock") for p in tmp_path.iterdir())


def test_experiment_switches_and_settings_are_checked_before_the_folder(tmp_path):
    out = tmp_path / "exp"
    with pytest.raises(BadInput, match="overwrite: expected True or False"):
        run_experiment(out, planners=["random"], objects=["sphere"], trials=1, budget=1, overwrite="no")
    with pytest.raises(BadInput, match="resume: expected True or False"):
        run_experiment(out, planners=["random"], objects=["sphere"], trials=1, budget=1, resume="no")
    with pytest.raises(BadInput, match="workers: expected an integer"):
        run_experiment(out, planners=["random"], objects=["sphere"], trials=1, budget=1, workers="1")
    with pytest.raises(BadInput, match="steps"):
        run_experiment(out, planners=["random"], objects=["sphere"], trials=1, budget=1, settings={"steps": -5})
    assert not out.exists()  # nothing written that would refuse the next, valid call
    # a comma-separated string is the command line's form, not a list of one-letter planners
    with pytest.raises(BadInput, match="'bogus'"):
        run_experiment(out, planners="random,bogus", objects="sphere", trials=1, budget=1)


def test_a_stroke_longer_than_one_loop_is_refused():
    """--duration beyond one loop round the section was cut to the loop without a word (60 s gave 15 s)."""
    sphere = load_object("sphere")
    with pytest.raises(BadInput, match=r"duration: 60 s is longer than one loop around sphere"):
        random_strokes(sphere, 1, seed=0, duration=60.0)
    (st,) = random_strokes(sphere, 1, seed=0, duration=5.0)
    assert abs(st.time[-1] - 5.0) < 0.05


def test_a_second_demo_keeps_every_file_of_the_first(tmp_path, monkeypatch, capsys):
    """The demo rebuilds a demo's folder; the earlier demo's recording, points, report and per-stroke summaries were
    overwritten without a word (and the fit's message named an --overwrite nobody gave). Now every file of it is
    moved into replaced-*/ and the demo says where."""
    import bayestouch.demo as demo
    from bayestouch.cli.main import main

    out = tmp_path / "dm"
    (out / "strokes").mkdir(parents=True)
    files = {"demo.json": "{}", "report.html": "<html>", "recording.nc": "rec", "points.csv": "x,y,z\n"}
    for name, text in files.items():
        (out / name).write_text(text)
    (out / "strokes" / "summary_0.json").write_text("{}")

    def fake_run_demo(folder, **kw):
        (folder / "demo.json").write_text('{"new": 1}')
        return {"table": "new demo"}

    monkeypatch.setattr(demo, "run_demo", fake_run_demo)
    capsys.readouterr()
    assert main(["demo", "--quick", "--quiet", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    (aside,) = out.glob("replaced-*")
    assert f"the earlier demo in {out} is kept in {aside}" in err and "--overwrite" not in err
    for name, text in files.items():
        assert (aside / name).read_text() == text
    assert (aside / "strokes" / "summary_0.json").exists()
    assert (out / "demo.json").read_text() == '{"new": 1}'


def test_api_bad_arguments_are_one_line_refusals(tmp_path):
    """Calls that ended in a TypeError, AttributeError, h5py OSError or IsADirectoryError."""
    import bayestouch as bt

    cases = [
        (lambda: bt.simulate("sphere", device_seed=1.5), "seed: expected an integer"),
        (lambda: bt.simulate("sphere", device_seed=-1), "seed: expected an integer"),
        (lambda: bt.simulate("sphere", duration="2"), "duration: expected a number"),
        (lambda: bt.simulate("sphere", hold_currents=["a", "b", "c"]), "hold_currents: expected"),
        (lambda: bt.simulate("sphere", strokes=10**7), "more than 200000 frames"),
        (lambda: bt.simulate("sphere", out=tmp_path / "rec.txt"), "ending in .nc"),
        (lambda: bt.simulate("sphere", models=5), "models: expected the path"),
        (lambda: bt.explore(5, "random", 1), "object: expected an object name"),
        (lambda: bt.explore("sphere", "random", 1, settings={"bogus": 1}), r"unknown field\(s\) \['bogus'\]"),
        (lambda: bt.read_recording(tmp_path), "is a folder"),
        (lambda: bt.read_recording(tmp_path / "none.nc"), "no such recording"),
    ]
    (tmp_path / "egg.csv").write_text("x,y,z\n0,0,0\n")
    cases.append((lambda: bt.read_recording(tmp_path / "egg.csv"), "not a recording"))
    rec = sorted((Path(__file__).parents[1] / "data" / "recordings").glob("*.nc"))[0]
    cases.append((lambda: bt.fit(rec, calibration=5), "calibration: expected a device file"))
    for call, message in cases:
        with pytest.raises(BadInput, match=message):
            call()


def test_api_simulate_takes_the_models_folder_as_a_string():
    import bayestouch as bt
    from bayestouch.params import MODELS

    ds = bt.simulate("sphere", strokes=1, duration=0.2, models=str(MODELS))
    assert ds.sizes["frame"] == 11  # 0 to 0.2 s at 50 frames/s, both ends


def test_fit_noise_names_gaussian_and_takes_it(tmp_path):
    import bayestouch as bt

    pts = np.random.default_rng(0).normal(size=(40, 3)) * 0.02
    with pytest.raises(BadInput, match="expected one of auto, gaussian, student"):
        bt.fit(pts, noise="bogus")
    with pytest.raises(BadInput, match="nu: the gaussian noise model"):
        bt.fit(pts, noise="gaussian", nu=4.0)
