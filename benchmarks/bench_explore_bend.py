"""Exploration through a finger whose bending constants are not the ones its pose estimate assumes (issue "The
finger's own physics moves the pad").

The same experiment in the :data:`CONDITIONS` (:func:`bayestouch.planning.experiment.run_experiment`,
``prober="finger"``: guarded strokes on the virtual finger over the serial protocol, the encoder's 0.3 mm pose
noise): the finger's bending constants equal to ``models/``'s, or each trial's finger drawn at 1× or 1.5× their
stated spread (``bend_spread``, :func:`bayestouch.planning.experiment.trial_finger`; the pad then runs on lines its
bent rod puts it on and is reported on the commanded ones); the loop's posterior either assumes only the encoder's
noise or marginalises the pose error's law (``pose_draws`` = :data:`POSE_DRAWS` fingers drawn at the stated spread,
:meth:`bayestouch.planning.device_prober.DeviceProber.pose_ensemble`), before or after a bending calibration of
the trial's finger on a 2-cm sphere (``bend_calibration``: six guarded strokes,
:func:`bayestouch.planning.device_prober.calibrate_bending`). The 1.5× finger lies outside the family the host's law
assumes, calibrated or not. The egg, the eig planner, :data:`TRIALS` paired trials (the same seeds) of :data:`BUDGET`
planned strokes after the scout.

Per condition, after the last stroke: the median Chamfer distance over the mean semi-axis and the median volume
error |V̂/V − 1| with bootstrap 95 % intervals, how often the truth lies within 1.645 posterior sds of the
estimate (the 90 % interval under a Gaussian reading of the draws' sd; the loop keeps no quantiles), with Wilson
intervals, and the volume's posterior sd over that of the same trial with the models' constants and no law (the
pose known to the encoder's noise), median with a bootstrap interval. Outputs
``benchmarks/results/explore_bend.json``.
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

#: paired trials per condition, planned strokes per trial
TRIALS = 20
BUDGET = 4
#: drawn fingers of the host's pose-error law
POSE_DRAWS = 24
#: (bending spread of the trials' fingers, the loop's pose_draws, a bending calibration first): the first is the
#: reference
CONDITIONS = (
    (0.0, 0, False),
    (1.0, 0, False),
    (1.0, POSE_DRAWS, False),
    (1.0, POSE_DRAWS, True),
    (1.5, POSE_DRAWS, False),
    (1.5, POSE_DRAWS, True),
    (0.0, POSE_DRAWS, False),
)
#: the 90 % interval's half-width in sds under a Gaussian reading
Z90 = 1.6448536269514722


def bench_explore_bend(trials: int | None = None) -> list[dict]:
    """Run both conditions (``BAYESTOUCH_BEND_TRIALS`` trials each, default :data:`TRIALS`;
    ``BAYESTOUCH_BEND_WORKERS`` processes, default 2) and return the harness rows."""
    n = int(os.environ.get("BAYESTOUCH_BEND_TRIALS", TRIALS)) if trials is None else trials
    workers = int(os.environ.get("BAYESTOUCH_BEND_WORKERS", "2"))
    volume = float(truth_of(load_object("egg")).volume)
    summary: dict = {
        "object": "egg",
        "planner": "eig",
        "trials": n,
        "budget": BUDGET,
        "pose_draws": POSE_DRAWS,
        "conditions": {},
    }
    res = []
    reference_sd = None
    for spread, draws, calibrated in CONDITIONS:
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
                settings={"pose_draws": draws} if draws else None,
                bend_calibration=calibrated,
                plot=False,
                log=lambda m, s=spread, d=draws, c=calibrated: print(f"[explore_bend {s:g} {d} {c}] {m}", flush=True),
            )
        last = sorted((r for r in out["rows"] if int(r["stroke"]) == BUDGET), key=lambda r: int(r["trial"]))
        chamfer = [float(r["chamfer"]) for r in last]
        vsd = np.array([float(r["volume_sd"]) for r in last])
        if reference_sd is None:
            reference_sd = vsd
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
            "volume_sd_over_reference": dict(
                zip(("median", "lo", "hi"), bootstrap_median(list(vsd / reference_sd)), strict=True)
            ),
            "bend_spread": spread,
            "pose_draws": draws,
            "bend_calibration": calibrated,
            "per_trial": [
                {"trial": int(r["trial"]), "chamfer": c, "volume_error": v, "volume_z": zz, "volume_sd": sd}
                for r, c, v, zz, sd in zip(last, chamfer, verr, z, vsd.tolist(), strict=True)
            ],
        }
        summary["conditions"][f"{spread:g}" + ("+law" if draws else "") + ("+calibrated" if calibrated else "")] = cond
        label = "the models' bending constants" if spread == 0 else f"bending constants drawn at {spread:g}x spread"
        label += f"; pose-error law of {draws} drawn fingers" if draws else "; encoder noise only"
        label += ", calibrated on a sphere first" if calibrated else ""
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
        if spread or draws:
            res.append(
                {
                    "metric": f"volume posterior sd over the reference's, median ({label})",
                    "value": cond["volume_sd_over_reference"]["median"],
                    "unit": "1",
                    "ci95": [cond["volume_sd_over_reference"]["lo"], cond["volume_sd_over_reference"]["hi"]],
                    "trials": len(last),
                }
            )
    write_text(RESULTS / "explore_bend.json", json.dumps(summary, indent=2) + "\n")
    return res
