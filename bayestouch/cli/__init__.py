"""The ``bayestouch`` command line: one parser (:mod:`.main`), one error policy (bad input: one line, exit 2)."""

from bayestouch.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
