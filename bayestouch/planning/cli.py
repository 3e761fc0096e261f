"""``bayestouch explore`` and ``bayestouch experiment`` (also ``python -m bayestouch.planning.cli``).

Wire into ``bayestouch/cli.py``: call :func:`add_planning_parsers` ``(sub)`` in ``build_parser`` and map
``"explore"`` → :func:`run_explore`, ``"experiment"`` → :func:`run_experiment` in ``COMMANDS``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bayestouch.errors import BadInput

__all__ = ["add_planning_parsers", "run_explore", "run_experiment", "main"]


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--budget", type=int, default=5, help="planned strokes after the scout stroke 0 (default 5)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--candidates", type=int, default=64, help="candidate strokes per decision (default 64)")
    p.add_argument("--draws", type=int, default=1000, help="posterior draws the planner uses (default 1000)")
    p.add_argument("--steps", type=int, default=300, help="emcee steps per posterior update (default 300)")
    p.add_argument("--out", required=True, help="output folder")


def add_planning_parsers(subparsers) -> None:
    """Add the ``explore`` and ``experiment`` subcommands to an argparse ``subparsers`` object."""
    ep = subparsers.add_parser(
        "explore",
        help="active exploration of a simulated object (plan, stroke, update)",
        description="Plan strokes over a simulated object, update the posterior after each "
        "and write per-stroke summaries and figures.",
    )
    ep.add_argument(
        "--object",
        default="egg",
        help="object name in models/objects (egg, sphere, box, cylinder) or a TOML file (default egg)",
    )
    ep.add_argument("--planner", default="eig", help="eig, random, coverage or oracle (default eig)")
    ep.add_argument(
        "--target-volume-sd",
        type=float,
        default=None,
        help="stop early once the volume's posterior sd is below this (m^3)",
    )
    _common(ep)
    xp = subparsers.add_parser(
        "experiment",
        help="compare planners over objects and seeded trials (results.csv)",
        description="Run objects x planners x trials of the exploration loop and write "
        "DIR/results.csv and DIR/error_vs_strokes.png.",
    )
    xp.add_argument("--planners", default="eig,random,oracle", help="comma-separated (default eig,random,oracle)")
    xp.add_argument("--objects", default="egg,sphere,box,cylinder", help="comma-separated names or TOML files")
    xp.add_argument("--trials", type=int, default=3, help="seeded trials per object and planner (default 3)")
    xp.add_argument("--workers", type=int, default=2, help="processes (default 2; 1 runs in this process)")
    xp.add_argument("--scheduler", default=None, help="Dask scheduler address tcp://HOST:PORT (optional)")
    xp.add_argument("--resume", action="store_true", help="keep complete trials of an existing results.csv")
    _common(xp)


def _settings(args) -> dict:
    for name in ("candidates", "draws", "steps"):
        if getattr(args, name) < 1:
            raise BadInput(f"--{name} must be a positive integer, got {getattr(args, name)}")
    if args.budget < 1:
        raise BadInput(f"--budget must be an integer number of strokes ≥ 1, got {args.budget}")
    return {"candidates": args.candidates, "draws": args.draws, "steps": args.steps}


def run_explore(args) -> int:
    """``bayestouch explore``: writes ``summary_<k>.json`` per stroke (k = 0 the scout), ``points.csv`` (all
    contacts), ``explore.json`` (the history) and ``explore.png`` (points and the final estimate)."""
    from bayestouch.io import save_contact_points, write_json
    from bayestouch.planning.experiment import resolve_object
    from bayestouch.planning.loop import ExploreSettings, explore
    from bayestouch.planning.policies import check_policy
    from bayestouch.scene.objects import load_object

    settings = ExploreSettings(**_settings(args))
    check_policy(args.planner)
    obj = load_object(resolve_object(args.object))
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)

    def on_stroke(rec):
        write_json(
            out / f"summary_{rec.stroke}.json",
            {**rec.summary, "seconds": rec.seconds, "eig_nats": rec.eig, "decision_s": rec.decision_s},
        )
        print(
            f"stroke {rec.stroke}: {rec.n_points} points, chamfer {rec.chamfer:.4f} of the mean semi-axis, "
            f"volume error {rec.volume_error:.4f}, volume sd {rec.volume_sd:.3g} m^3",
            file=sys.stderr,
        )

    res = explore(
        obj,
        args.planner,
        args.budget,
        seed=args.seed,
        settings=settings,
        target_volume_sd=args.target_volume_sd,
        on_stroke=on_stroke,
    )
    save_contact_points(out / "points.csv", res.points)
    write_json(
        out / "explore.json",
        {
            "object": obj.name,
            "planner": args.planner,
            "seed": args.seed,
            "strokes": [{k: v for k, v in r._asdict().items() if k != "summary"} for r in res.records],
        },
    )
    _plot_explore(res, obj, out / "explore.png")
    return 0


def _plot_explore(res, obj, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from bayestouch._jax import jnp
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.geometry.mesh import nellipsoid_mesh
    from bayestouch.planning.loop import shape_errors, truth_of

    est = shape_errors(res.shape_vectors, truth_of(obj))["estimate"]
    v, _ = nellipsoid_mesh(ne.from_vector(jnp.asarray(est)), 24)
    fig = plt.figure(figsize=(10, 4.5), constrained_layout=True)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.scatter(*(1e3 * v.T), s=2, alpha=0.35, color="grey", label="estimate")
    k0 = 0
    for i, rec in enumerate(res.records):
        n = rec.new_points
        p = res.points[k0 : k0 + n]
        k0 += n
        if len(p):
            ax.scatter(*(1e3 * p.T), s=6, label="scout" if i == 0 else f"stroke {i}")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.legend(fontsize=6, loc="upper left")
    ax2 = fig.add_subplot(1, 2, 2)
    k = np.array([r.stroke for r in res.records])
    ax2.plot(k, [r.chamfer for r in res.records], marker="o", label="Chamfer / mean semi-axis")
    ax2.plot(k, [r.volume_error for r in res.records], marker="s", label="volume error")
    ax2.set_yscale("log")
    ax2.set_xlabel("stroke")
    ax2.legend()
    fig.suptitle(f"explore {obj.name}: points and the posterior estimate")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run_experiment(args) -> int:
    """``bayestouch experiment``: writes ``results.csv`` and ``error_vs_strokes.png`` into ``--out``."""
    from bayestouch.planning.experiment import gap_closed
    from bayestouch.planning.experiment import run_experiment as run

    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    objects = [o.strip() for o in args.objects.split(",") if o.strip()]
    if args.trials < 1:
        raise BadInput(f"--trials must be an integer ≥ 1, got {args.trials}")
    res = run(
        args.out,
        planners=planners,
        objects=objects,
        trials=args.trials,
        budget=args.budget,
        seed=args.seed,
        workers=args.workers,
        scheduler=args.scheduler,
        resume=args.resume,
        settings=_settings(args),
    )
    g = gap_closed(res["rows"]) if res["rows"] else float("nan")
    if g == g:
        print(
            f"eig closes {100 * g:.0f} % of the random-oracle Chamfer gap after {args.budget} strokes", file=sys.stderr
        )
    print(str(res["path"]))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point (the same error handling as ``bayestouch``: BadInput → one line, exit 2)."""
    p = argparse.ArgumentParser(prog="python -m bayestouch.planning.cli")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    add_planning_parsers(sub)
    args = p.parse_args(argv)
    if args.command is None:
        p.print_help()
        return 2
    try:
        return {"explore": run_explore, "experiment": run_experiment}[args.command](args)
    except BadInput as e:
        print(f"bayestouch {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
