"""Time to a converged posterior from a fresh command line on users'-like touch data (issue "Shape posteriors that
hold up on real touch data", target: median ≤ 20 s, 95th percentile ≤ 60 s on the 2-core machine).

``bench_user_sets`` fits its sets in-process on two workers at once, so its seconds are those of a shared machine
and of processes that compiled before. This benchmark measures what the target names: each of the same sets
(:func:`benchmarks.bench_user_sets.make_user_sets`, seed 0) written to a contact CSV (its free-space positions as
``contact = 0`` rows) and fitted by ``bayestouch fit CSV --out DIR --seed SEED --quiet`` in a fresh process, one
at a time, the wall time of the whole process taken (interpreter start, imports, the fit, every output written).
The processes share one JAX compilation cache on disk (``BAYESTOUCH_JAX_CACHE``), empty at the start, as on a
user's machine; the first fit therefore compiles and is reported apart as well as in the medians.

Outputs ``benchmarks/results/user_cli.json`` and ``user_cli.csv`` (one row per set: wall and fit seconds,
converged, steps, and the volume interval's verdict against the truth, :func:`~benchmarks.bench_user_sets.
bayestouch_metrics`).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from bayestouch.io.contacts import save_contact_points
from bayestouch.io.files import write_csv_rows, write_text
from benchmarks.bench_user_sets import bayestouch_metrics, bootstrap_median, make_user_sets, wilson_interval
from benchmarks.harness import RESULTS, cli_fit

#: sets fitted (the first SETS of bench_user_sets' seed-0 sets)
SETS = 50
#: the targets: median and 95th percentile of the process's wall time (seconds)
TARGET_MEDIAN_S = 20.0
TARGET_P95_S = 60.0


def bench_user_cli(count: int | None = None):
    """Fresh-process ``bayestouch fit`` on bench_user_sets' sets, one after another (module docstring).

    ``count`` defaults to :data:`SETS` (``BAYESTOUCH_USER_CLI_SETS`` overrides it for a quick look)."""
    count = int(os.environ.get("BAYESTOUCH_USER_CLI_SETS", SETS)) if count is None else int(count)
    sets = make_user_sets(count, seed=0)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bt-user-cli-") as tmp:
        tmp = Path(tmp)
        cache = tmp / "jax-cache"
        for i, d in enumerate(sets):
            csv = save_contact_points(tmp / f"set{i}.csv", d.points, free=d.free_space)
            summary, wall, rc, err = cli_fit(csv, tmp / f"fit{i}", d.seed, cache)
            row = {
                "set": i,
                "seed": d.seed,
                "points": len(d.points),
                "free": len(d.free_space),
                "wall_s": wall,
                "exit_code": rc,
                "fit_s": float("nan"),
                "converged": False,
                "steps": 0,
                "volume_covered": False,
                "error": "",
            }
            if summary is None:
                row["error"] = err.strip().splitlines()[-1] if err.strip() else f"exit {rc}"
            else:
                g = summary["diagnostics"]
                row.update(
                    fit_s=g["seconds"],
                    converged=bool(g["converged"]),
                    steps=g["steps"],
                    volume_covered=bayestouch_metrics(summary, d.truth)["volume_covered"],
                )
            rows.append(row)
            print(f"user_cli: set {i}: {wall:.1f} s, exit {rc}, converged {row.get('converged')}", file=sys.stderr)
    ok = [r for r in rows if r["exit_code"] == 0]
    wall = np.array([r["wall_s"] for r in ok])
    med, lo, hi = bootstrap_median(wall, seed=0)
    later = wall[1:] if len(wall) > 1 else wall
    conv = [r for r in ok if r["converged"]]
    covered = sum(bool(r["volume_covered"]) for r in ok)
    result = {
        "sets": len(rows),
        "failed": len(rows) - len(ok),
        "wall_s": {
            "median": med,
            "ci95": [lo, hi],
            "p95": float(np.percentile(wall, 95)),
            "first": float(wall[0]),
            "median_after_first": float(np.median(later)),
        },
        "fit_s_median": float(np.median([r["fit_s"] for r in ok])),
        "converged": len(conv),
        "converged_wall_s_median": float(np.median([r["wall_s"] for r in conv])) if conv else float("nan"),
        "volume_covered": covered,
        "volume_coverage_wilson95": list(wilson_interval(covered, len(ok))),
        "targets": {"median_s": TARGET_MEDIAN_S, "p95_s": TARGET_P95_S},
    }
    write_csv_rows(RESULTS / "user_cli.csv", rows)
    write_text(RESULTS / "user_cli.json", json.dumps(result, indent=1) + "\n")
    return [
        {
            "metric": "bayestouch fit from a fresh process, users'-like sets, wall time median",
            "value": med,
            "unit": "s",
            "ci95": [lo, hi],
            "target": TARGET_MEDIAN_S,
        },
        {
            "metric": "bayestouch fit from a fresh process, users'-like sets, wall time 95th percentile",
            "value": result["wall_s"]["p95"],
            "unit": "s",
            "target": TARGET_P95_S,
        },
        {
            "metric": "bayestouch fit from a fresh process, users'-like sets, converged",
            "value": len(conv),
            "unit": f"of {len(ok)}",
        },
    ]
