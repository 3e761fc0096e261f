"""The main job on the built-in default: ``bayestouch demo`` (and ``make demo``).

1. **Explore through the finger.** A virtual finger whose bending constants are its own (drawn at 1× their stated
   spread, :func:`bayestouch.planning.experiment.trial_finger`: not ``models/``'s) runs guarded strokes over the
   serial protocol; its pad goes where its bent rod puts it, and the host knows the pose only from the models'
   constants. It is first calibrated on a 2-cm sphere
   (:func:`bayestouch.planning.device_prober.calibrate_bending`); then the eig planner explores the default egg
   (``models/objects/egg.toml``: a tilted, textured n-ellipsoid) for a few strokes after the scout, the contact-level
   posterior sampled after each stroke with the calibrated pose-error law marginalised
   (:func:`bayestouch.planning.loop.explore`, ``pose_draws``). ``finger=False`` explores in the ray world instead
   (contacts with the encoders' noise only, the earlier demo).
2. **Posterior.** The contact-level posterior of all the points touched, the pose-error law marginalised, continued
   from the exploration's last ensemble until converged or out of its time budget
   (:func:`bayestouch.inference.run.run_contact_fit`, ``pose``): ``summary.json``, ``posterior.nc``, ``chain.h5``,
   ``mean_shape.ply``, ``uncertainty_mesh.ply``. (The exploration's "no contact" observations are not in this final
   likelihood, only the contact points.)
3. **Taxels.** The strokes as the virtual finger feels them: taxel currents of every stroke (``recording.nc``, the
   schema of ``bayestouch simulate``) and the posterior of one contact patch (a, b, n of eq. 16–18,
   :func:`bayestouch.inference.patch.patch_posterior`), ``patch_summary.json``.
4. **Report.** ``report.html`` with its figures.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import NamedTuple

import arviz as az
import numpy as np
import xarray as xr
from tqdm.auto import tqdm

from bayestouch import __version__
from bayestouch.backend import jnp
from bayestouch.errors import BadInput, check_bools, check_int, check_number, check_path, shown
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference.patch import patch_posterior
from bayestouch.inference.run import run_contact_fit
from bayestouch.io.contacts import save_contact_points
from bayestouch.io.files import write_json
from bayestouch.io.meshes import read_spread_mesh
from bayestouch.io.recording import read_recording, write_recording
from bayestouch.params import MODELS
from bayestouch.physics.virtual import load_finger, recording_dataset
from bayestouch.planning.device_prober import VirtualFingerProber, calibrate_bending
from bayestouch.planning.experiment import calibration_object, trial_finger
from bayestouch.planning.loop import ExploreSettings, explore, truth_of
from bayestouch.report import figures as rp
from bayestouch.report.page import Figure, Table, check_in_browser, find_browser, write_report
from bayestouch.scene.objects import load_object
from bayestouch.scene.raycast import CONTACT, true_ray_distances
from bayestouch.scene.strokes import stroke_from_path

__all__ = ["DemoSizes", "FULL", "QUICK", "run_demo", "replay_strokes"]

_log = logging.getLogger(__name__)

DEFAULT_OBJECT = MODELS / "objects" / "egg.toml"
#: the demo finger's bending constants: drawn at this many times their stated spread (pose.FingerSpread)
BEND_SPREAD = 1.0
#: fingers of the pose-error law the exploration and the final posterior marginalise
POSE_DRAWS = 24
#: taxel response of the replay: the empirical mode (Δ ln I = S_p p, device-like sensitivity). The physics mode's
#: response at 1 kPa is Δ ln I ≈ 3e-5, far below the noise (physics.md, finding 2), so its images show only noise.
TAXEL_MODE = "empirical"


class DemoSizes(NamedTuple):
    """Sizes of a demo run.

    budget : int
        Planned strokes after the scout.
    candidates, draws, steps, init_steps : int
        The planner's candidates and posterior draws, emcee steps per update and for the first fit.
    fit_steps : int
        Largest chain of the final posterior (it stops earlier once converged).
    fit_budget_s : float, seconds
        Wall-clock budget of the final posterior.
    patch_steps : int
        emcee steps of the contact-patch posterior.
    """

    budget: int
    candidates: int
    draws: int
    steps: int
    init_steps: int
    fit_steps: int
    fit_budget_s: float
    patch_steps: int


FULL = DemoSizes(
    budget=5,
    candidates=64,
    draws=1000,
    steps=300,
    init_steps=600,
    fit_steps=20000,
    fit_budget_s=150.0,
    patch_steps=2000,
)
QUICK = DemoSizes(
    budget=1, candidates=12, draws=200, steps=80, init_steps=150, fit_steps=400, fit_budget_s=30.0, patch_steps=200
)


def replay_strokes(
    obj, strokes, *, rate: float = 50.0, depth: float = 3e-4, min_samples: int = 5, frames: int = 64
) -> list:
    """The planned strokes as finger strokes over the true object.

    Each planned stroke (:class:`bayestouch.planning.candidates.Strokes`, a path over the believed surface with its
    approach rays) becomes a :class:`bayestouch.scene.strokes.Stroke`: the path where its approach rays meet the
    true surface (:func:`bayestouch.scene.raycast.true_ray_distances`; the longest run of consecutive contacts),
    resampled at ``rate`` along its length at the stroke's speed, pressed ``depth`` below the surface along the base
    surface's normal.

    Parameters
    ----------
    obj : SceneObject
    strokes : list of Strokes
        Batches of planned strokes (the exploration's ``ExploreResult.strokes``).
    rate : float, Hz
        Frame rate of the finger.
    depth : float, metres
    min_samples : int
        Strokes with fewer consecutive contacts are skipped.
    frames : int
        Frames per stroke: each keeps the middle ``frames`` samples of its path (the forward model is compiled once
        per stroke length; with one length the replay costs one compilation); shorter strokes are skipped.

    Returns
    -------
    list of Stroke
    """
    out = []
    for batch in strokes:
        t, status = true_ray_distances(obj, batch.starts, batch.dirs, batch.t_max)
        for c in range(len(batch.length)):
            ok = status[c] == CONTACT
            if ok.sum() < min_samples:
                continue
            runs = np.split(np.flatnonzero(ok), np.flatnonzero(np.diff(np.flatnonzero(ok)) > 1) + 1)
            run = max(runs, key=len)
            if len(run) < min_samples:
                continue
            hits = batch.starts[c, run] + t[c, run, None] * batch.dirs[c, run]
            seg = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(hits, axis=0), axis=1))]
            speed = float(batch.length[c] / batch.duration[c])
            if seg[-1] / speed * rate + 1 < frames:
                continue
            # the middle ``frames`` samples of the run: one length, one compilation of the forward model
            s = 0.5 * (seg[-1] - (frames - 1) * speed / rate) + np.arange(frames) * speed / rate
            path = np.column_stack([np.interp(s, seg, hits[:, k]) for k in range(3)])
            nrm = ne.evaluate(ne.normals, obj.shape, path)
            out.append(stroke_from_path(path, nrm, (s - s[0]) / speed, depth))
    return out


def _fmt(x: float, digits: int = 3) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x:.{digits}g}"


def run_demo(
    out,
    *,
    seed: int = 0,
    sizes: DemoSizes = FULL,
    object_path=DEFAULT_OBJECT,
    progress: bool = True,
    check_browser: bool = True,
    finger: bool = True,
) -> dict:
    """Run the demo into the folder ``out`` and return its headline numbers.

    Parameters
    ----------
    out : path-like
        Output folder (created).
    seed : int
        Seeds every stage.
    sizes : DemoSizes
        :data:`FULL` (``make demo``) or :data:`QUICK` (tests).
    object_path : path-like
        The object TOML.
    progress : bool
        Progress bars on stderr and the four stages' messages logged (``logging.getLogger("bayestouch.demo")``,
        INFO).
    check_browser : bool
        Load ``report.html`` in headless Chromium when one is installed and say whether every image rendered.
    finger : bool
        Explore through a virtual finger with its own bending constants, calibrated first, the pose-error law
        marginalised (default); False: in the ray world, contacts with the encoders' noise only.

    Returns
    -------
    dict
        ``strokes`` (per-stroke rows), ``summary`` (the final posterior's summary.json), ``patch`` (the patch
        posterior's summary), ``report`` (path), ``browser`` (the check, or None), ``seconds``, ``table`` (the
        result as text, which ``bayestouch demo`` prints).
    """
    t_start = time.perf_counter()
    if not isinstance(seed, int) or seed < 0:
        raise BadInput(f"--seed: expected an integer ≥ 0, got {seed!r}")
    check_path(out, "out")
    if not isinstance(sizes, DemoSizes):
        raise BadInput(f"sizes: expected a DemoSizes (bayestouch.demo.FULL or QUICK), got {shown(sizes)}")
    for name, value in sizes._asdict().items():
        if name == "fit_budget_s":
            check_number(value, "sizes.fit_budget_s", 0, above=True, what="a number of seconds")
        else:
            check_int(value, f"sizes.{name}", 1)
    check_bools(progress=progress, check_browser=check_browser, finger=finger)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    (out / "strokes").mkdir(exist_ok=True)
    obj = load_object(object_path)
    truth = truth_of(obj)
    say = _log.info if progress else (lambda msg: None)

    # 1. explore
    settings = ExploreSettings(
        candidates=sizes.candidates,
        draws=sizes.draws,
        steps=sizes.steps,
        init_steps=sizes.init_steps,
        pose_draws=POSE_DRAWS if finger else 0,
    )
    calibration = None
    bent = trial_finger(seed, BEND_SPREAD) if finger else None
    if finger:
        say("[1/4] calibrating the virtual finger's bending on a 2-cm sphere (its constants are its own, not models/')")
        sphere = calibration_object()
        with VirtualFingerProber(sphere, seed=seed, finger=bent) as cal:
            calibration = calibrate_bending(cal, sphere, seed=seed)
    where = "through the finger's bending chain, pose error marginalised" if finger else "in the ray world"
    say(f"[1/4] exploring {obj.name} {where} with the eig planner: scout + {sizes.budget} strokes")
    bar = tqdm(total=sizes.budget + 1, desc="strokes", unit="stroke", disable=not progress)

    def on_stroke(rec):
        write_json(
            out / "strokes" / f"summary_{rec.stroke}.json",
            {**rec.summary, "seconds": rec.seconds, "eig_nats": rec.eig, "decision_s": rec.decision_s},
        )
        bar.set_postfix(points=rec.n_points, chamfer=f"{rec.chamfer:.3f}", vol_err=f"{rec.volume_error:.3f}")
        bar.update(1)

    pose_model = None
    if finger:
        with VirtualFingerProber(obj, seed=seed, finger=bent, pose_law=calibration.law) as prober:
            res = explore(
                obj, "eig", sizes.budget, seed=seed, settings=settings, on_stroke=on_stroke, truth=truth, prober=prober
            )
            pose_model = prober.pose_model(res.points, POSE_DRAWS, offset_sd=settings.pose_offset_sd)
    else:
        res = explore(obj, "eig", sizes.budget, seed=seed, settings=settings, on_stroke=on_stroke, truth=truth)
    bar.close()
    save_contact_points(out / "points.csv", res.points, overwrite=True)

    # 2. the posterior of everything touched
    say(
        f"[2/4] posterior of the {len(res.points)} contact points (stops once converged, at most "
        f"{sizes.fit_budget_s:.0f} s)"
    )
    summary = run_contact_fit(
        res.points,
        out,
        seed=seed,
        steps=sizes.fit_steps,
        budget_s=sizes.fit_budget_s,
        progress=progress,
        start=res.ensemble,
        overwrite=True,  # the demo's folder is rebuilt by every run
        pose=pose_model,
    )

    # 3. the strokes as the finger feels them
    say("[3/4] the virtual finger replays the strokes: taxel currents and a contact-patch posterior")
    patch_summary, patch_post, recording, gains = _taxels(obj, res, out, seed, sizes, progress)

    # 4. report
    say("[4/4] report")
    page = _report(out, obj, truth, res, summary, patch_summary, patch_post, recording, gains, calibration)
    check = None
    if check_browser:
        if find_browser():
            check = check_in_browser(page)
    seconds = time.perf_counter() - t_start
    rows = [{k: v for k, v in r._asdict().items() if k != "summary"} for r in res.records]
    write_json(
        out / "demo.json",
        {
            "object": obj.name,
            "planner": "eig",
            "seed": seed,
            "sizes": sizes._asdict(),
            "prober": "finger" if finger else "rays",
            "finger": None if not finger else _finger_record(calibration),
            "strokes": rows,
            "seconds": seconds,
            "browser_check": None if check is None else check._asdict(),
        },
    )
    return {
        "table": _table(res, summary, patch_summary, truth, page, check, seconds, calibration),
        "strokes": rows,
        "summary": summary,
        "patch": patch_summary,
        "report": page,
        "browser": check,
        "seconds": seconds,
    }


def _finger_record(calibration) -> dict:
    """What ``demo.json`` records of the finger: its constants' spread, the law's fingers and the calibration."""
    return {
        "bend_spread": BEND_SPREAD,
        "pose_draws": POSE_DRAWS,
        "calibration": {
            "object": "sphere, radius 0.02 m",
            "contacts": int(calibration.contacts),
            "residual_rms_nominal_m": float(calibration.residual_rms_prior),
            "residual_rms_calibrated_m": float(calibration.residual_rms),
        },
    }


def _calibration_text(calibration) -> str:
    """One sentence on the bending calibration (empty without one)."""
    if calibration is None:
        return ""
    return (
        f"bending calibration on a 2-cm sphere: {calibration.contacts} contacts lie "
        f"{1e3 * calibration.residual_rms_prior:.2f} mm (RMS) off it where the models' constants put the pad, "
        f"{1e3 * calibration.residual_rms:.2f} mm after calibration"
    )


def _taxels(obj, res, out: Path, seed: int, sizes: DemoSizes, progress: bool):
    vf = load_finger(seed=seed)
    strokes = replay_strokes(obj, res.strokes)
    if not strokes:
        raise RuntimeError("demo: no planned stroke met the object along its path")
    ds = recording_dataset(
        obj,
        strokes,
        vf,
        seed,
        mode=TAXEL_MODE,
        attrs={
            "object": obj.name,
            "object_file": str(obj.source or ""),
            "seed": seed,
            "mode": TAXEL_MODE,
            "wire_hold_currents_A": "0.15,0.05,0.05",
            "software": f"bayestouch {__version__}",
            "made_by": "bayestouch demo (replayed eig strokes)",
        },
        progress=progress,
    )
    write_recording(ds, out / "recording.nc", overwrite=True)  # the demo folder was checked by its caller
    recording = read_recording(out / "recording.nc")
    # the most loaded frame of the last stroke, with its neighbours: a window of 5 frames
    force = np.asarray(recording["contact_force"].values)
    last = np.flatnonzero(np.asarray(recording["stroke_index"].values) == int(recording["stroke_index"].values[-1]))
    f = last[int(np.argmax(force[last]))]
    lo = int(np.clip(f - 2, last[0], max(last[0], last[-1] - 4)))
    window = np.asarray(recording["taxel_current"].values)[lo : lo + 5]
    post = patch_posterior(
        window,
        vf.finger,
        seed=seed,
        mode=TAXEL_MODE,
        steps=sizes.patch_steps,
        temperature=float(np.mean(recording["skin_temperature"].values[lo : lo + 5])),
    )
    patch_summary = {
        **post.summary,
        "frames": [lo, lo + len(window)],
        "true_force_N": float(np.mean(force[lo : lo + len(window)])),
    }
    write_json(out / "patch_summary.json", patch_summary)
    return patch_summary, post, recording, np.asarray(vf.finger.gains).ravel()


def _report(
    out: Path, obj, truth, res, summary: dict, patch_summary: dict, patch_post, recording, gains, calibration
) -> Path:
    um = _read_ply(out / "uncertainty_mesh.ply")
    rp.plot_shape(out, obj.shape, (um[0], um[1]), um[2], res.points, _posterior_shapes(out / "posterior.nc", 30))
    rp.plot_errors(out, res.records, true_volume=truth.volume)
    rp.plot_taxel_frames(out, recording, gains=gains)
    rp.plot_patch_posterior(out, patch_post)
    idata = az.from_netcdf(str(out / "posterior.nc"))
    rp.plot_trace(out, idata, ["a", "b", "c", "n", "sigma"])
    rp.plot_pair(out, idata, ["a", "b", "c", "n"])

    d = summary["diagnostics"]
    conv = (
        '<span class="ok">converged</span>'
        if d["converged"]
        else '<span class="bad">not converged</span> (the numbers below are from a chain that has not converged; '
        "run <code>bayestouch fit points.csv --out DIR --resume</code> to continue it)"
    )
    vol = summary["derived"]["volume_m3"]
    how = (
        "Its contacts are where rays meet the object, with the encoders' noise only (no bending chain)."
        if calibration is None
        else "It ran guarded strokes over the serial protocol. Its bending constants are its own (drawn at "
        f"{BEND_SPREAD:g}× their stated spread), so its pad goes where its bent rod puts it while the host computes "
        f"the pose from the models' constants; {_calibration_text(calibration)}. The pad's pose error is "
        f"marginalised with the calibrated law of {POSE_DRAWS} fingers, in every update and in the posterior below."
    )
    intro = (
        f"<p>The virtual finger explored <b>{obj.name}</b> ({obj.description}) with the <b>eig</b> planner: a "
        f"scout stroke and {len(res.records) - 1} planned strokes, {len(res.points)} contact points. {how} The "
        f"posterior of the shape is {conv}: max R-hat {d['max_r_hat']:.4f}, min bulk ESS "
        f"{d['min_ess_bulk']:.0f}, {d['n_samples']} samples, {d['seconds']:.0f} s.</p>"
        f'<p class="note">Volume {1e6 * vol["mean"]:.3f} cm³ (90 % interval {1e6 * vol["q05"]:.3f}–'
        f"{1e6 * vol['q95']:.3f}); the true object's {1e6 * truth.volume:.3f} cm³ is "
        f"{'inside' if vol['q05'] <= truth.volume <= vol['q95'] else 'outside'} it.</p>"
    )
    strokes = Table(
        "Per stroke (0 = scout): the posterior after each stroke",
        [
            "stroke",
            "points",
            "new",
            "EIG (nats)",
            "Chamfer / mean axis",
            "volume error",
            "volume sd (cm³)",
            "decision (s)",
            "update (s)",
        ],
        [
            [
                r.stroke,
                r.n_points,
                r.new_points,
                _fmt(r.eig),
                _fmt(r.chamfer),
                _fmt(r.volume_error),
                _fmt(1e6 * r.volume_sd),
                _fmt(r.decision_s, 2),
                _fmt(r.update_s, 2),
            ]
            for r in res.records
        ],
    )
    true_vals = _true_natural(obj)
    params = Table(
        "Shape posterior (SI units: metres, radians); angles are canonicalised (symmetry aliases folded)",
        ["parameter", "truth", "mean", "sd", "q05", "q95", "R-hat", "bulk ESS"],
        [
            [
                k,
                _fmt(true_vals.get(k), 4),
                _fmt(v["mean"], 4),
                _fmt(v["sd"], 2),
                _fmt(v["q05"], 4),
                _fmt(v["q95"], 4),
                f"{v['r_hat']:.4f}",
                f"{v['ess_bulk']:.0f}",
            ]
            for k, v in summary["parameters"].items()
        ],
    )
    der = summary["derived"]
    derived = Table(
        "Derived quantities (eq. 11–13)",
        ["quantity", "truth", "mean", "sd", "q05", "q95"],
        [
            [
                "volume (m³)",
                _fmt(truth.volume, 4),
                *(_fmt(der["volume_m3"][k], 4) for k in ("mean", "sd", "q05", "q95")),
            ],
            ["area (m²)", "–", *(_fmt(der["area_m2"][k], 4) for k in ("mean", "sd", "q05", "q95"))],
            [
                "surface spread (m), mean / q95 / max",
                "–",
                _fmt(der["surface_spread_m"]["mean"]),
                "–",
                _fmt(der["surface_spread_m"]["q95"]),
                _fmt(der["surface_spread_m"]["max"]),
            ],
        ],
    )
    pp = patch_summary["parameters"]
    pd = patch_summary["diagnostics"]
    patch = Table(
        f"Contact patch, frames {patch_summary['frames'][0]}–{patch_summary['frames'][1] - 1} of the "
        f"recording ({'converged' if pd['converged'] else 'not converged'}, max R-hat "
        f"{pd['max_r_hat']:.3f})",
        ["parameter", "mean", "sd", "q05", "q95"],
        [[k, _fmt(v["mean"], 4), _fmt(v["sd"], 2), _fmt(v["q05"], 4), _fmt(v["q95"], 4)] for k, v in pp.items()]
        + [
            [f"{k} (derived)", _fmt(v["mean"], 4), _fmt(v["sd"], 2), _fmt(v["q05"], 4), _fmt(v["q95"], 4)]
            for k, v in patch_summary["derived"].items()
        ],
    )
    sections = [
        (
            "Shape",
            [
                Figure(
                    "shape.png",
                    "Left: the posterior mean shape, coloured by the posterior spread of its "
                    "surface along the normal, with the contact points (red). Right: sections through the "
                    "centre: the true object (dashed), 30 posterior draws (thin blue) and the contacts near each "
                    "plane.",
                ),
                derived,
                params,
            ],
        ),
        (
            "Exploration",
            [
                Figure(
                    "errors.png",
                    "Error against strokes: Chamfer distance of the point estimate "
                    "(the median-volume draw) over the true mean semi-axis and its volume error; the "
                    "volume posterior (mean ± 2 sd) against the truth.",
                ),
                strokes,
            ],
        ),
        (
            "Taxels and contact patches",
            [
                Figure(
                    "taxel_currents.png",
                    "Taxel current images: Δ ln I of the most loaded frame of each stroke, "
                    "fixed-pattern gains divided out, relative to the unloaded reference rows (dots). The taxels "
                    "respond in the empirical mode (device-like sensitivity); the physics mode's response is far below "
                    "the noise (physics.md, finding 2).",
                ),
                Figure(
                    "contact_patch.png",
                    "Posterior of one contact patch (superellipse, eq. 16–18): outlines of "
                    "posterior draws on the pad and the marginals of a, b and n.",
                ),
                patch,
            ],
        ),
        (
            "Sampler diagnostics",
            [
                Figure(
                    "trace.png",
                    "Trace plots of the semi-axes, the exponent n and the noise scale σ (one line "
                    "per walker, burn-in removed).",
                ),
                Figure("pair.png", "Pair plot of the semi-axes and the exponent n (thinned draws)."),
            ],
        ),
    ]
    files = [
        "summary.json",
        "posterior.nc",
        "mean_shape.ply",
        "uncertainty_mesh.ply",
        "chain.h5",
        "points.csv",
        "recording.nc",
        "patch_summary.json",
        "demo.json",
    ]
    return write_report(
        out,
        title=f"bayestouch demo: {obj.name}, eig exploration",
        intro=intro,
        sections=sections,
        files=files,
        overwrite=True,  # the demo's folder is rebuilt by every run
    )


def _posterior_shapes(path: Path, count: int) -> list:
    """``count`` posterior draws of ``posterior.nc`` as n-ellipsoids (evenly spread over the chain)."""
    post = xr.open_dataset(path, group="posterior")
    cols = np.column_stack([np.asarray(post[k].values).ravel() for k in ne.PARAM_NAMES])
    post.close()
    idx = np.linspace(0, len(cols) - 1, count).astype(int)
    return [ne.from_vector(jnp.asarray(cols[i])) for i in idx]


def _true_natural(obj) -> dict:
    """The true object's parameters under the summary's names (canonical order of the axes is not applied)."""
    s = obj.shape
    c, a, ang = (np.asarray(x, float) for x in (s.centre, s.axes, s.angles))
    return {"x_G": c[0], "y_G": c[1], "z_G": c[2], "a": a[0], "b": a[1], "c": a[2], "n": float(s.n)}


def _read_ply(path: Path):
    """Vertices (V, 3) m, faces (F, 3) and the per-vertex ``spread`` (V,) m of an uncertainty mesh."""
    m = read_spread_mesh(path)
    spread = m.vertex_attributes.get("spread", np.zeros(len(m.vertices)))
    return np.asarray(m.vertices), np.asarray(m.faces), np.asarray(spread, float)


def _table(res, summary: dict, patch: dict, truth, page: Path, check, seconds: float, calibration=None) -> str:
    """The demo's result as text: the calibration, errors per stroke, the final posterior, the patch, the report."""
    lines = [_calibration_text(calibration)] if calibration is not None else []
    lines += [f"{'stroke':>6} {'points':>6} {'EIG':>7} {'chamfer':>8} {'vol.err':>8} {'vol.sd cm3':>10}"]
    for r in res.records:
        lines.append(
            f"{r.stroke:>6} {r.n_points:>6} {_fmt(r.eig):>7} {r.chamfer:>8.4f} {r.volume_error:>8.4f} "
            f"{1e6 * r.volume_sd:>10.4f}"
        )
    d, v = summary["diagnostics"], summary["derived"]["volume_m3"]
    lines.append(
        f"posterior: volume {1e6 * v['mean']:.3f} cm3 [{1e6 * v['q05']:.3f}, {1e6 * v['q95']:.3f}] "
        f"(truth {1e6 * truth.volume:.3f}); {'converged' if d['converged'] else 'NOT converged'} "
        f"(max R-hat {d['max_r_hat']:.4f}, min ESS {d['min_ess_bulk']:.0f})"
    )
    pa = patch["parameters"]
    lines.append(
        f"contact patch: a {1e3 * pa['a']['mean']:.2f} mm, b {1e3 * pa['b']['mean']:.2f} mm, n {pa['n']['mean']:.2f}"
    )
    seen = "" if check is None else f"; browser: {check.images_ok}/{check.images_total} images render"
    lines.append(f"report: {page}{seen}; {seconds:.0f} s")
    return "\n".join(lines)
