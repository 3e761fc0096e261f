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

``bench_identification_mismatch``: the large library (``models/textures_large.toml``: 100 drawn textures and 20
close twins) on fingers that are not the one the identifier assumes. For each of ``BAYESTOUCH_TEXTURE_FINGERS``
(default 3) fingers, constants are drawn as :func:`benchmarks.bench_mismatch.perturbed_models` draws them
(sensitivity, lag, fixed-pattern spread, 1/f level, drift), the identifier calibrates with the nominal ``models/``
on 3 sphere strokes of that finger (empirical mode), then every texture is the truth in one trial (random strokes,
at most 10). Trials are pooled over fingers: accuracy at decision with its Wilson interval, wrong decisions, median
strokes to decision; ``results/texture_mismatch.json``.

The discrete posterior is :mod:`bayestouch.inference.texture_posterior`; the science is in
``docs/texture_identification.md``.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks bench_texture``.
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from bayestouch.inference.raw import calibrate_device
from bayestouch.io.files import write_text
from bayestouch.params import MODELS
from bayestouch.physics.virtual import finger_name, load_finger, recording_dataset
from bayestouch.planning.experiment import wilson_interval
from bayestouch.planning.texture_id import run_experiment
from bayestouch.scene.objects import load_object
from bayestouch.scene.strokes import random_strokes
from bayestouch.scene.textures import LARGE_LIBRARY, load_library
from benchmarks.bench_mismatch import perturbed_models

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


def _calibration(models: Path, seed: int, mode: str = "empirical"):
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
    cal = _calibration(MODELS, 0)
    s = run_experiment(out, textures=20, trials=trials, max_strokes=10, seed=0, progress=False, calibration=cal)
    rows = _rows(s, trials, ", device file")
    rows[0]["log_gain_sd_median"] = float(np.median(cal.log_gain_sd))
    return rows


def bench_identification_mismatch() -> list[dict]:
    fingers = int(os.environ.get("BAYESTOUCH_TEXTURE_FINGERS", "3"))
    n_tex = len(load_library(LARGE_LIBRARY))
    trials, per_finger = [], []
    with tempfile.TemporaryDirectory(prefix="bt-texmis-") as tmp:
        for f in range(fingers):
            rng = np.random.default_rng([f, 0x7E7])
            models = Path(tmp) / f"models{f}"
            drawn = perturbed_models(rng, models)
            device_seed = int(rng.integers(1, 2**31))
            cal = _calibration(models, device_seed)
            s = run_experiment(
                Path(tmp) / f"run{f}",
                textures=n_tex,
                trials=1,
                max_strokes=10,
                seed=device_seed,
                progress=False,
                calibration=cal,
                library=LARGE_LIBRARY,
                finger_models=models,
            )
            last = {}
            for r in _read_rows(Path(tmp) / f"run{f}" / "results.csv"):
                last[(r["texture"], r["trial"])] = r  # the decision stroke (or the 10th)
            trials += list(last.values())
            per_finger.append(
                {
                    "drawn": drawn,
                    "accuracy_at_decision": s["accuracy_at_decision"],
                    "decided_fraction": s["decided_fraction"],
                    "median_strokes_to_decision": s["median_strokes_to_decision"],
                    "calibration_noise_scale": cal.noise_scale,
                    "seconds": s["seconds"],
                }
            )
    n = len(trials)
    correct = sum(int(r["map_correct"]) for r in trials)
    decided = [r for r in trials if int(r["decided"])]
    wrong = sum(1 - int(r["map_correct"]) for r in decided)
    strokes = [int(r["stroke"]) if int(r["decided"]) else 10 for r in trials]
    summary = {
        "fingers": fingers,
        "textures": n_tex,
        "trials": n,
        "accuracy_at_decision": correct / n,
        "accuracy_wilson95": list(wilson_interval(correct, n)),
        "decided": len(decided),
        "wrong_decisions": wrong,
        "wrong_decision_wilson95": list(wilson_interval(wrong, max(len(decided), 1))),
        "median_strokes_to_decision": float(np.median(strokes)),
        "wrong": [
            {"texture": r["texture"], "map": r["map"], "p_true": float(r["p_true"])}
            for r in trials
            if not int(r["map_correct"])
        ],
        "per_finger": per_finger,
    }
    write_text(HERE / "results" / "texture_mismatch.json", json.dumps(summary, indent=2) + "\n")
    lo, hi = summary["accuracy_wilson95"]
    return [
        {
            "metric": f"accuracy at decision under mismatch ({n_tex} textures incl. 20 twins x {fingers} drawn "
            "fingers, device files)",
            "value": summary["accuracy_at_decision"],
            "unit": "1",
            "ci95_low": lo,
            "ci95_high": hi,
            "target": ">= 0.95",
        },
        {"metric": "wrong decisions under mismatch", "value": wrong, "unit": "trials", "decided": len(decided)},
        {
            "metric": "median strokes to decision under mismatch",
            "value": summary["median_strokes_to_decision"],
            "unit": "strokes",
            "target": "<= 5",
        },
    ]


def _read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))
