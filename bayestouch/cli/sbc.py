"""``bayestouch sbc``: simulation-based calibration of the contact-level posterior (:mod:`bayestouch.inference.sbc`)."""

from __future__ import annotations

import argparse

from bayestouch.cli.args import bounded_int, out_path
from bayestouch.cli.args import seed as seed_arg

__all__ = ["add_sbc_parser", "run_sbc"]


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
        type=bounded_int(1, 100_000),
        default=100,
        help="simulated data sets (default 100; at most 100000)",
    )
    ap.add_argument("--out", type=out_path, required=True, help="output folder")
    ap.add_argument("--seed", type=seed_arg, default=0, help="seed of the data sets and chains (default 0)")
    ap.add_argument("--points", type=int, default=100, help="contact points per data set (default 100)")
    ap.add_argument("--walkers", type=int, default=32, help="emcee walkers (default 32)")
    ap.add_argument("--steps", type=int, default=800, help="steps per chain (default 800)")
    ap.add_argument("--draws", type=int, default=99, help="thinned posterior draws ranked per data set (default 99)")
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
    ap.add_argument("--likelihood-power", type=float, default=1.0, help="temper the likelihood (default 1)")
    ap.add_argument(
        "--moves",
        choices=("default", "de", "adaptive"),
        default="adaptive",
        help="emcee moves: the adaptive sampler of bayestouch fit (default), the engine's default_moves, or "
        "differential evolution only",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress messages")
    return ap


def run_sbc(a) -> int:
    """Run the calibration from parsed arguments and print its coverage and chi-square p-values."""
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
