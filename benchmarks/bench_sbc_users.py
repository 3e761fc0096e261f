"""Simulation-based calibration where users are: sparse, one-sided, contaminated contact sets, the default
likelihood and the default sampler (:func:`bayestouch.inference.run.run_contact_fit`: tempered SMC from the prior,
then emcee), truths drawn from the fit's own prior.

For each data set: a truth θ* from the contact-level prior that ``run_contact_fit`` samples (``models/priors.toml``
with the stated size prior :data:`SIZE_PRIOR_M`, "objects 2–10 cm across"): log semi-axes normal (the size
prior) inside the prior box, rotation uniform over rotations (Haar), n and σ log-uniform over their prior boxes,
outlier fractions w_in, w_out uniform on [0, ½ outlier_max]; then contacts along 4–6 strokes within a cap of
directions of 100–180° (the user-set generator of :mod:`benchmarks.bench_user_sets`, 40–120 contacts, noise sd σ
per coordinate, free-space finger positions on each stroke's approach), and each contact displaced into the solid
with probability w_in or out into free space with probability w_out: its surface point moved along the normal by
a half-Cauchy distance of the prior's outlier scale (the model's outlier law), redrawn until the model's signed
distance of the moved contact is that displacement to :data:`OUTLIER_MATCH` (an inward displacement deeper than
the body ends near its centre or beyond its far side, which neither the model nor a real finger produces) and
within :data:`OUTLIER_CAP` scales (a displacement of metres would be refused as a unit error). The fit starts from
the prior (no truth is passed) and has its default 60-s budget.

The rank of each symmetry-invariant quantity's truth (centre m, sorted semi-axes m, n, σ m, volume m³) among
:data:`DRAWS` posterior draws (thinned by the chain's τ) is uniform on {0, …, L} if the posterior is calibrated
(Talts et al. 2018, Theorem 1). Reported: 90 % interval coverage per quantity with its binomial 95 % band, a
chi-square test of the ranks in :data:`BINS` bins (two-sided in the sense that both too-narrow and too-wide
posteriors fail it), and the rank ECDF's difference from uniform with simultaneous 95 % bands
(``az.plot_ecdf``-style, :func:`ecdf_band`). The same ranks recomputed with every data set's draws squeezed to
0.7 of their spread about their median (a 30 %-too-narrow posterior) and stretched to 1.3 are the negative
controls: the tests must reject them (power).

Where the generator departs from the model (the model is a likelihood of signed distances, not a generative law of
3-D points; the free-space positions are conditioned on lying outside; the centre's prior is flat over a box taken
from the data): ``docs/sbc.md``. Outputs: ``benchmarks/results/sbc_users.csv`` (one row per data set, written as
each finishes so that an interrupted run continues), ``sbc_users.json`` and ``docs/img/sbc_users_ecdf.png``.
``BAYESTOUCH_SBC_SETS`` sets the number of data sets (default 200), ``BAYESTOUCH_SBC_WORKERS`` the processes (2).
"""

from __future__ import annotations

import csv
import functools
import json
import math
import multiprocessing as mp
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.stats import binom, chi2, kstest

from bayestouch.inference import sbc
from benchmarks.harness import worker_init

__all__ = [
    "SIZE_PRIOR_M",
    "sbc_priors",
    "QUANTITIES",
    "draw_truth",
    "make_sbc_set",
    "posterior_invariants",
    "truth_theta",
    "local_mode_gap",
    "posterior_climb",
    "sbc_fit",
    "NOISE_BANDS",
    "noise_bands",
    "thinned_draws",
    "ranks_of",
    "squeezed_ranks",
    "coverage",
    "chi2_uniform",
    "ecdf_band",
    "summarise",
    "bench_sbc_users",
]

