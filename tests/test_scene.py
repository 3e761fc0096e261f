"""Scene objects (TOML, defects) and finger paths."""

from pathlib import Path

import numpy as np
import pytest

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.scene.objects import Defect, SceneObject, load_object, object_from_dict
from bayestouch.scene.paths import random_paths, ray_hits, section_path

OBJECTS = sorted((Path(__file__).parent.parent / "models" / "objects").glob("*.toml"))


@pytest.mark.parametrize("path", OBJECTS, ids=lambda p: p.stem)
def test_shipped_objects_load(path):
    obj = load_object(path)
    assert obj.name and float(obj.shape.n) >= 1.0
    assert np.all(np.asarray(obj.shape.axes) < 0.2)  # metres, hand-sized
    v, f = obj.mesh(12)
    assert v.shape[1] == 3 and np.isfinite(v).all()


def test_plate_matches_paper_size():
    plate = load_object(OBJECTS[0].parent / "graphite_plate.toml")
    assert np.allclose(2 * np.asarray(plate.shape.axes), [0.09, 0.05, 0.01])  # 9 × 5 × 1 cm (Sec. 3)
    kinds = sorted({d.kind for d in plate.defects})
    assert kinds == ["bump", "crack", "shallow"]


GOOD = {"shape": {"centre_m": [0, 0, 0], "axes_m": [0.03, 0.02, 0.01], "n": 2.0}}


@pytest.mark.parametrize(
    "doc,needle",
    [
        ({}, "[shape]"),
        ({"shape": {**GOOD["shape"], "axes_m": [30, 20, 10]}}, "millimetres"),
        ({"shape": {**GOOD["shape"], "axes_m": [0.03, 0.02]}}, "axes_m"),
        ({"shape": {**GOOD["shape"], "axes_m": [0.03, -0.02, 0.01]}}, "axes_m"),
        ({"shape": {**GOOD["shape"], "n": 0.5}}, "'n'"),
        ({"shape": {**GOOD["shape"], "n": "two"}}, "'n'"),
        ({**GOOD, "defects": [{"kind": "dent", "centre_m": [0, 0, 0.01], "radius_m": 0.001, "depth_m": 1e-4}]}, "kind"),
        (
            {**GOOD, "defects": [{"kind": "crack", "centre_m": [0, 0, 0.01], "radius_m": 0.001, "depth_m": 1e-4}]},
            "end_m",
        ),
        (
            {**GOOD, "defects": [{"kind": "bump", "centre_m": [0, 0, 0.01], "radius_m": 0.0, "depth_m": 1e-4}]},
            "radius_m",
        ),
    ],
)
def test_bad_object_documents(doc, needle):
    with pytest.raises(BadInput) as e:
        object_from_dict(doc, "obj.toml")
    msg = str(e.value)
    assert needle in msg and "\n" not in msg and msg.startswith("obj.toml")


