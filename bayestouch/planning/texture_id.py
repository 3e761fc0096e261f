"""Texture identification trials: which library texture is the finger stroking, and after how many strokes?

The loop and the experiment runner of ``bayestouch texture-id`` (science: ``docs/texture_identification.md``).
The pieces have their own homes: the library and the plate strokes in :mod:`bayestouch.scene.textures`, the
simulated truth in :mod:`bayestouch.physics.plate_strokes`, the discrete posterior in
:mod:`bayestouch.inference.texture_posterior`, the pairwise EIG in :mod:`bayestouch.planning.eig`, the results
file, task loop and Wilson interval in :mod:`bayestouch.planning.experiment`. What stays here is what planning
adds: the settings, the stroke choice, the stroke-by-stroke trial and its summary. The module keeps its name
(rather than ``texture_loop``) because ``bayestouch texture-id`` and the benchmark name it.

Units: metres, seconds, kelvin; posteriors are (K,) over the library's textures.
"""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.special import logsumexp

from bayestouch.backend import jax
from bayestouch.errors import BadInput, check_bool, check_path
from bayestouch.inference.raw import HostDevice, RawData, host_device
from bayestouch.inference.raw.priors import LAG_RANGE
from bayestouch.inference.texture_posterior import (
    read_stroke,
    texture_evidence,
    texture_means,
    update_posterior,
)
from bayestouch.io.device_file import DeviceCalibration, check_same_finger
from bayestouch.io.files import read_csv_rows, write_json, write_text
from bayestouch.io.runfolder import differences, fingerprint
from bayestouch.params import MODELS
from bayestouch.physics import taxel as tx
from bayestouch.physics.plate_strokes import known_finger, record_plate_stroke
from bayestouch.physics.virtual import VirtualFinger, finger_name, load_finger
from bayestouch.planning.eig import eig_pairwise
from bayestouch.planning.experiment import ResultsFile, run_tasks, wilson_interval
from bayestouch.scene.objects import SceneObject
from bayestouch.scene.surface import Surface
from bayestouch.scene.textures import LIBRARY, StrokeSpec, TextureLibrary, load_library, random_stroke_spec

__all__ = [
    "COLUMNS",
    "IdSettings",
    "record_stroke",
    "run_trial",
    "check_calibration",
    "read_results",
    "run_experiment",
    "summarise",
    "plot_accuracy",
]

#: columns of results.csv
COLUMNS = ("texture", "trial", "stroke", "p_true", "map_correct", "decided", "seconds", "map", "shift_m", "policy")
#: the run's key beside results.csv: what a ``resume`` must share with the trials it keeps
META = "texture_id.json"


