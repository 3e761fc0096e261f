"""The default contact-level fit on sparse data: SMC start, outlier parameters, free space, modes in summary.json."""

import json

import emcee
import numpy as np
import pytest

from bayestouch.inference import contact as cm
from bayestouch.inference import run as run_module
from bayestouch.inference.run import describe_modes, run_contact_fit, surrounds


def _sphere(m, r=0.02, hemisphere=False, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(m, 3))
    if hemisphere:
        p[:, 2] = np.abs(p[:, 2])
    return r * p / np.linalg.norm(p, axis=1, keepdims=True)


def test_surrounds_tells_all_round_from_one_sided():
    theta = np.array([0, 0, 0, *[np.log(0.02)] * 3, 0.0, 0.0, 0.0, np.log(2.0)])  # principal axes = world axes
    assert surrounds(_sphere(400), theta)
    assert not surrounds(_sphere(400, hemisphere=True), theta)


def test_describe_modes_weights_and_volumes():
    rng = np.random.default_rng(0)
    n = 3000
    nat = np.zeros((n, 11))
    big = rng.random(n) < 0.25
    nat[:, 3:6] = np.where(big[:, None], [0.04, 0.02, 0.015], [0.02, 0.02, 0.015]) * np.exp(rng.normal(0, 0.02, (n, 3)))
    nat[:, 9] = 2.0
    vol = 4 / 3 * np.pi * np.prod(nat[:, 3:6], axis=1)
    modes = describe_modes(nat, vol, 0)
    assert len(modes) == 2
    assert abs(modes[1]["weight"] - 0.25) < 0.01
    assert modes[1]["a"]["mean"] > 1.8 * modes[0]["a"]["mean"]
    # one mode: a single log-normal cloud
    assert len(describe_modes(nat[~big], vol[~big], 0)) == 1


def test_default_fit_of_a_one_sided_contaminated_set(tmp_path, monkeypatch):
    """60 contacts on one side of a sphere (r = 20 mm, 0.3 mm noise), 6 displaced 5 mm inwards, free-space points
    beyond the touched side: the SMC-started fit counts the displaced contacts as inward outliers (σ stays near
    0.3 mm), reports its SMC stage and its modes, and a resumed run reuses the saved particles and optimum check."""
    rng = np.random.default_rng(3)
    pts = _sphere(60, hemisphere=True, seed=1)
    pts += rng.normal(0, 3e-4, pts.shape)
    pts[:6] *= 1 - 0.005 / 0.02
    free = _sphere(20, 0.03, hemisphere=True, seed=2)
    s = run_contact_fit(pts, tmp_path, seed=0, steps=400, progress=False, free=free, budget_s=None)
    par, diag = s["parameters"], s["diagnostics"]
    assert s["model"]["init"] == "smc" and s["model"]["smc"]["complete"]
    assert s["model"]["n_free_points"] == 20
    assert 2e-4 < par["sigma"]["mean"] < 4.5e-4
    assert par["w_in"]["mean"] > 0.04 and par["w_out"]["mean"] < par["w_in"]["mean"]
    assert diag["modes"] and abs(sum(m["weight"] for m in diag["modes"]) - 1) < 1e-9
    assert "multimodal" in diag and "smc_modes" in diag
    # the right shape leaves noise: no misfit (bayestouch.inference.misfit), and the summary says so
    assert diag["misfit"] is False and diag["residual_neighbour_correlation"]["rho"] < 0.3
    # the smallest semi-axis is the sphere's radius, which the cap constrains
    assert abs(par["c"]["mean"] - 0.02) < 0.002
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["diagnostics"]["modes"] == diag["modes"]
    before = np.load(tmp_path / "smc.npz")["particles"]
    first = emcee.backends.HDFBackend(str(tmp_path / "chain.h5"), read_only=True).get_chain()

    def searched_again(*args, **kwargs):  # what a resume must not do: under another deadline it finds another optimum
        raise AssertionError("the resume ran the optimum check again instead of reading optimum.npz")

    monkeypatch.setattr(run_module, "optimum_mode", searched_again)
    s2 = run_contact_fit(pts, tmp_path, seed=0, steps=450, progress=False, free=free, resume=True, budget_s=None)
    assert s2["diagnostics"]["steps"] == 450
    assert np.array_equal(np.load(tmp_path / "smc.npz")["particles"], before)
    assert s2["model"]["smc"]["optimum_above_particles"] == s["model"]["smc"]["optimum_above_particles"]
    # a sphere leaves ψ and ζ free: every walker of the chain, resumed run included, holds each Euler angle within
    # one period (cm.angle_window); a chain free to take whole periods spreads over several
    chain = emcee.backends.HDFBackend(str(tmp_path / "chain.h5"), read_only=True).get_chain()
    for col, period in zip(cm.ANGLE_COLUMNS, cm.ANGLE_PERIODS, strict=True):
        assert np.ptp(chain[:, :, col]) < period
    assert np.array_equal(chain[:400], first)  # the first 400 steps kept bit for bit


