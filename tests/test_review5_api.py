"""The notebook API after the fifth review: ``Fit.save(overwrite=True)`` sets the earlier run aside and leaves
nothing stale beside the new one; ``simulate``/``calibrate`` set an earlier file aside only with ``overwrite`` (so a
file written meanwhile by another run is detected, not moved); ``fit`` takes the command line's ``"MIN:MAX"`` and
``"LxMxK"`` forms and refuses malformed ``size_prior``, ``ffd`` and ``free`` in one line naming them; malformed
occupancy query points and a ``posterior.nc`` without a posterior are one-line :class:`BadInput`."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import bayestouch as bt
from bayestouch.errors import BadInput
from bayestouch.io.runfolder import LOCK_FILE
from bayestouch.params import MODELS

SPHERE_REC = MODELS.parent / "data" / "recordings" / "sphere.nc"
SUMMARY = '{"derived": {}, "diagnostics": {}, "model": {}}'


def _aside(folder):
    return sorted(folder.glob("replaced-*"))


def _one_line(exc_info):
    text = str(exc_info.value)
    assert "\n" not in text and "\r" not in text, text
    return text


# ---------------------------------------------------------------------------------------------------------
# 1. Fit.save over a folder holding an earlier run


def test_save_with_overwrite_sets_every_earlier_file_aside_and_says_where(tmp_path, capsys):
    """save('s2', overwrite=True) replaced summary.json, chain.h5, posterior.nc in place without a word and left the
    earlier run's smc.npz (and any other file) beside the new run."""
    src = tmp_path / "new"
    src.mkdir()
    new = {"summary.json": SUMMARY.encode(), "chain.h5": b"new chain", "posterior.nc": b"new posterior"}
    for name, data in new.items():
        (src / name).write_bytes(data)
    dst = tmp_path / "s2"
    dst.mkdir()
    old = {
        "summary.json": b'{"old": 1}',
        "chain.h5": b"old chain",
        "posterior.nc": b"old posterior",
        "smc.npz": b"old smc",
        "notes.txt": b"the user's notes",
    }
    for name, data in old.items():
        (dst / name).write_bytes(data)
    fit = bt.Fit.load(src)
    with pytest.raises(BadInput, match="already holds a run") as e:
        fit.save(dst)
    _one_line(e)
    assert {p.name: p.read_bytes() for p in dst.iterdir()} == old  # refused: nothing touched
    capsys.readouterr()
    assert fit.save(dst, overwrite=True) == dst
    (aside,) = _aside(dst)
    assert {p.name: p.read_bytes() for p in aside.iterdir()} == old  # every earlier file kept, byte for byte
    # nothing stale beside the new run (the folder's lock file, empty of any holder, stays as in a fit's folder)
    assert {p.name: p.read_bytes() for p in dst.iterdir() if p.is_file() and p.name != LOCK_FILE} == new
    assert str(aside) in capsys.readouterr().err
    # a second overwrite keeps the first set-aside folder and adds another
    fit.save(dst, overwrite=True)
    assert len(_aside(dst)) == 2 and {p.name for p in dst.iterdir() if p.is_file()} - {LOCK_FILE} == set(new)


def test_save_refuses_a_folder_holding_any_file_of_a_run(tmp_path):
    """A folder holding only the smc.npz of an interrupted run was written into, mixing the two runs."""
    src = tmp_path / "new"
    src.mkdir()
    (src / "summary.json").write_text(SUMMARY)
    dst = tmp_path / "old"
    dst.mkdir()
    (dst / "smc.npz").write_bytes(b"old smc")
    with pytest.raises(BadInput, match="already holds a run.*smc.npz") as e:
        bt.Fit.load(src).save(dst)
    _one_line(e)
    assert [p.name for p in dst.iterdir()] == ["smc.npz"]


# ---------------------------------------------------------------------------------------------------------
# 2. simulate / calibrate set an earlier file aside only with overwrite

SIM = dict(strokes=1, seed=2, duration=0.5, rate=20.0, depth=3e-4, mode="empirical")


def test_simulate_detects_a_file_written_meanwhile_and_sets_aside_only_with_overwrite(tmp_path, monkeypatch, capsys):
    """Two simulate runs to the same out at once both exited 0: the later one moved the earlier's file aside with
    an "--overwrite:" message although overwrite was never given."""
    import bayestouch.physics.virtual as virtual

    out = tmp_path / "same.nc"
    bt.simulate("sphere", **SIM, out=out)
    first = out.read_bytes()
    with pytest.raises(BadInput, match="already exists") as e:
        bt.simulate("sphere", **SIM, out=out)
    _one_line(e)
    assert out.read_bytes() == first

    # another run writes the same name while this one simulates (after its check that out is free)
    race = tmp_path / "race.nc"
    real = virtual.recording_dataset

    def concurrent(*args, **kwargs):
        race.write_bytes(b"the other run's recording")
        return real(*args, **kwargs)

    monkeypatch.setattr(virtual, "recording_dataset", concurrent)
    capsys.readouterr()
    with pytest.raises(BadInput, match="appeared while this run wrote it|already exists and is kept") as e:
        bt.simulate("sphere", **SIM, out=race)
    _one_line(e)
    assert race.read_bytes() == b"the other run's recording"  # kept where it is, not moved aside
    assert not _aside(tmp_path) and "--overwrite" not in capsys.readouterr().err
    monkeypatch.setattr(virtual, "recording_dataset", real)

    bt.simulate("sphere", **{**SIM, "seed": 3}, out=out, overwrite=True)
    (aside,) = _aside(tmp_path)
    assert (aside / "same.nc").read_bytes() == first and out.read_bytes() != first
    assert str(aside) in capsys.readouterr().err