@dataclass(frozen=True)
class IdSettings:
    """Settings of the identifier and of the simulated truth.

    Attributes
    ----------
    threshold : float
        Decide when max_k p(k | strokes) ≥ threshold.
    shift_range : float, metres
        Start-phase error of the truth ~ U(−range, range) per stroke; the identifier's prior over it.
    shift_step : float, metres
        Grid step of the marginalisation over the shift.
    temperature_sd : float, kelvin
        Per-stroke skin-temperature offset of the truth, unknown to the identifier.
    mode : {"empirical", "physics"}
        Taxel response mode of finger and identifier.
    noise : bool
        Simulate the read-out noise (False: every noise source zeroed and unit gains, for tests; the
        identifier still uses the modelled reading sd).
    nu : float
        Student-t degrees of freedom.
    noise_scale : float
        Multiplier on the modelled reading sd.
    correlated : bool
        Whiten each taxel's residuals over the frames of a stroke with the noise model's frame correlation
        (1/f and random walk, :func:`~bayestouch.inference.texture_posterior.frame_whitener`); False treats
        readings as independent (the raw likelihood's choice).
    radius, contact_radius : float, metres
        Taxel selection of :func:`bayestouch.inference.raw.load_raw_data`.
    speed, depth : float
        Defaults of random strokes (m/s, m).
    candidates : int
        Candidate strokes per ``eig`` decision.
    lag_cells : int
        The taxels' response lag is marginalised jointly with the texture over the midpoints of this many equal
        cells of its prior range (:data:`~bayestouch.inference.raw.priors.LAG_RANGE`); 0: the identifier's own
        lag (models/) is taken as known.
    speeds, depths : tuple of float
        Candidate sets of the ``eig`` policy (m/s, m).
    """

    threshold: float = 0.95
    shift_range: float = 5e-4
    shift_step: float = 2.5e-5
    temperature_sd: float = 0.5
    mode: str = "empirical"
    noise: bool = True
    nu: float = 4.0
    noise_scale: float = 1.0
    radius: float = 4.5e-3
    contact_radius: float = 3.2e-3
    speed: float = 0.01
    depth: float = 3e-4
    correlated: bool = True
    candidates: int = 16
    speeds: tuple[float, ...] = (0.005, 0.01, 0.02)
    depths: tuple[float, ...] = (2e-4, 3e-4, 4e-4)
    lag_cells: int = 3

    def lags(self) -> np.ndarray:
        """The lags (L,) s marginalised: the midpoints of ``lag_cells`` equal cells of the prior range (empty when
        ``lag_cells`` is 0)."""
        lo, hi = LAG_RANGE
        return lo + (hi - lo) * (np.arange(self.lag_cells) + 0.5) / max(self.lag_cells, 1)

    def shifts(self) -> np.ndarray:
        """The shift grid (G,) metres, symmetric about 0 and including it."""
        m = int(np.floor(self.shift_range / self.shift_step + 1e-9))
        return self.shift_step * np.arange(-m, m + 1)

    def check(self) -> IdSettings:
        """Self, or :class:`BadInput` naming the bad setting."""
        if not 0.5 < self.threshold < 1.0:
            raise BadInput(f"--threshold must be in (0.5, 1), got {self.threshold}")
        if self.mode not in ("empirical", "physics"):
            raise BadInput(f"--mode must be empirical or physics, got {self.mode!r}")
        if not (self.shift_range >= 0 and self.shift_step > 0):
            raise BadInput("shift_range must be ≥ 0 and shift_step > 0 (metres)")
        if isinstance(self.lag_cells, bool) or not isinstance(self.lag_cells, int) or not 0 <= self.lag_cells <= 16:
            raise BadInput(f"lag_cells must be an integer from 0 to 16, got {self.lag_cells!r}")
        return self


def record_stroke(
    obj: SceneObject,
    spec: StrokeSpec,
    vf: VirtualFinger,
    rng: np.random.Generator,
    settings: IdSettings,
    device: HostDevice | None = None,
    *,
    finger=None,
) -> tuple[RawData, np.ndarray, float]:
    """Simulate one stroke over the textured ``obj`` with the truth's nuisances, and read it as the identifier does.

    Parameters
    ----------
    obj : SceneObject
        The object with its true texture.
    spec : StrokeSpec
        The commanded stroke.
    vf : VirtualFinger
        The simulated truth (:func:`bayestouch.physics.virtual.load_finger`); with ``settings.noise`` False its
        gains are taken as 1.
    device : HostDevice, optional
        The identifier's device (:func:`bayestouch.inference.raw.host_device`; default the models' constants with
        unit gains and their nominal spread): nothing of ``vf`` reaches the reading but its readings.
    finger : Finger, optional
        Read with this device known exactly instead (its gains taken as they are): for checks of the simulator
        and the noise model only, e.g. :func:`~bayestouch.physics.plate_strokes.known_finger` of ``vf`` — an
        identifier never has it.
    rng : numpy Generator
        Draws the shift, the temperature offset and the noise key
        (:func:`~bayestouch.physics.plate_strokes.record_plate_stroke`).
    settings : IdSettings

    Returns
    -------
    data : RawData
        Corrected ln I and its noise sd at the commanded (known) taxel positions.
    tangent : (3,) float
        Direction of the stroke (world frame).
    shift : float, metres
        The truth's start-phase error.
    """
    rec = record_plate_stroke(
        obj,
        spec,
        vf,
        rng,
        shift_range=settings.shift_range,
        temperature_sd=settings.temperature_sd,
        mode=settings.mode,
        noise=settings.noise,
    )
    if finger is None and device is None:
        device = host_device()
    data = read_stroke(
        rec.frames,
        finger,
        settings.mode,
        radius=settings.radius,
        contact_radius=settings.contact_radius,
        device=device,
    )
    return data, rec.tangent, rec.shift


