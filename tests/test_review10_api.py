"""Issue 24, tenth review: functions of ``bayestouch.__all__`` given arguments of the wrong form raised raw Python
errors (AttributeError, TypeError, IndexError, MemoryError, scipy's and numpy's messages), ran for minutes, or
returned empty or degenerate results; each now refuses in one line naming the argument, and the right form passes
(the control)."""

from __future__ import annotations

import numpy as np
import pytest

import bayestouch as bt
from bayestouch.errors import BadInput


def _one_line(e) -> str:
    text = str(e.value)
    assert "\n" not in text, text
    return text


@pytest.fixture(scope="module")
def sphere():
    return bt.load_object("sphere")


@pytest.fixture(scope="module")
def finger():
    return bt.load_finger()


def test_random_strokes_and_paths_share_their_checks(sphere):
    from bayestouch.scene.paths import MAX_PATHS

    with pytest.raises(BadInput, match=f"count: expected an integer number of strokes ≥ 1 \\(at most {MAX_PATHS:,}"):
        bt.random_strokes(sphere, 10**9)  # ran for minutes
    for call, needle in (
        (lambda: bt.random_paths("egg", 1), "obj: expected a SceneObject"),
        (lambda: bt.random_paths(sphere, "a"), "count: expected an integer number of paths"),
        (lambda: bt.random_paths(sphere, 2, rate=-5), "rate: expected a finite number > 0"),  # empty paths
        (lambda: bt.random_paths(sphere, 2, speed=-0.01), "speed: expected a finite number > 0"),
        (lambda: bt.random_paths(sphere, 2, max_offset=1.5), "max_offset"),
        (lambda: bt.random_strokes(sphere, 1, speed="a"), "speed: expected a finite number > 0"),
        (lambda: bt.random_strokes(sphere, 1, depth="x"), "depth"),
        (lambda: bt.random_strokes(sphere, 1, seed="x"), "seed: expected an integer ≥ 0"),
    ):
        with pytest.raises(BadInput, match=needle) as e:
            call()
        _one_line(e)
    paths = bt.random_paths(sphere, 2, seed=0)
    assert len(paths) == 2 and all(len(p.points) > 1 for p in paths)
    assert len(bt.random_strokes(sphere, 2, seed=0)) == 2


def test_simulate_names_its_depth_and_stroke_limit():
    from bayestouch.scene.paths import MAX_PATHS

    with pytest.raises(BadInput, match="depth: each pressing depth"):
        bt.simulate("sphere", depth="x")
    with pytest.raises(BadInput, match=f"strokes: expected an integer from 1 to {MAX_PATHS:,}"):
        bt.simulate("sphere", strokes=MAX_PATHS + 1, duration=0.04)


def test_patch_posterior_takes_the_finger_load_finger_returns(finger):
    with pytest.raises(BadInput, match="finger: expected bt.load_finger"):
        bt.patch_posterior(np.zeros(5), "abc", seed=0)
    with pytest.raises(BadInput, match="currents"):
        bt.patch_posterior("abc", finger, seed=0)
    # control: the VirtualFinger is accepted (the next check, of the currents' length, is reached) as is its .finger
    n = int(np.asarray(finger.finger.reference).size)
    for f in (finger, finger.finger):
        with pytest.raises(BadInput, match=f"currents: expected currents of shape .* N = {n} taxels"):
            bt.patch_posterior(np.zeros(5), f, seed=0)


def test_paths_that_are_not_paths_are_named(tmp_path):
    for call, name in (
        (lambda: bt.read_recording(5), "path"),
        (lambda: bt.read_recording(None), "path"),
        (lambda: bt.load_contact_points(5), "path"),
        (lambda: bt.load_object("egg", models=5), "models"),
        (lambda: bt.load_finger(models=5), "models"),
        (lambda: bt.load_occupancy(5), "path"),
    ):
        with pytest.raises(BadInput, match=f"{name}: expected a path") as e:
            call()
        _one_line(e)
    assert bt.load_object("egg", models=tmp_path).name == "egg"  # a folder without the object: the shipped one


