"""Planners through the virtual finger: strokes needed to reach a Chamfer distance of 0.02 of the mean semi-axis.

``bench_planners_finger``: ``run_experiment(prober="finger")`` (every stroke a guarded stroke on a virtual finger
over the serial protocol, the pad's pose error 0.3 mm per coordinate) on the egg and the box, planners eig, random
and gpis, ``BAYESTOUCH_PLANNERS_TRIALS`` paired trials per object (default 20: the planners of a trial share its
scout, seed and initial fit), ``BAYESTOUCH_PLANNERS_BUDGET`` planned strokes (default 8), default loop settings, 2
worker processes.

For each trial, planner and target of :data:`TARGETS`: the first stroke after which the Chamfer distance (point
estimate against the true surface, over the true mean semi-axis) is ≤ the target; a trial that never gets there
within the budget counts as budget + 1 (censored, so medians are lower bounds on the true need where many are
censored; the count is reported). Reported: the median strokes per planner with a bootstrap 95 % interval over
trials (resampling whole paired trials), the paired ratios eig/random and eig/gpis of the per-object means, the
median decision time (plan) per stroke, and the Chamfer distance after the last stroke. The rows are written to
``benchmarks/results/planners_finger.csv``; :func:`summarise` turns them into the results again.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks bench_planners``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: Chamfer distances over the true mean semi-axis that count as "shape found": the issue's 0.02, and 0.005 (the
#: standard objects reach 0.02 within the scout and the first stroke, whatever the planner)
TARGETS = (0.02, 0.005)
PLANNERS = ("eig", "random", "gpis")
OBJECTS = ("egg", "box")


def strokes_to_target(rows, budget: int, target: float) -> dict:
    """``{(object, planner, trial): strokes}`` — the first stroke (1 = the first planned one, 0 = the scout) whose
    Chamfer distance is ≤ ``target``; ``budget + 1`` when none is."""
    out: dict = {}
    for r in rows:
        key = (r["object"], r["planner"], int(r["trial"]))
        out.setdefault(key, budget + 1)
        if float(r["chamfer"]) <= target:
            out[key] = min(out[key], int(r["stroke"]))
    return out


def _bootstrap_median(values: np.ndarray, rng, n: int = 4000) -> list[float]:
    idx = rng.integers(len(values), size=(n, len(values)))
    med = np.median(values[idx], axis=1)
    return [float(np.quantile(med, 0.025)), float(np.quantile(med, 0.975))]


def bench_planners_finger() -> list[dict]:
    from bayestouch.io.files import read_csv_rows
    from bayestouch.planning.experiment import run_experiment

    trials = int(os.environ.get("BAYESTOUCH_PLANNERS_TRIALS", "20"))
    budget = int(os.environ.get("BAYESTOUCH_PLANNERS_BUDGET", "8"))
    with tempfile.TemporaryDirectory() as tmp:
        run_experiment(
            tmp,
            planners=PLANNERS,
            objects=OBJECTS,
            trials=trials,
            budget=budget,
            seed=0,
            workers=2,
            prober="finger",
            plot=False,
            log=lambda m: print(m, flush=True),
        )
        rows = read_csv_rows(Path(tmp) / "results.csv")
        shutil.copy(Path(tmp) / "results.csv", HERE / "results" / "planners_finger.csv")
    return summarise(rows, trials, budget)


def summarise(rows, trials: int, budget: int) -> list[dict]:
    """The benchmark's result rows from an experiment's ``results.csv`` rows (module docstring)."""
    rng = np.random.default_rng(0)
    out = []
    for target in TARGETS:
        need = strokes_to_target(rows, budget, target)
        for obj in OBJECTS:
            per = {p: np.array([need[(obj, p, t)] for t in range(trials) if (obj, p, t) in need]) for p in PLANNERS}
            for p in PLANNERS:
                v = per[p]
                out.append(
                    {
                        "metric": f"strokes to Chamfer <= {target} ({obj}, {p})",
                        "value": float(np.median(v)),
                        "unit": "strokes",
                        "ci95": _bootstrap_median(v.astype(float), rng),
                        "mean": float(v.mean()),
                        "censored": int(np.sum(v > budget)),
                        "trials": int(len(v)),
                        "budget": budget,
                        "prober": "finger",
                    }
                )
            for other in ("random", "gpis"):
                a, b = per["eig"].astype(float), per[other].astype(float)
                idx = rng.integers(len(a), size=(4000, len(a)))
                ratios = a[idx].mean(axis=1) / np.maximum(b[idx].mean(axis=1), 1e-9)
                out.append(
                    {
                        "metric": f"eig / {other} mean strokes to Chamfer <= {target} ({obj})",
                        "value": float(a.mean() / max(b.mean(), 1e-9)),
                        "unit": "1",
                        "ci95": [float(np.quantile(ratios, 0.025)), float(np.quantile(ratios, 0.975))],
                        "trials": int(len(a)),
                        "paired": True,
                    }
                )
    for obj in OBJECTS:
        for p in PLANNERS:
            mine = [r for r in rows if r["object"] == obj and r["planner"] == p]
            last = np.array([float(r["chamfer"]) for r in mine if int(r["stroke"]) == budget])
            if len(last):
                out.append(
                    {
                        "metric": f"Chamfer after {budget} strokes, median ({obj}, {p})",
                        "value": float(np.median(last)),
                        "unit": "1",
                        "ci95": _bootstrap_median(last, rng),
                        "trials": int(len(last)),
                    }
                )
    for p in PLANNERS:
        d = [float(r["decision_s"]) for r in rows if r["planner"] == p and int(r["stroke"]) > 0]
        out.append({"metric": f"decision time per stroke, median ({p})", "value": float(np.median(d)), "unit": "s"})
    planned = sum(int(r["stroke"]) > 0 for r in rows)
    out.append({"metric": "planned strokes run", "value": float(planned), "unit": "strokes"})
    return out
