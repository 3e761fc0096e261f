"""Active probing planner (issue 5): rays, EIG, policies, the exploration loop and the experiment runner."""

from __future__ import annotations

import numpy as np
import pytest

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.planning import eig as eg
from bayestouch.planning.candidates import make_candidates
from bayestouch.planning.experiment import COLUMNS, resolve_object, run_experiment
from bayestouch.planning.loop import ExploreSettings, explore
from bayestouch.planning.policies import check_policy, choose
from bayestouch.planning.signal import predict_signals
from bayestouch.scene.objects import object_from_dict
from bayestouch.scene.raycast import CONTACT, INSIDE, MISS, true_ray_distances

R_SPHERE = 0.02
# small runs for the tests (the defaults are 64 candidates, 1000 draws, 300/600 steps, 2 starts, 4 scout arcs)
SMALL = {"candidates": 16, "draws": 128, "steps": 100, "init_steps": 200, "scout": 3, "init_starts": 1}


def _sphere_vec(centre=(0.0, 0.0, 0.0), r=R_SPHERE):
    return np.array([*centre, r, r, r, 0.0, 0.0, 0.0, 2.0])


def _analytic(x0, d, c, r, t_max):
    """First crossing of rays with a sphere: (t, status) with the module's conventions."""
    w = x0 - c
    b = np.sum(d * w, axis=1)
    cc = np.sum(w * w, axis=1) - r * r
    disc = b * b - cc
    t1 = -b - np.sqrt(np.maximum(disc, 0.0))
    inside = cc <= 0
    hit = ~inside & (disc > 0) & (t1 >= 0) & (t1 <= t_max)
    t = np.where(inside, 0.0, np.where(hit, t1, t_max))
    return t, np.where(inside, INSIDE, np.where(hit, CONTACT, MISS)), disc


def _rays(rng, k):
    x0 = rng.uniform(-0.04, 0.04, size=(k, 3))
    d = rng.normal(size=(k, 3))
    return x0, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_ray_distances_exact_for_a_sphere():
    rng = np.random.default_rng(0)
    x0, d = _rays(rng, 4000)
    t_max = 0.05
    t_ref, status, disc = _analytic(x0, d, np.zeros(3), R_SPHERE, t_max)
    # grazing rays (the ray within ~0.2 mm of the tangent) converge slowly and may read as misses: excluded
    ok = np.abs(disc) > 0.01 * R_SPHERE**2
    assert {CONTACT, MISS, INSIDE} <= set(status[ok])  # the test covers hits, misses and starts inside
    t64 = predict_signals(_sphere_vec()[None], x0[None], d[None], t_max)[0, 0]
    np.testing.assert_allclose(t64[ok], t_ref[ok], rtol=0, atol=1e-10)
    t32 = predict_signals(_sphere_vec()[None], x0[None], d[None], t_max, single=True)[0, 0]
    # float32: G rounded to ~6e-8, divided by the slope dG/dt = cos(incidence)/r: ≲ 1e-7 r / cos, far below 0.3 mm
    np.testing.assert_allclose(t32[ok], t_ref[ok], rtol=0, atol=1e-6)
    # the true-object ray march agrees (grid + bisection to t_max · 2^-40)
    obj = object_from_dict(
        {"object": {"name": "ball"}, "shape": {"centre_m": [0.0, 0.0, 0.0], "axes_m": [R_SPHERE] * 3, "n": 2.0}}
    )
    tt, st = true_ray_distances(obj, x0[ok], d[ok], t_max)
    # a ray that enters and leaves between two grid points (a chord < t_max/255) is stepped over
    chord = 2 * np.sqrt(np.maximum(disc[ok], 0))
    sure = chord > 2 * t_max / 255
    np.testing.assert_array_equal(st[sure], status[ok][sure])
    np.testing.assert_allclose(tt[sure], t_ref[ok][sure], rtol=0, atol=1e-9)


