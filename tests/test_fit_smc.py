"""The default contact-level fit on sparse data: SMC start, outlier parameters, free space, modes in summary.json."""

import json

import numpy as np

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


def test_default_fit_of_a_one_sided_contaminated_set(tmp_path):
    """60 contacts on one side of a sphere (r = 20 mm, 0.3 mm noise), 6 displaced 5 mm inwards, free-space points
    beyond the touched side: the SMC-started fit counts the displaced contacts as inward outliers (σ stays near
    0.3 mm), reports its SMC stage and its modes, and a resumed run reuses the saved particles."""
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
    # the smallest semi-axis is the sphere's radius, which the cap constrains
    assert abs(par["c"]["mean"] - 0.02) < 0.002
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["diagnostics"]["modes"] == diag["modes"]
    before = np.load(tmp_path / "smc.npz")["particles"]
    s2 = run_contact_fit(pts, tmp_path, seed=0, steps=450, progress=False, free=free, resume=True, budget_s=None)
    assert s2["diagnostics"]["steps"] == 450
    assert np.array_equal(np.load(tmp_path / "smc.npz")["particles"], before)
