"""The ``bayestouch`` command: subcommands, bad input (exit 2, one line), the Table 2 files."""

import csv
import subprocess
import sys
from pathlib import Path

import pytest

from bayestouch.cli import build_parser, main

CONTRACT = ["epsilon", "ffd_size", "iterations", "bp_minus_x_percent", "j_ratio", "eps_v", "eps_a", "eps_i"]


def test_every_subcommand_of_the_issues_exists():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert {"reproduce-paper", "simulate", "fit", "demo", "device", "explore", "experiment", "texture-id"} <= set(
        sub.choices
    )


@pytest.mark.parametrize(
    "args,needle",
    [
        (["reproduce-paper"], "--out"),
        (["reproduce-paper", "--out", "X", "--sizes", "6x6"], "6x6x3"),
        (["reproduce-paper", "--out", "X", "--sizes", "6x1x3"], "6x6x3"),
        (["reproduce-paper", "--out", "X", "--epsilons", "abc"], "epsilons"),
        (["reproduce-paper", "--out", "X", "--epsilons", "0.7"], "[0, 0.5)"),
        (["reproduce-paper", "--out", "X", "--paths", "0"], "--paths: expected an integer from 1 to"),
        (["nonsense"], "invalid choice"),
    ],
)
def test_bad_arguments_exit_2(args, needle, capsys):
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    assert needle in capsys.readouterr().err


def test_bad_files_exit_2_with_one_line(tmp_path, capsys):
    assert main(["reproduce-paper", "--out", str(tmp_path / "o"), "--object", str(tmp_path / "no.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "no.toml" in err and "\n" not in err
    bad = tmp_path / "mm.toml"
    bad.write_text("[shape]\ncentre_m = [0, 0, 0]\naxes_m = [45, 25, 5]\nn = 10\n")
    assert main(["reproduce-paper", "--out", str(tmp_path / "o"), "--object", str(bad)]) == 2
    assert "millimetres" in capsys.readouterr().err
    afile = tmp_path / "file"
    afile.write_text("keep me")
    assert main(["reproduce-paper", "--out", str(afile)]) == 2
    assert afile.read_text() == "keep me"  # nothing already recorded is lost
    assert main(["reproduce-paper", "--out", str(tmp_path / "o"), "--rate", "-1"]) == 2


@pytest.mark.slow
def test_reproduce_paper_small_run_writes_contract_files(tmp_path, capsys):
    out = tmp_path / "paper"
    code = main(
        [
            "reproduce-paper",
            "--out",
            str(out),
            "--paths",
            "5",
            "--rate",
            "5",
            "--sizes",
            "6x6x3,7x7x7",
            "--epsilons",
            "0,0.001",
            "--res",
            "20",
            "--quiet",
        ]
    )
    assert code == 0
    with open(out / "table2.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[: len(CONTRACT)] == CONTRACT
    assert [(r["epsilon"], r["ffd_size"]) for r in rows] == [
        ("0.0", "6x6x3"),
        ("0.0", "7x7x7"),
        ("0.001", "6x6x3"),
        ("0.001", "7x7x7"),
    ]
    for r in rows:
        assert 0 < float(r["bp_minus_x_percent"]) < 1.0  # the issue's goal for perturbed rows, met here too
        assert int(r["iterations"]) >= 1 and float(r["paper_iterations"]) > 0
        assert float(r["defect_free_bp_minus_x_percent"]) < float(r["bp_minus_x_percent"])
    md = (out / "table2.md").read_text()
    assert "| 0.001 | 6x6x3 |" in md and "[3]" in md  # the paper's 3 % beside ours
    assert (out / "table2.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(out / "table1.csv", newline="") as fh:
        t1 = list(csv.DictReader(fh))
    assert list(t1[0])[:5] == ["path", "load_N", "a_mm", "b_mm", "n"] and len(t1) == 32
    for path in {r["path"] for r in t1}:
        areas = [float(r["area_mm2"]) for r in t1 if r["path"] == path]
        assert areas == sorted(areas)  # the patch grows with the load on every path


def test_console_script_runs_without_traceback(tmp_path):
    exe = Path(sys.executable).with_name("bayestouch")
    r = subprocess.run([str(exe), "fit"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    r = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "reproduce-paper" in r.stdout and "experiment" in r.stdout


def test_out_below_a_file_exits_2(tmp_path, capsys):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")
    with pytest.raises(SystemExit) as done:  # refused while the arguments are parsed, before any work
        main(["reproduce-paper", "--out", str(blocker / "sub"), "--paths", "1"])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "blocker" in err and "\n" not in err and "internal error" not in err
    assert blocker.read_text() == "a file, not a folder"


def test_one_meaning_per_flag_and_every_option_has_help():
    """--budget is seconds only in fit; explore and experiment count strokes with --strokes (--budget kept as its
    alias); every command that shows progress is silenced by --quiet; every option of every command has help."""
    from bayestouch.cli.main import build_parser

    parser = build_parser()
    subs = next(a for a in parser._actions if a.dest == "command").choices
    for name, sp in subs.items():
        for action in sp._actions:
            if action.option_strings and action.dest != "help":
                assert action.help, f"{name} {action.option_strings[0]} has no help"
        if sp.description is None:
            assert name == "device", f"{name} has no description"
    for name in ("explore", "experiment"):
        args = subs[name].parse_args(["--strokes", "3", "--out", "x"])
        assert args.budget == 3 and subs[name].parse_args(["--budget", "4", "--out", "x"]).budget == 4
        assert "seconds" not in next(a for a in subs[name]._actions if a.dest == "budget").help.split(";")[0]
    assert "seconds" in next(a for a in subs["fit"]._actions if a.dest == "budget").help
    for name in ("fit", "simulate", "demo", "texture-id", "sbc"):
        assert any("--quiet" in a.option_strings for a in subs[name]._actions), name
    assert subs["texture-id"].parse_args(["--no-progress", "--out", "x"]).no_progress  # the old spelling works