#: the stated size prior of every fit and every truth: objects 2–10 cm across (``--size-prior 0.02:0.1``)
SIZE_PRIOR_M = (0.02, 0.10)
#: contacts per data set (inclusive), the range of issue 19
POINTS_RANGE = (40, 120)
#: displaced contacts' half-Cauchy distance is cut at this many outlier scales (5 cm for the 5 mm default)
OUTLIER_CAP = 10.0
#: a displaced contact is kept where the model's first-order signed distance of it (under the truth) is the drawn
#: displacement to this fraction; redrawn otherwise, at most MAX_OUTLIER_DRAWS times (an inward
#: displacement deeper than the body, which would end near its centre or beyond its far side, is not what the model
#: describes, nor physical: a contact pressed into the solid does not pass through it)
OUTLIER_MATCH = 0.2
MAX_OUTLIER_DRAWS = 200
#: posterior draws per data set (ranks lie in {0, …, L})
DRAWS = 99
#: rank-histogram bins of the chi-square test
BINS = 10
#: the negative controls' factors on the draws' spread about their median
SQUEEZE = (0.7, 1.3)
#: ranked quantities: symmetry-invariant (axes sorted a₁ ≥ a₂ ≥ a₃), SI units
QUANTITIES = ("x_G", "y_G", "z_G", "a_1", "a_2", "a_3", "n", "sigma", "volume")

#: bands of the noise sd over the smallest true semi-axis (σ / a₃) in which coverage and the local-mode check are
#: reported: below 1 % the first-order distance likelihood describes 3-D contact noise well, above 5 % it does not
NOISE_BANDS = (0.0, 0.001, 0.01, 0.05, float("inf"))

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
FIGURE = HERE.parent / "docs" / "img" / "sbc_users_ecdf.png"


def sbc_priors():
    """The contact-level prior of every fit and truth here: models/priors.toml with :data:`SIZE_PRIOR_M`."""
    from bayestouch.inference import contact as cm

    return cm.with_size_prior(cm.load_priors(), *SIZE_PRIOR_M)


def draw_truth(rng: np.random.Generator) -> dict:
    """A truth from the prior that the fit samples (module docstring): semi-axes (3,) m, n, σ m, w_in, w_out."""
    from bayestouch.inference import contact as cm

    p = sbc_priors()
    mu, sd = cm.size_prior(p)
    lo, hi = math.log(p.axis_min), math.log(p.axis_max)
    axes = np.empty(3)
    for j in range(3):  # the size prior's normal on log a inside the box [axis_min, axis_max]
        while True:
            v = rng.normal(mu, sd)
            if lo <= v <= hi:
                axes[j] = math.exp(v)
                break
    n = math.exp(rng.uniform(math.log(p.n_min), math.log(p.n_max)))
    sigma = math.exp(rng.uniform(math.log(p.sigma_min), math.log(p.sigma_max)))
    w = rng.uniform(0.0, 0.5 * p.outlier_max, 2)
    return {"axes": axes, "n": n, "sigma": sigma, "w_in": float(w[0]), "w_out": float(w[1])}


def make_sbc_set(seed: int) -> dict:
    """One data set: ``truth`` (:class:`~bayestouch.geometry.nellipsoid.NEllipsoid`), ``theta`` (the draw of
    :func:`draw_truth`), ``points`` (M, 3) m, ``free`` (K, 3) m, ``outlier_sign`` (M,) int (−1 inward, +1 outward)
    and the stroke design (``cap_deg``, ``coverage``)."""
    from bayestouch.backend import jnp
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.inference import contact as cm
    from benchmarks.bench_user_sets import make_user_set

    r_truth, r_design, r_out = np.random.default_rng([seed, 0x5BC]).spawn(3)
    th = draw_truth(r_truth)
    m = int(r_design.integers(POINTS_RANGE[0], POINTS_RANGE[1] + 1))
    d = make_user_set(
        int(r_design.integers(2**31 - 1)),
        n=th["n"],
        axes=th["axes"],
        n_points=m,
        noise_m=th["sigma"],
        outlier_fraction=0.0,
    )
    pts = np.array(d.points)
    u = r_out.uniform(size=m)
    sign = np.where(u < th["w_in"], -1, np.where(u < th["w_in"] + th["w_out"], 1, 0))
    scale = sbc_priors().outlier_scale
    t = d.truth
    theta = np.concatenate(
        [np.asarray(t.centre), np.log(np.asarray(t.axes)), np.asarray(t.angles), [math.log(th["n"])]]
    )
    moved = np.flatnonzero(sign != 0)
    base = pts[moved].copy()
    nrm = np.asarray(ne.evaluate(ne.normals, t, jnp.asarray(base))) if len(moved) else np.zeros((0, 3))
    if len(moved):  # a displaced contact is a surface point moved along the normal, without the core's noise
        base = base - np.asarray(cm.residuals(theta, base))[:, None] * nrm
    todo = np.ones(len(moved), bool)
    for _ in range(MAX_OUTLIER_DRAWS):
        if not todo.any():
            break
        k = int(todo.sum())
        dist = np.abs(scale * np.tan(0.5 * np.pi * r_out.uniform(size=k)))  # half-Cauchy of that scale
        want = sign[moved][todo] * dist
        pts[moved[todo]] = base[todo] + want[:, None] * nrm[todo]
        got = np.asarray(cm.residuals(theta, pts[moved[todo]]))
        # kept where the model's signed distance of the displaced contact is the displacement drawn
        ok = (dist <= OUTLIER_CAP * scale) & (np.abs(got - want) <= OUTLIER_MATCH * dist)
        idx = np.flatnonzero(todo)
        todo[idx[ok]] = False
    sign[moved[todo]] = 0  # no displacement of this sign that the model can represent: left on the surface
    pts[moved[todo]] = base[todo]
    return {
        "truth": d.truth,
        "theta": th,
        "points": pts,
        "free": np.array(d.free_space),
        "outlier_sign": sign,
        "cap_deg": d.cap_deg,
        "coverage": d.coverage,
        "seed": seed,
    }


