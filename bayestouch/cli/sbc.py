"""``bayestouch sbc``: simulation-based calibration of the contact-level posterior (:mod:`bayestouch.inference.sbc`)."""

from __future__ import annotations

import argparse

from bayestouch.cli.args import bounded_int, check_out, out_path
from bayestouch.cli.args import seed as seed_arg
from bayestouch.errors import BadInput

__all__ = ["add_sbc_parser", "run_sbc"]

#: most simulated data sets, contact points per data set, walkers, steps and draws (each chain's memory grows with
#: walkers × steps, the data sets' with datasets × points and datasets × draws; ten chains run side by side)
MAX_DATASETS = 100_000
MAX_POINTS = 10_000
MAX_WALKERS = 1024
MAX_STEPS = 100_000
MAX_DRAWS = 10_000
#: most walkers × steps of one chain (32 walkers × 31250 steps; about 0.8 GB per chain at the end)
MAX_WALKER_STEPS = 1_000_000
#: most data sets × points (the simulated contacts, 240 MB) and data sets × draws (the ranked draws, 720 MB)
MAX_DATASET_POINTS = 10_000_000
MAX_DATASET_DRAWS = 10_000_000
#: largest --likelihood-power (a tempered likelihood: > 1 an overconfident posterior, < 1 a wide one)
MAX_LIKELIHOOD_POWER = 10.0


