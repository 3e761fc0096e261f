"""Exploration with carrier strokes against guarded ones on a finger whose bending constants are its own (issue "The
finger's own physics moves the pad", item 2).

Each trial draws a virtual finger at :data:`BEND_SPREAD` × its constants' stated spread
(:func:`bayestouch.planning.experiment.trial_finger`), calibrates it on the 2-cm sphere
(:func:`~bayestouch.planning.device_prober.calibrate_bending`) and explores the egg with the eig planner,
:data:`BUDGET` strokes after the scout, in two arms on the same finger and seeds:

- **guarded**: guarded strokes, the calibrated law of :data:`POSE_DRAWS` fingers marginalised in every update;
- **carrier**: carrier strokes from the inverse of the bending chain, corrected by the calibrated law's mean
  (:meth:`~bayestouch.planning.device_prober.DeviceProber.carrier_plan`), the contacts from the pad's sensed pose.

Per arm, after the last stroke: the median Chamfer distance over the mean semi-axis and volume error with bootstrap
intervals; how often the truth lies within 1.645 posterior sds of the volume (the loop keeps no quantiles), with
Wilson intervals; the contacts' median distance from the true surface; contacts per trial; and for carrier strokes
how many the device stopped at its 1 N limit. Outputs ``benchmarks/results/explore_carrier.json``.
"""

from __future__ import annotations

import json
import os

import numpy as np

from bayestouch.io.files import write_text
from bayestouch.planning.device_prober import VirtualFingerProber, calibrate_bending
from bayestouch.planning.experiment import calibration_object, trial_finger
from bayestouch.planning.loop import ExploreSettings, explore, truth_of
from bayestouch.scene.objects import load_object
from bayestouch.scene.surface import signed_distance
from benchmarks.bench_user_sets import bootstrap_median, wilson_interval
from benchmarks.harness import RESULTS, pool_rows

TRIALS = 16
BUDGET = 4
POSE_DRAWS = 24
BEND_SPREAD = 1.0
ARMS = ("guarded", "carrier")
Z90 = 1.6448536269514722


def trial(k: int) -> list[dict]:
    """Trial ``k``: one drawn, calibrated finger, both arms."""
    seed = 2000 + k
    egg = load_object("egg")
    volume = float(truth_of(egg).volume)
    finger = trial_finger(seed, BEND_SPREAD)
    sphere = calibration_object()
    with VirtualFingerProber(sphere, seed=seed, finger=finger) as cal:
        law = calibrate_bending(cal, sphere, seed=seed).law
    rows = []
    for arm in ARMS:
        carrier = arm == "carrier"
        settings = ExploreSettings(pose_draws=0 if carrier else POSE_DRAWS)
        with VirtualFingerProber(egg, seed=seed, finger=finger, pose_law=law, carrier=carrier) as prober:
            res = explore(egg, "eig", BUDGET, seed=seed, settings=settings, prober=prober)
            aborted, carriers = prober.aborted, len(prober.carriers)
        last = res.records[-1]
        d = np.abs(np.asarray(signed_distance(egg.surface(), res.points)))
        rows.append(
            {
                "trial": k,
                "arm": arm,
                "chamfer": last.chamfer,
                "volume_error": last.volume_error,
                "volume_z": (last.volume_mean - volume) / last.volume_sd,
                "points": len(res.points),
                "contact_distance_median_m": float(np.median(d)),
                "aborted": aborted,
                "carrier_strokes": carriers,
            }
        )
    print(
        f"[explore_carrier] trial {k}: "
        + ", ".join(f"{r['arm']} chamfer {r['chamfer']:.4f} z {r['volume_z']:+.1f}" for r in rows),
        flush=True,
    )
    return rows


def bench_explore_carrier(trials: int | None = None) -> list[dict]:
    """Run :data:`TRIALS` trials (``BAYESTOUCH_CARRIER_TRIALS``) on ``BAYESTOUCH_CARRIER_WORKERS`` processes (default
    2) and return the harness rows."""
    n = int(os.environ.get("BAYESTOUCH_CARRIER_TRIALS", TRIALS)) if trials is None else trials
    workers = int(os.environ.get("BAYESTOUCH_CARRIER_WORKERS", "2"))
    rows = pool_rows(trial, n, workers)
    summary = {"object": "egg", "planner": "eig", "trials": n, "budget": BUDGET, "bend_spread": BEND_SPREAD, "arms": {}}
    res = []
    for arm in ARMS:
        a = sorted((r for r in rows if r["arm"] == arm), key=lambda r: r["trial"])
        covered = int(sum(abs(r["volume_z"]) <= Z90 for r in a))
        s = {
            key: dict(zip(("median", "lo", "hi"), bootstrap_median([r[key] for r in a]), strict=True))
            for key in ("chamfer", "volume_error", "contact_distance_median_m", "points")
        }
        s.update(
            {
                "covered": covered,
                "of": len(a),
                "coverage_wilson95": list(wilson_interval(covered, len(a))),
                "median_abs_z": float(np.median([abs(r["volume_z"]) for r in a])),
                "aborted": int(sum(r["aborted"] for r in a)),
                "carrier_strokes": int(sum(r["carrier_strokes"] for r in a)),
                "per_trial": a,
            }
        )
        summary["arms"][arm] = s
        label = "carrier strokes corrected by the calibrated law" if arm == "carrier" else "guarded, law marginalised"
        res += [
            {
                "metric": f"Chamfer / mean semi-axis after {BUDGET} strokes, median ({label})",
                "value": s["chamfer"]["median"],
                "unit": "1",
                "ci95": [s["chamfer"]["lo"], s["chamfer"]["hi"]],
                "trials": len(a),
            },
            {
                "metric": f"truth within the 90 % volume interval (Gaussian reading; {label})",
                "value": covered / len(a),
                "unit": "fraction",
                "wilson95": s["coverage_wilson95"],
                "trials": len(a),
            },
        ]
    write_text(RESULTS / "explore_carrier.json", json.dumps(summary, indent=2) + "\n")
    return res
