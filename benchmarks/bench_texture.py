"""Texture identification (issue 5): accuracy and strokes to decision on the texture library.

``bench_identification``: :func:`bayestouch.planning.texture_id.run_experiment` with the first 20 textures of
``models/textures.toml``, ``BAYESTOUCH_TEXTURE_TRIALS`` trials per texture (default 5, so 100 trials: the 95 %
Wilson interval of an accuracy near 0.95 is then about ±0.05), random strokes (1 cm at 1 cm/s, 0.3 mm deep,
empirical taxel mode), decision at max posterior ≥ 0.95, at most 10 strokes. Target: accuracy ≥ 0.95 with a
median of ≤ 5 strokes (Fishel & Loeb 2012: 95.4 % on 117 textures, median 5 movements). The run folder
(results.csv, summary.json, accuracy_vs_strokes.png) goes to ``benchmarks/results/texture_id/`` (or
``BAYESTOUCH_TEXTURE_OUT``).

The discrete posterior is :mod:`bayestouch.inference.texture_posterior`; the science is in
``docs/texture_identification.md``.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks bench_texture``.
"""

from __future__ import annotations

import os
from pathlib import Path

from bayestouch.planning.texture_id import run_experiment

HERE = Path(__file__).resolve().parent


def bench_identification() -> list[dict]:
    trials = int(os.environ.get("BAYESTOUCH_TEXTURE_TRIALS", "5"))
    out = Path(os.environ.get("BAYESTOUCH_TEXTURE_OUT", HERE / "results" / "texture_id"))
    s = run_experiment(out, textures=20, trials=trials, max_strokes=10, seed=0, progress=False)
    n = s["trials"]
    lo, hi = s["accuracy_95ci"]
    rows = [
        {
            "metric": f"accuracy at decision (20 textures x {trials} trials, threshold 0.95)",
            "value": s["accuracy_at_decision"],
            "unit": "1",
            "ci95": f"[{lo:.3f}, {hi:.3f}] (Wilson, n={n})",
            "target": ">= 0.95",
        },
        {
            "metric": "median strokes to decision (undecided counted as 10)",
            "value": s["median_strokes_to_decision"],
            "unit": "strokes",
            "target": "<= 5",
        },
        {"metric": "mean strokes to decision", "value": s["mean_strokes_to_decision"], "unit": "strokes"},
        {"metric": "fraction of trials decided within 10 strokes", "value": s["decided_fraction"], "unit": "1"},
        {"metric": "accuracy after 1 stroke (MAP)", "value": s["accuracy_vs_strokes"][0], "unit": "1"},
        {"metric": "experiment wall time", "value": s["seconds"], "unit": "s"},
    ]
    return rows