def add_sbc_parser(sub) -> argparse.ArgumentParser:
    """Register ``bayestouch sbc`` on the ``bayestouch`` command's subparsers."""
    ap = sub.add_parser(
        "sbc",
        help="simulation-based calibration of the contact-level posterior",
        description="Simulation-based calibration (Talts et al. 2018) of the contact-level posterior: rank "
        "statistics of the truths among posterior draws over --datasets simulated data sets; writes sbc.json and "
        "sbc_ranks.png.",
    )
    ap.add_argument(
        "--datasets",
        type=bounded_int(2, MAX_DATASETS),
        default=100,
        help=f"simulated data sets (default 100; 2 to {MAX_DATASETS}, and datasets × points at most "
        f"{MAX_DATASET_POINTS:,}, datasets × draws at most {MAX_DATASET_DRAWS:,})",
    )
    ap.add_argument("--out", type=out_path, required=True, help="output folder")
    ap.add_argument(
        "--overwrite", action="store_true", help="set aside the results already in --out (otherwise refused)"
    )
    ap.add_argument("--seed", type=seed_arg, default=0, help="seed of the data sets and chains (default 0)")
    ap.add_argument(
        "--points",
        type=bounded_int(10, MAX_POINTS),
        default=100,
        help=f"contact points per data set (default 100; 10 to {MAX_POINTS})",
    )
    ap.add_argument(
        "--walkers",
        type=bounded_int(24, MAX_WALKERS),
        default=32,
        help=f"emcee walkers (default 32; a multiple of 4 from 24 to {MAX_WALKERS}, and walkers × steps at most "
        f"{MAX_WALKER_STEPS:,})",
    )
    ap.add_argument(
        "--steps",
        type=bounded_int(100, MAX_STEPS),
        default=800,
        help=f"steps per chain (default 800; 100 to {MAX_STEPS}, and walkers × steps at most {MAX_WALKER_STEPS:,})",
    )
    ap.add_argument(
        "--draws",
        type=bounded_int(9, MAX_DRAWS),
        default=99,
        help=f"thinned posterior draws ranked per data set (default 99; 9 to {MAX_DRAWS}, and at most the draws a "
        "chain keeps after burn-in: walkers × half the steps after the first 100)",
    )
    ap.add_argument(
        "--area-term",
        action="store_true",
        help="add -M log A(theta) to contact.log_likelihood (a check of the check; see the module docstring)",
    )
    ap.add_argument(
        "--no-area-term",
        action="store_true",
        help="contact.log_likelihood as the package uses it (the default; kept for old command lines)",
    )
    ap.add_argument(
        "--likelihood-power",
        type=float,
        default=1.0,
        help=f"temper the likelihood: a number in (0, {MAX_LIKELIHOOD_POWER:g}] (default 1; > 1 an overconfident "
        "posterior, a negative control)",
    )
    ap.add_argument(
        "--moves",
        choices=("default", "de", "adaptive"),
        default="adaptive",
        help="emcee moves: the adaptive sampler of bayestouch fit (default), the engine's default_moves, or "
        "differential evolution only",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress messages")
    return ap


def check_sbc_args(a) -> None:
    """Refuse settings whose memory or time is out of reach, or that fail only after hours (BadInput)."""
    if a.area_term and a.no_area_term:
        raise BadInput("--area-term and --no-area-term exclude each other")
    if a.out.exists() and not a.out.is_dir():
        raise BadInput(f"--out {a.out} exists and is not a folder")
    if a.walkers % 4:
        raise BadInput(f"--walkers must be a multiple of 4 (emcee's moves update quarters of it), got {a.walkers}")
    if a.walkers * a.steps > MAX_WALKER_STEPS:
        raise BadInput(
            f"--walkers × --steps must be at most {MAX_WALKER_STEPS} (each chain is held in memory, ten side by "
            f"side), got {a.walkers} × {a.steps} = {a.walkers * a.steps}"
        )
    if a.datasets * a.points > MAX_DATASET_POINTS:
        raise BadInput(
            f"--datasets × --points must be at most {MAX_DATASET_POINTS} (every data set is held in memory), got "
            f"{a.datasets} × {a.points}; split the calibration into several runs with different --seed"
        )
    if a.datasets * a.draws > MAX_DATASET_DRAWS:
        raise BadInput(
            f"--datasets × --draws must be at most {MAX_DATASET_DRAWS} (every draw is held in memory), got "
            f"{a.datasets} × {a.draws}; split the calibration into several runs with different --seed"
        )
    from bayestouch.inference.sampler import fewest_kept_steps

    kept = a.walkers * fewest_kept_steps(a.steps, a.moves == "adaptive")
    if a.draws > kept:
        raise BadInput(
            f"--draws must be at most the {kept} draws a chain of {a.walkers} walkers × {a.steps} steps keeps after "
            f"burn-in, got {a.draws}; lower --draws or raise --steps"
        )
    if not (0 < a.likelihood_power <= MAX_LIKELIHOOD_POWER):
        raise BadInput(
            f"--likelihood-power must be a number in (0, {MAX_LIKELIHOOD_POWER:g}] (1 for the honest posterior), "
            f"got {a.likelihood_power}"
        )


def run_sbc(a) -> int:
    """Run the calibration from parsed arguments and print its coverage and chi-square p-values."""
    check_sbc_args(a)
    from bayestouch.io.runfolder import locked_run_folder

    # the folder is this run's from the check of earlier results to the last output (a second run is refused)
    with locked_run_folder(a.out):
        return _sbc_into(a)


def _sbc_into(a) -> int:
    """The calibration of :func:`run_sbc`, its options checked and ``--out`` held."""
    check_out(a.out, a.overwrite, "sbc")
    from bayestouch.inference.sbc import de_moves, plot_ranks, sbc
    from bayestouch.io.files import write_json

    res = sbc(
        a.datasets,
        seed=a.seed,
        n_points=a.points,
        walkers=a.walkers,
        steps=a.steps,
        n_draws=a.draws,
        progress=not a.quiet,
        area_term=a.area_term and not a.no_area_term,
        likelihood_power=a.likelihood_power,
        moves=de_moves if a.moves == "de" else None,
        adapt=a.moves == "adaptive",
    )
    a.out.mkdir(parents=True, exist_ok=True)
    write_json(a.out / "sbc.json", res.to_dict())
    plot_ranks(res, a.out / "sbc_ranks.png")
    print(
        f"coverage ({res.level:.0%}, expected {res.coverage_expected:.3f}): "
        + ", ".join(f"{k} {v:.2f}" for k, v in zip(res.names, res.coverage, strict=True))
    )
    print("chi-square p: " + ", ".join(f"{k} {v:.3g}" for k, v in zip(res.names, res.chi2_p, strict=True)))
    return 0
