"""Limits of the sizes, durations and paths that ``sbc``, ``reproduce-paper`` and ``device simulate`` take (issue
24): a value whose memory or time is out of reach, or that is not a number at all, is one line on stderr naming the
option, exit code 2, before any heavy work; ``device simulate --link`` never replaces or deletes a file of the
user's, and leaves nothing behind.
"""

from __future__ import annotations

import os

import pytest

from bayestouch.cli import main

#: command line ({tmp}: a fresh folder), text the one-line message must contain
TABLE = [
    # sbc: each size has an upper limit, the products that hold memory too
    ("sbc --datasets 2 --steps 1000000000 --out {tmp}/o", "--steps"),
    ("sbc --datasets 2 --steps 100000 --out {tmp}/o", "--walkers × --steps"),
    ("sbc --datasets 2 --draws 1000000 --out {tmp}/o", "--draws"),
    ("sbc --datasets 2 --steps 200 --draws 2000 --out {tmp}/o", "--draws must be at most the 1600"),
    ("sbc --datasets 2 --points 100000000 --out {tmp}/o", "--points"),
    ("sbc --datasets 100000 --points 10000 --out {tmp}/o", "--datasets × --points"),
    ("sbc --datasets 100000 --draws 1000 --steps 10000 --out {tmp}/o", "--datasets × --draws"),
    ("sbc --datasets 2 --walkers 100000000 --out {tmp}/o", "--walkers"),
    ("sbc --datasets 2 --walkers 30 --out {tmp}/o", "multiple of 4"),
    ("sbc --datasets 2 --likelihood-power nan --out {tmp}/o", "--likelihood-power"),
    ("sbc --datasets 2 --likelihood-power -1 --out {tmp}/o", "--likelihood-power"),
    ("sbc --datasets 2 --likelihood-power 1e308 --out {tmp}/o", "--likelihood-power"),
    ("sbc --datasets 2 --likelihood-power 0 --out {tmp}/o", "(0, 10]"),
    ("sbc --datasets 1 --out {tmp}/o", "--datasets"),
    ("sbc --datasets 2 --steps 10 --out {tmp}/o", "--steps"),
    ("sbc --datasets 2 --out {tmp}/keep.txt", "keep.txt"),
    # reproduce-paper
    ("reproduce-paper --paths 2 --sizes 2x2x2 --res 100000 --out {tmp}/o", "--res"),
    ("reproduce-paper --paths 2 --res 10 --sizes 1000x1000x1000 --out {tmp}/o", "--sizes"),
    ("reproduce-paper --paths 2 --rate 1e9 --out {tmp}/o", "--rate"),
    ("reproduce-paper --paths 2 --rate nan --out {tmp}/o", "--rate"),
    ("reproduce-paper --paths 100000000 --out {tmp}/o", "--paths"),
    ("reproduce-paper --object {egg} --paths 1000 --rate 1000 --out {tmp}/o", "--paths × --rate"),
    # device simulate
    ("device simulate --model synthetic --for nan", "--for"),
    ("device simulate --model synthetic --for -1", "--for"),
    ("device simulate --model synthetic --for 1e308", "--for"),
    ("device simulate --model synthetic --delay nan", "--delay"),
    ("device simulate --model synthetic --delay 1e9", "--delay"),
    ("device simulate --model synthetic --delay -1", "--delay"),
    # segment mode (protocol revision 1.2): auto, 0 or a part size the protocol allows
    ("device run --port {tmp}/none --out {tmp}/r.nc --segment 8", "--segment"),
    ("device run --port {tmp}/none --out {tmp}/r.nc --segment 70000", "--segment"),
    ("device run --port {tmp}/none --out {tmp}/r.nc --segment -1", "--segment"),
    ("device run --port {tmp}/none --out {tmp}/r.nc --segment big", "--segment"),
    ("explore --out {tmp}/e --segment 48", "--segment applies to a finger on --port"),
]


def _run(line: str, tmp, capsys) -> tuple[int, list[str]]:
    from bayestouch.params import MODELS

    argv = line.format(tmp=tmp, egg=MODELS / "objects" / "egg.toml").split()
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's own errors
        code = e.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, [x for x in err.splitlines() if x.strip()]


