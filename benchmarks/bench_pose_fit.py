"""Shape posteriors from contacts that the host placed with its own idea of the pad's pose (issue "The finger's own
physics moves the pad", item 4: a fit that ignores the pose error is overconfident; one that models it is not).

Each scenario draws an object (n-ellipsoid, semi-axes U[15, 35] mm, n U[2, 5], rotation uniform), :data:`STROKES`
strokes of :data:`PER_STROKE` contacts (arcs of 1.2 rad of directions through the centre, anywhere on the object),
0.3 mm contact noise, and a finger (:func:`benchmarks.bench_pose.drawn_finger`) with one wire-current program per
stroke (:func:`benchmarks.bench_pose.program`). The pad's pose error along each stroke is the chain's
p_true − p_host (:func:`bayestouch.physics.pose.tip_path` of the drawn finger and of the nominal one, the host's),
sampled at the stroke's contacts and turned into the world by a random base orientation: the host records each
contact displaced by it. Two fits on the same recorded contacts, both emcee from the optimum (32 walkers, up to
:data:`STEPS` steps, stopped when converged):

* **ignoring the pose**: the Gaussian contact likelihood (:func:`bayestouch.inference.contact.make_log_prob`,
  ν = inf);
* **pose marginalised**: one Gaussian offset per stroke integrated out, prior median τ :data:`TAU_HOST` (the
  median tip error of ``bench_pose``'s nominal host) (:func:`bayestouch.inference.pose_error.make_pose_log_prob`).

Per scenario: the 90 % interval (5–95 % quantiles) of the volume and whether it holds the truth, the z-score,
convergence. Summary: coverage with Wilson 95 % intervals, median |z| and relative interval width per fit.
Outputs ``benchmarks/results/pose_fit.csv`` and ``pose_fit.json``.
"""

from __future__ import annotations

import json
import time

import arviz as az
import numpy as np
from scipy.spatial.transform import Rotation

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import contact as cm
from bayestouch.inference import pose_error as pe
from bayestouch.inference.run import initial_theta, start_ball
from bayestouch.inference.sampler import sample
from bayestouch.io.files import write_csv_rows, write_text
from bayestouch.physics import bending as bd
from bayestouch.physics import pose, sma
from benchmarks.bench_pose import DT, drawn_finger, program
from benchmarks.bench_user_sets import bootstrap_median, wilson_interval
from benchmarks.harness import RESULTS

SCENARIOS = 50
STROKES = 6
PER_STROKE = 20
NOISE_M = 3e-4
TAU_HOST = 1e-3
STEPS = 6000
WALKERS = 32


def _volume(theta) -> np.ndarray:
    """n-ellipsoid volumes (S,) m³ of θ draws (S, ≥ 10) (eq. 11, :func:`bayestouch.geometry.nellipsoid.volume`)."""
    return np.asarray(_volumes(jnp.asarray(np.asarray(theta)[:, :10])))


_volumes = jax.jit(jax.vmap(lambda t: ne.volume(cm.shape_of(t))))


def _contacts(rng: np.random.Generator):
    """An object, its true surface contacts (M, 3) m along strokes, stroke labels (M,), and the truth's volume."""
    axes = rng.uniform(0.015, 0.035, 3)
    n = float(rng.uniform(2.0, 5.0))
    R = Rotation.random(random_state=rng)
    euler = R.as_euler("ZXZ")  # R = R_z(ζ) R_x(ξ) R_z(ψ): the library's (ξ, ψ, ζ)
    shape = ne.NEllipsoid(jnp.zeros(3), jnp.asarray(axes), jnp.asarray([euler[1], euler[2], euler[0]]), jnp.asarray(n))
    pts, lab = [], []
    for s in range(STROKES):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        v = np.cross(u, rng.normal(size=3))
        v /= np.linalg.norm(v)
        t = rng.uniform(0, 2 * np.pi) + np.linspace(0.0, 1.2, PER_STROKE)
        dirs = np.cos(t)[:, None] * u + np.sin(t)[:, None] * v
        pts.append(np.asarray(ne.project_to_surface(shape, jnp.asarray(0.01 * dirs))))
        lab.append(np.full(PER_STROKE, s))
    vol = float(ne.volume(shape))
    return np.concatenate(pts), np.concatenate(lab), vol


