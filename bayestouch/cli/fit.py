"""``bayestouch fit``: a shape posterior from contact points (.csv) or a recording (.nc)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bayestouch.cli.args import (
    COMMAND_OUTPUTS,
    COMMAND_RESULTS,
    one_size,
    other_results,
    other_results_error,
    out_path,
    positive_int,
    size_range,
    stat,
)
from bayestouch.cli.args import seed as seed_arg
from bayestouch.errors import BadInput, file_problem

__all__ = ["add_parser", "run", "MAX_CONTACTS", "OTHER_RESULTS"]

#: most contacts a fit takes (more need --subsample): the contact-level posterior of 50,000 points is already far
#: narrower than the n-ellipsoid's misfit to any real object, and its outputs hold every point's log-likelihood
MAX_CONTACTS = 50_000


#: another command's results and what goes with them (:data:`bayestouch.cli.args.COMMAND_RESULTS`, glob patterns,
#: and :data:`~bayestouch.cli.args.COMMAND_OUTPUTS`); the fit's own outputs are set aside by the run folder
#: (:mod:`bayestouch.io.runfolder`)
OTHER_RESULTS = COMMAND_RESULTS
OTHER_OUTPUTS = COMMAND_OUTPUTS


#: most emcee walkers a fit takes
MAX_WALKERS = 10_000
#: most control points along one axis of an --ffd lattice (8 x 8 x 8: 1536 marginalised displacements)
MAX_FFD_SIZE = 8


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``bayestouch fit`` on the command's subparsers."""
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
        "points",
        type=Path,
        metavar="DATA",
        help="contact points CSV (x,y,z in metres; optional nx,ny,nz,force) or a recording .nc",
    )
    fp.add_argument("--out", required=True, type=out_path, help="output folder")
    fp.add_argument("--seed", type=seed_arg, default=0, help="seed of the initial fit, walkers and emcee (default 0)")
    fp.add_argument("--walkers", type=positive_int, default=32, help="emcee walkers (default 32)")
    fp.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        help="largest chain length in steps (default 20000 for contact points, 1500 for a recording); "
        "sampling stops earlier once converged (N > 50 autocorrelation times, R-hat < 1.01, bulk ESS "
        "> 400)",
    )
    fp.add_argument("--no-early-stop", action="store_true", help="sample exactly --steps steps")
    fp.add_argument(
        "--resume",
        action="store_true",
        help="continue the chain in OUT/chain.h5 (refused when OUT holds a run of other data or options)",
    )
    fp.add_argument(
        "--subsample",
        type=int,
        default=None,
        metavar="N",
        help=f"fit N contacts drawn at random (seeded by --seed) from a larger file; files of more than {MAX_CONTACTS} "
        "contacts need it",
    )
    fp.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the run already in OUT (without it, a folder holding a run is refused)",
    )
    fp.add_argument(
        "--budget",
        type=float,
        default=None,
        help="wall-clock budget of the fit, seconds (default: 60 for contact points, 180 with --parts, none for a "
        "recording; 0 for none): for contact points it covers search, sampling and outputs; for a recording it ends "
        "the sampling, and the search before it and the outputs after it add their time (tens of seconds); the "
        "chain runs at least 200 steps; a run stopped by it is reported as not converged and can be continued with "
        "--resume",
    )
    fp.add_argument(
        "--noise",
        choices=["auto", "outlier", "student", "gaussian", "multiplicative", "mixture"],
        default="auto",
        help="contact level residual model: Gaussian with contacts displaced into the solid or out into "
        "free space as separate outlier events, Student-t, Gaussian, the paper's multiplicative (1 + r) "
        "perturbation, or Gaussian + uniform outliers; auto (default): outlier, or Student-t for 300 or more "
        "contacts surrounding the object",
    )
    fp.add_argument(
        "--size-prior",
        type=size_range,
        default=None,
        metavar="MIN:MAX",
        help="contact level: objects MIN-MAX metres across (the central 95 %% of each axis's full length, "
        "log-normal), e.g. 0.01:0.1 for 1-10 cm (default models/priors.toml: 0.01:0.3)",
    )
    fp.add_argument(
        "--init",
        choices=["auto", "smc", "optimize"],
        default="auto",
        help="contact level: start the chain from a tempered SMC from the prior (finds separated modes, writes "
        "smc.npz) or from a small ball around an evolutionary-search optimum; auto (default): the optimum for "
        "300 or more contacts that surround the object, else SMC",
    )
    fp.add_argument("--nu", type=float, default=None, help="Student-t degrees of freedom (default: models/priors.toml)")
    fp.add_argument(
        "--precision",
        choices=["auto", "float64", "mixed"],
        default="auto",
        help="arithmetic of the sampled contact-level log-density: mixed (float32 per-point "
        "transcendentals, ~2x faster, error < 1e-3 nat) where it applies (auto: Student-t or Gaussian "
        "or outlier noise, no normals, no --ffd), else float64; summaries are float64 always",
    )
    fp.add_argument(
        "--ignore-normals",
        action="store_true",
        help="do not use the file's nx,ny,nz columns (by default they add a von Mises-Fisher term)",
    )
    fp.add_argument(
        "--ffd",
        type=one_size,
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
        "--lag",
        choices=["known", "sampled"],
        default=None,
        help="recording (.nc) only: the taxels' response lag: sampled over its prior range ([raw_priors] "
        "lag_min-lag_max of models/priors.toml; default: no calibration measures it) or known (the value in "
        "models/taxels.toml)",
    )
    fp.add_argument(
        "--stride",
        type=positive_int,
        default=None,
        help="recording (.nc) only: use every STRIDE-th frame (default 2 with texture, 5 without)",
    )
    fp.add_argument(
        "--calibration",
        type=Path,
        default=None,
        metavar="DEVICE.toml",
        help="recording (.nc) only: the finger's device file from `bayestouch calibrate` (per-taxel gains and "
        "their errors); without it the gains are unknown and marginalised with the nominal spread of "
        "models/noise.toml (wider intervals)",
    )
    fp.add_argument(
        "--parts",
        default=None,
        metavar="auto|K",
        help="contact level: fit the object as a union of K n-ellipsoids (1-4; a head and a body, a mug and its "
        "handle), or auto: K = 1 ... --max-parts chosen by the tempered-SMC evidence; writes occupancy.npz (the "
        "posterior probability that a point is inside the object) besides summary.json, posterior.nc, "
        "mean_shape.ply, uncertainty_mesh.ply",
    )
    fp.add_argument(
        "--max-parts",
        type=positive_int,
        default=None,
        help="with --parts auto: the largest number of parts considered (default 2; each costs an SMC run)",
    )
    fp.add_argument("--quiet", action="store_true", help="no progress bar")
    return fp


