"""A fit of an object made of parts (:mod:`bayestouch.inference.parts`): the number of parts chosen by the
evidence, the chosen union sampled, and a run folder whose summaries mean something for any shape.

1. **Evidence per K.** A tempered SMC from the (connected-parts) prior for each candidate K
   (:func:`bayestouch.inference.smc.tempered_smc`, :data:`PARTS_PARTICLES` particles, HMC moves) estimates log Z_K;
   the smallest K within :data:`CHOICE_NATS` of the best is chosen (a Bayes factor below e^2.3 ≈ 10, "strong" on
   Jeffreys' scale, does not buy a part). The posterior probabilities of the K's (uniform prior over them) are
   reported; a chosen K with probability below :data:`CHOICE_CONFIDENT` is a warning.
2. **Chain.** emcee from the chosen K's particles, parts ordered by volume and each part aligned to one alias,
   with the independence mixture fitted to them (:func:`bayestouch.inference.run.smc_moves`); stopped on
   convergence of the monitored quantities (each part's volume and exponent in volume order, σ) or the budget.
3. **Summaries** (:func:`write_parts_outputs`) on thinned draws: the union's volume (quasi-Monte Carlo inside each
   draw's bounding box: :data:`VOLUME_POINTS` Sobol points, relative error ~1 %), its extent along the world axes
   and its principal second moments (m⁵), with 90 % intervals; every part's centre, semi-axes, exponent and volume
   in volume order; the occupancy grid (:mod:`bayestouch.io.occupancy`); the mean surface (the 0.5 level set of
   the occupancy, ``mean_shape.ply``) and its per-vertex spread (sd over draws of the distance to each draw's
   union, metres, ``uncertainty_mesh.ply``); ``posterior.nc`` with every kept draw.
"""

from __future__ import annotations

import time
from pathlib import Path

import arviz as az
import numpy as np
import xarray as xr
from scipy.stats import qmc

from bayestouch.backend import jnp, release_compiled
from bayestouch.errors import BadInput, check_bools, check_int, check_path, check_seed
from bayestouch.geometry.mesh import to_trimesh
from bayestouch.geometry.symmetry import align_batch
from bayestouch.inference import contact as cm
from bayestouch.inference import parts as pm
from bayestouch.inference.posterior import interval, rhat_and_ess
from bayestouch.inference.run import (
    MIN_CHAIN_STEPS,
    check_budget,
    check_walkers,
    sampling_budget,
    smc_moves,
    smc_stage,
)
from bayestouch.inference.sampler import convergence, sample
from bayestouch.io.files import atomic_path, write_json
from bayestouch.io.meshes import write_spread_mesh
from bayestouch.io.occupancy import OCCUPANCY_FILE, Occupancy, write_occupancy
from bayestouch.io.runfolder import fingerprint, prepare_run_folder, release_run_folder

__all__ = [
    "run_parts_fit",
    "choose_parts",
    "write_parts_outputs",
    "union_summaries",
    "PARTS_PARTICLES",
    "PARTS_ESS",
    "PARTS_BUDGET_S",
    "CHOICE_NATS",
    "CHOICE_CONFIDENT",
    "DEFAULT_MAX_PARTS",
    "VOLUME_POINTS",
    "OCCUPANCY_RES",
    "SUMMARY_DRAWS",
]

