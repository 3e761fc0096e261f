"""Exploration through a finger whose bending constants are not the ones its pose estimate assumes (issue "The
finger's own physics moves the pad").

The same experiment twice (:func:`bayestouch.planning.experiment.run_experiment`, ``prober="finger"``: guarded
strokes on the virtual finger over the serial protocol, the encoder's 0.3 mm pose noise): once with the finger's
bending constants equal to ``models/``'s, once with each trial's finger drawn at 1× their stated spread
(``bend_spread``, :func:`bayestouch.planning.experiment.trial_finger`; the pad then runs on lines its bent rod puts
it on and is reported on the commanded ones). The loop's posterior assumes only the encoder's noise. The egg,
the eig planner, :data:`TRIALS` paired trials (the same seeds) of :data:`BUDGET` planned strokes after the scout.

Per condition, after the last stroke: the median Chamfer distance over the mean semi-axis and the median volume
error |V̂/V − 1| with bootstrap 95 % intervals, and how often the truth lies within 1.645 posterior sds of the
estimate (the 90 % interval under a Gaussian reading of the draws' sd; the loop keeps no quantiles), with Wilson
intervals. Outputs ``benchmarks/results/explore_bend.json``.
"""

from __future__ import annotations

import json
import os
import tempfile

import numpy as np

from bayestouch.io.files import write_text
from bayestouch.planning.experiment import run_experiment
from bayestouch.planning.loop import truth_of
from bayestouch.scene.objects import load_object
from benchmarks.bench_user_sets import bootstrap_median, wilson_interval
from benchmarks.harness import RESULTS

#: paired trials per condition, planned strokes per trial, the bending spreads compared
TRIALS = 20
BUDGET = 4
SPREADS = (0.0, 1.0)
#: the 90 % interval's half-width in sds under a Gaussian reading
Z90 = 1.6448536269514722


def bench_explore_bend(trials: int | None = None) -> list[dict]:
    """Run both conditions (``BAYESTOUCH_BEND_TRIALS`` trials each, default :data:`TRIALS`;
    ``BAYESTOUCH_BEND_WORKERS`` processes, default 2) and return the harness rows."""
    n = int(os.environ.get("BAYESTOUCH_BEND_TRIALS", TRIALS)) if trials is None else trials
    workers = int(os.environ.get("BAYESTOUCH_BEND_WORKERS", "2"))
    volume = float(truth_of(load_object("egg")).volume)
    summary: dict = {"object": "egg", "planner": "eig", "trials": n, "budget": BUDGET, "conditions": {}}
    res = []
    for spread in SPREADS:
        with tempfile.TemporaryDirectory() as tmp:
            out = run_experiment(
                tmp,
                planners=("eig",),
                objects=("egg",),
                trials=n,
                budget=BUDGET,
                seed=0,
                workers=workers,
                prober="finger",
                bend_spread=spread,
                plot=False,
                log=lambda m, s=spread: print(f"[explore_bend {s:g}] {m}", flush=True),
            )
        last = [r for r in out["rows"] if int(r["stroke"]) == BUDGET]
        chamfer = [float(r["chamfer"]) for r in last]
        verr = [float(r["volume_error"]) for r in last]
        z = [float(r["volume_error"]) * volume / float(r["volume_sd"]) for r in last]
        covered = int(sum(abs(v) <= Z90 for v in z))
        cond = {
            "chamfer": dict(zip(("median", "lo", "hi"), bootstrap_median(chamfer), strict=True)),
            "volume_error": dict(zip(("median", "lo", "hi"), bootstrap_median(verr), strict=True)),
            "volume_z_median": float(np.median(z)),
            "covered": covered,
            "of": len(last),
            "coverage_wilson95": list(wilson_interval(covered, len(last))),
            "per_trial": [
                {"trial": int(r["trial"]), "chamfer": c, "volume_error": v, "volume_z": zz}
                for r, c, v, zz in zip(last, chamfer, verr, z, strict=True)
            ],
        }
        summary["conditions"][f"{spread:g}"] = cond
        label = "the models' bending constants" if spread == 0 else f"bending constants drawn at {spread:g}x spread"
        res += [
            {
                "metric": f"Chamfer / mean semi-axis after {BUDGET} strokes, median ({label})",
                "value": cond["chamfer"]["median"],
                "unit": "1",
                "ci95": [cond["chamfer"]["lo"], cond["chamfer"]["hi"]],
                "trials": len(last),
            },
            {
                "metric": f"volume error after {BUDGET} strokes, median ({label})",
                "value": cond["volume_error"]["median"],
                "unit": "1",
                "ci95": [cond["volume_error"]["lo"], cond["volume_error"]["hi"]],
                "trials": len(last),
            },
            {
                "metric": f"truth within the 90 % volume interval (Gaussian reading; {label})",
                "value": covered / len(last),
                "unit": "fraction",
                "wilson95": cond["coverage_wilson95"],
                "median_abs_z": float(np.median(np.abs(z))),
                "trials": len(last),
            },
        ]
    write_text(RESULTS / "explore_bend.json", json.dumps(summary, indent=2) + "\n")
    return res