def test_recordings_and_strokes_of_the_wrong_form(sphere, finger, tmp_path):
    with pytest.raises(BadInput, match="recording: expected the path of a .nc recording or an xarray Dataset"):
        bt.calibrate({"a": 1}, "sphere")
    strokes = bt.random_strokes(sphere, 1, seed=0)
    with pytest.raises(BadInput, match="strokes: expected a list of strokes"):
        bt.record_strokes(sphere, "abc", finger, 0)
    with pytest.raises(BadInput, match="stroke 0 is int"):
        bt.record_strokes(sphere, [1], finger, 0)
    with pytest.raises(BadInput, match="vf: expected the VirtualFinger"):
        bt.record_strokes(sphere, strokes, None, 0)
    with pytest.raises(BadInput, match="obj: expected a SceneObject"):
        bt.record_strokes("sphere", strokes, finger, 0)
    short = [s._replace(contact=s.contact[:3], normal=s.normal[:3], time=s.time[:3]) for s in strokes]
    with pytest.raises(BadInput, match="stroke 0: tangent must be \\(3, 3\\)"):  # was JAX's vmap error
        bt.record_strokes(sphere, short, finger, 0)
    short = [s._replace(tangent=s.tangent[:3]) for s in short]
    rec = bt.record_strokes(sphere, short, finger, 0)  # control
    assert rec["taxel_current"].shape[0] == 3


def test_raw_fit_stroke_selection_is_checked_before_any_work(tmp_path):
    from bayestouch.inference.raw.data import check_stroke_selection

    with pytest.raises(BadInput, match="strokes: expected stroke indices"):
        bt.run_raw_fit("missing.nc", tmp_path / "run", strokes="a")
    with pytest.raises(BadInput, match="stride must be an integer ≥ 1, got 'a'"):
        bt.run_raw_fit("missing.nc", tmp_path / "run", stride="a")
    with pytest.raises(BadInput, match="has no stroke 7"):
        check_stroke_selection([0, 7], np.array([0, 1, 2]))
    assert check_stroke_selection([0, 2], np.array([0, 1, 2])).tolist() == [0, 2]
    assert check_stroke_selection(np.int64(1)).tolist() == [1]
    assert not (tmp_path / "run").exists()


def test_table2_and_its_sizes(sphere):
    with pytest.raises(BadInput, match="obj: expected a SceneObject"):
        bt.reproduce_table2("egg")
    with pytest.raises(BadInput, match="sizes: expected FFD sizes 'LxMxK'"):
        bt.reproduce_table2(sphere, sizes=("9x9",))
    with pytest.raises(BadInput, match="sizes must be three integer lattice sizes"):
        bt.reproduce_table2(sphere, sizes=("99x2x2",))
    with pytest.raises(BadInput, match="epsilons"):
        bt.reproduce_table2(sphere, epsilons=(-1.0,))


def test_meshes_and_surface_samples(sphere):
    from bayestouch.geometry.mesh import MAX_MESH_RES

    shape = sphere.shape
    for res in (-1, "a", 10**6, 0, 2.5):
        with pytest.raises(BadInput, match=f"res: expected an integer resolution .* from 1 to {MAX_MESH_RES}"):
            bt.nellipsoid_mesh(shape, res)
    with pytest.raises(BadInput, match="res: expected an integer resolution"):
        bt.sample_surface(shape, 10, res=0)
    for seed in ("x", -1, 1.5):
        with pytest.raises(BadInput, match="seed: expected an integer ≥ 0, a numpy Generator or None"):
            bt.sample_surface(shape, 10, seed=seed)
    v, f = bt.nellipsoid_mesh(shape, 4)  # control
    assert v.shape == (6 * 16 + 2, 3)
    a = bt.sample_surface(shape, 10, seed=np.random.default_rng(0))
    assert a.shape == (10, 3)