def truth_invariants(s) -> np.ndarray:
    """The ranked quantities (9,) of a true n-ellipsoid and its σ (m): :data:`QUANTITIES`."""
    from bayestouch.geometry import nellipsoid as ne

    truth, sigma = s["truth"], s["theta"]["sigma"]
    axes = -np.sort(-np.asarray(truth.axes, float))
    return np.array([*np.asarray(truth.centre, float), *axes, float(truth.n), sigma, float(ne.volume(truth))])


def truth_theta(s) -> np.ndarray:
    """The true parameter vector (13,) of a data set in the fit's layout (``param_names(noise="outlier")``)."""
    t, th = s["truth"], s["theta"]
    return np.concatenate(
        [
            np.asarray(t.centre, float),
            np.log(np.asarray(t.axes, float)),
            np.asarray(t.angles, float),
            [math.log(th["n"]), math.log(th["sigma"]), th["w_in"], th["w_out"]],
        ]
    )


def posterior_climb(s):
    """The log-posterior that ``run_contact_fit`` samples for data set ``s`` (outlier noise, free space, the size
    prior) and an L-BFGS-B climb on it.

    Returns
    -------
    log_post : callable
        θ (13,) → log-posterior (nats; −inf outside the prior).
    climb : callable
        θ₀ (13,) → the local mode reached from θ₀ (the angles unbounded, the rest inside the prior's box).
    """
    from bayestouch.inference import contact as cm

    f, bounds = cm.make_log_prob(s["points"], sbc_priors(), noise="outlier", free=s["free"])
    lo, hi = np.asarray(bounds.lower, float), np.asarray(bounds.upper, float)
    d = lo.size
    box = [(None, None) if j in cm.ANGLE_COLUMNS else (lo[j], hi[j]) for j in range(d)]

    def fg(x):
        lp, ll, glp, gll = f.parts(np.asarray(x, float)[None])
        v = float(lp[0] + ll[0])
        return (-v, -(glp[0] + gll[0])) if np.isfinite(v) else (1e300, np.zeros(d))

    def climb(x0):
        return minimize(fg, np.asarray(x0, float), jac=True, method="L-BFGS-B", bounds=box, options={"maxiter": 2000}).x

    return (lambda x: -fg(x)[0]), climb


def local_mode_gap(s) -> dict:
    """How far the truth lies below the mode of its own neighbourhood on the fit's log-posterior, without a fit.

    Δ = log p(θ̂ | y) − log p(θ* | y), θ̂ the L-BFGS-B optimum reached from the truth θ* on the log-posterior that
    ``run_contact_fit`` samples (outlier noise, free space, the size prior). Where the likelihood is the law that
    made the data and the mode is near-Gaussian, 2Δ ~ χ²_D (D = 13): a small p-value says that the data, as the
    model reads them, do not come from the truth (the generator departs from the model), whatever a sampler does.

    Returns
    -------
    dict
        ``local_gap`` (nats), ``local_gap_p`` (the χ²_D tail probability of 2Δ) and ``noise_ratio`` (σ over the
        smallest true semi-axis).
    """
    from bayestouch.inference import contact as cm

    log_post, climb = posterior_climb(s)
    x0 = np.asarray(cm.wrap_angles(truth_theta(s)), float)
    gap = max(0.0, log_post(climb(x0)) - log_post(x0))
    d = x0.size
    return {
        "local_gap": gap,
        "local_gap_p": float(chi2.sf(2.0 * gap, d)),
        "noise_ratio": float(s["theta"]["sigma"] / np.min(np.asarray(s["truth"].axes, float))),
    }


