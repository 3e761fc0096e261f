"""Errors that users see.

:class:`BadInput` carries a one-line message naming the offending field and the expected form. The CLI
turns it into that line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import os
import stat
from typing import Any

import numpy as np

__all__ = [
    "BadInput",
    "as_array",
    "check_bool",
    "check_bools",
    "check_int",
    "check_number",
    "check_path",
    "check_seed",
    "command_line_message",
    "file_problem",
    "shown",
]

#: how messages shared by the API and the command line name a switch in both spellings, and what the command line
#: shows instead (the flag alone)
PYTHON_GLOSSES = (
    ("--resume (resume=True)", "--resume"),
    ("--overwrite (overwrite=True)", "--overwrite"),
    ("overwrite=True (--overwrite)", "--overwrite"),
)


class BadInput(ValueError):
    """Invalid user input (file, argument, parameter). ``str(err)`` is one line: field, problem, expected form."""


def command_line_message(message: str) -> str:
    """``message`` as the command line prints it: a switch named in both spellings (:data:`PYTHON_GLOSSES`) named by
    its flag alone."""
    for both, flag in PYTHON_GLOSSES:
        message = message.replace(both, flag)
    return message


def check_bool(value, name: str) -> None:
    """Refuse a switch ``name`` that is not ``True`` or ``False`` (a numpy bool is accepted): ``"no"`` is truthy,
    and taken as True it had set earlier results aside."""
    if not isinstance(value, bool | np.bool_):
        raise BadInput(f"{name}: expected True or False, got {shown(value)}")


def check_bools(**switches) -> None:
    """:func:`check_bool` of every keyword (name → value)."""
    for name, value in switches.items():
        check_bool(value, name)


def shown(value, limit: int = 80) -> str:
    """The start of ``value``'s repr on one line, for messages."""
    return " ".join(repr(value).split())[:limit]


def check_int(value, name: str, lo: int, hi: int | None = None, what: str = "an integer") -> int:
    """``value`` as an int, or a one-line refusal naming ``name`` when it is not an integer (bools and floats
    included) in ``[lo, hi]`` (``hi`` None: no upper bound); ``what`` says what it counts (e.g. "an integer number
    of points")."""
    if (
        isinstance(value, bool | np.bool_)
        or not isinstance(value, int | np.integer)
        or value < lo
        or (hi is not None and value > hi)
    ):
        limits = f"≥ {lo}" if hi is None else f"from {lo} to {hi:,}"
        raise BadInput(f"{name}: expected {what} {limits}, got {shown(value)}")
    return int(value)


def check_number(
    value, name: str, lo: float, *, above: bool = False, what: str = "a finite number", unit: str = ""
) -> float:
    """``value`` as a float, or a one-line refusal naming ``name`` when it is not a finite real number (bools and text
    included) ≥ ``lo`` (> ``lo`` with ``above``); ``what`` says what it is (e.g. "a number of seconds"), ``unit``
    (e.g. "m/s") follows the bound in the message."""
    ok = not isinstance(value, bool | np.bool_) and isinstance(value, int | float | np.integer | np.floating)
    if not (ok and np.isfinite(value) and (value > lo if above else value >= lo)):
        unit = f" ({unit})" if unit else ""
        raise BadInput(f"{name}: expected {what} {'>' if above else '≥'} {lo:g}{unit}, got {shown(value)}")
    return float(value)


def check_seed(seed, name: str = "seed", note: str = "") -> None:
    """Refuse a seed ``name`` that is not an integer in [0, 2**32) (emcee's and JAX's seeds); ``note`` (e.g. " (the
    finger's fixed pattern)") follows the range in the message."""
    if isinstance(seed, bool | np.bool_) or not isinstance(seed, int | np.integer) or not 0 <= seed < 2**32:
        raise BadInput(f"{name}: expected an integer in [0, 2**32){note}, got {shown(seed)}")


def as_array(value: Any, name: str, shape: tuple[int | None, ...], form: str) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (None: any length along that axis) with finite values, or a
    one-line refusal naming ``name`` and ``form`` (e.g. "an (N, 3) array (metres)"): text, a ragged nesting, the
    wrong shape, NaN or infinity (naming the first bad row)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInput(f"{name} must be {form} of numbers, got {type(value).__name__} {shown(value, 40)}") from None
    if a.ndim != len(shape) or any(s is not None and s != t for s, t in zip(shape, a.shape, strict=False)):
        raise BadInput(f"{name} must be {form}, got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a).reshape(len(a), -1).all(axis=1)) if a.ndim and a.size else np.empty(0, int)
    if a.ndim == 0 and not np.isfinite(a):
        raise BadInput(f"{name} must be finite, got {a.item()}")
    if bad.size:
        raise BadInput(f"{name} must be finite, row {int(bad[0]) + 1} (1-based) is {a[bad[0]].tolist()}")
    return a


def check_path(value, name: str) -> None:
    """Refuse an output or input path ``name`` that is not a non-empty string or :class:`os.PathLike` (None ended
    in a TypeError from deep inside a run)."""
    if not (isinstance(value, os.PathLike) or (isinstance(value, str) and value.strip())):
        raise BadInput(f"{name}: expected a path (a string or pathlib.Path), got {shown(value)}")


def file_problem(path: str | os.PathLike[str]) -> str:
    """Why ``path`` cannot be read as a file, in a few words for a one-line message ("no such file", "is a folder,
    not a file", "is not a regular file", the system's reason such as "file name too long"), or ``""`` when it is a
    regular file."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "no such file"
    except OSError as e:  # a name too long for the file system, a link loop, no permission
        return (e.strerror or type(e).__name__).lower()
    if stat.S_ISREG(mode):
        return ""
    return "is a folder, not a file" if stat.S_ISDIR(mode) else "is not a regular file"