def test_compare_shapes_names_a_bad_argument(sphere):
    s = sphere.shape
    for call, needle in (
        (lambda: bt.compare_shapes("egg", "sphere"), "a: expected an NEllipsoid .* or a mesh"),
        (lambda: bt.compare_shapes(s, s, count=-1), "count: expected an integer number of Monte-Carlo points"),
        (lambda: bt.compare_shapes(s, s, res=0), "res: expected an integer resolution"),
        (lambda: bt.compare_shapes(s, (np.zeros((3, 3)), [[0, 1, 5]])), "b: faces: vertex indices must be in"),
        (lambda: bt.compare_shapes(s, s, seed="q"), "seed"),
    ):
        with pytest.raises(BadInput, match=needle) as e:
            call()
        _one_line(e)
    out = bt.compare_shapes(s, s, res=8, count=2000, chamfer_count=200)
    assert out["iou"] > 0.9


def test_text_and_bad_meshes_are_named_not_converted():
    v, f = bt.nellipsoid_mesh(bt.load_object("sphere").shape, 6)
    for call, needle in (
        (lambda: bt.surface_integrals("a", "b"), "vertices must be a \\(V, 3\\) array"),
        (lambda: bt.surface_integrals(np.zeros((3, 3)), np.array([[0, 1, 7]])), "faces: vertex indices"),
        (lambda: bt.surface_integrals(v, f.astype(float)), "faces: expected an \\(F ≥ 1, 3\\) array of integer"),
        (lambda: bt.fit_two_step("a", "b", "c", 0, 1, (2, 2, 2)), "model_points must be"),
        (lambda: bt.fit_two_step(v, f, "c", -np.ones(3), np.ones(3), (2, 2, 2)), "data must be"),
        (lambda: bt.fit_two_step(v, f, v[:5], -np.ones(3), np.ones(3), "9x9"), "dims must be three integer"),
        (lambda: bt.texture_indicator("a", "b", "c", "d", tol=0.1), "vertices must be"),
        (lambda: bt.texture_indicator(v, f, v[:5], "d", tol=0.1), "residuals must be"),
        (lambda: bt.texture_indicator(v, f, v[:5], np.zeros(4), tol=0.1), "residuals must be a \\(5,\\) array"),
        (lambda: bt.texture_indicator(v, f, v[:5], np.zeros(5), tol=-1.0), "tol: expected a finite number > 0"),
    ):
        with pytest.raises(BadInput, match=needle) as e:
            call()
        _one_line(e)
    assert bt.surface_integrals(v, f).volume > 0  # controls
    assert bt.texture_indicator(v, f, v[:10], np.zeros(10), tol=1e-4).J >= 0
    fit = bt.fit_two_step(v, f, v[::3], v.min(axis=0) * 1.2, v.max(axis=0) * 1.2, (2, 2, 2), max_iter=2)
    assert fit.vertices.shape == v.shape


def test_fit_nellipsoid_de_refuses_points_that_determine_no_shape(sphere):
    for points, needle in (
        ("good.csv", "points must be an \\(M ≥ 12, 3\\) array \\(metres\\) of numbers, got str"),
        (np.full((20, 3), np.nan), "points must be finite, row 1"),  # was scipy's bounds error
        (np.zeros((2, 3)), "points: expected at least 12 points"),  # axes ~1e-25
        (np.ones((3, 3)) * 0.01, "points: expected at least 12 points"),
        (np.ones((20, 3)) * 0.01, "points: all 20 points are identical"),
        (np.c_[np.random.default_rng(0).random((20, 2)) * 0.05, np.zeros(20)], "lie in one plane"),
    ):
        with pytest.raises(BadInput, match=needle) as e:
            bt.fit_nellipsoid_de(points)
        _one_line(e)
    with pytest.raises(BadInput, match="n_bounds"):
        bt.fit_nellipsoid_de(bt.sample_surface(sphere, 20, seed=0), n_bounds=(5, 2))
    points = bt.sample_surface(sphere, 40, seed=0)  # control
    de = bt.fit_nellipsoid_de(points, 0, popsize=5, maxiter=5)
    assert np.all(np.asarray(de.shape.axes) > 0.005)