def test_calibrate_detects_a_file_written_meanwhile_and_sets_aside_only_with_overwrite(tmp_path, monkeypatch, capsys):
    import bayestouch.inference.raw.calibrate as rc
    from bayestouch.io.device_file import DeviceCalibration, read_device_file

    cal = DeviceCalibration(np.zeros(256), np.full(256, 1e-3), 1.0, "empirical", {})
    dev = tmp_path / "finger.toml"

    def concurrent(*args, **kwargs):
        dev.write_text("# the other run's device file\n")
        return cal

    monkeypatch.setattr(rc, "calibrate_device", concurrent)
    capsys.readouterr()
    with pytest.raises(BadInput, match="appeared while this run wrote it|already exists and is kept") as e:
        bt.calibrate(SPHERE_REC, "sphere", out=dev)
    _one_line(e)
    assert dev.read_text() == "# the other run's device file\n"
    assert not _aside(tmp_path) and "--overwrite" not in capsys.readouterr().err

    monkeypatch.setattr(rc, "calibrate_device", lambda *a, **k: cal)
    bt.calibrate(SPHERE_REC, "sphere", out=dev, overwrite=True)
    (aside,) = _aside(tmp_path)
    assert (aside / "finger.toml").read_text() == "# the other run's device file\n"
    np.testing.assert_array_equal(read_device_file(dev).log_gain, cal.log_gain)
    assert str(aside) in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------------------
# 3. fit's size_prior, ffd and free


@pytest.fixture
def points():
    d = np.random.default_rng(1).normal(size=(60, 3))
    return np.array([0.03, 0.02, 0.015]) * d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.fixture
def forwarded(monkeypatch):
    """run_contact_fit replaced by one that records what fit passes it and writes a minimal run folder."""
    import bayestouch.inference.run as run

    seen = {}

    def fake(points, out, **kwargs):
        seen.update(kwargs)
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.json").write_text(SUMMARY)

    monkeypatch.setattr(run, "run_contact_fit", fake)
    return seen


def test_fit_takes_the_command_lines_size_prior_and_ffd_forms(points, forwarded, tmp_path):
    """size_prior="0.01:0.1" raised TypeError with_size_prior() takes 3 positional arguments but 9 were given;
    ffd="3x3x3" ValueError invalid literal for int()."""
    bt.fit(points, tmp_path / "a", size_prior="0.01:0.1", progress=False)
    assert forwarded["size_prior"] == (0.01, 0.1)
    bt.fit(points, tmp_path / "b", ffd="3x4x5", progress=False)
    assert forwarded["ffd"] == (3, 4, 5)
    bt.fit(points, tmp_path / "c", size_prior=[0.02, 0.2], ffd=np.array([2, 2, 3]), free=[[0.1, 0.1, 0.1]])
    assert forwarded["size_prior"] == (0.02, 0.2) and forwarded["ffd"] == (2, 2, 3)
    np.testing.assert_array_equal(forwarded["free"], [[0.1, 0.1, 0.1]])


@pytest.mark.parametrize(
    "option,value,needle",
    [
        ("size_prior", "0.01-0.1", "MIN:MAX"),
        ("size_prior", "0.1:0.01", "MIN < MAX"),
        ("size_prior", 0.1, r"\(min, max\)"),
        ("size_prior", (0.01, 0.05, 0.1), r"\(min, max\)"),
        ("size_prior", ("a", "b"), r"\(min, max\)"),
        ("size_prior", np.ones((2, 2)), r"\(min, max\)"),
        ("size_prior", [(0.01,), (0.1, 0.2)], r"\(min, max\)"),
        ("ffd", "3x3", "6x6x3"),
        ("ffd", "axbxc", "6x6x3"),
        ("ffd", (3.5, 3, 3), r"\(l, m, k\)"),
        ("ffd", (3, 3), r"\(l, m, k\)"),
        ("ffd", 3, r"\(l, m, k\)"),
        ("ffd", [(3,), (3, 3), 3], r"\(l, m, k\)"),
        ("ffd", (1, 3, 3), r"\[2, 8\]"),
        ("ffd", "9x9x9", r"\[2, 8\]"),
        ("free", np.ones((5, 2)), r"\(K, 3\).*shape \(5, 2\)"),
        ("free", [0.1, 0.1, 0.1], r"\(K, 3\).*shape \(3,\)"),
        ("free", np.full((2, 3), np.nan), "NaN"),
        ("free", "0,0,0", r"\(K, 3\)"),
        ("free", np.ones((2, 3)) * 1j, r"\(K, 3\)"),
        ("free", [[0.1, 0.1], [0.1]], r"\(K, 3\)"),
    ],
)
def test_fit_refuses_malformed_size_prior_ffd_and_free_naming_them(points, forwarded, tmp_path, option, value, needle):
    """free=np.ones((5, 2)) raised ValueError cannot reshape array of size 10 into shape (3)."""
    out = tmp_path / "run"
    with pytest.raises(BadInput, match=needle) as e:
        bt.fit(points, out, progress=False, **{option: value})
    assert _one_line(e).startswith(f"{option}: ")
    assert not forwarded and not out.exists()  # refused before anything ran or was written