def _choose_eig(lib: TextureLibrary, surfs: Surface, vf, settings: IdSettings, rng, log_post, device: HostDevice):
    """The candidate stroke with the largest :func:`~bayestouch.planning.eig.eig_pairwise` under the current
    posterior: μ_k the noise-free prediction at zero shift (``device``'s, with ``vf`` noise-free and of unit
    gains as the simulator of the candidates' kinematics) of the textures holding 99.9 % of the mass."""
    post = np.exp(log_post)
    order = np.argsort(post)[::-1]
    keep = order[: int(np.searchsorted(np.cumsum(post[order]), 0.999) + 1)]
    if len(keep) < 2:
        keep = order[:2]
    sub = surfs._replace(texture=jax.tree.map(lambda a: a[keep], surfs.texture))
    clean = replace(settings, noise=False, temperature_sd=0.0, shift_range=0.0)
    quiet = known_finger(vf, clean.noise)  # noise-free, unit gains: only the candidates' kinematics
    best, best_spec = -np.inf, None
    for _ in range(settings.candidates):
        spec = random_stroke_spec(
            lib.base, rng, speed=float(rng.choice(settings.speeds)), depth=float(rng.choice(settings.depths))
        )
        data, _, _ = record_stroke(lib.base, spec, vf, np.random.default_rng(0), clean, finger=quiet)
        mu = texture_means(sub, data, device.finger)
        sd = settings.noise_scale * np.asarray(data.noise_sd).ravel()
        val = eig_pairwise(post[keep] / post[keep].sum(), mu, sd)
        if val > best:
            best, best_spec = val, spec
    return best_spec, best


def run_trial(
    lib: TextureLibrary,
    true_k: int,
    trial: int,
    seed: int,
    vf: VirtualFinger,
    *,
    max_strokes: int = 10,
    settings: IdSettings = IdSettings(),
    policy: str = "random",
    stop_at_decision: bool = True,
    surfs: Surface | None = None,
    device: HostDevice | None = None,
) -> list[dict]:
    """Identify texture ``true_k`` stroke by stroke; one row per stroke (:data:`COLUMNS`).

    The decision is latched at the first stroke where the posterior's maximum reaches ``settings.threshold``;
    with ``stop_at_decision`` the trial ends there. Randomness: ``np.random.default_rng((seed, true_k, trial))``.

    Parameters
    ----------
    lib : TextureLibrary
    true_k : int
        Index of the true texture.
    trial, seed : int
    vf : VirtualFinger
    max_strokes : int
        Strokes before a forced decision.
    settings : IdSettings
    policy : {"random", "eig"}
        Stroke choice (``eig``: from the second stroke on, :func:`~bayestouch.planning.eig.eig_pairwise` over
        ``settings.candidates`` random candidates).
    stop_at_decision : bool
    surfs : Surface, optional
        ``lib.surfaces()`` (computed when not given).
    device : HostDevice, optional
        The identifier's device (:func:`bayestouch.inference.raw.host_device`, the default: the models'
        constants, unit gains and their nominal spread, marginalised). ``vf`` is only the simulated truth.

    Returns
    -------
    list of dict
        ``p_true`` the posterior of the truth, ``map_correct`` and ``decided`` 0/1, ``seconds`` the stroke's wall
        time, ``shift_m`` the truth's start-phase error (metres).
    """
    if policy not in ("random", "eig"):
        raise BadInput(f"--policy must be random or eig, got {policy!r}")
    settings = settings.check()
    surfs = lib.surfaces() if surfs is None else surfs
    rng = np.random.default_rng((int(seed), int(true_k), int(trial)))
    obj = lib.object(true_k)
    device = host_device() if device is None else device
    shifts = settings.shifts()
    lags = settings.lags()
    # the joint posterior over (texture, lag): the lag is one and the same in every stroke of the finger
    log_joint = np.full((len(lib), max(len(lags), 1)), -np.log(len(lib) * max(len(lags), 1)))
    log_post = logsumexp(log_joint, axis=1)
    rows, decided = [], False
    for s in range(1, max_strokes + 1):
        t0 = time.perf_counter()
        if policy == "eig" and s > 1:
            spec, _ = _choose_eig(lib, surfs, vf, settings, rng, log_post, device)
        else:
            spec = random_stroke_spec(lib.base, rng, speed=settings.speed, depth=settings.depth)
        data, tangent, shift = record_stroke(obj, spec, vf, rng, settings, device)
        evidence = texture_evidence(
            surfs,
            data,
            device.finger,
            shifts,
            tangent,
            nu=settings.nu,
            noise_scale=settings.noise_scale,
            correlated=settings.correlated,
            lags=np.stack([tx.coarse_lag_weights(float(data.dt), float(t), 1) for t in lags]) if len(lags) else None,
        )
        log_joint = update_posterior(log_joint, np.reshape(evidence, log_joint.shape))
        log_post = logsumexp(log_joint, axis=1)
        post = np.minimum(np.exp(log_post), 1.0)  # a marginal of 1 + 3e-13 after the sum over lags
        k_map = int(np.argmax(post))
        decided = decided or bool(post[k_map] >= settings.threshold)
        rows.append(
            {
                "texture": lib.names[true_k],
                "trial": int(trial),
                "stroke": s,
                "p_true": float(post[true_k]),
                "map_correct": int(k_map == true_k),
                "decided": int(decided),
                "seconds": time.perf_counter() - t0,
                "map": lib.names[k_map],
                "shift_m": shift,
                "policy": policy,
            }
        )
        if decided and stop_at_decision:
            break
    return rows