def posterior_invariants(posterior) -> np.ndarray:
    """The ranked quantities (chain, draw, 9) of a run's ``posterior.nc`` posterior group (an xarray Dataset)."""
    axes = np.stack([posterior[k].values for k in ("a", "b", "c")], axis=-1)
    axes = -np.sort(-axes, axis=-1)
    cols = [posterior[k].values for k in ("x_G", "y_G", "z_G")]
    cols += [axes[..., 0], axes[..., 1], axes[..., 2]]
    cols += [posterior[k].values for k in ("n", "sigma", "volume")]
    return np.stack(cols, axis=-1)


def thinned_draws(values, tau: float, count: int, rng: np.random.Generator) -> tuple[np.ndarray, bool]:
    """``count`` draws (count, Q) without replacement from ``values (walkers, steps, Q)`` thinned by ⌈τ⌉ steps;
    from the unthinned chain when the thinned pool is smaller (second value True: the draws are correlated)."""
    v = np.asarray(values, float)
    step = max(1, int(math.ceil(tau))) if np.isfinite(tau) else 1
    pool = v[:, ::step].reshape(-1, v.shape[-1])
    short = len(pool) < count
    if short:
        pool = v.reshape(-1, v.shape[-1])
    return pool[rng.choice(len(pool), count, replace=False)], short


def ranks_of(truth, draws) -> np.ndarray:
    """Ranks (Q,): the number of ``draws (L, Q)`` strictly below ``truth (Q,)``
    (:func:`bayestouch.inference.sbc.ranks_of` for one data set)."""
    return sbc.ranks_of(np.asarray(truth)[None], np.asarray(draws)[None])[0]


def squeezed_ranks(truth, draws, factor: float) -> np.ndarray:
    """Ranks (Q,) of ``truth`` among ``draws (L, Q)`` moved to ``factor`` times their spread about their median:
    a posterior ``factor`` times as wide (< 1: overconfident)."""
    d = np.asarray(draws, float)
    med = np.median(d, axis=0)
    return ranks_of(truth, med + factor * (d - med))


def coverage(ranks, draws: int = DRAWS, level: float = 0.9) -> tuple[np.ndarray, float, tuple[float, float]]:
    """Coverage (Q,) of the central ``level`` interval of L draws from ranks (N, Q) and its exact value under
    calibration (:func:`bayestouch.inference.sbc.coverage_of`), and the central 95 % range of the covered fraction
    of N calibrated data sets (binomial)."""
    cov, p = sbc.coverage_of(ranks, draws, level)
    n = np.asarray(ranks).shape[0]
    return cov, p, (binom.ppf(0.025, n, p) / n, binom.ppf(0.975, n, p) / n)


def chi2_uniform(ranks, draws: int = DRAWS, bins: int = BINS) -> np.ndarray:
    """p-values (Q,) of the chi-square test of ranks (N, Q) in ``bins`` bins against the uniform law on {0, …, L}
    (:func:`bayestouch.inference.sbc.uniformity_pvalues`)."""
    return sbc.uniformity_pvalues(ranks, draws, bins)


@functools.lru_cache(maxsize=32)
def ecdf_band(n: int, draws: int = DRAWS, prob: float = 0.95, sims: int = 4000, seed: int = 0):
    """Simultaneous ``prob`` band of the ECDF difference F̂(z) − z of ``n`` calibrated ranks on {0, …, L}, at
    z = (r + 1)/(L + 1) for r = 0 … L − 1, by simulation (Säilynoja, Bürkner & Vehtari 2022, the bands of
    ``az.plot_ecdf``): one factor on the pointwise binomial sds so that ``prob`` of simulated ECDFs stay inside at
    every z. Returns (z (L,), lower (L,), upper (L,))."""
    rng = np.random.default_rng(seed)
    z = np.arange(1, draws + 1) / (draws + 1)
    sd = np.sqrt(z * (1 - z) / n)
    sim = rng.integers(0, draws + 1, size=(sims, n))
    F = np.stack([np.mean(sim <= r, axis=1) for r in range(draws)], axis=1)  # (sims, L)
    worst = np.max(np.abs(F - z[None]) / sd[None], axis=1)
    c = float(np.quantile(worst, prob))
    return z, -c * sd, c * sd


