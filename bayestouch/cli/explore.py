"""``bayestouch explore`` (active exploration, simulated or on a finger) and ``bayestouch experiment`` (planners
compared over objects and seeded trials)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from bayestouch.cli.args import RESULT_FILES, out_path
from bayestouch.cli.args import seed as seed_arg
from bayestouch.cli.args import segment as segment_arg
from bayestouch.errors import BadInput

__all__ = ["add_planning_parsers", "run_explore", "run_experiment"]


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--strokes",
        "--budget",
        dest="budget",
        type=int,
        default=5,
        help="planned strokes after the scout stroke 0 (default 5); --budget is the same (older command lines; "
        "in fit, --budget is seconds)",
    )
    p.add_argument("--seed", type=seed_arg, default=0, help="base seed (default 0)")
    p.add_argument("--candidates", type=int, default=64, help="candidate strokes per decision (default 64)")
    p.add_argument("--draws", type=int, default=1000, help="posterior draws the planner uses (default 1000)")
    p.add_argument("--steps", type=int, default=300, help="emcee steps per posterior update (default 300)")
    p.add_argument(
        "--per-second",
        action="store_true",
        help="eig planner: maximise information per second of stroke (cost-aware) instead of per stroke",
    )
    p.add_argument(
        "--pose-draws",
        type=int,
        default=0,
        metavar="K",
        help="on a finger (--port, --prober finger): marginalise the pad's pose error with the law of K fingers "
        "drawn about its bending constants (K >= 2; default 0: the contacts are where the finger says)",
    )
    p.add_argument(
        "--pose-offset-sd",
        type=float,
        default=0.0,
        metavar="METRES",
        help="with --pose-draws: sd of one more offset per stroke, for pose errors the drawn fingers do not make "
        "(a carrier's calibration, the pad's mount; default 0)",
    )
    p.add_argument(
        "--carrier",
        action="store_true",
        help="on a finger (--port, --prober finger): run the planned strokes as carrier strokes (protocol 1.3), the "
        "pad slid along the believed surface by base motion and wire currents from the inverse of the bending "
        "model, corrected by the calibrated law of --pose-law / --bend-calibration, the contacts taken from the pad's "
        "sensed pose (the scout stays guarded; not with --pose-draws)",
    )
    p.add_argument("--out", required=True, type=out_path, help="output folder")


#: drawn members of a pose-error law when ``--pose-law`` is given without ``--pose-draws``
DEFAULT_POSE_DRAWS = 24


def add_planning_parsers(subparsers) -> tuple[argparse.ArgumentParser, argparse.ArgumentParser]:
    """Add the ``explore`` and ``experiment`` subcommands to an argparse ``subparsers`` object; returns both."""
    ep = subparsers.add_parser(
        "explore",
        help="active exploration of a simulated object or on a finger (plan, stroke, update)",
        description="Plan strokes over a simulated object (or run them on a finger with --port), update the "
        "posterior after each and write per-stroke summaries and figures.",
    )
    ep.add_argument(
        "--object",
        default=None,
        help="object name in models/objects (egg, sphere, box, cylinder) or a TOML file (default egg); with "
        "--port optional: the truth the errors are measured against",
    )
    ep.add_argument(
        "--port",
        default=None,
        help="drive a finger instead of the simulation: serial port path or pyserial URL (e.g. the pty of "
        "`bayestouch device simulate`); writes OUT/recording.nc and OUT/device.journal",
    )
    ep.add_argument(
        "--centre",
        default=None,
        metavar="X,Y,Z",
        help="nominal centre of the object (the fixture), metres; required with --port and no --object",
    )
    ep.add_argument(
        "--timeout", type=float, default=None, help="with --port: seconds to wait for an answer (default 0.3)"
    )
    ep.add_argument(
        "--pose-law",
        type=Path,
        default=None,
        metavar="LAW.toml",
        help="with --port: this finger's calibrated pad-pose error law (`device calibrate-bending`), marginalised "
        f"with --pose-draws members (default {DEFAULT_POSE_DRAWS})",
    )
    ep.add_argument(
        "--segment",
        type=segment_arg,
        default=False,  # not given (False, not a string: argparse leaves it unconverted)
        help="with --port: packets on a lossy link (protocol 1.2): auto (default: parts of 48 bytes once whole "
        "packets do not get through), 0 (always whole) or a part size in bytes",
    )
    ep.add_argument(
        "--planner", default="eig", help="eig, random, coverage, gpis (GPIS max-variance) or oracle (default eig)"
    )
    ep.add_argument(
        "--target-volume-sd",
        type=float,
        default=None,
        help="stop early once the volume's posterior sd is below this (m^3)",
    )
    ep.add_argument("--overwrite", action="store_true", help="replace an exploration already in --out")
    _common(ep)
    xp = subparsers.add_parser(
        "experiment",
        help="compare planners over objects and seeded trials (results.csv)",
        description="Run objects x planners x trials of the exploration loop and write "
        "DIR/results.csv and DIR/error_vs_strokes.png.",
    )
    xp.add_argument(
        "--planners",
        default="eig,random,oracle",
        help="comma-separated, of eig, random, coverage, gpis (touch where a GPIS surface is most uncertain) and "
        "oracle (default eig,random,oracle)",
    )
    xp.add_argument(
        "--prober",
        choices=("rays", "finger"),
        default="rays",
        help="how strokes are measured: rays on the simulated object (default), or guarded strokes on a virtual "
        "finger over the serial protocol (force threshold, pad pose error)",
    )
    xp.add_argument(
        "--bend-spread",
        type=float,
        default=0.0,
        metavar="FACTOR",
        help="with --prober finger: each trial's finger gets bending constants of its own, drawn at FACTOR times "
        "their stated spread, while its pose estimate keeps the models' (guarded strokes then touch millimetres off "
        "their lines; default 0; at most 3)",
    )
    xp.add_argument(
        "--bend-calibration",
        action="store_true",
        help="with --prober finger and --pose-draws: calibrate each trial's finger on a 2-cm sphere first (six "
        "guarded strokes with tilted approaches) and marginalise its calibrated pose-error law",
    )
    xp.add_argument("--objects", default="egg,sphere,box,cylinder", help="comma-separated names or TOML files")
    xp.add_argument("--trials", type=int, default=3, help="seeded trials per object and planner (default 3)")
    xp.add_argument("--workers", type=int, default=2, help="processes (default 2; 1 runs in this process)")
    xp.add_argument("--scheduler", default=None, help="Dask scheduler address tcp://HOST:PORT (optional)")
    xp.add_argument(
        "--resume",
        action="store_true",
        help="keep complete trials of an existing results.csv (refused when made with another seed or settings)",
    )
    xp.add_argument("--overwrite", action="store_true", help="replace an existing results.csv")
    _common(xp)
    return ep, xp


#: largest values of the planner's sizes (memory grows with candidates × draws × rays, time with each): beyond
#: them a run would end in a MemoryError or an hours-long silence
SETTING_LIMITS = {"candidates": 4096, "draws": 100_000, "steps": 1_000_000, "budget": 1000, "pose_draws": 1000}


def _settings(args) -> dict:
    from bayestouch.planning.loop import MIN_DRAWS  # the loop's own least (check_settings)

    for name in ("candidates", "draws", "steps"):
        v, hi = getattr(args, name), SETTING_LIMITS[name]
        lo = MIN_DRAWS if name == "draws" else 1  # a covariance of the posterior needs a few draws
        if not lo <= v <= hi:
            raise BadInput(f"--{name} must be an integer from {lo} to {hi}, got {v}")
    if not 1 <= args.budget <= SETTING_LIMITS["budget"]:
        raise BadInput(
            f"--strokes (--budget) must be an integer number of strokes from 1 to {SETTING_LIMITS['budget']}, "
            f"got {args.budget}"
        )
    out = {"candidates": args.candidates, "draws": args.draws, "steps": args.steps}
    if getattr(args, "per_second", False):
        out["per_second"] = True
    k, sd = getattr(args, "pose_draws", 0), getattr(args, "pose_offset_sd", 0.0)
    if getattr(args, "pose_law", None) is not None and k == 0:
        k = DEFAULT_POSE_DRAWS
    if not (k == 0 or 2 <= k <= SETTING_LIMITS["pose_draws"]):
        raise BadInput(f"--pose-draws must be 0 or an integer from 2 to {SETTING_LIMITS['pose_draws']}, got {k}")
    if not (math.isfinite(sd) and 0 <= sd < 0.1):
        raise BadInput(f"--pose-offset-sd must be a per-stroke offset sd in metres in [0, 0.1), got {sd}")
    if sd and not k:
        raise BadInput("--pose-offset-sd applies with --pose-draws (the pose-error law it widens)")
    if k:
        out["pose_draws"] = k
        out["pose_offset_sd"] = sd
    return out


def _centre(text):
    if text is None:
        return None
    try:
        c = [float(x) for x in text.split(",")]
    except ValueError:
        c = []
    if len(c) != 3 or not all(map(math.isfinite, c)):
        raise BadInput(f"--centre must be three numbers in metres like 0,0,0.03, got {text!r}")
    from bayestouch.io.contacts import unit_problem

    if hint := unit_problem([c]):  # 0,0,5 sent strokes to a point 5 m away (only the ±10 m safety limit caught more)
        raise BadInput(f"--centre {text}: the coordinates {hint}")
    return c


def run_explore(args) -> int:
    """``bayestouch explore``: writes ``summary_<k>.json`` per stroke (k = 0 the scout), ``points.csv`` (all
    contacts), ``explore.json`` (the history) and ``explore.png`` (points and the final estimate). With ``--port``
    the strokes run on a finger (:class:`bayestouch.planning.device_prober.DeviceProber`) and ``recording.nc``
    (the schema of ``bayestouch simulate``, rewritten after every stroke) and ``device.journal`` (every packet
    received) are written too; without ``--object`` there is no truth and the errors are unknown (NaN)."""
    from bayestouch.planning.loop import ExploreSettings
    from bayestouch.planning.policies import check_policy
    from bayestouch.scene.objects import load_object, resolve_object

    settings = ExploreSettings(**_settings(args))
    check_policy(args.planner)
    if getattr(args, "per_second", False) and args.planner != "eig":
        raise BadInput(f"--per-second applies to the eig planner (information per second), not to {args.planner}")
    tv = args.target_volume_sd
    if tv is not None and not (math.isfinite(tv) and tv > 0):
        raise BadInput(f"--target-volume-sd must be a positive volume in m^3, got {tv}")
    port = getattr(args, "port", None)
    centre = _centre(getattr(args, "centre", None))
    if port is not None and not port.strip():
        raise BadInput("--port: expected a serial port path or a pyserial URL, got an empty string")
    if port is not None:
        from bayestouch.cli.device import check_port

        check_port(port)
    name = args.object if args.object is not None else (None if port else "egg")
    obj = load_object(resolve_object(name)) if name is not None else None
    if obj is None and centre is None:
        raise BadInput("--centre: expected the object's nominal centre X,Y,Z in metres when --port has no --object")
    if port is not None and args.planner == "oracle":
        raise BadInput("--planner oracle needs the simulated truth; use eig, random or coverage with --port")
    timeout = getattr(args, "timeout", None)
    if timeout is not None and port is None:
        raise BadInput("--timeout applies to a finger on --port; without --port the strokes are simulated")
    if getattr(args, "pose_law", None) is not None and port is None:
        raise BadInput("--pose-law applies to a finger on --port; simulated rays have no pad-pose error")
    if settings.pose_draws and port is None:
        raise BadInput("--pose-draws applies to a finger on --port; simulated rays have no pad-pose error")
    if args.carrier and port is None:
        raise BadInput("--carrier applies to a finger on --port; simulated rays have no carrier strokes")
    if args.carrier and settings.pose_draws:
        raise BadInput(
            "--carrier: carrier strokes take their contacts from the pad's sensed pose; there is no pose-error law to "
            "marginalise (drop --pose-draws; --pose-law alone corrects the programs)"
        )
    args.law = None
    if getattr(args, "pose_law", None) is not None:
        from bayestouch.io.pose_law_file import read_pose_law

        args.law = read_pose_law(args.pose_law)[0]
    segment = getattr(args, "segment", False)
    if segment is not False and port is None:
        raise BadInput("--segment applies to a finger on --port; without --port the strokes are simulated")
    args.segment = None if segment is False else segment
    args.timeout = 0.3 if timeout is None else timeout
    if not (0.01 <= args.timeout <= 60):
        raise BadInput(f"--timeout must be in [0.01, 60] seconds, got {args.timeout}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out} exists and is not a folder")
    from bayestouch.io.runfolder import locked_run_folder

    # the folder is this run's from the check of earlier results to the last output: a second run into it at the
    # same time is refused in one line (the lock goes with a killed run's process)
    with locked_run_folder(out):
        return _explore_into(out, args, obj, name, port, centre, settings)


def _explore_into(out: Path, args, obj, name, port, centre, settings) -> int:
    """The exploration of :func:`run_explore`, its options checked and ``out`` held."""
    from bayestouch.io.contacts import save_contact_points
    from bayestouch.io.files import set_aside, write_json
    from bayestouch.io.runfolder import every_earlier_file
    from bayestouch.planning.loop import explore

    # what an exploration writes, and any other command's result (a fit's summary.json, a points.csv of the user's)
    written = {"explore.json", "explore.png", "points.csv", "device.journal", *RESULT_FILES}
    earlier = sorted(out.glob("summary_*.json")) if out.is_dir() else []
    earlier += [out / f for f in sorted(written) if (out / f).exists()]
    if earlier and not args.overwrite:
        raise BadInput(
            f"--out {out} already holds results ({', '.join(sorted({f.name for f in earlier})[:4])}"
            f"{' …' if len(earlier) > 4 else ''}); pass --overwrite to set them aside, or choose another folder"
        )
    if earlier:  # --overwrite: never deleted, and no file of the earlier run (its meshes, figures …) left beside
        set_aside(every_earlier_file(out, (args.object,)), "explore")
    out.mkdir(parents=True, exist_ok=True)
    truthless = obj is None
    object_name = name if name is not None else "unknown (a finger without --object)"
    pose_model = _pose_model(port, settings, getattr(args, "pose_law", None), args.carrier)
    if port is not None and not settings.pose_draws and not args.carrier:
        print(
            "bayestouch explore: note: the pad's pose error is not modelled: the contacts are taken where the finger "
            "reports them, and a finger whose bending constants differ from models/ gets intervals too narrow "
            "(see --pose-draws and --pose-law)",
            file=sys.stderr,
        )

    def on_stroke(rec):
        write_json(
            out / f"summary_{rec.stroke}.json",
            {
                "object": object_name,
                **rec.summary,
                "seconds": rec.seconds,
                "eig_nats": rec.eig,
                "decision_s": rec.decision_s,
                "refused_candidates": rec.refused,
                **({"pose_error": pose_model} if pose_model else {}),
                **({"errors_note": "unknown: no truth (a finger without --object)"} if truthless else {}),
            },
        )
        errs = (
            "errors unknown (no truth)"
            if truthless
            else f"chamfer {rec.chamfer:.4f} of the mean semi-axis, volume error {rec.volume_error:.4f}"
        )
        print(
            f"stroke {rec.stroke}: {rec.n_points} points, {errs}, volume sd {rec.volume_sd:.3g} m^3"
            + (f", {rec.refused} unsafe candidate(s) refused" if rec.refused else ""),
            file=sys.stderr,
        )

    kw = dict(
        seed=args.seed,
        settings=settings,
        target_volume_sd=args.target_volume_sd,
        on_stroke=on_stroke,
        centre=centre,
    )
    if port is None:
        res = explore(obj, args.planner, args.budget, **kw)
    else:
        res = _explore_device(obj, args, port, out, kw)
        if res is None:
            return 2  # the device failed: said in one line, the complete strokes kept
    save_contact_points(out / "points.csv", res.points, overwrite=True)
    write_json(
        out / "explore.json",
        {
            "object": obj.name if obj is not None else "unknown (device)",
            "planner": args.planner,
            "seed": args.seed,
            **({"port": port} if port else {}),
            "strokes": [{k: v for k, v in r._asdict().items() if k != "summary"} for r in res.records],
        },
    )
    _plot_explore(res, obj, out / "explore.png")
    return 0


def _pose_model(port, settings, law_path, carrier: bool = False) -> str | None:
    """What the summaries say about the pad's pose error on a finger (None in simulation)."""
    if port is None:
        return None
    if carrier:
        if law_path is None:
            return (
                "carrier strokes: contacts from the pad's sensed pose, programs not corrected; the scout's as reported"
            )
        return (
            f"carrier strokes: contacts from the pad's sensed pose, programs corrected by the calibrated law of "
            f"{law_path}; the guarded scout's moved by its mean"
        )
    if not settings.pose_draws:
        return "not modelled: contacts as the finger reports them"
    src = f"the calibrated law of {law_path}" if law_path is not None else "fingers drawn about models/'s constants"
    extra = f", one more offset per stroke of sd {settings.pose_offset_sd:g} m" if settings.pose_offset_sd else ""
    return f"marginalised: {settings.pose_draws} members of {src}{extra}"


