"""Run folders: a finished run is never overwritten by accident, a chain is resumed only by its own data and options,
and outputs are replaced atomically."""

import json

import numpy as np
import pytest

from bayestouch.cli import main
from bayestouch.errors import BadInput
from bayestouch.io.contacts import save_contact_points
from bayestouch.io.files import atomic_path
from bayestouch.io.runfolder import FINGERPRINT_FILE, fingerprint, prepare_run_folder


def _fp(points, **options):
    return fingerprint(
        "contact", {"points": points, "free-space points": None}, {"seed": 0, "noise": "outlier", **options}
    )


def test_a_folder_holding_a_run_is_refused_without_resume_or_overwrite(tmp_path):
    pts = np.arange(12.0).reshape(4, 3)
    out = tmp_path / "run"
    prepare_run_folder(out, _fp(pts), resume=False)  # an empty folder: accepted, fingerprint written
    assert json.loads((out / FINGERPRINT_FILE).read_text())["options"]["seed"] == 0
    (out / "summary.json").write_text('{"old": true}')
    with pytest.raises(BadInput, match="already holds a run.*--resume.*--overwrite"):
        prepare_run_folder(out, _fp(pts), resume=False)
    assert (out / "summary.json").read_text() == '{"old": true}'  # nothing lost
    # a finished run whose chain is gone cannot be continued: a fresh chain replaced its results, exit 0 (issue
    # 24, ninth review)
    with pytest.raises(BadInput, match="not its chain.h5, so it cannot be continued.*--overwrite"):
        prepare_run_folder(out, _fp(pts), resume=True)
    (out / "smc.npz").write_bytes(b"stage")  # every finished fit keeps its tempering stage (tenth review)
    with pytest.raises(BadInput, match="not its chain.h5, so it cannot be continued.*--overwrite"):
        prepare_run_folder(out, _fp(pts), resume=True)
    (out / "smc.npz").unlink()
    assert (out / "summary.json").read_text() == '{"old": true}'
    (out / "chain.h5").write_bytes(b"chain")
    prepare_run_folder(out, _fp(pts), resume=True)  # the same data and options resume
    prepare_run_folder(out, _fp(pts, seed=1), resume=False, overwrite=True)
    assert not (out / "summary.json").exists()  # the old run's outputs went before the new run starts ...
    (aside,) = out.glob("replaced-*")
    assert (aside / "summary.json").read_text() == '{"old": true}'  # ... aside, not deleted
    assert json.loads((out / FINGERPRINT_FILE).read_text())["options"]["seed"] == 1
    with pytest.raises(BadInput, match="exclude each other"):
        prepare_run_folder(out, _fp(pts), resume=True, overwrite=True)
    (tmp_path / "file").write_text("x")
    with pytest.raises(BadInput, match="not a folder"):
        prepare_run_folder(tmp_path / "file", _fp(pts), resume=False)


def test_resume_refuses_other_data_or_options_and_names_them(tmp_path):
    pts = np.arange(12.0).reshape(4, 3)
    out = tmp_path / "run"
    prepare_run_folder(out, _fp(pts), resume=False)
    (out / "chain.h5").write_bytes(b"chain")
    other = pts.copy()
    other[0, 0] += 1e-12  # one coordinate off by a picometre is other data
    with pytest.raises(BadInput, match="other points"):
        prepare_run_folder(out, _fp(other), resume=True)
    with pytest.raises(BadInput, match=r"seed 0 \(now 7\)"):
        prepare_run_folder(out, _fp(pts, seed=7), resume=True)
    with pytest.raises(BadInput, match="noise 'outlier' \\(now 'student'\\)"):
        prepare_run_folder(out, _fp(pts, noise="student"), resume=True)
    assert (out / "chain.h5").read_bytes() == b"chain"
    # a run without its run.json (deleted, or from before fingerprints) cannot show its data: refused (issue 24,
    # fourth review: other data continued it and reported the old object's volume, exit 0)
    (out / FINGERPRINT_FILE).unlink()
    with pytest.raises(BadInput, match="but no run.json"):
        prepare_run_folder(out, _fp(other), resume=True)
    assert (out / "chain.h5").read_bytes() == b"chain"


def test_atomic_path_keeps_the_old_file_when_the_writer_fails(tmp_path):
    target = tmp_path / "posterior.nc"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        assert tmp.suffix == ".nc" and tmp.parent == tmp_path
        tmp.write_bytes(b"half")
        raise RuntimeError("killed")
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["posterior.nc"]
    with atomic_path(target) as tmp:
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new" and sorted(p.name for p in tmp_path.iterdir()) == ["posterior.nc"]


