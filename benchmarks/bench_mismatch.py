"""Raw-level posteriors when the finger is not the simulator's (issue "The finger is not the simulator").

Each scenario draws a finger whose constants differ from ``models/`` within their stated uncertainty
(``models/*.toml`` sources, physics.md §4–5), writes it as a parameter folder, and simulates with it; the fits use
only ``models/`` (the nominal constants) and what the recordings carry:

* **the perturbed finger** (:func:`perturbed_models`): empirical sensitivity S_p × exp(N(0, 0.2²)) (an assumption
  "to be fitted to device data"), taxel lag τ ~ U[0.10, 0.15] s (physics.md §4: τ ≈ 0.1–0.15 s), fixed-pattern
  spread σ_Φ ~ U[10, 30] mV (§5), 1/f level K_f × log-U[1/3, 3], per-taxel drift ~ U[0.5, 3]·1e-4 /√s; its fixed
  pattern from a device seed of its own;
* **calibration**: 6 strokes over the sphere at depths 0.2, 0.3, 0.4 mm (cycled), then
  :func:`bayestouch.inference.raw.calibrate_device` with the nominal ``models/``;
* **data**: :data:`STROKES` strokes over the textured egg (grating 2 mm, 50 µm, orientation 0.5 rad; roughness
  10 µm), empirical mode, another noise seed;
* **fit**: :func:`bayestouch.inference.raw.run_raw_fit` with the device file and the response lag sampled
  (``lag="sampled"``; texture auto, other options default).

Per scenario: whether the 90 % interval (q05, q95) of the volume covers the egg's n-ellipsoid volume, its z-score
and relative width; for the grating (when detected) the same for wavelength, amplitude and orientation (mod π, and
mirrored: the egg's b = c leave its principal frame free about the long axis, so the grating's plane holds the long
axis with either short axis and the angle from the long axis is o or π − o; the alias nearest the posterior mean
is compared); the same for the sampled response lag against the drawn one; the noise multiplier k, convergence and
wall time. Summary: coverage fractions with Wilson 95 % intervals, median |z| and
width. Outputs ``benchmarks/results/mismatch.csv`` (a row per scenario) and ``mismatch.json``.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import re
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference.raw import calibrate_device, run_raw_fit
from bayestouch.io.files import write_csv_rows, write_text
from bayestouch.params import MODELS
from bayestouch.physics.virtual import load_finger, recording_dataset
from bayestouch.scene.objects import load_object
from bayestouch.scene.strokes import random_strokes
from benchmarks.bench_user_sets import wilson_interval
from benchmarks.harness import RESULTS, worker_init

#: scenarios (perturbed fingers) and strokes over the egg in each
SCENARIOS = 50
STROKES = 10
CAL_STROKES = 6
CAL_DEPTHS = (2e-4, 3e-4, 4e-4)


def _set(text: str, name: str, value: float) -> str:
    """``text`` (a models TOML) with the ``value`` of the entry ``name = { value = ... }`` replaced."""
    new, n = re.subn(rf"(?m)^({name} = \{{ value = )[^,]+", lambda m: m.group(1) + repr(float(value)), text)
    if n != 1:
        raise ValueError(f"entry {name} not found once")
    return new


def perturbed_models(rng: np.random.Generator, folder: Path) -> dict:
    """Copy ``models/`` to ``folder`` with the finger's constants drawn as the module docstring says; returns them."""
    shutil.copytree(MODELS, folder)
    drawn = {
        "sensitivity": 5.0e-5 * float(np.exp(rng.normal(0.0, 0.2))),
        "lag": float(rng.uniform(0.10, 0.15)),
        "barrier_spread": float(rng.uniform(0.010, 0.030)),
        "flicker": 1.0e-8 * float(np.exp(rng.uniform(np.log(1 / 3), np.log(3)))),
        "drift_local": float(rng.uniform(0.5e-4, 3e-4)),
    }
    taxels, noise = folder / "taxels.toml", folder / "noise.toml"
    t = taxels.read_text()
    for k in ("sensitivity", "lag"):
        t = _set(t, k, drawn[k])
    taxels.write_text(t)
    n = noise.read_text()
    for k in ("barrier_spread", "flicker", "drift_local"):
        n = _set(n, k, drawn[k])
    noise.write_text(n)
    return drawn


