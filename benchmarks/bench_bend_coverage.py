"""Calibrated shape posteriors through the bending chain over many objects (issue "The finger's own physics moves the
pad", item 4): the pose-error model's coverage over ≥ 50 scenarios.

Each scenario draws an object wider than the egg's one case (an n-ellipsoid with semi-axes log-uniform in
:data:`AXES`, n uniform in :data:`N_RANGE`, orientation uniform over rotations, at the fixture's origin) and a
virtual finger whose bending constants are its own (drawn at :data:`BEND_SPREAD` × their stated spread,
:func:`bayestouch.planning.experiment.trial_finger`; the host computes the pad's pose from ``models/``'s). The eig
planner explores it with guarded strokes over the serial protocol (:class:`~bayestouch.planning.device_prober.
VirtualFingerProber`, :data:`BUDGET` strokes after the scout), and the final contact-level posterior of every
point touched is sampled (:func:`bayestouch.inference.run.run_contact_fit`, started from the loop's last
ensemble, Gaussian noise, :data:`FIT_BUDGET_S`) in three arms on the same object and seeds:

- **reference**: the models' own finger (the pose known to the encoders' 0.3 mm), a plain fit;
- **ignoring** (the negative control): the drawn finger, the loop and the fit taking the contacts as they come;
- **calibrated**: the drawn finger calibrated on a 2-cm sphere first
  (:func:`~bayestouch.planning.device_prober.calibrate_bending`), the calibrated law of :data:`POSE_DRAWS` fingers
  marginalised in the loop and in the fit (``pose=``).

Per arm: how often the 90 % intervals (the posterior's 5–95 % quantiles) of the volume and of each semi-axis hold
the truth, with Wilson intervals; the median volume error and Chamfer distance over the mean semi-axis of the
posterior-mean shape (exact point-to-surface distances, :func:`~bayestouch.geometry.compare.chamfer_surfaces`),
with bootstrap intervals; how many fits converged; and the volume interval's width over the
reference's on the same object (median, bootstrap interval). Outputs ``benchmarks/results/bend_coverage.json`` and
``bend_coverage.csv`` (one row per scenario and arm).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bayestouch.backend import jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.compare import chamfer_surfaces
from bayestouch.inference.run import run_contact_fit
from bayestouch.io.files import write_csv_rows, write_text
from bayestouch.planning.device_prober import VirtualFingerProber, calibrate_bending
from bayestouch.planning.experiment import calibration_object, trial_finger
from bayestouch.planning.loop import ExploreSettings, explore
from bayestouch.scene.objects import object_from_dict
from benchmarks.bench_user_sets import bootstrap_median, wilson_interval
from benchmarks.harness import RESULTS, pool_rows

#: scenarios, planned strokes after the scout, fingers of the pose-error law, the drawn fingers' spread factor
SCENARIOS = 50
BUDGET = 4
POSE_DRAWS = 24
BEND_SPREAD = 1.0
#: the objects: semi-axes (m, log-uniform), exponent n (uniform)
AXES = (0.016, 0.032)
N_RANGE = (2.0, 4.0)
#: wall-clock budget of each final fit (seconds)
FIT_BUDGET_S = 60.0
ARMS = ("reference", "ignoring", "calibrated")


def scenario_object(k: int):
    """Scenario ``k``'s object (a :class:`~bayestouch.scene.objects.SceneObject`): semi-axes log-uniform in
    :data:`AXES`, n uniform in :data:`N_RANGE`, z-x-z Euler angles from the Haar measure (cos ξ uniform)."""
    rng = np.random.default_rng([k, 0xB0C0])
    axes = np.exp(rng.uniform(*np.log(AXES), 3))
    angles = [float(np.arccos(rng.uniform(-1, 1))), *rng.uniform(-np.pi, np.pi, 2).tolist()]
    doc = {
        "object": {"name": f"scenario {k}", "description": "drawn n-ellipsoid"},
        "shape": {
            "centre_m": [0.0, 0.0, 0.0],
            "axes_m": axes.tolist(),
            "angles_rad": angles,
            "n": rng.uniform(*N_RANGE),
        },
    }
    return object_from_dict(doc)


def _arm(obj, seed: int, arm: str, out: Path) -> dict:
    finger = None if arm == "reference" else trial_finger(seed, BEND_SPREAD)
    settings = ExploreSettings(pose_draws=POSE_DRAWS if arm == "calibrated" else 0)
    law, model = None, None
    t0 = time.perf_counter()
    if arm == "calibrated":
        sphere = calibration_object()
        with VirtualFingerProber(sphere, seed=seed, finger=finger) as cal:
            law = calibrate_bending(cal, sphere, seed=seed).law
    with VirtualFingerProber(obj, seed=seed, finger=finger, pose_law=law) as prober:
        res = explore(obj, "eig", BUDGET, seed=seed, settings=settings, prober=prober)
        if arm == "calibrated":
            model = prober.pose_model(res.points, POSE_DRAWS)
    s = run_contact_fit(
        res.points,
        out / arm,
        seed=seed,
        start=res.ensemble,
        noise="gaussian",
        pose=model,
        budget_s=FIT_BUDGET_S,
        progress=False,
    )
    seconds = time.perf_counter() - t0
    true_axes = np.sort(np.asarray(obj.shape.axes, float))[::-1]
    volume = float(ne.volume(obj.shape))
    v = s["derived"]["volume_m3"]
    est = ne.from_vector(jnp.asarray([s["derived"]["mean_shape"][k] for k in ne.PARAM_NAMES]))
    row = {
        "arm": arm,
        "points": len(res.points),
        "volume_m3": volume,
        "volume_mean_m3": v["mean"],
        "volume_q05_m3": v["q05"],
        "volume_q95_m3": v["q95"],
        "volume_covered": bool(v["q05"] <= volume <= v["q95"]),
        "volume_error": abs(v["mean"] / volume - 1.0),
        "volume_z": (v["mean"] - volume) / v["sd"],
        "chamfer_ratio": chamfer_surfaces(est, obj.shape, seed=seed)[0] / float(np.mean(true_axes)),
        "converged": bool(s["diagnostics"]["converged"]),
        "seconds": seconds,
    }
    for i, name in enumerate(("a", "b", "c")):
        p = s["parameters"][name]
        row[f"{name}_covered"] = bool(p["q05"] <= true_axes[i] <= p["q95"])
    row["pose_scale"] = s["parameters"].get("pose_scale", {}).get("mean", float("nan"))
    return row


def _failed(arm: str, error: Exception) -> dict:
    """The row of an arm that raised: not covered, an infinite error, not converged, and why."""
    row = {"arm": arm, "volume_covered": False, "volume_error": np.inf, "volume_z": np.inf, "chamfer_ratio": np.inf}
    row.update({f"{x}_covered": False for x in "abc"})
    row.update({"converged": False, "seconds": np.nan, "volume_q05_m3": np.nan, "volume_q95_m3": np.nan})
    row.update({"points": 0, "volume_m3": np.nan, "volume_mean_m3": np.nan, "pose_scale": np.nan})
    row["error"] = f"{type(error).__name__}: {error}"[:200]
    return row


def scenario(k: int) -> list[dict]:
    """Scenario ``k``'s three arms (rows of ``bend_coverage.csv``; an arm that raised counts as a failure)."""
    obj = scenario_object(k)
    seed = 1000 + k
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for arm in ARMS:
            try:
                rows.append(_arm(obj, seed, arm, Path(tmp)))
            except Exception as e:  # noqa: BLE001 - a failed arm is a result, not the end of the benchmark
                rows.append(_failed(arm, e))
    for r in rows:
        r.update({"scenario": k, "seed": seed, "n_true": float(obj.shape.n), "error": r.get("error", "")})
        width = (r["volume_q95_m3"] - r["volume_q05_m3"]) / (rows[0]["volume_q95_m3"] - rows[0]["volume_q05_m3"])
        r["width_over_reference"] = width if np.isfinite(width) else np.inf  # a failed arm or reference
    print(f"[bend_coverage] scenario {k}: " + ", ".join(f"{r['arm']} z {r['volume_z']:+.1f}" for r in rows), flush=True)
    return rows