def test_candidate_rays_start_a_standoff_outside_the_believed_surface():
    shape = ne.from_vector(jnp.asarray([0.01, 0.0, -0.01, 0.03, 0.022, 0.02, 0.4, 0.3, -0.5, 3.0]))
    st = make_candidates(shape, 32, points=12, seed=1, standoff=0.01)
    assert st.starts.shape == (32, 12, 3)
    np.testing.assert_allclose(np.linalg.norm(st.dirs, axis=-1), 1.0, atol=1e-12)
    # predicted signal of the believed shape itself: exactly the stand-off on every ray
    t = predict_signals(np.asarray(ne.to_vector(shape))[None], st.starts, st.dirs, st.t_max)[0]
    np.testing.assert_allclose(t, 0.01, atol=1e-9)
    # path length matches the requested length (polyline of small steps on a smooth surface)
    seg = np.linalg.norm(np.diff(st.path, axis=1), axis=-1).sum(axis=1)
    np.testing.assert_allclose(seg, st.length, rtol=0.02)
    assert np.all((st.length >= 0.01) & (st.length <= 0.03)) and np.all(st.force <= 1.0)


def _whitened(rng, n, cov):
    """n draws whose sample mean is 0 and sample covariance (ddof 1) is exactly ``cov``."""
    z = rng.normal(size=(n, len(cov)))
    z -= z.mean(axis=0)
    L = np.linalg.cholesky(np.atleast_2d(np.cov(z.T)))
    z = z @ np.linalg.inv(L).T
    return z @ np.linalg.cholesky(cov).T


def test_eig_of_a_linear_gaussian_model_is_the_closed_form():
    rng = np.random.default_rng(2)
    cov = np.array([[4.0, 1.0, 0.0], [1.0, 2.0, 0.5], [0.0, 0.5, 1.0]]) * 1e-6
    theta = _whitened(rng, 2000, cov)
    A = rng.normal(size=(6, 3))
    sigma = 1e-3
    sig = theta @ A.T  # (N, T)
    closed = 0.5 * np.linalg.slogdet(np.eye(6) + A @ cov @ A.T / sigma**2)[1]
    assert eg.eig_gaussian(sig, sigma)[0] == pytest.approx(closed, rel=1e-10)
    # PCE: a lower bound with a downward bias of order 1/N (Foster et al. 2020, Thm 1), removed by Richardson
    # extrapolation from N and N/2 draws (2 PCE_N − PCE_N/2); the Monte Carlo error of each is estimated from 8
    # independent noise seeds (sd of the mean = spread / √8) and combined as √(4 se_N² + se_N/2²)
    pce = np.array([eg.eig_pce(sig, sigma, seed=s)[0] for s in range(8)])
    half = np.array([eg.eig_pce(sig[s % 2 :: 2], sigma, seed=100 + s)[0] for s in range(8)])
    se = np.hypot(2 * pce.std(ddof=1), half.std(ddof=1)) / np.sqrt(8)
    assert abs(2 * pce.mean() - half.mean() - closed) < 4 * se
    assert pce.mean() < closed  # a lower bound
    assert np.all(pce <= np.log(len(sig)) + 1e-12)


def test_whole_stroke_eig_does_not_double_count_correlated_readings():
    rng = np.random.default_rng(3)
    sigma = 1.0
    # stroke A: 20 readings all driven by one parameter (rank-1 covariance); stroke B: 3 independent readings
    u = _whitened(rng, 4000, np.eye(1))
    a = u @ np.ones((1, 20))
    b = _whitened(rng, 4000, 4.0 * np.eye(3))
    eig_a, eig_b = eg.eig_gaussian(a, sigma)[0], eg.eig_gaussian(b, sigma)[0]
    assert eig_a == pytest.approx(0.5 * np.log(1 + 20), rel=1e-10)
    assert eig_b == pytest.approx(1.5 * np.log(5), rel=1e-10)
    assert eig_b > eig_a
    # negative control: the per-point sum counts A's one number 20 times and picks the wrong stroke
    pp_a, pp_b = eg.eig_per_point(a, sigma)[0], eg.eig_per_point(b, sigma)[0]
    assert pp_a == pytest.approx(10 * np.log(2)) and pp_a > pp_b
    # the same stroke twice (independent noise): ½ log det(I + 2C/σ²) < 2 EIG, while the per-point sum doubles
    c = _whitened(rng, 4000, np.array([[2.0, 1.5], [1.5, 2.0]]))
    cc = np.concatenate([c, c], axis=1)
    assert eg.eig_gaussian(cc, sigma)[0] == pytest.approx(
        0.5 * np.linalg.slogdet(np.eye(2) + 2 * np.array([[2.0, 1.5], [1.5, 2.0]]))[1], rel=1e-10
    )
    assert eg.eig_gaussian(cc, sigma)[0] < 1.6 * eg.eig_gaussian(c, sigma)[0]
    assert eg.eig_per_point(cc, sigma)[0] == pytest.approx(2 * eg.eig_per_point(c, sigma)[0])


