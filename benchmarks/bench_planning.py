"""Active probing planner (issue 5): decision time and how much of the random–oracle gap the eig planner closes.

``bench_decision``: one eig decision for 64 candidate strokes of 20 rays from 1000 posterior draws (candidate
generation over the posterior-mean surface, predicted signals by float32 Newton ray casting, Gaussian EIG by
Cholesky of the 20 × 20 matrices), best of 5 after a warm-up call (compilation excluded). Target < 0.5 s on 2
cores. The draws are the egg's true shape perturbed by a posterior-like spread (1 mm in the centre, 3 % in the
axes, 0.05 rad in the angles, 5 % in n).

``bench_experiment``: ``run_experiment`` on the egg, planners eig/random/oracle, ``BAYESTOUCH_PLANNING_TRIALS``
trials (default 3) × budget 5, 2 worker processes, default settings but ``BAYESTOUCH_PLANNING_SCOUT`` scout arcs
(default 4, as the loop's); reports the mean Chamfer distance (over the true mean semi-axis) and volume error after
5 strokes per planner and the fraction of the random–oracle gap the eig planner closes,
(random − eig) / (random − oracle) of the means over trials (target ≥ 60 % for the Chamfer distance), with a
bootstrap 68 % and 95 % interval over trials (each resample draws whole trials: the three planners of a trial
share its scout and initial fit). The rows go to ``benchmarks/results/planning_trials.csv`` (or
``BAYESTOUCH_PLANNING_CSV``).

The Chamfer distance is the symmetric distance between the SURFACES (the point estimate's n-ellipsoid and the
true, textured mesh): ½ (E_{x∼U(Ŝ)} d(x, S) + E_{y∼U(S)} d(y, Ŝ)), U area-uniform, d the exact point-to-surface
distance (:func:`bayestouch.geometry.compare.chamfer_surfaces`, 4000 samples per surface,
:func:`bayestouch.planning.loop.shape_errors`). It has only Monte-Carlo error (≈ 1 % of its value) and no floor; the
point-cloud Chamfer distance used before had a floor of ≈ 0.02 of the mean semi-axis, at which all three planners
sat on the egg, so that the gap was noise.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks bench_planning``.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.harness import best_of

HERE = Path(__file__).resolve().parent


def bench_decision() -> list[dict]:
    from bayestouch.backend import jnp
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.planning.candidates import make_candidates
    from bayestouch.planning.policies import choose
    from bayestouch.scene.objects import load_object

    obj = load_object(HERE.parent / "models" / "objects" / "egg.toml")
    v = np.asarray(ne.to_vector(obj.shape))
    rng = np.random.default_rng(0)
    scale = np.concatenate([np.full(3, 1e-3), 0.03 * v[3:6], np.full(3, 0.05), [0.05 * v[9]]])
    draws = v + scale * rng.standard_normal((1000, 10))
    mean = ne.from_vector(jnp.asarray(draws.mean(axis=0)))

    def decide():
        cands = make_candidates(mean, 64, points=20, seed=rng, standoff=0.025)
        return choose("eig", cands, draws, noise_sd=3e-4, rng=rng, standoff=0.025)

    decide()
    t = best_of(decide, repeat=5)
    cands = make_candidates(mean, 64, points=20, seed=1, standoff=0.025)
    dec = choose("eig", cands, draws, noise_sd=3e-4, rng=rng, standoff=0.025)
    t_choose = best_of(lambda: choose("eig", cands, draws, noise_sd=3e-4, rng=rng, standoff=0.025), repeat=5)
    return [
        {
            "metric": "planner decision, 64 candidates x 1000 draws (incl. candidate generation)",
            "value": t,
            "unit": "s",
            "target": "< 0.5 s on 2 cores",
        },
        {"metric": "planner decision, EIG of 64 given candidates x 1000 draws", "value": t_choose, "unit": "s"},
        {
            "metric": "EIG of the chosen stroke (egg, posterior-like spread)",
            "value": float(dec.eig[dec.index]),
            "unit": "nats",
        },
    ]


def gap_interval(rows, metric: str = "chamfer", stroke: int = 5, boots: int = 2000, seed: int = 0) -> tuple:
    """Bootstrap intervals (68 % low, high, 95 % low, high) of :func:`~bayestouch.planning.experiment.gap_closed`
    over whole trials (object, trial): each resample keeps the three planners of a trial together."""
    from bayestouch.planning.experiment import gap_closed

    keys = sorted({(str(r["object"]), int(r["trial"])) for r in rows})
    groups = {k: [r for r in rows if (str(r["object"]), int(r["trial"])) == k] for k in keys}
    rng = np.random.default_rng(seed)
    vals = []
    for _ in range(boots):
        pick = rng.integers(0, len(keys), len(keys))
        # relabel the resampled trials so that repeats count as separate trials
        sample = [{**r, "trial": j} for j, i in enumerate(pick) for r in groups[keys[i]]]
        vals.append(gap_closed(sample, metric, stroke))
    vals = np.asarray(vals)
    vals = vals[np.isfinite(vals)]
    return tuple(float(np.percentile(vals, q)) for q in (16, 84, 2.5, 97.5))


def bench_experiment() -> list[dict]:
    from bayestouch.io.files import write_csv_rows
    from bayestouch.planning.experiment import COLUMNS, gap_closed, run_experiment

    trials = int(os.environ.get("BAYESTOUCH_PLANNING_TRIALS", "3"))
    scout = int(os.environ.get("BAYESTOUCH_PLANNING_SCOUT", "4"))
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        res = run_experiment(
            tmp,
            planners=("eig", "random", "oracle"),
            objects=("egg",),
            trials=trials,
            budget=5,
            seed=0,
            workers=2,
            settings={"scout": scout},
        )
        seconds = time.perf_counter() - t
    rows = res["rows"]
    write_csv_rows(os.environ.get("BAYESTOUCH_PLANNING_CSV", HERE / "results" / "planning_trials.csv"), rows, COLUMNS)
    out = [
        {
            "metric": f"experiment wall time (egg, 3 planners x {trials} trials x 5 strokes, {scout} scout arcs)",
            "value": seconds,
            "unit": "s",
        }
    ]
    last = [r for r in rows if int(r["stroke"]) == 5]
    for p in ("eig", "random", "oracle"):
        sel = [r for r in last if r["planner"] == p]
        out.append(
            {
                "metric": f"{p}: Chamfer / mean semi-axis after 5 strokes (mean of {len(sel)})",
                "value": float(np.mean([float(r["chamfer"]) for r in sel])),
                "unit": "1",
            }
        )
        out.append(
            {
                "metric": f"{p}: volume error after 5 strokes (mean of {len(sel)})",
                "value": float(np.mean([float(r["volume_error"]) for r in sel])),
                "unit": "1",
            }
        )
    per_trial = [float(r["seconds"]) for r in rows]
    out.append(
        {
            "metric": "seconds per stroke (median; stroke 0 includes the initial fit)",
            "value": float(np.median(per_trial)),
            "unit": "s",
        }
    )
    lo68, hi68, lo95, hi95 = gap_interval(rows, "chamfer", 5)
    out.append(
        {
            "metric": f"fraction of the random-oracle Chamfer gap closed by eig after 5 strokes ({trials} trials)",
            "value": gap_closed(rows, "chamfer", 5),
            "unit": "1",
            "target": ">= 0.6",
            "bootstrap_68": f"[{lo68:.2f}, {hi68:.2f}]",
            "bootstrap_95": f"[{lo95:.2f}, {hi95:.2f}]",
        }
    )
    out.append(
        {
            "metric": "fraction of the random-oracle volume-error gap closed by eig after 5 strokes",
            "value": gap_closed(rows, "volume_error", 5),
            "unit": "1",
        }
    )
    return out
