"""`bayestouch fit` on contact points: outputs, resumable chain, bad input."""

import json

import numpy as np
import pytest

from bayestouch.backend import jnp
from bayestouch.cli import main
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_surface
from bayestouch.inference import contact as cm
from bayestouch.io.contacts import save_contact_points

TRUE = ne.NEllipsoid(
    jnp.array([0.004, -0.002, 0.001]), jnp.array([0.03, 0.022, 0.015]), jnp.array([0.4, 0.3, -0.5]), jnp.array(3.0)
)


@pytest.fixture(scope="module")
def points_csv(tmp_path_factory):
    rng = np.random.default_rng(0)
    on = sample_surface(TRUE, 200, seed=0)
    n = np.asarray(ne.normals(TRUE, jnp.asarray(on)))
    path = tmp_path_factory.mktemp("fit") / "pts.csv"
    save_contact_points(path, on + rng.normal(0, 3e-4, (200, 1)) * n)
    return path


@pytest.mark.slow
def test_fit_writes_outputs_and_resumes(points_csv, tmp_path):
    import emcee

    out = tmp_path / "run"
    # --budget 0: no time limit (the default 60 s, SMC included, can cut a slow CI machine's chain short)
    args = ["--walkers", "24", "--quiet", "--budget", "0"]
    assert main(["fit", str(points_csv), "--out", str(out), "--steps", "200", *args]) == 0
    s = json.loads((out / "summary.json").read_text())
    for k in ("mean", "sd", "q05", "q95", "r_hat", "ess_bulk"):
        assert np.isfinite(s["parameters"]["a"][k])
    v = s["derived"]["volume_m3"]
    assert v["q05"] < float(ne.volume(TRUE)) * 1.02 and v["q95"] > float(ne.volume(TRUE)) * 0.98
    assert s["diagnostics"]["n_samples"] > 0 and s["diagnostics"]["converged"] is False  # 200 steps: too short
    assert s["model"]["precision"] == "mixed"  # the default (outlier) model without normals samples in mixed precision
    assert (out / "posterior.nc").is_file() and (out / "mean_shape.ply").read_bytes()[:3] == b"ply"
    _check_posterior_file(out, n_points=200)
    _check_uncertainty_mesh(out, s)
    # the occupancy grid: inside at the centre, outside beyond the longest axis, its 0.5 set of the true volume
    from bayestouch.io.occupancy import load_occupancy

    occ = load_occupancy(out)
    assert "occupancy.npz" in s["files"]
    c = np.asarray(TRUE.centre)
    assert occ.at([c])[0] > 0.99 and occ.at([c + [0.045, 0.0, 0.0], c + [0.0, 0.0, 0.03]]).max() < 0.01
    assert occ.volume(0.5) == pytest.approx(float(ne.volume(TRUE)), rel=0.08)  # 40^3 cells of the grid
    first = emcee.backends.HDFBackend(str(out / "chain.h5"), read_only=True).get_chain()
    # resume to 300 steps: the first 200 are kept bit for bit
    assert main(["fit", str(points_csv), "--out", str(out), "--steps", "300", "--resume", *args]) == 0
    chain = emcee.backends.HDFBackend(str(out / "chain.h5"), read_only=True).get_chain()
    assert chain.shape == (300, 24, 13) and np.array_equal(chain[:200], first)


