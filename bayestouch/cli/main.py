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

# One BLAS thread unless the user says otherwise, set before NumPy loads BLAS: the toolkit's linear algebra is on
# 11×11 matrices, where a second OpenBLAS thread only spins; on a busy 2-core machine it made each L-BFGS-B
# iteration of the initial fit 2.7 ms instead of ~0.05 ms. (JAX's own threads are not affected.)
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from bayestouch.cli.args import seed as seed_arg  # noqa: E402
from bayestouch.params import MODELS  # noqa: E402

__all__ = ["main", "build_parser"]

DEFAULT_OBJECTS = MODELS / "objects"


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


def _one_size(text: str) -> tuple[int, int, int]:
    sizes = _size_list(text)
    if len(sizes) != 1:
        raise argparse.ArgumentTypeError(f"expected one lattice size like 3x3x3, got {text!r}")
    return tuple(int(p) for p in sizes[0].split("x"))


def _eps_list(text: str) -> list[float]:
    try:
        eps = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"epsilons must be comma-separated numbers, got {text!r}") from None
    if any(not 0 <= e < 0.5 for e in eps):
        raise argparse.ArgumentTypeError(f"epsilons must lie in [0, 0.5), got {eps}")
    return eps


class _OneLineParser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage block): ``bayestouch fit: error: ... (see bayestouch fit --help)``,
    exit code 2. Subcommand parsers inherit the class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _OneLineParser(
        prog="bayestouch",
        description="Probabilistic inference for tactile shape and texture sensing.",
    )
    from bayestouch import __version__

    p.add_argument("--version", action="version", version=f"bayestouch {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    rp = sub.add_parser(
        "reproduce-paper",
        help="reproduce the paper's Table 2 (n-ellipsoid + FFD pipeline)",
        description="Reproduce Table 2 of the paper on the damaged graphite plate: "
        "differential-evolution fit of the 12-parameter n-ellipsoid, FFD refinement for each "
        "lattice size, and the indicators of eq. 3 and 11–13, beside the paper's figures.",
    )
    rp.add_argument("--out", required=True, type=Path, help="output folder (table2.csv, table2.md)")
    rp.add_argument("--seed", type=seed_arg, default=0, help="seed of the paths, perturbation and DE (default 0)")
    rp.add_argument(
        "--object",
        type=Path,
        default=DEFAULT_OBJECTS / "graphite_plate.toml",
        help="object TOML (default: the damaged graphite plate)",
    )
    rp.add_argument("--paths", type=_positive_int, default=25, help="number of finger paths (default 25)")
    rp.add_argument("--rate", type=float, default=20.0, help="contact samples per second at 1 cm/s (default 20)")
    rp.add_argument(
        "--sizes", type=_size_list, default=None, help="FFD sizes, e.g. 7x7x7,6x6x3 (default: the paper's five)"
    )
    rp.add_argument("--epsilons", type=_eps_list, default=None, help="perturbation levels (default 0,0.001)")
    rp.add_argument("--res", type=_positive_int, default=40, help="model mesh cells per cube edge (default 40)")
    rp.add_argument("--quiet", action="store_true", help="no progress bar")

    fp = sub.add_parser(
        "fit",
        help="posterior over the object's shape from contact points or a recording (emcee)",
        description="Bayesian shape fit sampled with emcee. Contact level (a .csv of contact points): "
        "Student-t residuals of the points against an n-ellipsoid. Raw-current level (a .nc "
        "recording from `bayestouch simulate` or `bayestouch device run`): the forward model "
        "predicts every taxel's current. Writes summary.json, posterior.nc (ArviZ), mean_shape.ply, "
        "uncertainty_mesh.ply and the resumable chain.h5.",
    )
    fp.add_argument(
        "points", type=Path, help="contact points CSV (x,y,z in metres; optional nx,ny,nz,force) or a recording .nc"
    )
    fp.add_argument("--out", required=True, type=Path, help="output folder")
    fp.add_argument("--seed", type=seed_arg, default=0, help="seed of the initial fit, walkers and emcee (default 0)")
    fp.add_argument("--walkers", type=_positive_int, default=32, help="emcee walkers (default 32)")
    fp.add_argument(
        "--steps",
        type=_positive_int,
        default=None,
        help="largest chain length in steps (default 20000 for contact points, 1500 for a recording); "
        "sampling stops earlier once converged (N > 50 autocorrelation times, R-hat < 1.01, bulk ESS "
        "> 400)",
    )
    fp.add_argument("--no-early-stop", action="store_true", help="sample exactly --steps steps")
    fp.add_argument("--resume", action="store_true", help="continue the chain in OUT/chain.h5")
    fp.add_argument("--budget", type=float, default=None, help="wall-clock budget for sampling, seconds")
    fp.add_argument(
        "--noise",
        choices=["student", "gaussian", "multiplicative", "mixture"],
        default="student",
        help="contact level residual model: Student-t (default, robust), Gaussian, the paper's "
        "multiplicative (1 + r) perturbation, or Gaussian + uniform outliers",
    )
    fp.add_argument("--nu", type=float, default=None, help="Student-t degrees of freedom (default: models/priors.toml)")
    fp.add_argument(
        "--precision",
        choices=["auto", "float64", "mixed"],
        default="auto",
        help="arithmetic of the sampled contact-level log-density: mixed (float32 per-point "
        "transcendentals, ~2x faster, error < 1e-3 nat) where it applies (auto: Student-t or Gaussian "
        "noise, no normals, no --ffd), else float64; summaries are float64 always",
    )
    fp.add_argument(
        "--ignore-normals",
        action="store_true",
        help="do not use the file's nx,ny,nz columns (by default they add a von Mises-Fisher term)",
    )
    fp.add_argument(
        "--ffd",
        type=_one_size,
        default=None,
        metavar="LxMxK",
        help="contact level: refine the n-ellipsoid with an FFD lattice of this size, marginalised "
        "analytically (Gaussian noise), e.g. 3x3x3",
    )
    fp.add_argument(
        "--ffd-tau",
        type=float,
        default=None,
        help="prior sd of the FFD control-point displacements, metres (default 5e-4)",
    )
    fp.add_argument(
        "--texture",
        choices=["auto", "on", "off"],
        default="auto",
        help="recording (.nc) only: sample the surface texture (grating amplitude, wavelength, "
        "orientation, phase and roughness): auto = when the grating search finds one (default)",
    )
    fp.add_argument(
        "--stride",
        type=_positive_int,
        default=None,
        help="recording (.nc) only: use every STRIDE-th frame (default 2 with texture, 5 without)",
    )
    fp.add_argument("--quiet", action="store_true", help="no progress bar")

    sp = sub.add_parser(
        "simulate",
        help="simulate strokes of the virtual finger over an object (netCDF)",
        description="Run the physics forward model (SMA wires, auxetic skin, piezotronic taxels, "
        "noise) for random strokes over an object and write a recording (netCDF, SI units).",
    )
    sp.add_argument("--object", required=True, type=Path, help="object TOML, e.g. models/objects/egg.toml")
    sp.add_argument("--strokes", type=_positive_int, default=1, help="number of strokes (default 1)")
    sp.add_argument("--seed", type=seed_arg, default=0, help="seed of the strokes and the noise (default 0)")
    sp.add_argument("--out", required=True, type=Path, help="recording to write (.nc)")
    sp.add_argument("--duration", type=float, default=2.0, help="seconds per stroke at 1 cm/s (default 2)")
    sp.add_argument("--rate", type=float, default=50.0, help="taxel frames per second (default 50)")
    sp.add_argument("--depth", type=float, default=3e-4, help="pressing depth in metres (default 3e-4)")
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
    sp.add_argument("--models", type=Path, default=DEFAULT_OBJECTS.parent, help="parameter folder (default models/)")
    sp.add_argument("--quiet", action="store_true", help="no progress bar")

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

    from bayestouch.cli.device import add_device_parser
    from bayestouch.cli.explore import add_planning_parsers

    add_device_parser(sub)
    add_planning_parsers(sub)
    from bayestouch.cli.sbc import add_sbc_parser
    from bayestouch.cli.texture_id import add_texture_parser

    add_texture_parser(sub)
    add_sbc_parser(sub)
    return p