def summarise(rows: list[dict], max_strokes: int, threshold: float) -> dict:
    """Accuracy at decision, strokes to decision, accuracy against strokes (latched after a decision).

    A trial's outcome after s strokes is its MAP after min(s, its last stroke) strokes: after a decision
    (and the trial's end) the decision stands. Undecided trials are forced to their MAP after ``max_strokes``;
    their strokes to decision are counted as ``max_strokes`` in the median (so the median is a lower bound when
    fewer than half decided). The 95 % interval of the accuracy is Wilson's score interval
    (:func:`~bayestouch.planning.experiment.wilson_interval`).

    Parameters
    ----------
    rows : list of dict
        Rows of :func:`run_trial` (values may be the strings of a read-back CSV).
    max_strokes : int
    threshold : float

    Returns
    -------
    dict
        The keys of ``summary.json`` other than the run's own (policy, seed, seconds, library, settings).
    """
    trials: dict = {}
    for r in rows:
        trials.setdefault((r["texture"], int(r["trial"])), []).append(r)
    outcome, strokes, decided = [], [], []
    curve = np.zeros(max_strokes)
    for rs in trials.values():
        rs = sorted(rs, key=lambda r: int(r["stroke"]))
        dec = [r for r in rs if int(r["decided"])]
        last = dec[0] if dec else rs[-1]
        outcome.append(int(last["map_correct"]))
        strokes.append(int(last["stroke"]) if dec else max_strokes)
        decided.append(bool(dec))
        for s in range(1, max_strokes + 1):
            upto = [r for r in rs if int(r["stroke"]) <= s]
            curve[s - 1] += int(upto[-1]["map_correct"])
    n = len(outcome)
    acc = float(np.mean(outcome)) if n else float("nan")
    lo, hi = wilson_interval(int(np.sum(outcome)), n)
    dec_ok = [o for o, d in zip(outcome, decided, strict=True) if d]
    return {
        "trials": n,
        "textures": len({t for t, _ in trials}),
        "threshold": threshold,
        "max_strokes": max_strokes,
        "accuracy_at_decision": acc,
        "accuracy_95ci": [lo, hi],
        "decided_fraction": float(np.mean(decided)) if n else float("nan"),
        "accuracy_of_decided": float(np.mean(dec_ok)) if dec_ok else float("nan"),
        "median_strokes_to_decision": float(np.median(strokes)) if n else float("nan"),
        "mean_strokes_to_decision": float(np.mean(strokes)) if n else float("nan"),
        "accuracy_vs_strokes": [float(c / n) for c in curve] if n else [],
        "target": "accuracy >= 0.95 with median strokes <= 5 (Fishel & Loeb 2012: 95.4 % on 117 textures, median 5)",
    }


