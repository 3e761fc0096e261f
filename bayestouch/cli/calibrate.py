"""``bayestouch calibrate``: a finger's device file from strokes over a known object."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bayestouch.cli.args import out_path
from bayestouch.errors import BadInput
from bayestouch.params import MODELS

__all__ = ["add_parser", "run", "MISFIT_NOISE_SCALE"]

#: residual sd over the modelled read-out sd above which the calibration warns that the object, its pose or the
#: finger's constants do not fit the readings
MISFIT_NOISE_SCALE = 3.0


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``bayestouch calibrate`` on the command's subparsers."""
    cp = sub.add_parser(
        "calibrate",
        help="device file (per-taxel gains and their errors) from strokes over a known object",
        description="Estimate each taxel's fixed-pattern log-gain, with its standard error from the spread between "
        "strokes, and the read-out noise's scale, from a recording of strokes over a known object in a known pose "
        "(at least 2 strokes). Writes a TOML device file for `bayestouch fit REC.nc --calibration DEVICE.toml`.",
    )
    cp.add_argument("recording", type=Path, help="recording .nc of strokes over the known object")
    cp.add_argument(
        "--object",
        required=True,
        help="the touched object: a name (sphere, egg, ...) or a TOML file, in the recording's world frame",
    )
    cp.add_argument("--out", required=True, type=out_path, help="device file to write (.toml)")
    cp.add_argument("--models", type=Path, default=MODELS, help="the finger's parameter folder (default models/)")
    cp.add_argument("--overwrite", action="store_true", help="replace an existing device file")
    return cp


def run(args) -> int:
    """Run ``bayestouch calibrate`` from parsed arguments (bad input raises BadInput)."""
    from bayestouch.api import calibrate

    if args.out.suffix != ".toml":
        raise BadInput(f"--out {args.out}: expected a .toml device file")
    if args.out.exists() and not args.overwrite:
        raise BadInput(f"--out {args.out} exists; pass --overwrite to replace it")
    cal = calibrate(args.recording, args.object, models=args.models, out=args.out, overwrite=args.overwrite)
    print(
        f"wrote {args.out}: {np.size(cal.log_gain)} taxels from {cal.info['strokes']} stroke(s) over "
        f"{args.object}, log-gain sd {np.median(cal.log_gain_sd):.2g} (median), noise scale {cal.noise_scale:.2f}"
    )
    if "response" in cal.info:  # the response factor stays the fit's prior (±30 %)
        print(f"bayestouch calibrate: the taxels' response is {cal.info['response']}", file=sys.stderr)
    if cal.noise_scale > MISFIT_NOISE_SCALE:
        print(
            f"bayestouch calibrate: warning: the residuals are {cal.noise_scale:.1f}x the modelled read-out noise: "
            "the object, its pose or the finger's constants do not fit these readings; the gains are unreliable",
            file=sys.stderr,
        )
    return 0