def _other_results(args) -> list[Path]:
    """What in ``--out`` another command made (:data:`OTHER_RESULTS` and, when one of them is there, its companions
    :data:`OTHER_OUTPUTS`), the fit's own input file excepted; empty when the folder holds no other command's
    result."""
    return other_results(args.out, keep=(args.points,), patterns=OTHER_RESULTS)


def _check_other_results(args) -> None:
    """Refuse an ``--out`` folder holding another command's results unless ``--overwrite`` (as ``explore`` refuses a
    fit's folder); ``--resume`` of a fit already in such a folder goes on."""
    from bayestouch.io.runfolder import FINGERPRINT_FILE

    others = _other_results(args)
    if not others or args.overwrite or (args.resume and (args.out / FINGERPRINT_FILE).is_file()):
        return
    raise other_results_error(args.out, others, OTHER_RESULTS)


def _set_aside_other_results(args) -> None:
    """``--overwrite``: move another command's results in ``--out`` into ``replaced-<UTC time>/`` (never deleted)."""
    if args.overwrite:
        from bayestouch.io.files import set_aside

        set_aside(_other_results(args), "fit")


def _contacts(args):
    """The contact file of ``fit DATA``, ``--subsample`` applied (seeded by ``--seed``), at most
    :data:`MAX_CONTACTS` contacts: the data of the single fit and of the parts fit alike."""
    from bayestouch.inference.contact import load_priors
    from bayestouch.io.contacts import check_contact_spread, load_contact_points

    cp = load_contact_points(args.points)
    if args.subsample is not None:
        if args.subsample < 20:
            raise BadInput(f"--subsample must be an integer ≥ 20 contacts, got {args.subsample}")
        if args.subsample < len(cp.points):
            keep = np.sort(np.random.default_rng([args.seed, 0x5B5]).choice(len(cp.points), args.subsample, False))
            cp = cp._replace(
                points=cp.points[keep],
                normals=None if cp.normals is None else cp.normals[keep],
                force=None if cp.force is None else cp.force[keep],
            )
    check_contact_spread(cp.points, str(args.points), load_priors().axis_max)
    if len(cp.points) > MAX_CONTACTS:
        raise BadInput(
            f"{args.points}: {len(cp.points)} contacts; a fit takes at most {MAX_CONTACTS} (the posterior of "
            f"more is no sharper than the model's own error): pass --subsample N to fit N of them"
        )
    return cp


