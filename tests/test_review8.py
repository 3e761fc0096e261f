"""Fixes from the seventh adversarial review's smaller findings (issue 24, nothing lost, nothing silently wrong): a
report page replaced without a word, a folder called "no such file", a stroke file in millimetres or with inward
normals, a switch passed where an array belongs."""

from __future__ import annotations

import json

import numpy as np
import pytest

import bayestouch as bt
from bayestouch.cli import main
from bayestouch.cli.device import load_stroke_file
from bayestouch.errors import BadInput, file_problem
from bayestouch.io.contacts import unit_hint
from bayestouch.scene.objects import load_object
from bayestouch.scene.strokes import random_strokes

HOLD = (0.15, 0.05, 0.05)


def test_file_problem_names_what_the_path_is(tmp_path):
    (tmp_path / "f.txt").write_text("x")
    assert file_problem(tmp_path / "f.txt") == ""
    assert file_problem(tmp_path) == "is a folder, not a file"
    assert file_problem(tmp_path / "none") == "no such file"


def test_calibrate_given_a_folder_says_it_is_a_folder(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    assert main(["calibrate", str(tmp_path / "run"), "--object", "sphere", "--out", str(tmp_path / "d.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "is a folder, not a file; expected a .nc recording" in err and "no such file" not in err, err
    assert not (tmp_path / "d.toml").exists()


def test_fit_refuses_normals_true_naming_the_expected_forms():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(40, 3))
    points = 0.03 * v / np.linalg.norm(v, axis=1, keepdims=True)
    for bad in (True, "yes"):
        with pytest.raises(BadInput, match=r"normals=.*expected an \(n, 3\) array of outward unit normals.*False"):
            bt.fit(points, normals=bad, steps=10, budget_s=1, progress=False)


def _stroke_file(tmp_path, name, scale=1.0, flip=1.0, count=4):
    strokes = random_strokes(load_object("egg"), count, seed=3, duration=1.0)
    doc = {
        "strokes": [
            {
                "time": s.time.tolist(),
                "contact": (scale * np.asarray(s.contact)).tolist(),
                "normal": (flip * np.asarray(s.normal)).tolist(),
                "depth": float(s.depth),
            }
            for s in strokes
        ]
    }
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def test_a_stroke_file_in_millimetres_is_told_the_unit(tmp_path):
    assert len(load_stroke_file(_stroke_file(tmp_path, "m.json"), HOLD)) == 4  # the control: metres pass
    with pytest.raises(BadInput, match=r"contact points look like millimetres.*divide by 1000 if they are millimetres"):
        load_stroke_file(_stroke_file(tmp_path, "mm.json", scale=1e3), HOLD)


def test_a_stroke_file_with_inward_normals_is_refused(tmp_path):
    with pytest.raises(BadInput, match="normals point inwards.*negate every stroke's normal"):
        load_stroke_file(_stroke_file(tmp_path, "in.json", flip=-1.0), HOLD)


def test_unit_hint_names_both_units_that_fit_and_a_fallback():
    assert "centimetres or millimetres" in unit_hint(4.5, 8.7)  # an 8.7 cm egg in cm, or an 8.7 mm one in mm
    assert unit_hint(4.5, 8.7).endswith(
        "(divide by 100 if they are centimetres, divide by 1000 if they are millimetres)"
    )
    assert "some unit other than metres" in unit_hint(1e30, 1e30) and "e.g. divide by 1000" in unit_hint(1e30, 1e30)


def test_calibration_says_why_the_response_is_not_identified(tmp_path, capsys):
    """simulate --help's calibration recipe identifies the response with --mode empirical; in the physics mode the
    pressure signal is below the read-out noise, and calibrate says so on the command line and in the file."""
    rec = {}
    for mode in ("physics", "empirical"):
        rec[mode] = tmp_path / f"{mode}.nc"
        argv = ["simulate", "--object", "sphere", "--strokes", "4", "--depth", "2e-4,3e-4,4e-4", "--seed", "7"]
        assert main([*argv, "--mode", mode, "--quiet", "--out", str(rec[mode])]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(rec["physics"]), "--object", "sphere", "--out", str(tmp_path / "p.toml")]) == 0
    err = capsys.readouterr().err
    assert "response is not identified: the pressure signal of these strokes" in err and "physics" in err, err
    assert "below the read-out noise" in (tmp_path / "p.toml").read_text()
    assert main(["calibrate", str(rec["empirical"]), "--object", "sphere", "--out", str(tmp_path / "e.toml")]) == 0
    assert "not identified" not in capsys.readouterr().err  # the control: the recipe as --help gives it
    assert "not identified" not in (tmp_path / "e.toml").read_text()


def test_a_device_file_of_another_finger_is_refused(tmp_path, capsys):
    """simulate names its finger (attribute ``finger``), calibrate keeps the name in the device file, and a fit of
    another finger's recording with it is refused before its folder is made; the same finger's passes the check."""
    from bayestouch.inference.raw.data import recording_mode
    from bayestouch.io.device_file import read_device_file
    from bayestouch.io.recording import read_recording

    paths = {}
    for name, dev in (("cal", "3"), ("same", "3"), ("other", "4")):
        paths[name] = tmp_path / f"{name}.nc"
        obj = "sphere" if name == "cal" else "egg"
        argv = ["simulate", "--object", obj, "--strokes", "3", "--seed", "1", "--device-seed", dev, "--duration", "1"]
        assert main([*argv, "--mode", "empirical", "--quiet", "--out", str(paths[name])]) == 0
    dev_file = tmp_path / "finger.toml"
    assert main(["calibrate", str(paths["cal"]), "--object", "sphere", "--out", str(dev_file)]) == 0
    cal = read_device_file(dev_file)
    assert cal.info["finger"] == "virtual finger 3"
    assert recording_mode(read_recording(paths["same"]), "same.nc", cal) == "empirical"  # the control
    capsys.readouterr()
    out = tmp_path / "fit"
    assert main(["fit", str(paths["other"]), "--calibration", str(dev_file), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "calibration: made on virtual finger 3" in err and "recorded by virtual finger 4" in err, err
    assert not out.exists()


def test_run_folder_messages_name_the_python_keywords_too(tmp_path):
    """bt.fit and run_contact_fit share the run folder's checks with the command line: the refusal names
    resume=True / overwrite=True beside the flags (it named only --resume and --overwrite)."""
    from bayestouch.io.runfolder import fingerprint, prepare_run_folder, release_run_folder

    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    fp = fingerprint("contact", {"points": np.zeros((3, 3))}, {"seed": 0})
    with pytest.raises(BadInput, match=r"--resume \(resume=True\) to continue it, --overwrite \(overwrite=True\)"):
        prepare_run_folder(out, fp, resume=False)
    release_run_folder(out)
    with pytest.raises(BadInput, match=r"--resume \(resume=True\) and --overwrite \(overwrite=True\) exclude"):
        prepare_run_folder(out, fp, resume=True, overwrite=True)


def test_write_report_refuses_malformed_input_in_one_line(tmp_path):
    from bayestouch.report.page import Table, write_report

    (tmp_path / "file").write_text("x")
    (tmp_path / "run").mkdir()
    (tmp_path / "dir_page").mkdir()
    (tmp_path / "dir_page" / "report.html").mkdir()
    cases = [
        ({"out": tmp_path / "file"}, "is not a folder"),
        ({"out": tmp_path / "dir_page", "overwrite": True}, "report.html is a folder"),
        ({"sections": [1]}, r"sections\[0\] must be a \(heading, items\) pair"),
        ({"sections": None}, "sections must be a list"),
        ({"title": None}, "title must be a str"),
        ({"sections": [("s", [Table("c", ["a"], [["1", "2"]])])]}, "row 0 has 2 cells for 1 columns"),
        ({"sections": [("s", [3.0])]}, "holds a float; expected Table, Figure or str"),
        ({"files": "summary.json"}, "files must be a list of file names"),
    ]
    for change, message in cases:
        kw = {"out": tmp_path / "run", "title": "t", "intro": "", "sections": []} | change
        with pytest.raises(BadInput, match=message):
            write_report(kw.pop("out"), **kw)
    assert not (tmp_path / "run" / "report.html").exists()
    assert write_report(tmp_path / "run", title="t", intro="", sections=[("s", ["<p>x</p>"])]).is_file()


def test_texture_id_refuses_another_fingers_device_file_before_setting_results_aside(tmp_path, capsys):
    from bayestouch.io.device_file import read_device_file
    from bayestouch.planning.texture_id import check_calibration

    rec, dev = tmp_path / "cal.nc", tmp_path / "d.toml"
    argv = ["simulate", "--object", "sphere", "--strokes", "3", "--duration", "1", "--seed", "1", "--device-seed", "3"]
    assert main([*argv, "--mode", "empirical", "--depth", "2e-4,3e-4,4e-4", "--quiet", "--out", str(rec)]) == 0
    assert main(["calibrate", str(rec), "--object", "sphere", "--out", str(dev)]) == 0
    check_calibration(read_device_file(dev), "empirical", 3)  # the control: the finger the file was made on
    out = tmp_path / "tx"
    out.mkdir()
    (out / "results.csv").write_text("texture,trial\n0,0\n")
    capsys.readouterr()
    argv = ["texture-id", "--textures", "2", "--trials", "1", "--seed", "0", "--calibration", str(dev)]
    assert main([*argv, "--out", str(out), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "made on virtual finger 3; the strokes are simulated on virtual finger 0 (--seed 0)" in err, err
    assert (out / "results.csv").read_text() == "texture,trial\n0,0\n" and not list(out.glob("replaced-*"))


def test_resume_differences_name_which_object_each_run_has():
    """experiment --resume over sphere results with --objects egg named "other object egg" (the new key, as if the
    results were egg's); each side is named now, and an edited object file stays "other"."""
    from bayestouch.io.runfolder import differences, fingerprint

    old = fingerprint("experiment", {"object sphere": b"s"}, {"seed": 0})
    new = fingerprint("experiment", {"object egg": b"e"}, {"seed": 0})
    assert sorted(differences(old, new)) == ["no object egg (this run has it)", "object sphere (this run lacks it)"]
    edited = fingerprint("experiment", {"object sphere": b"s2"}, {"seed": 0})
    assert differences(old, edited) == ["other object sphere"]
    assert differences(old, old) == []


def test_a_device_that_names_its_unit_names_the_recording():
    """The handshake's firmware string may end in "; finger=ID" (PROTOCOL.md §4): device-run recordings then name
    their finger, so a device file of another finger is refused for them too; a device that names none (the
    control) leaves the recording unnamed, and a named but empty ID names nothing."""
    from bayestouch.hardware import protocol as pr
    from bayestouch.hardware.device import build_recording, finger_of

    assert finger_of("bayestouch-virtual-1; finger=virtual finger 4") == "virtual finger 4"
    assert finger_of("bayestouch-virtual-1") is None and finger_of("fw; finger= ") is None
    uv = np.zeros((4, 2))

    def hello(fw):
        return pr.HelloReply(1, pr.PROTOCOL_VERSION, fw, 2, 2, 50.0, 0.2, 393.0, 1.0, 1.0, 1000, uv, np.zeros(4, int))

    named = build_recording([], hello("bayestouch-virtual-1; finger=virtual finger 4"))
    assert named.attrs["finger"] == "virtual finger 4"
    assert "finger" not in build_recording([], hello("bayestouch-virtual-1")).attrs


def test_command_line_names_the_flags_alone(tmp_path, capsys):
    """Issue 24, tenth review: the command line printed the Python spelling beside its flags ("--resume
    (resume=True)"); it prints the flag alone, while the API's message keeps both (the test above)."""
    from bayestouch.cli import main as cli_main
    from bayestouch.errors import command_line_message

    assert command_line_message("pass --resume (resume=True) or overwrite=True (--overwrite)") == (
        "pass --resume or --overwrite"
    )
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    pts = tmp_path / "p.csv"
    rng = np.random.default_rng(0)
    u = rng.normal(size=(40, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    np.savetxt(pts, 0.03 * u, delimiter=",", header="x,y,z", comments="")
    assert cli_main(["fit", str(pts), "--out", str(out), "--resume", "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--resume and --overwrite exclude" in err and "=True" not in err
