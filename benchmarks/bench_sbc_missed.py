"""Where the users'-conditions SBC finds the truth beyond every posterior draw: did the sampler miss a better mode,
or does the posterior itself exclude the truth?

:mod:`benchmarks.bench_sbc_users` counts the data sets whose truth lies outside all of its posterior draws in a
shape quantity (a semi-axis or the volume). Such a set is one of two failures: the fit's posterior, sampled
correctly, puts the truth in its far tail (a model or prior problem, or chance), or the sampler settled in a mode
whose log-posterior is far below the truth's own (a search problem: the fit's answer is not its model's). This
audit tells them apart on the sets where the likelihood is trustworthy — σ below :data:`NOISE_RATIO_MAX` of the
smallest semi-axis, where :func:`~benchmarks.bench_sbc_users.local_mode_gap` accepts the truth — by fitting each
again exactly as the SBC did (same data, seed, size prior and 60-s budget) and comparing on the sampled
log-posterior:

* the truth's local mode (L-BFGS-B from the truth, :func:`~benchmarks.bench_sbc_users.posterior_climb`), and
* the best of the fit's draws, climbed the same way (the top of the mode the sampler holds).

A gap above :data:`MISSED_NATS` (the fit's own threshold for a missed mode,
:data:`bayestouch.inference.run.MISSED_MODE_NATS`) means the sampler missed a mode e^gap times denser than the one
it reports. Each set's verdict, the fit's flags (converged, multimodal, misfit) and its warnings are written to
``benchmarks/results/sbc_missed.csv`` and counted in ``sbc_missed.json``.
"""

from __future__ import annotations

import csv
import json
import multiprocessing as mp
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks.bench_sbc_users import (
    DRAWS,
    RESULTS,
    make_sbc_set,
    posterior_climb,
    sbc_fit,
    truth_theta,
)
from benchmarks.bench_user_sets import wilson_interval
from benchmarks.harness import worker_init

__all__ = ["NOISE_RATIO_MAX", "MISSED_NATS", "audited_seeds", "audit_set", "bench_sbc_missed"]

#: sets audited: σ / smallest true semi-axis below this (the first-order likelihood holds, docs/sbc.md)
NOISE_RATIO_MAX = 0.01
#: a truth's local mode this many nats above the climbed best draw is a mode the sampler missed
MISSED_NATS = 5.0
#: posterior draws the best is taken among (evenly spaced over the chain)
DRAWS_SCANNED = 400
#: the sampled parameters, as posterior.nc names them (natural units)
NAMES = ("x_G", "y_G", "z_G", "a", "b", "c", "xi", "psi", "zeta", "n", "sigma", "w_in", "w_out")


def audited_seeds(rows: list[dict]) -> list[int]:
    """Seeds of the SBC rows (``sbc_users.csv`` as dicts of strings) whose truth lies beyond every draw in a
    semi-axis or the volume (as :func:`~benchmarks.bench_sbc_users.summarise` counts them) and whose noise ratio
    is below :data:`NOISE_RATIO_MAX`."""
    shape = ("a_1", "a_2", "a_3", "volume")
    return sorted(
        int(r["seed"])
        for r in rows
        if float(r["noise_ratio"]) < NOISE_RATIO_MAX and any(int(r[f"rank_{q}"]) in (0, DRAWS) for q in shape)
    )


def _sampled(post) -> np.ndarray:
    """posterior.nc's posterior group as θ rows (N, 13) in the sampled parametrisation (log axes, n, σ)."""
    x = np.stack([post[k].values.ravel() for k in NAMES], axis=1)
    x[:, 3:6] = np.log(x[:, 3:6])
    x[:, 9:11] = np.log(x[:, 9:11])
    return x