def test_bad_object_files(tmp_path):
    with pytest.raises(BadInput, match="no such file"):
        load_object(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[shape\ncentre_m = [")
    with pytest.raises(BadInput, match="not valid TOML"):
        load_object(bad)


def test_defect_heights():
    y = np.array([[0.0, 0.0, 0.01], [0.003, 0.0, 0.01], [0.05, 0.0, 0.01]])
    bump = Defect("bump", (0.0, 0.0, 0.01), 0.003, 5e-4)
    h = bump.height(y)
    assert h[0] == pytest.approx(5e-4) and h[1] == pytest.approx(5e-4 * np.exp(-0.5)) and h[2] < 1e-12
    shallow = Defect("shallow", (0.0, 0.0, 0.01), 0.003, 5e-4)
    assert np.allclose(shallow.height(y), -h)
    crack = Defect("crack", (-0.01, 0.0, 0.01), 0.001, 4e-4, end=(0.01, 0.0, 0.01))
    along = np.array([[x, 0.0, 0.01] for x in np.linspace(-0.01, 0.01, 5)])
    assert np.allclose(crack.height(along), -4e-4)  # full depth anywhere on the segment
    assert crack.height(np.array([[0.0, 0.001, 0.01]]))[0] == pytest.approx(-4e-4 * np.exp(-0.5))


def test_ray_hits_sphere_exact():
    s = ne.NEllipsoid(jnp.array([0.01, 0.0, 0.0]), jnp.full(3, 0.02), jnp.zeros(3), jnp.array(2.0))
    dirs = np.random.default_rng(0).normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = ray_hits(s, np.array([0.01, 0.0, 0.0]), dirs)
    assert np.allclose(np.linalg.norm(hits - [0.01, 0.0, 0.0], axis=1), 0.02, atol=1e-12)


def test_section_path_on_surface_at_speed(shape):
    obj = SceneObject("t", shape)
    rate, speed = 20.0, 0.01
    path = section_path(obj, [0.2, 0.3, 1.0], offset=0.003, arc=np.pi, speed=speed, rate=rate)
    F = np.asarray(ne.inside_outside(shape, jnp.asarray(path.points)))
    assert np.allclose(F, 1.0, atol=1e-9)
    step = np.linalg.norm(np.diff(path.points, axis=0), axis=1)
    # chords of a curve walked at 1 cm/s, sampled at 20 Hz: 0.5 mm apart (chord ≤ arc)
    assert np.all(step <= speed / rate * (1 + 1e-6)) and np.median(step) == pytest.approx(speed / rate, rel=0.02)
    assert np.allclose(np.diff(path.time), 1 / rate)
    # all points lie in one plane (a section)
    c = path.points - path.points.mean(axis=0)
    assert np.linalg.svd(c, compute_uv=False)[-1] < 1e-9


def test_defects_displace_paths_along_normal():
    plate = load_object(OBJECTS[0].parent / "graphite_plate.toml")
    base = SceneObject("base", plate.shape)
    p_def = random_paths(plate, 3, seed=7, arc=np.pi)
    p_base = random_paths(base, 3, seed=7, arc=np.pi)
    for a, b in zip(p_def, p_base, strict=True):
        d = a.points - b.points
        h = np.einsum("ij,ij->i", d, b.normals)
        assert np.allclose(d, h[:, None] * b.normals, atol=1e-15)  # displacement along the normal
        assert np.allclose(h, plate.height(b.points))
    assert max(np.abs(plate.height(p.points)).max() for p in p_base) > 1e-5  # the paths do cross defects


def test_public_api_resolves_lazily():
    import subprocess
    import sys

    import bayestouch

    code = "import sys, bayestouch; print('jax' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.stdout.strip() == "False"  # importing the package does not load JAX
    for name in bayestouch.__all__:
        assert getattr(bayestouch, name) is not None
    with pytest.raises(AttributeError):
        bayestouch.no_such_thing  # noqa: B018


def test_object_names_resolve_in_a_users_models_folder_first(tmp_path):
    """``egg`` is the shipped egg, unless the parameter folder given has its own objects/egg.toml; a name in neither
    is one line naming both folders' objects."""
    import shutil

    from bayestouch.errors import BadInput
    from bayestouch.scene.objects import OBJECTS_DIR, load_object, resolve_object

    assert resolve_object("egg") == OBJECTS_DIR / "egg.toml"
    assert resolve_object("egg", tmp_path) == OBJECTS_DIR / "egg.toml"  # the user's folder has none
    (tmp_path / "objects").mkdir()
    text = (OBJECTS_DIR / "sphere.toml").read_text()
    (tmp_path / "objects" / "egg.toml").write_text(text)  # the user's "egg" is a sphere
    shutil.copy(OBJECTS_DIR / "box.toml", tmp_path / "objects" / "crate.toml")
    assert resolve_object("egg", tmp_path) == tmp_path / "objects" / "egg.toml"
    mine, shipped = load_object("egg", tmp_path), load_object("egg")
    sphere = load_object("sphere")
    assert np.allclose(np.asarray(mine.shape.axes), np.asarray(sphere.shape.axes))
    assert not np.allclose(np.asarray(shipped.shape.axes), np.asarray(sphere.shape.axes))
    assert resolve_object("crate", tmp_path).name == "crate.toml"
    with pytest.raises(BadInput, match="unknown object 'teapot'.*crate.*egg"):
        resolve_object("teapot", tmp_path)
