"""Shape posteriors on data like users' touch data (issue "Shape posteriors that hold up on real touch data"):
sparse, one-sided, contaminated contact sets; bayestouch's default contact-level fit against the least-squares
superquadric peer ``sage-superquadric`` and a Gaussian-process implicit surface (:mod:`bayestouch.inference.gpis`).

Data (:func:`make_user_set`; every length in metres, every angle in radians unless the name says degrees). Each
set is drawn from ``np.random.default_rng(seed)``, split with ``Generator.spawn`` into independent streams for the
shape, the strokes, the noise, the displaced contacts and the free-space samples, so a seed always gives the same
set and overriding one component (e.g. ``outlier_fraction=0``) leaves the others as they were:

* **shape**: an n-ellipsoid with n ~ U[2, 6]; semi-axes i.i.d. U[12, 40] mm conditioned on max/min ≤ 3
  (rejection); orientation uniform on SO(3) (Haar measure: a normalised Gaussian quaternion, Shoemake 1992;
  :func:`random_rotations`); centre uniform in [−5, 5] cm³;
* **strokes**: M ~ U{60..100} contacts (40–120 via ``n_points``) along K ~ U{4..6} finger strokes. Stroke s is a
  great-circle arc of *world* directions from the true centre, of length L_s ~ U[0.6, 1.4] rad, each direction
  mapped radially onto the surface (the surface point of the object along that ray: :func:`radial_surface_point`),
  so a stroke is an arc of the planar section of the surface by a plane through the centre. The contacts of a
  stroke (their number ∝ L_s) sit at its two ends and, in between, one in each of equal steps of the arc at a
  uniformly random place within it. Every contact direction lies within a cap of half-angle α ~ U[100°, 180°]
  (drawn per set; 180°: anywhere on the object) around a uniformly random approach direction h: each stroke's
  midpoint is uniform by area in the cap and its heading uniform, redrawn until the whole stroke lies in the cap;
* **noise**: isotropic Gaussian, 0.3 mm sd per coordinate, on every contact;
* **displaced contacts**: a fraction f ~ U[0, 0.15] per set (round(f M) contacts, chosen uniformly) moved
  δ ~ U[3, 10] mm along the true outward normal, inwards or outwards with probability ½ each: inwards, a point
  inside the solid (the finger pressed into something softer, or a mis-registered contact); outwards, a phantom
  contact in free space. A displacement that does not end on its side of the surface (an inward one through a
  thin part) is redrawn;
* **free space**: along the approach to the first contact of every stroke, 5 finger positions 3–30 mm from it,
  on a line tilted U[0°, 30°] from the outward normal (so in the open half-space beyond the tangent plane: outside
  a convex solid), with the same noise; a sample the noise would put inside is redrawn.

How these sets differ from :mod:`benchmarks.bench_sparse`'s: there the arcs are of the *parametric* directions
(mapped onto the unit n-sphere before scaling by the semi-axes; here the rays are physical directions from the
centre, so α and L are angles an observer at the centre would see), the cap is fixed per benchmark run (100° or
180°) rather than drawn per set, strokes are 2–5 with lengths tied to the cap rather than 4–6 arcs of
0.6–1.4 rad, semi-axes 15–50 mm without a ratio bound rather than 12–40 mm with ratios ≤ 3, n ∈ [2, 5], and every
third set has exactly 15 % outliers (half outward along the normal, half in a random direction, 1–10 mm), whereas
here every set has 0–15 %, of both signs, 3–10 mm along the normal; and there are no free-space samples.

Methods: **bayestouch** through its default contact-level path
:func:`bayestouch.inference.run.run_contact_fit` (default settings: tempered SMC from the prior checked against
the polished optimum, then emcee, 32 walkers, outlier noise model, the 60 s budget, free-space positions given)
into a temporary run folder, point estimate the summary's posterior-mean shape (``derived.mean_shape``, the shape
of ``mean_shape.ply``), volume the summary's posterior-mean volume; **sage** its default
single-superquadric fit (:func:`benchmarks.bench_sparse.fit_sage`); **gpis** :func:`bayestouch.inference.gpis.fit_gpis`.

Metrics per set and method: volume error |V̂/V − 1| (closed forms for the truth and the superquadric, the mesh
volume for GPIS, the posterior-mean volume for bayestouch); symmetric Chamfer distance between the surfaces by
exact point-to-surface distances (:func:`bayestouch.geometry.compare.chamfer_surfaces`, :data:`CHAMFER_COUNT`
samples per surface) divided by the true mean semi-axis; wall time. For bayestouch also whether the 90 % interval
(q05, q95) of the volume and of each semi-axis (canonical order, largest first, against the sorted true axes)
covers the truth, z-scores (posterior mean − truth)/sd, the convergence flag, the largest R-hat, the smallest bulk
ESS, the steps run, and whether the posterior reaches the prior's box (an axis's q95 above half ``axis_max``, or n
at its bounds; ``models/priors.toml``).

Summary (:func:`bench_user_sets`): per method the medians with percentile-bootstrap 95 % intervals
(:func:`bootstrap_median`, seed 0, :data:`BOOTSTRAP_RESAMPLES` resamples) of the volume error and the Chamfer
ratio, a failed fit counting as an infinite error; bayestouch's coverage fractions with Wilson 95 % intervals
(:func:`wilson_interval`) and the number of converged fits; time median and 95th percentile. Outputs:
``benchmarks/results/user_sets.csv`` (a row per set and method), ``user_sets.json``, ``user_sets.md``.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks bench_user_sets`` (``BAYESTOUCH_USER_SETS`` sets the count, default
50; ``BAYESTOUCH_USER_STEPS`` caps bayestouch's steps, default run_contact_fit's own).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
import tomllib
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.rotation import euler_from_matrix
from benchmarks.bench_sparse import fit_sage

__all__ = [
    "UserSet",
    "make_user_set",
    "make_user_sets",
    "random_rotations",
    "draw_axes",
    "radial_surface_point",
    "bootstrap_median",
    "wilson_interval",
    "fit_bayestouch_default",
    "bayestouch_metrics",
    "shape_metrics",
    "fit_set",
    "summarise",
    "markdown_table",
    "bench_user_sets",
    "METHODS",
]

#: exponent range of the true n-ellipsoids
N_RANGE = (2.0, 6.0)
#: semi-axis range, metres
AXIS_RANGE_M = (0.012, 0.040)
#: largest ratio of two semi-axes of one shape
MAX_AXIS_RATIO = 3.0
#: half-width of the cube of centres, metres
CENTRE_RANGE_M = 0.05
#: contacts per set: default draw (inclusive) and the range allowed through ``n_points``
POINTS_RANGE = (60, 100)
POINTS_ALLOWED = (40, 120)
#: strokes per set (inclusive)
STROKES_RANGE = (4, 6)
#: length of a stroke's arc of directions, radians
ARC_RANGE_RAD = (0.6, 1.4)
#: half-angle of the cap of directions holding every stroke, degrees
CAP_RANGE_DEG = (100.0, 180.0)
#: contact noise sd per coordinate, metres
NOISE_M = 3e-4
#: largest fraction of displaced contacts, and their displacement range along the normal, metres
OUTLIER_FRACTION_MAX = 0.15
OUTLIER_RANGE_M = (3e-3, 1e-2)
#: free-space samples per stroke, their distance range from the first contact (m) and the approach's largest tilt
FREE_PER_STROKE = 5
FREE_RANGE_M = (3e-3, 3e-2)
FREE_TILT_MAX_RAD = math.radians(30.0)
#: redraws allowed for a conditioned draw before giving up
MAX_REDRAWS = 1000

#: methods of the benchmark
METHODS = ("bayestouch", "sage", "gpis")
#: surface samples per shape in the exact Chamfer distance
CHAMFER_COUNT = 4000
#: bootstrap resamples of the medians' intervals
BOOTSTRAP_RESAMPLES = 4000
#: nominal level of bayestouch's intervals in the summary (q05–q95)
INTERVAL_LEVEL = 0.90

RESULTS = Path(__file__).resolve().parent / "results"
PRIORS_TOML = Path(__file__).resolve().parents[1] / "models" / "priors.toml"


class UserSet(NamedTuple):
    """One synthetic contact set like users' touch data (:func:`make_user_set`).

    Attributes
    ----------
    truth : NEllipsoid
        The true shape (centre (3,) m, semi-axes (3,) m, Euler angles (3,) rad, n).
    points : (M, 3) float, metres
        Contacts in stroke order, noise and displaced contacts included.
    outlier : (M,) bool
        Which contacts are displaced.
    outlier_sign : (M,) int
        +1 displaced outwards (in free space), −1 inwards (inside the solid), 0 not displaced.
    free_space : (K, 3) float, metres
        Finger positions on the approach of each stroke, known to be outside the solid (K = 5 × strokes).
    strokes : int
        Number of strokes.
    coverage : float
        (1 − cos β)/2 for β the largest angle between a contact's direction (from the true centre, before noise)
        and the approach direction: the fraction of the sphere of directions in the smallest cap about it
        holding the data.
    cap_deg : float, degrees
        Half-angle α of the cap the strokes were drawn in.
    seed : int
    stroke : (M,) int
        Stroke of each contact.
    arcs : (strokes,) float, radians
        Length of each stroke's arc of directions.
    approach : (3,) float
        Unit approach direction h (the cap's axis), world frame.
    outlier_fraction : float
        The drawn fraction f of displaced contacts (round(f M) of them are).
    """

    truth: ne.NEllipsoid
    points: np.ndarray
    outlier: np.ndarray
    outlier_sign: np.ndarray
    free_space: np.ndarray
    strokes: int
    coverage: float
    cap_deg: float
    seed: int
    stroke: np.ndarray
    arcs: np.ndarray
    approach: np.ndarray
    outlier_fraction: float


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_rotations(rng: np.random.Generator, count: int) -> np.ndarray:
    """Rotation matrices (count, 3, 3) uniform on SO(3) (Haar measure): unit quaternions from normalised
    4-D Gaussians (uniform on S³, which double-covers SO(3); Shoemake 1992, "Uniform random rotations").

    Parameters
    ----------
    rng : numpy.random.Generator
    count : int

    Returns
    -------
    (count, 3, 3) float
        Proper rotations; column j is the rotated j-th axis.
    """
    w, x, y, z = unit(rng.normal(size=(int(count), 4))).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def draw_axes(rng: np.random.Generator) -> np.ndarray:
    """Semi-axes (3,) m: i.i.d. U[12, 40] mm, redrawn until max/min ≤ :data:`MAX_AXIS_RATIO`.

    Raises
    ------
    RuntimeError
        After :data:`MAX_REDRAWS` rejections (probability ≈ 0.12 each: not in practice).
    """
    for _ in range(MAX_REDRAWS):
        a = rng.uniform(*AXIS_RANGE_M, 3)
        if a.max() <= MAX_AXIS_RATIO * a.min():
            return a
    raise RuntimeError("draw_axes: no semi-axes within the ratio bound")


def radial_surface_point(s: ne.NEllipsoid, directions):
    """The surface point of ``s`` along each world ray ``directions`` (…, 3) from its centre, metres.

    The local direction q = Rᵀ d is scaled to the unit n-sphere radially (eq. 4 on q / a) and mapped by eq. 5–6:
    y = u + R (a ∘ Y) with Y ∝ q / a, so y − u ∝ R q = d.
    """
    q = jnp.asarray(directions) @ s.rotation
    return ne.surface_point(s, ne.unit_nsphere(q / s.axes, s.n))


def stroke_counts(m: int, arcs: np.ndarray) -> np.ndarray:
    """Contacts per stroke ∝ its arc length (largest remainders), each ≥ 2."""
    share = m * arcs / arcs.sum()
    counts = np.floor(share).astype(int)
    counts[np.argsort(-(share - counts), kind="stable")[: m - counts.sum()]] += 1
    while (counts < 2).any():  # only for extreme overrides: take from the largest stroke
        counts[np.argmin(counts)] += 1
        counts[np.argmax(counts)] -= 1
    return counts


def stroke_directions(rng: np.random.Generator, h: np.ndarray, cap: float, arc: float, count: int) -> np.ndarray:
    """Unit directions (count, 3) along one great-circle arc of length ``arc`` (rad) lying in the cap of half-angle
    ``cap`` (rad) about ``h``: both ends, and one contact in each equal step of the arc in between."""
    u = np.linspace(-arc / 2, arc / 2, count)
    if count > 2:
        u[1:-1] += (rng.uniform(size=count - 2) - 0.5) * arc / (count - 1)
    for _ in range(MAX_REDRAWS):
        # midpoint uniform by area in the cap: cos t uniform in [cos cap, 1]
        t = math.acos(1.0 - rng.uniform() * (1.0 - math.cos(cap)))
        side = unit(np.cross(h, rng.normal(size=3)))
        mid = h * math.cos(t) + side * math.sin(t)
        heading = unit(np.cross(mid, rng.normal(size=3)))  # uniform unit tangent at mid
        d = mid[None, :] * np.cos(u)[:, None] + heading[None, :] * np.sin(u)[:, None]
        if np.min(d @ h) >= math.cos(cap) - 1e-12:
            return d
    raise RuntimeError("stroke_directions: no stroke fits in the cap")


def _check_range(name: str, value: float, lo: float, hi: float) -> float:
    value = float(value)
    if not lo <= value <= hi:
        raise ValueError(f"make_user_set: {name} must lie in [{lo:g}, {hi:g}], got {value!r}")
    return value


def make_user_set(
    seed: int,
    *,
    n: float | None = None,
    axes=None,
    n_points: int | None = None,
    strokes: int | None = None,
    cap_deg: float | None = None,
    outlier_fraction: float | None = None,
    noise_m: float = NOISE_M,
) -> UserSet:
    """A random true n-ellipsoid and a sparse, one-sided, contaminated contact set on it (module docstring).

    Every quantity is drawn in the same order whatever the overrides (an override replaces the drawn value), from
    independent streams of ``np.random.default_rng(seed)`` per component, so sets of one seed are paired across
    overrides of a later component.

    Parameters
    ----------
    seed : int
        Seeds everything.
    n : float, optional
        Exponent of the true shape, ≥ 1 (convex: the free-space and outward guarantees need it); default U[2, 6].
    axes : (3,) float, optional, metres
        Semi-axes, > 0; default U[12, 40] mm with ratios ≤ 3.
    n_points : int, optional
        Contacts M in [40, 120]; default U{60..100}.
    strokes : int, optional
        Number of strokes in [1, 20]; default U{4..6}.
    cap_deg : float, optional, degrees
        Half-angle of the cap of directions, in [60, 180]; default U[100, 180].
    outlier_fraction : float, optional
        Fraction of displaced contacts in [0, 0.5]; default U[0, 0.15].
    noise_m : float, metres
        Contact (and free-space) noise sd, ≥ 0.

    Returns
    -------
    UserSet

    Raises
    ------
    ValueError
        An override outside its range.
    """
    r_shape, r_strokes, r_noise, r_out, r_free = np.random.default_rng(seed).spawn(5)

    # ---- shape
    n_draw = r_shape.uniform(*N_RANGE)
    axes_draw = draw_axes(r_shape)
    R = random_rotations(r_shape, 1)[0]
    centre = r_shape.uniform(-CENTRE_RANGE_M, CENTRE_RANGE_M, 3)
    n = n_draw if n is None else _check_range("n", n, 1.0, 64.0)
    axes = axes_draw if axes is None else np.asarray(axes, dtype=np.float64)
    if axes.shape != (3,) or not (axes > 0).all():
        raise ValueError(f"make_user_set: axes must be three positive lengths in metres, got {axes!r}")
    angles = np.asarray(euler_from_matrix(jnp.asarray(R)))
    truth = ne.NEllipsoid(jnp.asarray(centre), jnp.asarray(axes), jnp.asarray(angles), jnp.asarray(float(n)))

    # ---- strokes
    m = int(r_strokes.integers(POINTS_RANGE[0], POINTS_RANGE[1] + 1))
    k = int(r_strokes.integers(STROKES_RANGE[0], STROKES_RANGE[1] + 1))
    cap = r_strokes.uniform(*CAP_RANGE_DEG)
    h = unit(r_strokes.normal(size=3))
    m = m if n_points is None else int(_check_range("n_points", n_points, *POINTS_ALLOWED))
    k = k if strokes is None else int(_check_range("strokes", strokes, 1, 20))
    cap = cap if cap_deg is None else _check_range("cap_deg", cap_deg, 60.0, 180.0)
    if 2 * k > m:
        raise ValueError(f"make_user_set: {k} strokes need at least {2 * k} contacts, got {m}")
    arcs = r_strokes.uniform(*ARC_RANGE_RAD, k)
    counts = stroke_counts(m, arcs)
    dirs = np.concatenate(
        [stroke_directions(r_strokes, h, math.radians(cap), a, c) for a, c in zip(arcs, counts, strict=True)]
    )
    stroke = np.repeat(np.arange(k), counts)
    coverage = float((1.0 - np.min(dirs @ h)) / 2.0)
    surf = ne.evaluate(radial_surface_point, truth, dirs)
    nrm = ne.evaluate(ne.normals, truth, surf)
    noise_m = _check_range("noise_m", noise_m, 0.0, 1e-2)
    noise = r_noise.normal(0.0, noise_m, surf.shape)
    pts = surf + noise

    # ---- displaced contacts
    frac = r_out.uniform(0.0, OUTLIER_FRACTION_MAX)
    frac = frac if outlier_fraction is None else _check_range("outlier_fraction", outlier_fraction, 0.0, 0.5)
    idx = np.sort(r_out.choice(m, int(round(frac * m)), replace=False))
    sign = np.where(r_out.uniform(size=len(idx)) < 0.5, 1, -1)
    todo = np.ones(len(idx), bool)
    for _ in range(MAX_REDRAWS):
        if not todo.any():
            break
        j = idx[todo]
        pts[j] = surf[j] + noise[j] + (sign[todo] * r_out.uniform(*OUTLIER_RANGE_M, len(j)))[:, None] * nrm[j]
        F = ne.evaluate(ne.inside_outside, truth, pts[idx])
        todo = np.where(sign > 0, F <= 1.0, F >= 1.0)
    else:
        raise RuntimeError("make_user_set: displaced contacts do not end on their side of the surface")
    bad = np.zeros(m, bool)
    bad[idx] = True
    outlier_sign = np.zeros(m, int)
    outlier_sign[idx] = sign

    # ---- free space along the approach of every stroke
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tilt = r_free.uniform(0.0, FREE_TILT_MAX_RAD, k)
    side = unit(np.cross(nrm[first], r_free.normal(size=(k, 3))))
    along = nrm[first] * np.cos(tilt)[:, None] + side * np.sin(tilt)[:, None]
    dist = np.linspace(*FREE_RANGE_M, FREE_PER_STROKE)
    ideal = (surf[first][:, None, :] + dist[None, :, None] * along[:, None, :]).reshape(-1, 3)
    free = ideal.copy()
    todo = np.ones(len(free), bool)
    for _ in range(MAX_REDRAWS):
        if not todo.any():
            break
        free[todo] = ideal[todo] + r_free.normal(0.0, noise_m, (int(todo.sum()), 3))
        todo = ne.evaluate(ne.inside_outside, truth, free) <= 1.0
    else:
        raise RuntimeError("make_user_set: free-space samples do not stay outside")

    return UserSet(
        truth, pts, bad, outlier_sign, free, k, coverage, float(cap), int(seed), stroke, arcs, h, float(frac)
    )


def make_user_sets(count: int, seed: int = 0, **overrides) -> list[UserSet]:
    """``count`` sets (:func:`make_user_set`) with seeds ``1000 seed + i``, i = 0 … count − 1."""
    return [make_user_set(1000 * int(seed) + i, **overrides) for i in range(int(count))]


# ---------------------------------------------------------------------------------------- statistics


def bootstrap_median(values, resamples: int = BOOTSTRAP_RESAMPLES, level: float = 0.95, seed: int = 0):
    """The median of ``values`` and its percentile-bootstrap interval.

    Resamples the values with replacement ``resamples`` times (``np.random.default_rng(seed)``) and takes the
    (1 ∓ level)/2 quantiles of the resampled medians (inverted-CDF quantiles, so +inf values, e.g. failed fits, give
    finite or infinite bounds but never nan).

    Parameters
    ----------
    values : (N,) float
        N ≥ 1; nan is not allowed (count a failure as +inf).
    resamples : int
        ≥ 2000 for the benchmark.
    level : float
        Coverage of the interval, in (0, 1).
    seed : int

    Returns
    -------
    median, lower, upper : float

    Raises
    ------
    ValueError
        On an empty sample or a nan.
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    if x.size == 0 or np.isnan(x).any():
        raise ValueError("bootstrap_median: need at least one value and no nan (count failures as inf)")
    rng = np.random.default_rng(seed)
    meds = np.median(x[rng.integers(0, x.size, (int(resamples), x.size))], axis=1)
    lo, hi = np.quantile(meds, [(1 - level) / 2, (1 + level) / 2], method="inverted_cdf")
    return float(np.median(x)), float(lo), float(hi)


def wilson_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n (Wilson 1927).

    Returns
    -------
    lower, upper : float
        In [0, 1]; (nan, nan) for n = 0.
    """
    from scipy.stats import norm

    if n == 0:
        return float("nan"), float("nan")
    z = float(norm.ppf(0.5 + level / 2))
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, centre - half), min(1.0, centre + half)


# ---------------------------------------------------------------------------------------- methods and metrics


def _prior_box() -> dict:
    """``axis_min``, ``axis_max`` (m), ``n_min``, ``n_max`` of the contact-level prior (``models/priors.toml``)."""
    with open(PRIORS_TOML, "rb") as f:
        pri = tomllib.load(f)["priors"]
    return {k: float(pri[k]["value"]) for k in ("axis_min", "axis_max", "n_min", "n_max")}


def shape_metrics(estimate, volume: float, truth: ne.NEllipsoid, seed: int = 0) -> dict:
    """Volume error and Chamfer ratio of an estimate against the truth.

    Parameters
    ----------
    estimate : NEllipsoid or (vertices (V, 3) m, faces (F, 3))
    volume : float, m³
        The estimate's volume.
    truth : NEllipsoid
    seed : int
        Seed of the Chamfer distance's surface samples.

    Returns
    -------
    dict
        ``volume_est_m3``; ``volume_error`` |V̂/V − 1|; ``chamfer_m`` and ``chamfer_se_m`` (exact surface distances,
        :func:`bayestouch.geometry.compare.chamfer_surfaces`, :data:`CHAMFER_COUNT` samples per surface);
        ``chamfer_ratio`` = chamfer_m / mean true semi-axis.
    """
    from bayestouch.geometry.compare import chamfer_surfaces

    v_true = float(ne.volume(truth))
    ch, se = chamfer_surfaces(estimate, truth, count=CHAMFER_COUNT, seed=seed)
    return {
        "volume_est_m3": float(volume),
        "volume_error": abs(float(volume) / v_true - 1.0),
        "chamfer_m": ch,
        "chamfer_se_m": se,
        "chamfer_ratio": ch / float(np.mean(truth.axes)),
    }


def fit_bayestouch_default(points, seed: int = 0, steps: int | None = None, free=None, size_prior=None) -> dict:
    """bayestouch's default contact-level fit (:func:`bayestouch.inference.run.run_contact_fit`) of ``points``
    (M, 3) m into a temporary run folder, timed.

    Parameters
    ----------
    points : (M, 3) float, metres
    seed : int
    steps : int, optional
        Largest number of emcee steps (default: run_contact_fit's own); every other setting is its default.
    free : (K, 3) float, metres, optional
        Free-space finger positions (what a contact CSV's ``contact = 0`` rows carry).
    size_prior : (2,) float, metres, optional
        The size prior a user states (``--size-prior MIN:MAX``); default ``models/priors.toml``'s.

    Returns
    -------
    dict
        ``summary`` (the run's ``summary.json`` as a dict) and ``seconds`` (wall time of the whole run, outputs
        included).
    """
    from bayestouch.inference.run import run_contact_fit

    kwargs = {} if steps is None else {"steps": int(steps)}
    with tempfile.TemporaryDirectory(prefix="bt-user-") as tmp:
        t0 = time.perf_counter()
        summary = run_contact_fit(
            np.asarray(points, dtype=np.float64),
            Path(tmp),
            seed=seed,
            progress=False,
            free=free,
            size_prior=size_prior,
            **kwargs,
        )
        seconds = time.perf_counter() - t0
    return {"summary": summary, "seconds": seconds}


def bayestouch_metrics(summary: dict, truth: ne.NEllipsoid) -> dict:
    """Calibration and diagnostics of a bayestouch run's summary against the truth.

    Parameters
    ----------
    summary : dict
        ``summary.json`` of a contact-level run.
    truth : NEllipsoid

    Returns
    -------
    dict
        ``volume_covered`` (the 90 % interval q05–q95 holds the true volume), ``volume_z`` ((mean − V)/sd),
        ``volume_q05_m3``/``volume_q95_m3``; per semi-axis j = 0, 1, 2 (largest first, against the sorted true axes)
        ``axis{j}_covered``, ``axis{j}_z``, ``axis{j}_q05_m``/``axis{j}_q95_m``; ``axes_covered`` (all three);
        ``converged``, ``max_r_hat``, ``min_ess_bulk``, ``steps``, ``tau_max`` (steps); ``sigma_m`` (posterior mean
        noise scale); ``n_mean``, ``n_true``; ``at_prior_box`` (an axis's q95 above half ``axis_max``, or n's
        interval touching its bounds to 2 %); ``warnings`` (the run's own, joined).
    """
    par, vol = summary["parameters"], summary["derived"]["volume_m3"]
    diag = summary["diagnostics"]
    v_true = float(ne.volume(truth))
    true_axes = np.sort(np.asarray(truth.axes))[::-1]
    box = _prior_box()
    out = {
        "volume_covered": bool(vol["q05"] <= v_true <= vol["q95"]),
        "volume_z": (vol["mean"] - v_true) / vol["sd"] if vol["sd"] > 0 else float("inf"),
        "volume_q05_m3": vol["q05"],
        "volume_q95_m3": vol["q95"],
    }
    covered = []
    for j, name in enumerate(("a", "b", "c")):
        p = par[name]
        covered.append(p["q05"] <= true_axes[j] <= p["q95"])
        out[f"axis{j}_covered"] = bool(covered[-1])
        out[f"axis{j}_z"] = (p["mean"] - true_axes[j]) / p["sd"] if p["sd"] > 0 else float("inf")
        out[f"axis{j}_q05_m"], out[f"axis{j}_q95_m"] = p["q05"], p["q95"]
    n_lo, n_hi = par["n"]["q05"], par["n"]["q95"]
    out.update(
        {
            "axes_covered": bool(all(covered)),
            "converged": bool(diag["converged"]),
            "max_r_hat": float(diag["max_r_hat"]),
            "min_ess_bulk": float(diag["min_ess_bulk"]),
            "steps": int(diag["steps"]),
            "tau_max": float(diag.get("autocorr_time_max", float("nan"))),
            "sigma_m": float(par["sigma"]["mean"]),
            "n_mean": float(par["n"]["mean"]),
            "n_true": float(truth.n),
            "at_prior_box": bool(
                max(par[a]["q95"] for a in "abc") > 0.5 * box["axis_max"]
                or n_lo <= 1.02 * box["n_min"]
                or n_hi >= 0.98 * box["n_max"]
            ),
            "reach": float(diag["reach"]["median"]) if diag.get("reach") else float("nan"),
            "extrapolated": bool(diag.get("extrapolated", False)),
            "warnings": "; ".join(diag.get("warnings", [])),
        }
    )
    return out


def mean_shape(summary: dict) -> ne.NEllipsoid:
    """The posterior-mean shape of the summary (``derived.mean_shape``, the shape of ``mean_shape.ply``)."""
    return ne.from_vector(jnp.asarray([summary["derived"]["mean_shape"][k] for k in ne.PARAM_NAMES]))


def fit_set(d: UserSet, method: str, index: int = 0, steps: int | None = None, size_prior=None) -> dict:
    """Fit one set with one method: its CSV row.

    Parameters
    ----------
    d : UserSet
    method : {"bayestouch", "sage", "gpis"}
    index : int
        Position of the set in the run (seeds the Chamfer samples).
    steps : int, optional
        bayestouch's largest number of steps (default: run_contact_fit's own).
    size_prior : (2,) float, metres, optional
        bayestouch's size prior (:func:`fit_bayestouch_default`).

    Returns
    -------
    dict
        The set's description, ``method``, ``seconds``, :func:`shape_metrics`' keys (nan with ``error`` set when the
        method failed) and, for bayestouch, :func:`bayestouch_metrics`' keys prefixed ``bt_``.

    Raises
    ------
    ValueError
        An unknown method.
    """
    if method not in METHODS:
        raise ValueError(f"fit_set: unknown method {method!r}; expected one of {METHODS}")
    row = {
        "set": index,
        "seed": d.seed,
        "method": method,
        "points": len(d.points),
        "strokes": d.strokes,
        "cap_deg": d.cap_deg,
        "coverage": d.coverage,
        "outlier_fraction": float(d.outlier.mean()),
        "outliers_out": int((d.outlier_sign > 0).sum()),
        "outliers_in": int((d.outlier_sign < 0).sum()),
        "n_true": float(d.truth.n),
        "mean_axis_m": float(np.mean(d.truth.axes)),
        "axis_ratio": float(np.max(d.truth.axes) / np.min(d.truth.axes)),
        "volume_m3": float(ne.volume(d.truth)),
        "error": "",
    }
    nan = float("nan")
    failed = dict.fromkeys(("volume_est_m3", "volume_error", "chamfer_m", "chamfer_se_m", "chamfer_ratio"), nan)
    try:
        if method == "bayestouch":
            fit = fit_bayestouch_default(d.points, seed=d.seed, steps=steps, free=d.free_space, size_prior=size_prior)
            s = fit["summary"]
            row["seconds"] = fit["seconds"]
            row.update(shape_metrics(mean_shape(s), s["derived"]["volume_m3"]["mean"], d.truth, seed=index))
            row.update({f"bt_{k}": v for k, v in bayestouch_metrics(s, d.truth).items()})
        elif method == "sage":
            sq = fit_sage(d.points)
            row["seconds"] = sq["seconds"]
            row.update(shape_metrics(sq["mesh"], sq["volume"], d.truth, seed=index))
        else:
            from bayestouch.inference.gpis import fit_gpis

            t0 = time.perf_counter()
            g = fit_gpis(d.points)
            row["seconds"] = time.perf_counter() - t0
            row["gpis_touches_box"] = g.touches_box
            if not np.isfinite(g.volume):
                row.update(failed, error="gpis: the GP mean has no zero crossing on the grid")
            else:
                row.update(shape_metrics((g.vertices, g.faces), g.volume, d.truth, seed=index))
    except Exception as exc:  # noqa: BLE001 - a method's crash is a result of the benchmark, recorded as such
        row.setdefault("seconds", nan)
        row.update(failed, error=f"{type(exc).__name__}: {exc}"[:200])
    return row


# ---------------------------------------------------------------------------------------- summary


def _median_block(values, seed: int) -> dict:
    med, lo, hi = bootstrap_median(values, seed=seed)
    return {"median": med, "ci95": [lo, hi]}


def _proportion(flags) -> dict:
    flags = [bool(f) for f in flags]
    k, n = sum(flags), len(flags)
    lo, hi = wilson_interval(k, n)
    return {"k": k, "n": n, "fraction": k / n if n else float("nan"), "wilson95": [lo, hi]}


def _or(value, default: float) -> float:
    """``value`` as a float, ``default`` where it is None or NaN."""
    return default if value is None or not np.isfinite(value) else float(value)


def summarise(rows: list[dict], seed: int = 0) -> dict:
    """Per-method summary of the rows of :func:`fit_set`.

    Medians and bootstrap 95 % intervals (:func:`bootstrap_median`, ``seed``) of the volume error and the Chamfer
    ratio (a failed fit counts as +inf); time median and 95th percentile (over the fits that ran); for bayestouch
    the fractions of sets whose 90 % volume interval, each semi-axis interval and all three semi-axis intervals
    cover the truth (Wilson 95 % intervals; the three axis intervals of a set are not independent, so the pooled
    per-interval fraction's interval is optimistic), the converged fits, the sets at the prior box, and the mean
    and sd of the volume z-scores (0 and 1 for a calibrated Gaussian posterior).

    Returns
    -------
    dict
        ``{method: {...}}``.
    """
    out = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        rs = [r for r in rows if r["method"] == method]
        vol = [r["volume_error"] if np.isfinite(r["volume_error"]) else np.inf for r in rs]
        ch = [r["chamfer_ratio"] if np.isfinite(r["chamfer_ratio"]) else np.inf for r in rs]
        secs = np.array([r["seconds"] for r in rs if np.isfinite(r.get("seconds", np.nan))])
        s = {
            "sets": len(rs),
            "failed": sum(1 for r in rs if r["error"]),
            "volume_error": _median_block(vol, seed),
            "chamfer_ratio": _median_block(ch, seed),
            "seconds": {
                "median": float(np.median(secs)) if secs.size else float("nan"),
                "p95": float(np.quantile(secs, 0.95)) if secs.size else float("nan"),
            },
        }
        if method == "bayestouch":
            ok = [r for r in rs if not r["error"]]
            z = np.array([r["bt_volume_z"] for r in ok], dtype=np.float64)
            s.update(
                {
                    "volume_coverage_90": _proportion(r["bt_volume_covered"] for r in ok),
                    "axes_all_coverage_90": _proportion(r["bt_axes_covered"] for r in ok),
                    "axis_interval_coverage_90": _proportion(r[f"bt_axis{j}_covered"] for r in ok for j in range(3)),
                    "converged": sum(bool(r["bt_converged"]) for r in ok),
                    "at_prior_box": sum(bool(r["bt_at_prior_box"]) for r in ok),
                    "volume_z": {
                        "mean": float(z.mean()) if z.size else float("nan"),
                        "sd": float(z.std(ddof=1)) if z.size > 1 else float("nan"),
                    },
                    # a chain too short for R-hat (NaN; null in a shard's JSON) counts as not mixed at all
                    "max_r_hat_median": float(np.median([_or(r["bt_max_r_hat"], np.inf) for r in ok]))
                    if ok
                    else float("nan"),
                    "min_ess_bulk_median": float(np.median([_or(r["bt_min_ess_bulk"], 0.0) for r in ok]))
                    if ok
                    else float("nan"),
                    "off_by_more_than_3_sd": int(np.sum(np.abs(z) > 3)),
                    "chain_steps_median": float(np.median([r["bt_steps"] for r in ok])) if ok else float("nan"),
                    "chains_of_one_step": sum(int(r["bt_steps"]) <= 1 for r in ok),
                }
            )
        out[method] = s
    return out


def markdown_table(summary: dict, note: str = "") -> str:
    """Markdown tables of :func:`summarise`'s result (one row per method; bayestouch's calibration below)."""

    def ci(b):
        return f"{b['median']:.3g} [{b['ci95'][0]:.3g}, {b['ci95'][1]:.3g}]"

    lines = ["# Shape from users'-like touch data (benchmarks/bench_user_sets.py)", ""]
    if note:
        lines += [note, ""]
    lines += [
        "| method | sets | failed | median volume error [95 % CI] | median Chamfer / mean semi-axis [95 % CI] "
        "| time median (s) | time p95 (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for m, s in summary.items():
        lines.append(
            f"| {m} | {s['sets']} | {s['failed']} | {ci(s['volume_error'])} | {ci(s['chamfer_ratio'])} "
            f"| {s['seconds']['median']:.3g} | {s['seconds']['p95']:.3g} |"
        )
    bt = summary.get("bayestouch")
    if bt is not None:

        def prop(p):
            return f"{p['k']}/{p['n']} = {p['fraction']:.2f} [{p['wilson95'][0]:.2f}, {p['wilson95'][1]:.2f}]"

        lines += [
            "",
            "bayestouch's 90 % intervals (nominal coverage 0.90; Wilson 95 % intervals):",
            "",
            "| quantity | value |",
            "|---|---|",
            f"| volume interval covers the truth | {prop(bt['volume_coverage_90'])} |",
            f"| all three semi-axis intervals cover | {prop(bt['axes_all_coverage_90'])} |",
            f"| semi-axis intervals covering (pooled) | {prop(bt['axis_interval_coverage_90'])} |",
            f"| volume z-score mean, sd | {bt['volume_z']['mean']:.2f}, {bt['volume_z']['sd']:.2f} |",
            f"| converged | {bt['converged']}/{bt['sets'] - bt['failed']} |",
            f"| posterior at the prior box | {bt['at_prior_box']}/{bt['sets'] - bt['failed']} |",
            f"| median of the largest R-hat | {bt['max_r_hat_median']:.3g} |",
            f"| median of the smallest bulk ESS | {bt['min_ess_bulk_median']:.3g} |",
        ]
    return "\n".join(lines) + "\n"


def write_results(
    rows: list[dict], out, count: int, seed: int, steps, stem: str = "user_sets", size_prior=None
) -> dict:
    """Summarise the per-set ``rows`` (:func:`summarise`) and, with a folder ``out``, write ``{stem}.csv``,
    ``{stem}.json`` and ``{stem}.md`` there (``size_prior`` (2,) metres, bayestouch's stated size prior, noted;
    None: the default). Returns the summary."""
    from bayestouch.io.files import write_csv_rows, write_json, write_text

    summary = summarise(rows, seed)
    note = (
        f"{count} sets (seed {seed}), bayestouch steps: {steps if steps is not None else 'run_contact_fit default'}; "
        "a failed fit counts as an infinite error."
        + (
            ""
            if size_prior is None
            else f" bayestouch's size prior stated: objects {size_prior[0]:g}–{size_prior[1]:g} m."
        )
    )
    if out is not None:
        out = Path(out)
        write_csv_rows(out / f"{stem}.csv", rows)
        meta = {"sets": count, "seed": seed, "steps": steps, "bootstrap_resamples": BOOTSTRAP_RESAMPLES}
        if size_prior is not None:
            meta["size_prior_m"] = [float(v) for v in size_prior]
        write_json(out / f"{stem}.json", {**meta, **summary})
        write_text(out / f"{stem}.md", markdown_table(summary, note))
    return summary


def bench_user_sets(
    count: int | None = None,
    seed: int = 0,
    methods=METHODS,
    steps: int | None = None,
    out: Path | None = RESULTS,
    size_prior=None,
    stem: str = "user_sets",
) -> list[dict]:
    """Fit every set with each method; write the per-set CSV, the summary JSON and a Markdown table.

    Parameters
    ----------
    count : int, optional
        Number of sets (default ``$BAYESTOUCH_USER_SETS`` or 50), seeds ``1000 seed + i``.
    seed : int
        Seed of the sets (and of the bootstrap).
    methods : sequence of {"bayestouch", "sage", "gpis"}
    steps : int, optional
        bayestouch's largest number of steps (default ``$BAYESTOUCH_USER_STEPS`` or run_contact_fit's own).
    out : Path or None
        Folder of ``{stem}.csv``, ``{stem}.json`` and ``{stem}.md``; None: nothing written.
    size_prior : (2,) float, metres, optional
        bayestouch's stated size prior ``(min, max)`` across (default: ``models/priors.toml``'s).
    stem : str
        Name of the output files.

    Returns
    -------
    list of dict
        ``{"metric", "value", "unit", "method", ...}`` rows for :mod:`benchmarks.harness`.

    Raises
    ------
    ValueError
        An unknown method.
    """
    from tqdm import tqdm

    from bayestouch.io.files import write_json

    count = int(os.environ.get("BAYESTOUCH_USER_SETS", 50)) if count is None else int(count)
    if steps is None and os.environ.get("BAYESTOUCH_USER_STEPS"):
        steps = int(os.environ["BAYESTOUCH_USER_STEPS"])
    methods = tuple(methods)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"bench_user_sets: unknown methods {unknown}; expected some of {METHODS}")

    shard = os.environ.get("BAYESTOUCH_USER_SHARD")  # "k/K": fit only sets i with i % K == k, save the rows
    k_of = tuple(int(v) for v in shard.split("/")) if shard else (0, 1)
    mine = [i for i in range(count) if i % k_of[1] == k_of[0]]
    rows = []
    sets = make_user_sets(count, seed)
    with tqdm(total=len(mine) * len(methods), desc="user sets", unit="fit") as bar:
        for i in mine:
            for method in methods:
                bar.set_postfix_str(f"set {i} {method}")
                rows.append(fit_set(sets[i], method, i, steps, size_prior))
                bar.update()
    if shard:
        if out is not None:
            write_json(Path(out) / f"{stem}.shard{k_of[0]}of{k_of[1]}.json", rows)
        shards = sorted(Path(out).glob(f"{stem}.shard*of{k_of[1]}.json")) if out is not None else []
        if len(shards) < k_of[1]:
            return []  # the last shard to finish writes the summary
        rows = sorted((r for f in shards for r in json.loads(f.read_text())), key=lambda r: (r["set"], r["method"]))
    summary = write_results(rows, out, count, seed, steps, stem, size_prior)

    results = []
    for m, s in summary.items():
        common = {"method": m, "sets": s["sets"], "failed": s["failed"]}
        for key, label in (("volume_error", "median volume error"), ("chamfer_ratio", "median Chamfer / mean axis")):
            results.append({"metric": label, "value": s[key]["median"], "unit": "1", "ci95": s[key]["ci95"], **common})
        results.append({"metric": "seconds per set (median)", "value": s["seconds"]["median"], "unit": "s", **common})
        if m == "bayestouch":
            p = s["volume_coverage_90"]
            results.append(
                {"metric": "90 % volume interval coverage", "value": p["fraction"], "unit": "1", **common}
                | {"wilson95": p["wilson95"]}
            )
            results.append({"metric": "converged fits", "value": float(s["converged"]), "unit": "sets", **common})
    return results