def ecdf_outside(ranks, draws: int = DRAWS, prob: float = 0.95) -> np.ndarray:
    """Whether each quantity's rank ECDF (ranks (N, Q)) leaves the simultaneous band of :func:`ecdf_band`: a
    test of uniformity at level 1 − ``prob`` that looks at every z at once."""
    r = np.asarray(ranks)
    z, lo, hi = ecdf_band(r.shape[0], draws, prob)
    F = np.stack([np.mean(r <= k, axis=0) for k in range(draws)], axis=0)  # (L, Q)
    diff = F - z[:, None]
    return np.any((diff < lo[:, None]) | (diff > hi[:, None]), axis=0)


def sbc_fit(s: dict, out: Path, seed: int, budget_s: float | None = None) -> dict:
    """Fit data set ``s`` (:func:`make_sbc_set`) into run folder ``out`` as every SBC fit is made: the default
    contact fit from the prior with its free-space points, the size prior :data:`SIZE_PRIOR_M` and the default
    budget (or ``budget_s`` seconds); its summary."""
    from bayestouch.inference.run import DEFAULT_BUDGET_S, run_contact_fit

    return run_contact_fit(
        s["points"],
        out,
        seed=seed,
        progress=False,
        free=s["free"],
        size_prior=SIZE_PRIOR_M,
        budget_s=DEFAULT_BUDGET_S if budget_s is None else budget_s,
    )


def fit_sbc_set(seed: int, budget_s: float | None = None) -> dict:
    """Generate data set ``seed``, fit it with ``run_contact_fit`` (defaults; the size prior of
    :data:`SIZE_PRIOR_M`), and return its CSV row: truths, ranks (nominal and the negative controls), design and
    diagnostics."""
    import arviz as az

    s = make_sbc_set(seed)
    truth = truth_invariants(s)
    with tempfile.TemporaryDirectory(prefix="bt-sbc-") as tmp:
        t0 = time.perf_counter()
        summary = sbc_fit(s, Path(tmp), seed, budget_s)
        seconds = time.perf_counter() - t0
        post = az.from_netcdf(Path(tmp) / "posterior.nc").posterior
        values = posterior_invariants(post)
    dg = summary["diagnostics"]
    draws, short = thinned_draws(values, dg["autocorr_time_max"], DRAWS, np.random.default_rng([seed, 0xD2]))
    row = {
        "seed": seed,
        "points": len(s["points"]),
        "cap_deg": s["cap_deg"],
        "coverage": s["coverage"],
        "inward": int(np.sum(s["outlier_sign"] < 0)),
        "outward": int(np.sum(s["outlier_sign"] > 0)),
        "w_in": s["theta"]["w_in"],
        "w_out": s["theta"]["w_out"],
        "converged": bool(dg["converged"]),
        "multimodal": bool(dg.get("multimodal", False)),
        "misfit": bool(dg.get("misfit", False)),
        "residual_rho": (dg.get("residual_neighbour_correlation") or {}).get("rho"),
        "residual_z": (dg.get("residual_neighbour_correlation") or {}).get("z"),
        "tau_max": dg["autocorr_time_max"],
        "short": short,
        "seconds": seconds,
        **local_mode_gap(s),
    }
    for q, name in enumerate(QUANTITIES):
        row[f"true_{name}"] = float(truth[q])
    for tag, r in (
        ("rank", ranks_of(truth, draws)),
        ("rank_squeeze", squeezed_ranks(truth, draws, SQUEEZE[0])),
        ("rank_stretch", squeezed_ranks(truth, draws, SQUEEZE[1])),
    ):
        for q, name in enumerate(QUANTITIES):
            row[f"{tag}_{name}"] = int(r[q])
    return row


