"""The notebook API after the sixth review: its switches (``overwrite``, ``resume``, ``progress``,
``stop_when_converged``) take only True or False, refused before any folder is touched; a ``pandas.DataFrame`` is
read by its column names as the CSV loader reads a file; contacts in millimetres or centimetres get the loader's
unit hint; wrong argument types (a scene object for a shape, a float count, a non-path) are one-line
:class:`BadInput` naming the argument."""

from __future__ import annotations

import pathlib

import numpy as np
import pandas as pd
import pytest

import bayestouch as bt
from bayestouch.errors import BadInput
from bayestouch.params import MODELS

EGG_CSV = MODELS.parent / "data" / "contacts" / "egg.csv"
SUMMARY = '{"derived": {}, "diagnostics": {}, "model": {}}'
FAST = dict(steps=50, budget_s=1, progress=False)


def _one_line(exc_info):
    text = str(exc_info.value)
    assert "\n" not in text and "\r" not in text, text
    return text


@pytest.fixture(scope="module")
def egg_table():
    return pd.read_csv(EGG_CSV)


@pytest.mark.parametrize("name", ["overwrite", "resume", "progress", "stop_when_converged"])
@pytest.mark.parametrize("value", ["no", 0.0, None, 1])
def test_fit_switches_are_bools(tmp_path, egg_table, name, value):
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text(SUMMARY)
    with pytest.raises(BadInput) as e:
        bt.fit(egg_table[["x", "y", "z"]].to_numpy(), out, **{**FAST, name: value})
    assert _one_line(e) == f"{name}: expected True or False, got {value!r}"
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]  # nothing set aside


def test_numpy_bool_switch_is_accepted(egg_table):
    fit = bt.fit(egg_table[["x", "y", "z"]].to_numpy(), steps=50, budget_s=1, progress=np.False_)
    assert isinstance(fit, bt.Fit)


def test_simulate_and_save_switches_are_bools(tmp_path):
    rec = tmp_path / "s.nc"
    rec.write_bytes(b"earlier")
    with pytest.raises(BadInput, match=r"^overwrite: expected True or False, got 'no'$"):
        bt.simulate("sphere", strokes=1, duration=0.5, out=rec, overwrite="no")
    with pytest.raises(BadInput, match=r"^progress: expected True or False, got 'no'$"):
        bt.simulate("sphere", strokes=1, duration=0.5, progress="no")
    assert rec.read_bytes() == b"earlier" and sorted(p.name for p in tmp_path.iterdir()) == ["s.nc"]
    with pytest.raises(BadInput, match=r"^overwrite: expected True or False, got 'no'$"):
        bt.calibrate(rec, "sphere", out=tmp_path / "d.toml", overwrite="no")
    folder = tmp_path / "f"
    folder.mkdir()
    (folder / "summary.json").write_text(SUMMARY)
    with pytest.raises(BadInput, match=r"^overwrite: expected True or False, got 'yes'$"):
        bt.Fit(folder).save(tmp_path / "g", overwrite="yes")


def _means(fit):
    return fit.summary()["mean"].to_numpy()


def test_dataframe_columns_by_name(egg_table):
    xyz = egg_table[["x", "y", "z"]]
    a = bt.fit(xyz, seed=0, **FAST)
    b = bt.fit(xyz[["z", "x", "y"]], seed=0, **FAST)
    np.testing.assert_array_equal(_means(a), _means(b))  # the same contacts, the same fit


def test_dataframe_normals_read():
    from bayestouch.api import _contacts

    table = pd.read_csv(EGG_CSV)
    cp = _contacts(table)
    want = bt.load_contact_points(EGG_CSV)
    np.testing.assert_array_equal(cp.points, want.points)
    np.testing.assert_array_equal(cp.normals, want.normals)
    cp = _contacts(table[["nz", "x", "ny", "y", "nx", "z"]].rename(columns=str.upper))
    np.testing.assert_array_equal(cp.normals, want.normals)


def test_dataframe_free_rows_and_force(egg_table):
    from bayestouch.api import _contacts

    t = egg_table[["x", "y", "z"]].copy()
    t["force"] = 0.1
    t["contact"] = True
    t.loc[0, "contact"] = False
    cp = _contacts(t)
    assert cp.points.shape == (len(t) - 1, 3) and cp.free.shape == (1, 3)
    np.testing.assert_array_equal(cp.force, np.full(len(t) - 1, 0.1))
    t.loc[3, "force"] = -1.0
    with pytest.raises(BadInput, match=r"^data: data row 4, column force is -1\.0 N, negative"):
        _contacts(t)


def test_dataframe_without_xyz_names_its_columns(egg_table):
    bad = pd.DataFrame(egg_table[["x", "y", "z"]].to_numpy(), columns=["a", "b", "c"])
    with pytest.raises(BadInput) as e:
        bt.fit(bad, **FAST)
    text = _one_line(e)
    assert text.startswith("data: a table without column(s) x,y,z (its columns: 'a', 'b', 'c')"), text


def test_dataframe_nan_cell(egg_table):
    t = egg_table[["x", "y", "z"]].copy()
    t.loc[4, "y"] = np.nan
    with pytest.raises(BadInput, match=r"^data: data row 5, column y is empty; expected a number in metres$"):
        bt.fit(t, **FAST)


@pytest.mark.parametrize(("factor", "unit"), [(1000, "millimetres"), (100, "centimetres")])
def test_array_in_other_units_gets_hint(egg_table, factor, unit):
    points = egg_table[["x", "y", "z"]].to_numpy() * factor
    with pytest.raises(BadInput) as e:
        bt.fit(points, **FAST)
    text = _one_line(e)
    assert "more than twice the prior's largest semi-axis" in text
    assert unit in text and f"divide by {factor:g} if they are {unit}" in text


def test_sample_surface_takes_scene_object():
    egg = bt.load_object("egg")
    np.testing.assert_array_equal(bt.sample_surface(egg, 5, seed=0), bt.sample_surface(egg.shape, 5, seed=0))
    with pytest.raises(BadInput, match=r"^shape: expected an NEllipsoid"):
        bt.sample_surface("egg", 5)


@pytest.mark.parametrize("count", [2.0, "2", True])
def test_random_strokes_count_is_integer(count):
    with pytest.raises(BadInput) as e:
        bt.random_strokes(bt.load_object("egg"), count, seed=0)
    assert _one_line(e).startswith("count: expected an integer number of strokes ≥ 1")


@pytest.mark.parametrize("value", [None, 3, b"egg"])
def test_load_object_needs_path_or_name(value):
    with pytest.raises(BadInput) as e:
        bt.load_object(value)
    assert _one_line(e).startswith("path: expected a path or an object name")


@pytest.mark.parametrize("value", [3, b"dir", None])
def test_fit_load_needs_path(value):
    with pytest.raises(BadInput) as e:
        bt.Fit.load(value)
    assert _one_line(e).startswith("folder: expected a path")


def test_fit_load_takes_pathlike(tmp_path):
    (tmp_path / "summary.json").write_text(SUMMARY)
    assert bt.Fit.load(pathlib.PurePath(tmp_path)).folder == tmp_path
