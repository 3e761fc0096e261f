"""Shape recovery from sparse tactile data (issue 4): bayestouch's contact-level posterior against the
pip-installable peer ``sage-superquadric``.

Data (:func:`make_sparse_set`): a random n-ellipsoid (semi-axes 1.5–5 cm, n ∈ [2, 5], uniform random
orientation, centre within ±5 cm) touched along 2–5 strokes, great-circle arcs of the unit sphere of
directions mapped onto the surface (eq. 4–6), all inside a cap of half-angle ``cap_deg`` around one
"approach" direction (100° by default: the data cover part of the object only; 180°: anywhere on it);
35–100 points, isotropic Gaussian noise of 0.3 mm, and in the outlier sets 15 % of the points moved 1–10 mm off
the surface (half along the outward normal, half in a random direction).

Targets (issue 4): median volume error |V̂/V − 1| ≤ 4 % and symmetric Chamfer distance ≤ 0.03 of the true
mean semi-axis. The issue quotes 8–15 % and 0.07–0.08 for sage-superquadric and for EMS (Liu et al., "Robust
and Accurate Superquadric Recovery: a Probabilistic Approach", CVPR 2022) on such data.

What "such data" means: the issue gives the peer's figures but not how much of the object the strokes cover, and
the medians depend on it more than on anything else. The cap is therefore calibrated on the peer: the sets are
paired across caps (the same shapes, point counts and strokes; only where the strokes lie changes), and
sage-superquadric's median errors were measured per cap (seed 0, sets 0–23; bootstrap 68 % intervals of the
median in brackets; its errors are bimodal, near zero or 20–60 %, so the medians of a few sets are uncertain):

========  ==================  ===========================  =================================
cap       median coverage     sage median volume error      sage median Chamfer / mean axis
========  ==================  ===========================  =================================
100°      0.35 (8 sets)       0.78 (0.42–56; 3 of 8 sets    0.37
                              diverge to metre-sized
                              shapes)
140°      0.61 (24 sets)      0.21 (0.09–0.28)             0.16 (0.07–0.19)
160°      0.73 (24 sets)      0.28 (0.09–0.33)             0.15 (0.13–0.20)
180°      0.83 (24 sets)      0.056 (0.04–0.16);           0.067 (0.03–0.13);
                              sets 0–7: 0.13               sets 0–7: 0.083
========  ==================  ===========================  =================================

Only at 180° (strokes anywhere on the object, wrapping round it; 55–100 % of the sphere of directions, median
0.8) does the peer come near the issue's figures: its median Chamfer ratio there, 0.067–0.098 depending on which
8–24 sets, brackets the issue's 0.07–0.08, and its median volume error, 0.04–0.13, overlaps the issue's 8–15 %;
at 140–160° it is 0.2–0.3. So :data:`CALIBRATED_CAP_DEG` = 180° stands for "such data" (it is the widest
cap; no cap gives the peer more than that). The one-sided default :data:`CAP_DEG` = 100° (30–45 % coverage) is much
harder than the data behind the issue's figures (the peer's median there is 0.7–0.8, with fits diverging to
metre-sized shapes); it stays in the benchmark, reported per cap beside the calibrated cap, so that the hard case
remains visible.

Measured (``bench_sparse()`` defaults: seed 0, 10 sets per cap, 3 of them with outliers; 6000 adaptive steps × 32
walkers, ≈ 11 s a fit; medians; ``benchmarks/results/sparse_sets.csv``):

=====  ======================  =========================  =====================  ==========================
cap    bayestouch volume err.  bayestouch Chamfer ratio   sage volume error      sage Chamfer ratio
=====  ======================  =========================  =====================  ==========================
180°   0.013 (7 of 10 sets     0.013 (0.016 in an         0.13 (3 of 10)         0.098
       within both targets)    earlier sampler version)
100°   0.24 (0 of 10)          0.14–0.16                  0.78 (0 of 10)         0.40
=====  ======================  =========================  =====================  ==========================

At 180° the chains are long on most sets (median largest τ ≈ 8 steps); the three sets that miss the targets are
three of the four two-stroke sets, whose posterior is a long ridge over the unseen side (τ 220–350, volume errors
0.16–0.82; on two of them the posterior's volume interval excludes the truth). At 100° every set is like that
(median τ ≈ 410 steps at 6000 steps; without the adaptive proposal τ kept growing with the chain, 1000–2800 steps
at 24 000), so the per-set errors there carry a large Monte Carlo error, and their median (0.22–0.29 over repeated
runs and sampler versions) is as much the sampler's as the data's.

Metrics: volume error from the closed forms (n-ellipsoid: :func:`bayestouch.geometry.nellipsoid.volume`;
superquadric: :func:`superquadric_volume`), Chamfer from :func:`bayestouch.geometry.compare.chamfer_shapes`
(½ (mean A→B + mean B→A) of nearest-neighbour distances between area-uniform surface samples) with
:data:`CHAMFER_COUNT` points per surface, divided by the true mean semi-axis.

Point estimate of bayestouch: the posterior draw whose volume is the posterior median. The median minimises the
expected absolute error of the volume under the posterior, and a single draw is a coherent surface for the Chamfer
distance, whereas the mean of canonicalised parameters averages Euler angles and axes across aliases and modes
and can describe a surface no draw supports. The posterior-mean shape is reported alongside.

The peer's "default" is its single-primitive fit ``fit_superquadric(points)`` (its object pipeline
``SAGE._fit`` calls the same function first and splits off second parts only from ≥ 40 unexplained points, never
the case with these sets). Its soft-L1 scale (0.05) is far above its residuals (metres × √(a1 a2 a3)), so it is in
effect plain least squares; its semi-axes are unbounded above, and on some sets it diverges to metre-sized shapes
(kept as they are: they are its result).

Run: ``OMP_NUM_THREADS=1 python -m benchmarks bench_sparse`` (``BAYESTOUCH_SPARSE_SETS`` sets the number of
data sets per cap, default 10, ≈ 30 s each on a shared 2-core machine; ``BAYESTOUCH_SPARSE_STEPS`` the emcee steps
per fit, default :data:`BENCH_STEPS`; ``BAYESTOUCH_SPARSE_CAP`` the caps, comma-separated degrees, default
``180,100``). The per-set table of every cap (column ``cap_deg``) is written to
``benchmarks/results/sparse_sets.csv``.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.compare import chamfer_shapes
from bayestouch.geometry.mesh import cube_sphere
from bayestouch.geometry.rotation import euler_from_matrix

__all__ = [
    "SparseSet",
    "make_sparse_set",
    "make_sparse_sets",
    "distance_to_surface",
    "superquadric_volume",
    "superquadric_mesh",
    "fit_bayestouch",
    "fit_sage",
    "shape_errors",
    "bench_sparse",
    "VOLUME_TARGET",
    "CHAMFER_TARGET",
    "CAP_DEG",
    "CALIBRATED_CAP_DEG",
    "BENCH_CAPS",
]

#: issue 4: median |V̂/V − 1|
VOLUME_TARGET = 0.04
#: issue 4: median symmetric Chamfer distance / true mean semi-axis
CHAMFER_TARGET = 0.03
#: half-angle of the cap of directions (around the approach direction) that holds every stroke, degrees;
#: a cap of half-angle α holds (1 − cos α)/2 of the directions: 59 % for 100° (issue: "covering part of the object")
CAP_DEG = 100.0
#: the cap at which sage-superquadric's median volume error is in the issue's 8–15 % ("such data"; module docstring)
CALIBRATED_CAP_DEG = 180.0
#: caps the benchmark reports by default: the calibrated cap, and the hard one-sided default kept visible beside it
BENCH_CAPS = (CALIBRATED_CAP_DEG, CAP_DEG)
#: emcee steps per bayestouch fit in the benchmark (32 walkers)
BENCH_STEPS = 6000
#: surface samples per shape in the Chamfer distance. For coincident surfaces the estimate is ≈ ½ √(A/count)
#: (chamfer_shapes' docstring): 0.004–0.006 of the mean semi-axis here, well under the 0.03 target
CHAMFER_COUNT = 60_000
#: noise of the contact points, metres (issue 4)
NOISE_M = 3e-4
#: fraction of outliers in the outlier sets and their distance range off the surface, metres (issue 4)
OUTLIER_FRACTION = 0.15
OUTLIER_RANGE_M = (1e-3, 1e-2)

RESULTS = Path(__file__).resolve().parent / "results"


class SparseSet(NamedTuple):
    """One sparse tactile data set.

    Attributes
    ----------
    truth : NEllipsoid
        The true shape (metres, radians).
    points : (M, 3) float, metres
        Noisy contact points, outliers included.
    outlier : (M,) bool
        Which points are outliers.
    strokes : int
        Number of strokes.
    coverage : float
        (1 − cos α_max)/2 for α_max the largest angle between a point's direction and the approach
        direction: the fraction of the sphere of directions in the smallest cap around it holding the data.
    seed : int
    """

    truth: ne.NEllipsoid
    points: np.ndarray
    outlier: np.ndarray
    strokes: int
    coverage: float
    seed: int


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly distributed rotation matrix (3, 3): a normalised Gaussian quaternion (Shoemake 1992)."""
    w, x, y, z = _unit(rng.normal(size=4))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _rotate_towards(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotate unit vector ``v`` by ``angle`` (rad) about unit ``axis`` (Rodrigues)."""
    return v * math.cos(angle) + np.cross(axis, v) * math.sin(angle) + axis * (axis @ v) * (1 - math.cos(angle))


def _surface_along(s: ne.NEllipsoid, directions):
    """Surface points (…, 3) m of ``s`` along local ``directions`` (…, 3): eq. 4 radially, then eq. 5–6."""
    return ne.surface_point(s, ne.unit_nsphere(directions, s.n))


def distance_to_surface(s: ne.NEllipsoid, points):
    """First-order signed distance (…,) m of world ``points`` (…, 3) m to the surface of ``s`` (> 0 outside)."""
    return ne.first_order_distance(s, ne.to_local(s, points))[0]


def make_sparse_set(
    seed: int,
    *,
    outliers: bool = False,
    n_points: int | None = None,
    strokes: int | None = None,
    cap_deg: float = CAP_DEG,
) -> SparseSet:
    """A random true n-ellipsoid and sparse, noisy contact points along a few strokes over part of it.

    Each stroke is a great-circle arc of the unit sphere of directions whose midpoint lies within
    ``cap_deg / 2`` of the approach direction h and whose half-length is uniform in ``[¼, ½] cap_deg``, so every
    direction lies within ``cap_deg`` of h; directions are mapped radially onto the unit n-sphere and then by
    eq. 5–6 onto the surface (:func:`~bayestouch.geometry.nellipsoid.surface_point`). At ``cap_deg = 180`` the
    midpoints fill the hemisphere around h and a stroke spans up to half a great circle, so strokes wrap round the
    object and reach its far side. The true shape, M and the number of strokes do not depend on ``cap_deg`` (the
    same random draws, in the same order), so sets of one seed at different caps are paired.

    Parameters
    ----------
    seed : int
        Seeds everything (``np.random.default_rng(seed)``).
    outliers : bool
        Replace ``round(0.15 M)`` points by outliers 1–10 mm off the surface (outward along the normal
        for half of them, in a uniformly random direction for the others).
    n_points : int, optional
        Total points M (default uniform in 35–100).
    strokes : int, optional
        Number of strokes (default uniform in 2–5).
    cap_deg : float
        Half-angle of the cap of directions around h that holds every stroke, degrees in (0, 180]
        (default :data:`CAP_DEG`; 180: anywhere on the object).

    Returns
    -------
    SparseSet

    Raises
    ------
    BadInput
        When ``cap_deg`` is outside (0, 180].
    """
    rng = np.random.default_rng(seed)
    axes = rng.uniform(0.015, 0.05, 3)
    n = rng.uniform(2.0, 5.0)
    R = _random_rotation(rng)
    angles = np.asarray(euler_from_matrix(jnp.asarray(R)))
    truth = ne.NEllipsoid(
        jnp.asarray(rng.uniform(-0.05, 0.05, 3)), jnp.asarray(axes), jnp.asarray(angles), jnp.asarray(n)
    )
    m = int(rng.integers(35, 101)) if n_points is None else int(n_points)
    k = int(rng.integers(2, 6)) if strokes is None else int(strokes)
    h = _unit(rng.normal(size=3))
    if not 0 < cap_deg <= 180:
        raise BadInput(f"cap_deg must be a half-angle in (0, 180] degrees, got {cap_deg!r}")
    half = math.radians(cap_deg) / 2
    counts = np.full(k, m // k) + (np.arange(k) < m % k)
    dirs = []
    for c in counts:
        # midpoint: h turned by an angle ≤ half (uniform by area in that cap) about a random axis ⟂ h
        t = math.acos(1 - rng.uniform() * (1 - math.cos(half)))
        mid = _rotate_towards(h, _unit(np.cross(h, rng.normal(size=3))), t)
        along = _unit(np.cross(mid, rng.normal(size=3)))  # great circle through mid, random heading
        s = rng.uniform(0.5, 1.0) * half
        for u in np.linspace(-s, s, int(c)):
            dirs.append(_rotate_towards(mid, along, u))
    d = np.array(dirs)
    coverage = float((1 - np.min(d @ h)) / 2)
    surf = ne.evaluate(_surface_along, truth, d)
    pts = surf + rng.normal(0.0, NOISE_M, surf.shape)
    bad = np.zeros(m, bool)
    if outliers:
        idx = rng.choice(m, int(round(OUTLIER_FRACTION * m)), replace=False)
        bad[idx] = True
        dist = rng.uniform(*OUTLIER_RANGE_M, len(idx))
        nrm = ne.evaluate(ne.normals, truth, surf[idx])
        rnd = _unit(rng.normal(size=(len(idx), 3)))
        outward = np.arange(len(idx)) < (len(idx) + 1) // 2
        pts[idx] = surf[idx] + dist[:, None] * np.where(outward[:, None], nrm, rnd)
    return SparseSet(truth, pts, bad, k, coverage, int(seed))


def make_sparse_sets(count: int, seed: int = 0, outlier_every: int = 3, cap_deg: float = CAP_DEG) -> list[SparseSet]:
    """``count`` sets with seeds ``1000 seed + i``; every ``outlier_every``-th set (i mod k = k − 1) has outliers;
    strokes within ``cap_deg`` of each set's approach direction (:func:`make_sparse_set`)."""
    return [
        make_sparse_set(1000 * seed + i, outliers=(i % outlier_every == outlier_every - 1), cap_deg=cap_deg)
        for i in range(count)
    ]


# ---------------------------------------------------------------------------------------- superquadrics


def superquadric_volume(a1: float, a2: float, a3: float, eps1: float, eps2: float) -> float:
    """Volume of a superquadric, m³: 2 a1 a2 a3 ε1 ε2 B(ε1/2 + 1, ε1) B(ε2/2, ε2/2) (Jaklič, Leonardis &
    Solina 2000, "Segmentation and Recovery of Superquadrics", ch. 2; checked in the tests against the
    n-ellipsoid closed form and against the volume of a fine mesh).

    With ε1 = ε2 = 2/n it is the n-ellipsoid's 8abc Γ(1 + 1/n)³ / Γ(1 + 3/n).
    """

    def beta(x, y):
        return math.exp(math.lgamma(x) + math.lgamma(y) - math.lgamma(x + y))

    return 2 * a1 * a2 * a3 * eps1 * eps2 * beta(eps1 / 2 + 1, eps1) * beta(eps2 / 2, eps2 / 2)


def _sage_rotation(p: dict) -> np.ndarray:
    """sage-superquadric's rotation (world = centre + R local): scipy's ``from_euler('zyx', [yaw, pitch, roll])``."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("zyx", [p["yaw"], p["pitch"], p["roll"]]).as_matrix()


def superquadric_mesh(p: dict, res: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Watertight mesh of a superquadric in sage-superquadric's parametrisation, metres.

    F(x) = ((|x/a1|^(2/ε2) + |y/a2|^(2/ε2))^(ε2/ε1) + |z/a3|^(2/ε1)) is homogeneous of degree 2/ε1, so the
    surface point along a direction d is d F(d)^(−ε1/2); directions from the cube-sphere grid.

    Parameters
    ----------
    p : dict
        ``a1, a2, a3`` (m), ``eps1, eps2``, ``cx, cy, cz`` (m), ``roll, pitch, yaw`` (rad).
    res : int
        Cube-sphere cells per edge.

    Returns
    -------
    vertices : (V, 3) float, metres
    faces : (F, 3) int, outward
    """
    d, faces = cube_sphere(res)
    d = _unit(d)
    e1, e2 = p["eps1"], p["eps2"]
    x, y, z = (np.abs(d[:, i] / p[k]) for i, k in enumerate(("a1", "a2", "a3")))
    F = (x ** (2 / e2) + y ** (2 / e2)) ** (e2 / e1) + z ** (2 / e1)
    local = d * F[:, None] ** (-e1 / 2)
    return local @ _sage_rotation(p).T + np.array([p["cx"], p["cy"], p["cz"]]), faces


# ---------------------------------------------------------------------------------------- the methods


def shape_errors(estimate, volume: float, truth: ne.NEllipsoid, seed: int = 0) -> dict:
    """Volume error |V̂/V − 1| and Chamfer distance / true mean semi-axis of an estimate.

    Parameters
    ----------
    estimate : NEllipsoid or (vertices (V, 3) m, faces (F, 3))
    volume : float, m³
        The estimate's volume.
    truth : NEllipsoid

    Returns
    -------
    dict
        ``volume_error`` and ``chamfer_ratio`` (dimensionless), ``chamfer_m`` (metres).
    """
    v_true = float(ne.volume(truth))
    ch = chamfer_shapes(estimate, truth, count=CHAMFER_COUNT, seed=seed)
    return {
        "volume_error": abs(volume / v_true - 1.0),
        "chamfer_ratio": ch / float(np.mean(truth.axes)),
        "chamfer_m": ch,
    }


def fit_bayestouch(points, seed: int = 0, *, steps: int = 2000, walkers: int = 32, run_folder: bool = False) -> dict:
    """bayestouch's contact-level posterior of ``points (M, 3)`` m and two point estimates.

    With ``run_folder`` the whole :func:`bayestouch.inference.run.run_contact_fit` runs (in a temporary folder,
    writing every output); without, the same initialisation (:func:`~bayestouch.inference.run.initial_theta`),
    log-probability and emcee engine (:func:`bayestouch.inference.sampler.sample`, adaptive, for the full ``steps``:
    no early stop) run without the run folder's
    summaries, predictive draws and meshes (≈ 30 s a set of their own, not part of the inference).

    Returns
    -------
    dict
        ``mean``: the posterior-mean shape (mean of the canonicalised natural parameters, as in the summary);
        ``median_volume``: the posterior draw whose volume is the posterior median; ``volume_median``: that
        volume (m³); ``volume_mean``: the posterior-mean volume (m³); ``draws``: (S, 10) canonicalised shape
        vectors; ``volumes``: (S,) their volumes (m³); ``seconds``; ``tau_max``: emcee's largest integrated
        autocorrelation time (steps).
    """
    from scipy.special import gammaln

    from bayestouch.inference import contact as cm
    from bayestouch.inference import run as rn
    from bayestouch.inference.sampler import sample

    points = np.asarray(points, dtype=np.float64)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bt-sparse-") as tmp:
        if run_folder:
            import xarray as xr

            summ = rn.run_contact_fit(points, Path(tmp), seed=seed, walkers=walkers, steps=steps, progress=False)
            with xr.open_dataset(Path(tmp) / "posterior.nc", group="posterior") as ds:
                draws = np.column_stack([np.asarray(ds[k]).ravel() for k in rn.NATURAL_NAMES[:10]])
            tau = float(summ["diagnostics"].get("autocorr_time_max", float("nan")))
        else:
            priors = cm.load_priors()
            logp, bounds = cm.make_log_prob(points, priors)

            def start():
                theta0 = rn.initial_theta(points, seed, priors)
                return rn.start_ball(theta0, bounds, walkers, np.random.default_rng(seed))

            ch = sample(
                logp,
                start,
                Path(tmp) / "chain.h5",
                walkers=walkers,
                ndim=len(cm.PARAM_NAMES),
                seed=seed,
                steps=steps,
                progress=False,
                adapt=True,  # as run_contact_fit samples
            )
            draws = rn.natural_draws(ch.kept.reshape(-1, ch.kept.shape[-1]))[:, :10]
            tau = ch.tau_max
    seconds = time.perf_counter() - t0
    mean = ne.from_vector(jnp.asarray(draws.mean(axis=0)))
    axes, n = draws[:, 3:6], draws[:, 9]
    vols = 8 * axes.prod(axis=1) * np.exp(3 * gammaln(1 + 1 / n) - gammaln(1 + 3 / n))  # ne.volume, vectorised
    i = int(np.argsort(vols)[len(vols) // 2])
    return {
        "mean": mean,
        "median_volume": ne.from_vector(jnp.asarray(draws[i])),
        "volume_median": float(vols[i]),
        "volume_mean": float(vols.mean()),
        "draws": draws,
        "volumes": vols,
        "seconds": seconds,
        "tau_max": tau,
    }


def fit_sage(points) -> dict:
    """sage-superquadric's single-superquadric fit (``sage_superquadrics.superquadric.fit_superquadric`` with its
    default settings: bounded trust-region least squares on its radial residual, soft-L1 loss).

    Returns
    -------
    dict
        ``params`` (its parameter dict), ``mesh`` (vertices, faces), ``volume`` (m³), ``seconds``.

    Raises
    ------
    ImportError
        When the package is not installed.
    """
    from sage_superquadrics.superquadric import fit_superquadric

    t0 = time.perf_counter()
    p, _ = fit_superquadric(np.asarray(points, dtype=np.float64))
    seconds = time.perf_counter() - t0
    p = {k: float(v) for k, v in p.items()}
    return {
        "params": p,
        "mesh": superquadric_mesh(p),
        "volume": superquadric_volume(p["a1"], p["a2"], p["a3"], p["eps1"], p["eps2"]),
        "seconds": seconds,
    }


# ---------------------------------------------------------------------------------------- benchmark


def _summary_rows(rows: list[dict], method: str, key: str, subset: str, cap: float) -> list[dict]:
    vol = np.array([r[f"{key}_volume_error"] for r in rows])
    ch = np.array([r[f"{key}_chamfer_ratio"] for r in rows])
    ok = np.isfinite(vol) & np.isfinite(ch)
    if not ok.any():
        return []
    vol, ch = vol[ok], ch[ok]
    tag = f" (cap {cap:g}°)" if subset == "all" else f" (cap {cap:g}°, {subset})"
    both = (vol <= VOLUME_TARGET) & (ch <= CHAMFER_TARGET)
    common = {"method": method, "sets": int(ok.sum()), "subset": subset, "cap_deg": cap}
    return [
        {
            "metric": f"median volume error{tag}",
            "value": float(np.median(vol)),
            "unit": "1",
            "target": VOLUME_TARGET,
            **common,
        },
        {
            "metric": f"median Chamfer / mean semi-axis{tag}",
            "value": float(np.median(ch)),
            "unit": "1",
            "target": CHAMFER_TARGET,
            **common,
        },
        {
            "metric": f"fraction of sets within both targets{tag}",
            "value": float(both.mean()),
            "unit": "1",
            "target": None,
            **common,
        },
    ]


def _caps(cap_deg) -> tuple[float, ...]:
    """The caps to run: ``cap_deg`` (a number or a sequence), else ``$BAYESTOUCH_SPARSE_CAP`` (comma-separated
    degrees), else :data:`BENCH_CAPS`."""
    if cap_deg is None:
        env = os.environ.get("BAYESTOUCH_SPARSE_CAP", "").strip()
        if not env:
            return BENCH_CAPS
        try:
            cap_deg = [float(c) for c in env.split(",") if c.strip()]
        except ValueError:
            raise BadInput(
                f"BAYESTOUCH_SPARSE_CAP must be comma-separated degrees in (0, 180], e.g. '180,100'; got {env!r}"
            ) from None
    caps = (float(cap_deg),) if np.ndim(cap_deg) == 0 else tuple(float(c) for c in cap_deg)
    bad = [c for c in caps if not 0 < c <= 180]
    if not caps or bad:
        raise BadInput(f"cap_deg must be one or more half-angles in (0, 180] degrees, got {cap_deg!r}")
    return caps


def _fit_one(d: SparseSet, i: int, cap: float, steps: int, seed: int, with_sage: bool) -> dict:
    """Both methods on one set: the per-set CSV row."""
    truth_v = float(ne.volume(d.truth))
    row = {
        "cap_deg": cap,
        "set": i,
        "seed": d.seed,
        "outliers": bool(d.outlier.any()),
        "points": len(d.points),
        "strokes": d.strokes,
        "coverage": d.coverage,
        "n_true": float(d.truth.n),
        "mean_axis_m": float(np.mean(d.truth.axes)),
        "volume_m3": truth_v,
        "chamfer_floor": shape_errors(d.truth, truth_v, d.truth, seed=i + 1)["chamfer_ratio"],
    }
    fit = fit_bayestouch(d.points, seed=seed + i, steps=steps)
    med = shape_errors(fit["median_volume"], fit["volume_median"], d.truth, seed=i)
    mean = shape_errors(fit["mean"], float(ne.volume(fit["mean"])), d.truth, seed=i)
    row.update(
        {
            "bt_seconds": fit["seconds"],
            "bt_tau_max": fit["tau_max"],
            "bt_volume_error": med["volume_error"],
            "bt_chamfer_ratio": med["chamfer_ratio"],
            "bt_mean_volume_error": mean["volume_error"],
            "bt_mean_chamfer_ratio": mean["chamfer_ratio"],
            "bt_mean_volume_summary_error": abs(fit["volume_mean"] / truth_v - 1.0),
            "bt_truth_volume_quantile": float(np.mean(fit["volumes"] < truth_v)),
        }
    )
    if with_sage:
        try:
            sq = fit_sage(d.points)
            e = shape_errors(sq["mesh"], sq["volume"], d.truth, seed=i)
            row.update(
                {
                    "sage_seconds": sq["seconds"],
                    "sage_volume_error": e["volume_error"],
                    "sage_chamfer_ratio": e["chamfer_ratio"],
                    "sage_eps1": sq["params"]["eps1"],
                    "sage_eps2": sq["params"]["eps2"],
                    "sage_error": "",
                }
            )
        except Exception as exc:  # noqa: BLE001 - a crash of the peer is a result, recorded as such
            row.update(
                {
                    "sage_volume_error": float("nan"),
                    "sage_chamfer_ratio": float("nan"),
                    "sage_error": f"{type(exc).__name__}: {exc}"[:200],
                }
            )
    print(
        f"cap {cap:g}° set {i}: bt vol {row['bt_volume_error']:.3f} ch {row['bt_chamfer_ratio']:.3f} "
        f"(τ {row['bt_tau_max']:.0f}, {row['bt_seconds']:.0f} s); sage vol {row.get('sage_volume_error', np.nan):.3f} "
        f"ch {row.get('sage_chamfer_ratio', np.nan):.3f}",
        flush=True,
    )
    return row


def bench_sparse(
    sets: int | None = None,
    steps: int | None = None,
    seed: int = 0,
    csv_path: Path | None = RESULTS / "sparse_sets.csv",
    cap_deg=None,
) -> list[dict]:
    """Fit every sparse set with bayestouch and with sage-superquadric, per cap; medians and fractions within target.

    Parameters
    ----------
    sets : int, optional
        Number of data sets per cap (default ``$BAYESTOUCH_SPARSE_SETS`` or 10). The sets of one seed are the same
        shapes at every cap (:func:`make_sparse_set`), so the caps are compared on paired data.
    steps : int, optional
        emcee steps per bayestouch fit (default ``$BAYESTOUCH_SPARSE_STEPS`` or :data:`BENCH_STEPS`; 32 walkers).
    seed : int
        Seed of the data sets (and of the fits).
    csv_path : Path or None
        Where to write the per-set table of every cap (:func:`bayestouch.io.files.write_csv_rows`); None: not written.
    cap_deg : float or sequence of float, optional
        Caps of the strokes, degrees (default ``$BAYESTOUCH_SPARSE_CAP``, comma-separated, or :data:`BENCH_CAPS`:
        the calibrated cap and the hard default).

    Returns
    -------
    list of dict
        ``{"metric", "value", "unit", "method", "sets", "target", "cap_deg", ...}``, one group per cap.

    Raises
    ------
    BadInput
        When a cap is outside (0, 180] degrees.
    """
    from bayestouch.io.files import write_csv_rows

    caps = _caps(cap_deg)
    sets = int(os.environ.get("BAYESTOUCH_SPARSE_SETS", 10)) if sets is None else int(sets)
    steps = int(os.environ.get("BAYESTOUCH_SPARSE_STEPS", BENCH_STEPS)) if steps is None else int(steps)
    try:
        import sage_superquadrics

        sage_note = f"sage-superquadric {getattr(sage_superquadrics, '__version__', '?')}"
    except ImportError as e:
        sage_superquadrics, sage_note = None, f"not installed ({e}); pip install sage-superquadric"
    with_sage = sage_superquadrics is not None

    per_set, out = [], []
    for cap in caps:
        rows = [
            _fit_one(d, i, cap, steps, seed, with_sage) for i, d in enumerate(make_sparse_sets(sets, seed, cap_deg=cap))
        ]
        per_set += rows
        for subset, sub in (("all", rows), ("outlier sets", [r for r in rows if r["outliers"]])):
            out += _summary_rows(sub, "bayestouch", "bt", subset, cap)
            out += _summary_rows(sub, "bayestouch (posterior-mean shape)", "bt_mean", subset, cap)
            if with_sage:
                out += _summary_rows(sub, "sage-superquadric", "sage", subset, cap)
        common = {"sets": len(rows), "target": None, "cap_deg": cap}
        out.append(
            {
                "metric": f"median coverage (cap {cap:g}°)",
                "value": float(np.median([r["coverage"] for r in rows])),
                "unit": "1",
                "method": "data",
                **common,
            }
        )
        out.append(
            {
                "metric": f"largest autocorrelation time (median; cap {cap:g}°)",
                "value": float(np.median([r["bt_tau_max"] for r in rows])),
                "unit": "steps",
                "method": "bayestouch",
                "steps": steps,
                **common,
            }
        )
    if csv_path is not None:
        write_csv_rows(csv_path, per_set)

    out.append(
        {
            "metric": "seconds per set (median)",
            "value": float(np.median([r["bt_seconds"] for r in per_set])),
            "unit": "s",
            "method": "bayestouch",
            "sets": len(per_set),
            "target": None,
            "steps": steps,
            "walkers": 32,
        }
    )
    if not with_sage:
        out.append(
            {
                "metric": "median volume error",
                "value": float("nan"),
                "unit": "1",
                "method": "sage-superquadric",
                "sets": 0,
                "target": VOLUME_TARGET,
                "note": sage_note,
            }
        )
    else:
        errs = [r["sage_error"] for r in per_set if r.get("sage_error")]
        out.append(
            {
                "metric": "seconds per set (median)",
                "value": float(np.median([r.get("sage_seconds", np.nan) for r in per_set])),
                "unit": "s",
                "method": "sage-superquadric",
                "sets": len(per_set),
                "target": None,
                "note": sage_note + (f"; {len(errs)} fits crashed: {errs[0]}" if errs else ""),
            }
        )
    return out
