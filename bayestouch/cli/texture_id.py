"""``bayestouch texture-id``: the texture identification experiment (accuracy against strokes)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bayestouch.cli.args import bounded_int, check_out, out_path, terminations_as_interrupts
from bayestouch.cli.args import seed as seed_arg

__all__ = ["add_texture_parser", "run_texture_id"]

#: most trials per texture and strokes per trial (each stroke a simulated recording and a posterior update; the
#: summary loops over strokes): beyond them the run takes days or its memory
MAX_TRIALS = 10_000
MAX_STROKES = 1_000


def add_texture_parser(sub) -> argparse.ArgumentParser:
    """Register ``bayestouch texture-id`` on the ``bayestouch`` command's subparsers."""
    from bayestouch.params import MODELS
    from bayestouch.scene.textures import LIBRARY

    p = sub.add_parser(
        "texture-id",
        help="texture identification experiment: accuracy against strokes",
        description="Identify which texture of a library the finger strokes: every texture is the truth in "
        "--trials trials; writes results.csv (one row per stroke), summary.json and accuracy_vs_strokes.png.",
    )
    p.add_argument("--textures", type=int, default=20, help="use the first N library textures (default 20)")
    p.add_argument(
        "--trials", type=bounded_int(1, MAX_TRIALS), default=3, help=f"trials per texture (default 3, ≤ {MAX_TRIALS})"
    )
    p.add_argument(
        "--max-strokes",
        type=bounded_int(1, MAX_STROKES),
        default=10,
        help=f"strokes before a forced decision (default 10, ≤ {MAX_STROKES})",
    )
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of the trials (default 0)")
    p.add_argument("--out", required=True, type=out_path, help="output folder")
    p.add_argument(
        "--overwrite", action="store_true", help="set aside the results already in --out (otherwise refused)"
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="keep the finished trials in --out/results.csv and run the rest (the same library, finger, device "
        "file, seed, --textures and settings; more --trials extend the run)",
    )
    p.add_argument("--policy", default="random", choices=("random", "eig"), help="stroke choice (default random)")
    p.add_argument("--threshold", type=float, default=0.95, help="decide when max posterior >= this")
    p.add_argument("--mode", default="empirical", choices=("empirical", "physics"), help="taxel response mode")
    p.add_argument("--library", default=str(LIBRARY), help="texture library TOML (default models/textures.toml)")
    p.add_argument("--full", action="store_true", help="keep stroking after a decision (up to --max-strokes)")
    p.add_argument(
        "--calibration",
        type=Path,
        default=None,
        metavar="DEVICE.toml",
        help="the identifier's device file from `bayestouch calibrate` (per-taxel gains and their errors, in "
        "--mode's taxel mode); without it the gains are unknown and marginalised with the nominal spread of "
        "models/noise.toml. The simulated finger's own gains are never read",
    )
    p.add_argument(
        "--finger-models",
        type=Path,
        default=MODELS,
        metavar="DIR",
        help="parameter folder of the simulated finger (default models/); the identifier always assumes models/, "
        "so a folder with other constants tries it on a finger that is not the one it knows",
    )
    p.add_argument(
        "--quiet", "--no-progress", dest="no_progress", action="store_true", help="no progress bar (or --no-progress)"
    )
    return p


def run_texture_id(args) -> int:
    """Run the experiment from parsed arguments; :class:`~bayestouch.errors.BadInput` propagates (the caller prints
    one line)."""
    from bayestouch.errors import BadInput
    from bayestouch.io.device_file import read_device_file
    from bayestouch.planning.texture_id import check_calibration

    if args.resume and args.overwrite:
        raise BadInput("--resume and --overwrite exclude each other: keep the finished trials, or set them aside")
    if not Path(args.finger_models).is_dir():
        raise BadInput(
            f"--finger-models: {args.finger_models} is not a folder (expected a parameter folder like models/)"
        )
    calibration = None if args.calibration is None else read_device_file(args.calibration)
    check_calibration(calibration, args.mode, args.seed)  # before earlier results are set aside
    with terminations_as_interrupts():  # SIGTERM, SIGHUP: as Ctrl-C (one line, exit 130), not a silent death
        try:
            return _run(args, calibration)
        except KeyboardInterrupt:
            print(f"bayestouch texture-id: interrupted; {_finished(args.out)}", file=sys.stderr)
            return 130


def _finished(out: Path) -> str:
    """What an interrupted run leaves: its finished trials in results.csv, and how to go on."""
    from bayestouch.errors import BadInput
    from bayestouch.planning.texture_id import read_results

    path = Path(out) / "results.csv"
    try:
        n = len({(r["texture"], r["trial"]) for r in read_results(path)}) if path.is_file() else 0
    except BadInput:
        n = 0
    if not n:
        return "no trial finished"
    return f"{n} finished trial(s) in {path}; rerun with --resume to do the rest"


def _check_folder(args) -> None:
    """``--out``: refused when it holds another run's results, unless ``--overwrite`` sets them aside or
    ``--resume`` continues a texture-id run there (an interrupted one is named as such)."""
    from bayestouch.cli.args import other_results, other_results_error
    from bayestouch.errors import BadInput
    from bayestouch.planning.texture_id import META

    out = Path(args.out)
    inputs = (args.library, args.calibration)
    own = {"results.csv", "summary.json", META, "accuracy_vs_strokes.png"}
    found = other_results(out, own=own, keep=inputs)
    if found and not args.overwrite:
        raise other_results_error(out, found)
    if args.resume:
        check_out(out)
        return
    if (out / "results.csv").is_file() and not (out / "summary.json").exists() and not args.overwrite:
        raise BadInput(
            f"--out {out} holds an interrupted run (results.csv without summary.json); pass --resume to finish it, "
            "--overwrite to set it aside, or choose another folder"
        )
    check_out(out, args.overwrite, "texture-id", inputs=inputs)


def _run(args, calibration) -> int:
    from bayestouch.io.runfolder import locked_run_folder
    from bayestouch.planning.texture_id import IdSettings, run_experiment

    # the folder is this run's from the check of earlier results to the last output (a second run is refused)
    with locked_run_folder(args.out):
        _check_folder(args)
        s = run_experiment(
            args.out,
            textures=args.textures,
            trials=args.trials,
            max_strokes=args.max_strokes,
            seed=args.seed,
            settings=IdSettings(threshold=args.threshold, mode=args.mode),
            policy=args.policy,
            library=args.library,
            stop_at_decision=not args.full,
            progress=not args.no_progress,
            calibration=calibration,
            finger_models=args.finger_models,
            resume=args.resume,
        )
    keys = ("trials", "accuracy_at_decision", "accuracy_95ci", "median_strokes_to_decision", "decided_fraction")
    print(json.dumps({k: s[k] for k in keys}))
    return 0