def test_the_time_budget_covers_the_smc_and_a_cut_tempering_says_so(tmp_path):
    """With a budget of 1 s the tempered SMC stops after its first stages (its share of the budget is 0.5 s)
    instead of tempering to the posterior, the summary says so (complete False, β < 1, a warning) and the chain
    still runs its minimum steps; negative control: without a budget the same data temper to β = 1 (the test
    above)."""
    rng = np.random.default_rng(3)
    pts = _sphere(60, hemisphere=True, seed=1) + rng.normal(0, 3e-4, (60, 3))
    s = run_contact_fit(pts, tmp_path, seed=0, progress=False, budget_s=1.0)
    smc = s["model"]["smc"]
    assert not smc["complete"] and np.load(tmp_path / "smc.npz")["betas"][-1] < 1
    assert any("tempering stopped" in w for w in s["diagnostics"]["warnings"])
    assert s["diagnostics"]["stopped_by_budget"] and not s["diagnostics"]["converged"]


def test_optimum_mode_reaches_the_optimum_with_its_laplace_width():
    """All-round contacts on a sphere (r = 20 mm, 0.3 mm noise): the polished optimum has the radius, a
    log-posterior at least the truth's, and a Laplace sd of log σ near the Gaussian limit 1/√(2M)."""
    from bayestouch.inference.run import optimum_mode

    m = 120
    rng = np.random.default_rng(5)
    pts = _sphere(m, seed=4) + rng.normal(0, 3e-4, (m, 3))
    priors = cm.load_priors()
    logp, bounds = cm.make_log_prob(pts, priors, noise="outlier", precision="float64")
    opt = optimum_mode(pts, logp, bounds, priors, seed=0, sampled=cm.param_names(False, "outlier"))
    th = opt["theta"]
    np.testing.assert_allclose(np.exp(th[3:6]), 0.02, atol=5e-4)
    truth = np.array([0, 0, 0, *[np.log(0.02)] * 3, 1.0, 1.0, 1.0, np.log(2.0), np.log(3e-4), 1e-3, 1e-3])
    assert opt["log_post"] >= float(logp(truth[None])[0]) - 1e-6
    assert opt["log_post"] == pytest.approx(float(logp(th[None])[0]), rel=1e-12, abs=1e-9)
    sd = np.sqrt(np.diag(opt["cov"]))
    assert np.all(np.linalg.eigvalsh(opt["cov"]) > 0)
    # Gaussian core, no outliers: the sd of log σ is about 1/√(2M) = 0.065 (±30 % for the outlier fractions' pull)
    assert 0.045 < sd[10] < 0.085
    assert np.all(sd[3:6] < 0.03)  # every radius constrained to a few per cent


def test_optimum_check_finds_the_low_noise_mode_of_a_heavily_contaminated_set():
    """SBC set 35 (n 3.07, σ 0.11 mm, 40 % of the contacts displaced): every evolutionary-search result polished on
    the robust Student-t cost falls into a wide-noise basin (n ≈ 1.5, σ ≈ 0.8 mm, log-posterior ≈ 452), where the
    tempered SMC also ends; the results as found lie in the truth's basin, whose mode (≈ 502.7, climbed from the
    truth) the optimum check reaches by polishing them too on the sampled posterior."""
    from bayestouch.inference.run import optimum_mode
    from benchmarks.bench_sbc_users import SIZE_PRIOR_M, make_sbc_set

    s = make_sbc_set(35)
    pri = cm.with_size_prior(cm.load_priors(), *SIZE_PRIOR_M)
    logp, bounds = cm.make_log_prob(s["points"], pri, noise="outlier", free=s["free"])
    opt = optimum_mode(s["points"], logp, bounds, pri, 35, cm.param_names(False, "outlier"), batch=32)
    assert opt["log_post"] > 490, opt["log_post"]
    assert 2.7 < np.exp(opt["theta"][9]) < 3.7 and np.exp(opt["theta"][10]) < 3e-4