def test_fit_bad_inputs_exit_2(tmp_path, capsys, points_csv):
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n1,2\n")
    assert main(["fit", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "z" in err and "\n" not in err
    assert main(["fit", str(points_csv), "--out", str(tmp_path / "o"), "--walkers", "10"]) == 2
    assert "--walkers" in capsys.readouterr().err
    assert main(["fit", str(points_csv), "--out", str(tmp_path / "o"), "--ffd-tau", "-1"]) == 2
    assert "--ffd-tau" in capsys.readouterr().err
    assert main(["fit", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "no such file" in err and "\n" not in err
    garbage = tmp_path / "rec.nc"
    garbage.write_bytes(b"not a netCDF file")
    assert main(["fit", str(garbage), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "netCDF" in err and "\n" not in err
    with pytest.raises(SystemExit) as e:  # argparse: a malformed lattice size is a usage error (exit 2)
        main(["fit", str(points_csv), "--out", str(tmp_path / "o"), "--ffd", "3x3"])
    assert e.value.code == 2 and "3x3" in capsys.readouterr().err


def _check_posterior_file(out, n_points):
    import arviz as az

    idata = az.from_netcdf(str(out / "posterior.nc"))
    for g in ("posterior", "log_likelihood", "posterior_predictive", "observed_data"):
        assert g in idata.groups(), g
    assert idata.log_likelihood["points"].shape[-1] == n_points
    obs = idata.observed_data["points"].values
    rep = idata.posterior_predictive["points"].values.reshape(-1, n_points, 3)
    assert obs.shape == (n_points, 3) and np.isfinite(rep).all()
    # a posterior-predictive check with a known answer: the data were drawn from the model, so the spread of the
    # replicated points about their own median point matches the observed one to within the draws' scatter (2 %).
    # Medians: the outlier model's displaced contacts are half-Cauchy (a replicate may hold one metres away), and
    # one such point moves a mean radius by ~10 %
    r_obs = np.median(np.linalg.norm(obs - np.median(obs, axis=0), axis=1))
    r_rep = np.median(np.linalg.norm(rep - np.median(rep, axis=1, keepdims=True), axis=2), axis=1)
    assert abs(np.median(r_rep) / r_obs - 1) < 0.02
    # log-likelihood group = the model's pointwise density at those draws: its sum is finite and near the
    # Student-t optimum (σ ≈ 0.3 mm → log density ≈ −log σ ≈ 8 per point)
    ll = idata.log_likelihood["points"].values.sum(axis=-1)
    assert np.isfinite(ll).all() and 5 * n_points < ll.mean() < 9 * n_points
    # sample_stats' lp is the log-posterior of θ (the chain's semi-axes sampled in metres, the Jacobian's Σ log a
    # taken back out: left in, it would be off by ≈ 12 nats), recomputed in float64 from the draws themselves. The
    # posterior group holds each draw's canonical alias, whose Haar density log|sin ξ| differs from the sampled
    # alias's: the sampled one is among the 24 (aliases), so the nearest of their log-posteriors matches
    from bayestouch.geometry.symmetry import aliases

    post = idata.posterior
    names = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n", "sigma", "w_in", "w_out")
    flat = np.column_stack([post[k].values.reshape(-1) for k in names])[::397][:10]
    lp = idata.sample_stats["lp"].values.reshape(-1)[::397][:10]
    theta = flat.copy()
    theta[:, [3, 4, 5, 9, 10]] = np.log(flat[:, [3, 4, 5, 9, 10]])
    logp, _ = cm.make_log_prob(obs, cm.load_priors(), None, noise="outlier", precision="float64")
    nearest = [np.min(np.abs(np.asarray(logp(aliases(t))) - v)) for t, v in zip(theta, lp, strict=True)]
    assert max(nearest) < 0.01, nearest  # mixed precision in the run


def _check_uncertainty_mesh(out, summary):
    from bayestouch.io.meshes import read_spread_mesh

    m = read_spread_mesh(out / "uncertainty_mesh.ply")
    spread = m.vertex_attributes["spread"]  # the PLY's vertex property, loaded as a vertex attribute
    assert np.array_equal(m.vertex_attributes["quality"], spread)  # and as MeshLab's scalar field
    assert len(spread) == len(m.vertices) and (spread > 0).all()
    colours = np.asarray(m.visual.vertex_colors)
    assert len(np.unique(colours[:, :3], axis=0)) > 10  # coloured by the spread, not one colour
    # 200 points with 0.3 mm noise pin the surface to a fraction of the noise, and nowhere to more than the noise
    assert spread.max() < 3e-4 and summary["derived"]["surface_spread_m"]["mean"] < 1.5e-4
    inertia = summary["derived"]["inertia_principal_m5"]
    assert inertia["q05"][0] <= inertia["mean"][0] <= inertia["q95"][0]


@pytest.mark.slow
def test_fit_with_ffd_lattice_follows_a_dented_surface(tmp_path):
    """Data on an n-ellipsoid moved by a lattice displacement: the --ffd run's mean mesh lies closer to the data
    than the rigid n-ellipsoid of the same posterior (negative control)."""
    import trimesh

    from bayestouch.geometry.mesh import closest_points, nellipsoid_mesh
    from bayestouch.inference import ffd_marginal as fm

    theta = np.concatenate(
        [np.asarray(TRUE.centre), np.log(np.asarray(TRUE.axes)), np.asarray(TRUE.angles), [np.log(3.0)], [np.log(1e-4)]]
    )
    rng = np.random.default_rng(7)
    local = np.asarray(ne.to_local(TRUE, jnp.asarray(sample_surface(TRUE, 300, seed=7))))
    moved = np.asarray(
        fm.deformed_points(jnp.asarray(theta), jnp.asarray(rng.normal(0, 2e-3, (27, 3))), jnp.asarray(local), (3, 3, 3))
    )
    pts = moved + rng.normal(0, 1e-4, moved.shape)
    path = tmp_path / "dented.csv"
    save_contact_points(path, pts)
    out = tmp_path / "ffd"
    assert (
        main(
            [
                "fit",
                str(path),
                "--out",
                str(out),
                "--steps",
                "150",
                "--walkers",
                "24",
                "--ffd",
                "3x3x3",
                "--ffd-tau",
                "2e-3",
                "--quiet",
            ]
        )
        == 0
    )
    s = json.loads((out / "summary.json").read_text())
    assert s["model"]["ffd_size"] == "3x3x3"
    refined = trimesh.load(str(out / "mean_shape.ply"), process=False)
    p = s["parameters"]
    rigid = ne.NEllipsoid(
        jnp.array([p[k]["mean"] for k in ("x_G", "y_G", "z_G")]),
        jnp.array([p[k]["mean"] for k in ("a", "b", "c")]),
        jnp.array([p[k]["mean"] for k in ("xi", "psi", "zeta")]),
        jnp.array(p["n"]["mean"]),
    )
    d_ref = closest_points(np.asarray(refined.vertices), np.asarray(refined.faces), pts)[1]
    d_rig = closest_points(*nellipsoid_mesh(rigid, 32), pts)[1]
    assert np.sqrt(np.mean(d_ref**2)) < 0.5 * np.sqrt(np.mean(d_rig**2))


@pytest.mark.slow
def test_fit_killed_mid_run_resumes_with_nothing_lost(points_csv, tmp_path):
    """SIGKILL the CLI while it samples, then --resume: every step on disk at the kill is kept bit for bit and the
    chain reaches its full length."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import emcee

    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "bayestouch.cli",
        "fit",
        str(points_csv),
        "--out",
        str(out),
        "--steps",
        "3000",
        "--walkers",
        "24",
        "--quiet",
        "--budget",
        "0",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 300
        while time.time() < deadline:
            time.sleep(0.5)
            try:
                if emcee.backends.HDFBackend(str(out / "chain.h5"), read_only=True).iteration >= 50:
                    break
            except (OSError, KeyError, AttributeError):
                continue
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(30)
    before = emcee.backends.HDFBackend(str(out / "chain.h5"), read_only=True).get_chain()
    assert 50 <= len(before) < 3000
    done = len(before) + 40
    assert (
        main(
            ["fit", str(points_csv), "--out", str(out), "--steps", str(done), "--walkers", "24", "--resume", "--quiet"]
            + ["--budget", "0"]
        )
        == 0
    )
    after = emcee.backends.HDFBackend(str(out / "chain.h5"), read_only=True).get_chain()
    assert after.shape == (done, 24, 13) and np.array_equal(after[: len(before)], before)


@pytest.mark.slow
def test_fit_with_normals_and_outlier_mixture(tmp_path):
    """Normals in the file add κ; --noise mixture adds the outlier fraction w, whose posterior finds the 15 %
    outliers; the log-likelihood group has one column per point."""
    import arviz as az

    rng = np.random.default_rng(3)
    on = sample_surface(TRUE, 200, seed=3)
    n = np.asarray(ne.normals(TRUE, jnp.asarray(on)))
    pts = on + rng.normal(0, 3e-4, (200, 1)) * n
    bad = rng.choice(200, 30, replace=False)
    pts[bad] += rng.uniform(0.005, 0.015, (30, 1)) * n[bad]
    measured_n = n + rng.normal(0, 0.05, n.shape)
    path = tmp_path / "with_normals.csv"
    save_contact_points(path, pts, normals=measured_n)
    out = tmp_path / "mix"
    assert (
        main(
            ["fit", str(path), "--out", str(out), "--steps", "300", "--walkers", "28", "--noise", "mixture", "--quiet"]
        )
        == 0
    )
    s = json.loads((out / "summary.json").read_text())
    assert s["model"]["normals_used"] is True and s["model"]["noise"] == "mixture"
    assert s["model"]["precision"] == "float64"  # mixed precision does not apply to normals or the mixture
    w = s["parameters"]["w_outlier"]
    # 30 of 200 are outliers: the binomial sd of the fraction is 0.025; the interval must hold 0.15
    assert w["q05"] < 0.15 < w["q95"] and 0.08 < w["mean"] < 0.25
    # normals measured with 0.05 rad-ish noise per component: κ ≈ 1/(2·0.05²) = 200, certainly > 50
    assert s["parameters"]["kappa"]["mean"] > 50
    idata = az.from_netcdf(str(out / "posterior.nc"))
    assert idata.log_likelihood["points"].shape[-1] == 200
    # the measured normals are data too: observed (normalised) and replicated (unit vMF draws about the model's)
    obs_n = idata.observed_data["normals"].values
    np.testing.assert_allclose(obs_n, measured_n / np.linalg.norm(measured_n, axis=1, keepdims=True), atol=1e-12)
    rep_n = idata.posterior_predictive["normals"].values
    assert rep_n.shape[-2:] == (200, 3) and rep_n.shape[:2] == idata.posterior_predictive["points"].shape[:2]
    np.testing.assert_allclose(np.linalg.norm(rep_n, axis=-1), 1.0, atol=1e-12)
    assert main(["fit", str(path), "--out", str(tmp_path / "x"), "--ffd", "3x3x3"]) == 2


def test_vmf_sample_has_the_known_mean_cosine_and_no_preferred_azimuth():
    """E[cos] to the mean direction is coth κ − 1/κ (3-D von Mises–Fisher), the tangent part averages to zero;
    a sampler at the wrong κ (2κ) is caught by the same tolerance (negative control)."""
    from bayestouch.inference.posterior import vmf_sample

    rng = np.random.default_rng(4)
    n = 100_000
    mean = rng.normal(size=(n, 3))
    mean /= np.linalg.norm(mean, axis=1, keepdims=True)
    for kappa in (0.5, 5.0, 200.0):
        x = vmf_sample(mean, kappa, rng)
        np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-12)
        w = np.sum(x * mean, axis=1)
        expect = 1.0 / np.tanh(kappa) - 1.0 / kappa
        tol = 5 * w.std() / np.sqrt(n)
        assert abs(w.mean() - expect) < tol, (kappa, w.mean(), expect, tol)
        wrong = 1.0 / np.tanh(2 * kappa) - 1.0 / (2 * kappa)
        assert abs(w.mean() - wrong) > 3 * tol, (kappa, w.mean(), wrong, tol)
        tangent = x - w[:, None] * mean
        assert np.all(np.abs(tangent.mean(axis=0)) < 5 * np.sqrt(max(1 - expect, 1e-12) / n) + 1e-12)


def test_a_chain_too_short_for_diagnostics_reports_them_as_unknown(points_csv, tmp_path, capsys):
    """--steps 5 leaves R-hat and ESS undefined (null in summary.json): the CLI's report line says n/a and NOT
    converged instead of failing with an internal error after writing the run (issue 24)."""
    out = tmp_path / "short"
    assert main(["fit", str(points_csv), "--out", str(out), "--steps", "5", "--init", "optimize", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "NOT converged" in printed and "n/a" in printed
    d = json.loads((out / "summary.json").read_text())["diagnostics"]
    assert d["converged"] is False
    # and why: the reasons in summary.json, printed one per line under NOT CONVERGED
    assert d["not_converged_because"] and "step limit" in d["not_converged_because"][-1]
    assert "NOT CONVERGED" in printed and all(f"  - {w}" in printed for w in d["not_converged_because"])
