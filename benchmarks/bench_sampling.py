"""Sampling efficiency of the contact-level posterior (issue 4's targets): effective samples per second of emcee
(the project's engine and settings) against numpyro's NUTS on the same log-density and data, and the time to a
converged contact-level posterior for 1000 points (target < 10 s), with its diagnostics."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from bayestouch.inference.contact import make_log_prob
from bayestouch.inference.sbc import simulate_points

# a tilted, unequal-axes n-ellipsoid (centre m, log axes, Euler angles rad, log n, log σ) and 1000 points
THETA = np.array([0.0, 0.0, 0.0, np.log(0.03), np.log(0.022), np.log(0.015), 0.4, 0.3, -0.5, np.log(2.2), np.log(3e-4)])
N_POINTS = 1000


def _points():
    return simulate_points(THETA, N_POINTS, np.random.default_rng(0))


def _min_ess(chain) -> float:
    """Smallest ESS over parameters: draws / integrated autocorrelation time (chain (S, W, D))."""
    from emcee.autocorr import integrated_time

    return float(np.min(chain.shape[0] * chain.shape[1] / integrated_time(chain, tol=0)))


def bench_emcee_vs_nuts():
    from bayestouch.inference.nuts import nuts_contact
    from bayestouch.inference.run import start_ball
    from bayestouch.inference.sampler import sample

    pts = _points()
    logp, bounds = make_log_prob(pts)
    logp(THETA[None])  # compile outside the timing
    walkers, steps = 32, 4000  # run_contact_fit's defaults
    with tempfile.TemporaryDirectory() as tmp:
        ch = sample(
            logp,
            start_ball(THETA, bounds, walkers, np.random.default_rng(0)),
            Path(tmp) / "c.h5",
            walkers=walkers,
            ndim=11,
            seed=0,
            steps=steps,
            progress=False,
        )
    ess_e = _min_ess(ch.kept)
    logp(THETA[None].repeat(walkers // 2, axis=0))  # the half-ensemble batch, compiled outside the timing
    with tempfile.TemporaryDirectory() as tmp:
        ad = sample(
            logp,
            start_ball(THETA, bounds, walkers, np.random.default_rng(0)),
            Path(tmp) / "a.h5",
            walkers=walkers,
            ndim=11,
            seed=0,
            steps=1000,
            progress=False,
            adapt=True,
        )
    ess_a = _min_ess(ad.kept)
    t = time.perf_counter()
    out = nuts_contact(pts, seed=0, num_warmup=500, num_samples=1000, init=THETA)
    t_nuts = time.perf_counter() - t
    ess_n = _min_ess(np.swapaxes(out["theta"], 0, 1))
    common = {
        "points": N_POINTS,
        "start": "truth (both samplers)",
        "ess_method": "min over the 11 parameters, draws / integrated autocorrelation time",
    }
    return [
        {
            "metric": "emcee min ESS/s",
            "value": ess_e / ch.seconds,
            "unit": "1/s",
            "walkers": walkers,
            "steps": steps,
            "burn": ch.burn,
            "ess": round(ess_e),
            "seconds": round(ch.seconds, 1),
            "moves": "default_moves (DE + snooker)",
            "backend": "HDF5 checkpoint, written in batches at most every second",
            **common,
        },
        {
            "metric": "NUTS min ESS/s",
            "value": ess_n / t_nuts,
            "unit": "1/s",
            "warmup": 500,
            "samples": 1000,
            "ess": round(ess_n),
            "seconds": round(t_nuts, 1),
            "divergences": int(out["diverging"].sum()),
            "timing": "includes JIT compilation",
            **common,
        },
        {
            "metric": "emcee min ESS/s, adaptive moves (run_contact_fit's sampler)",
            "value": ess_a / ad.seconds,
            "unit": "1/s",
            "walkers": walkers,
            "steps": 1000,
            "burn": ad.burn,
            "ess": round(ess_a),
            "seconds": round(ad.seconds, 1),
            "autocorr_time_max": round(ad.tau_max, 1),
            "moves": "adaptive_moves (t independence proposal refitted at steps 100, 200, 400, 800 + DE + snooker)",
            **common,
        },
        {
            "metric": "emcee / NUTS ESS/s, adaptive moves",
            "value": (ess_a / ad.seconds) / (ess_n / t_nuts),
            "unit": "1",
            "target": 1,
        },
        {"metric": "emcee / NUTS ESS/s", "value": (ess_e / ch.seconds) / (ess_n / t_nuts), "unit": "1", "target": 1},
    ]


def _cli_fit(csv: Path, out: Path, cache: str) -> tuple[dict, float]:
    """``bayestouch fit`` in a fresh process with the JAX compilation cache at ``cache`` ("0": none): the summary's
    diagnostics and the process's wall time (interpreter start and imports included)."""
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "BAYESTOUCH_JAX_CACHE": cache, "OMP_NUM_THREADS": "1"}
    t = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "bayestouch.cli", "fit", str(csv), "--out", str(out), "--seed", "0", "--quiet"],
        check=True,
        env=env,
        capture_output=True,
    )
    wall = time.perf_counter() - t
    return json.loads((out / "summary.json").read_text())["diagnostics"], wall


def bench_time_to_converged():
    """Seconds from the call to a converged contact-level posterior of 1000 points with every output written
    (``diagnostics.seconds`` of ``run_contact_fit``: initial fit, adaptive emcee to convergence with the HDF5
    checkpoint, summary, ArviZ netCDF, meshes), in three situations: a process that has fitted before (compiled
    programs in memory), a fresh ``bayestouch fit`` process whose JAX compilation cache on disk is warm (the usual
    case from the second run on), and a fresh process without that cache (a first run ever: ~100 programs
    compiled)."""
    from bayestouch.inference.run import run_contact_fit
    from bayestouch.io.files import save_contact_points

    pts = _points()
    rows = []

    def row(label, d, wall=None):
        r = {
            "metric": f"seconds to a converged contact-level posterior, {label}",
            "value": d["seconds"],
            "unit": "s",
            "points": N_POINTS,
            "target": 10,
            "converged": d["converged"],
            "max_r_hat": round(d["max_r_hat"], 4),
            "min_ess_bulk": round(d["min_ess_bulk"]),
            "steps": d["steps"],
            "autocorr_time_max": round(d["autocorr_time_max"], 1),
            "includes": "initial fit, adaptive emcee with HDF5, summary, netCDF, meshes",
        }
        if wall is not None:
            r["process_wall_s"] = round(wall, 2)
        return r

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        run_contact_fit(pts, tmp / "first", seed=1, progress=False)  # compiles
        rows.append(
            row(
                "process that has fitted before",
                run_contact_fit(pts, tmp / "warm", seed=0, progress=False)["diagnostics"],
            )
        )
        csv = tmp / "points.csv"
        save_contact_points(csv, pts)
        cache = tmp / "jax-cache"
        _cli_fit(csv, tmp / "fill", str(cache))  # fills the compilation cache
        rows.append(row("fresh CLI process, compilation cache warm", *_cli_fit(csv, tmp / "cached", str(cache))))
        rows.append(row("fresh CLI process, no compilation cache", *_cli_fit(csv, tmp / "cold", "0")))
    return rows