def _read_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _write_rows(path: Path, rows: list[dict]) -> None:
    """All rows, under the union of their columns (rows of an earlier version of the benchmark leave the newer
    columns empty), replacing ``path`` atomically."""
    from bayestouch.io.files import atomic_path

    fields = list(dict.fromkeys(k for r in rows for k in r))
    with atomic_path(path) as tmp, Path(tmp).open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, restval="")
        w.writeheader()
        w.writerows(sorted(rows, key=lambda r: int(r["seed"])))


def _ranks(rows, tag: str) -> np.ndarray:
    return np.array([[int(r[f"{tag}_{q}"]) for q in QUANTITIES] for r in rows])


def summarise(rows: list[dict], failed: int = 0) -> dict:
    """Coverage, chi-square p-values and ECDF-band verdicts of the nominal ranks and of the negative controls, over
    the fitted sets ``rows``; ``failed`` fits (no ranks) are counted apart."""
    out = {"sets": len(rows), "failed": int(failed), "draws": DRAWS, "bins": BINS, "quantities": list(QUANTITIES)}
    for tag in ("rank", "rank_squeeze", "rank_stretch"):
        r = _ranks(rows, tag)
        cov, p, band = coverage(r)
        out[tag] = {
            "coverage_90": dict(zip(QUANTITIES, map(float, cov), strict=True)),
            "coverage_expected": p,
            "coverage_band95": [float(band[0]), float(band[1])],
            "chi2_p": dict(zip(QUANTITIES, map(float, chi2_uniform(r)), strict=True)),
            "ecdf_outside_band95": dict(zip(QUANTITIES, map(bool, ecdf_outside(r)), strict=True)),
        }
    flags = [str(r["converged"]) == "True" for r in rows]
    out["converged"] = int(sum(flags))
    out["multimodal"] = int(sum(str(r["multimodal"]) == "True" for r in rows))
    out["misfit"] = int(sum(str(r.get("misfit")) == "True" for r in rows))
    # a truth beyond every draw of a shape quantity: does the fit say something is wrong?
    shape = [q for q in QUANTITIES if q.startswith("a_") or q == "volume"]
    beyond = [r for r in rows if any(int(r[f"rank_{q}"]) in (0, DRAWS) for q in shape)]
    said = [
        r
        for r in beyond
        if str(r["converged"]) != "True" or str(r["multimodal"]) == "True" or str(r.get("misfit")) == "True"
    ]
    out["truth_beyond_every_draw"] = {"sets": len(beyond), "flagged": len(said)}
    out["short_chains"] = int(sum(str(r["short"]) == "True" for r in rows))
    out["by_noise_ratio"] = noise_bands(rows)
    out["seconds_median"] = float(np.median([float(r["seconds"]) for r in rows]))
    return out


def noise_bands(rows: list[dict]) -> dict:
    """Per band of σ / a₃ (:data:`NOISE_BANDS`): sets, 90 % coverage of the volume and of all nine quantities
    pooled, and the local-mode check (:func:`local_mode_gap`): the share of sets whose truth it rejects at 5 % and
    the Kolmogorov-Smirnov p-value of its p-values against uniform, over all sets."""
    ratio = np.array([float(r["noise_ratio"]) for r in rows])
    p_gap = np.array([float(r["local_gap_p"]) for r in rows])
    gaps = np.array([float(r["local_gap"]) for r in rows])
    ranks = _ranks(rows, "rank")
    vol = QUANTITIES.index("volume")
    bands = []
    for lo, hi in zip(NOISE_BANDS[:-1], NOISE_BANDS[1:], strict=True):
        m = (ratio >= lo) & (ratio < hi)
        cov = sbc.coverage_of(ranks[m], DRAWS)[0] if m.any() else None
        bands.append(
            {
                "ratio": [lo, hi if math.isfinite(hi) else None],  # JSON has no infinity
                "sets": int(m.sum()),
                "coverage_90_volume": float(cov[vol]) if m.any() else None,
                "coverage_90_pooled": float(cov.mean()) if m.any() else None,
                "local_gap_rejected_5pct": float(np.mean(p_gap[m] < 0.05)) if m.any() else None,
                "local_gap_median": float(np.median(gaps[m])) if m.any() else None,
            }
        )
    return {"bands": bands, "local_gap_ks_p": float(kstest(p_gap, "uniform").pvalue)}


