"""How far the pad is from where a host thinks it is (issue "The finger's own physics moves the pad").

Each scenario draws a finger whose bending constants differ from ``models/finger.toml`` and a current program for
its three wires, runs the bending chain (:func:`bayestouch.physics.pose.tip_path`: SMA thermal model, Brinson
kinetics with its hysteresis, three-wire equilibrium, constant-curvature tip pose) with the drawn constants, and
compares the tip with three host predictions from the same commanded currents:

* **nominal, hysteresis modelled**: the same chain with the nominal constants (what a host with ``models/`` and no
  calibration predicts);
* **nominal, no hysteresis**: the nominal constants' temperatures with the bend of the major heating branch from cold
  (``curvature_equilibrium(xi=None)``: a host that treats the wire as a one-to-one current → bend map);
* **true constants, no hysteresis**: the drawn finger's own temperatures, heating branch only: the error the
  hysteresis alone makes when every constant is known.

The drawn finger (:func:`bayestouch.physics.pose.draw_finger` with the default
:class:`~bayestouch.physics.pose.FingerSpread`; assumptions, the sources in ``models/finger.toml`` give the nominal
values): bending stiffness EI × exp(N(0, 0.2²)) (physics.md §2 puts EI_eff anywhere in 3e-4–1.5e-3 N m²);
pre-strain U[3.5, 4.5] % (Flexinol's 3–5 % stroke); the four transformation temperatures shifted together by
N(0, (3 K)²) (alloy batches); convection × U[0.8, 1.25] (still air against a draught); ambient + U[−3, 3] K.
Programs: each wire holds a level drawn every :data:`HOLD_S` seconds, zero with probability ½, else U[0, I_max] with
I_max the nominal wire's largest steady current, for :data:`PROGRAM_S` seconds at :data:`DT` s frames, starting
cold.

Per scenario: the median and the 95th percentile over frames of the tip-position error |p_true − p_host|; summary:
medians over scenarios with percentile-bootstrap 95 % intervals. Outputs ``benchmarks/results/pose.csv`` (a row per
scenario) and ``pose.json``.
"""

from __future__ import annotations

import json
from functools import partial

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.io.files import write_csv_rows, write_text
from bayestouch.physics import bending as bd
from bayestouch.physics import pose, sma
from benchmarks.bench_user_sets import bootstrap_median
from benchmarks.harness import RESULTS

SCENARIOS = 48
PROGRAM_S = 40.0
HOLD_S = 4.0
DT = 0.05
HOSTS = ("nominal", "nominal_no_hysteresis", "true_no_hysteresis")


def program(rng: np.random.Generator, i_max: float) -> np.ndarray:
    """A (T, 3) current program in amperes: piecewise-constant levels as the module docstring says."""
    holds = int(round(PROGRAM_S / HOLD_S))
    per = int(round(HOLD_S / DT))
    levels = np.where(rng.random((holds, 3)) < 0.5, 0.0, rng.uniform(0.0, i_max, (holds, 3)))
    return np.repeat(levels, per, axis=0)


@jax.jit
@partial(jax.vmap, in_axes=(None, None, 0))
def _heating_branch(rod, wire, temperatures):
    """Tip position (3,) m of the major heating branch's bend at wire temperatures (3,) K (no hysteresis)."""
    return bd.tip_pose(rod, bd.curvature_equilibrium(rod, wire, temperatures).u)[0]


def scenario(k: int, wire: sma.WireParams, rod: bd.RodParams) -> dict:
    rng = np.random.default_rng([0x905E, k])
    w, r = pose.draw_finger(rng, wire, rod)
    cur = program(rng, float(sma.max_steady_current(wire)))
    truth = pose.tip_path(w, r, cur, DT)
    host = pose.tip_path(wire, rod, cur, DT)
    predictions = {
        "nominal": host.tip_position,
        "nominal_no_hysteresis": np.asarray(_heating_branch(rod, wire, jnp.asarray(host.wire_temperature))),
        "true_no_hysteresis": np.asarray(_heating_branch(r, w, jnp.asarray(truth.wire_temperature))),
    }
    row = {
        "scenario": k,
        "EI_factor": r.EI / rod.EI,
        "prestrain": w.prestrain,
        "transformation_shift_K": w.A_s - wire.A_s,
        "convection_factor": w.convection / wire.convection,
        "ambient_K": w.ambient,
        "max_deflection_mm": 1e3 * float(np.max(np.linalg.norm(truth.tip_position[:, :2], axis=1))),
    }
    for name, p in predictions.items():
        err = 1e3 * np.linalg.norm(truth.tip_position - p, axis=1)
        row[f"{name}_median_mm"] = float(np.median(err))
        row[f"{name}_p95_mm"] = float(np.percentile(err, 95))
    return row


def bench_pose(scenarios: int = SCENARIOS) -> list[dict]:
    wire, rod = sma.load_wire(), bd.load_rod()
    rows = []
    for k in range(scenarios):
        rows.append(scenario(k, wire, rod))
        r = rows[-1]
        print(
            f"[pose] {k}: deflection up to {r['max_deflection_mm']:.1f} mm; median error "
            + ", ".join(f"{h} {r[f'{h}_median_mm']:.2f}" for h in HOSTS)
            + " mm",
            flush=True,
        )
    write_csv_rows(RESULTS / "pose.csv", rows, list(rows[0]))
    summary = {"scenarios": len(rows), "frames_per_scenario": int(round(PROGRAM_S / DT))}
    res = []
    for h in HOSTS:
        for stat in ("median", "p95"):
            med, lo, hi = bootstrap_median([r[f"{h}_{stat}_mm"] for r in rows])
            summary[f"{h}_{stat}_mm"] = {"median": med, "ci95": [lo, hi]}
            res.append(
                {
                    "metric": f"tip error, {'median' if stat == 'median' else '95th percentile'} over frames "
                    f"(host: {h.replace('_', ' ')}), median over scenarios",
                    "value": med,
                    "unit": "mm",
                    "ci95": [lo, hi],
                    "scenarios": len(rows),
                }
            )
    med, lo, hi = bootstrap_median([r["max_deflection_mm"] for r in rows])
    summary["max_deflection_mm"] = {"median": med, "ci95": [lo, hi]}
    write_text(RESULTS / "pose.json", json.dumps(summary, indent=2) + "\n")
    return res