def _check_out(path: Path) -> Path:
    if path.exists() and not path.is_dir():
        from bayestouch.errors import BadInput

        raise BadInput(f"--out {path} exists and is not a folder")
    path.mkdir(parents=True, exist_ok=True)
    return path


def _cmd_reproduce_paper(args) -> int:
    from bayestouch.paper import TABLE2_SIZES
    from bayestouch.report.tables import write_table2
    from bayestouch.scene.objects import load_object

    if not args.rate > 0:
        from bayestouch.errors import BadInput

        raise BadInput(f"--rate must be > 0 samples per second, got {args.rate}")
    obj = load_object(args.object)
    out = _check_out(args.out)
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


def _cmd_demo(args) -> int:
    from bayestouch.demo import FULL, QUICK, run_demo

    run_demo(args.out, seed=args.seed, sizes=QUICK if args.quick else FULL, progress=not args.quiet)
    return 0


def _cmd_simulate(args) -> int:
    from bayestouch.errors import BadInput

    if args.out.suffix != ".nc":
        raise BadInput(f"--out {args.out}: expected a netCDF file name ending in .nc")
    if args.out.exists() and args.out.is_dir():
        raise BadInput(f"--out {args.out} is a folder; expected a .nc file name")
    if not (0 < args.duration <= 600):
        raise BadInput(f"--duration must be in (0, 600] seconds, got {args.duration}")
    if not (1 <= args.rate <= 2000):
        raise BadInput(f"--rate must be in [1, 2000] frames per second, got {args.rate}")
    try:
        currents = [float(x) for x in args.currents.split(",")]
    except ValueError:
        raise BadInput(
            f"--currents must be three numbers in amperes like 0.15,0.05,0.05, got {args.currents!r}"
        ) from None
    if len(currents) != 3:
        raise BadInput(f"--currents must be three numbers in amperes, got {len(currents)}")
    if args.force is not None and not (0 < args.force <= 2.0):
        raise BadInput(f"--force must be in (0, 2] newtons, got {args.force}")
    from bayestouch import __version__
    from bayestouch.io.recording import build_dataset, write_recording
    from bayestouch.physics.virtual import load_finger, record_strokes
    from bayestouch.scene.objects import load_object
    from bayestouch.scene.strokes import random_strokes

    obj = load_object(args.object)
    vf = load_finger(args.models, seed=args.seed)
    max_current = float(vf.wire.max_current)
    if not all(0 <= c <= max_current for c in currents):
        raise BadInput(f"--currents: wire currents must each be in [0, {max_current:g}] A (amperes), got {currents}")
    strokes = random_strokes(
        obj, args.strokes, seed=args.seed, duration=args.duration, rate=args.rate, depth=args.depth
    )
    t0 = time.perf_counter()
    rec = record_strokes(
        obj, strokes, vf, args.seed, hold_currents=currents, mode=args.mode, force=args.force, progress=not args.quiet
    )
    lay_u = np.asarray(vf.finger.grid[..., 0]).ravel()
    lay_v = np.asarray(vf.finger.grid[..., 1]).ravel()
    ds = build_dataset(
        rec,
        lay_u,
        lay_v,
        np.asarray(vf.finger.reference).ravel(),
        [s.depth for s in strokes],
        {
            "object": obj.name,
            "object_file": str(args.object),
            "seed": args.seed,
            "mode": args.mode or vf.mode,
            "wire_hold_currents_A": args.currents,
            "software": f"bayestouch {__version__}",
            "conventions": "SI units in 'units'",
        },
    )
    write_recording(ds, args.out)
    f = rec["contact_force"]
    print(
        f"wrote {args.out}: {len(strokes)} stroke(s), {len(rec['time'])} frames × {len(lay_u)} taxels, "
        f"contact force {f.min():.3f}–{f.max():.3f} N, in {time.perf_counter() - t0:.1f} s"
    )
    return 0