def _run_parts(args) -> int:
    """``bayestouch fit DATA --parts …``: the union-of-parts fit (:mod:`bayestouch.inference.parts_run`)."""
    from bayestouch.inference.parts import MAX_PARTS
    from bayestouch.inference.parts_run import DEFAULT_MAX_PARTS, PARTS_BUDGET_S, run_parts_fit

    if args.points.suffix.lower() == ".nc":
        raise BadInput("--parts applies to contact points (.csv), not to a recording (.nc)")
    clash = [
        flag
        for flag, used in (
            ("--ffd", args.ffd is not None),
            ("--noise", args.noise not in ("auto", "outlier")),
            ("--nu", args.nu is not None),
            ("--init", args.init != "auto"),
            ("--size-prior", args.size_prior is not None),
            ("--precision", args.precision != "auto"),
            (
                "--texture/--stride/--calibration/--lag",
                args.texture != "auto" or args.stride or args.calibration or args.lag is not None,
            ),
        )
        if used
    ]
    if clash:
        raise BadInput(f"--parts: the parts fit has its own model (outlier noise, SMC start); drop {', '.join(clash)}")
    parts = args.parts.strip().lower()
    if parts != "auto" and not (parts.isdigit() and 1 <= int(parts) <= MAX_PARTS):
        raise BadInput(f"--parts: expected auto or a number of parts 1 to {MAX_PARTS}, got {args.parts!r}")
    if args.max_parts is not None and (parts != "auto" or args.max_parts > MAX_PARTS):
        raise BadInput(f"--max-parts goes with --parts auto and is at most {MAX_PARTS}, got {args.max_parts}")
    cp = _contacts(args)
    if cp.normals is not None and not args.ignore_normals:
        print("bayestouch fit: note: --parts does not use the file's normals (nx, ny, nz)", file=sys.stderr)
    _set_aside_other_results(args)
    s = run_parts_fit(
        cp.points,
        args.out,
        parts=parts if parts == "auto" else int(parts),
        max_parts=args.max_parts or DEFAULT_MAX_PARTS,
        seed=args.seed,
        walkers=None if args.walkers == 32 else args.walkers,
        steps=args.steps or 20000,
        budget_s=PARTS_BUDGET_S if args.budget is None else (args.budget or None),
        free=cp.free,
        progress=not args.quiet,
        resume=args.resume,
        overwrite=args.overwrite,
    )
    d, v, mc = s["diagnostics"], s["derived"]["volume_m3"], s["model"]["model_choice"]
    probs = ", ".join(f"P(K={k}) {p:.2f}" for k, p in mc["posterior_probability"].items())
    print(
        f"wrote {args.out}/summary.json, posterior.nc, occupancy.npz, mean_shape.ply, uncertainty_mesh.ply: "
        f"{s['model']['parts']} part(s) ({probs}); volume {v['mean'] * 1e6:.3f} ± {v['sd'] * 1e6:.3f} cm³ "
        f"(90 % {v['q05'] * 1e6:.3f}–{v['q95'] * 1e6:.3f}), max R-hat {stat(d['max_r_hat'], '.3f')}, "
        f"min ESS {stat(d['min_ess_bulk'], '.0f')}, {'converged' if d['converged'] else 'NOT converged'}"
        f"{' (stopped by --budget)' if d.get('stopped_by_budget') else ''} ({d['seconds']:.1f} s)"
    )
    _print_not_converged(d)
    for w in d.get("warnings", []):
        print(f"bayestouch fit: warning: {w}", file=sys.stderr)
    return 0