#: particles of each K's tempered SMC
PARTS_PARTICLES = 1024
#: conditional-ESS target of each tempering step (0.7: about 30 % fewer stages than the default fit's 0.8, the
#: dumbbell of bench_objects' seed 1 gives log Z within 1 nat of the 0.8 run's)
PARTS_ESS = 0.7
#: default wall-clock budget of a parts fit, seconds: two tempered SMCs (K = 1, 2) and the chain
PARTS_BUDGET_S = 180.0
#: a larger K is chosen only when its log-evidence beats every smaller K's by this many nats
CHOICE_NATS = 2.3
#: a chosen K with posterior probability below this is reported as an uncertain model choice
CHOICE_CONFIDENT = 0.9
#: the largest K that ``parts="auto"`` considers
DEFAULT_MAX_PARTS = 2
#: Sobol points per draw of the union's volume, extent and moments
VOLUME_POINTS = 8192
#: grid points per axis of the occupancy grid
OCCUPANCY_RES = 40
#: thinned draws the summaries and the occupancy grid are computed on
SUMMARY_DRAWS = 400
#: share of the budget the SMC stages may take together
SMC_SHARE = 0.6
#: seconds the outputs after the chain take (union summaries, occupancy grid, mean surface, posterior.nc; 8.4 s for
#: two parts on 160 contacts here), reserved from the budget
PARTS_OUTPUT_SECONDS = 10.0


def choose_parts(log_evidence: dict[int, float], nats: float = CHOICE_NATS) -> tuple[int, dict[int, float]]:
    """The chosen number of parts and the posterior probability of each K (uniform prior over the K's).

    Parameters
    ----------
    log_evidence : {K: log Z_K}, nats
    nats : float
        A larger K is chosen only when it beats every smaller K by this much.
    """
    ks = sorted(log_evidence)
    z = np.array([log_evidence[k] for k in ks], float)
    prob = np.exp(z - np.max(z))
    prob /= prob.sum()
    best = max(z)
    chosen = min(k for k in ks if log_evidence[k] >= best - nats)
    return chosen, {k: float(p) for k, p in zip(ks, prob, strict=True)}


def _aligned(particles, log_post, k: int) -> np.ndarray:
    """Particles (N, 10 K + 3) in volume order, each part rewritten as the alias nearest the best particle's."""
    x = pm.canonical_order(particles, k)
    ref = x[int(np.nanargmax(log_post))]
    for j in range(k):
        sl = slice(10 * j, 10 * j + 10)
        x[:, sl] = align_batch(x[:, sl], ref[sl])
    return x


def _judged(c, vols, k: int) -> np.ndarray:
    """The label-free quantities of draws ``c`` in volume order (:func:`bayestouch.inference.parts.canonical_order`)
    with their part volumes ``vols`` (N, K): each part's log volume and log n, and log σ (:func:`_judged_names`)."""
    return np.column_stack([np.log(vols), c[:, [10 * j + 9 for j in range(k)]], c[:, 10 * k]])


def _judged_names(k: int) -> list[str]:
    """Names of :func:`_judged`'s columns for ``k`` parts (part 1 the largest)."""
    return [f"log_volume_{j + 1}" for j in range(k)] + [f"log_n_{j + 1}" for j in range(k)] + ["log_sigma"]


def _monitor(k: int):
    """Chain draws (N, 10 K + 3) → :func:`_judged` (the stopping rule's monitor)."""

    def monitor(draws):
        c = pm.canonical_order(draws, k)
        return _judged(c, pm.part_volumes(c, k), k)

    return monitor