@pytest.mark.parametrize("line,needle", TABLE, ids=[row[0].split(" {")[0] + f"#{i}" for i, row in enumerate(TABLE)])
def test_out_of_range_values_are_one_line_exit_2(line, needle, tmp_path, capsys):
    (tmp_path / "keep.txt").write_text("recorded")
    code, lines = _run(line, tmp_path, capsys)
    assert code == 2, (code, lines)
    assert len(lines) == 1, lines
    assert needle in lines[0], lines[0]
    assert not (tmp_path / "o").exists()  # refused before any work
    assert (tmp_path / "keep.txt").read_text() == "recorded"


def _listing(folder) -> dict:
    return {p.name: (p.is_symlink(), p.is_dir() and not p.is_symlink()) for p in folder.iterdir()}


@pytest.mark.parametrize(
    "name,needle",
    [
        ("keep_link.txt", "not a symbolic link"),  # a regular file: it was replaced by the link, then deleted
        ("linkdir", "is a folder"),  # a folder: "Is a directory: linkdir.tmp" and a stale linkdir.tmp
        ("link_to_file", "not to a pty"),  # a link of the user's to a file
        ("no_such_folder/port", "does not exist"),
    ],
)
def test_device_simulate_link_never_replaces_a_users_file(name, needle, tmp_path, capsys):
    (tmp_path / "keep_link.txt").write_text("precious")
    (tmp_path / "linkdir").mkdir()
    (tmp_path / "link_to_file").symlink_to(tmp_path / "keep_link.txt")
    before = _listing(tmp_path)
    code, lines = _run(f"device simulate --model synthetic --for 3 --link {tmp_path / name}", tmp_path, capsys)
    assert code == 2, (code, lines)
    assert len(lines) == 1 and "--link" in lines[0] and needle in lines[0], lines
    assert _listing(tmp_path) == before  # nothing left behind, nothing replaced
    assert (tmp_path / "keep_link.txt").read_text() == "precious"
    assert os.readlink(tmp_path / "link_to_file") == str(tmp_path / "keep_link.txt")


def test_device_simulate_link_where_no_link_can_be_made_names_link(tmp_path, capsys):
    """``--link /proc/x`` said "No such file or directory: /dev/pts/0", naming the pty."""
    code, lines = _run("device simulate --model synthetic --for 3 --link /proc/x", tmp_path, capsys)
    assert code == 2, (code, lines)
    assert len(lines) == 1 and "--link /proc/x" in lines[0] and "/dev/pts" not in lines[0], lines


def test_device_simulate_link_leaves_other_files_alone(tmp_path, capsys):
    """``--link f/myport`` deleted the user's ``f/myport.tmp`` (the link went through that fixed name)."""
    (tmp_path / "myport.tmp").write_text("data")
    (tmp_path / "old").symlink_to("/dev/pts/no-such-pty")  # a dangling link (a finger run before) is replaced
    code, lines = _run(f"device simulate --model synthetic --for 0.2 --link {tmp_path / 'myport'}", tmp_path, capsys)
    assert code == 0, lines
    code, lines = _run(f"device simulate --model synthetic --for 0.2 --link {tmp_path / 'old'}", tmp_path, capsys)
    assert code == 0, lines
    assert sorted(p.name for p in tmp_path.iterdir()) == ["myport.tmp"]  # both links removed at the end
    assert (tmp_path / "myport.tmp").read_text() == "data"


def test_virtual_device_link_moves_to_the_new_pty_and_survives_a_users_replacement(tmp_path):
    """The link follows a reopened pty through a uniquely named temporary link; a link the user put in its place
    meanwhile is kept at close."""
    from bayestouch.hardware.simulator import VirtualDevice

    link = tmp_path / "finger"
    sim = VirtualDevice(None, link=link)
    first = sim.open()
    assert os.readlink(link) == first
    sim._close_pty()
    second = sim.open()  # as after an injected disconnect
    assert os.readlink(link) == second
    assert sorted(p.name for p in tmp_path.iterdir()) == ["finger"]
    link.unlink()
    (tmp_path / "mine.txt").write_text("mine")
    link.symlink_to(tmp_path / "mine.txt")  # a link of the user's: close removed every link there
    sim.close()
    assert link.read_text() == "mine"
