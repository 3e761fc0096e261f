"""``bayestouch demo``: the main job on the built-in simulated finger (exploration, posterior, report)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bayestouch.cli.args import COMMAND_OUTPUTS, COMMAND_RESULTS, out_path
from bayestouch.cli.args import seed as seed_arg
from bayestouch.errors import BadInput

__all__ = ["add_parser", "run"]

#: files a demo writes besides a fit's outputs: another command's (an exploration's points.csv, a finger's
#: recording.nc) unless the folder is a demo's
DEMO_FILES = ("points.csv", "recording.nc", "patch_summary.json")
#: another command's results (:data:`bayestouch.cli.args.COMMAND_RESULTS`, glob patterns; the demo's own excepted):
#: a demo into that folder is refused unless --overwrite sets them aside, with what goes with them (figures, tables,
#: a finger's journal; not the files a demo writes itself)
OTHER_RESULTS = tuple(p for p in COMMAND_RESULTS if p not in ("demo.json", "report.html"))
OTHER_OUTPUTS = tuple(f for f in COMMAND_OUTPUTS if f not in (*DEMO_FILES, "strokes"))


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``bayestouch demo`` on the command's subparsers."""
    dp = sub.add_parser(
        "demo",
        help="the main job: eig exploration of the egg, its posterior and report.html",
        description="A virtual finger with bending constants of its own (not models/') is calibrated on a "
        "2-cm sphere, then explores the default egg with guarded strokes over the serial protocol and the eig "
        "planner (a scout and 5 planned strokes, the posterior sampled after each with the pad's pose error "
        "marginalised); then the posterior of every point touched is sampled, the strokes are replayed through "
        "the taxels (currents and a contact-patch posterior) and report.html is written with its figures, "
        "summary.json, posterior.nc and the meshes into --out.",
    )
    dp.add_argument("--out", type=out_path, default=Path("out/demo"), help="output folder (default out/demo)")
    dp.add_argument("--seed", type=seed_arg, default=0, help="seed of every stage (default 0)")
    dp.add_argument("--quick", action="store_true", help="small sizes (scout + 1 stroke, short chains): a smoke run")
    dp.add_argument("--quiet", action="store_true", help="no progress bars")
    dp.add_argument(
        "--rays",
        action="store_true",
        help="explore in the ray world (contacts with the encoders' noise only; the demo before the bending chain) "
        "instead of through the finger",
    )
    dp.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a run in --out that is not an earlier demo's (an earlier demo's folder is rebuilt without it, "
        "its files kept in --out/replaced-<UTC time>/)",
    )
    return dp


def run(args) -> int:
    """Run ``bayestouch demo`` from parsed arguments (bad input raises
    :class:`~bayestouch.errors.BadInput`)."""
    from bayestouch.demo import FULL, QUICK, run_demo
    from bayestouch.io.files import move_aside, set_aside
    from bayestouch.io.runfolder import RESULT_FILES, every_earlier_file, locked_run_folder

    # the folder is this run's from the check below to the report (a second run into it is refused; the fit inside
    # the demo leaves it locked)
    with locked_run_folder(args.out) as out:
        # a demo's folder (its strokes/ made first, demo.json and report.html later) is rebuilt by the next demo
        demo_made = any((out / f).exists() for f in ("strokes", "demo.json", "report.html"))
        # another command's results: the demo would write its points.csv, recording.nc … over an exploration's
        other = sorted({p for pattern in OTHER_RESULTS for p in out.glob(pattern) if p.is_file()})
        if not demo_made:
            other += [out / f for f in DEMO_FILES if (out / f).exists()]
        held = [f for f in RESULT_FILES if (out / f).exists()]
        if (other or (held and not demo_made)) and not args.overwrite:
            names = sorted({p.name for p in other} | ({*held} if not demo_made else set()))
            raise BadInput(
                f"--out {out} holds a run that is not a demo's ({', '.join(names[:4])}"
                f"{' …' if len(names) > 4 else ''}); pass --overwrite to replace it, or choose another folder"
            )
        if other:  # --overwrite: set aside, never deleted (a fit's own outputs are set aside by the demo's fit)
            set_aside([*other, *(out / f for f in OTHER_OUTPUTS if (out / f).exists())], "demo")
        if demo_made:  # the earlier demo is rebuilt, and every file of it kept (its recording was overwritten)
            earlier = [*every_earlier_file(out), *([out / "strokes"] if (out / "strokes").is_dir() else [])]
            if earlier:
                aside = move_aside(out, earlier)
                print(
                    f"bayestouch demo: the earlier demo in {out} is kept in {aside} (delete it when no longer needed)",
                    file=sys.stderr,
                )
        result = run_demo(
            args.out, seed=args.seed, sizes=QUICK if args.quick else FULL, progress=not args.quiet, finger=not args.rays
        )
    print(result["table"])
    return 0