def union_summaries(theta, k: int, seed: int = 0, points: int = VOLUME_POINTS, chunk: int = 25) -> dict:
    """Volume (N,) m³, extent lo/hi (N, 3) m, centre of volume (N, 3) m and principal second moments (N, 3) m⁵ of
    the union of each draw θ (N, 10 K + 3), by ``points`` scrambled Sobol points in each draw's bounding box."""
    th = np.asarray(theta, float)
    lo, hi = pm.bounding_boxes(th, k)
    u = qmc.Sobol(3, scramble=True, seed=np.random.default_rng([seed, 0x50B])).random(points)
    vol, ext_lo, ext_hi, com, mom = [], [], [], [], []
    for s in range(0, len(th), chunk):  # draws in chunks: each its own points in its own box
        pts = lo[s : s + chunk, None, :] + u[None] * (hi - lo)[s : s + chunk, None, :]  # (n, P, 3)
        inside = pm.inside_union(th[s : s + chunk], k, pts)  # (n, P)
        count = inside.sum(axis=1)
        w = inside / np.maximum(count, 1)[:, None]
        v = np.prod(hi - lo, axis=1)[s : s + chunk] * count / points
        c = np.einsum("np,npi->ni", w, pts)
        d = pts - c[:, None, :]
        C = v[:, None, None] * np.einsum("np,npi,npj->nij", w, d, d)
        big = np.where(inside[..., None], pts, -np.inf).max(axis=1)
        small = np.where(inside[..., None], pts, np.inf).min(axis=1)
        none = count == 0  # no point inside: the box's first point, as a degenerate solid
        big[none], small[none], c[none] = pts[none, 0], pts[none, 0], pts[none, 0]
        vol.append(v)
        ext_lo.append(small)
        ext_hi.append(big)
        com.append(c)
        mom.append(np.linalg.eigvalsh(C)[:, ::-1])
    return {
        "volume": np.concatenate(vol),
        "extent_lo": np.concatenate(ext_lo),
        "extent_hi": np.concatenate(ext_hi),
        "centre": np.concatenate(com),
        "moments": np.concatenate(mom),
    }


def _mean_surface(occ: Occupancy, theta, k: int):
    """Vertices (V, 3) m, faces (F, 3) of the occupancy's 0.5 level set, and the per-vertex spread (V,) m."""
    from skimage.measure import marching_cubes

    h = np.array([occ.x[1] - occ.x[0], occ.y[1] - occ.y[0], occ.z[1] - occ.z[0]])
    if not (occ.probability.max() > 0.5 > occ.probability.min()):
        return None, None, None
    verts, faces, _, _ = marching_cubes(occ.probability, level=0.5, spacing=tuple(h))
    verts = verts + np.array([occ.x[0], occ.y[0], occ.z[0]])
    faces = faces[:, ::-1]  # marching cubes orients towards increasing values (inwards here): flip outwards
    hom = jnp.asarray(np.concatenate([verts.T, np.ones((1, len(verts)))]))
    d = np.asarray(pm.union_distance(jnp.asarray(theta[:200]), hom, k))  # (draws, V)
    return verts, faces, d.std(axis=0, ddof=1)


def _parts_dataset(c, k: int, S: int, W: int) -> xr.Dataset:
    """Every kept draw, parts in volume order, natural units: (chain = walker, draw = step, part …)."""
    nat = c.reshape(S, W, -1).swapaxes(0, 1)  # (W, S, D)
    parts = nat[..., : 10 * k].reshape(W, S, k, 10)
    dims3 = ("chain", "draw", "part", "xyz")
    ds = xr.Dataset(
        {
            "centre": (dims3, parts[..., 0:3], {"units": "m"}),
            "semi_axes": (dims3, np.exp(parts[..., 3:6]), {"units": "m"}),
            "euler_angles": (dims3, parts[..., 6:9], {"units": "rad"}),
            "n": (("chain", "draw", "part"), np.exp(parts[..., 9]), {"units": "1"}),
            "sigma": (("chain", "draw"), np.exp(nat[..., 10 * k]), {"units": "m"}),
            "w_in": (("chain", "draw"), nat[..., 10 * k + 1], {"units": "1"}),
            "w_out": (("chain", "draw"), nat[..., 10 * k + 2], {"units": "1"}),
        },
        coords={"chain": np.arange(W), "draw": np.arange(S), "part": np.arange(k), "xyz": ["x", "y", "z"]},
    )
    return ds