def test_smc_moves_one_component_per_mode_and_half_the_walkers_in_a_missed_mode():
    from bayestouch.inference.run import MIXTURE_SHARE, smc_moves

    rng = np.random.default_rng(0)
    # two separated modes holding 75 % and 25 % of the particles
    particles = np.vstack([rng.normal(0.0, 1.0, (768, 4)), rng.normal(0.0, 1.0, (256, 4)) + [12.0, 0, 0, 0]])
    moves, walkers = smc_moves(particles, 32, seed=0)
    mix, share = moves[0]
    assert share == MIXTURE_SHARE and abs(sum(w for _, w in moves) - 1) < 1e-12
    assert len(mix.centres) == 2
    np.testing.assert_allclose(mix.weights, [0.75, 0.25])
    np.testing.assert_allclose(mix.centres[1], [12.0, 0, 0, 0], atol=0.2)
    np.testing.assert_allclose(mix.chols[0] @ mix.chols[0].T, np.eye(4), atol=0.2)  # the mode's own width
    assert all(any(np.array_equal(w, p) for p in particles) for w in walkers)  # walkers start at particles
    assert len(np.unique(walkers, axis=0)) == 32
    far = {"theta": np.full(4, 20.0), "cov": 0.25 * np.eye(4)}
    moves, walkers = smc_moves(particles, 32, seed=0, extra_mode=far)
    near = np.linalg.norm(walkers - 20.0, axis=1) < 0.5 * 6
    assert near.sum() == 16
    mix = moves[0][0]
    assert len(mix.centres) == 3
    np.testing.assert_allclose(mix.centres[2], 20.0, atol=0.15)  # mean of ≥ 256 Laplace draws of sd 0.5
    np.testing.assert_allclose(mix.weights, [0.375, 0.125, 0.5])
    # negative control: one Gaussian cloud is one component, no walker far away
    moves0, walkers0 = smc_moves(particles[:768], 32, seed=0)
    assert len(moves0[0][0].centres) == 1 and not np.any(np.linalg.norm(walkers0 - 20.0, axis=1) < 3)


def test_smc_moves_start_on_distinct_particles_and_survive_copies_of_one():
    """Resampling leaves copies of a particle that no mutation moved (users'-like SBC set 9, σ 6 µm: 26 distinct
    walkers of 32). The walkers start on distinct particle values where there are enough, and where there are not
    (every particle one of 20 values), the chain still runs: emcee's snooker divided by the distance between a
    walker and its copy (0/0) and emcee stopped the fit on the NaN proposal; the project's snooker leaves such a
    walker where it is."""
    from bayestouch.inference.run import smc_moves
    from bayestouch.inference.sampler import sample

    rng = np.random.default_rng(3)
    base = rng.normal(0.0, 1.0, (40, 4))
    copies = base[rng.integers(0, 40, 1024)]  # 1024 particles, at most 40 distinct values
    _, walkers = smc_moves(copies, 32, seed=0)
    assert len(np.unique(walkers, axis=0)) == 32
    few = base[:20][rng.integers(0, 20, 1024)]  # 20 distinct values for 32 walkers: copies unavoidable
    moves, walkers = smc_moves(few, 32, seed=0)
    assert len(np.unique(walkers, axis=0)) == 20

    def logp(x):
        return -0.5 * np.sum(x * x, axis=1)

    # only the red-blue moves, the snooker's share raised: every walker meets its copy as z within the run
    red_blue = [(m, 1.0) for m, _ in moves[1:]]
    ch = sample(logp, walkers, None, walkers=32, ndim=4, seed=1, steps=300, progress=False, moves=red_blue)
    assert np.all(np.isfinite(ch.kept))


