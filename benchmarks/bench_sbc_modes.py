"""Does the fit miss the truth's mode, or does the posterior prefer another? For data sets of
:mod:`benchmarks.bench_sbc_users`, the default fit's best draw and the truth's local mode compared on the
log-posterior the fit samples.

For each set: the truth θ* polished by L-BFGS-B to its local mode θ̂* (:func:`~benchmarks.bench_sbc_users.local_mode_gap`
reports the same climb), the default fit (``run_contact_fit``, 60 s budget, started from the prior) and its best
draw polished to its mode θ̂_fit. ``fit_mode − truth_mode`` ≥ 0 says the sampler found a mode at least as probable
as the truth's: a truth beyond every draw is then the posterior's verdict, not the sampler's failure; < 0 says the
sampler missed a better mode. The displaced contacts' share of the difference is reported per group (core
contacts, displaced inwards, displaced outwards, free-space positions).

Run: ``python -m benchmarks bench_sbc_modes`` (``BAYESTOUCH_SBC_MODE_SEEDS``: comma-separated seeds, default the
sets of ``results/sbc_users.csv`` whose truth lay beyond every draw of a shape quantity without a flag, and set 0).
Writes ``results/sbc_modes.json``.
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import bench_sbc_users as su

__all__ = ["compare_modes", "default_seeds", "bench_sbc_modes"]

RESULTS = Path(__file__).resolve().parent / "results"
SHAPE = ("a_1", "a_2", "a_3", "volume")


def default_seeds() -> list[int]:
    """Set 0 and the sets of ``sbc_users.csv`` whose truth lay beyond every draw of a semi-axis or the volume while
    the fit raised no flag."""
    path = RESULTS / "sbc_users.csv"
    rows = list(csv.DictReader(path.open(newline=""))) if path.exists() else []
    seeds = [0]
    for r in rows:
        beyond = any(int(r[f"rank_{q}"]) in (0, su.DRAWS) for q in SHAPE)
        flagged = r["converged"] != "True" or r["multimodal"] == "True" or r.get("misfit") == "True"
        if beyond and not flagged:
            seeds.append(int(r["seed"]))
    return sorted(set(seeds))


def compare_modes(seed: int) -> dict:
    """One data set: the log-posterior (nats) of the truth, its local mode and the fit's polished best draw, the
    fit's diagnostics and the per-group log-likelihood differences (fit mode − truth mode)."""
    import arviz as az

    from bayestouch.inference import contact as cm

    s = su.make_sbc_set(seed)
    log_post, polish = su.posterior_climb(s)
    truth = np.asarray(cm.wrap_angles(su.truth_theta(s)), float)
    truth_mode = polish(truth)
    with tempfile.TemporaryDirectory(prefix="bt-sbc-modes-") as tmp:
        summary = su.sbc_fit(s, Path(tmp), seed)
        idata = az.from_netcdf(Path(tmp) / "posterior.nc")
        post, lp = idata.posterior, np.asarray(idata.sample_stats["lp"].values).ravel()
        i = int(np.argmax(lp))
        nat = {k: float(np.asarray(post[k].values).ravel()[i]) for k in post.data_vars if k != "volume"}
    best = np.array(
        [nat["x_G"], nat["y_G"], nat["z_G"], *np.log([nat["a"], nat["b"], nat["c"]]), nat["xi"], nat["psi"]]
        + [nat["zeta"], np.log(nat["n"]), np.log(nat["sigma"]), nat["w_in"], nat["w_out"]]
    )
    fit_mode = polish(best)
    points, free, sign = s["points"], s["free"], s["outlier_sign"]
    pr = su.sbc_priors()
    kw = {"noise": "outlier", "free": free, "free_miss": pr.free_miss, "outlier_scale": pr.outlier_scale}
    ll_t = cm.pointwise_log_likelihood(truth_mode[None], points, **kw)[0]
    ll_f = cm.pointwise_log_likelihood(fit_mode[None], points, **kw)[0]
    m = len(points)
    groups = {
        "core": np.flatnonzero(sign == 0),
        "inward": np.flatnonzero(sign < 0),
        "outward": np.flatnonzero(sign > 0),
        "free": m + np.arange(len(free)),
    }
    dg = summary["diagnostics"]
    return {
        "seed": seed,
        "truth": log_post(truth),
        "truth_mode": log_post(truth_mode),
        "fit_best_draw": float(lp[i]),
        "fit_mode": log_post(fit_mode),
        "fit_minus_truth_mode": log_post(fit_mode) - log_post(truth_mode),
        "by_group_fit_minus_truth_mode": {k: float(ll_f[v].sum() - ll_t[v].sum()) for k, v in groups.items()},
        "converged": bool(dg["converged"]),
        "multimodal": bool(dg.get("multimodal", False)),
        "noise_ratio": float(s["theta"]["sigma"] / np.min(np.asarray(s["truth"].axes, float))),
    }


def bench_sbc_modes() -> list[dict]:
    """Compare the modes of the chosen sets; write ``results/sbc_modes.json`` and return the harness rows."""
    env = os.environ.get("BAYESTOUCH_SBC_MODE_SEEDS", "").strip()
    seeds = [int(v) for v in env.split(",")] if env else default_seeds()
    sets = []
    for seed in seeds:
        sets.append(compare_modes(seed))
        print(f"[sbc_modes] set {seed}: fit mode − truth mode {sets[-1]['fit_minus_truth_mode']:+.1f} nats", flush=True)
    gaps = np.array([r["fit_minus_truth_mode"] for r in sets])
    summary = {
        "sets": sets,
        "fit_at_least_truth_mode": int(np.sum(gaps >= -1.0)),
        "sampler_missed_better_mode": int(np.sum(gaps < -1.0)),
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sbc_modes.json").write_text(json.dumps(summary, indent=1) + "\n")
    return [
        {
            "metric": "fit's mode at least the truth's (within 1 nat)",
            "value": summary["fit_at_least_truth_mode"],
            "unit": "sets",
            "sets": len(sets),
        },
        {
            "metric": "sampler missed a better mode",
            "value": summary["sampler_missed_better_mode"],
            "unit": "sets",
            "sets": len(sets),
        },
    ]