def write_parts_outputs(out: Path, chain, k: int, points, *, seed: int, t0: float, info: dict, priors) -> dict:
    """Summarise a parts chain and write ``summary.json``, ``posterior.nc``, ``occupancy.npz``, ``mean_shape.ply``
    and ``uncertainty_mesh.ply`` to ``out`` (every file atomically, the summary last). Returns the summary."""
    out = Path(out)
    S, W, D = chain.kept.shape
    flat = chain.kept.reshape(-1, D)
    c = pm.canonical_order(flat, k)
    vols = pm.part_volumes(c, k)
    mon = _judged(c, vols, k).reshape(S, W, -1).swapaxes(0, 1)
    for j in range(k):  # after the monitor's quantities: wrapping the angles changes no volume or n
        sl = slice(10 * j, 10 * j + 10)
        c[:, sl] = cm.wrap_angles(c[:, sl])
    post = _parts_dataset(c, k, S, W)

    mds = xr.Dataset({name: (("chain", "draw"), mon[..., i]) for i, name in enumerate(_judged_names(k))})
    rhat, ess = rhat_and_ess(mds)
    diag = convergence([float(rhat[v]) for v in mds], [float(ess[v]) for v in mds], chain, names=list(mds))

    rng = np.random.default_rng([seed, 0x7A2])
    thin = c[rng.choice(len(c), min(SUMMARY_DRAWS, len(c)), replace=False)]
    u = union_summaries(thin, k, seed)
    occ = pm.occupancy_grid(thin, k, OCCUPANCY_RES)
    verts, faces, spread = _mean_surface(occ, thin, k)

    parts = []
    for j in range(k):
        p = c[:, 10 * j : 10 * j + 10]
        nat = np.column_stack([p[:, :3], np.exp(p[:, 3:6]), p[:, 6:9], np.exp(p[:, 9])])
        axes = np.sort(nat[:, 3:6], axis=1)[:, ::-1]
        parts.append(
            {
                "centre_m": [interval(nat[:, i]) for i in range(3)],
                **{name: interval(axes[:, i]) for i, name in enumerate(("a", "b", "c"))},
                "n": interval(nat[:, 9]),
                "volume_m3": interval(vols[:, j]),
            }
        )
    warnings = []
    if not diag["converged"]:
        if np.isfinite(diag["max_r_hat"]) and np.isfinite(diag["min_ess_bulk"]):
            why = f"largest R-hat {diag['max_r_hat']:.3f}, smallest bulk ESS {diag['min_ess_bulk']:.0f}"
        else:
            why = "chain too short for R-hat and ESS"
        budget = ", stopped by the budget" if diag["stopped_by_budget"] else ""
        warnings.append(f"not converged ({why}{budget}): the intervals are not reliable")
    choice = info["model_choice"]
    if choice["posterior_probability"].get(str(k), 0.0) < CHOICE_CONFIDENT:
        warnings.append(
            f"uncertain number of parts: P(K = {k}) = {choice['posterior_probability'].get(str(k), 0.0):.2f} "
            f"(log-evidences {choice['log_evidence']})"
        )
    if not all(choice["smc_complete"].values()):
        stopped = [key for key, ok in choice["smc_complete"].items() if not ok]
        warnings.append(
            f"the tempered SMC of K = {', '.join(stopped)} stopped before the posterior (budget): no evidence for "
            "it, the number of parts was chosen without it; a larger --budget lets it finish"
        )
    if any(max(p[a]["q95"] for a in "abc") > 0.5 * priors.axis_max for p in parts):
        warnings.append("a part's semi-axis runs to the prior box: the data do not bound it")
    if verts is None:
        warnings.append("no mean surface: the occupancy never crosses 0.5 on the grid")

    sigma = np.exp(c[:, 10 * k])
    summary = {
        "parameters": {
            "parts": parts,
            "sigma": interval(sigma),
            "w_in": interval(c[:, 10 * k + 1]),
            "w_out": interval(c[:, 10 * k + 2]),
        },
        "derived": {
            "volume_m3": interval(u["volume"]),
            "extent_lo_m": [interval(u["extent_lo"][:, i]) for i in range(3)],
            "extent_hi_m": [interval(u["extent_hi"][:, i]) for i in range(3)],
            "centre_of_volume_m": [interval(u["centre"][:, i]) for i in range(3)],
            "second_moments_principal_m5": [interval(u["moments"][:, i]) for i in range(3)],
            "surface_spread_m": None
            if spread is None
            else {"mean": float(spread.mean()), "max": float(spread.max()), "q95": float(np.quantile(spread, 0.95))},
            "summary_draws": int(len(thin)),
        },
        "diagnostics": {**diag, "seconds": time.perf_counter() - t0, "warnings": warnings},
        "model": {**info, "seed": seed},
        "files": ["summary.json", "posterior.nc", "chain.h5", OCCUPANCY_FILE]
        + ([] if verts is None else ["mean_shape.ply", "uncertainty_mesh.ply"]),
    }
    idata = az.InferenceData(
        posterior=post,
        observed_data=xr.Dataset({"points": (("point", "xyz"), np.asarray(points, float), {"units": "m"})}),
    )
    write_occupancy(out / OCCUPANCY_FILE, occ)
    if verts is not None:
        mesh = to_trimesh(verts, faces)
        with atomic_path(out / "mean_shape.ply") as tmp:
            mesh.export(str(tmp))
        write_spread_mesh(out / "uncertainty_mesh.ply", mesh, spread)
    with atomic_path(out / "posterior.nc") as tmp:
        idata.to_netcdf(str(tmp), compress=False)
    write_json(out / "summary.json", summary)
    return summary