def _explore_device(obj, args, port: str, out: Path, kw: dict):
    """The loop on the finger at ``port``; None (after saying why) when the device failed."""
    from bayestouch import __version__
    from bayestouch.hardware.device import DeviceError, FingerDevice
    from bayestouch.planning.device_prober import DeviceProber
    from bayestouch.planning.loop import explore

    journal = out / "device.journal"
    rec = out / "recording.nc"
    attrs = {
        "port": port,
        "seed": args.seed,
        "planner": args.planner,
        "software": f"bayestouch {__version__}",
        "object": f"device; truth {obj.name}" if obj is not None else "unknown (device)",
    }
    dev = FingerDevice(port, timeout=args.timeout, journal=journal, segment=args.segment)
    prober = None
    try:
        with dev:
            prober = DeviceProber(dev, recording=rec, attrs=attrs, pose_law=args.law, carrier=args.carrier)
            res = explore(obj, args.planner, args.budget, prober=prober, **kw)
    except DeviceError as e:
        n = len(prober.strokes) if prober is not None else 0
        got = f"everything received is in {journal}" if journal.is_file() else "nothing was received"
        kept = f" in {rec}" if n else ""
        print(f"bayestouch explore: error: {e}; {n} complete stroke(s){kept}; {got}", file=sys.stderr)
        return None
    print(
        f"wrote {rec}: {len(prober.strokes)} stroke(s) from {dev.info.firmware}, "
        f"{len(prober.refused)} unsafe candidate(s) refused before sending"
        + (
            f"; {len(prober.carriers)} carrier stroke(s), {prober.aborted} stopped at the force limit (their frames "
            "before the stop kept)"
            if prober.carrier
            else ""
        ),
        file=sys.stderr,
    )
    return res