def test_smc_moves_propose_log_columns_in_log_space():
    """A positive parameter piled near 0 (an outlier fraction) is a Gaussian in its logarithm: the mixture proposes
    there, never below 0, and its density carries the Jacobian, so importance weights against the true density are
    nearly equal (negative control: without ``log_columns`` the mixture needs several components for the skewed
    coordinate, some of its proposals fall below 0, and its weights spread more)."""
    from bayestouch.inference.run import smc_moves

    rng = np.random.default_rng(1)
    w = np.exp(rng.normal(np.log(0.01), 0.8, 2048))
    particles = np.column_stack([rng.normal(0.0, 1.0, (2048, 3)), w])
    mix = smc_moves(particles, 32, seed=0, log_columns=[3])[0][0][0]
    draws = mix.draw(np.random.RandomState(0), 20000)
    assert np.all(draws[:, 3] > 0)
    assert abs(np.median(np.log(draws[:, 3])) - np.log(0.01)) < 0.05
    assert np.all(np.isneginf(mix.log_g(np.array([[0.0, 0.0, 0.0, -0.01], [0.0, 0.0, 0.0, 0.0]]))))
    # the density is that of the log-space mixture times 1/w: ratios at two values of w with the same log-space
    # density (a one-component mixture, symmetric in log w about its centre) are w2/w1
    c = float(mix.centres[0][3])
    lo, hi = np.array([[*mix.centres[0][:3], np.exp(c - 0.3)]]), np.array([[*mix.centres[0][:3], np.exp(c + 0.3)]])
    if len(mix.centres) == 1:
        np.testing.assert_allclose(mix.log_g(lo) - mix.log_g(hi), 0.6, atol=1e-9)

    def ess_fraction(m):
        x = m.draw(np.random.RandomState(0), 20000)
        with np.errstate(divide="ignore", invalid="ignore"):
            lw = np.log(x[:, 3])
            log_pi = -0.5 * np.sum(x[:, :3] ** 2, axis=1) - 0.5 * ((lw - np.log(0.01)) / 0.8) ** 2 - lw
        r = np.where(x[:, 3] > 0, log_pi - m.log_g(x), -np.inf)
        r = np.exp(r - r.max())
        return r.sum() ** 2 / (r**2).sum() / len(r), np.mean(x[:, 3] <= 0)

    plain = smc_moves(particles, 32, seed=0)[0][0][0]
    (ess_log, below_log), (ess_plain, below_plain) = ess_fraction(mix), ess_fraction(plain)
    assert len(mix.centres) == 1 and ess_log > 0.9 and below_log == 0
    assert len(plain.centres) > 1 and ess_plain < ess_log - 0.02 and below_plain > 0.005


def test_mean_shape_vector_is_the_same_for_every_alias():
    """Draws of one n-ellipsoid written as different aliases (axes permuted with the frame, wrapped angles) have
    that n-ellipsoid as their mean shape; averaging their canonical-looking parameters would not (negative control:
    the arithmetic mean of the raw vectors is off)."""
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.geometry.rotation import euler_from_matrix, rotation_matrix
    from bayestouch.inference.posterior import mean_shape_vector

    truth = np.array([0.01, -0.02, 0.03, 0.04, 0.02, 0.01, 0.7, 0.4, -1.1, 3.0])
    R = np.asarray(rotation_matrix(truth[6:9]))
    perms = [(0, 1, 2), (1, 0, 2), (2, 1, 0), (0, 2, 1)]
    rows = []
    for p in perms:
        P = np.eye(3)[:, list(p)]
        Rp = R @ P
        if np.linalg.det(Rp) < 0:
            Rp[:, 0] = -Rp[:, 0]
        ang = np.asarray(euler_from_matrix(Rp))
        rows.append(np.concatenate([truth[:3], truth[3:6][list(p)], ang, [truth[9]]]))
    rows = np.array(rows)
    shapes = [ne.from_vector(r) for r in rows]
    pts = np.array([[0.05, -0.01, 0.03], [0.0, 0.0, 0.0], [0.02, -0.04, 0.05]])
    res = [np.asarray(ne.inside_outside(s, pts)) for s in shapes]  # the rows are one surface
    np.testing.assert_allclose(np.array(res), np.tile(res[0], (len(res), 1)), rtol=1e-9)  # one surface
    m = mean_shape_vector(rows)
    np.testing.assert_allclose(m[3:6], truth[3:6], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(ne.inside_outside(ne.from_vector(m), pts)), res[0], rtol=1e-9)
    naive = rows.mean(axis=0)
    assert not np.allclose(np.asarray(ne.inside_outside(ne.from_vector(naive), pts)), res[0], rtol=1e-3)


