"""Errors that users see.

:class:`BadInput` carries a one-line message naming the offending field and the expected form. The CLI
turns it into that line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["BadInput", "check_bool", "file_problem"]


class BadInput(ValueError):
    """Invalid user input (file, argument, parameter). ``str(err)`` is one line: field, problem, expected form."""


def check_bool(value, name: str) -> None:
    """Refuse a switch ``name`` that is not ``True`` or ``False`` (a numpy bool is accepted): ``"no"`` is truthy,
    and taken as True it had set earlier results aside."""
    if not isinstance(value, bool | np.bool_):
        shown = " ".join(repr(value).split())[:80]
        raise BadInput(f"{name}: expected True or False, got {shown}")


def file_problem(path: str | os.PathLike[str]) -> str:
    """Why ``path`` cannot be read as a file, in a few words for a one-line message ("no such file", "is a folder,
    not a file", "is not a regular file"), or ``""`` when it is a regular file."""
    if os.path.isfile(path):
        return ""
    if os.path.isdir(path):
        return "is a folder, not a file"
    return "is not a regular file" if os.path.exists(path) else "no such file"