def plot_ecdf(rows: list[dict], path: Path) -> None:
    """Rank-ECDF differences from uniform with their simultaneous 95 % band, one panel per quantity: nominal ranks
    and the 30 %-too-narrow control."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r, sq = _ranks(rows, "rank"), _ranks(rows, "rank_squeeze")
    z, lo, hi = ecdf_band(len(rows))
    fig, axs = plt.subplots(3, 3, figsize=(10, 8), sharex=True, sharey=True)
    for q, ax in enumerate(axs.ravel()):
        ax.fill_between(z, lo, hi, color="0.85", label="95 % simultaneous band")
        for ranks, style, label in ((r, "C0-", "posterior"), (sq, "C3--", "30 % too narrow (control)")):
            F = np.array([np.mean(ranks[:, q] <= k) for k in range(DRAWS)])
            ax.plot(z, F - z, style, lw=1.2, label=label)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(QUANTITIES[q])
    for ax in axs[-1]:
        ax.set_xlabel("fractional rank")
    for ax in axs[:, 0]:
        ax.set_ylabel("ECDF − uniform")
    axs[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"SBC where users are: {len(rows)} sparse, one-sided, contaminated sets, default fit")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def bench_sbc_users() -> list[dict]:
    """Run (or continue) the SBC over ``BAYESTOUCH_SBC_SETS`` data sets (default 200) and return the harness rows."""
    count = int(os.environ.get("BAYESTOUCH_SBC_SETS", "200"))
    workers = int(os.environ.get("BAYESTOUCH_SBC_WORKERS", "2"))
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / "sbc_users.csv"
    # a set whose fit failed (a row with ``error``) is fitted again; the others are kept
    rows = [r for r in _read_rows(path) if not r.get("error")]
    done = {int(r["seed"]) for r in rows}
    todo = [s for s in range(count) if s not in done]
    t0 = time.perf_counter()
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=worker_init) as pool:
        futures = {pool.submit(fit_sbc_set, s): s for s in todo}
        for fut in as_completed(futures):
            try:
                rows.append({k: str(v) for k, v in fut.result().items()})
            except Exception as exc:  # noqa: BLE001 - a fit that fails is a result, recorded; the others go on
                rows.append({"seed": str(futures[fut]), "error": f"{type(exc).__name__}: {exc}"[:200]})
                print(f"[sbc_users] set {futures[fut]} failed: {rows[-1]['error']}", flush=True)
            _write_rows(path, rows)
            print(f"[sbc_users] {len(rows)}/{count} sets, {time.perf_counter() - t0:.0f} s", flush=True)
    rows = sorted((r for r in rows if int(r["seed"]) < count), key=lambda r: int(r["seed"]))
    failed = [r for r in rows if r.get("error")]
    rows = [r for r in rows if not r.get("error")]
    missing = [r for r in rows if not r.get("local_gap")]  # rows of an earlier version: the check needs no fit
    for r in missing:
        r.update({k: str(v) for k, v in local_mode_gap(make_sbc_set(int(r["seed"]))).items()})
    if missing:
        _write_rows(path, rows + failed)
    summary = summarise(rows, failed=len(failed))
    (RESULTS / "sbc_users.json").write_text(json.dumps(summary, indent=1) + "\n")
    plot_ecdf(rows, FIGURE)
    out = []
    for tag, label in (
        ("rank", "posterior"),
        ("rank_squeeze", "30 %-too-narrow control"),
        ("rank_stretch", "30 %-too-wide control"),
    ):
        s = summary[tag]
        for q in QUANTITIES:
            out.append(
                {
                    "metric": f"90 % interval coverage, {q} ({label})",
                    "value": s["coverage_90"][q],
                    "unit": "1",
                    "expected": s["coverage_expected"],
                    "band95": s["coverage_band95"],
                    "chi2_p": s["chi2_p"][q],
                    "ecdf_outside_band95": s["ecdf_outside_band95"][q],
                    "sets": summary["sets"],
                }
            )
    out.append({"metric": "converged fits", "value": summary["converged"], "unit": "sets", "sets": summary["sets"]})
    out.append({"metric": "seconds per fit (median)", "value": summary["seconds_median"], "unit": "s"})
    return out