# ---------------------------------------------------------------------------------------------------------
# 4. occupancy query points


@pytest.mark.parametrize(
    "value,needle",
    [
        ("0,0,0", "got str"),
        (b"0,0,0", "got bytes"),
        ([["a", "b", "c"]], "got list"),
        ([[0.0, 0.0, 0.0], [0.0, 0.0]], "got list"),
        (np.zeros((2, 3)) + 1j, "got ndarray"),
        ({"x": 0}, "got dict"),
    ],
)
def test_occupancy_at_refuses_malformed_points_naming_them(tmp_path, value, needle):
    """at("0,0,0") raised ValueError could not convert string to float; complex points were answered, their
    imaginary part dropped."""
    from bayestouch.io.occupancy import Occupancy

    axis = np.linspace(-0.01, 0.01, 4)
    occ = Occupancy(axis, axis, axis, np.full((4, 4, 4), 0.5), 10)
    with pytest.raises(BadInput, match=needle) as e:
        occ.at(value)
    assert _one_line(e).startswith("points: expected (N, 3)")
    assert occ.at([0.0, 0.0, 0.0]) == pytest.approx([0.5]) and occ.at([[1.0, 0, 0]]) == pytest.approx([0.0])


# ---------------------------------------------------------------------------------------------------------
# 5. a posterior.nc that holds no posterior


def test_a_posterior_nc_without_a_posterior_group_is_named(tmp_path):
    """A recording written as posterior.nc gave AttributeError: 'InferenceData' object has no attribute
    'posterior'."""
    (tmp_path / "summary.json").write_text(SUMMARY)
    shutil.copyfile(SPHERE_REC, tmp_path / "posterior.nc")
    fit = bt.Fit.load(tmp_path)
    for _ in range(2):  # and again: nothing half-loaded is kept
        with pytest.raises(BadInput, match=r"posterior\.nc: no posterior group") as e:
            fit.summary()
        _one_line(e)


def test_fit_refuses_ragged_contact_points_naming_data():
    """A ragged list of points raised numpy's ValueError (inhomogeneous shape) from np.iscomplexobj."""
    with pytest.raises(BadInput, match=r"data: expected contact points as an \(M, 3\) array") as e:
        bt.fit([[0.01, 0.0, 0.0], [0.0, 0.01]], progress=False)
    _one_line(e)


def test_size_prior_with_ffd_is_refused_in_the_api_as_on_the_command_line(tmp_path):
    """The FFD-marginalised fit keeps its own prior: bt.fit(size_prior=…, ffd=…) is refused in one line (it ran,
    silently dropping the size prior), before any folder is made."""
    import bayestouch as bt
    from bayestouch.errors import BadInput

    pts = bt.load_contact_points(Path(__file__).resolve().parents[1] / "data" / "contacts" / "egg.csv").points
    out = tmp_path / "run"
    with pytest.raises(BadInput, match="size_prior: the FFD-marginalised fit keeps its own prior"):
        bt.fit(pts, out, size_prior=(0.01, 0.1), ffd=(3, 3, 3), steps=50)
    assert not out.exists()


def test_save_waits_for_no_one_it_refuses_a_folder_in_use(tmp_path):
    """Fit.save(overwrite=True) into a folder another process is writing is refused in one line; nothing there is
    moved (it would have set the running fit's files aside from under it)."""
    import subprocess
    import sys

    import bayestouch as bt
    from bayestouch.errors import BadInput

    src = tmp_path / "src"
    pts = bt.load_contact_points(Path(__file__).resolve().parents[1] / "data" / "contacts" / "egg.csv").points
    fit = bt.fit(pts, src, steps=60, seed=0)
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "summary.json").write_text("{}")
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\nfrom bayestouch.io.runfolder import locked_run_folder\n"
            f"with locked_run_folder({str(busy)!r}):\n    print('held', flush=True)\n    time.sleep(60)\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(BadInput, match="in use by another bayestouch run"):
            fit.save(busy, overwrite=True)
        assert (busy / "summary.json").read_text() == "{}"
        assert not any(p.name.startswith("replaced-") for p in busy.iterdir())
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    fit.save(busy, overwrite=True)  # the holder gone, the earlier file is set aside
    assert any(p.name.startswith("replaced-") for p in busy.iterdir())