@pytest.mark.parametrize("axis", [0, 2])
def test_planner_prefers_rays_along_the_uncertain_direction(axis):
    rng = np.random.default_rng(4)
    vecs = np.tile(_sphere_vec(), (500, 1))
    vecs[:, axis] += 2e-3 * rng.standard_normal(500)  # only the centre's coordinate `axis` is uncertain
    shape = ne.from_vector(jnp.asarray(_sphere_vec()))
    st = make_candidates(shape, 64, points=10, seed=5, length_range=(0.005, 0.01))
    dec = choose("eig", st, vecs, noise_sd=3e-4, rng=rng)
    along = np.abs(st.dirs[..., axis]).mean(axis=1)  # how much each stroke's rays run along the axis
    assert along[dec.index] > 0.8
    assert along[dec.index] >= np.quantile(along, 0.9)
    # control: random choices are not that aligned on average
    assert np.mean(along) < 0.7


def test_oracle_looks_where_the_truth_differs_from_the_belief():
    rng = np.random.default_rng(7)
    vecs = np.tile(_sphere_vec(), (500, 1))
    vecs[:, 0] += 2e-3 * rng.standard_normal(500)  # belief: centred at 0 ± 2 mm along x
    obj = object_from_dict(
        {"object": {"name": "ball"}, "shape": {"centre_m": [0.003, 0.0, 0.0], "axes_m": [R_SPHERE] * 3, "n": 2.0}}
    )
    st = make_candidates(ne.from_vector(jnp.asarray(_sphere_vec())), 64, points=10, seed=5, length_range=(0.005, 0.01))
    dec = choose("oracle", st, vecs, noise_sd=3e-4, rng=rng, obj=obj)
    assert np.abs(st.dirs[dec.index, :, 0]).mean() > 0.8  # its rays run along x, where the truth is off
    # negative control: the stroke it rates worst has rays mostly across x (they barely see an x shift)
    assert np.abs(st.dirs[int(np.argmax(dec.score)), :, 0]).mean() < 0.5


def test_multimodality_check_flags_two_modes_only():
    rng = np.random.default_rng(6)
    assert eg.looks_multimodal(np.concatenate([rng.normal(0, 1, 500), rng.normal(8, 1, 500)]))
    assert not eg.looks_multimodal(rng.normal(0, 1, 1000))


