"""``bayestouch demo``: the main job on the built-in simulated finger (exploration, posterior, report)."""

from __future__ import annotations

import argparse
from pathlib import Path

from bayestouch.cli.args import check_out, out_path
from bayestouch.cli.args import seed as seed_arg
from bayestouch.errors import BadInput

__all__ = ["add_parser", "run"]


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``bayestouch demo`` on the command's subparsers."""
    dp = sub.add_parser(
        "demo",
        help="the main job: eig exploration of the egg, its posterior and report.html",
        description="The virtual finger explores the default egg with the eig planner (a scout and "
        "5 planned strokes, the posterior sampled after each), then samples the posterior of every "
        "point touched, replays the strokes through the taxels (currents and a contact-patch "
        "posterior) and writes report.html with its figures, summary.json, posterior.nc and the "
        "meshes into --out.",
    )
    dp.add_argument("--out", type=out_path, default=Path("out/demo"), help="output folder (default out/demo)")
    dp.add_argument("--seed", type=seed_arg, default=0, help="seed of every stage (default 0)")
    dp.add_argument("--quick", action="store_true", help="small sizes (scout + 1 stroke, short chains): a smoke run")
    dp.add_argument("--quiet", action="store_true", help="no progress bars")
    dp.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a run in --out that is not an earlier demo's (a demo's own folder is rebuilt without it)",
    )
    return dp


def run(args) -> int:
    """Run ``bayestouch demo`` from parsed arguments (bad input raises
    :class:`~bayestouch.errors.BadInput`)."""
    from bayestouch.demo import FULL, QUICK, run_demo
    from bayestouch.io.runfolder import RESULT_FILES

    out = check_out(args.out)
    held = [f for f in RESULT_FILES if (out / f).exists()]
    # a demo's folder (its strokes/ made first, demo.json and report.html later) is rebuilt by the next demo
    demo_made = any((out / f).exists() for f in ("strokes", "demo.json", "report.html"))
    if held and not demo_made and not args.overwrite:
        raise BadInput(
            f"--out {out} holds a run that is not a demo's ({', '.join(held)}); pass --overwrite to replace it, or "
            "choose another folder"
        )
    result = run_demo(args.out, seed=args.seed, sizes=QUICK if args.quick else FULL, progress=not args.quiet)
    print(result["table"])
    return 0
