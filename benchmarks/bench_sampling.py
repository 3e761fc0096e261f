"""Time to a converged contact-level posterior for 1000 points (target < 10 s), with its diagnostics. (The sampler
comparison with NUTS is :mod:`benchmarks.bench_samplers`: compiled contestants, several chains, one ESS estimator.)"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from bayestouch.inference.sbc import simulate_points
from benchmarks.harness import cli_fit

# a tilted, unequal-axes n-ellipsoid (centre m, log axes, Euler angles rad, log n, log σ) and 1000 points
THETA = np.array([0.0, 0.0, 0.0, np.log(0.03), np.log(0.022), np.log(0.015), 0.4, 0.3, -0.5, np.log(2.2), np.log(3e-4)])
N_POINTS = 1000


def _points():
    return simulate_points(THETA, N_POINTS, np.random.default_rng(0))


def _cli_fit(csv: Path, out: Path, cache: str) -> tuple[dict, float]:
    """:func:`benchmarks.harness.cli_fit` with seed 0: the summary's diagnostics and the process's wall time; a
    failed process raises."""
    summary, wall, rc, err = cli_fit(csv, out, 0, cache)
    if summary is None:
        raise RuntimeError(f"bayestouch fit exited with {rc}: {err}")
    return summary["diagnostics"], wall


def bench_time_to_converged():
    """Seconds from the call to a converged contact-level posterior of 1000 points with every output written
    (``diagnostics.seconds`` of ``run_contact_fit``: initial fit, adaptive emcee to convergence with the HDF5
    checkpoint, summary, ArviZ netCDF, meshes), in three situations: a process that has fitted before (compiled
    programs in memory), a fresh ``bayestouch fit`` process whose JAX compilation cache on disk is warm (the usual
    case from the second run on), and a fresh process without that cache (a first run ever: ~100 programs
    compiled)."""
    from bayestouch.inference.run import run_contact_fit
    from bayestouch.io.contacts import save_contact_points

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