def plot_accuracy(summary: dict, path) -> Path:
    """``accuracy_vs_strokes.png``: fraction correct against strokes (latched decisions), with the target.

    Parameters
    ----------
    summary : dict
        From :func:`summarise`.
    path : path
        The PNG written.

    Returns
    -------
    Path
    """
    from bayestouch.report import canvas

    acc = summary["accuracy_vs_strokes"]
    s = np.arange(1, len(acc) + 1)
    fig, ax = canvas.subplots(figsize=(5, 3.5))
    ax.plot(s, acc, "o-", label=f"{summary['textures']} textures, {summary['trials']} trials")
    ax.axhline(0.95, color="k", ls="--", lw=0.8, label="target 95 %")
    ax.axvline(summary["median_strokes_to_decision"], color="C1", ls=":", label="median strokes to decision")
    ax.set_xlabel("strokes")
    ax.set_ylabel("fraction correct (MAP, latched at decision)")
    ax.set_ylim(0, 1.02)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    return path


def check_calibration(calibration: DeviceCalibration | None, mode: str, seed: int) -> None:
    """Refuse (:class:`BadInput`) a device file made in another taxel ``mode`` or on another finger than the
    simulated one that ``seed`` draws (when the file names its finger)."""
    if calibration is None:
        return
    if calibration.mode != mode:
        raise BadInput(f"--calibration: made in the {calibration.mode} taxel mode, not --mode {mode}")
    simulated = finger_name(int(seed))
    check_same_finger(
        calibration, simulated, "the strokes are simulated on", field="--calibration", note=f" (--seed {seed})"
    )