def _pose_errors(rng, wire, rod) -> np.ndarray:
    """(STROKES, PER_STROKE, 3) pad-pose errors p_true − p_host, metres, in world axes."""
    w, r = drawn_finger(rng, wire, rod)
    i_max = float(sma.max_steady_current(wire))
    out = []
    for _ in range(STROKES):
        cur = program(rng, i_max)
        err = pose.tip_path(w, r, cur, DT).tip_position - pose.tip_path(wire, rod, cur, DT).tip_position
        frames = np.linspace(len(cur) // 4, len(cur) - 1, PER_STROKE).astype(int)  # the stroke after settling
        out.append(err[frames] @ Rotation.random(random_state=rng).as_matrix().T)
    return np.stack(out)


def _fit(logp, bounds, theta0, ndim: int, seed: int) -> dict:
    """emcee from a ball about the optimum (with log τ at the host's value for the pose model): the volume's
    quantiles, mean, sd, R-hat and bulk ESS, τ's posterior median (metres) and the seconds taken."""
    rng = np.random.default_rng(seed)
    start = start_ball(theta0, cm.Bounds(bounds.lower[:11], bounds.upper[:11]), WALKERS, rng)
    if ndim > 11:
        start = np.column_stack([start, np.log(TAU_HOST) + 0.05 * rng.normal(size=WALKERS)])
    t = time.perf_counter()
    ch = sample(
        logp,
        start,
        None,
        walkers=WALKERS,
        ndim=ndim,
        seed=seed,
        steps=STEPS,
        progress=False,
        stop_when_converged=True,
        adapt=True,
    )
    flat = ch.kept.reshape(-1, ndim)
    vol = _volume(flat)
    by_walker = np.swapaxes(vol.reshape(ch.kept.shape[:2]), 0, 1)
    return {
        "q05": float(np.quantile(vol, 0.05)),
        "q95": float(np.quantile(vol, 0.95)),
        "mean": float(vol.mean()),
        "sd": float(vol.std()),
        "r_hat": float(az.rhat(by_walker)),
        "ess": float(az.ess(by_walker)),
        "tau_m": float(np.median(np.exp(flat[:, 11]))) if ndim > 11 else float("nan"),
        "seconds": time.perf_counter() - t,
    }


def scenario(k: int, wire, rod) -> dict:
    rng = np.random.default_rng([0x90F, k])
    surf, lab, vol = _contacts(rng)
    err = _pose_errors(rng, wire, rod).reshape(-1, 3)
    pts = surf + rng.normal(0.0, NOISE_M, surf.shape) - err
    priors = cm.load_priors()
    theta0 = initial_theta(pts, k, priors)
    row = {
        "scenario": k,
        "true_volume_m3": vol,
        "pose_error_median_mm": 1e3 * float(np.median(np.linalg.norm(err, axis=1))),
    }
    plain, b_plain = cm.make_log_prob(pts, priors, np.inf, noise="student")
    marg, b_marg = pe.make_pose_log_prob(pts, lab, TAU_HOST, priors)  # prior sd of log τ: pe.TAU_LOG_SD
    for name, (f, b, d) in {"ignoring": (plain, b_plain, 11), "marginalised": (marg, b_marg, 12)}.items():
        r = _fit(f, b, theta0, d, k)
        z = (r["mean"] - vol) / r["sd"]
        row.update(
            {
                f"{name}_covered": bool(r["q05"] <= vol <= r["q95"]),
                f"{name}_z": z,
                f"{name}_width_rel": (r["q95"] - r["q05"]) / vol,
                f"{name}_r_hat": r["r_hat"],
                f"{name}_ess": r["ess"],
                f"{name}_seconds": r["seconds"],
            }
        )
        if name == "marginalised":
            row["tau_posterior_median_mm"] = 1e3 * r["tau_m"]
    return row


def bench_pose_fit(scenarios: int = SCENARIOS) -> list[dict]:
    wire, rod = sma.load_wire(), bd.load_rod()
    rows = []
    for k in range(scenarios):
        rows.append(scenario(k, wire, rod))
        r = rows[-1]
        print(
            f"[pose_fit] {k}: pose error {r['pose_error_median_mm']:.2f} mm; ignoring z {r['ignoring_z']:+.1f} "
            f"covered {r['ignoring_covered']}; marginalised z {r['marginalised_z']:+.1f} covered "
            f"{r['marginalised_covered']} (tau {r['tau_posterior_median_mm']:.2f} mm)",
            flush=True,
        )
    write_csv_rows(RESULTS / "pose_fit.csv", rows, list(rows[0]))
    summary = {"scenarios": len(rows)}
    res = []
    for name in ("ignoring", "marginalised"):
        k = sum(r[f"{name}_covered"] for r in rows)
        lo, hi = wilson_interval(k, len(rows))
        med_z = bootstrap_median([abs(r[f"{name}_z"]) for r in rows])
        width = bootstrap_median([r[f"{name}_width_rel"] for r in rows])
        conv = sum(r[f"{name}_r_hat"] < 1.01 and r[f"{name}_ess"] > 400 for r in rows)
        summary[name] = {
            "volume_coverage_90": {"k": k, "n": len(rows), "wilson95": [lo, hi]},
            "abs_z_median": {"median": med_z[0], "ci95": list(med_z[1:])},
            "width_rel_median": {"median": width[0], "ci95": list(width[1:])},
            "converged": conv,
        }
        res.append(
            {
                "metric": f"90 % volume interval coverage (pose {name})",
                "value": k / len(rows),
                "unit": "fraction",
                "n": len(rows),
                "wilson95": [lo, hi],
            }
        )
        res.append(
            {
                "metric": f"median |z| of the volume (pose {name})",
                "value": med_z[0],
                "unit": "1",
                "ci95": list(med_z[1:]),
            }
        )
    summary["pose_error_median_mm"] = bootstrap_median([r["pose_error_median_mm"] for r in rows])[0]
    write_text(RESULTS / "pose_fit.json", json.dumps(summary, indent=2) + "\n")
    return res
