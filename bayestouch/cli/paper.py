"""``bayestouch reproduce-paper``: the paper's Tables 1 and 2 on the damaged graphite plate."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from bayestouch.cli.args import check_out, eps_list, out_path, positive_int, size_list
from bayestouch.cli.args import seed as seed_arg
from bayestouch.errors import BadInput
from bayestouch.params import MODELS

__all__ = ["add_parser", "run"]


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
    rp.add_argument("--seed", type=seed_arg, default=0, help="seed of the paths, perturbation and DE (default 0)")
    rp.add_argument(
        "--object",
        type=Path,
        default=MODELS / "objects" / "graphite_plate.toml",
        help="object TOML (default: the damaged graphite plate)",
    )
    rp.add_argument("--paths", type=positive_int, default=25, help="number of finger paths (default 25)")
    rp.add_argument("--rate", type=float, default=20.0, help="contact samples per second at 1 cm/s (default 20)")
    rp.add_argument(
        "--sizes", type=size_list, default=None, help="FFD sizes, e.g. 7x7x7,6x6x3 (default: the paper's five)"
    )
    rp.add_argument("--epsilons", type=eps_list, default=None, help="perturbation levels (default 0,0.001)")
    rp.add_argument("--res", type=positive_int, default=40, help="model mesh cells per cube edge (default 40)")
    rp.add_argument("--quiet", action="store_true", help="no progress bar")
    return rp


def run(args) -> int:
    """Run ``bayestouch reproduce-paper`` from parsed arguments (bad input raises
    :class:`~bayestouch.errors.BadInput`)."""
    from bayestouch.paper import TABLE2_SIZES
    from bayestouch.report.tables import write_table2
    from bayestouch.scene.objects import load_object

    if not args.rate > 0:
        raise BadInput(f"--rate must be > 0 samples per second, got {args.rate}")
    obj = load_object(args.object)
    out = check_out(args.out)
    from bayestouch.paper import reproduce_table2

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
