"""``bayestouch reproduce-paper``: the paper's Tables 1 and 2 on the damaged graphite plate."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bayestouch.cli.args import bounded_int, check_out, eps_list, out_path, size_list
from bayestouch.cli.args import seed as seed_arg
from bayestouch.errors import BadInput
from bayestouch.params import MODELS

__all__ = ["add_parser", "run"]

#: most finger paths, and the highest sampling rate (samples per second at 1 cm/s)
MAX_PATHS = 1000
MAX_RATE = 1000.0
#: most model mesh cells per cube edge (6·res² vertices; the FFD matrix is vertices × control points)
MAX_RES = 200
#: most FFD control points along one lattice axis (the paper's largest lattice is 7x7x7)
MAX_FFD_AXIS = 10
#: most contact points of the probed data (an upper bound from --paths, --rate and the object's size; the FFD
#: least squares holds points × control points)
MAX_POINTS = 500_000
#: the finger's speed along the paths, m/s (``scene.paths.random_paths``, the paper's 1 cm/s)
_SPEED = 0.01


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``bayestouch reproduce-paper`` on the command's subparsers."""
    rp = sub.add_parser(
        "reproduce-paper",
        help="reproduce the paper's Table 2 (n-ellipsoid + FFD pipeline)",
        description="Reproduce Table 2 of the paper on the damaged graphite plate: "
        "differential-evolution fit of the 12-parameter n-ellipsoid, FFD refinement for each "
        "lattice size, and the indicators of eq. 3 and 11–13, beside the paper's figures.",
    )
    rp.add_argument("--out", required=True, type=out_path, help="output folder (table2.csv, table2.md)")
    rp.add_argument(
        "--overwrite", action="store_true", help="set aside the results already in --out (otherwise refused)"
    )
    rp.add_argument("--seed", type=seed_arg, default=0, help="seed of the paths, perturbation and DE (default 0)")
    rp.add_argument(
        "--object",
        type=Path,
        default=MODELS / "objects" / "graphite_plate.toml",
        help="object TOML (default: the damaged graphite plate)",
    )
    rp.add_argument(
        "--paths",
        type=bounded_int(1, MAX_PATHS),
        default=25,
        help=f"number of finger paths (default 25; 1 to {MAX_PATHS}, and at most {MAX_POINTS} contact points with "
        "--rate)",
    )
    rp.add_argument(
        "--rate",
        type=float,
        default=20.0,
        help=f"contact samples per second at 1 cm/s (default 20; more than 0 and at most {MAX_RATE:g})",
    )
    rp.add_argument(
        "--sizes",
        type=size_list,
        default=None,
        help=f"FFD sizes, e.g. 7x7x7,6x6x3, each from 2 to {MAX_FFD_AXIS} (default: the paper's five)",
    )
    rp.add_argument("--epsilons", type=eps_list, default=None, help="perturbation levels (default 0,0.001)")
    rp.add_argument(
        "--res",
        type=bounded_int(1, MAX_RES),
        default=40,
        help=f"model mesh cells per cube edge (default 40; 1 to {MAX_RES})",
    )
    rp.add_argument("--quiet", action="store_true", help="no progress bar")
    return rp


def run(args) -> int:
    """Run ``bayestouch reproduce-paper`` from parsed arguments (bad input raises
    :class:`~bayestouch.errors.BadInput`)."""
    from bayestouch.scene.objects import load_object

    if not (0 < args.rate <= MAX_RATE):
        raise BadInput(f"--rate must be in (0, {MAX_RATE:g}] samples per second, got {args.rate}")
    for size in args.sizes or ():
        if max(int(p) for p in size.split("x")) > MAX_FFD_AXIS:
            raise BadInput(
                f"--sizes: at most {MAX_FFD_AXIS} control points along each axis (the FFD matrix holds mesh "
                f"vertices × control points), got {size}"
            )
    if args.out.exists() and not args.out.is_dir():
        raise BadInput(f"--out {args.out} exists and is not a folder")
    obj = load_object(args.object)
    # a path walks part of a plane section at 1 cm/s, a convex curve inside a great circle of the object's
    # bounding sphere: at most that circle's length
    seconds = 2 * np.pi * float(np.linalg.norm(np.asarray(obj.shape.axes, float))) / _SPEED
    most = max(args.paths, 21) * args.rate * seconds  # Table 1 takes at least 21 paths
    if most > MAX_POINTS:
        raise BadInput(
            f"--paths × --rate: up to {most:.3g} contact points on {obj.name} ({args.paths} paths of up to "
            f"{seconds:.0f} s at {args.rate:g} samples/s); at most {MAX_POINTS} fit in memory, lower --rate or --paths"
        )
    from bayestouch.io.runfolder import locked_run_folder

    # the folder is this run's from the check of earlier results to the last table (a second run is refused)
    with locked_run_folder(args.out):
        return _reproduce_into(args, obj)


def _reproduce_into(args, obj) -> int:
    """Tables 2 and 1 of :func:`run`, the options checked and ``--out`` held."""
    from bayestouch.paper import TABLE2_SIZES, reproduce_table2
    from bayestouch.report.tables import write_table2

    out = check_out(args.out, args.overwrite, "reproduce-paper", inputs=(args.object,))

    t0 = time.perf_counter()
    rows = reproduce_table2(
        obj,
        sizes=tuple(args.sizes or TABLE2_SIZES),
        epsilons=tuple(args.epsilons or (0.0, 1e-3)),
        seed=args.seed,
        n_paths=args.paths,
        rate=args.rate,
        res=args.res,
        progress=not args.quiet,
    )
    md = write_table2(rows, out)
    from bayestouch.report.figures import plot_table2

    fig = plot_table2(rows, out)
    print(md)
    from bayestouch.paper import reproduce_table1
    from bayestouch.physics.virtual import load_finger
    from bayestouch.report.tables import write_table1

    rows1 = reproduce_table1(
        obj,
        load_finger(seed=args.seed),
        seed=args.seed,
        n_paths=max(args.paths, 21),
        rate=args.rate,
        progress=not args.quiet,
    )
    print(write_table1(rows1, out))
    print(
        f"wrote table2.csv, table2.md, {fig.name}, table1.csv and table1.md in {out} "
        f"in {time.perf_counter() - t0:.1f} s"
    )
    return 0
