"""The notebook API: ``bt.fit(array) -> Fit`` with ArviZ InferenceData as ArviZ users expect, a summary table with
units, trimesh meshes, a picture, save and load; ArviZ's own functions on the result."""

import gc
import json

import arviz as az
import numpy as np
import pytest
import xarray as xr

import bayestouch as bt
from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_surface

TRUE = ne.NEllipsoid(
    jnp.array([0.002, -0.001, 0.003]), jnp.array([0.028, 0.02, 0.014]), jnp.array([0.3, -0.2, 0.6]), jnp.array(2.6)
)
N_POINTS = 320
SIGMA = 3e-4


@pytest.fixture(scope="module")
def points():
    rng = np.random.default_rng(4)
    on = sample_surface(TRUE, N_POINTS, seed=4)
    n = np.asarray(ne.normals(TRUE, jnp.asarray(on)))
    return on + rng.normal(0, SIGMA, (N_POINTS, 1)) * n


@pytest.fixture(scope="module")
def result(points):
    return bt.fit(points, seed=0, progress=False, budget_s=None)


def test_fit_returns_inference_data_with_named_dims_units_and_volume(result):
    idata = result.idata
    assert isinstance(idata, az.InferenceData)
    for g in ("posterior", "sample_stats", "log_likelihood", "posterior_predictive", "observed_data", "derived"):
        assert g in idata.groups(), g
    post = idata.posterior
    assert post["volume"].attrs["units"] == "m3" and post["a"].attrs["units"] == "m"
    assert post["xi"].attrs["units"] == "rad" and post["n"].attrs["units"] == "1"
    assert post.attrs["inference_library"] == "emcee" and post.attrs["creator"] == "bayestouch"
    # the volume of every draw is the closed form of that draw's shape (eq. 11)
    i, j = 3, 7
    vec = jnp.asarray([float(post[k][i, j]) for k in ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n")])
    assert float(post["volume"][i, j]) == pytest.approx(float(ne.volume(ne.from_vector(vec))), rel=1e-12)
    # a recovered truth: the true volume inside the posterior's 99.9 % range, and the summary agrees with the draws
    vol = post["volume"].values.ravel()
    assert np.quantile(vol, 0.0005) < float(ne.volume(TRUE)) < np.quantile(vol, 0.9995)
    assert vol.mean() == pytest.approx(result.results["derived"]["volume_m3"]["mean"], rel=1e-12)
    # observations keyed alike in every group, with named dims and coordinates
    obs = idata.observed_data
    assert obs["points"].dims == ("point", "xyz") and list(obs["xyz"].values) == ["x", "y", "z"]
    assert idata.posterior_predictive["points"].dims == ("chain", "draw", "point", "xyz")
    assert idata.log_likelihood["points"].dims == ("chain", "draw", "point")
    assert list(idata.log_likelihood.data_vars) == ["points"]
    # sample_stats: lp is the chain's log-posterior; the walkers' move rate lies strictly between 0 and 1
    lp = idata.sample_stats["lp"].values
    assert lp.shape == post["a"].shape and np.isfinite(lp).all()
    moved = np.nanmean(idata.sample_stats["accepted"].values)
    assert 0.05 < moved < 0.95
    inertia = idata.derived["inertia"]
    assert inertia.attrs["units"] == "m5" and (np.diff(inertia.values, axis=-1) <= 0).all()


# ArviZ 0.23's plots call a matplotlib helper that matplotlib 3.11 deprecates: theirs, not ours
@pytest.mark.filterwarnings("ignore:Passing a dict or None as alias_mapping:DeprecationWarning")
def test_arviz_functions_work_on_the_result(result):
    import matplotlib

    matplotlib.use("Agg")  # the test process only: the library itself never switches the backend
    import matplotlib.pyplot as plt

    idata = result.idata
    table = az.summary(idata, var_names=["a", "n", "volume"], round_to="none")
    assert table.loc["volume", "r_hat"] < 1.01 and table.loc["a", "mean"] == pytest.approx(0.028, rel=0.02)
    az.plot_trace(idata, var_names=["a", "volume"])
    az.plot_ppc(idata, var_names=["radius"], num_pp_samples=20)
    plt.close("all")
    loo = result.loo()
    assert np.isfinite(loo.elpd_loo) and loo.n_data_points == N_POINTS
    # the same through ArviZ directly, told that the log-likelihood's draws are thinned (nearly independent)
    assert az.loo(idata, reff=1.0).elpd_loo == loo.elpd_loo
    assert (loo.pareto_k.values < 0.7).mean() > 0.98  # the contacts are drawn from the model: few influential ones


def test_loo_pit_is_calibrated_and_detects_a_too_narrow_predictive(result):
    """LOO-PIT of each contact's radius: the model generated the data, so 90 % of the PIT values fall in
    [0.05, 0.95] (binomial sd for 320 points: 1.7 %; tolerance 3 sd). Negative control: the same predictive shrunk
    to 70 % of its spread about each point's predictive mean (a 30 %-too-narrow posterior predictive) puts
    only ~75 % there (Gaussian: P(|z| < 1.645 × 0.7)), which the tolerance rejects."""
    pit = np.asarray(result.loo_pit())
    inside = np.mean((pit > 0.05) & (pit < 0.95))
    assert abs(inside - 0.90) < 0.051
    idata = result.idata
    ll = idata.log_likelihood["points"].stack(__sample__=("chain", "draw"))
    lw = az.psislw(-ll, reff=1.0)[0]
    y_hat = idata.posterior_predictive["radius"].stack(__sample__=("chain", "draw"))
    narrow = y_hat.mean("__sample__") + 0.7 * (y_hat - y_hat.mean("__sample__"))
    pit_narrow = np.asarray(az.loo_pit(y=idata.observed_data["radius"], y_hat=narrow, log_weights=lw))
    assert np.mean((pit_narrow > 0.05) & (pit_narrow < 0.95)) < 0.90 - 0.051


def test_summary_table_meshes_and_plot(result):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = result.summary()
    assert {"mean", "sd", "q05", "q95", "unit", "r_hat", "ess_bulk"} <= set(table.columns)
    assert table.loc["volume", "unit"] == "m3" and table.loc["a", "unit"] == "m" and table.loc["xi", "unit"] == "rad"
    assert table.loc["volume", "mean"] == result.results["derived"]["volume_m3"]["mean"]
    mesh = result.mesh()
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(table.loc["volume", "mean"], rel=0.01)  # the mean shape's mesh
    um = result.uncertainty_mesh()
    spread = um.vertex_attributes["spread"]
    assert spread.shape == (len(um.vertices),) and (spread > 0).all() and spread.max() < 3 * SIGMA
    assert np.array_equal(um.vertex_attributes["quality"], spread)
    fig = result.plot()
    assert len(fig.axes) >= 2 and "volume" in fig.axes[-1].get_xlabel()
    plt.close(fig)
    assert result.converged and "volume" in repr(result)


def test_save_load_round_trip_and_temporary_folder(result, tmp_path):
    saved = result.save(tmp_path / "run")
    loaded = bt.Fit.load(saved)
    assert loaded.results == json.loads((saved / "summary.json").read_text()) == result.results
    xr.testing.assert_identical(loaded.idata.posterior, result.idata.posterior)
    with pytest.raises(BadInput, match="already holds a run"):
        result.save(saved)
    result.save(saved, overwrite=True)
    # a fit without a folder runs in a temporary one that goes with the object
    small = bt.fit(result.idata.observed_data["points"].values[:60], seed=1, progress=False, steps=300)
    folder = small.folder
    assert (folder / "posterior.nc").is_file()
    del small
    gc.collect()
    assert not folder.exists()


def test_bad_input_names_the_argument(points, tmp_path):
    with pytest.raises(BadInput, match=r"data: expected contact points as an \(M, 3\) array"):
        bt.fit(np.zeros((5, 2)))
    with pytest.raises(BadInput, match="NaN"):
        bt.fit(np.full((20, 3), np.nan))
    with pytest.raises(BadInput, match="unknown option.*texture"):
        bt.fit(points, texture="on")
    with pytest.raises(BadInput, match="walkers"):
        bt.fit(points, walkers=11)
    with pytest.raises(BadInput, match="budget_s"):
        bt.fit(points, budget_s=-3)
    with pytest.raises(BadInput, match="no such file"):
        bt.fit(tmp_path / "missing.csv")
    with pytest.raises(BadInput, match="no summary.json"):
        bt.Fit.load(tmp_path)


def test_library_figures_leave_the_users_backend_alone(tmp_path):
    """A notebook's backend survives the library's figures (trace, pair and experiment plots, all written to files
    without pyplot), and no figure is left open in pyplot: run in a fresh interpreter whose backend is set to
    matplotlib's ``template`` first."""
    import subprocess
    import sys

    script = f"""
import matplotlib
matplotlib.use("template")
import matplotlib.pyplot as plt
import numpy as np, arviz as az
from pathlib import Path
from bayestouch.report import figures as rp
from bayestouch.planning.experiment import plot_results
out = Path({str(tmp_path)!r})
rng = np.random.default_rng(0)
idata = az.from_dict(posterior={{k: rng.normal(size=(4, 50)) for k in ("a", "b", "n")}})
rp.plot_trace(out, idata, ["a", "b"])
rp.plot_pair(out, idata, ["a", "b", "n"])
rows = [dict(planner=p, object="egg", trial=t, stroke=s, chamfer=rng.random(), volume_error=rng.random())
        for p in ("eig", "random") for t in range(2) for s in range(3)]
plot_results(rows, out / "err.png")
assert matplotlib.get_backend() == "template", matplotlib.get_backend()
assert plt.get_fignums() == [], plt.get_fignums()
print("ok")
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]
    for name in ("trace.png", "pair.png", "err.png"):
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"


def test_simulate_and_calibrate_verbs_match_the_commands(tmp_path):
    """bt.simulate returns the recording `bayestouch simulate` writes (same arguments, same data); bt.calibrate
    the device file `bayestouch calibrate` writes."""
    from bayestouch.cli import main
    from bayestouch.io.device_file import read_device_file
    from bayestouch.io.recording import read_recording

    kw = dict(strokes=2, seed=5, duration=0.5, rate=20.0, depth=[2e-4, 4e-4], mode="empirical")
    ds = bt.simulate("sphere", **kw, out=tmp_path / "api.nc")
    assert ds.sizes["stroke"] == 2 and "time" in ds.coords and ds.attrs["Conventions"] == "CF-1.10"
    assert np.allclose(ds["stroke_depth"].values, [2e-4, 4e-4])
    args = ["--strokes", "2", "--seed", "5", "--duration", "0.5", "--rate", "20", "--depth", "2e-4,4e-4"]
    assert (
        main(
            [
                "simulate",
                "--object",
                "sphere",
                *args,
                "--mode",
                "empirical",
                "--out",
                str(tmp_path / "cli.nc"),
                "--quiet",
            ]
        )
        == 0
    )
    cli = read_recording(tmp_path / "cli.nc")
    for v in ("taxel_current", "contact_force", "time"):
        np.testing.assert_array_equal(cli[v].values, ds[v].values)
    with pytest.raises(BadInput, match="already exists"):
        bt.simulate("sphere", **kw, out=tmp_path / "api.nc")
    with pytest.raises(BadInput, match="depth"):
        bt.simulate("sphere", depth=0.01)
    cal = bt.calibrate(ds, "sphere", out=tmp_path / "finger.toml")
    assert np.shape(cal.log_gain) == (ds.sizes["taxel"],) and np.all(np.isfinite(cal.log_gain_sd))
    np.testing.assert_allclose(read_device_file(tmp_path / "finger.toml").log_gain, cal.log_gain, rtol=1e-6)


def test_misfit_is_a_property_and_is_said(result, tmp_path):
    """A correct fit is no misfit; the same run with the wrong shape's verdict written into its summary (as the
    fit writes it) reads as one in the property, the repr and the figure's title."""
    assert result.misfit is False
    assert "MISFIT" not in repr(result)
    saved = result.save(tmp_path / "run")
    summary = json.loads((saved / "summary.json").read_text())
    summary["diagnostics"]["misfit"] = True
    (saved / "summary.json").write_text(json.dumps(summary))
    wrong = bt.Fit.load(saved)
    assert wrong.misfit is True and "MISFIT" in repr(wrong)
    assert wrong.converged  # the figure names the first problem: here the misfit
    fig = wrong.plot()
    assert "MISFIT" in fig._suptitle.get_text()