def test_fit_cli_refuses_to_replace_or_wrongly_resume_a_run(tmp_path, capsys):
    """The issue's cases end to end: a second fit into a finished run's folder, and a resume with another object's
    points or another seed, exit 2 with one line and leave the run as it was; --overwrite replaces it."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(150, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    egg = tmp_path / "egg.csv"
    sphere = tmp_path / "sphere.csv"
    save_contact_points(egg, d * [0.03, 0.022, 0.015] + rng.normal(0, 3e-4, (150, 3)))
    save_contact_points(sphere, d * 0.02 + rng.normal(0, 3e-4, (150, 3)))
    out = tmp_path / "run"
    fast = ["--walkers", "24", "--steps", "60", "--init", "optimize", "--no-early-stop", "--budget", "0", "--quiet"]
    assert main(["fit", str(egg), "--out", str(out), *fast]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    assert main(["fit", str(egg), "--out", str(out), *fast]) == 2
    err = capsys.readouterr().err.strip()
    assert "already holds a run" in err and len(err.splitlines()) == 1
    assert main(["fit", str(sphere), "--out", str(out), "--resume", *fast]) == 2
    assert "other points" in capsys.readouterr().err
    assert main(["fit", str(egg), "--out", str(out), "--resume", "--seed", "7", *fast]) == 2
    assert "seed 0 (now 7)" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main(["fit", str(sphere), "--out", str(out), "--overwrite", *fast]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert abs(s["derived"]["mean_shape"]["a"] - 0.02) < 2e-3  # the sphere's run, not the egg's


def test_a_folder_in_use_by_another_process_is_refused(tmp_path):
    """Two fits into one folder at once replaced the first's finished result (review of issue 24): the folder is
    locked by the process that prepared it, another process is refused in one line, and the lock goes with
    release_run_folder (the same process may prepare it again meanwhile)."""
    import subprocess
    import sys

    from bayestouch.io.runfolder import release_run_folder

    pts = np.arange(12.0).reshape(4, 3)
    out = tmp_path / "run"
    prepare_run_folder(out, _fp(pts), resume=False)
    prepare_run_folder(out, _fp(pts), resume=True)  # this process holds it: no self-deadlock
    other = (
        "import sys, numpy as np\n"
        "from bayestouch.errors import BadInput\n"
        "from bayestouch.io.runfolder import fingerprint, prepare_run_folder\n"
        "fp = fingerprint('contact', {'points': np.arange(12.0).reshape(4, 3)}, {'seed': 0})\n"
        "try:\n"
        f"    prepare_run_folder({str(out)!r}, fp, resume=True)\n"
        "except BadInput as e:\n"
        "    print(e); sys.exit(2)\n"
    )
    busy = subprocess.run([sys.executable, "-c", other], capture_output=True, text=True)
    assert busy.returncode == 2 and "in use by another bayestouch run" in busy.stdout
    release_run_folder(out)
    free = subprocess.run([sys.executable, "-c", other], capture_output=True, text=True)
    assert free.returncode == 0, free.stdout + free.stderr


@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 cut off"])
def test_a_damaged_tempering_stage_is_refused_in_one_line(tmp_path, content):
    """Issue 24, ninth review: ``--resume`` over an empty or truncated smc.npz (a kill mid-write) ended in EOFError or
    BadZipFile, exit 1. Refused as bad input naming the file and --overwrite. Control: a whole file is read back."""
    from bayestouch.inference.run import smc_stage

    path = tmp_path / "smc.npz"
    np.savez(path, particles=np.zeros((2, 3)), log_evidence=np.float64(-1.5))
    assert smc_stage(None, None, None, path=path)["log_evidence"] == -1.5
    path.write_bytes(content)
    with pytest.raises(BadInput, match=r"smc\.npz cannot be read as a finished tempering stage.*--overwrite"):
        smc_stage(None, None, None, path=path)


def test_resume_refusal_names_only_what_changed(tmp_path):
    """Issue 24, ninth review: a changed --size-prior printed the whole 17-entry priors table twice (~900
    characters), and a parts fit over a single fit listed every option. Now a table names its changed entries,
    and a run of another kind says only that."""
    from bayestouch.io.runfolder import differences

    priors = {f"p{i}": float(i) for i in range(17)}
    old = _fp(np.zeros((4, 3)), priors=priors)
    new = _fp(np.zeros((4, 3)), priors={**priors, "p3": 30.0})
    (diff,) = differences(old, new)
    assert diff == "priors: p3 3.0 (now 30.0)"
    other = fingerprint("parts", {"points": np.zeros((4, 3))}, {"walkers": 32})
    assert differences(old, other) == ["a contact-level run, not parts"]
    assert differences(old, old) == []


def test_one_overwrite_sets_an_earlier_run_aside_in_one_folder(tmp_path):
    """Issue 24, ninth review: ``fit --overwrite`` over a texture-id folder moved results.csv and the figure into one
    replaced-* folder and summary.json into another, which the message called "the previous run". Steps of one
    overwrite now share the folder; a name already there (another run's file of the same name) still gets a new
    one, so nothing is replaced."""
    from bayestouch.io.files import move_aside

    for name in ("results.csv", "accuracy_vs_strokes.png", "summary.json"):
        (tmp_path / name).write_text(name)
    first = move_aside(tmp_path, [tmp_path / "results.csv", tmp_path / "accuracy_vs_strokes.png"])
    second = move_aside(tmp_path, [tmp_path / "summary.json"])
    assert first == second and sorted(p.name for p in first.iterdir()) == [
        "accuracy_vs_strokes.png",
        "results.csv",
        "summary.json",
    ]
    (tmp_path / "summary.json").write_text("a later run")
    third = move_aside(tmp_path, [tmp_path / "summary.json"])
    assert third != first and (third / "summary.json").read_text() == "a later run"
    assert (first / "summary.json").read_text() == "summary.json"
