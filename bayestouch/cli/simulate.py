"""``bayestouch simulate``: strokes of the simulated finger over an object, written as a recording (netCDF)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bayestouch.cli.args import check_duration_rate, out_path, positive_int
from bayestouch.cli.args import seed as seed_arg
from bayestouch.errors import BadInput
from bayestouch.params import MODELS

__all__ = ["add_parser", "run"]


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``bayestouch simulate`` on the command's subparsers."""
    sp = sub.add_parser(
        "simulate",
        help="simulate strokes of the virtual finger over an object (netCDF)",
        description="Run the physics forward model (SMA wires, auxetic skin, piezotronic taxels, "
        "noise) for random strokes over an object and write a recording (netCDF, SI units).",
    )
    sp.add_argument(
        "--object",
        required=True,
        type=Path,
        help="object name (egg, sphere, box, cylinder, ...) or TOML file, e.g. models/objects/egg.toml",
    )
    sp.add_argument("--strokes", type=positive_int, default=1, help="number of strokes (default 1)")
    sp.add_argument("--seed", type=seed_arg, default=0, help="seed of the strokes and the noise (default 0)")
    sp.add_argument(
        "--device-seed",
        type=seed_arg,
        default=None,
        help="which simulated finger (its taxels' fixed-pattern gains); default --seed. Recordings of one finger "
        "share it, e.g. a calibration and the strokes it serves",
    )
    sp.add_argument("--out", required=True, type=out_path, help="recording to write (.nc)")
    sp.add_argument("--overwrite", action="store_true", help="replace an existing --out recording")
    sp.add_argument("--duration", type=float, default=2.0, help="seconds per stroke at 1 cm/s (default 2)")
    sp.add_argument("--rate", type=float, default=50.0, help="taxel frames per second (default 50)")
    sp.add_argument(
        "--depth",
        default=None,
        help="pressing depth in metres, or a comma list cycled over the strokes, e.g. 2e-4,3e-4,4e-4 with "
        "--mode empirical for a calibration that identifies the taxels' response (the physics mode's pressure "
        "signal is below the read-out noise at such depths) (default 3e-4)",
    )
    sp.add_argument(
        "--force",
        type=float,
        default=None,
        help="force-controlled strokes: normal force in newtons (replaces --depth), e.g. 0.07",
    )
    sp.add_argument(
        "--mode", choices=["physics", "empirical"], default=None, help="taxel response (default: models/taxels.toml)"
    )
    sp.add_argument(
        "--currents",
        default="0.15,0.05,0.05",
        help="hold currents of the three wires in amperes (default 0.15,0.05,0.05)",
    )
    sp.add_argument("--models", type=Path, default=MODELS, help="parameter folder (default models/)")
    sp.add_argument("--quiet", action="store_true", help="no progress bar")
    return sp


def run(args) -> int:
    """Run ``bayestouch simulate`` from parsed arguments (bad input raises
    :class:`~bayestouch.errors.BadInput`)."""
    if args.out.suffix != ".nc":
        raise BadInput(f"--out {args.out}: expected a netCDF file name ending in .nc")
    if args.out.exists() and args.out.is_dir():
        raise BadInput(f"--out {args.out} is a folder; expected a .nc file name")
    check_duration_rate(args.duration, args.rate)
    try:
        currents = [float(x) for x in args.currents.split(",")]
    except ValueError:
        raise BadInput(
            f"--currents must be three numbers in amperes like 0.15,0.05,0.05, got {args.currents!r}"
        ) from None
    if len(currents) != 3:
        raise BadInput(f"--currents must be three numbers in amperes, got {len(currents)}")
    if args.depth is not None and args.force is not None:
        raise BadInput("--depth and --force exclude each other: with --force each frame's depth is solved for it")
    try:
        depths = [float(x) for x in str("3e-4" if args.depth is None else args.depth).split(",")]
    except ValueError:
        raise BadInput(f"--depth must be metres or a comma list of metres like 2e-4,3e-4, got {args.depth!r}") from None
    if not all(0 < d <= 2e-3 for d in depths):
        raise BadInput(f"--depth: each pressing depth must be in (0, 2e-3] metres, got {args.depth}")
    from bayestouch.io.recording import MAX_FRAMES

    frames = args.strokes * int(np.ceil(args.duration * args.rate))
    if frames > MAX_FRAMES:
        raise BadInput(
            f"--strokes {args.strokes} × --duration {args.duration:g} s × --rate {args.rate:g} Hz is {frames} frames, "
            f"more than {MAX_FRAMES} in one recording (each frame holds every taxel); split it into several recordings"
        )
    if args.force is not None and not (0 < args.force <= 2.0):
        raise BadInput(f"--force must be in (0, 2] newtons, got {args.force}")
    from bayestouch.api import simulate  # checks --out last: an existing recording is refused after bad arguments

    t0 = time.perf_counter()
    ds = simulate(
        args.object,
        strokes=args.strokes,
        seed=args.seed,
        device_seed=args.device_seed,
        duration=args.duration,
        rate=args.rate,
        depth=depths,
        mode=args.mode,
        hold_currents=currents,
        force=args.force,
        models=args.models,
        progress=not args.quiet,
        out=args.out,
        overwrite=args.overwrite,
    )
    n_strokes = int(ds.sizes["stroke"])
    f = ds["contact_force"].values
    print(
        f"wrote {args.out}: {n_strokes} stroke(s), {ds.sizes['frame']} frames × {ds.sizes['taxel']} taxels, "
        f"contact force {f.min():.3f}–{f.max():.3f} N, in {time.perf_counter() - t0:.1f} s"
    )
    return 0
