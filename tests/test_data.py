"""The shipped data sets (data/): reproducible from data/regenerate.py, readable by the project's readers, with
the schema data/README.md states."""

import csv
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from bayestouch.io.contacts import load_contact_points
from bayestouch.io.files import read_csv_rows
from bayestouch.io.recording import COORDINATES, UNITS, read_recording

ROOT = Path(__file__).parent.parent
DATA = ROOT / "data"
OBJECTS = ("egg", "sphere", "box", "cylinder")
README = (DATA / "README.md").read_text(encoding="utf-8")


def _regenerate_module():
    spec = importlib.util.spec_from_file_location("bayestouch_data_regenerate", DATA / "regenerate.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_sizes_and_every_file_is_documented():
    files = [p for p in DATA.rglob("*") if p.is_file() and p.name not in ("README.md", "regenerate.py")]
    files = [p for p in files if "__pycache__" not in p.parts]
    assert sum(p.stat().st_size for p in files) < 8e6  # the whole of data/ under 8 MB
    for p in files:
        assert p.stat().st_size < 1.5e6, p
    regen = set(_regenerate_module().targets())
    for p in files:
        rel = p.relative_to(DATA).as_posix()
        # each file is named in the README (the recordings and contact sets by their brace pattern)
        stem = rel.split("/")[0] + "/{egg,sphere,box,cylinder}." + p.suffix[1:] if "/" in rel else rel
        assert f"`{stem}`" in README, rel
        assert rel in regen or rel.endswith("_paper.csv"), f"{rel}: neither regenerated nor a paper table"
    # and every regenerated file is shipped (negative control of the check above: a name not in data/)
    shipped = {p.relative_to(DATA).as_posix() for p in files}
    assert regen <= shipped
    assert "recordings/teapot.nc" not in shipped


@pytest.mark.parametrize("name", OBJECTS)
def test_recordings_load_with_the_stated_schema(name):
    ds = read_recording(DATA / "recordings" / f"{name}.nc")
    assert ds.attrs["object"] == name and ds.attrs["seed"] == "0"
    assert ds.attrs["object_file"] == f"models/objects/{name}.toml"  # relative: names no machine
    assert dict(ds.sizes) == {"frame": 78, "taxel": 256, "xyz": 3, "wire": 3, "uv": 2, "stroke": 3}
    for var, unit in UNITS.items():
        assert ds[var].attrs["units"] == unit, var
        assert f"`{var}`" in README, var  # the README's table names every variable
    assert np.array_equal(np.unique(ds["stroke_index"]), [0, 1, 2])
    assert np.all(np.diff(ds["time"].values) > 0)
    i = ds["taxel_current"].values
    assert np.all(np.isfinite(i)) and np.all(i > 0)  # amperes, a transistor's current is positive
    assert 1e-9 < np.median(i) < 1e-5  # and of the order of the taxels' 0.1 µA, not mA or pA
    f = ds["contact_force"].values
    assert 0.01 < f.max() < 1.0  # newtons: the pad touched the object, gently
    assert np.allclose(np.linalg.norm(ds["contact_normal"].values, axis=1), 1.0, atol=1e-9)
    assert np.allclose(ds["stroke_depth"].values, 3e-4)  # the README's 0.3 mm
    # the contact points lie on the object: inside–outside function of the true shape ≈ 1
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.scene.objects import load_object

    obj = load_object(ROOT / ds.attrs["object_file"])
    io = np.asarray(ne.inside_outside(obj.shape, ds["contact_point"].values))
    assert np.allclose(io, 1.0, atol=0.05)


@pytest.mark.parametrize("name", OBJECTS)
def test_contact_sets_load_and_lie_near_the_surface(name):
    cp = load_contact_points(DATA / "contacts" / f"{name}.csv")
    with open(DATA / "contacts" / f"{name}.csv", newline="") as fh:
        assert next(csv.reader(fh)) == ["x", "y", "z", "nx", "ny", "nz"]
    assert 300 <= len(cp.points) <= 450 and cp.normals is not None and cp.force is None
    assert np.allclose(np.linalg.norm(cp.normals, axis=1), 1.0, atol=1e-9)
    # the stated noise: σ = 0.1 mm isotropic, so the distance along the normal to the true surface has
    # sd 0.1 mm. First-order distance (|F−1| / |∇F|) of the true shape; the sample sd of ~380 normal deviates
    # is within 0.1 mm · (1 ± 4/sqrt(2·380)) = ±15 % (4 standard errors), plus the first-order error.
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.scene.objects import load_object

    obj = load_object(ROOT / "models" / "objects" / f"{name}.toml")
    dist = np.asarray(ne.first_order_distance(obj.shape, ne.to_local(obj.shape, cp.points))[0])
    sd = float(np.sqrt(np.mean(dist**2)))
    assert 0.8e-4 < sd < 1.2e-4, sd
    # negative control: against another object the points are centimetres off
    other = load_object(ROOT / "models" / "objects" / ("box.toml" if name != "box" else "egg.toml"))
    far = np.asarray(ne.first_order_distance(other.shape, ne.to_local(other.shape, cp.points))[0])
    assert float(np.sqrt(np.mean(far**2))) > 1e-3


def test_plate_paths_load_with_the_stated_schema():
    rows = read_csv_rows(DATA / "graphite_plate_paths.csv")
    assert list(rows[0]) == ["path", "time", "x", "y", "z", "nx", "ny", "nz"]
    path = np.array([int(r["path"]) for r in rows])
    assert np.array_equal(np.unique(path), np.arange(1, 26))  # the paper's 25 paths, numbered from 1
    assert np.all(np.diff(path) >= 0)
    t = np.array([float(r["time"]) for r in rows])
    for k in range(1, 26):  # 20 samples per second along each path
        assert np.allclose(np.diff(t[path == k]), 0.05)
    cp = load_contact_points(DATA / "graphite_plate_paths.csv")
    assert len(cp.points) == len(rows) == 4623
    # the plate is 90 × 50 × 10 mm about the origin
    assert np.all(np.abs(cp.points) <= np.array([0.045, 0.025, 0.005]) + 2e-4)


def test_plate_paths_are_those_of_reproduce_paper():
    """The shipped paths are bayestouch.paper.plate_data's (what reproduce-paper and Table 1 use)."""
    from bayestouch.paper import plate_data
    from bayestouch.scene.objects import load_object

    plate = load_object(ROOT / "models" / "objects" / "graphite_plate.toml")
    cp = load_contact_points(DATA / "graphite_plate_paths.csv")
    assert np.allclose(cp.points, plate_data(plate, 25, seed=0, rate=20.0), rtol=0, atol=1e-12)  # 1 pm
    assert not np.allclose(cp.points[:100], plate_data(plate, 25, seed=1, rate=20.0)[:100], atol=1e-6)


def test_contact_set_regenerates_identically(tmp_path):
    """A shipped file is reproducible: rerun its recipe and compare the text (same platform) or, failing that,
    the numbers to 1e-12 m (an XLA build on another CPU may differ in the last bits of a ray hit)."""
    mod = _regenerate_module()
    out = mod.contact_set("sphere", tmp_path / "sphere.csv")
    new, old = out.read_text(), (DATA / "contacts" / "sphere.csv").read_text()
    if new != old:
        a, b = load_contact_points(out), load_contact_points(DATA / "contacts" / "sphere.csv")
        assert np.allclose(a.points, b.points, rtol=0, atol=1e-12)
        assert np.allclose(a.normals, b.normals, rtol=0, atol=1e-12)
    # negative control: another noise seed changes the file
    mod.CONTACT_SEED += 1
    other = mod.contact_set("sphere", tmp_path / "other.csv")
    assert not np.allclose(load_contact_points(other).points, load_contact_points(out).points, atol=1e-6)


@pytest.mark.slow
def test_recording_regenerates(tmp_path, monkeypatch):
    """The box recording rerun by its recipe equals the shipped one: every variable to 1e-9 relative (round-off
    of a different CPU; on this one the arrays are identical), the attributes exactly."""
    mod = _regenerate_module()
    monkeypatch.chdir(ROOT)
    new = read_recording(mod.recording("box", tmp_path / "box.nc"))
    old = read_recording(DATA / "recordings" / "box.nc")
    assert new.attrs == old.attrs and set(new.data_vars) == set(old.data_vars) and set(new.coords) == set(old.coords)
    for v in [*old.data_vars, *COORDINATES]:
        np.testing.assert_allclose(new[v].values, old[v].values, rtol=1e-9, atol=0, err_msg=v)
    # negative control: the sphere's recording (same seed, so the same noise) is not the box's
    sph = read_recording(DATA / "recordings" / "sphere.nc")
    assert not np.allclose(sph["pressure"].values, old["pressure"].values, rtol=1e-3)