def _plot_explore(res, obj, path: Path) -> None:
    import numpy as np

    from bayestouch.backend import jnp
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.geometry.mesh import nellipsoid_mesh
    from bayestouch.planning.loop import point_estimate
    from bayestouch.report import canvas

    est = point_estimate(res.shape_vectors)["estimate"]
    v, _ = nellipsoid_mesh(ne.from_vector(jnp.asarray(est)), 24)
    fig = canvas.figure(figsize=(10, 4.5), constrained_layout=True)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.scatter(*(1e3 * v.T), s=2, alpha=0.35, color="grey", label="estimate")
    k0 = 0
    for i, rec in enumerate(res.records):
        n = rec.new_points
        p = res.points[k0 : k0 + n]
        k0 += n
        if len(p):
            ax.scatter(*(1e3 * p.T), s=6, label="scout" if i == 0 else f"stroke {i}")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.legend(fontsize=6, loc="upper left")
    ax2 = fig.add_subplot(1, 2, 2)
    k = np.array([r.stroke for r in res.records])
    if obj is None:
        ax2.plot(k, [r.volume_sd for r in res.records], marker="o", label="volume sd (m^3); errors unknown")
    else:
        ax2.plot(k, [r.chamfer for r in res.records], marker="o", label="Chamfer / mean semi-axis")
        ax2.plot(k, [r.volume_error for r in res.records], marker="s", label="volume error")
    ax2.set_yscale("log")
    ax2.set_xlabel("stroke")
    ax2.legend()
    fig.suptitle(f"explore {obj.name if obj is not None else 'on a finger'}: points and the posterior estimate")
    fig.savefig(path, dpi=100)


