"""Exploration experiments: objects × planners × seeded trials, in parallel, into ``DIR/results.csv``.

Each task (object, planner, trial) runs :func:`bayestouch.planning.loop.explore` with seed ``(seed, trial)``:
every planner of one trial and object starts from the same scout and initial fit. Tasks run in a process pool
(``spawn``: JAX does not survive ``fork`` after initialisation; 2 workers by default), in this process
(``workers=1``), or on a Dask cluster (``scheduler="tcp://HOST:PORT"``, ``dask[distributed]`` installed). The
parent collects finished trials and rewrites ``results.csv`` atomically after each
(:func:`bayestouch.io.files.write_csv_rows`), so a killed worker or run loses no finished trial; ``resume=True`` keeps
the trials already complete in an existing ``results.csv`` and runs only the others. The folder is locked while
the experiment runs (:func:`bayestouch.io.runfolder.locked_run_folder`): a second run into it is refused.

``results.csv`` columns: :data:`COLUMNS` (one row per stroke, stroke 0 the scout); ``error_vs_strokes.png``:
median and 25–75 % band of the Chamfer distance and the volume error against strokes, one line per planner.

The machinery is shared with the texture identification experiment (:mod:`bayestouch.planning.texture_id`):
:class:`ResultsFile` (rows rewritten after every trial), :func:`run_tasks` (here, pool or Dask, with an optional
progress bar) and :func:`wilson_interval`.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import math
import multiprocessing as mp
import os
import socket
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from bayestouch.backend import release_compiled
from bayestouch.errors import BadInput, check_bool, check_bools, check_path, shown
from bayestouch.io.files import read_csv_rows, set_aside, write_csv_rows, write_json
from bayestouch.io.runfolder import differences, fingerprint, locked_run_folder
from bayestouch.physics import bending, pose, sma
from bayestouch.planning.device_prober import VirtualFingerProber, calibrate_bending
from bayestouch.planning.loop import ExploreSettings, check_settings, explore, settings_from
from bayestouch.planning.policies import check_policy
from bayestouch.scene.objects import OBJECTS_DIR, SceneObject, load_object, object_from_dict, resolve_object

__all__ = [
    "COLUMNS",
    "run_trial",
    "run_experiment",
    "resolve_object",
    "plot_results",
    "gap_closed",
    "OBJECTS",
    "ResultsFile",
    "run_tasks",
    "wilson_interval",
    "checked_rows",
    "FINITE_COLUMNS",
]

_log = logging.getLogger(__name__)

#: the columns of results.csv
COLUMNS = (
    "planner",
    "trial",
    "object",
    "stroke",
    "chamfer",
    "volume_error",
    "seconds",
    "n_points",
    "new_points",
    "volume_sd",
    "eig",
    "decision_s",
    "seed",
)
#: how a trial's strokes are measured: ``rays`` on the simulated object (the planner's own ray world, noise along
#: the ray), ``finger`` as guarded strokes on a virtual finger over the serial protocol
#: (:class:`~bayestouch.planning.device_prober.VirtualFingerProber`)
PROBERS = ("rays", "finger")
#: most trials of one experiment (each is seconds to minutes of work and a task object in memory)
MAX_TRIALS = 100_000
#: seconds to wait for a Dask scheduler to answer
SCHEDULER_TIMEOUT_S = 10.0
#: default objects (models/objects/<name>.toml)
OBJECTS = ("egg", "sphere", "box", "cylinder")


#: largest ``bend_spread`` (times the bending constants' stated spread) an experiment takes
MAX_BEND_SPREAD = 3.0


@functools.cache
def calibration_object() -> SceneObject:
    """The known object a trial's finger is calibrated on (``bend_calibration``): a sphere of 2 cm radius in its
    fixture at the origin (built on first use: it holds JAX arrays)."""
    shape = {"centre_m": [0.0, 0.0, 0.0], "axes_m": [0.02] * 3, "n": 2.0}
    return object_from_dict({"object": {"name": "calibration sphere"}, "shape": shape})


def trial_finger(seed: int, bend_spread: float):
    """The bending constants (wire, rod) of a trial's virtual finger: drawn with the trial's ``seed`` at
    ``bend_spread`` times :class:`~bayestouch.physics.pose.FingerSpread` about ``models/finger.toml``'s (the same
    finger for every planner of the trial: paired), or None for 0 (the models' constants)."""
    if not bend_spread:
        return None
    rng = np.random.default_rng([int(seed), 0xBE4D])
    wire, rod = sma.load_wire(), bending.load_rod()
    return pose.draw_finger(rng, wire, rod, pose.FingerSpread().widened(float(bend_spread)))


def run_trial(task: dict) -> list[dict]:
    """Run one (object, planner, trial) and return its rows (a top-level function: picklable for pools). The task
    carries the :class:`~bayestouch.scene.objects.SceneObject` itself (``scene_object``), not a file path."""
    # before the trial's virtual finger starts: dropped programs compiled again in the middle of a stroke could trip
    # the device's watchdog
    release_compiled()
    obj = task["scene_object"]
    settings = ExploreSettings(**task.get("settings", {}))
    if task.get("prober", "rays") == "finger":
        finger = trial_finger(task["seed"], task.get("bend_spread", 0.0))
        law = None
        if task.get("bend_calibration"):
            sphere = calibration_object()
            with VirtualFingerProber(sphere, seed=task["seed"], finger=finger) as cal:
                law = calibrate_bending(cal, sphere, seed=task["seed"]).law
        carrier = bool(task.get("carrier", False))
        with VirtualFingerProber(obj, seed=task["seed"], finger=finger, pose_law=law, carrier=carrier) as prober:
            res = explore(obj, task["planner"], task["budget"], seed=task["seed"], settings=settings, prober=prober)
    else:
        res = explore(obj, task["planner"], task["budget"], seed=task["seed"], settings=settings)
    return [
        {
            "planner": task["planner"],
            "trial": task["trial"],
            "object": task["object"],
            "stroke": r.stroke,
            "chamfer": r.chamfer,
            "volume_error": r.volume_error,
            "seconds": r.seconds,
            "n_points": r.n_points,
            "new_points": r.new_points,
            "volume_sd": r.volume_sd,
            "eig": r.eig,
            "decision_s": r.decision_s,
            "seed": task["seed"],
        }
        for r in res.records
    ]


class ResultsFile:
    """An experiment's ``results.csv``: its rows in memory, the file rewritten atomically after every finished trial
    (:func:`bayestouch.io.files.write_csv_rows`), so a killed run loses no finished trial.

    Parameters
    ----------
    path : path
        The CSV file.
    columns : sequence of str
        Its columns, in order.
    rows : sequence of dict, optional
        Rows kept from an earlier run.
    order : callable, optional
        Sort key of the rows (None: in order of arrival).
    """

    def __init__(self, path, columns: Sequence[str], rows=(), order: Callable | None = None):
        self.path = Path(path)
        self.columns = tuple(columns)
        self.rows: list[dict] = list(rows)
        self.order = order

    def write(self) -> Path:
        """Write every row now."""
        return write_csv_rows(self.path, self.rows, self.columns)

    def add(self, new_rows: Sequence[dict]) -> None:
        """Append one finished trial's rows (re-sorted with ``order``) and rewrite the file."""
        self.rows.extend(new_rows)
        if self.order is not None:
            self.rows.sort(key=self.order)
        self.write()


def run_tasks(
    tasks: Sequence,
    run: Callable,
    finished: Callable,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    progress: str | None = None,
) -> None:
    """Run ``run(task)`` for every task and hand each result to ``finished`` (in this process) as it arrives.

    Parameters
    ----------
    tasks : sequence
        One item per trial.
    run : callable
        task → result; a top-level (picklable) function when ``workers > 1`` or with ``scheduler``.
    finished : callable
        Called with each result, in order of completion (task order when run here).
    workers : int
        Processes of a ``spawn`` pool (1: run here, in order).
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a Dask scheduler (needs ``dask[distributed]``).
    progress : str, optional
        Label of a progress bar over the tasks run here (None: no bar).
    """
    if scheduler is not None:
        _run_dask(scheduler, tasks, run, finished)
    elif workers == 1 or len(tasks) <= 1:
        for t in tqdm(tasks, desc=progress, unit="trial", disable=progress is None):
            finished(run(t))
    else:
        _run_pool(workers, tasks, run, finished)


def wilson_interval(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson's score interval (lo, hi) of a proportion ``k`` of ``n`` (95 % for the default ``z``); NaNs for n = 0."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return float(c - h), float(c + h)


#: results.csv columns that every row holds as a finite number (``volume_sd`` and ``eig`` may be nan: no posterior
#: spread yet, or a planner without an information gain)
FINITE_COLUMNS = ("chamfer", "volume_error", "seconds", "n_points", "new_points", "decision_s")


def checked_rows(rows: list[dict], path) -> list[dict]:
    """The rows of an experiment's ``results.csv`` ``path``, refused (:class:`BadInput` naming the line and column)
    when one is damaged: a missing column, a trial or stroke that is not a whole number ≥ 0, a seed that is not a
    whole number, a measure that is not a (finite) number, or a stroke of a trial listed twice."""
    seen: dict[tuple, int] = {}
    for i, r in enumerate(rows):
        line = i + 2  # the header is line 1
        missing = [c for c in COLUMNS if c not in r or r[c] is None]
        if missing:
            raise BadInput(f"{path}: line {line} lacks column(s) {missing}; expected {', '.join(COLUMNS)}")

        def bad(col: str, expected: str, line=line, r=r) -> BadInput:
            return BadInput(f"{path}: line {line}, column {col}: {r[col]!r} is not {expected} (a damaged file)")

        for col in ("trial", "stroke"):
            if not str(r[col]).isdigit():
                raise bad(col, "a whole number ≥ 0")
        if str(r["seed"]) not in ("",) and not str(r["seed"]).isdigit():
            raise bad("seed", "a whole number")
        if not str(r["planner"]).strip() or not str(r["object"]).strip():
            raise bad("planner" if not str(r["planner"]).strip() else "object", "a name")
        for col in (*FINITE_COLUMNS, "volume_sd", "eig"):
            try:
                v = float(r[col])
            except ValueError:
                raise bad(col, "a number") from None
            if col in FINITE_COLUMNS and not math.isfinite(v):
                raise bad(col, "a finite number")
        key = (*_key(r), int(r["stroke"]))
        if key in seen:
            raise BadInput(
                f"{path}: line {line} repeats stroke {key[3]} of trial {key[2]} ({key[0]}, {key[1]}) from line "
                f"{seen[key]} (a damaged file: each stroke of a trial is one row)"
            )
        seen[key] = line
    return rows


def _key(row) -> tuple:
    return str(row["object"]), str(row["planner"]), int(row["trial"])


def _complete(rows: list[dict], budget: int) -> set:
    """Trials of ``rows`` that reached ``budget`` strokes."""
    return {_key(r) for r in rows if int(r["stroke"]) == budget}


def _trial_seed(seed: int, trial: int) -> int:
    return int(np.random.SeedSequence([seed, trial]).generate_state(1)[0] % (2**31 - 1))


def run_experiment(
    out,
    *,
    planners=("eig", "random", "oracle"),
    objects=OBJECTS,
    trials: int = 3,
    budget: int = 5,
    seed: int = 0,
    workers: int = 2,
    scheduler: str | None = None,
    resume: bool = False,
    overwrite: bool = False,
    settings: dict | None = None,
    prober: str = "rays",
    bend_spread: float = 0.0,
    bend_calibration: bool = False,
    carrier: bool = False,
    plot: bool = True,
    log=None,
) -> dict:
    """Run the experiment and write ``out/results.csv`` (and ``out/error_vs_strokes.png``).

    Parameters
    ----------
    out : path
        Output folder (created).
    planners : sequence of str
        Policies (:data:`bayestouch.planning.policies.POLICIES`).
    objects : sequence of str or str
        Object names or TOML paths (at least one; a string is split at commas, as ``--objects``).
    trials, budget, seed : int
        Seeded trials per (object, planner); planned strokes per trial (after the scout); the base seed.
    workers : int
        Processes (1: run here, in order).
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a Dask scheduler (needs ``dask[distributed]``).
    resume : bool
        Keep the complete trials of an existing ``results.csv`` and run only the others; refused when they were
        made with another seed, budget or settings (``experiment.json``).
    overwrite : bool
        Replace an existing ``results.csv``, which is otherwise refused.
    settings : dict, optional
        Fields of :class:`~bayestouch.planning.loop.ExploreSettings`.
    prober : {"rays", "finger"}
        How strokes are measured (:data:`PROBERS`); part of the experiment's key (a resume with another is refused).
    bend_spread : float
        With ``prober="finger"``: each trial's finger gets bending constants of its own, drawn at this many times
        their stated spread (:func:`trial_finger`), while its pose estimate keeps the models' (0: the models'
        constants; at most :data:`MAX_BEND_SPREAD`); part of the key when not 0.
    bend_calibration : bool
        With ``prober="finger"`` and ``settings["pose_draws"]``: each trial's finger is first calibrated on
        :func:`calibration_object` (:func:`~bayestouch.planning.device_prober.calibrate_bending`) and the loop
        marginalises the calibrated pose-error law; part of the key when set. With ``carrier`` the calibrated law
        corrects the carrier programs instead (no ``pose_draws``).
    carrier : bool
        With ``prober="finger"``: the planned strokes run as carrier strokes
        (:meth:`~bayestouch.planning.device_prober.DeviceProber.carrier_plan`; the scout stays guarded), the
        contacts taken from the pad's sensed pose; not with ``settings["pose_draws"]``; part of the key when set.
    plot : bool
        Write ``error_vs_strokes.png``.
    log : callable, optional
        Called with each progress message (str); default ``logging.getLogger("bayestouch.planning.experiment").info``.

    Returns
    -------
    dict
        ``{"ran": trials run now, "skipped": trials kept from before, "rows": all rows, "path": results.csv}``.
    """
    # a comma-separated string is the command line's form: iterated, it read as one-letter planners ("'r'")
    if isinstance(planners, str):
        planners = [p.strip() for p in planners.split(",") if p.strip()]
    elif isinstance(planners, list | tuple):
        planners = list(planners)
    else:
        raise BadInput(
            f"planners: expected a list of planners or a comma-separated string like eig,random, got {shown(planners)}"
        )
    if isinstance(objects, str):
        objects = [o.strip() for o in objects.split(",") if o.strip()]
    elif isinstance(objects, list | tuple) and all(isinstance(o, str | os.PathLike) for o in objects):
        objects = list(objects)
    else:  # 5 gave "'int' object is not iterable"
        raise BadInput(
            f"objects: expected object names or TOML paths (a list, or a comma-separated string like "
            f"sphere,egg), got {shown(objects)}"
        )
    if not objects:  # () ran nothing and wrote an empty results.csv
        raise BadInput("objects: expected at least one object name or TOML path, like sphere,egg; got none")
    check_path(out, "out")
    check_bools(resume=resume, overwrite=overwrite, plot=plot)
    if log is not None and not callable(log):
        raise BadInput(f"log: expected a function of one message (str) or None, got {shown(log)}")
    if isinstance(workers, bool) or not isinstance(workers, int | np.integer):
        raise BadInput(f"workers: expected an integer ≥ 1, got {workers!r}")
    if not planners:
        raise BadInput("planners: expected a comma-separated list like eig,random,oracle")
    for p in planners:
        check_policy(p)
    if not isinstance(budget, int | np.integer) or budget < 1:
        raise BadInput(f"budget: expected an integer number of strokes ≥ 1, got {budget!r}")
    if not isinstance(trials, int | np.integer) or trials < 1:
        raise BadInput(f"trials: expected an integer ≥ 1, got {trials!r}")
    if trials * max(len(planners), 1) * max(len(list(objects)), 1) > MAX_TRIALS:
        raise BadInput(
            f"trials: {trials} × {len(planners)} planner(s) × {len(list(objects))} object(s) is more than "
            f"{MAX_TRIALS} trials in one experiment; split it into several --out folders"
        )
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise BadInput(f"seed: expected an integer ≥ 0, got {seed!r}")
    if workers < 1:
        raise BadInput(f"workers: expected an integer ≥ 1, got {workers}")
    if scheduler is not None:
        _connect(scheduler).close()  # before any work or output: an unreachable scheduler is bad input
    paths = {str(o): resolve_object(str(o)) for o in objects}
    by_file: dict[Path, str] = {}
    for o, p in paths.items():  # one object named twice (by name and by path) would run its trials twice
        first = by_file.setdefault(p.resolve(), o)
        if first != o:
            raise BadInput(f"objects: {first} and {o} are the same object file ({p}); name each object once")
    # the objects themselves travel with the tasks: a Dask worker on another machine has no such path
    loaded = {o: load_object(p) for o, p in paths.items()}
    names = {o: p.stem if p.parent == OBJECTS_DIR else str(o) for o, p in paths.items()}
    if settings is not None and not isinstance(settings, dict):
        raise BadInput(f"settings: expected a dict of ExploreSettings fields, got {type(settings).__name__}")
    # checked before the folder is touched: a refused setting had left experiment.json and a header-only
    # results.csv that refused the next, valid call
    check_settings(settings_from(settings or {}))
    out = Path(out)
    if prober not in PROBERS:
        raise BadInput(f"prober: expected one of {', '.join(PROBERS)}, got {prober!r}")
    if not (isinstance(bend_spread, int | float) and 0 <= bend_spread <= MAX_BEND_SPREAD):
        raise BadInput(
            f"bend_spread: expected a factor in [0, {MAX_BEND_SPREAD:g}] times the bending constants' spread, got "
            f"{bend_spread!r}"
        )
    if bend_spread and prober != "finger":
        raise BadInput("bend_spread: the bending pose error is the virtual finger's; use it with prober 'finger'")
    if (settings or {}).get("pose_draws") and prober != "finger":
        raise BadInput("settings.pose_draws: the pose-error law is a finger's; use it with prober 'finger'")
    check_bool(bend_calibration, "bend_calibration")
    check_bool(carrier, "carrier")
    if carrier and prober != "finger":
        raise BadInput("carrier: carrier strokes run on a finger; use them with prober 'finger'")
    if carrier and (settings or {}).get("pose_draws"):
        raise BadInput(
            "carrier: carrier strokes take their contacts from the pad's sensed pose; there is no pose-error law to "
            "marginalise (drop pose_draws)"
        )
    if bend_calibration and not ((settings or {}).get("pose_draws") or carrier):
        raise BadInput(
            "bend_calibration: the calibrated pose-error law needs settings pose_draws ≥ 2 (or carrier strokes) to be "
            "used"
        )
    # the folder is this run's from the check of an earlier results.csv to the plot: a second experiment into it at
    # the same time is refused in one line, not left to replace the first's rows (the lock goes with a killed run)
    with locked_run_folder(out):
        csv_path = out / "results.csv"
        meta_path = out / "experiment.json"
        options = {"seed": int(seed), "budget": int(budget), "settings": dict(settings or {})}
        if prober != "rays":  # the key of earlier experiments (all in the ray world) stays as it was
            options["prober"] = prober
        if bend_spread:
            options["bend_spread"] = float(bend_spread)
        if bend_calibration:
            options["bend_calibration"] = True
        if carrier:
            options["carrier"] = True
        # the objects' contents are part of the key: an object file edited between runs is another experiment
        contents = {f"object {names[o]}": p.read_bytes() for o, p in paths.items()}
        meta = fingerprint("experiment", contents, options)
        if csv_path.exists() and not csv_path.is_file():
            raise BadInput(
                f"--out {out}: {csv_path} is not a file; expected the results.csv of an experiment, or nothing"
            )
        if csv_path.is_file() and not resume and not overwrite:
            raise BadInput(
                f"--out {out} already holds results.csv; pass --resume to keep its complete trials, --overwrite to "
                "replace it, or choose another folder"
            )
        if overwrite and not resume and csv_path.is_file():
            # set aside, not deleted: an interrupted new run leaves the old results where the user finds them
            set_aside([out / n for n in ("results.csv", "experiment.json", "error_vs_strokes.png")], "experiment")
        rows: list[dict] = []
        if resume and csv_path.is_file():
            old_meta = None
            with contextlib.suppress(OSError, ValueError):
                old_meta = json.loads(meta_path.read_text(encoding="utf-8"))
            if not isinstance(old_meta, dict) or "options" not in old_meta:
                # without it nothing says which settings the kept trials were made with
                raise BadInput(
                    f"--resume: cannot verify the settings of {csv_path}: {meta_path.name} is missing or damaged; "
                    "expected the experiment.json written with it (or pass --overwrite, or choose another --out)"
                )
            if not old_meta.get("data_sha256"):
                # written before the objects' contents were keyed: compared on the options alone, as then
                old_meta = {**old_meta, "data_sha256": meta["data_sha256"]}
            # the command line's names beside the keys: `budget` is `--strokes` there
            diff = [d.replace("budget ", "budget (--strokes) ", 1) for d in differences(old_meta, meta)]
            if diff:
                raise BadInput(
                    f"--resume: {csv_path} was made with {'; '.join(diff)}; resume with the same settings or choose "
                    "another --out"
                )
            old = checked_rows(read_csv_rows(csv_path), csv_path)
            wrong = [
                r
                for r in old
                if r.get("seed") not in (None, "") and int(r["seed"]) != _trial_seed(seed, int(r["trial"]))
            ]
            if wrong:
                raise BadInput(
                    f"--resume: {csv_path} holds trials of another --seed (trial {wrong[0]['trial']}); resume with the "
                    "seed they were made with or choose another --out"
                )
            done = _complete(old, budget)
            rows = [r for r in old if _key(r) in done]
        write_json(meta_path, meta)
        done = {_key(r) for r in rows}
        tasks = [
            {
                "object": names[o],
                "scene_object": loaded[o],
                "planner": p,
                "trial": t,
                "budget": int(budget),
                "seed": _trial_seed(seed, t),
                "settings": dict(settings or {}),
                "prober": prober,
                "bend_spread": float(bend_spread),
                "bend_calibration": bool(bend_calibration),
                "carrier": bool(carrier),
            }
            for t in range(trials)
            for o in paths
            for p in planners
            if (names[o], p, t) not in done
        ]
        log = log or _log.info
        log(
            f"experiment: {len(tasks)} trial(s) to run, {len(done)} kept from {csv_path}"
            if done
            else f"experiment: {len(tasks)} trial(s) to run"
        )

        results = ResultsFile(
            csv_path,
            COLUMNS,
            rows,
            order=lambda r: (str(r["object"]), str(r["planner"]), int(r["trial"]), int(r["stroke"])),
        )

        def finished(new_rows):
            results.add(new_rows)
            last = new_rows[-1]
            log(
                f"  {last['object']} {last['planner']} trial {last['trial']}: chamfer {float(last['chamfer']):.4f}, "
                f"volume error {float(last['volume_error']):.4f} after {last['stroke']} strokes"
            )

        if not csv_path.is_file():
            results.write()
        run_tasks(tasks, run_trial, finished, workers=workers, scheduler=scheduler)
        rows = results.rows
        if plot and rows:
            plot_results(rows, out / "error_vs_strokes.png")
        return {"ran": len(tasks), "skipped": len(done), "rows": rows, "path": csv_path}


def _run_pool(workers: int, tasks: Sequence, run: Callable, finished: Callable) -> None:
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=mp.get_context("spawn")) as ex:
        futures = [ex.submit(run, t) for t in tasks]
        try:
            for f in as_completed(futures):
                finished(f.result())
        except BrokenProcessPool:
            raise RuntimeError(
                "a worker process died; every finished trial is in results.csv: rerun with --resume to do the rest"
            ) from None


def _check_address(address) -> None:
    if not (isinstance(address, str) and address.startswith(("tcp://", "tls://", "inproc://"))):
        raise BadInput(f"--scheduler: expected an address like tcp://HOST:PORT, got {address!r}")


#: largest frame count a Dask message header may announce (its first 8 bytes, little-endian): anything else on
#: the port (an HTTP server, a dashboard, a proxy) is not a Dask scheduler
_DASK_MAX_FRAMES = 1 << 16


def probe_scheduler(address: str, timeout_s: float = SCHEDULER_TIMEOUT_S) -> None:
    """Check that a Dask scheduler answers at ``tcp://HOST:PORT`` before a client connects to it: a scheduler
    speaks first on a new connection (its handshake: an 8-byte little-endian frame count, then the frames), so
    the first bytes of another server (HTTP's "HTTP/1.1", a dashboard) or its silence are told apart within
    ``timeout_s`` seconds. Other schemes (tls, inproc) pass unprobed.

    Raises
    ------
    BadInput
        Nothing listens, the peer is silent, or its first bytes are not a Dask message header.
    """
    if not address.startswith("tcp://"):
        return
    host, _, port = address[len("tcp://") :].rpartition(":")
    try:
        port_n = int(port)
    except ValueError:
        raise BadInput(f"--scheduler: expected an address like tcp://HOST:PORT, got {address!r}") from None
    hint = "start one with `dask scheduler` or check the address (the scheduler's port, not its dashboard's)"
    try:
        with socket.create_connection((host.strip("[]"), port_n), timeout=timeout_s) as sock:
            sock.settimeout(timeout_s)
            head = b""
            while len(head) < 8:
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    break
                head += chunk
    except TimeoutError:
        raise BadInput(f"--scheduler {address}: the server there said nothing in {timeout_s:g} s; {hint}") from None
    except OSError as e:
        raise BadInput(
            f"--scheduler {address}: no Dask scheduler answered within {timeout_s:g} s ({type(e).__name__}); {hint}"
        ) from None
    if len(head) < 8 or int.from_bytes(head, "little") > _DASK_MAX_FRAMES:
        raise BadInput(
            f"--scheduler {address}: the server there is not a Dask scheduler (first bytes {head[:8]!r}); {hint}"
        )


def _connect(address: str):
    """A Dask client of the scheduler at ``address``; BadInput when dask.distributed is missing or nothing answers."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise BadInput(
            '--scheduler: needs dask\'s distributed scheduler; install it with pip install "dask[distributed]"'
        ) from None
    _check_address(address)
    probe_scheduler(address)
    try:
        return Client(address, set_as_default=False, timeout=SCHEDULER_TIMEOUT_S)
    except (OSError, TimeoutError, MemoryError, ValueError) as e:
        raise BadInput(
            f"--scheduler {address}: no Dask scheduler answered within {SCHEDULER_TIMEOUT_S:g} s ({type(e).__name__}); "
            "start one with `dask scheduler` or check the address"
        ) from None


def _run_dask(address: str, tasks: Sequence, run: Callable, finished: Callable) -> None:
    from dask.distributed import as_completed as dask_completed

    # set_as_default=False: the client is used explicitly; as the default it would point dask's global scheduler at
    # the cluster, and once closed leave it there ("no Client active") for every later xarray/dask call
    with _connect(address) as client:
        # pure=False: every task runs (a retried task after a worker died reruns the whole trial)
        futures = [client.submit(run, t, pure=False, retries=2) for t in tasks]
        for f in dask_completed(futures, loop=client.loop):  # not the default client's loop: there is none
            finished(f.result())


def _as_table(rows):
    import pandas as pd

    df = pd.DataFrame(rows)
    for c in ("trial", "stroke"):
        df[c] = df[c].astype(int)
    for c in ("chamfer", "volume_error"):
        df[c] = df[c].astype(float)
    return df


def gap_closed(rows, metric: str = "chamfer", stroke: int | None = None) -> float:
    """Fraction of the random–oracle gap that eig closes: (random − eig) / (random − oracle) of the mean
    ``metric`` at ``stroke`` (default the last), over objects and trials. NaN when a planner is missing or the
    gap is 0."""
    df = _as_table(rows)
    stroke = int(df["stroke"].max()) if stroke is None else stroke
    m = df[df["stroke"] == stroke].groupby("planner")[metric].mean()
    if not {"eig", "random", "oracle"} <= set(m.index) or m["random"] == m["oracle"]:
        return float("nan")
    return float((m["random"] - m["eig"]) / (m["random"] - m["oracle"]))


def plot_results(rows, path) -> Path:
    """Median and 25–75 % band of the Chamfer distance and the volume error against strokes, one line per
    planner (over objects and trials); written to ``path`` (PNG)."""
    from matplotlib.ticker import MaxNLocator

    from bayestouch.report import canvas

    df = _as_table(rows)
    fig, axes = canvas.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, metric, label in (
        (axes[0], "chamfer", "Chamfer distance / mean semi-axis"),
        (axes[1], "volume_error", "volume error |V/V_true - 1|"),
    ):
        for planner, g in df.groupby("planner"):
            q = g.groupby("stroke")[metric].quantile([0.25, 0.5, 0.75]).unstack()
            ax.plot(q.index, q[0.5], marker="o", label=planner)
            ax.fill_between(q.index, q[0.25], q[0.75], alpha=0.2)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("strokes (0 = scout)")
        ax.set_ylabel(label)
        ax.set_yscale("log")
        ax.legend()
    fig.suptitle("exploration: error against strokes (median, 25-75 % band)")
    path = Path(path)
    fig.savefig(path, dpi=100)
    return path
