"""The exploration loop: plan → run the stroke (simulator or finger) → update the posterior (warm-started emcee) →
repeat.

Stroke 0 is a scout over a sphere of :data:`SCOUT_RADIUS` at the nominal centre; each later stroke is chosen by a
policy among candidates over the current point estimate. A *prober* runs each stroke (``prober.probe(stroke, rng)
-> (points (K, 3) m, free)``, ``free`` a :class:`~bayestouch.inference.freespace.Free`): :class:`RayProber` on a
simulated object, :class:`bayestouch.planning.device_prober.DeviceProber` on a finger. Contact points and the
free-space observations (:mod:`bayestouch.inference.freespace`) update the posterior. Errors against the truth:
the Chamfer distance between the estimate's and the true surface over the true mean semi-axis (dimensionless) and
the relative volume error. Lengths in metres, volumes in m³. The loop's design and its error measures:
``docs/planning.md``.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput, as_array, check_bool
from bayestouch.errors import shown as shown_value
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.compare import chamfer_surfaces
from bayestouch.geometry.integrals import surface_integrals
from bayestouch.hardware.safety import UnsafePlan
from bayestouch.inference import contact as cm
from bayestouch.inference import pose_error as pe
from bayestouch.inference.freespace import Free, with_free
from bayestouch.inference.posterior import interval
from bayestouch.inference.run import initial_theta, natural_draws, natural_names, start_ball
from bayestouch.inference.sampler import sample
from bayestouch.planning.candidates import Strokes, make_candidates, select
from bayestouch.planning.policies import check_policy, choose
from bayestouch.scene.objects import SceneObject, load_object
from bayestouch.scene.raycast import CONTACT, INSIDE, MISS, true_ray_distances

__all__ = [
    "ExploreSettings",
    "StrokeRecord",
    "ExploreResult",
    "explore",
    "Truth",
    "truth_of",
    "shape_errors",
    "SCOUT_RADIUS",
    "CONTACT_NOISE",
    "RayProber",
    "point_estimate",
    "check_settings",
    "settings_from",
    "MIN_DRAWS",
]

#: radius of the believed sphere before any touch, metres (a hand-held object of a few centimetres)
SCOUT_RADIUS = 0.025
#: contact noise along the ray, metres (the 0.3 mm of the sparse-data sets of issue 4)
CONTACT_NOISE = 3e-4
#: new random scout arcs tried in place of one the prober refused as unsafe
SCOUT_REDRAWS = 8
#: area-uniform surface samples per shape for the Chamfer distance (exact distances to the other surface)
CHAMFER_COUNT = 4000

_vol = jax.jit(jax.vmap(lambda v: ne.volume(ne.from_vector(v))))


class _ExploreSettingsFields(NamedTuple):
    candidates: int = 64
    draws: int = 1000
    walkers: int = 32
    steps: int = 300
    init_steps: int = 600
    points: int = 20
    noise_sd: float = CONTACT_NOISE
    standoff: float = 0.025
    init_starts: int = 2
    scout: int = 4
    per_second: bool = False
    pose_draws: int = 0
    pose_offset_sd: float = 0.0


class ExploreSettings(_ExploreSettingsFields):
    """Sizes of an exploration run, checked on construction (:func:`check_settings`: a one-line
    :class:`~bayestouch.errors.BadInput` naming the field, e.g. ``candidates=-1`` or ``draws="a"``).

    candidates : int
        Candidate strokes per decision.
    draws : int
        Posterior draws the planner uses (thinned from the chain).
    walkers : int
    steps, init_steps : int
        emcee steps per update, and for the first fit.
    points : int
        Samples (rays) per stroke T.
    noise_sd : float, metres
        Contact noise along the ray (simulated and assumed by the planner).
    standoff : float, metres
        Ray starts outside the believed surface; rays are twice as long. Generous (2.5 cm), so that a ray aimed
        at a believed surface that is centimetres off still meets the true one (a miss or a start inside the
        object gives no contact point, see :mod:`bayestouch.planning.signal`).
    init_starts : int
        Evolutionary starts of the initial fit (:func:`bayestouch.inference.run.initial_theta`).
    scout : int
        Arcs of the scout stroke 0 (2.5–3 cm each, evenly spread start directions).
    per_second : bool
        ``eig``: maximise information per second of stroke.
    pose_draws : int
        0: the contacts are where the prober says. K ≥ 2: the prober's pad-pose error is marginalised with the law
        of K fingers drawn about its bending constants (a prober with ``pose_ensemble``, e.g.
        :class:`~bayestouch.planning.device_prober.DeviceProber`;
        :func:`bayestouch.inference.pose_error.make_ensemble_pose_log_prob`, one more parameter: the law's scale).
    pose_offset_sd : float, metres
        With ``pose_draws``: sd of one more offset per stroke for what the drawn fingers do not produce
        (:func:`bayestouch.inference.pose_error.ensemble_model`'s ``offset_sd``; 0: none).
    """

    __slots__ = ()

    def __new__(cls, *args, **kwargs):
        try:
            settings = super().__new__(cls, *args, **kwargs)
        except TypeError as e:  # an unknown field, too many values
            why = str(e).replace("_ExploreSettingsFields.__new__()", "ExploreSettings()")
            raise BadInput(f"ExploreSettings: {why}; expected fields {', '.join(cls._fields)}") from None
        check_settings(settings)
        return settings


#: fewest posterior draws the planner can estimate a covariance from
MIN_DRAWS = 10
#: the smallest value of each integer field of :class:`ExploreSettings` (emcee's moves split 24 walkers in halves)
_SETTING_MIN = {
    "candidates": 1,
    "draws": MIN_DRAWS,
    "walkers": 24,
    "steps": 1,
    "init_steps": 1,
    "points": 1,
    "init_starts": 1,
    "scout": 1,
}


def settings_from(fields: dict) -> ExploreSettings:
    """:class:`ExploreSettings` with the given ``fields`` (a dict, as :func:`explore` and
    :func:`bayestouch.planning.experiment.run_experiment` take them), an unknown field refused by name."""
    unknown = set(fields) - set(ExploreSettings._fields)
    if unknown:
        raise BadInput(f"settings: unknown field(s) {sorted(unknown)}; expected {', '.join(ExploreSettings._fields)}")
    return ExploreSettings(**fields)


def check_settings(s: ExploreSettings) -> None:
    """Refuse (:class:`BadInput` naming the field) settings the loop cannot run: integer fields below their least
    (``draws=0`` was an IndexError, ``steps=-1`` an emcee error), an odd walker count, a noise sd or standoff that
    is not a positive finite number of metres."""
    for name, lo in _SETTING_MIN.items():
        v = getattr(s, name)
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < lo:
            raise BadInput(f"settings.{name}: expected an integer ≥ {lo}, got {v!r}")
    if s.walkers % 2:
        raise BadInput(f"settings.walkers: expected an even number (emcee moves halves of it), got {s.walkers}")
    for name in ("noise_sd", "standoff"):
        v = getattr(s, name)
        if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and v > 0):
            raise BadInput(f"settings.{name}: expected a positive finite number of metres, got {v!r}")
    check_bool(s.per_second, "settings.per_second")
    v = s.pose_draws
    if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 0 or v == 1:
        raise BadInput(f"settings.pose_draws: expected 0 (no pose-error law) or an integer ≥ 2 fingers, got {v!r}")
    v = s.pose_offset_sd
    if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and 0 <= v < 0.1):
        raise BadInput(f"settings.pose_offset_sd: expected a per-stroke offset sd in metres in [0, 0.1), got {v!r}")


class StrokeRecord(NamedTuple):
    """One stroke of the loop (stroke 0 is the scout). ``chamfer`` and ``volume_error`` are NaN without a truth;
    ``refused`` counts the candidates (scout arcs) the prober refused as unsafe before this stroke ran."""

    stroke: int
    n_points: int
    new_points: int
    chamfer: float
    volume_error: float
    volume_mean: float
    volume_sd: float
    eig: float
    decision_s: float
    update_s: float
    seconds: float
    summary: dict
    refused: int = 0


class ExploreResult(NamedTuple):
    """The loop's history, all contact points (M, 3) m, the last draws (N, 10) and the last ensemble (W, 11), (W, 12)
    with a pose-error law (its last column log s, :data:`bayestouch.inference.pose_error.ENSEMBLE_PARAM_NAMES`)."""

    records: list
    points: np.ndarray
    shape_vectors: np.ndarray
    ensemble: np.ndarray
    strokes: list


class Truth(NamedTuple):
    """What the errors are measured against: the true mesh, its volume (m³) and mean semi-axis (m)."""

    mesh: tuple
    volume: float
    mean_axis: float


def truth_of(obj) -> Truth:
    """The :class:`Truth` of a scene object (mesh at resolution 64, volume by eq. 11)."""
    v, f = obj.mesh(64)
    return Truth((v, f), float(surface_integrals(v, f).volume), float(np.mean(np.asarray(obj.shape.axes))))


def point_estimate(shape_vectors) -> dict:
    """The point estimate (the median-volume draw) of draws ``(N, 10)``: ``estimate`` (10,), ``volume_mean`` and
    ``volume_sd`` (m³, over the draws) and NaN ``chamfer`` and ``volume_error`` (no truth to compare with)."""
    vecs = np.asarray(shape_vectors, float)
    vols = np.asarray(_vol(jnp.asarray(vecs)))
    k = int(np.argsort(vols)[len(vols) // 2])
    return {
        "chamfer": float("nan"),
        "volume_error": float("nan"),
        "volume_mean": float(vols.mean()),
        "volume_sd": float(vols.std(ddof=1)),
        "estimate": vecs[k],
    }


def shape_errors(shape_vectors, truth: Truth, seed: int = 0) -> dict:
    """Point estimate (median-volume draw) and its errors against ``truth``.

    Returns
    -------
    dict
        ``chamfer``: the symmetric Chamfer distance between the estimate's surface and the true mesh, by exact
        point-to-surface distances from :data:`CHAMFER_COUNT` area-uniform samples per surface
        (:func:`bayestouch.geometry.compare.chamfer_surfaces`), as a fraction of the true mean semi-axis
        (dimensionless; no sampling floor); ``chamfer_se`` its Monte-Carlo standard error (same units);
        ``volume_error`` (|V̂/V − 1|), ``volume_mean``, ``volume_sd`` (m³, over the draws) and ``estimate``
        (10,) the point estimate's vector.
    """
    vecs = np.asarray(shape_vectors, float)
    vols = np.asarray(_vol(jnp.asarray(vecs)))
    k = int(np.argsort(vols)[len(vols) // 2])
    est = ne.from_vector(jnp.asarray(vecs[k]))
    ch, se = chamfer_surfaces(est, truth.mesh, count=CHAMFER_COUNT, seed=seed)
    return {
        "chamfer": float(ch / truth.mean_axis),
        "chamfer_se": float(se / truth.mean_axis),
        "volume_error": float(abs(vols[k] / truth.volume - 1.0)),
        "volume_mean": float(vols.mean()),
        "volume_sd": float(vols.std(ddof=1)),
        "estimate": vecs[k],
    }


def _measure(obj, stroke: Strokes, noise_sd: float, rng: np.random.Generator) -> tuple[np.ndarray, Free]:
    """Contact points (K, 3) m of one stroke on the true object (real contacts, noise along the ray), and its
    :class:`~bayestouch.inference.freespace.Free` observations (misses and starts inside)."""
    x0, d = stroke.starts[0], stroke.dirs[0]
    t, status = true_ray_distances(obj, x0, d, stroke.t_max)
    t = t + noise_sd * rng.standard_normal(t.shape)
    ok = status == CONTACT
    miss, inside = status == MISS, status == INSIDE
    return x0[ok] + t[ok, None] * d[ok], Free(x0[miss], d[miss], float(stroke.t_max), x0[inside])


class RayProber:
    """The default prober: a stroke measured on a simulated object by rays (:func:`~bayestouch.scene.raycast.
    true_ray_distances`, Gaussian noise of ``noise_sd`` metres along the ray).

    Parameters
    ----------
    obj : SceneObject
        The true object.
    noise_sd : float, metres
    """

    def __init__(self, obj, noise_sd: float = CONTACT_NOISE):
        self.obj, self.noise_sd = obj, float(noise_sd)

    def probe(self, stroke: Strokes, rng: np.random.Generator) -> tuple[np.ndarray, Free]:
        """Contact points (K, 3) m and :class:`~bayestouch.inference.freespace.Free` observations of ``stroke`` (a
        batch of one)."""
        return _measure(self.obj, stroke, self.noise_sd, rng)


def _concat(batches: list[Strokes]) -> Strokes:
    """Strokes batches (of equal T and t_max) one after another."""
    cat = [np.concatenate([getattr(b, f) for b in batches]) for f in ("path", "starts", "dirs")]
    rest = [np.concatenate([getattr(b, f) for b in batches]) for f in ("length", "force", "duration")]
    return Strokes(*cat, batches[0].t_max, *rest)


def _draws(chain_kept, count: int, rng: np.random.Generator, sampled: tuple = cm.PARAM_NAMES) -> np.ndarray:
    """Thinned, canonicalised draws (count, len(sampled)) in natural units from the last half of the kept chain."""
    kept = chain_kept[len(chain_kept) // 2 :]
    flat = kept.reshape(-1, kept.shape[-1])
    idx = np.sort(rng.choice(len(flat), size=count, replace=len(flat) < count))
    return natural_draws(flat[idx], sampled)


def _subseed(*key: int) -> int:
    """A 32-bit seed derived from integers (emcee's RandomState takes < 2**32)."""
    return int(np.random.SeedSequence(list(key)).generate_state(1)[0])


def _sample(logp, start, walkers: int, seed: int, steps: int):
    """A short in-memory emcee run (:func:`bayestouch.inference.sampler.sample`). emcee's autocorrelation estimate
    divides by zero (a RuntimeWarning) when a parameter's walker-mean does not move over a short chain; τ is not
    used here (the chain is short by design and reported as such), so that warning is silenced."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "invalid value encountered", RuntimeWarning)
        return sample(logp, start, None, walkers=walkers, ndim=start.shape[1], seed=seed, steps=steps, progress=False)


def _density(pts: np.ndarray, free: Free, priors, prober, s: ExploreSettings) -> tuple:
    """The loop's log-posterior of the contacts and free space so far, its box and the sampled parameters' names:
    the contact likelihood, or with ``s.pose_draws`` the prober's pose-error law marginalised
    (:meth:`~bayestouch.planning.device_prober.DeviceProber.pose_ensemble`)."""
    if not s.pose_draws:
        logp, bounds = cm.make_log_prob(pts, priors)
        return with_free(logp, bounds, free), bounds, cm.PARAM_NAMES
    model = prober.pose_model(pts, s.pose_draws, offset_sd=s.pose_offset_sd)
    logp, bounds = pe.make_ensemble_pose_log_prob(model, priors)
    return with_free(logp, bounds, free), bounds, pe.ENSEMBLE_PARAM_NAMES


def _summary(k: int, nat: np.ndarray, errors: dict, n_points: int, policy: str, sampled: tuple) -> dict:
    names = natural_names(sampled)
    return {
        "stroke": k,
        "planner": policy,
        "n_points": n_points,
        "parameters": {name: interval(nat[:, i]) for i, name in enumerate(names)},
        "derived": {"volume_m3": {"mean": errors["volume_mean"], "sd": errors["volume_sd"]}},
        "errors": {"chamfer_over_mean_axis": errors["chamfer"], "volume_error": errors["volume_error"]},
        "point_estimate": dict(zip(ne.PARAM_NAMES, map(float, errors["estimate"]), strict=True)),
    }


def explore(
    obj,
    policy: str,
    budget: int,
    *,
    seed: int = 0,
    settings: ExploreSettings | None = None,
    target_volume_sd: float | None = None,
    on_stroke=None,
    truth: Truth | None = None,
    prober=None,
    centre=None,
) -> ExploreResult:
    """Run the exploration loop on a simulated object or a finger.

    Parameters
    ----------
    obj : SceneObject, str, path or None
        The true object (:func:`bayestouch.scene.objects.load_object`; a name or TOML file is loaded); None with a
        ``prober`` that touches a real object (no truth: NaN errors; the ``oracle`` policy needs it).
    policy : {"eig", "random", "coverage", "gpis", "oracle"}
    budget : int
        Planned strokes after the scout (≥ 1).
    seed : int
        The scout, its noise and the initial fit depend on ``seed`` only (common to every policy: comparisons
        between policies start from the same posterior); the policies' choices, later noise and sampling on
        ``(seed, policy)``.
    settings : ExploreSettings or dict, optional
        Default ``ExploreSettings()``; a dict gives some of its fields.
    target_volume_sd : float, m³, optional
        Stop early once the volume's posterior sd is below this.
    on_stroke : callable, optional
        Called with each :class:`StrokeRecord` as it is made.
    truth : Truth, optional
        Precomputed :func:`truth_of` ``(obj)`` (computed from ``obj`` when None and ``obj`` is given).
    prober : optional
        Runs the strokes (module docstring); default :class:`RayProber` ``(obj, settings.noise_sd)``.
    centre : (3,) float, metres, optional
        Nominal centre (the fixture) for the scout; default ``obj.shape.centre``; required without ``obj``.

    Returns
    -------
    ExploreResult
    """
    check_policy(policy)
    if isinstance(obj, str | os.PathLike):  # a name or a TOML file, as every other verb takes
        obj = load_object(obj)
    elif obj is not None and not isinstance(obj, SceneObject):
        raise BadInput(f"object: expected an object name, a TOML file or a SceneObject, got {type(obj).__name__}")
    if not isinstance(budget, int | np.integer) or budget < 1:
        raise BadInput(f"budget: expected an integer number of strokes ≥ 1, got {budget!r}")
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise BadInput(f"seed: expected an integer ≥ 0, got {seed!r}")
    if isinstance(settings, dict):  # the form run_experiment takes
        settings = settings_from(settings)
    elif settings is not None and not (isinstance(settings, tuple) and hasattr(settings, "_fields")):
        raise BadInput(f"settings: expected an ExploreSettings or a dict of its fields, got {type(settings).__name__}")
    s = settings or ExploreSettings()
    check_settings(s)
    if target_volume_sd is not None and not (isinstance(target_volume_sd, int | float) and target_volume_sd > 0):
        raise BadInput(f"target_volume_sd: expected a positive volume in m^3 or None, got {target_volume_sd!r}")
    if on_stroke is not None and not callable(on_stroke):
        raise BadInput(f"on_stroke: expected a function of one StrokeRecord or None, got {shown_value(on_stroke)}")
    if prober is not None and not callable(getattr(prober, "probe", None)):
        raise BadInput(
            f"prober: expected an object with a probe(stroke, rng) method (e.g. RayProber, DeviceProber) or None, "
            f"got {type(prober).__name__} {shown_value(prober, 40)}"
        )
    if truth is not None and not isinstance(truth, Truth):
        raise BadInput(
            f"truth: expected a Truth (truth_of(obj)) or None, got {type(truth).__name__} {shown_value(truth, 40)}"
        )
    if obj is None and prober is None:
        raise BadInput("object: expected a scene object or a prober (a finger) to explore, got neither")
    if obj is None and policy == "oracle":
        raise BadInput("planner: the oracle needs the true object (simulation only); use eig, random or coverage")
    if centre is None:
        if obj is None:
            raise BadInput("centre: expected the nominal centre (x, y, z) m of the object when no object is given")
        centre = obj.shape.centre
    centre = as_array(centre, "centre", (3,), "a (3,) array (x, y, z in metres)")
    if truth is None and obj is not None:
        truth = truth_of(obj)
    if prober is None:
        prober = RayProber(obj, s.noise_sd)
    if s.pose_draws and getattr(prober, "carrier", False):
        raise BadInput(
            "settings.pose_draws: carrier strokes take their contacts from the pad's sensed pose; there is no "
            "pose-error law to marginalise (use 0)"
        )
    if s.pose_draws and not callable(getattr(prober, "pose_ensemble", None)):
        raise BadInput(
            f"settings.pose_draws: the prober ({type(prober).__name__}) reports no pose-error law "
            "(pose_ensemble); use 0, or a finger's DeviceProber"
        )
    priors = cm.load_priors()
    pol_id = 1 + ("eig", "random", "coverage", "oracle", "gpis").index(policy)  # appended: earlier ids unchanged
    rng_common = np.random.default_rng([seed, 0])
    rng = np.random.default_rng([seed, pol_id])
    records: list[StrokeRecord] = []

    # stroke 0: the scout over the believed sphere at the nominal centre
    t0 = time.perf_counter()
    sphere = ne.NEllipsoid(jnp.asarray(centre), jnp.full(3, SCOUT_RADIUS), jnp.zeros(3), jnp.asarray(2.0))
    scout = make_candidates(
        sphere, s.scout, points=s.points, seed=rng_common, standoff=s.standoff, length_range=(0.025, 0.03)
    )
    free = Free(np.empty((0, 3)), np.empty((0, 3)), float(scout.t_max), np.empty((0, 3)))
    pts = np.empty((0, 3))
    refused = 0
    arcs = []
    for i in range(s.scout):
        arc = select(scout, i)
        for attempt in range(1, SCOUT_REDRAWS + 1):
            try:
                p, fr = getattr(prober, "scout", prober.probe)(arc, rng_common)
                break
            except UnsafePlan:  # nothing was sent: try a new random arc instead
                refused += 1
                arc = select(  # a batch of the scout's size: no new compilation of the surface walk
                    make_candidates(
                        sphere,
                        s.scout,
                        points=s.points,
                        seed=[seed, 0, i, attempt],
                        standoff=s.standoff,
                        length_range=(0.025, 0.03),
                    ),
                    i,
                )
        else:
            continue
        arcs.append(arc)
        pts, free = np.concatenate([pts, p]), free.add(fr)
    if len(pts) < 12:
        raise BadInput(
            f"object: the scout touched only {len(pts)} points; is the object near its nominal centre "
            f"{centre.tolist()} m and a few centimetres across?"
        )
    logp, bounds, sampled = _density(pts, free, priors, prober, s)
    theta0 = initial_theta(pts, seed, priors, starts=s.init_starts)
    start = start_ball(theta0, bounds, s.walkers, rng_common, sampled)
    ch = _sample(logp, start, s.walkers, _subseed(seed, 0, 0), s.init_steps)
    strokes = [scout if refused == 0 else _concat(arcs)]

    k = 0
    decision_s, eig_value = 0.0, float("nan")
    n_new = len(pts)
    while True:
        nat = _draws(ch.kept, s.draws, rng_common if k == 0 else rng, sampled)
        vecs = nat[:, :10]
        err = shape_errors(vecs, truth) if truth is not None else point_estimate(vecs)
        rec = StrokeRecord(
            k,
            len(pts),
            n_new,
            err["chamfer"],
            err["volume_error"],
            err["volume_mean"],
            err["volume_sd"],
            eig_value,
            decision_s,
            ch.seconds,
            time.perf_counter() - t0,
            _summary(k, nat, err, len(pts), policy, sampled),
            refused,
        )
        records.append(rec)
        if on_stroke is not None:
            on_stroke(rec)
        if k >= budget or (target_volume_sd is not None and err["volume_sd"] < target_volume_sd):
            break
        k += 1
        t0 = time.perf_counter()
        # plan
        mean_shape = ne.from_vector(jnp.asarray(err["estimate"]))
        cands = make_candidates(mean_shape, s.candidates, points=s.points, seed=rng, standoff=s.standoff)
        avail = np.arange(len(cands.force))
        shown, refused, decision_s = cands, 0, 0.0
        while True:
            dec = choose(
                policy,
                shown,
                vecs,
                noise_sd=s.noise_sd,
                rng=rng,
                touched=pts,
                obj=obj,
                volumes=np.asarray(_vol(jnp.asarray(vecs))),
                per_second=s.per_second,
                standoff=s.standoff,
            )
            decision_s += dec.seconds
            eig_value = float(dec.eig[dec.index]) if dec.eig is not None else float("nan")
            # run the stroke
            chosen = select(shown, dec.index)
            try:
                new, fr = prober.probe(chosen, np.random.default_rng([seed, pol_id, k]))
                break
            except UnsafePlan as e:  # refused before anything was sent: the policy chooses among the others
                refused += 1
                avail = np.delete(avail, dec.index)
                if len(avail) == 0:
                    raise BadInput(f"candidates: the prober refused all {len(cands.force)} candidates ({e})") from None
                shown = select(cands, avail)
        strokes.append(chosen)
        free = free.add(fr)
        n_new = len(new)
        if n_new:
            pts = np.concatenate([pts, new])
        # update, warm-started from the last ensemble
        logp, bounds, sampled = _density(pts, free, priors, prober, s)
        ch = _sample(logp, cm.walkers_inside(ch.kept[-1], bounds), s.walkers, _subseed(seed, pol_id, k), s.steps)
    return ExploreResult(records, pts, vecs, ch.kept[-1], strokes)