def run_parts_fit(
    points,
    out,
    *,
    parts="auto",
    max_parts: int = DEFAULT_MAX_PARTS,
    seed: int = 0,
    walkers: int | None = None,
    steps: int = 20000,
    budget_s: float | None = PARTS_BUDGET_S,
    free=None,
    priors: cm.PriorParams | None = None,
    progress: bool = True,
    resume: bool = False,
    overwrite: bool = False,
) -> dict:
    """Fit contacts ``points (M, 3)`` m as a union of parts and write the run folder ``out`` (module docstring).

    Parameters
    ----------
    parts : "auto" or int
        The number of parts K, or ``"auto"``: K = 1 … ``max_parts`` by the evidence.
    max_parts : int
        Largest K considered by ``"auto"`` (1 … :data:`bayestouch.inference.parts.MAX_PARTS`).
    seed : int
    walkers : int, optional
        Ensemble size (default max(32, 2 D + 2) for D = 10 K + 3 parameters).
    steps : int
        Largest number of chain steps.
    budget_s : float, seconds, optional
        Wall-clock budget of the whole fit: the SMC stages share :data:`SMC_SHARE` of it, the chain stops
        :data:`PARTS_OUTPUT_SECONDS` before it is spent, for the outputs (after at least :data:`MIN_CHAIN_STEPS`
        steps; :func:`bayestouch.inference.run.sampling_budget`).
    free : (K_f, 3) float, metres, optional
        Free-space finger positions.
    priors : PriorParams, optional
    resume, overwrite : bool
        As :func:`bayestouch.inference.run.run_contact_fit` (a resume must match data and options).

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    t0 = time.perf_counter()
    release_compiled()
    # every argument checked before the folder is touched: steps=-1, budget_s=-1 or walkers=-2 had started the
    # tempering, which ran on
    points, _ = cm.check_points(points)
    check_path(out, "out")
    check_seed(seed)
    if walkers is not None:
        check_walkers(walkers)
    check_int(steps, "steps", 1, None, "an integer number of steps")
    check_budget(budget_s)
    check_bools(progress=progress, resume=resume, overwrite=overwrite)
    free = cm.check_free(free)
    priors = cm.check_priors(priors)
    out = Path(out)
    if parts == "auto":
        max_parts = check_int(max_parts, "max_parts", 1, pm.MAX_PARTS, "a number of parts")
        candidates = list(range(1, max_parts + 1))
    else:
        try:
            k = int(parts)
        except (TypeError, ValueError):
            raise BadInput(f"parts: expected 'auto' or a number of parts 1 to {pm.MAX_PARTS}, got {parts!r}") from None
        if not 1 <= k <= pm.MAX_PARTS or str(k) != str(parts).strip():
            raise BadInput(f"parts: expected 'auto' or a number of parts 1 to {pm.MAX_PARTS}, got {parts!r}")
        candidates = [k]
    free = None if free is None or len(free) == 0 else free
    options = {
        "parts": str(parts),
        "candidates": candidates,
        "seed": int(seed),
        "walkers": walkers,
        "priors": {key: float(v) for key, v in priors._asdict().items()},
        # a chain of an older version has its Euler angles anywhere, outside this version's windows
        "angles": "one period around the particles",
    }
    fp = fingerprint("parts", {"points": points, "free-space points": free}, options)
    prepare_run_folder(out, fp, resume=resume, overwrite=overwrite)

    share = None if budget_s is None else SMC_SHARE * budget_s / len(candidates)
    runs, models = {}, {}
    for k in candidates:
        f, prior = pm.make_parts_log_prob(points, k, priors, free)
        path = out / f"smc_parts{k}.npz"
        if not resume:
            path.unlink(missing_ok=True)
        runs[k] = smc_stage(
            f,
            None,
            seed,
            path,
            progress=progress,
            budget_s=share,
            prior=(f.log_prior, lambda count, g, prior=prior: pm.sample_prior(prior, count, g)),
            particles=PARTS_PARTICLES,
            ess=PARTS_ESS,
            stream=(0x9A7, k),
            label=f"tempering, {k} part{'s' if k > 1 else ''}",
        )
        models[k] = f
    log_z = {k: float(r["log_evidence"]) for k, r in runs.items()}
    # a tempering stopped by the budget estimates ∫ p L^β, not the evidence: it takes no part in the choice unless
    # no K finished
    done = {key: v for key, v in log_z.items() if runs[key]["complete"]} or log_z
    k, prob = choose_parts(done)
    f, r = models[k], runs[k]
    dim = 10 * k + 3
    walkers = int(walkers or max(32, 2 * dim + 2))
    aligned = _aligned(r["particles"], np.asarray(r["log_lik"]) + np.asarray(r["log_prior"]), k)
    # each part's Euler angles held to one period around the aligned particles (cm.angle_window); the particles are
    # shifted into those windows first, so the mixture fitted to them and the start lie there too
    angles = pm.angle_columns(k)
    periods = cm.ANGLE_PERIODS * k
    around = cm.angle_centres(aligned, angles, periods)
    aligned = cm.shift_angles(aligned, around, angles, periods)
    cols = [10 * k + 1, 10 * k + 2]
    moves, start = smc_moves(aligned, walkers, seed, logp=f, log_columns=cols)
    ch = sample(
        cm.angle_window(f, around, angles, periods),
        start,
        out / "chain.h5",
        walkers=walkers,
        ndim=dim,
        seed=seed,
        steps=steps,
        resume=resume,
        budget_s=sampling_budget(budget_s, PARTS_OUTPUT_SECONDS),
        min_steps=MIN_CHAIN_STEPS,
        progress=progress,
        t0=t0,
        stop_when_converged=True,
        adapt=True,
        moves=moves,
        monitor=_monitor(k),
    )
    info = {
        "level": "parts",
        "parts": k,
        "noise": "outlier",
        "free_space_points": 0 if free is None else int(len(free)),
        "model_choice": {
            "method": f"tempered SMC evidence ({PARTS_PARTICLES} particles); smallest K within {CHOICE_NATS} nats",
            "log_evidence": {str(key): v for key, v in log_z.items()},
            "posterior_probability": {str(key): v for key, v in prob.items()},  # over the K's that finished
            "smc_complete": {str(key): bool(rr["complete"]) for key, rr in runs.items()},
            "smc_seconds": {str(key): float(rr["seconds"]) for key, rr in runs.items()},
            "chosen": k,
        },
        "parameter_names": list(pm.param_names(k)),
    }
    summary = write_parts_outputs(out, ch, k, points, seed=seed, t0=t0, info=info, priors=priors)
    release_run_folder(out)
    return summary