def _cmd_fit(args) -> int:
    from bayestouch.errors import BadInput

    if args.walkers < 24 or args.walkers % 2:
        raise BadInput(
            f"--walkers must be an even number ≥ 24 (twice the parameters, plus a margin), got {args.walkers}"
        )
    if args.budget is not None and not args.budget > 0:
        raise BadInput(f"--budget must be > 0 seconds, got {args.budget}")
    if args.out.exists() and not args.out.is_dir():
        raise BadInput(f"--out {args.out} exists and is not a folder")
    if not args.points.is_file():
        raise BadInput(f"{args.points}: no such file (expected a contact points CSV or a recording .nc)")
    if args.ffd_tau is not None and not (0 < args.ffd_tau < 0.1):
        raise BadInput(f"--ffd-tau must be in (0, 0.1) metres, got {args.ffd_tau}")
    if args.points.suffix == ".nc":
        if args.ffd is not None:
            raise BadInput("--ffd applies to contact points (.csv), not to a recording (.nc)")
        from bayestouch.inference.raw import run_raw_fit

        s = run_raw_fit(
            args.points,
            args.out,
            seed=args.seed,
            walkers=args.walkers,
            steps=args.steps or 1500,
            resume=args.resume,
            budget_s=args.budget,
            progress=not args.quiet,
            stop_when_converged=not args.no_early_stop,
            texture=args.texture,
            stride=args.stride,
        )
    else:
        from bayestouch.inference.run import run_contact_fit
        from bayestouch.io.contacts import load_contact_points

        if args.texture != "auto" or args.stride is not None:
            raise BadInput("--texture and --stride apply to a recording (.nc), not to contact points (.csv)")

        cp = load_contact_points(args.points)
        if args.nu is not None and (args.noise != "student" or not args.nu > 0):
            raise BadInput(f"--nu must be > 0 and goes with --noise student, got --nu {args.nu} --noise {args.noise}")
        noise, nu = ("student", float("inf")) if args.noise == "gaussian" else (args.noise, args.nu)
        s = run_contact_fit(
            cp.points,
            args.out,
            seed=args.seed,
            walkers=args.walkers,
            steps=args.steps or 20000,
            resume=args.resume,
            budget_s=args.budget,
            progress=not args.quiet,
            normals=None if args.ignore_normals else cp.normals,
            noise=noise,
            nu=nu,
            ffd=args.ffd,
            ffd_tau=args.ffd_tau,
            stop_when_converged=not args.no_early_stop,
            precision=args.precision,
        )
    d = s["diagnostics"]
    v = s["derived"]["volume_m3"]
    print(
        f"wrote {args.out}/summary.json, posterior.nc, mean_shape.ply, uncertainty_mesh.ply: volume "
        f"{v['mean'] * 1e6:.3f} ± {v['sd'] * 1e6:.3f} cm³ (90 % {v['q05'] * 1e6:.3f}–{v['q95'] * 1e6:.3f}), "
        f"max R-hat {d['max_r_hat']:.3f}, min ESS {d['min_ess_bulk']:.0f}, "
        f"{'converged' if d['converged'] else 'NOT converged'}"
        f"{' (stopped by --budget)' if d.get('stopped_by_budget') else ''} ({d['seconds']:.1f} s)"
    )
    for w in d.get("warnings", []):
        print(f"bayestouch fit: warning: {w}", file=sys.stderr)
    return 0


def _cmd_explore(args) -> int:
    from bayestouch.cli.explore import run_explore

    return run_explore(args)


def _cmd_experiment(args) -> int:
    from bayestouch.cli.explore import run_experiment

    return run_experiment(args)


def _cmd_texture_id(args) -> int:
    from bayestouch.cli.texture_id import run_texture_id

    return run_texture_id(args)


def _cmd_sbc(args) -> int:
    from bayestouch.cli.sbc import run_sbc

    return run_sbc(args)


def _cmd_device(args) -> int:
    from bayestouch.cli.device import run_device

    return run_device(args)


COMMANDS = {
    "reproduce-paper": _cmd_reproduce_paper,
    "demo": _cmd_demo,
    "simulate": _cmd_simulate,
    "fit": _cmd_fit,
    "device": _cmd_device,
    "explore": _cmd_explore,
    "experiment": _cmd_experiment,
    "texture-id": _cmd_texture_id,
    "sbc": _cmd_sbc,
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    from bayestouch.backend import enable_compilation_cache
    from bayestouch.errors import BadInput

    enable_compilation_cache()
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
        print(
            f"bayestouch {args.command}: internal error: {type(e).__name__}: {e} "
            "(set BAYESTOUCH_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