def test_fitting_functions_take_arrays_and_name_their_options(tmp_path, sphere):
    points = bt.sample_surface(sphere, 80, seed=0)
    csv = bt.save_contact_points(tmp_path / "good.csv", points)
    with pytest.raises(
        BadInput, match="points: expected an \\(M, 3\\) array in metres, not a path .* bt.fit\\(PATH\\)"
    ):
        bt.run_contact_fit(str(csv), tmp_path / "run", budget_s=1)
    with pytest.raises(BadInput, match="walkers must be an even integer ≥ 24"):
        bt.run_contact_fit(points, tmp_path / "run2", walkers="a")
    with pytest.raises(BadInput, match="walkers must be an even integer ≥ 24"):
        bt.fit(points, walkers=23)  # one home for the check: the same message
    with pytest.raises(BadInput, match="out: expected a path"):
        bt.run_contact_fit(points, None)
    assert not (tmp_path / "run").exists() and not (tmp_path / "run2").exists()


def test_sample_checks_its_log_density_and_sizes(tmp_path):
    def logp(x):
        return -0.5 * np.sum(np.asarray(x) ** 2, axis=-1)

    start = np.random.default_rng(0).normal(size=(4, 2))
    for call, needle in (
        (lambda: bt.sample("abc", start, None, walkers=4, ndim=2, seed=0, steps=1), "logp: expected a callable"),
        (lambda: bt.sample(logp, start, None, walkers=0, ndim=2, seed=0, steps=1), "walkers: expected an integer"),
        (lambda: bt.sample(logp, start, None, walkers=4, ndim=2, seed=0, steps=0), "steps: expected an integer"),
        (lambda: bt.sample(logp, start, None, walkers=4, ndim=2, seed=-1, steps=1), "seed: expected an integer"),
        (lambda: bt.sample(logp, start, None, walkers=6, ndim=2, seed=0, steps=1), "start must be a \\(6, 2\\)"),
        (lambda: bt.sample(logp, "abc", None, walkers=4, ndim=2, seed=0, steps=1), "start must be"),
    ):
        with pytest.raises(BadInput, match=needle) as e:
            call()
        _one_line(e)
    chain = bt.sample(logp, start, None, walkers=4, ndim=2, seed=0, steps=5, progress=False)  # control
    assert chain.steps == 5 and chain.kept.shape[1:] == (4, 2)


def test_occupancy_message_offers_no_unsafe_loading(tmp_path):
    csv = tmp_path / "good.csv"
    csv.write_text("x,y,z\n0,0,0\n")
    with pytest.raises(BadInput, match="not an occupancy grid") as e:
        bt.load_occupancy(csv)
    assert "pickle" not in _one_line(e)
    obj = tmp_path / "obj.npz"
    np.savez(obj, x=np.array([object()], dtype=object))
    with pytest.raises(BadInput, match="holds Python objects") as e:
        bt.load_occupancy(obj)
    assert "allow_pickle" not in _one_line(e)


def test_explore_settings_are_checked_on_construction(sphere):
    for kw, field in (({"candidates": -1}, "candidates"), ({"draws": "a"}, "draws"), ({"per_second": "no"}, "per")):
        with pytest.raises(BadInput, match=f"settings.{field}"):
            bt.ExploreSettings(**kw)
    with pytest.raises(BadInput, match="ExploreSettings: .*bogus.*; expected fields candidates"):
        bt.ExploreSettings(bogus=1)
    with pytest.raises(BadInput, match="settings.candidates"):  # refused before any work (the dict form)
        bt.explore(sphere, "random", 1, settings={"candidates": -1})
    s = bt.ExploreSettings(candidates=8)  # control: a NamedTuple still
    assert s.candidates == 8 and s._fields[0] == "candidates" and s._replace(draws=20).draws == 20
    import pickle

    assert pickle.loads(pickle.dumps(s)) == s


