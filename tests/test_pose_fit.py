"""The contact-level fit with the pad's pose error marginalised (run_contact_fit(pose=...)): the law's limit, its
effect, its outputs and its refusals."""

import json

import numpy as np
import pytest
import xarray as xr

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import pose_error as pe
from bayestouch.inference.run import run_contact_fit
from bayestouch.planning.candidates import make_candidates

TRUE = ne.NEllipsoid(
    jnp.array([0.0, 0.01, 0.0]), jnp.array([0.03, 0.02, 0.015]), jnp.array([0.3, 0.2, 0.1]), jnp.array(2.5)
)
STROKES, PER, K = 6, 15, 12
FIT = {"seed": 1, "progress": False, "init": "optimize", "steps": 4000, "budget_s": 40.0}


def _case(sd: float):
    """Guarded-stroke-like contacts on TRUE (six arcs of 15, encoder noise 0.3 mm) and a law of K fingers whose
    error is one shift per stroke along its approach, sd ``sd`` metres; the contacts carry no pose error."""
    rng = np.random.default_rng(5)
    arcs = make_candidates(TRUE, STROKES, points=PER, seed=4, standoff=0.02)
    path = np.asarray(arcs.path).reshape(-1, 3)
    u = np.asarray(arcs.dirs).reshape(-1, 3)
    lab = np.repeat(np.arange(STROKES), PER)
    t = np.tile(np.linspace(0.0, 2.0, PER), STROKES)
    pts = path + rng.normal(0.0, 3e-4, path.shape)
    ens = rng.normal(0.0, sd, (K, STROKES))[:, lab, None] * u[None]
    return pts, pe.ensemble_model(pts, ens, lab, t, offset_sd=0.0)


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    root = tmp_path_factory.mktemp("pose_fit")
    pts, narrow = _case(1e-7)
    _, wide = _case(2e-3)
    out = {
        "plain": run_contact_fit(pts, root / "plain", noise="gaussian", **FIT),
        "narrow": run_contact_fit(pts, root / "narrow", pose=narrow, **FIT),
        "wide": run_contact_fit(pts, root / "wide", pose=wide, **FIT),
    }
    return root, pts, wide, out


@pytest.mark.slow
def test_a_law_without_spread_is_the_plain_fit_and_a_wide_one_widens_it(fits):
    """A pose-error law of 0.1 µm gives the plain Gaussian fit's posterior (the volume's mean within 3 Monte Carlo
    errors of the two, its sd within 20 %); a law of 2 mm per stroke on the same contacts widens the volume's sd
    more than 1.5× (the control: a fit that dropped the law would not). Every fit lies within 3 sd of the truth."""
    _, _, _, s = fits
    v = {k: s[k]["derived"]["volume_m3"] for k in s}
    for k in s:
        assert s[k]["diagnostics"]["converged"], (k, s[k]["diagnostics"])
    ess = min(s["plain"]["diagnostics"]["min_ess_bulk"], s["narrow"]["diagnostics"]["min_ess_bulk"])
    mc = v["plain"]["sd"] * np.sqrt(2.0 / ess)
    assert abs(v["narrow"]["mean"] - v["plain"]["mean"]) < 3 * mc
    assert 0.8 < v["narrow"]["sd"] / v["plain"]["sd"] < 1.25
    assert v["wide"]["sd"] > 1.5 * v["plain"]["sd"]
    volume = float(ne.volume(TRUE))
    for k in s:  # the contacts carry no pose error: every fit is within 3 sd of the truth (one case: not 90 %)
        assert abs(v[k]["mean"] - volume) < 3 * v[k]["sd"], (k, v[k], volume)


@pytest.mark.slow
def test_the_pose_fit_reports_its_scale_and_no_pointwise_terms(fits, tmp_path):
    """summary.json has the law's scale s and the likelihood's description; posterior.nc has no log-likelihood or
    replicated data (the law couples a stroke's contacts); the residuals' neighbour check is not made; resuming
    with another law is refused, as another run."""
    root, pts, wide, s = fits
    w = s["wide"]
    assert set(w["parameters"]["pose_scale"]) >= {"mean", "q05", "q95", "r_hat"}
    assert w["parameters"]["pose_scale"]["mean"] > 0
    assert "pose error marginalised" in w["model"]["likelihood"]
    assert "misfit" not in w["diagnostics"] and "misfit" in s["plain"]["diagnostics"]
    assert (
        json.loads((root / "wide" / "summary.json").read_text())["parameters"]["pose_scale"]
        == w["parameters"]["pose_scale"]
    )
    with pytest.raises(OSError):
        xr.open_dataset(root / "wide" / "posterior.nc", group="log_likelihood")
    post = xr.open_dataset(root / "wide" / "posterior.nc", group="posterior")
    assert post["pose_scale"].attrs["units"] == "1"
    post.close()
    _, other = _case(1e-3)
    with pytest.raises(BadInput, match="pose-error law"):
        run_contact_fit(pts, root / "wide", pose=other, resume=True, **{**FIT, "steps": 5000})


def test_bad_pose_input_is_refused_before_any_work(tmp_path):
    pts, law = _case(1e-3)
    cases = [
        ({"pose": "law.toml"}, "pose: expected an EnsembleModel"),
        ({"pose": law._replace(moved=law.moved[:-1])}, "covers 89 contacts, the fit has 90"),
        ({"pose": law, "ffd": (3, 3, 3)}, "no ffd"),
        ({"pose": law, "normals": np.tile([0.0, 0.0, 1.0], (len(pts), 1))}, "no normals"),
        ({"pose": law, "free": np.zeros((3, 3))}, "no free"),
        ({"pose": law, "noise": "outlier"}, "no noise"),
        ({"pose": law, "nu": 4.0}, "no noise"),
        ({"pose": law, "precision": "mixed"}, "no precision"),
    ]
    for kw, msg in cases:
        with pytest.raises(BadInput, match=msg):
            run_contact_fit(pts, tmp_path / "o", progress=False, **kw)
        assert not (tmp_path / "o").exists()