def _record(name: str, models: Path, strokes: int, seed: int, device_seed: int, depths=None):
    obj = load_object(name)
    vf = load_finger(models, seed=device_seed)
    st = random_strokes(obj, strokes, seed=seed, duration=2.0, rate=50.0)
    if depths is not None:
        st = [s._replace(depth=depths[i % len(depths)]) for i, s in enumerate(st)]
    return recording_dataset(obj, st, vf, seed, mode="empirical"), obj


def _interval(p: dict, truth: float, period: float | None = None, mirror: bool = False) -> dict:
    """Coverage of ``truth`` by (q05, q95), the z-score and the relative width; with ``period`` the truth is first
    moved by whole periods to the alias nearest the posterior mean (a grating's orientation is defined mod π), and
    with ``mirror`` π − truth is an alias too (the egg's b = c: the grating's principal plane holds the long axis
    with either short axis, and the angle from the long axis is o or π − o)."""
    width = (p["q95"] - p["q05"]) / abs(truth)
    if period is not None:
        cands = [truth, period - truth] if mirror else [truth]
        cands = [c + period * np.round((p["mean"] - c) / period) for c in cands]
        truth = min(cands, key=lambda c: abs(p["mean"] - c))
    return {
        "covered": bool(p["q05"] <= truth <= p["q95"]),
        "z": (p["mean"] - truth) / p["sd"] if p["sd"] > 0 else float("inf"),
        "width_rel": width,
    }


def scenario(k: int, work: Path) -> dict:
    """One perturbed finger: calibrate on the sphere, fit the egg; the row of ``mismatch.csv``."""
    rng = np.random.default_rng([k, 0x3A7])
    models = work / f"models{k}"
    drawn = perturbed_models(rng, models)
    device_seed = int(rng.integers(1, 2**31))
    t0 = time.perf_counter()
    cal_ds, sphere = _record("sphere", models, CAL_STROKES, 1000 + k, device_seed, CAL_DEPTHS)
    cal = calibrate_device(cal_ds, sphere)
    t_cal = time.perf_counter() - t0
    ds, egg = _record("egg", models, STROKES, 2000 + k, device_seed)
    s = run_raw_fit(ds, work / f"fit{k}", seed=k, calibration=cal, progress=False, overwrite=True, lag="sampled")
    row = {"scenario": k, **{f"true_{n}": v for n, v in drawn.items()}}
    row.update(
        {
            "cal_response": cal.response_scale,
            "cal_response_sd": cal.response_scale_sd,
            "cal_noise_scale": cal.noise_scale,
            "cal_seconds": t_cal,
        }
    )
    v = _interval(s["derived"]["volume_m3"], float(ne.volume(egg.shape)))
    row.update({f"volume_{n}": x for n, x in v.items()})
    p = s["parameters"]
    tex = egg.texture
    row["texture_detected"] = "wavelength" in p
    for name, truth in (("wavelength", tex.wavelength), ("amplitude", tex.amplitude), ("orientation", tex.orientation)):
        period = np.pi if name == "orientation" else None
        got = (
            _interval(p[name], truth, period, mirror=True)
            if name in p
            else {"covered": None, "z": None, "width_rel": None}
        )
        row.update({f"{name}_{n}": x for n, x in got.items()})
    lag = _interval(p["lag"], drawn["lag"]) if "lag" in p else {"covered": None, "z": None, "width_rel": None}
    row.update({f"lag_{n}": x for n, x in lag.items()})
    row["lag_mean"] = p["lag"]["mean"] if "lag" in p else None
    d = s["diagnostics"]
    row.update(
        {
            "noise_scale": p["noise_scale"]["mean"],
            "converged": bool(d["converged"]),
            "fit_seconds": d["seconds"],
            "warnings": len(d.get("warnings", [])),
        }
    )
    return row