def _summary(rows: list[dict]) -> dict:
    out = {}
    for arm in ARMS:
        a = [r for r in rows if r["arm"] == arm]
        n = len(a)
        cov = sum(r["volume_covered"] for r in a)
        axes = sum(r[f"{x}_covered"] for r in a for x in "abc")
        med = {
            key: dict(zip(("median", "lo", "hi"), bootstrap_median([r[key] for r in a]), strict=True))
            for key in ("volume_error", "chamfer_ratio", "width_over_reference")
        }
        out[arm] = {
            "scenarios": n,
            "volume_covered": cov,
            "volume_coverage_wilson95": list(wilson_interval(cov, n)),
            "axes_covered": axes,
            "axes_of": 3 * n,
            "axes_coverage_wilson95": list(wilson_interval(axes, 3 * n)),
            "median_abs_volume_z": float(np.median([abs(r["volume_z"]) for r in a])),
            "beyond_3sd": int(sum(abs(r["volume_z"]) > 3 for r in a)),
            "converged": int(sum(r["converged"] for r in a)),
            "failed": int(sum(bool(r["error"]) for r in a)),
            "seconds_median": float(np.nanmedian([r["seconds"] for r in a])),
            **med,
        }
    return out


def bench_bend_coverage(scenarios: int | None = None) -> list[dict]:
    """Run :data:`SCENARIOS` scenarios (``BAYESTOUCH_BEND_SCENARIOS``) on ``BAYESTOUCH_BEND_WORKERS`` processes
    (default 2) and return the harness rows."""
    n = int(os.environ.get("BAYESTOUCH_BEND_SCENARIOS", SCENARIOS)) if scenarios is None else scenarios
    workers = int(os.environ.get("BAYESTOUCH_BEND_WORKERS", "2"))
    rows = pool_rows(scenario, n, workers)
    rows.sort(key=lambda r: (r["scenario"], ARMS.index(r["arm"])))
    cols = list(dict.fromkeys(k for r in rows for k in r))
    write_csv_rows(RESULTS / "bend_coverage.csv", [{k: r.get(k, "") for k in cols} for r in rows], cols)
    summary = {
        "scenarios": n,
        "budget": BUDGET,
        "pose_draws": POSE_DRAWS,
        "bend_spread": BEND_SPREAD,
        "axes_m": list(AXES),
        "n_range": list(N_RANGE),
        "fit_budget_s": FIT_BUDGET_S,
        "arms": _summary(rows),
    }
    write_text(RESULTS / "bend_coverage.json", json.dumps(summary, indent=2) + "\n")
    res = []
    for arm, s in summary["arms"].items():
        res += [
            {
                "metric": f"truth within the 90 % volume interval ({arm})",
                "value": s["volume_covered"] / s["scenarios"],
                "unit": "fraction",
                "wilson95": s["volume_coverage_wilson95"],
                "trials": s["scenarios"],
            },
            {
                "metric": f"volume error of the posterior mean, median ({arm})",
                "value": s["volume_error"]["median"],
                "unit": "1",
                "ci95": [s["volume_error"]["lo"], s["volume_error"]["hi"]],
                "trials": s["scenarios"],
            },
        ]
        if arm != "reference":
            res.append(
                {
                    "metric": f"volume interval width over the reference's, median ({arm})",
                    "value": s["width_over_reference"]["median"],
                    "unit": "1",
                    "ci95": [s["width_over_reference"]["lo"], s["width_over_reference"]["hi"]],
                    "trials": s["scenarios"],
                }
            )
    return res
