"""Argument types shared by the command lines (argparse ``type=``): a bad value is a one-line usage error, exit 2."""

from __future__ import annotations

import argparse

__all__ = ["seed"]


def seed(text: str) -> int:
    """A random seed: an integer in [0, 2³²), the range NumPy's and emcee's generators accept."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed in [0, 2**32), got {text!r}") from None
    if not 0 <= v < 2**32:
        raise argparse.ArgumentTypeError(f"expected an integer seed in [0, 2**32), got {v}")
    return v
