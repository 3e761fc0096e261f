"""The ``bayestouch`` command.

Exit codes: 0 success, 2 bad input (one line on stderr naming the problem), 1 internal error.
Set ``BAYESTOUCH_DEBUG=1`` to see tracebacks of internal errors.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

__all__ = ["main", "build_parser"]

#: subcommands that later work fills in, with where they are specified
PLANNED = {
    "simulate": "the physics forward model (issue 3)",
    "fit": "the inference engine (issue 4)",
    "explore": "the active probing planner (issue 5)",
    "experiment": "the exploration experiments (issue 5)",
    "device": "the hardware adapter (issue 6)",
}

DEFAULT_OBJECTS = Path(__file__).resolve().parent.parent / "models" / "objects"


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def _size_list(text: str) -> list[str]:
    sizes = [s.strip().lower() for s in text.split(",") if s.strip()]
    for s in sizes:
        parts = s.split("x")
        if len(parts) != 3 or not all(p.isdigit() and int(p) >= 2 for p in parts):
            raise argparse.ArgumentTypeError(f"FFD sizes must look like 6x6x3 (each ≥ 2), got {s!r}")
    return sizes


def _eps_list(text: str) -> list[float]:
    try:
        eps = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"epsilons must be comma-separated numbers, got {text!r}") from None
    if any(not 0 <= e < 0.5 for e in eps):
        raise argparse.ArgumentTypeError(f"epsilons must lie in [0, 0.5), got {eps}")
    return eps


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="bayestouch",
        description="Probabilistic inference for tactile shape and texture sensing.",
        epilog="planned subcommands (not in this version yet): "
        + "; ".join(f"{k}: {v}" for k, v in PLANNED.items()),
    )
    from bayestouch import __version__

    p.add_argument("--version", action="version", version=f"bayestouch {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    rp = sub.add_parser("reproduce-paper", help="reproduce the paper's Table 2 (n-ellipsoid + FFD pipeline)",
                        description="Reproduce Table 2 of the paper on the damaged graphite plate: "
                        "differential-evolution fit of the 12-parameter n-ellipsoid, FFD refinement for each "
                        "lattice size, and the indicators of eq. 3 and 11–13, beside the paper's figures.")
    rp.add_argument("--out", required=True, type=Path, help="output folder (table2.csv, table2.md)")
    rp.add_argument("--seed", type=int, default=0, help="seed of the paths, perturbation and DE (default 0)")
    rp.add_argument("--object", type=Path, default=DEFAULT_OBJECTS / "graphite_plate.toml",
                    help="object TOML (default: the damaged graphite plate)")
    rp.add_argument("--paths", type=_positive_int, default=25, help="number of finger paths (default 25)")
    rp.add_argument("--rate", type=float, default=20.0, help="contact samples per second at 1 cm/s (default 20)")
    rp.add_argument("--sizes", type=_size_list, default=None,
                    help="FFD sizes, e.g. 7x7x7,6x6x3 (default: the paper's five)")
    rp.add_argument("--epsilons", type=_eps_list, default=None, help="perturbation levels (default 0,0.001)")
    rp.add_argument("--res", type=_positive_int, default=40, help="model mesh cells per cube edge (default 40)")
    rp.add_argument("--quiet", action="store_true", help="no progress bar")

    dp = sub.add_parser("demo", help="run the main job on the built-in default (what exists so far)",
                        description="End-to-end run of what this version provides: the paper pipeline on the "
                        "damaged graphite plate at a reduced size, written to --out.")
    dp.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    dp.add_argument("--seed", type=int, default=0)
    return p


def _check_out(path: Path) -> Path:
    if path.exists() and not path.is_dir():
        from bayestouch.errors import BadInput

        raise BadInput(f"--out {path} exists and is not a folder")
    path.mkdir(parents=True, exist_ok=True)
    return path


def _cmd_reproduce_paper(args) -> int:
    from bayestouch.paper import TABLE2_SIZES
    from bayestouch.report_tables import write_table2
    from bayestouch.scene.objects import load_object

    if not args.rate > 0:
        from bayestouch.errors import BadInput

        raise BadInput(f"--rate must be > 0 samples per second, got {args.rate}")
    obj = load_object(args.object)
    out = _check_out(args.out)
    from bayestouch.paper import reproduce_table2

    t0 = time.perf_counter()
    rows = reproduce_table2(obj, sizes=tuple(args.sizes or TABLE2_SIZES), epsilons=tuple(args.epsilons or (0.0, 1e-3)),
                            seed=args.seed, n_paths=args.paths, rate=args.rate, res=args.res,
                            progress=not args.quiet)
    md = write_table2(rows, out)
    from bayestouch.report import plot_table2

    fig = plot_table2(rows, out)
    print(md)
    print(f"wrote {out / 'table2.csv'}, {out / 'table2.md'} and {fig} in {time.perf_counter() - t0:.1f} s")
    return 0


def _cmd_demo(args) -> int:
    ns = argparse.Namespace(out=args.out, seed=args.seed, object=DEFAULT_OBJECTS / "graphite_plate.toml",
                            paths=25, rate=10.0, sizes=["6x6x3", "6x5x5"], epsilons=[0.0, 1e-3], res=32,
                            quiet=False)
    print("bayestouch demo: the paper pipeline on the damaged graphite plate (reduced size).")
    print("The virtual-finger exploration of the full demo arrives with the physics, inference and planning work.")
    return _cmd_reproduce_paper(ns)


COMMANDS = {"reproduce-paper": _cmd_reproduce_paper, "demo": _cmd_demo}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in PLANNED:
        print(f"bayestouch: error: '{argv[0]}' is not available in this version yet ({PLANNED[argv[0]]})",
              file=sys.stderr)
        return 2
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    from bayestouch.errors import BadInput

    try:
        return COMMANDS[args.command](args)
    except BadInput as e:
        print(f"bayestouch {args.command}: error: {e}", file=sys.stderr)
        return 2
    except (PermissionError, FileNotFoundError, IsADirectoryError, NotADirectoryError) as e:
        print(f"bayestouch {args.command}: error: {e.strerror or e}: {e.filename}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"bayestouch {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # internal error: one line unless debugging
        if os.environ.get("BAYESTOUCH_DEBUG"):
            raise
        print(f"bayestouch {args.command}: internal error: {type(e).__name__}: {e} "
              "(set BAYESTOUCH_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