def test_containers_refuse_fields_of_the_wrong_form(sphere):
    from bayestouch.scene.objects import SceneObject

    with pytest.raises(BadInput, match="SceneObject.shape: expected an NEllipsoid"):
        bt.SceneObject("x", "notashape")
    with pytest.raises(BadInput, match="SceneObject.shape: axes must be 3 finite numbers > 0"):
        bt.SceneObject("x", bt.NEllipsoid("a", "b", "c", "d")._replace(centre=np.zeros(3)))
    with pytest.raises(BadInput, match="SceneObject.name"):
        bt.SceneObject(5, sphere.shape)
    assert SceneObject("ball", sphere.shape).name == "ball"  # control
    # NEllipsoid is a JAX pytree (built on tracers inside jit): checked where it enters the public functions
    junk = bt.NEllipsoid("a", "b", "c", "d")
    with pytest.raises(BadInput, match="shape: centre must be 3 finite numbers, got 'a'"):
        bt.nellipsoid_mesh(junk)
    with pytest.raises(BadInput, match="a: centre must be 3 finite numbers"):
        bt.compare_shapes(junk, sphere.shape)
    with pytest.raises(BadInput, match="ContactPoints.points must be an \\(N, 3\\) array"):
        bt.ContactPoints("abc")
    with pytest.raises(BadInput, match="ContactPoints.points must be finite, row 1"):
        bt.ContactPoints(np.full((3, 3), np.nan))
    with pytest.raises(BadInput, match="ContactPoints.normals must be an \\(3, 3\\) array"):
        bt.ContactPoints(np.ones((3, 3)), np.ones((2, 3)))
    with pytest.raises(BadInput, match="ContactPoints.source"):
        bt.ContactPoints(np.ones((3, 3)), source=5)
    cp = bt.ContactPoints(np.ones((3, 3)), np.ones((3, 3)), np.ones(3), "src", np.empty((0, 3)))  # control
    assert cp.source == "src" and cp._fields[-1] == "free"


# every public function listed above, with one argument of the wrong form: a one-line BadInput
_JUNK = [
    ("random_strokes", lambda o: bt.random_strokes(o, 1, speed="a")),
    ("random_paths", lambda o: bt.random_paths("egg", 1)),
    ("patch_posterior", lambda o: bt.patch_posterior("abc", "finger", seed=0)),
    ("read_recording", lambda o: bt.read_recording(5)),
    ("load_contact_points", lambda o: bt.load_contact_points(None)),
    ("load_object", lambda o: bt.load_object("egg", models=5)),
    ("load_finger", lambda o: bt.load_finger(models=5)),
    ("calibrate", lambda o: bt.calibrate({"a": 1}, "sphere")),
    ("record_strokes", lambda o: bt.record_strokes(o, "abc", None, 0)),
    ("reproduce_table2", lambda o: bt.reproduce_table2("egg")),
    ("nellipsoid_mesh", lambda o: bt.nellipsoid_mesh(o.shape, "a")),
    ("sample_surface", lambda o: bt.sample_surface(o.shape, 10, seed="x")),
    ("compare_shapes", lambda o: bt.compare_shapes("egg", "sphere")),
    ("fit_nellipsoid_de", lambda o: bt.fit_nellipsoid_de("good.csv")),
    ("surface_integrals", lambda o: bt.surface_integrals("a", "b")),
    ("fit_two_step", lambda o: bt.fit_two_step("a", "b", "c", 0, 1, (2, 2, 2))),
    ("texture_indicator", lambda o: bt.texture_indicator("a", "b", "c", "d", tol=0.1)),
    ("simulate", lambda o: bt.simulate("sphere", depth="x")),
    ("run_raw_fit", lambda o: bt.run_raw_fit("missing.nc", "out", stride="a")),
    ("run_contact_fit", lambda o: bt.run_contact_fit(bt.sample_surface(o, 20, seed=0), "out", walkers="a")),
    ("sample", lambda o: bt.sample("abc", np.zeros((4, 2)), None, walkers=4, ndim=2, seed=0, steps=1)),
    ("load_occupancy", lambda o: bt.load_occupancy(5)),
    ("ExploreSettings", lambda o: bt.ExploreSettings(candidates=-1)),
    ("SceneObject", lambda o: bt.SceneObject("x", "notashape")),
    ("ContactPoints", lambda o: bt.ContactPoints("abc")),
    ("refine_ffd", lambda o: bt.refine_ffd(o.shape, "abc", (2, 2, 2))),
]


@pytest.mark.parametrize("name,call", _JUNK, ids=[n for n, _ in _JUNK])
def test_every_listed_function_refuses_junk_in_one_line(name, call, sphere):
    assert name in bt.__all__
    with pytest.raises(BadInput) as e:
        call(sphere)
    _one_line(e)
