"""``bayestouch demo``: the main job on the built-in simulated finger (exploration, posterior, report)."""

from __future__ import annotations

import argparse
from pathlib import Path

from bayestouch.cli.args import seed as seed_arg

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
    dp.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    dp.add_argument("--seed", type=seed_arg, default=0, help="seed of every stage (default 0)")
    dp.add_argument("--quick", action="store_true", help="small sizes (scout + 1 stroke, short chains): a smoke run")
    dp.add_argument("--quiet", action="store_true", help="no progress bars")
    return dp


def run(args) -> int:
    """Run ``bayestouch demo`` from parsed arguments (bad input raises
    :class:`~bayestouch.errors.BadInput`)."""
    from bayestouch.demo import FULL, QUICK, run_demo

    result = run_demo(args.out, seed=args.seed, sizes=QUICK if args.quick else FULL, progress=not args.quiet)
    print(result["table"])
    return 0
