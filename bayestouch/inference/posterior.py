"""How a likelihood level's chain becomes a run folder: the level describes itself with a :class:`PosteriorModel`
and hands its chain (:class:`~bayestouch.inference.sampler.Chain`) to :func:`write_posterior`, which writes

* ``chain.h5`` — the emcee backend (the checkpoint; written by :func:`bayestouch.inference.sampler.sample`);
* ``posterior.nc`` — ArviZ InferenceData (:func:`inference_data`): ``posterior`` (every kept draw: the
  canonicalised natural parameters and the volume, m³), ``sample_stats`` (``lp``, the log-posterior, and
  ``accepted``, whether the walker moved at that step), ``log_likelihood`` and ``posterior_predictive`` (on thinned
  draws, keyed and dimensioned like ``observed_data``: ``points`` over ``(point, xyz)``, a recording's
  ``log_current`` over ``(frame, taxel)``), ``observed_data``, and ``derived`` (area m² and principal moments of
  inertia m⁵ on :data:`DERIVED_DRAWS` thinned draws: a mesh per draw is too slow for every draw). Every variable
  has a ``units`` attribute; every group names ``inference_library`` (emcee) and the package version;
* ``summary.json`` — parameters (mean, sd, q05, q95, R-hat, bulk ESS), derived volume m³, area m² and principal
  inertia m⁵ (eq. 11–13) with intervals, diagnostics (converged or not, and why), the model;
* ``mean_shape.ply`` — the posterior-mean surface (m); ``uncertainty_mesh.ply`` — the same mesh coloured by the
  per-vertex posterior spread of the surface along its normal (m, also in the vertex properties ``spread`` and
  ``quality``, :mod:`bayestouch.io.meshes`, and summarised in ``summary.json``).

Shared by the contact level (:mod:`bayestouch.inference.run`) and the raw-current level
(:mod:`bayestouch.inference.raw`); the patch level summarises with :func:`interval`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import UTC, datetime
from functools import partial
from pathlib import Path
from typing import NamedTuple

import arviz as az
import emcee
import matplotlib
import numpy as np
import xarray as xr

from bayestouch import __version__
from bayestouch.backend import jax, jnp, pad_pow2
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.integrals import surface_integrals_batch
from bayestouch.geometry.mesh import cube_sphere, to_trimesh
from bayestouch.geometry.rotation import euler_from_matrix
from bayestouch.geometry.symmetry import rotation_matrices
from bayestouch.inference.sampler import convergence
from bayestouch.io.files import atomic_path, write_json
from bayestouch.io.meshes import write_spread_mesh

__all__ = [
    "ANGLE_NAMES",
    "judged_quantities",
    "mean_shape_vector",
    "PosteriorModel",
    "write_posterior",
    "inference_data",
    "interval",
    "rhat_and_ess",
    "MIN_DIAGNOSTIC_DRAWS",
    "uncertainty_spread",
    "vmf_sample",
    "draw_volumes",
    "VOLUME_BLOCK",
    "PREDICTIVE_DRAWS",
    "DERIVED_DRAWS",
    "OBSERVATION_VALUES",
]

#: draws kept for the log-likelihood and posterior-predictive groups (memory: draws × observations × 8 bytes)
PREDICTIVE_DRAWS = 500
#: draws used for the derived quantities and the uncertainty mesh
DERIVED_DRAWS = 200


#: summary names of the Euler angles, reported but not judged for convergence: the canonical frame's angles jump
#: between their aliases' values wherever two semi-axes are close or an angle is near its wrap (ψ near 0 and π are
#: one orientation), so their R-hat and ESS measure that bookkeeping, not the chain's mixing. The orientation's
#: mixing shows in the centre, semi-axes and n, which the surface ties to it.
ANGLE_NAMES = ("xi", "psi", "zeta")


class PosteriorModel(NamedTuple):
    """How a likelihood level's chain becomes outputs.

    names : tuple of str
        Natural (summary) names of the columns :attr:`natural` returns.
    natural : callable
        ``(N, D) sampled → (N, K) natural``, canonicalised (axis order, signs, angle aliases).
    shape_vectors : callable
        ``(N, K) natural → (N, 10)`` n-ellipsoid vectors (centre m, axes m, angles rad, n).
    pointwise_log_lik : callable or None
        ``(N, D) sampled → {observed name: (N, M)}`` log-likelihood of each observation (ArviZ ``log_likelihood``
        group, keyed like :attr:`observed`).
    predictive : callable or None
        ``((N, D) sampled, np.random.Generator) → {name: (N, ...) array}`` replicated data.
    observed : dict
        ``{name: array}`` the data (ArviZ ``observed_data`` group); names match :attr:`predictive`'s.
    info : dict
        Written as ``summary["model"]``.
    refine_mesh : callable, optional
        ``((K,) natural posterior mean, (V, 3) mean-shape vertices m) → (V, 3) m``: moves the mean mesh (e.g. by
        the lattice displacements of an FFD model); default: the n-ellipsoid mesh as it is.
    checks : callable, optional
        ``(summary dict) → list of str``: the level's own warnings about the fit (e.g. a noise multiplier far above
        1, i.e. a model that does not fit the data), written as ``summary["diagnostics"]["warnings"]``.
    predictive_draws : int, optional
        Draws in the posterior predictive group (default :data:`PREDICTIVE_DRAWS`; fewer where one replicate is
        large, as a recording's readings are).
    dims : dict, optional
        ``{observed name: dim names}`` of the observations' axes (e.g. ``{"points": ("point", "xyz")}``); the
        log-likelihood of an observation uses the leading ones (one value per point, per frame). Default
        ``name_dim_0`` …
    units : dict, optional
        ``{name: unit}`` of :attr:`names` and the observed variables (SI, ``"1"`` for dimensionless), written
        as each variable's ``units`` attribute.
    """

    names: tuple
    natural: Callable
    shape_vectors: Callable
    pointwise_log_lik: Callable | None
    predictive: Callable | None
    observed: dict
    info: dict
    refine_mesh: Callable | None = None
    checks: Callable | None = None
    predictive_draws: int | None = None
    dims: dict | None = None
    units: dict | None = None


def mean_shape_vector(vectors) -> np.ndarray:
    """The posterior-mean n-ellipsoid (10,) of draws ``vectors (N, 10)`` (centre m, semi-axes m, angles rad, n),
    whatever alias each draw is written in.

    The centre and n are averaged; the axes and orientation come from the mean of the symmetric matrices
    R diag(a, b, c) Rᵀ (eigenvalues the semi-axes, eigenvectors the principal directions), which every alias of a
    surface (permuted axes, flipped signs, wrapped angles) shares. Averaging the canonical angles instead jumps
    wherever two semi-axes are close or an angle is near its wrap, and gives a shape no draw resembles.
    """
    v = np.asarray(vectors, float)
    R = rotation_matrices(v[:, 6:9])
    S = np.einsum("nij,nj,nkj->ik", R, v[:, 3:6], R) / len(v)
    axes, vec = np.linalg.eigh(S)
    axes, vec = axes[::-1], vec[:, ::-1]
    if np.linalg.det(vec) < 0:
        vec[:, 2] = -vec[:, 2]
    angles = np.asarray(euler_from_matrix(jnp.asarray(vec)))
    return np.concatenate([v[:, :3].mean(axis=0), axes, angles, [v[:, 9].mean()]])


def judged_quantities(names, natural):
    """The stopping rule's monitor (:func:`bayestouch.inference.sampler.sample`) for natural quantities ``names``
    computed by ``natural`` ((N, D) sampled → (N, len(names))): sampled draws (N, D) → those quantities without the
    Euler angles (:data:`ANGLE_NAMES`), the ones whose R-hat and ESS :func:`write_posterior` judges."""
    keep = np.array([k for k, name in enumerate(names) if name not in ANGLE_NAMES])

    def monitor(draws):
        return np.asarray(natural(draws))[:, keep]

    return monitor


def interval(x) -> dict:
    """Mean, sd and the central 90 % interval (q05, q95) of draws ``x`` (N,)."""
    x = np.asarray(x, float)
    return {
        "mean": float(x.mean()),
        "sd": float(x.std(ddof=1)) if x.size > 1 else 0.0,
        "q05": float(np.quantile(x, 0.05)),
        "q95": float(np.quantile(x, 0.95)),
    }


def _thin_rows(n_steps: int, per_walker: int) -> np.ndarray:
    return np.unique(np.linspace(0, n_steps - 1, max(1, min(n_steps, per_walker))).round().astype(int))


def uncertainty_spread(mean_vertices, mean_normals, shape_vectors) -> np.ndarray:
    """Per-vertex posterior spread (V,) m of the surface: the sd over draws of where each draw's surface crosses
    the line through a mean-mesh vertex along its normal (first-order distance, so exact near the surface).

    Parameters
    ----------
    mean_vertices : (V, 3) float, metres
    mean_normals : (V, 3) float or None
        Unit normals of the mean surface. Not needed: the first-order distance is taken along the draw's own
        gradient, which agrees with the mean surface's normal to first order (``write_posterior`` passes None).
    shape_vectors : (N, 10) float
        Posterior draws as n-ellipsoid vectors.
    """
    del mean_normals  # the first-order distance is already along the normal to first order
    d = np.asarray(
        _first_order_distances(
            jnp.asarray(np.asarray(shape_vectors, dtype=float)), jnp.asarray(mean_vertices, dtype=float)
        )
    )
    return d.std(axis=0, ddof=1)


# module level, data as arguments: compiled once per array shape and shared by every run of a process
@jax.jit
@partial(jax.vmap, in_axes=(0, None))
def _first_order_distances(v, pts):
    s = ne.from_vector(v)
    return ne.first_order_distance(s, ne.to_local(s, pts))[0]


@jax.jit
@partial(jax.vmap, in_axes=(0, None))
def _mesh_vertices(v, dirs):
    s = ne.from_vector(v)
    return ne.surface_point(s, ne.unit_nsphere(dirs, s.n))


def vmf_sample(mean, kappa, rng: np.random.Generator) -> np.ndarray:
    """Unit vectors (..., 3) drawn from von Mises–Fisher distributions on the sphere with mean directions
    ``mean (..., 3)`` (unit) and concentrations ``kappa`` (broadcast to (...,), > 0): the cosine to the mean is
    w = 1 + ln(u + (1 − u) e^(−2κ))/κ, u ~ U(0, 1) (exact inversion in 3-D; E[w] = coth κ − 1/κ), the azimuth
    uniform."""
    mean = np.asarray(mean, float)
    kappa = np.broadcast_to(np.asarray(kappa, float), mean.shape[:-1])
    u = rng.random(mean.shape[:-1])
    w = np.clip(1.0 + np.log(u + (1.0 - u) * np.exp(-2.0 * kappa)) / kappa, -1.0, 1.0)
    phi = rng.uniform(0.0, 2.0 * np.pi, mean.shape[:-1])
    # an orthonormal tangent basis (t1, t2) at each mean: t1 ⟂ mean from the axis least aligned with it
    axis = np.eye(3)[np.argmin(np.abs(mean), axis=-1)]
    t1 = np.cross(mean, axis)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.cross(mean, t1)
    r = np.sqrt(np.maximum(1.0 - w * w, 0.0))[..., None]
    return w[..., None] * mean + r * (np.cos(phi)[..., None] * t1 + np.sin(phi)[..., None] * t2)


_volumes = jax.jit(jax.vmap(lambda v: ne.volume(ne.from_vector(v))))
#: most rows per call of the volumes' compiled program
VOLUME_BLOCK = 16384


def draw_volumes(vectors) -> np.ndarray:
    """Closed-form volumes (N,) m³ (eq. 11, :func:`bayestouch.geometry.nellipsoid.volume`) of n-ellipsoid draws
    ``vectors (N, ≥ 10)`` (the first 10 columns: centre m, semi-axes m, Euler angles rad, n), in blocks of at most
    :data:`VOLUME_BLOCK` rows, each padded to a power of two (copies of its first row, cut off again): a few compiled
    programs for every chain length, not one per length."""
    v = np.asarray(vectors, dtype=np.float64)[:, :10]
    blocks = [v[s : s + VOLUME_BLOCK] for s in range(0, len(v), VOLUME_BLOCK)]
    out = [np.asarray(_volumes(jax.device_put(pad_pow2(b))))[: len(b)] for b in blocks]
    return np.concatenate(out) if out else np.empty(0)


def _draw_meshes(shape_vectors, res: int):
    """Vertices (N, V, 3) m of the n-ellipsoids ``shape_vectors (N, 10)`` on one cube-sphere topology, and its
    faces (one compiled map for all draws)."""
    dirs, faces = cube_sphere(res)
    return np.asarray(_mesh_vertices(jnp.asarray(np.asarray(shape_vectors, dtype=float)), jnp.asarray(dirs))), faces


def _spread_colours(spread: np.ndarray) -> np.ndarray:
    """RGBA colours (V, 4) uint8 of per-vertex spreads (V,) m: viridis up to their 99th percentile."""
    cmap = matplotlib.colormaps["viridis"]
    hi = float(np.quantile(spread, 0.99)) or 1.0
    return (np.asarray(cmap(np.clip(spread / hi, 0.0, 1.0))) * 255).round().astype(np.uint8)


def write_posterior(out: Path, chain, model: PosteriorModel, *, seed: int, t0: float) -> dict:
    """Summarise a chain (:class:`~bayestouch.inference.sampler.Chain`) and write the run folder ``out``.

    Returns the summary written to ``summary.json``.
    """
    out = Path(out)
    kept = chain.kept  # (S, W, D)
    S, W, D = kept.shape
    nat = model.natural(kept.reshape(-1, D)).reshape(S, W, -1)
    flat = nat.reshape(-1, nat.shape[-1])
    post = _posterior_group(nat, model)
    rhat, ess = rhat_and_ess(post)
    params = {
        name: {**interval(nat[..., i]), "r_hat": float(rhat[name]), "ess_bulk": float(ess[name])}
        for i, name in enumerate(model.names)
    }
    rng = np.random.default_rng(seed)
    # derived quantities on thinned draws of every walker (a mesh per draw), in the ``derived`` group too
    drows = _thin_rows(S, max(1, DERIVED_DRAWS // W))
    vecs = np.asarray(model.shape_vectors(np.swapaxes(nat[drows], 0, 1).reshape(-1, nat.shape[-1])))
    meshes, tri = _draw_meshes(vecs, 16)
    ints = surface_integrals_batch(meshes, tri)
    areas = np.asarray(ints.area)
    inertia = np.linalg.eigvalsh(ints.inertia)[:, ::-1]  # principal moments, largest first
    derived = xr.Dataset(
        {
            "area": (("chain", "draw"), areas.reshape(W, len(drows)), {"units": "m2"}),
            "inertia": (
                ("chain", "draw", "principal"),
                inertia.reshape(W, len(drows), 3),
                {"units": "m5", "long_name": "principal second moments of the volume, largest first"},
            ),
        },
        coords={"chain": np.arange(W), "draw": drows, "principal": np.arange(3)},
    )
    idata = inference_data(chain, model, post, derived, rng)
    exact_vols = np.asarray(post["volume"].values).ravel()

    mean_nat = flat.mean(axis=0)
    # the mean shape's mesh (nellipsoid_mesh(mean, 32), through the compiled map of the draws' meshes)
    mean_vec = mean_shape_vector(vecs)
    verts, faces = _draw_meshes(mean_vec[None], 32)
    verts = verts[0]
    spread = uncertainty_spread(verts, None, vecs[: min(200, len(vecs))])
    if model.refine_mesh is not None:
        verts = np.asarray(model.refine_mesh(mean_nat, verts))
    um = to_trimesh(verts, faces)
    um.visual.vertex_colors = _spread_colours(spread)

    judged = {name: p for name, p in params.items() if name not in ANGLE_NAMES}
    diag = convergence(
        [p["r_hat"] for p in judged.values()], [p["ess_bulk"] for p in judged.values()], chain, names=list(judged)
    )
    summary = {
        "parameters": params,
        "derived": {
            "volume_m3": interval(exact_vols),  # every draw
            # the mesh mean_shape.ply is drawn from (mean_shape_vector): the shape to plot or compare, not the
            # parameters' means, which are averages of canonical labels
            "mean_shape": dict(zip(ne.PARAM_NAMES, map(float, mean_vec), strict=True)),
            "area_m2": interval(areas),
            "inertia_principal_m5": {
                k: [interval(inertia[:, i])[k] for i in range(3)] for k in ("mean", "sd", "q05", "q95")
            },
            "surface_spread_m": {
                "mean": float(spread.mean()),
                "max": float(spread.max()),
                "q95": float(np.quantile(spread, 0.95)),
            },
        },
        "diagnostics": {**diag, "seconds": time.perf_counter() - t0},
        "model": {**model.info, "seed": seed},
        "files": ["summary.json", "posterior.nc", "chain.h5", "mean_shape.ply", "uncertainty_mesh.ply"],
    }
    summary["diagnostics"]["warnings"] = list(model.checks(summary)) if model.checks is not None else []
    # uncompressed: posterior draws and replicated points are noisy floats that zlib shrinks by ~10 % at ~1 s a run
    # every file atomically (a kill leaves each one old or new, never truncated), the summary last
    with atomic_path(out / "mean_shape.ply") as tmp:
        to_trimesh(verts, faces).export(str(tmp))
    write_spread_mesh(out / "uncertainty_mesh.ply", um, spread)
    with atomic_path(out / "posterior.nc") as tmp:
        idata.to_netcdf(str(tmp), compress=False)
    write_json(out / "summary.json", summary)
    return summary


def _posterior_group(nat, model: PosteriorModel) -> xr.Dataset:
    """The ``posterior`` group: natural parameters ``nat (S, W, K)`` and the exact volume of every draw."""
    S, W, _ = nat.shape
    units = model.units or {}
    data = {
        name: (("chain", "draw"), np.swapaxes(nat[..., i], 0, 1), _unit(units, name))
        for i, name in enumerate(model.names)
    }
    vecs = np.asarray(model.shape_vectors(nat.reshape(S * W, -1)))
    # eq. 11 in closed form for an n-ellipsoid (the FFD lattice's mean displacement is not in it)
    vol = draw_volumes(vecs)
    data["volume"] = (("chain", "draw"), np.swapaxes(vol.reshape(S, W), 0, 1), {"units": "m3"})
    return xr.Dataset(data, coords={"chain": np.arange(W), "draw": np.arange(S)})


def _unit(units: dict, name: str) -> dict:
    """The attributes of variable ``name``: its ``units`` when the level states one."""
    return {"units": units[name]} if name in units else {}


def _obs_dims(model: PosteriorModel, name: str, ndim: int) -> list[str]:
    dims = list((model.dims or {}).get(name, ()))
    return (dims + [f"{name}_dim_{j}" for j in range(len(dims), ndim)])[:ndim]


def _coords(ds: xr.Dataset) -> xr.Dataset:
    """Index coordinates for every dim of ``ds`` that has none (``xyz`` gets its axis names)."""
    new = {d: (["x", "y", "z"] if d == "xyz" else np.arange(n)) for d, n in ds.sizes.items() if d not in ds.coords}
    return ds.assign_coords(new)


def _attrs() -> dict:
    return {
        "created_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "inference_library": "emcee",
        "inference_library_version": emcee.__version__,
        "arviz_version": az.__version__,
        "creator": "bayestouch",
        "creator_version": __version__,
    }


#: most values (draws × observations) of the log-likelihood and posterior-predictive groups: data sets larger than
#: PREDICTIVE_DRAWS × 10,000 observations get fewer thinned draws there, so writing them stays seconds and MB
OBSERVATION_VALUES = 5_000_000


#: fewest kept draws per walker for R-hat and the bulk ESS (ArviZ's minimum)
MIN_DIAGNOSTIC_DRAWS = 4


def rhat_and_ess(post: xr.Dataset) -> tuple:
    """Rank-normalised R-hat and bulk ESS of every variable of ``post`` (dims chain, draw), each indexable by the
    variable's name; NaN for all when the chains are shorter than :data:`MIN_DIAGNOSTIC_DRAWS` (reported as n/a and
    not converged, without ArviZ's "Shape validation failed" warnings)."""
    if post.sizes["draw"] >= MIN_DIAGNOSTIC_DRAWS:
        return az.rhat(post), az.ess(post, method="bulk")
    missing = dict.fromkeys(post.data_vars, float("nan"))
    return missing, missing


def _in_batches(fn, draws, n_obs: int, values: int = 500_000) -> dict:
    """``fn(draws)`` (a dict of (N, …) arrays) evaluated on batches of draws of about ``values`` draws ×
    observations each, concatenated: the peak memory of a pointwise log-likelihood stays bounded."""
    step = max(1, values // max(n_obs, 1))
    parts = [fn(draws[i : i + step]) for i in range(0, len(draws), step)]
    return {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in parts[0]}


def inference_data(chain, model: PosteriorModel, post: xr.Dataset, derived: xr.Dataset, rng) -> az.InferenceData:
    """ArviZ InferenceData of a chain (:class:`~bayestouch.inference.sampler.Chain`) as ``posterior.nc`` holds it
    (the module docstring lists the groups); ``post`` is :func:`_posterior_group`'s, ``derived`` the area and
    inertia of thinned draws; ``rng`` draws the posterior predictive."""
    kept = chain.kept
    S, W, D = kept.shape
    units = model.units or {}
    lp = np.swapaxes(np.asarray(chain.log_prob, float), 0, 1)
    moved = np.full((W, S), np.nan)
    moved[:, 1:] = np.swapaxes(np.any(kept[1:] != kept[:-1], axis=-1), 0, 1)
    groups = {
        "posterior": post,
        "sample_stats": xr.Dataset(
            {
                "lp": (("chain", "draw"), lp, {"units": "nat", "long_name": "log-posterior density"}),
                "accepted": (
                    ("chain", "draw"),
                    moved,
                    {"units": "1", "long_name": "1 if the walker moved at this step, 0 if not (NaN: first kept)"},
                ),
            },
            coords=post.coords,
        ),
    }
    # draws × observations bounded (OBSERVATION_VALUES): 500 draws of 50,000 contacts were 25 M log-likelihoods and
    # 75 M replicated coordinates, gigabytes and half a minute after the budget had stopped the chain
    n_obs = max([int(np.shape(v)[0]) for v in model.observed.values() if np.ndim(v)] or [1])
    per_walker = max(1, min(PREDICTIVE_DRAWS, OBSERVATION_VALUES // n_obs) // W)
    rows = _thin_rows(S, per_walker)
    coords = {"chain": np.arange(W), "draw": rows}
    if model.pointwise_log_lik is not None:
        ll = _in_batches(model.pointwise_log_lik, np.swapaxes(kept[rows], 0, 1).reshape(-1, D), n_obs)  # chain-major
        groups["log_likelihood"] = _coords(
            xr.Dataset(
                {
                    k: (
                        ("chain", "draw", *_obs_dims(model, k, np.ndim(v) - 1)),
                        np.asarray(v).reshape(W, len(rows), *np.shape(v)[1:]),
                        {"units": "nat"},
                    )
                    for k, v in ll.items()
                },
                coords=coords,
            )
        )
    if model.predictive is not None:
        prows = (
            rows
            if model.predictive_draws is None
            else _thin_rows(S, min(per_walker, max(1, model.predictive_draws // W)))
        )
        rep = model.predictive(np.swapaxes(kept[prows], 0, 1).reshape(-1, D), rng)
        groups["posterior_predictive"] = _coords(
            xr.Dataset(
                {
                    k: (
                        ("chain", "draw", *_obs_dims(model, k, v.ndim - 1)),
                        v.reshape(W, len(prows), *v.shape[1:]),
                        _unit(units, k),
                    )
                    for k, v in rep.items()
                },
                coords={"chain": np.arange(W), "draw": prows},
            )
        )
    if model.observed:
        groups["observed_data"] = _coords(
            xr.Dataset(
                {
                    k: (_obs_dims(model, k, np.ndim(v)), np.asarray(v), _unit(units, k))
                    for k, v in model.observed.items()
                }
            )
        )
    groups["derived"] = derived
    attrs = _attrs()
    for g in groups.values():
        g.attrs.update(attrs)
    return az.InferenceData(**groups)


# module level, data as arguments: one compiled program per number of points, shared by every initial fit