def _check_foreign_results(out: Path, overwrite: bool) -> None:
    """Refuse an experiment's ``--out`` that holds another command's finished results (a fit's summary.json, an
    exploration's explore.json, …) unless ``overwrite``, which sets them aside with what goes with them; the
    experiment's own results.csv and experiment.json are its own check's (every other command refused such a folder,
    the experiment wrote beside them)."""
    from bayestouch.cli.args import other_results, other_results_error
    from bayestouch.io.files import set_aside

    found = other_results(out, own={"results.csv", "experiment.json", "error_vs_strokes.png"})
    if found and not overwrite:
        raise other_results_error(out, found)
    set_aside(found, "experiment")


def run_experiment(args) -> int:
    """``bayestouch experiment``: writes ``results.csv`` and ``error_vs_strokes.png`` into ``--out``."""
    from bayestouch.planning.experiment import gap_closed
    from bayestouch.planning.experiment import run_experiment as run

    if args.resume and args.overwrite:
        raise BadInput("--resume and --overwrite exclude each other: keep the finished trials, or replace them")
    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    objects = [o.strip() for o in args.objects.split(",") if o.strip()]
    if not objects:
        raise BadInput(f"--objects: expected comma-separated object names or TOML files, got {args.objects!r}")
    for flag, names in (("--planners", planners), ("--objects", objects)):
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise BadInput(f"{flag}: {', '.join(twice)} named twice; each trial runs once per entry")
    if args.trials < 1:
        raise BadInput(f"--trials must be an integer ≥ 1, got {args.trials}")
    _check_foreign_results(args.out, args.overwrite)
    res = run(
        args.out,
        planners=planners,
        objects=objects,
        trials=args.trials,
        budget=args.budget,
        seed=args.seed,
        workers=args.workers,
        prober=args.prober,
        bend_spread=args.bend_spread,
        bend_calibration=args.bend_calibration,
        carrier=args.carrier,
        scheduler=args.scheduler,
        resume=args.resume,
        overwrite=args.overwrite,
        settings=_settings(args),
    )
    g = gap_closed(res["rows"]) if res["rows"] else float("nan")
    if g == g:
        print(
            f"eig closes {100 * g:.0f} % of the random-oracle Chamfer gap after {args.budget} strokes", file=sys.stderr
        )
    print(str(res["path"]))
    return 0