def summarise(rows: list[dict]) -> dict:
    """Coverage (Wilson 95 %), median |z| and relative width per quantity; detection and convergence counts."""
    out = {"scenarios": len(rows)}
    for q in ("volume", "wavelength", "amplitude", "orientation", "lag"):
        cov = [r[f"{q}_covered"] for r in rows if r[f"{q}_covered"] is not None]
        if not cov:
            continue
        lo, hi = wilson_interval(sum(cov), len(cov))
        z = np.abs([r[f"{q}_z"] for r in rows if r[f"{q}_z"] is not None])
        out[q] = {
            "covered": int(sum(cov)),
            "of": len(cov),
            "coverage": sum(cov) / len(cov),
            "coverage_wilson95": [lo, hi],
            "median_abs_z": float(np.median(z)),
            "median_width_rel": float(np.median([r[f"{q}_width_rel"] for r in rows if r[f"{q}_width_rel"]])),
        }
    out["texture_detected"] = int(sum(r["texture_detected"] for r in rows))
    out["converged"] = int(sum(r["converged"] for r in rows))
    out["fit_seconds_median"] = float(np.median([r["fit_seconds"] for r in rows]))
    out["calibration_seconds_median"] = float(np.median([r["cal_seconds"] for r in rows]))
    return out


def _scenario_in(k: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        r = scenario(k, Path(tmp))
    print(
        f"[mismatch] {k}: volume z {r['volume_z']:+.2f} covered {r['volume_covered']}, amplitude z {r['amplitude_z']}, "
        f"lag {drawn_lag(r)}, k {r['noise_scale']:.2f}, {time.perf_counter() - t:.0f} s",
        flush=True,
    )
    return r


def drawn_lag(r: dict) -> str:
    """'true → fitted' lag (s) of a row, for the progress line."""
    got = "known" if r.get("lag_mean") is None else f"{r['lag_mean']:.4f}"
    return f"{r['true_lag']:.4f} -> {got}"


def bench_mismatch(scenarios: int | None = None) -> list[dict]:
    """Run ``BAYESTOUCH_MISMATCH_SCENARIOS`` scenarios (default :data:`SCENARIOS`) on
    ``BAYESTOUCH_MISMATCH_WORKERS`` processes (default 2); return the harness rows."""
    count = int(os.environ.get("BAYESTOUCH_MISMATCH_SCENARIOS", SCENARIOS)) if scenarios is None else scenarios
    workers = int(os.environ.get("BAYESTOUCH_MISMATCH_WORKERS", "2"))
    if workers > 1:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=worker_init) as pool:
            rows = []
            for r in pool.imap(_scenario_in, range(count)):  # the rows so far kept as they come
                rows.append(r)
                write_csv_rows(RESULTS / "mismatch.csv", rows, list(rows[0]))
    else:
        rows = [_scenario_in(k) for k in range(count)]
    write_csv_rows(RESULTS / "mismatch.csv", rows, list(rows[0]))
    summary = summarise(rows)
    write_text(RESULTS / "mismatch.json", json.dumps(summary, indent=2) + "\n")
    res = []
    for q in ("volume", "wavelength", "amplitude", "orientation", "lag"):
        if q in summary:
            res.append(
                {
                    "metric": f"{q} 90% interval coverage",
                    "value": summary[q]["coverage"],
                    "unit": "fraction",
                    "n": summary[q]["of"],
                    "wilson95": summary[q]["coverage_wilson95"],
                }
            )
    res.append({"metric": "raw fit time, median", "value": summary["fit_seconds_median"], "unit": "s"})
    return res