def test_bad_inputs_raise_one_line_bad_input(tmp_path, capsys):
    for call, field in [
        (lambda: check_policy("greedy"), "planner"),
        (lambda: resolve_object("no_such_object"), "object"),
        (lambda: resolve_object(str(tmp_path / "missing.toml")), "object"),
        (lambda: run_experiment(tmp_path, budget=0, objects=("sphere",)), "budget"),
        (lambda: run_experiment(tmp_path, planners=("eig", "best"), objects=("sphere",)), "planner"),
        (lambda: explore(None, "eig", 0), "budget"),
    ]:
        with pytest.raises(BadInput) as e:
            call()
        assert "\n" not in str(e.value) and str(e.value).startswith(field)
    from bayestouch.cli import main

    assert main(["experiment", "--planners", "eig,nope", "--budget", "1", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nope" in err


def _ball():
    return object_from_dict(
        {"object": {"name": "ball"}, "shape": {"centre_m": [0.0, 0.0, 0.0], "axes_m": [0.025, 0.025, 0.025], "n": 2.0}}
    )


@pytest.mark.slow
def test_explore_adds_one_stroke_per_iteration_and_the_spread_shrinks():
    seen = []
    res = explore(_ball(), "eig", 2, seed=1, settings=ExploreSettings(**SMALL), on_stroke=seen.append)
    assert [r.stroke for r in res.records] == [0, 1, 2] and len(seen) == 3 and len(res.strokes) == 3
    n = [r.n_points for r in res.records]
    assert all(r.new_points > 0 for r in res.records)
    assert n == list(np.cumsum([r.new_points for r in res.records]))
    assert res.records[-1].volume_sd < res.records[0].volume_sd
    assert np.all(np.isfinite([r.eig for r in res.records[1:]]))
    assert res.records[-1].chamfer < 0.1 and res.records[-1].volume_error < 0.05


@pytest.mark.slow
def test_experiment_writes_results_and_resumes_without_redoing(tmp_path, monkeypatch):
    from bayestouch.io.files import read_csv_rows, write_csv_rows
    from bayestouch.planning import experiment as ex

    kw = dict(
        planners=("random", "coverage"),
        objects=("sphere",),
        trials=1,
        budget=1,
        seed=3,
        workers=1,
        settings=SMALL,
        log=lambda m: None,
    )
    res = run_experiment(tmp_path, **{**kw, "workers": 2})  # the process pool (spawned workers)
    rows = read_csv_rows(tmp_path / "results.csv")
    assert {"planner", "trial", "object", "stroke", "chamfer", "volume_error", "seconds"} <= set(rows[0])
    assert list(rows[0]) == list(COLUMNS) and res["ran"] == 2 and len(rows) == 4
    assert (tmp_path / "error_vs_strokes.png").stat().st_size > 0
    # both planners share the scout (stroke 0) of the trial
    s0 = [r for r in rows if r["stroke"] == "0"]
    assert s0[0]["chamfer"] == s0[1]["chamfer"]
    calls = []
    monkeypatch.setattr(ex, "run_trial", lambda t: calls.append(t) or [])
    again = run_experiment(tmp_path, **{**kw, "plot": False}, resume=True)
    assert again["ran"] == 0 and again["skipped"] == 2 and calls == []
    assert read_csv_rows(tmp_path / "results.csv") == rows
    # nothing recorded is lost or silently mixed: a new run over the results, or a resume with another seed or
    # other settings, is refused and leaves results.csv as it was
    with pytest.raises(BadInput, match="already holds results.csv.*--resume.*--overwrite"):
        run_experiment(tmp_path, **{**kw, "plot": False})
    with pytest.raises(BadInput, match="seed 3 \\(now 7\\)"):
        run_experiment(tmp_path, **{**kw, "plot": False, "seed": 7}, resume=True)
    with pytest.raises(BadInput, match="budget \\(--strokes\\) 1 \\(now 2\\)"):
        run_experiment(tmp_path, **{**kw, "plot": False, "budget": 2}, resume=True)
    assert read_csv_rows(tmp_path / "results.csv") == rows and calls == []
    # an incomplete trial (its last stroke missing) is run again, the complete one is kept
    write_csv_rows(
        tmp_path / "results.csv", [r for r in rows if not (r["planner"] == "random" and r["stroke"] == "1")], COLUMNS
    )
    monkeypatch.undo()
    third = run_experiment(tmp_path, **{**kw, "plot": False}, resume=True)
    assert third["ran"] == 1 and third["skipped"] == 1
    assert len(read_csv_rows(tmp_path / "results.csv")) == 4
    # without the experiment.json written with them, the kept trials' settings cannot be checked: refused (before,
    # the resume went on and wrote a new experiment.json claiming the new settings)
    (tmp_path / "experiment.json").unlink()
    with pytest.raises(BadInput, match="experiment.json is missing or damaged"):
        run_experiment(tmp_path, **{**kw, "plot": False, "seed": 7}, resume=True)
    assert not (tmp_path / "experiment.json").exists()


def test_a_miss_penalises_shapes_that_the_ray_would_have_touched():
    from bayestouch.inference import contact as cm
    from bayestouch.inference.freespace import Free, with_free

    # one ray along -z from (0, 0, 0.05), 3 cm long, that met nothing; one start found inside, at the origin
    free = Free(np.array([[0.0, 0.0, 0.05]]), np.array([[0.0, 0.0, -1.0]]), 0.03, np.zeros((1, 3)))
    pts = 0.02 * np.vstack([np.eye(3), -np.eye(3)])  # only sets the prior box (the centre within ±4 cm)
    base, bounds = cm.make_log_prob(pts, nu=np.inf)
    f = with_free(base, bounds, free)
    sig = np.log(3e-4)
    small = [0.0, 0.0, 0.0, *np.log([0.019] * 3), 0.0, 0.0, 0.0, np.log(2.0), sig]  # top at z = 1.9 cm: no touch
    big = [0.0, 0.0, 0.0, *np.log([0.021] * 3), 0.0, 0.0, 0.0, np.log(2.0), sig]  # top at 2.1 cm: touched at 2.9 cm
    away = [0.0, 0.0, -0.035, *np.log([0.01] * 3), 0.0, 0.0, 0.0, np.log(2.0), sig]  # origin outside: contradicts
    th = np.array([small, big, away])
    extra = f(th) - base(th)
    # the top of `small` is 1 mm (3.3 σ) beyond the ray's end: Φ(3.3) ≈ 1; the start at the centre is inside both
    assert extra[0] == pytest.approx(0.0, abs=1e-3)
    # `big` would have been touched at t = 2.9 cm < 3 cm, 1 mm before the end: Φ(−3.3) ≈ 5e-4
    from scipy.stats import norm

    assert extra[1] == pytest.approx(norm.logcdf(-1e-3 / 3e-4), rel=1e-3)
    assert extra[2] < -1000  # negative control: the origin lies 2.5 cm (83 σ) outside this shape


@pytest.mark.slow
def test_a_dask_worker_killed_mid_run_loses_no_finished_trial(tmp_path):
    """Two worker processes; once the first trial is in results.csv, the worker running another trial is killed
    (SIGKILL). The run still completes: every trial once, with all its strokes, and the finished rows kept."""
    import os
    import signal
    import threading
    import time

    from bayestouch.io.files import read_csv_rows

    distributed = pytest.importorskip("dask.distributed")
    csv = tmp_path / "results.csv"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        result, errors = {}, []

        def run():
            try:
                result.update(
                    run_experiment(
                        tmp_path,
                        planners=("random",),
                        objects=("sphere",),
                        trials=4,
                        budget=1,
                        seed=7,
                        scheduler=lc.scheduler_address,
                        settings=SMALL,
                        plot=False,
                        log=lambda m: None,
                    )
                )
            except Exception as e:  # reported below
                errors.append(e)

        th = threading.Thread(target=run)
        th.start()
        killed_pid, first_rows = None, None
        with distributed.Client(lc.scheduler_address, set_as_default=False) as client:
            deadline = time.monotonic() + 600
            while killed_pid is None and time.monotonic() < deadline and th.is_alive():
                time.sleep(0.2)
                if not (csv.is_file() and read_csv_rows(csv)):
                    continue
                busy = [w for w, tasks in client.processing().items() if tasks]
                if busy:
                    first_rows = read_csv_rows(csv)
                    killed_pid = client.run(os.getpid, workers=[busy[0]])[busy[0]]
                    os.kill(killed_pid, signal.SIGKILL)
        th.join(timeout=900)
    assert not errors, errors
    assert killed_pid is not None, "no trial was running when the first one finished"
    rows = read_csv_rows(csv)
    # every row recorded before the kill is still there
    assert all(r in rows for r in first_rows)
    # every trial exactly once, each with the scout and one planned stroke
    keys = sorted((int(r["trial"]), int(r["stroke"])) for r in rows)
    assert keys == [(t, k) for t in range(4) for k in range(2)]
    assert result["ran"] == 4


def test_shape_errors_chamfer_has_no_sampling_floor():
    from bayestouch.geometry.compare import chamfer_shapes
    from bayestouch.planning.loop import CHAMFER_COUNT, shape_errors, truth_of

    obj = object_from_dict(
        {"object": {"name": "ball"}, "shape": {"centre_m": [0.001, 0.0, 0.0], "axes_m": [R_SPHERE] * 3, "n": 2.0}}
    )
    truth = truth_of(obj)
    exact = np.tile(_sphere_vec((0.001, 0.0, 0.0)), (8, 1))
    err = shape_errors(exact, truth)
    # the truth mesh (resolution 64) is inscribed in the sphere: its sag, ≤ h²/(8 r) ≈ 1e-4 r, is all that is left
    assert err["chamfer"] < 1e-4
    # negative control: the point-cloud Chamfer distance of the same pair sits at its floor, ½ √(A / count) ≈ 0.02 r
    floor = 0.5 * np.sqrt(4 * np.pi * R_SPHERE**2 / CHAMFER_COUNT) / R_SPHERE
    est = ne.from_vector(jnp.asarray(exact[0]))
    assert chamfer_shapes(est, truth.mesh, count=CHAMFER_COUNT, seed=0) / R_SPHERE > 0.5 * floor
    # a concentric sphere 2 % larger: every point is 0.02 r from the other surface (up to the sag)
    bigger = np.tile(_sphere_vec((0.001, 0.0, 0.0), 1.02 * R_SPHERE), (8, 1))
    assert shape_errors(bigger, truth)["chamfer"] == pytest.approx(0.02, abs=1e-4)


def test_cost_aware_eig_prefers_information_per_second():
    """Two candidates: A gains 2 nats in 4 s, B 1.5 nats in 1 s. Per stroke A wins; per second B does (0.5 < 1.5
    nats/s). Checked through the CLI's settings too."""
    from bayestouch.cli import build_parser
    from bayestouch.cli.explore import _settings

    rng = np.random.default_rng(0)
    # signals (N, C, T) with per-candidate covariance giving the two EIGs: one reading each, var = (e^{2g} − 1) σ²
    sigma = 1.0
    g = np.array([2.0, 1.5])
    sd = np.sqrt(np.expm1(2 * g)) * sigma
    sig = rng.standard_normal((20000, 2, 1)) * sd[None, :, None]
    per_stroke = eg.decide(sig, sigma)
    per_second = eg.decide(sig, sigma, durations=np.array([4.0, 1.0]))
    assert (per_stroke.best, per_second.best) == (0, 1)
    args = build_parser().parse_args(["explore", "--object", "egg", "--out", "x", "--per-second"])
    assert _settings(args)["per_second"] is True
    assert "per_second" not in _settings(build_parser().parse_args(["explore", "--object", "egg", "--out", "x"]))


def test_experiment_tasks_carry_the_object_not_a_path(tmp_path, monkeypatch):
    """A Dask worker on another machine has none of the client's files: each task holds the object itself, which
    survives pickling and the deletion of the file it was read from."""
    import pickle
    import shutil

    from bayestouch.planning import experiment as ex
    from bayestouch.scene.objects import OBJECTS_DIR, load_object

    mine = tmp_path / "my_sphere.toml"
    shutil.copy(OBJECTS_DIR / "sphere.toml", mine)
    tasks = []

    def fake(task):  # records the task, returns one row of the right columns
        tasks.append(task)
        return [{**dict.fromkeys(COLUMNS, 0), "object": task["object"], "planner": task["planner"]}]

    monkeypatch.setattr(ex, "run_trial", fake)
    run_experiment(
        tmp_path / "exp",
        planners=("random",),
        objects=(str(mine),),
        trials=1,
        budget=1,
        seed=0,
        workers=1,
        settings=SMALL,
        log=lambda m: None,
        plot=False,
    )
    (task,) = tasks
    assert not any(
        isinstance(v, str) and "/" in v and v.endswith(".toml") for v in task.values() if v != task["object"]
    )
    mine.unlink()
    sent = pickle.loads(pickle.dumps(task))
    ref = load_object(OBJECTS_DIR / "sphere.toml")
    assert np.allclose(np.asarray(sent["scene_object"].shape.axes), np.asarray(ref.shape.axes))


@pytest.mark.slow
def test_experiment_through_the_virtual_finger_with_the_gpis_planner(tmp_path):
    """--prober finger: every stroke is a guarded stroke on a virtual finger over the serial protocol; its
    contacts carry the pad's pose error (0.3 mm per coordinate), so they lie near, not on, the true sphere; the
    gpis planner chooses among the candidates once the scout has touched enough. The prober is part of the
    experiment's key: a resume in the ray world is refused."""
    from bayestouch.io.files import read_csv_rows

    kw = dict(
        planners=("gpis", "random"),
        objects=("sphere",),
        trials=1,
        budget=1,
        seed=2,
        workers=1,
        settings=SMALL,
        log=lambda m: None,
        plot=False,
    )
    res = run_experiment(tmp_path, prober="finger", **kw)
    rows = read_csv_rows(tmp_path / "results.csv")
    assert res["ran"] == 2 and {r["planner"] for r in rows} == {"gpis", "random"}
    last = {r["planner"]: r for r in rows if r["stroke"] == "1"}
    assert all(float(r["chamfer"]) < 0.1 for r in last.values())  # the sphere is found through the finger
    assert float(last["gpis"]["decision_s"]) > 0  # the GPIS was conditioned and scored the candidates
    with pytest.raises(BadInput, match="prober"):
        run_experiment(tmp_path, resume=True, **kw)
    with pytest.raises(BadInput, match="prober: expected one of rays, finger"):
        run_experiment(tmp_path / "x", prober="laser", **kw)
    with pytest.raises(BadInput, match="bend_spread"):  # another finger is another experiment
        run_experiment(tmp_path, resume=True, prober="finger", bend_spread=1.0, **kw)


def test_experiment_bend_spread_draws_one_finger_per_trial_and_refuses_misuse(tmp_path):
    """A trial's finger is drawn from its seed (the same for every planner of the trial: paired), another trial
    gets another, a wider spread moves it further from the models' constants, 0 is the models' finger; a spread out
    of range or with the ray world is refused before the folder is touched."""
    from bayestouch.physics.virtual import load_finger
    from bayestouch.planning.experiment import trial_finger

    assert trial_finger(5, 0.0) is None
    a, b, c = trial_finger(5, 1.0), trial_finger(5, 1.0), trial_finger(6, 1.0)
    assert a == b and a != c
    wide = trial_finger(5, 2.0)
    nominal = load_finger()
    assert abs(np.log(wide[1].EI / nominal.rod.EI)) == pytest.approx(2 * abs(np.log(a[1].EI / nominal.rod.EI)))
    for kw, needle in (
        ({"prober": "finger", "bend_spread": 4.0}, r"bend_spread: expected a factor in \[0, 3\]"),
        ({"prober": "rays", "bend_spread": 1.0}, "use it with prober 'finger'"),
    ):
        with pytest.raises(BadInput, match=needle):
            run_experiment(tmp_path / "x", planners=("random",), objects=("sphere",), trials=1, budget=1, **kw)
    assert not (tmp_path / "x").exists()


def test_scheduler_probe_tells_a_dask_scheduler_from_other_servers():
    """--scheduler pointing at an HTTP server answered HTTP 400 read as a 3 EiB Dask frame (MemoryError), and a
    silent server hung for minutes (issue 24): both are one-line BadInput now, a real scheduler passes."""
    import socket
    import threading

    from bayestouch.planning.experiment import probe_scheduler

    def serve(reply):
        srv = socket.socket()
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)

        def run():
            conn, _ = srv.accept()
            if reply:
                conn.sendall(reply)
            threading.Event().wait(1.0)
            conn.close()
            srv.close()

        threading.Thread(target=run, daemon=True).start()
        return f"tcp://127.0.0.1:{srv.getsockname()[1]}"

    with pytest.raises(BadInput, match="not a Dask scheduler"):
        probe_scheduler(serve(b"HTTP/1.1 400 Bad Request\r\n\r\n"), timeout_s=2.0)
    with pytest.raises(BadInput, match="said nothing"):
        probe_scheduler(serve(b""), timeout_s=0.3)
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        probe_scheduler(cluster.scheduler_address, timeout_s=5.0)  # no exception


def test_experiment_resume_refuses_an_edited_object_file(tmp_path, monkeypatch):
    """The trial key holds the object's contents, not only its file name (issue 24: an edited object file was
    resumed as '0 trial(s) to run, 1 kept')."""
    from bayestouch.params import MODELS
    from bayestouch.planning import experiment as ex

    obj = tmp_path / "myobj.toml"
    obj.write_text((MODELS / "objects" / "sphere.toml").read_text())

    def fake(task):
        return [
            dict.fromkeys(COLUMNS, 0.0)
            | {"planner": task["planner"], "trial": task["trial"], "object": task["object"], "stroke": s}
            | {"chamfer": 0.1, "volume_error": 0.1, "seed": task["seed"]}
            for s in range(task["budget"] + 1)
        ]

    monkeypatch.setattr(ex, "run_trial", fake)
    kw = dict(planners=("random",), objects=(str(obj),), trials=1, budget=1, seed=0, workers=1, plot=False)
    out = tmp_path / "exp"
    assert run_experiment(out, **kw, log=lambda m: None)["ran"] == 1
    assert run_experiment(out, **kw, log=lambda m: None, resume=True)["ran"] == 0  # the same file: kept
    text = obj.read_text()
    line = next(x for x in text.splitlines() if x.startswith("axes_m"))
    obj.write_text(text.replace(line, "axes_m = [0.04, 0.02, 0.01]"))
    with pytest.raises(BadInput, match="other object"):
        run_experiment(out, **kw, log=lambda m: None, resume=True)


def test_a_damaged_results_file_is_refused_naming_line_and_column(tmp_path):
    """results.csv damaged between runs (issue 24, third review): a header line appended, a text or nan measure,
    a stroke listed twice were an internal error or were kept silently (and counted twice). Each is one line
    naming the line and the column; negative control: the undamaged rows pass unchanged."""
    from bayestouch.planning.experiment import checked_rows

    good = [
        dict(
            zip(
                COLUMNS,
                ["random", "0", "sphere", str(k), "0.01", "0.02", "1.5", "80", "80", "1e-6", "nan", "0.0", "7"],
                strict=True,
            )
        )
        for k in range(2)
    ]
    assert checked_rows(good, "r.csv") == good
    cases = [
        (good + [{c: c for c in COLUMNS}], r"line 4, column trial: 'trial' is not a whole number"),
        ([{**good[0], "chamfer": "abc"}, good[1]], r"line 2, column chamfer: 'abc' is not a number"),
        ([{**good[0], "seconds": "nan"}, good[1]], r"line 2, column seconds: 'nan' is not a finite number"),
        ([*good, good[1]], r"line 4 repeats stroke 1 of trial 0 \(sphere, random\) from line 3"),
        ([good[0], {**good[1], "seed": "-3"}], r"line 3, column seed"),
        ([good[0], {k: v for k, v in good[1].items() if k != "eig"}], r"line 3 lacks column\(s\) \['eig'\]"),
    ]
    for rows, needle in cases:
        with pytest.raises(BadInput, match=needle):
            checked_rows(rows, "r.csv")


def _split_and_spread(rng, n: int, p_miss: float, spread: float, t_max: float = 0.02, t_hit: float = 0.005):
    """Signals (n, 3) m of one stroke: reading 0 misses (t_max) for a share ``p_miss`` of the draws and touches at
    ``t_hit`` for the rest; readings 1 and 2 touch at t_hit + spread·z, one z ~ N(0, 1) per draw."""
    z = rng.standard_normal(n)
    first = np.where(rng.random(n) < p_miss, t_max, t_hit)
    return np.column_stack([first, t_hit + spread * z, t_hit + spread * z])


def test_reading_events_tell_inside_touch_and_miss():
    ev = eg.reading_events(np.array([[0.0, 0.003, 0.02, np.float32(0.02) * (1 - 1e-7), 0.0199]]), 0.02)
    np.testing.assert_array_equal(ev, [[0, 1, 2, 2, 1]])


def test_event_eig_is_the_entropy_of_touch_or_miss_plus_the_gaussian_within():
    """Reading 0 misses for 30 % of the draws (15 mm beyond the touch), readings 1–2 share a spread of 0.5 mm with
    σ = 0.5 mm: the mutual information is H(0.3) + ½ log(1 + 2·0.5²/0.5²) = 0.611 + 0.549 = 1.160 nats (events
    deterministic given θ). The Gaussian formula, taking the miss for a reading 15 mm away, credits it ~3 nats (the
    control). A stroke on which every draw agrees gets the Gaussian value exactly."""
    rng = np.random.default_rng(4)
    sig = _split_and_spread(rng, 20000, 0.3, 5e-4)
    want = -(0.3 * np.log(0.3) + 0.7 * np.log(0.7)) + 0.5 * np.log(3.0)
    got = eg.eig_events(sig, 5e-4, 0.02)[0]
    assert got == pytest.approx(want, abs=0.02)  # MC error of the plug-in terms at 20,000 draws: < 0.01
    assert eg.eig_gaussian(sig, 5e-4)[0] > want + 1.5
    agree = sig.copy()
    agree[:, 0] = 0.005
    assert eg.eig_events(agree, 5e-4, 0.02)[0] == pytest.approx(eg.eig_gaussian(agree, 5e-4)[0], rel=1e-12)
    inside = sig.copy()
    inside[:, 0] = np.where(sig[:, 0] == 0.02, 0.0, 0.005)  # a start inside is an event too
    assert eg.eig_events(inside, 5e-4, 0.02)[0] == pytest.approx(got, abs=1e-9)


def test_decide_with_events_prefers_information_over_a_large_miss():
    """Candidate A only tells touch from miss (50/50, 15 mm apart: log 2 = 0.69 nats, which the Gaussian formula
    counts as ½ log(1 + ¼·30²) = 2.7); B's three touch readings share a spread of 1.5 σ: ½ log(1 + 3·1.5²) = 1.02
    nats. The events EIG picks B; the Gaussian EIG (the control) picks A."""
    rng = np.random.default_rng(5)
    n = 20000
    a = _split_and_spread(rng, n, 0.5, 0.0)
    z = rng.standard_normal(n)
    b = 0.005 + 1.5 * 5e-4 * np.column_stack([z, z, z])
    sig = np.stack([a, b], axis=1)  # (N, 2, 3)
    assert eg.decide(sig, 5e-4).best == 0
    dec = eg.decide(sig, 5e-4, t_max=0.02)
    assert dec.best == 1
    assert dec.eig[0] == pytest.approx(np.log(2.0), abs=0.01)
    assert dec.eig[1] == pytest.approx(0.5 * np.log(1 + 3 * 1.5**2), abs=0.02)
