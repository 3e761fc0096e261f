"""The ``bayestouch`` command: one parser assembled from the command modules, one error policy.

Exit codes: 0 success, 2 bad input (one line on stderr naming the problem), 1 internal error.
Set ``BAYESTOUCH_DEBUG=1`` to see tracebacks of internal errors.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import re
import sys

# One BLAS thread unless the user says otherwise, set before NumPy loads BLAS: the toolkit's linear algebra is on
# 11×11 matrices, where a second OpenBLAS thread only spins; on a busy 2-core machine it made each L-BFGS-B
# iteration of the initial fit 2.7 ms instead of ~0.05 ms. (JAX's own threads are not affected.)
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from bayestouch import __version__  # noqa: E402
from bayestouch.cli import calibrate, demo, device, explore, fit, paper, sbc, simulate, texture_id  # noqa: E402
from bayestouch.errors import BadInput, command_line_message  # noqa: E402

__all__ = ["main", "build_parser"]


class _OneLineParser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage block): ``bayestouch fit: error: ... (see bayestouch fit --help)``,
    exit code 2. Subcommand parsers inherit the class."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # a negative number in scientific notation (--depth -1e-4) or a list starting with one is a value, not an
        # option: argparse's own pattern knows only -12 and -1.5
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


_NUMBER = r"(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?"
#: a negative number, or a comma list of numbers that starts with one (--currents -0.15,0.05,0.05)
_NEGATIVE_NUMBER = re.compile(rf"^-{_NUMBER}(,-?{_NUMBER})*$")


def build_parser() -> argparse.ArgumentParser:
    """The ``bayestouch`` parser: every subcommand, each with ``run`` set to the function that executes it."""
    p = _OneLineParser(
        prog="bayestouch",
        description="Probabilistic inference for tactile shape and texture sensing.",
    )
    p.add_argument("--version", action="version", version=f"bayestouch {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    paper.add_parser(sub).set_defaults(run=paper.run)
    fit.add_parser(sub).set_defaults(run=fit.run)
    calibrate.add_parser(sub).set_defaults(run=calibrate.run)
    simulate.add_parser(sub).set_defaults(run=simulate.run)
    demo.add_parser(sub).set_defaults(run=demo.run)
    device.add_device_parser(sub).set_defaults(run=device.run_device)
    explore_p, experiment_p = explore.add_planning_parsers(sub)
    explore_p.set_defaults(run=explore.run_explore)
    experiment_p.set_defaults(run=explore.run_experiment)
    texture_id.add_texture_parser(sub).set_defaults(run=texture_id.run_texture_id)
    sbc.add_sbc_parser(sub).set_defaults(run=sbc.run_sbc)
    return p


class _StderrHandler(logging.StreamHandler):
    """A handler writing to the ``sys.stderr`` of the moment (pytest and notebooks replace it)."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


def _log_to_stderr() -> None:
    """The command line shows the library's INFO messages (``logging.getLogger("bayestouch")``) on stderr, once."""
    logger = logging.getLogger("bayestouch")
    if not any(isinstance(h, _StderrHandler) for h in logger.handlers):
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
    logger.setLevel(logging.INFO)


#: errno values of an OSError that is the user's file system refusing a path or a write (a name over its length
#: limit, a read-only or full disk, a symbolic-link loop): one line and exit 2, like a missing file
USER_FILE_ERRNOS = frozenset(
    {errno.ENAMETOOLONG, errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.ELOOP, errno.EFBIG, errno.EMLINK}
)


def _name(args) -> str:
    """The command as its messages name it: ``fit``, ``device recover`` (a subcommand included)."""
    sub = getattr(args, "device_command", None)
    return f"{args.command} {sub}" if sub else str(args.command)


def _report_internal(args, e: Exception) -> int:
    print(
        f"bayestouch {_name(args)}: internal error: {type(e).__name__}: {e} (set BAYESTOUCH_DEBUG=1 for the traceback)",
        file=sys.stderr,
    )
    return 1


def main(argv: list[str] | None = None) -> int:
    """Run the ``bayestouch`` command with ``argv`` (default ``sys.argv[1:]``); returns the exit code.

    The one error policy of every command: bad input (:class:`~bayestouch.errors.BadInput`, a missing or unwritable
    file) is one line on stderr and exit 2; an interrupt exits 130; anything else is an internal error, one line
    and exit 1 (``BAYESTOUCH_DEBUG=1`` re-raises it with its traceback).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    from bayestouch.backend import enable_compilation_cache

    enable_compilation_cache()
    _log_to_stderr()
    try:
        return args.run(args)
    except BadInput as e:
        print(f"bayestouch {_name(args)}: error: {command_line_message(str(e))}", file=sys.stderr)
        return 2
    except (PermissionError, FileNotFoundError, IsADirectoryError, NotADirectoryError) as e:
        print(f"bayestouch {_name(args)}: error: {e.strerror or e}: {e.filename}", file=sys.stderr)
        return 2
    except OSError as e:
        if e.errno in USER_FILE_ERRNOS:  # the user's file system refused a path or a write: not a bug
            name = str(e.filename or "")
            shown = f"{name[:80]}…" if len(name) > 80 else name
            print(f"bayestouch {_name(args)}: error: {e.strerror}: {shown}", file=sys.stderr)
            return 2
        if os.environ.get("BAYESTOUCH_DEBUG"):
            raise
        return _report_internal(args, e)
    except KeyboardInterrupt:
        print(f"bayestouch {_name(args)}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # internal error: one line unless debugging
        if os.environ.get("BAYESTOUCH_DEBUG"):
            raise
        return _report_internal(args, e)