def _print_not_converged(d: dict) -> None:
    """The reasons a chain failed its convergence checks (``diagnostics.not_converged_because``), one per line."""
    why = d.get("not_converged_because", [])
    if not d["converged"] and why:
        print("NOT CONVERGED: the intervals above are not yet a posterior's:")
        for line in why:
            print(f"  - {line}")


def run(args) -> int:
    """Run ``bayestouch fit`` from parsed arguments (bad input raises
    :class:`~bayestouch.errors.BadInput`)."""
    if args.walkers > MAX_WALKERS:
        raise BadInput(
            f"--walkers must be at most {MAX_WALKERS} (memory grows with walkers × data), got {args.walkers}"
        )
    if args.ffd is not None and max(args.ffd) > MAX_FFD_SIZE:
        raise BadInput(
            f"--ffd: at most {MAX_FFD_SIZE} control points along each axis (the marginal's Cholesky grows as the cube "
            f"of 3 l m k), got {'x'.join(map(str, args.ffd))}"
        )
    if args.walkers < 24 or args.walkers % 2:
        raise BadInput(
            f"--walkers must be an even number ≥ 24 (twice the parameters, plus a margin), got {args.walkers}"
        )
    if args.budget is not None and not args.budget >= 0:
        raise BadInput(f"--budget must be ≥ 0 seconds (0: no budget), got {args.budget}")
    if args.out.exists() and not args.out.is_dir():
        raise BadInput(f"--out {args.out} exists and is not a folder")
    if problem := file_problem(args.points):
        raise BadInput(f"{args.points}: {problem} (expected a contact points CSV or a recording .nc)")
    if args.ffd_tau is not None and not (0 < args.ffd_tau < 0.1):
        raise BadInput(f"--ffd-tau must be in (0, 0.1) metres, got {args.ffd_tau}")
    from bayestouch.io.runfolder import locked_run_folder

    # the folder is this run's from the checks to the last output (a second run into it is refused, a killed
    # run's lock goes with its process)
    with locked_run_folder(args.out):
        _check_other_results(args)
        return _run_fit(args)