@pytest.mark.slow
def test_optimum_check_continued_in_sigma_finds_the_mode_the_fit_missed_without_a_warning():
    """SBC set 19 (n 1.61, 33 of 98 contacts displaced, σ 26 µm; truth's mode ≈ 642.9): the default fit reported a
    wider mode as converged, with no warning (``benchmarks/bench_sbc_missed.py``). The optimum check with the
    trimmed starts, as the fit runs it on such data, polishes to ≈ 628 (negative control); continued downwards in σ
    (``anneal``, :func:`~bayestouch.inference.run.sigma_continuation`) it reaches the truth's mode, now more than
    :data:`~bayestouch.inference.run.MISSED_MODE_NATS` above the SMC's particles, so the chain starts walkers there.
    On the mixed-precision log-density the same check stops at ≈ 608."""
    from bayestouch.inference.run import TRIM_SEARCHES, candidate_thetas, optimum_mode
    from bayestouch.inference.trimmed import trimmed_starts
    from benchmarks.bench_sbc_users import SIZE_PRIOR_M, make_sbc_set

    s = make_sbc_set(19)
    pri = cm.with_size_prior(cm.load_priors(), *SIZE_PRIOR_M)
    logp, bounds = cm.make_log_prob(s["points"], pri, noise="outlier", free=s["free"])
    trimmed = trimmed_starts(
        s["points"], lambda sub, step: candidate_thetas(sub, 19 + 101 + step, pri, TRIM_SEARCHES)[0]
    )
    names = cm.param_names(False, "outlier")
    opt = {
        an: optimum_mode(s["points"], logp, bounds, pri, 19, names, batch=32, extra_starts=trimmed, anneal=an)
        for an in (False, True)
    }
    assert opt[False]["log_post"] < 635, opt[False]["log_post"]
    assert opt[True]["log_post"] > 640, opt[True]["log_post"]
    # the same on the mixed-precision log-density the sampler uses: its rounding stops the polishes short, which is
    # why run_contact_fit hands the check a float64 twin
    mixed, _ = cm.make_log_prob(s["points"], pri, noise="outlier", free=s["free"], precision="mixed")
    low = optimum_mode(s["points"], mixed, bounds, pri, 19, names, batch=32, extra_starts=trimmed, anneal=True)
    assert low["log_post"] < 620, low["log_post"]
    th = opt[True]["theta"]
    np.testing.assert_allclose(np.sort(np.exp(th[3:6])), np.sort(s["truth"].axes), rtol=0.03)
    assert abs(np.exp(th[9]) - 1.61) < 0.05 and np.exp(th[10]) < 35e-6


def test_sigma_continuation_returns_only_runs_it_raised():
    """A 1-D toy whose value falls as σ falls down to log σ = −3 and rises below: a run started at log σ = 0 is
    continued in halvings until a round no longer raises it; a run already at the optimum, or rounds = 0, returns
    nothing; equal values are continued once."""
    from bayestouch.inference.run import ANNEAL_STEP, sigma_continuation

    j = cm.PARAM_NAMES.index("log_sigma")
    box = [(-10.0, 10.0)] * 11

    def fg_batch(xs):
        xs = np.atleast_2d(xs)
        v = (xs[:, j] + 3.0) ** 2 + np.sum(xs[:, :j] ** 2, axis=1)
        g = 2 * xs.copy()
        g[:, j] = 2 * (xs[:, j] + 3.0)
        return v, g

    x0 = np.zeros(11)
    # the toy has no barrier, so a free polish from anywhere finds log σ = −3; held at each halving, the continuation
    # moves σ only by its steps and ends at the best: the free polish after the first round
    out = sigma_continuation(fg_batch, [(x0, 9.0), (x0.copy(), 9.0)], box)
    assert len(out) == 1
    th, v = out[0]
    assert abs(th[j] + 3.0) < 1e-6 and v < 1e-10
    at = np.full(11, 0.0)
    at[j] = -3.0
    assert sigma_continuation(fg_batch, [(at, 0.0)], box) == []
    assert sigma_continuation(fg_batch, [(x0, 9.0)], box, rounds=0) == []
    floor = [b if i != j else (-0.5 * ANNEAL_STEP, 10.0) for i, b in enumerate(box)]  # no room for a halving
    assert sigma_continuation(fg_batch, [(x0, 9.0)], floor) == []


def test_read_optimum_round_trips_and_refuses_a_damaged_file(tmp_path):
    from bayestouch.errors import BadInput
    from bayestouch.inference.run import read_optimum

    path = tmp_path / "optimum.npz"
    assert read_optimum(path) is None  # a run interrupted before its optimum check: searched on the resume
    opt = {"theta": np.arange(13.0), "log_post": 512.5, "cov": np.eye(13) * 1e-4, "trimmed_starts": 2}
    with open(path, "wb") as fh:
        np.savez(fh, **opt)
    back = read_optimum(path)
    assert np.array_equal(back["theta"], opt["theta"]) and np.array_equal(back["cov"], opt["cov"])
    assert back["log_post"] == 512.5 and back["trimmed_starts"] == 2
    path.write_bytes(path.read_bytes()[:100])  # cut off by a kill mid-write
    with pytest.raises(BadInput, match="optimum.npz cannot be read"):
        read_optimum(path)
