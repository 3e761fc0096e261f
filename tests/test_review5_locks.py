"""Output folders of every command (review 5): a folder in use by another run is refused (a lock, as fit's), a fit
does not write into another command's results, and a comma list naming one entry twice is refused."""

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from bayestouch.cli import main
from bayestouch.cli.main import build_parser
from bayestouch.io.contacts import save_contact_points
from bayestouch.io.runfolder import LOCK_FILE

#: a process that holds ``sys.argv[1]`` with the public helper until its stdin closes (or it is killed)
_HOLDER = (
    "import sys\n"
    "from bayestouch.io.runfolder import locked_run_folder\n"
    "with locked_run_folder(sys.argv[1]):\n"
    "    print('held', flush=True)\n"
    "    sys.stdin.read()\n"
)
#: the smallest exploration settings (a run of seconds)
_SMALL = ["--strokes", "1", "--candidates", "4", "--draws", "10", "--steps", "20"]


def _hold(folder):
    """Start a process holding ``folder`` locked; returns it once the lock is taken."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(folder)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "held"
    return proc


def _release(proc, kill: bool = False) -> None:
    """End a holder of :func:`_hold`: its stdin closed (a run that finishes), or SIGKILL (a run killed)."""
    if kill:
        proc.send_signal(signal.SIGKILL)
    proc.stdin.close()
    proc.wait()
    proc.stdout.close()


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file() and p.name != LOCK_FILE}


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def _explore_folder(folder):
    """An exploration's results (as `bayestouch explore` writes them), made without running one."""
    folder.mkdir()
    (folder / "explore.json").write_text('{"object": "sphere", "planner": "random", "seed": 0, "strokes": []}')
    (folder / "summary_0.json").write_text('{"stroke": 0}')
    d = np.random.default_rng(0).normal(size=(150, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    save_contact_points(folder / "points.csv", d * 0.02 + np.random.default_rng(1).normal(0, 3e-4, (150, 3)))
    return folder


def test_explore_and_experiment_refuse_a_folder_in_use_and_run_once_it_is_free(tmp_path, capsys):
    """Two runs into one --out at once both exited 0 and the first's results were lost: while another process holds
    the folder, explore and experiment (even with --overwrite, which would set the earlier results aside) exit 2 with
    one line naming the holder's pid and leave every file as it was; a holder killed with SIGKILL leaves no stale
    lock, and the next run goes on."""
    ex = _explore_folder(tmp_path / "ex")
    xp = tmp_path / "xp"
    xp.mkdir()
    (xp / "results.csv").write_text("planner,trial\nrandom,0\n")
    (xp / "experiment.json").write_text('{"level": "experiment", "options": {}}')
    before = {ex: _snapshot(ex), xp: _snapshot(xp)}
    holders = {ex: _hold(ex), xp: _hold(xp)}
    try:
        capsys.readouterr()
        explore = ["explore", "--object", "sphere", "--planner", "random", *_SMALL, "--out", str(ex), "--overwrite"]
        assert main(explore) == 2
        err = _one_line(capsys)
        assert f"--out {ex} is in use by another bayestouch run (pid {holders[ex].pid})" in err
        experiment = ["experiment", "--objects", "sphere", "--planners", "random", "--trials", "1", "--workers", "1"]
        assert main([*experiment, *_SMALL, "--seed", "5", "--out", str(xp), "--overwrite"]) == 2
        err = _one_line(capsys)
        assert f"--out {xp} is in use by another bayestouch run (pid {holders[xp].pid})" in err
        for folder in (ex, xp):  # nothing moved, nothing written
            assert _snapshot(folder) == before[folder]
            assert sorted(p.name for p in folder.iterdir() if p.is_dir()) == []
    finally:
        for proc in holders.values():
            _release(proc, kill=True)  # a killed run: its lock goes with it, its lock file stays
    assert (ex / LOCK_FILE).read_text().strip() == str(holders[ex].pid)
    assert main(explore) == 0
    aside = [p for p in ex.iterdir() if p.name.startswith("replaced-")]
    assert len(aside) == 1 and _snapshot(aside[0]) == before[ex]  # the earlier exploration set aside, not lost
    assert (ex / "summary_1.json").is_file()
    assert main([*experiment, *_SMALL, "--seed", "5", "--out", str(xp), "--overwrite"]) == 0
    rows = (xp / "results.csv").read_text().splitlines()
    assert rows[0].startswith("planner,trial,object") and len(rows) == 3  # the scout and one stroke


@pytest.mark.parametrize(
    ("command", "result"),
    [
        (["sbc", "--datasets", "2"], "sbc.json"),
        (["texture-id", "--textures", "2", "--trials", "1"], "results.csv"),
        (["reproduce-paper", "--paths", "1"], "table2.csv"),
        (["demo", "--quick"], "summary.json"),
    ],
)
def test_every_command_with_an_out_folder_refuses_one_in_use(tmp_path, capsys, command, result):
    """sbc, texture-id, reproduce-paper and demo take the same lock: refused in one line (not "already holds",
    which a second run started at the same moment as the first does not see), the folder as it was."""
    out = tmp_path / "out"
    out.mkdir()
    (out / result).write_text("earlier")
    holder = _hold(out)
    try:
        capsys.readouterr()
        assert main([*command, "--out", str(out)]) == 2
        err = _one_line(capsys)
        assert f"is in use by another bayestouch run (pid {holder.pid})" in err
        assert _snapshot(out) == {result: b"earlier"}
    finally:
        _release(holder)


def test_the_lock_of_a_command_outlives_a_fit_inside_it_and_goes_at_its_end(tmp_path):
    """The demo's fit prepares and releases the demo's own folder: the folder stays locked until the demo's block
    ends (also when it ends by an error); a folder the block made and left empty is removed."""
    from bayestouch.io.runfolder import fingerprint, locked_run_folder, prepare_run_folder, release_run_folder

    def other_process_may_lock(folder) -> bool:
        probe = subprocess.run(
            [sys.executable, "-c", _HOLDER, str(folder)], input="", capture_output=True, text=True, timeout=120
        )
        assert probe.returncode in (0, 1), probe.stderr
        return probe.returncode == 0

    out = tmp_path / "demo"
    fp = fingerprint("contact", {"points": np.zeros((4, 3))}, {"seed": 0})
    with pytest.raises(RuntimeError, match="stopped"), locked_run_folder(out):
        prepare_run_folder(out, fp, resume=False)
        release_run_folder(out)  # the fit's release inside the demo
        assert not other_process_may_lock(out)
        raise RuntimeError("stopped")
    assert other_process_may_lock(out)
    empty = tmp_path / "refused"
    with locked_run_folder(empty):
        assert empty.is_dir()
    assert not empty.exists()  # nothing written: no folder left behind


@pytest.mark.parametrize("marker", ["explore.json", "results.csv"])
def test_fit_refuses_a_folder_holding_another_commands_results(tmp_path, capsys, marker):
    """`fit ex2/points.csv --out ex2` wrote a fit into an exploration's folder: refused in one line naming what is
    there (as explore refuses a fit's folder), nothing written, nothing moved."""
    ex = _explore_folder(tmp_path / "ex")
    if marker != "explore.json":
        (ex / "explore.json").replace(ex / marker)
    before = _snapshot(ex)
    capsys.readouterr()
    assert main(["fit", str(ex / "points.csv"), "--out", str(ex), "--steps", "60", "--quiet"]) == 2
    err = _one_line(capsys)
    assert f"--out {ex} already holds the results of another command" in err and marker in err
    assert "--overwrite" in err
    assert _snapshot(ex) == before and not [p for p in ex.iterdir() if p.is_dir()]


def test_fit_overwrite_sets_another_commands_results_aside(tmp_path, capsys):
    """--overwrite sets the exploration's results aside (never deleted) and keeps the fitted points.csv where the
    command line names it."""
    ex = _explore_folder(tmp_path / "ex")
    before = _snapshot(ex)
    fast = ["--walkers", "24", "--steps", "60", "--init", "optimize", "--no-early-stop", "--budget", "0", "--quiet"]
    assert main(["fit", str(ex / "points.csv"), "--out", str(ex), "--overwrite", *fast]) == 0
    aside = [p for p in ex.iterdir() if p.name.startswith("replaced-")]
    assert len(aside) == 1
    assert _snapshot(aside[0]) == {k: v for k, v in before.items() if k != "points.csv"}
    assert (ex / "points.csv").read_bytes() == before["points.csv"] and (ex / "summary.json").is_file()
    assert not (ex / "explore.json").exists()


@pytest.mark.parametrize(
    ("option", "value", "named"),
    [
        ("--sizes", "2x2x2,3x3x3,2x2x2", "2x2x2 named twice"),
        ("--sizes", "2x2x2,02x2x2", "02x2x2 named twice"),
        ("--epsilons", "0,0.001,0.0", "0.0 named twice"),
        ("--epsilons", "0.001,1e-3", "1e-3 named twice"),
    ],
)
def test_reproduce_paper_refuses_a_list_naming_one_entry_twice(tmp_path, capsys, option, value, named):
    """--sizes 2x2x2,2x2x2 fitted the lattice twice and wrote every row of table2.csv twice: refused by the parser
    in one line naming the option and the entry (as experiment --planners eig,eig)."""
    out = tmp_path / "rp"
    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(["reproduce-paper", option, value, "--paths", "1", "--out", str(out)])
    assert e.value.code == 2
    err = _one_line(capsys)
    assert f"argument {option}: {named}" in err
    assert not out.exists()
    ok = ["reproduce-paper", "--sizes", "2x2x2,3x3x3", "--epsilons", "0,0.001", "--out", str(out)]
    args = build_parser().parse_args(ok)
    assert args.sizes == ["2x2x2", "3x3x3"] and args.epsilons == [0.0, 0.001]


def test_lock_file_names_its_holder(tmp_path):
    """The lock file holds the pid of the process holding it (the refusal names it)."""
    from bayestouch.io.runfolder import locked_run_folder

    with locked_run_folder(tmp_path / "o") as out:
        (out / "x").write_text("")
        assert (out / LOCK_FILE).read_text().strip() == str(os.getpid())


def test_demo_refuses_a_folder_holding_an_exploration(tmp_path, capsys):
    """The demo wrote its points.csv over an exploration's (its check knew only a fit's files): refused in one line
    naming what is there, the exploration as it was."""
    ex = _explore_folder(tmp_path / "ex")
    before = _snapshot(ex)
    capsys.readouterr()
    assert main(["demo", "--quick", "--quiet", "--out", str(ex)]) == 2
    err = _one_line(capsys)
    assert f"--out {ex} holds a run that is not a demo's (explore.json, points.csv, summary_0.json)" in err
    assert _snapshot(ex) == before and not [p for p in ex.iterdir() if p.is_dir()]
