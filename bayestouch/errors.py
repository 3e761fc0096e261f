"""Errors that users see.

:class:`BadInput` carries a one-line message naming the offending field and the expected form. The CLI
turns it into that line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import os
import stat

import numpy as np

__all__ = ["BadInput", "check_bool", "check_path", "command_line_message", "file_problem"]

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
        shown = " ".join(repr(value).split())[:80]
        raise BadInput(f"{name}: expected True or False, got {shown}")


def check_path(value, name: str) -> None:
    """Refuse an output or input path ``name`` that is not a non-empty string or :class:`os.PathLike` (None ended
    in a TypeError from deep inside a run)."""
    if not (isinstance(value, os.PathLike) or (isinstance(value, str) and value.strip())):
        shown = " ".join(repr(value).split())[:80]
        raise BadInput(f"{name}: expected a path (a string or pathlib.Path), got {shown}")


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