def run_experiment(
    out,
    *,
    textures: int = 20,
    trials: int = 3,
    max_strokes: int = 10,
    seed: int = 0,
    settings: IdSettings = IdSettings(),
    policy: str = "random",
    library=LIBRARY,
    stop_at_decision: bool = True,
    progress: bool = True,
    calibration: DeviceCalibration | None = None,
    finger_models=MODELS,
    resume: bool = False,
) -> dict:
    """Every one of the first ``textures`` library entries is the truth in ``trials`` trials.

    Writes ``out/results.csv`` (:data:`COLUMNS`, rewritten after every trial), ``out/summary.json`` and
    ``out/accuracy_vs_strokes.png``; trials run in this process, trial-major (every texture of trial 0 first).

    Parameters
    ----------
    out : path
        Output folder (created).
    textures, trials, max_strokes, seed : int
    settings : IdSettings
    policy : {"random", "eig"}
    library : path
        Texture library TOML (:func:`bayestouch.scene.textures.load_library`).
    stop_at_decision : bool
        End each trial at its decision (False: stroke on to ``max_strokes``).
    progress : bool
        Show a progress bar over the trials.
    calibration : DeviceCalibration, optional
        The identifier's device file (``bayestouch calibrate``; its taxel mode must be ``settings.mode``); without
        it the identifier knows the models' constants with unit gains and their nominal spread. The simulated
        finger's own gains (drawn from ``seed``) are never read.
    finger_models : path
        Parameter folder of the simulated finger (the truth; default ``models/``). The identifier always assumes
        ``models/``: a folder whose constants differ tries it on a finger that is not the one it knows.
    resume : bool
        Keep the trials already in ``out/results.csv`` (each is written whole when it ends) and run only the rest;
        refused (:class:`BadInput`) when ``out/texture_id.json`` shows they were made with another library, finger,
        device file, seed, number of textures (the candidates of every trial's posterior) or setting, when it holds
        more trials than ``trials``, or when its rows are not whole trials (a damaged file). More ``trials`` than
        before extend the run (each trial's randomness depends only on seed, texture and trial).

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    check_path(out, "out")
    check_bool(resume, "resume")
    if trials < 1 or max_strokes < 1:
        raise BadInput(f"--trials and --max-strokes must be ≥ 1, got {trials} and {max_strokes}")
    lib = load_library(library).subset(textures)
    settings = settings.check()
    check_calibration(calibration, settings.mode, seed)
    out = Path(out)
    vf = load_finger(Path(finger_models), seed=int(seed))
    device = host_device(calibration=calibration)
    if np.shape(vf.finger.grid) != np.shape(device.finger.grid):  # an exit 1 in the recording's assembly before
        raise BadInput(
            f"--finger-models {finger_models}: a finger of {np.shape(vf.finger.grid)[0]}×{np.shape(vf.finger.grid)[1]}"
            f" taxels; the identifier's (models/) has {np.shape(device.finger.grid)[0]}×"
            f"{np.shape(device.finger.grid)[1]}, and reads only that layout"
        )
    out.mkdir(parents=True, exist_ok=True)
    plain = {k: (list(v) if isinstance(v, tuple) else v) for k, v in settings.__dict__.items()}  # JSON values
    rest = dict(plain)
    # named as the command line names them (a refused resume names the flag that differs); only --trials may
    # differ: each trial's rows depend on the candidate textures, the seed and the settings, not on other trials
    options = {
        "--seed": int(seed),
        "--textures": len(lib),
        "--max-strokes": int(max_strokes),
        "--policy": str(policy),
        "--full": not stop_at_decision,
        "--threshold": rest.pop("threshold"),
        "--mode": rest.pop("mode"),
        "settings": rest,
    }
    meta = fingerprint("texture-id", _inputs(library, finger_models, calibration), options)
    kept = _kept_rows(out, meta, trials, int(max_strokes), stop_at_decision) if resume else []
    write_json(out / META, meta)
    surfs = lib.surfaces()
    t0 = time.perf_counter()
    results = ResultsFile(out / "results.csv", COLUMNS, kept)
    done = {(r["texture"], int(r["trial"])) for r in kept}
    tasks = [(k, tr) for tr in range(trials) for k in range(len(lib)) if (lib.names[k], tr) not in done]

    def one(task):
        k, tr = task
        return run_trial(
            lib,
            k,
            tr,
            seed,
            vf,
            max_strokes=max_strokes,
            settings=settings,
            policy=policy,
            stop_at_decision=stop_at_decision,
            surfs=surfs,
            device=device,
        )

    run_tasks(tasks, one, results.add, progress="texture trials" if progress else None)
    summary = summarise(results.rows, max_strokes, settings.threshold)
    summary.update(
        {
            "policy": policy,
            "seed": int(seed),
            "seconds": time.perf_counter() - t0,
            "trials_kept": len(done),
            "library": [str(n) for n in lib.names],
            # what the identifier knew of the finger (never the simulated finger's own gains)
            "device": "nominal: models/ constants, unit gains marginalised with their nominal spread"
            if calibration is None
            else f"device file: gains and their errors of a {calibration.mode}-mode calibration",
            "settings": plain,
            "finger_models": str(finger_models),
        }
    )
    write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    plot_accuracy(summary, out / "accuracy_vs_strokes.png")
    return summary


def _inputs(library, finger_models, calibration: DeviceCalibration | None) -> dict:
    """The inputs a resumed run must share with the trials it keeps, as bytes: the library file, the simulated
    finger's parameter files and the identifier's device file."""
    folder = Path(finger_models)
    models = b"".join(f.name.encode() + b"\0" + f.read_bytes() for f in sorted(folder.glob("*.toml")))
    cal = None
    if calibration is not None:
        cal = (
            np.asarray(calibration.log_gain, float).tobytes()
            + np.asarray(calibration.log_gain_sd, float).tobytes()
            + repr(
                (
                    float(calibration.noise_scale),
                    calibration.mode,
                    float(calibration.response_scale),
                    calibration.response_scale_sd,
                )
            ).encode()
        )
    return {"--library file": Path(library).read_bytes(), "--finger-models files": models, "--calibration file": cal}


def read_results(path) -> list[dict]:
    """The rows of a texture-id ``results.csv``, typed as :func:`run_trial` returns them; a damaged file is refused
    (:class:`BadInput` naming the line and column)."""
    rows = []
    for i, r in enumerate(read_csv_rows(path)):
        line = i + 2  # the header is line 1
        missing = [c for c in COLUMNS if c not in r]
        if missing:
            raise BadInput(f"{path}: line {line} lacks column(s) {missing}; expected {', '.join(COLUMNS)}")
        try:
            row = {
                "texture": r["texture"],
                "trial": int(r["trial"]),
                "stroke": int(r["stroke"]),
                "p_true": float(r["p_true"]),
                "map_correct": int(r["map_correct"]),
                "decided": int(r["decided"]),
                "seconds": float(r["seconds"]),
                "map": r["map"],
                "shift_m": float(r["shift_m"]),
                "policy": r["policy"],
            }
        except ValueError as e:
            raise BadInput(f"{path}: line {line}: {e} (a damaged file)") from None
        if row["trial"] < 0 or row["stroke"] < 1 or not 0 <= row["p_true"] <= 1 + 1e-9:
            raise BadInput(f"{path}: line {line}: trial ≥ 0, stroke ≥ 1 and p_true in [0, 1] expected (a damaged file)")
        if row["map_correct"] not in (0, 1) or row["decided"] not in (0, 1):
            raise BadInput(f"{path}: line {line}: map_correct and decided must be 0 or 1 (a damaged file)")
        if row["map_correct"] != int(row["map"] == row["texture"]):
            raise BadInput(
                f"{path}: line {line}: map_correct {row['map_correct']} but map is {row['map']!r} for "
                f"texture {row['texture']!r} (a damaged file)"
            )
        rows.append(row)
    return rows


def _kept_rows(out: Path, meta: dict, trials: int, max_strokes: int, stop_at_decision: bool) -> list[dict]:
    """The finished trials of an earlier run in ``out`` that a resume keeps (every trial in results.csv is whole:
    the file is rewritten when a trial ends); refused when the earlier run's key differs from ``meta``, when it holds
    more trials than ``trials`` (its summary would be replaced by a subset's), or when a trial is not one that the
    run writes (a damaged file)."""
    csv_path = out / "results.csv"
    if csv_path.exists() and not csv_path.is_file():
        raise BadInput(f"--out {out}: {csv_path} is not a file; expected the results.csv of a texture-id run")
    if not csv_path.is_file():
        return []
    old = None
    with contextlib.suppress(OSError, ValueError):
        old = json.loads((out / META).read_text(encoding="utf-8"))
    if not isinstance(old, dict) or "options" not in old or old.get("level") != meta["level"]:
        raise BadInput(
            f"--resume: cannot verify the settings of {csv_path}: {META} is missing or damaged; expected the "
            f"{META} written with it (or pass --overwrite, or choose another --out)"
        )
    diff = differences(old, meta)
    if diff:
        raise BadInput(
            f"--resume: {csv_path} was made with {'; '.join(diff)}; resume with the same settings or choose another "
            "--out"
        )
    rows = read_results(csv_path)
    by_trial: dict[tuple, list[dict]] = {}
    for r in rows:
        by_trial.setdefault((r["texture"], r["trial"]), []).append(r)
    for (texture, trial), rs in by_trial.items():
        rs = sorted(rs, key=lambda r: r["stroke"])
        ss, dec = [r["stroke"] for r in rs], [r["decided"] for r in rs]
        where = f"--resume: {csv_path}: trial {trial} of {texture}"
        if ss != list(range(1, len(ss) + 1)):
            raise BadInput(f"{where} has strokes {ss}; expected 1, 2, … once each (a damaged file)")
        if any(a > b for a, b in zip(dec, dec[1:], strict=False)):
            raise BadInput(f"{where} is decided and then undecided (a damaged file)")
        ends = ss[-1] == max_strokes or (stop_at_decision and dec[-1] == 1 and dec.count(1) == 1)
        if not ends or len(ss) > max_strokes:
            raise BadInput(
                f"{where} ends at stroke {ss[-1]}, neither at its decision nor at --max-strokes {max_strokes} (a "
                "damaged file)"
            )
    most = max((t for _, t in by_trial), default=-1) + 1
    if most > trials:
        raise BadInput(
            f"--resume: {csv_path} holds {most} trials per texture, more than --trials {trials}; resume with "
            f"--trials {most} or more (a resume extends a run, it does not cut it)"
        )
    return rows
