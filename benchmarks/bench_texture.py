"""Texture identification (issue 5): accuracy and strokes to decision on the texture library.

``bench_identification``: :func:`bayestouch.planning.texture_id.run_experiment` with the first 20 textures of
``models/textures.toml``, ``BAYESTOUCH_TEXTURE_TRIALS`` trials per texture (default 5, so 100 trials: the 95 %
Wilson interval of an accuracy near 0.95 is then about ±0.05), random strokes (1 cm at 1 cm/s, 0.3 mm deep,
empirical taxel mode), decision at max posterior ≥ 0.95, at most 10 strokes. Target: accuracy ≥ 0.95 with a
median of ≤ 5 strokes (Fishel & Loeb 2012: 95.4 % on 117 textures, median 5 movements). The run folder
(results.csv, summary.json, accuracy_vs_strokes.png) goes to ``benchmarks/results/texture_id/`` (or
``BAYESTOUCH_TEXTURE_OUT``).

``bench_identification_calibrated``: the same experiment with the identifier holding a device file of the
simulated finger, as a user makes one (3 strokes of 1 s over the sphere at 0.2, 0.3 and 0.4 mm, then
:func:`bayestouch.inference.raw.calibrate_device`): gains pinned to ~2e-4, so every other nuisance (the per-stroke
skin-temperature error above all) must be marginalised rather than absorbed by loose gains.

``benchmarks/bench_texture_mismatch.py`` tries the identifier on fingers that are not the one it assumes.

The discrete posterior is :mod:`bayestouch.inference.texture_posterior`; the science is in
``docs/texture_identification.md``.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks bench_texture``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bayestouch.inference.raw import calibrate_device
from bayestouch.params import MODELS
from bayestouch.physics.virtual import finger_name, load_finger, recording_dataset
from bayestouch.planning.texture_id import run_experiment
from bayestouch.scene.objects import load_object
from bayestouch.scene.strokes import random_strokes

HERE = Path(__file__).resolve().parent


def _rows(s: dict, trials: int, label: str) -> list[dict]:
    n = s["trials"]
    lo, hi = s["accuracy_95ci"]
    return [
        {
            "metric": f"accuracy at decision (20 textures x {trials} trials, threshold 0.95){label}",
            "value": s["accuracy_at_decision"],
            "unit": "1",
            "ci95": f"[{lo:.3f}, {hi:.3f}] (Wilson, n={n})",
            "ci95_low": lo,
            "ci95_high": hi,
            "target": ">= 0.95",
        },
        {
            "metric": f"median strokes to decision (undecided counted as 10){label}",
            "value": s["median_strokes_to_decision"],
            "unit": "strokes",
            "target": "<= 5",
        },
        {"metric": f"mean strokes to decision{label}", "value": s["mean_strokes_to_decision"], "unit": "strokes"},
        {
            "metric": f"fraction of trials decided within 10 strokes{label}",
            "value": s["decided_fraction"],
            "unit": "1",
        },
        {"metric": f"accuracy after 1 stroke (MAP){label}", "value": s["accuracy_vs_strokes"][0], "unit": "1"},
        {"metric": f"experiment wall time{label}", "value": s["seconds"], "unit": "s"},
    ]


def bench_identification() -> list[dict]:
    trials = int(os.environ.get("BAYESTOUCH_TEXTURE_TRIALS", "5"))
    out = Path(os.environ.get("BAYESTOUCH_TEXTURE_OUT", HERE / "results" / "texture_id"))
    s = run_experiment(out, textures=20, trials=trials, max_strokes=10, seed=0, progress=False)
    return _rows(s, trials, "")


def calibration(models: Path, seed: int, mode: str = "empirical"):
    """A user's device file of the finger ``models``/``seed``: 3 strokes of 1 s over the sphere at 0.2, 0.3 and 0.4 mm,
    calibrated with the nominal ``models/``."""
    sphere = load_object("sphere")
    strokes = random_strokes(sphere, 3, seed=1, duration=1.0, rate=50.0)
    strokes = [st._replace(depth=d) for st, d in zip(strokes, (2e-4, 3e-4, 4e-4), strict=True)]
    vf = load_finger(models, seed=seed)
    rec = recording_dataset(sphere, strokes, vf, 1, mode=mode, attrs={"finger": finger_name(seed)})
    return calibrate_device(rec, sphere)


def bench_identification_calibrated() -> list[dict]:
    trials = int(os.environ.get("BAYESTOUCH_TEXTURE_TRIALS", "5"))
    out = Path(os.environ.get("BAYESTOUCH_TEXTURE_OUT", HERE / "results" / "texture_id")).with_name(
        "texture_id_calibrated"
    )
    cal = calibration(MODELS, 0)
    s = run_experiment(out, textures=20, trials=trials, max_strokes=10, seed=0, progress=False, calibration=cal)
    rows = _rows(s, trials, ", device file")
    rows[0]["log_gain_sd_median"] = float(np.median(cal.log_gain_sd))
    return rows