def _run_fit(args) -> int:
    """The fit of :func:`run`, its options checked and ``--out`` held."""
    if args.parts is not None:
        return _run_parts(args)
    if args.max_parts is not None:
        raise BadInput("--max-parts goes with --parts auto")
    from bayestouch.api import fit

    common = dict(
        seed=args.seed,
        walkers=args.walkers,
        resume=args.resume,
        overwrite=args.overwrite,
        progress=not args.quiet,
        stop_when_converged=not args.no_early_stop,
    )
    if args.points.suffix.lower() == ".nc":
        if args.ffd is not None:
            raise BadInput("--ffd applies to contact points (.csv), not to a recording (.nc)")
        contact_only = {
            "--size-prior": args.size_prior is not None,
            "--init": args.init != "auto",
            "--subsample": args.subsample is not None,
            "--noise": args.noise != "auto",
            "--nu": args.nu is not None,
            "--precision": args.precision != "auto",
            "--ffd-tau": args.ffd_tau is not None,
            "--ignore-normals": args.ignore_normals,
        }
        given = [k for k, v in contact_only.items() if v]
        if given:  # options of the contact level: silently without effect on a recording before
            raise BadInput(f"{', '.join(given)}: apply to contact points (.csv), not to a recording (.nc)")
        from bayestouch.inference.raw.data import open_recording

        open_recording(args.points)  # a file that is no recording is refused before anything is set aside
        _set_aside_other_results(args)
        s = fit(
            args.points,
            args.out,
            steps=args.steps,
            budget_s=args.budget or None,
            texture=args.texture,
            stride=args.stride,
            calibration=args.calibration,
            lag=args.lag or "sampled",
            **common,
        ).results
    else:
        if args.ffd_tau is not None and args.ffd is None:
            raise BadInput("--ffd-tau goes with --ffd (the FFD lattice whose displacements it scales)")
        if args.size_prior is not None and args.ffd is not None:
            raise BadInput("--size-prior: the FFD-marginalised fit keeps its own prior; use one of --size-prior, --ffd")
        if args.texture != "auto" or args.stride is not None or args.calibration is not None or args.lag is not None:
            raise BadInput(
                "--texture, --stride, --calibration and --lag apply to a recording (.nc), not to contact points (.csv)"
            )

        from bayestouch.inference.run import NU_RANGE

        cp = _contacts(args)
        if args.nu is not None and args.noise != "student":
            raise BadInput(f"--nu goes with --noise student, got --nu {args.nu} --noise {args.noise}")
        if args.nu is not None and not NU_RANGE[0] <= args.nu <= NU_RANGE[1]:
            raise BadInput(f"--nu must be in [{NU_RANGE[0]:g}, {NU_RANGE[1]:g}] (or --noise gaussian), got {args.nu}")
        noise, nu = ("student", float("inf")) if args.noise == "gaussian" else (args.noise, args.nu)
        _set_aside_other_results(args)
        s = fit(
            cp,
            args.out,
            steps=args.steps,
            budget_s="auto" if args.budget is None else (args.budget or None),
            normals=False if args.ignore_normals else None,
            noise=noise,
            nu=nu,
            ffd=args.ffd,
            ffd_tau=args.ffd_tau,
            precision=args.precision,
            size_prior=args.size_prior,
            init=args.init,
            **common,
        ).results
    d = s["diagnostics"]
    v = s["derived"]["volume_m3"]
    print(
        f"wrote {args.out}/summary.json, posterior.nc, mean_shape.ply, uncertainty_mesh.ply: volume "
        f"{v['mean'] * 1e6:.3f} ± {v['sd'] * 1e6:.3f} cm³ (90 % {v['q05'] * 1e6:.3f}–{v['q95'] * 1e6:.3f}), "
        f"max R-hat {stat(d['max_r_hat'], '.3f')}, min ESS {stat(d['min_ess_bulk'], '.0f')}, "
        f"{'converged' if d['converged'] else 'NOT converged'}"
        f"{' (stopped by --budget)' if d.get('stopped_by_budget') else ''} ({d['seconds']:.1f} s)"
    )
    _print_not_converged(d)
    if d.get("multimodal"):
        print(f"MULTIMODAL: {len(d['modes'])} separated shapes; the mean describes none of them:")
        for i, m in enumerate(d["modes"], start=1):
            mv = m["volume_m3"]
            print(
                f"  mode {i}: weight {m['weight']:.0%}, volume {mv['mean'] * 1e6:.3f} cm³ "
                f"(90 % {mv['q05'] * 1e6:.3f}–{mv['q95'] * 1e6:.3f}), n {m['n']['mean']:.2f}"
            )
    if d.get("misfit"):
        rc = d["residual_neighbour_correlation"]
        print(
            f"MISFIT: neighbouring contacts' residuals correlate (rank rho {rc['rho']:.2f}): the shape does not "
            "explain the contacts as noise; the intervals above are not to be trusted"
        )
    if d.get("noise_large"):
        print(
            f"NOISE: σ is {100 * d['noise_to_smallest_axis']:.0f} % of the smallest semi-axis: the distance "
            "likelihood is an approximation there and the intervals above are too narrow"
        )
    if d.get("extrapolated"):
        print(
            f"EXTRAPOLATED: the surface runs up to {d['reach']['median']:.1f} times the contacts' span from the "
            "nearest contact: there the shape is the n-ellipsoid family's extension, not the data's"
        )
    for w in d.get("warnings", []):
        print(f"bayestouch fit: warning: {w}", file=sys.stderr)
    return 0
