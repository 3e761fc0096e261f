"""Errors that users see.

:class:`BadInput` carries a one-line message naming the offending field and the expected form. The CLI
turns it into that line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

__all__ = ["BadInput"]


class BadInput(ValueError):
    """Invalid user input (file, argument, parameter). ``str(err)`` is one line: field, problem, expected form."""