def audit_set(seed: int) -> dict:
    """Fit SBC data set ``seed`` as :func:`~benchmarks.bench_sbc_users.fit_sbc_set` does and compare the truth's
    local mode with the climbed best draw (module docstring): one CSV row."""
    import arviz as az

    from bayestouch.inference import contact as cm

    s = make_sbc_set(seed)
    log_post, climb = posterior_climb(s)
    truth = np.asarray(cm.wrap_angles(truth_theta(s)), float)
    local = climb(truth)
    with tempfile.TemporaryDirectory(prefix="bt-sbc-audit-") as tmp:
        summary = sbc_fit(s, Path(tmp), seed)
        x = _sampled(az.from_netcdf(Path(tmp) / "posterior.nc").posterior)
    x = x[np.linspace(0, len(x) - 1, min(DRAWS_SCANNED, len(x))).astype(int)]
    lp = np.array([log_post(t) for t in x])
    best = climb(x[int(np.nanargmax(lp))])
    dg = summary["diagnostics"]
    gap = float(log_post(local) - log_post(best))
    return {
        "seed": seed,
        "points": len(s["points"]),
        "outliers": int(np.sum(s["outlier_sign"] != 0)),
        "noise_ratio": float(s["theta"]["sigma"] / np.min(np.asarray(s["truth"].axes, float))),
        "log_post_truth": float(log_post(truth)),
        "log_post_truth_local": float(log_post(local)),
        "log_post_best_draw": float(np.nanmax(lp)),
        "log_post_best_climbed": float(log_post(best)),
        "gap_nats": gap,
        "missed": gap > MISSED_NATS,
        "converged": bool(dg["converged"]),
        "multimodal": bool(dg.get("multimodal", False)),
        "misfit": bool(dg.get("misfit", False)),
        "warnings": len(dg.get("warnings", [])),
        "sigma_fit_over_true": float(np.exp(best[10]) / s["theta"]["sigma"]),
    }


def bench_sbc_missed() -> list[dict]:
    """Audit the SBC's truth-beyond-every-draw sets (module docstring) on two processes; the harness rows."""
    with open(RESULTS / "sbc_users.csv", newline="") as fh:
        seeds = audited_seeds(list(csv.DictReader(fh)))
    t0 = time.perf_counter()
    with ProcessPoolExecutor(2, mp_context=mp.get_context("spawn"), initializer=worker_init) as pool:
        rows = sorted(pool.map(audit_set, seeds), key=lambda r: r["seed"])
    with open(RESULTS / "sbc_missed.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    missed = [r for r in rows if r["missed"]]
    silent = [r for r in missed if r["converged"] and not r["multimodal"] and not r["misfit"] and not r["warnings"]]
    said = [r for r in missed if not r["converged"] or r["multimodal"] or r["misfit"]]
    lo, hi = wilson_interval(len(missed), len(rows))
    gaps = [r["gap_nats"] for r in missed]
    summary = {
        "noise_ratio_max": NOISE_RATIO_MAX,
        "missed_nats": MISSED_NATS,
        "sets": len(rows),
        "missed": len(missed),
        "missed_wilson95": [lo, hi],
        "missed_gap_nats_median": float(np.median(gaps)) if gaps else None,
        "missed_flagged": len(said),
        "missed_without_any_warning": len(silent),
        "seconds": time.perf_counter() - t0,
    }
    (RESULTS / "sbc_missed.json").write_text(json.dumps(summary, indent=1) + "\n")
    return [
        {
            "metric": "SBC sets audited (truth beyond every draw, noise ratio < 0.01)",
            "value": len(rows),
            "unit": "sets",
        },
        {
            "metric": "of them, a mode the sampler missed (truth's local mode > 5 nats above every draw)",
            "value": len(missed),
            "unit": "sets",
            "wilson95": [lo, hi],
            "gap_median_nats": summary["missed_gap_nats_median"],
        },
        {"metric": "missed modes flagged (not converged, multimodal or misfit)", "value": len(said), "unit": "sets"},
        {"metric": "missed modes with no warning at all", "value": len(silent), "unit": "sets"},
    ]
