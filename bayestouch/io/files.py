"""Atomic writers of text, CSV tables and JSON, and a CSV reader whose errors are one line.

All writers are atomic: the text goes to a temporary file in the target's folder, which replaces the target
(:func:`os.replace`) only once it is complete and flushed, so a crash never leaves a half-written file and an
existing file is either the old one or the new one. Floats are written with :func:`repr`, the shortest text that
reads back to the same bits. Every problem with a file read raises :class:`~bayestouch.errors.BadInput` whose
message is one line naming the file, the problem and the expected form. Contact-point files:
:mod:`bayestouch.io.contacts`.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import secrets
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from bayestouch.errors import BadInput, file_problem

__all__ = [
    "write_csv_rows",
    "read_csv_rows",
    "write_json",
    "write_text",
    "atomic_write",
    "atomic_path",
    "utc_stamp",
    "move_aside",
    "set_aside",
    "read_csv_records",
    "file_error",
    "ragged_error",
    "toml_value",
    "toml_array",
]


# ---------------------------------------------------------------------------------------------------------
# one-line errors and CSV records


def _one_line(text: str) -> str:
    """``text`` with line breaks escaped, so an error message stays on one line."""
    return text.replace("\r", "\\r").replace("\n", "\\n")


def file_error(source: str, problem: str) -> BadInput:
    """A :class:`BadInput` whose message is one line: ``"{source}: {problem}"`` with line breaks escaped.

    Parameters
    ----------
    source : str
        The file as the user named it.
    problem : str
        What is wrong and the expected form.

    Returns
    -------
    BadInput
    """
    return BadInput(_one_line(f"{source}: {problem}"))


def read_csv_records(path: str | os.PathLike[str], source: str) -> Iterator[tuple[int, list[str]]]:
    """The non-blank records of a UTF-8 CSV file (a BOM is tolerated), one at a time.

    A blank record (no fields, or only whitespace in every field) is skipped. File-system, decoding and CSV
    syntax problems become :class:`BadInput` (:func:`file_error`).

    Parameters
    ----------
    path : str or path-like
    source : str
        The file as the user named it, for messages.

    Yields
    ------
    line : int
        File line (1-based) on which the record starts.
    fields : list of str
        The record's fields as written.
    """
    p = Path(path)
    if problem := file_problem(p):
        raise file_error(source, f"{problem} (expected a CSV file with header x,y,z)")
    try:
        with open(p, encoding="utf-8-sig", newline="") as f:
            reader = csv.reader(f)
            last_line = 0
            for fields in reader:
                # reader.line_num counts physical lines read so far; a record starts after the previous one
                start, last_line = last_line + 1, reader.line_num
                if not fields or all(not s.strip() for s in fields):
                    continue
                yield start, fields
    except UnicodeDecodeError as err:
        raise file_error(
            source, f"is not UTF-8 text ({err.reason} at byte {err.start}); expected a UTF-8 CSV file"
        ) from None
    except csv.Error as err:
        raise file_error(
            source, f"is not valid CSV near line {last_line + 1} ({err}); expected a comma-separated file"
        ) from None
    except OSError as err:
        raise file_error(source, f"cannot be read ({err.strerror or err}); expected a readable CSV file") from None


def ragged_error(source: str, line: int, k: int, h: int, row: int | None = None) -> BadInput:
    """The one-line error (:func:`file_error`) for file line ``line`` with ``k`` fields under a header of ``h``
    (``row``: its 1-based data row, named in the message when given)."""
    data_row = f" (data row {row})" if row is not None else ""
    return file_error(
        source,
        f"file line {line} has {k} field{'s' if k != 1 else ''} but the header has {h}"
        f"{data_row}; expected {h} comma-separated fields on every line",
    )


# ---------------------------------------------------------------------------------------------------------
# atomic writing


def atomic_write(path: str | os.PathLike[str], write: Callable[[IO[str]], None]) -> Path:
    """Write a UTF-8 text file atomically and return its path.

    ``write(f)`` fills a temporary file beside ``path`` (same folder, so the rename cannot cross file
    systems); once it is complete and flushed to disk it replaces ``path`` with :func:`os.replace`. Parent
    folders are created. On any failure (an exception from ``write``, a full disk, a failed rename) the
    temporary file is removed, ``path`` is left as it was and the exception propagates (:class:`OSError`
    for file-system problems).
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    # our own O_EXCL file rather than mkstemp, so that it gets the usual umask-derived mode, not 0600
    for _ in range(100):  # pragma: no branch - a collision of 48 random bits does not happen
        tmp = target.parent / f".{target.name}.{secrets.token_hex(6)}.tmp"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
            break
        except FileExistsError:
            continue
    else:  # pragma: no cover
        raise FileExistsError(f"cannot create a temporary file beside {target}")
    try:
        with open(fd, "w", encoding="utf-8", newline="") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        if target.is_file():  # keep the permissions of the file being replaced
            try:
                os.chmod(tmp, target.stat().st_mode & 0o7777)
            except OSError:
                pass
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    _fsync_dir(target.parent)
    return target


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, replace: bool = True) -> Iterator[Path]:
    """A temporary path beside ``path`` for a writer that takes a file name (netCDF, PLY, HDF5, ``.npz``): when
    the ``with`` block ends without an exception the file there is flushed to disk and replaces ``path``
    (:func:`os.replace`); otherwise it is removed and ``path`` is left as it was. The temporary name ends in
    ``path``'s own suffix, so writers that choose a format by the extension choose the same one.

    With ``replace=False`` a file that appeared at ``path`` meanwhile (another process writing the same name) is
    kept: the new file is linked into place only where nothing is (:func:`os.link`, atomic), else it is kept beside
    it as ``NAME.<UTC time>.SUFFIX`` and :class:`~bayestouch.errors.BadInput` names both.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f".{target.name}.{secrets.token_hex(6)}.tmp{target.suffix}"
    try:
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        if replace:
            os.replace(tmp, target)
        else:
            try:
                os.link(tmp, target)
                clash = False
            except FileExistsError:
                clash = True
            except OSError:  # a file system without hard links: the check and the rename are two steps there
                clash = target.exists()
                if not clash:
                    os.replace(tmp, target)
            if clash:
                kept = target.with_name(f"{target.stem}.{utc_stamp()}{target.suffix}")
                os.replace(tmp, kept)
                raise BadInput(
                    f"{target} appeared while this run wrote it (another run writing the same name?); it is kept, "
                    f"and this run's file is {kept}"
                ) from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()
    _fsync_dir(target.parent)


def utc_stamp() -> str:
    """The current UTC time as it names kept files and folders: ``20261126T102857Z``."""
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())


def move_aside(folder: str | os.PathLike[str], paths) -> Path:
    """Move the files ``paths`` into a new folder ``folder/replaced-<UTC time>`` (``.2``, ``.3`` … when that name
    is taken) and return it: an earlier run's outputs kept, never deleted, where a new run replaces them."""
    paths = [Path(p) for p in paths]
    # one overwrite sets aside in steps (another command's results, then the run's own): this process's folder of
    # the last minute takes them all while no name clashes (two replaced-* folders split one earlier run)
    key = str(Path(folder).resolve())
    recent = _ASIDE.get(key)
    if recent is not None and time.monotonic() - recent[1] < 60 and recent[0].is_dir():
        if not any((recent[0] / p.name).exists() for p in paths):
            for p in paths:
                p.replace(recent[0] / p.name)
            return recent[0]
    base = Path(folder) / f"replaced-{utc_stamp()}"
    aside, k = base, 1
    while aside.exists():
        k += 1
        aside = base.with_name(f"{base.name}.{k}")
    aside.mkdir(parents=True)
    for p in paths:
        p.replace(aside / p.name)
    _ASIDE[key] = (aside, time.monotonic())
    return aside


#: the folder :func:`move_aside` made last in each run folder, by this process, and when (time.monotonic)
_ASIDE: dict[str, tuple[Path, float]] = {}


def set_aside(paths, who: str) -> Path | None:
    """``--overwrite``: move those of ``paths`` that exist (all in one folder) aside with :func:`move_aside` and say
    where on stderr, naming the command ``who``; returns the folder, or None when none of them exists."""
    present = [Path(p) for p in paths if Path(p).exists()]
    if not present:
        return None
    aside = move_aside(present[0].parent, present)
    names = ", ".join(p.name for p in present[:4]) + (" …" if len(present) > 4 else "")
    print(f"bayestouch {who}: --overwrite: the earlier {names} moved to {aside}", file=sys.stderr)
    return aside


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write a UTF-8 text file atomically (see :func:`atomic_write`), creating parent folders."""
    return atomic_write(path, lambda f: f.write(text))


def _fsync_dir(folder: Path) -> None:
    """Best-effort fsync of a folder so that a rename survives a power cut (POSIX only)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _cell(value: Any, column: str) -> str:
    """Text of one CSV cell: floats by repr (round-trips exactly), None empty, bools true/false."""
    if isinstance(value, np.generic | np.ndarray) and np.ndim(value) == 0:
        value = value.item()
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(
        f"column {column!r}: cannot write a {type(value).__name__} to a CSV cell; expected a "
        "number, string, bool or None"
    )


# ---------------------------------------------------------------------------------------------------------
# generic tables and JSON


def write_csv_rows(
    path: str | os.PathLike[str], rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None
) -> Path:
    """Write a list of dicts as a CSV file with a header, atomically (parent folders created).

    Parameters
    ----------
    path : str or path-like
        Target file.
    rows : sequence of mappings
        One mapping per row. Values: numbers (floats by :func:`repr`, exact round trip; NaN as ``nan``),
        strings, bools (``true`` / ``false``), None (empty cell), NumPy scalars, paths. A key missing from
        a row gives an empty cell.
    columns : sequence of str, optional
        Column order. Default: the keys of the first row in order, then any new keys of later rows in
        order of appearance. Keys not in ``columns`` raise :class:`ValueError`.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    TypeError
        A value of another type (list, dict, array, …); an existing file is left as it was.
    ValueError
        A row key not in the given ``columns``.
    OSError
        The file cannot be written; an existing file is left as it was.
    """
    if columns is None:
        cols: list[str] = []
        seen: set[str] = set()
        for r in rows:
            for k in r:
                if k not in seen:
                    seen.add(k)
                    cols.append(k)
    else:
        cols = list(columns)
        allowed = set(cols)
        for i, r in enumerate(rows):
            extra = [k for k in r if k not in allowed]
            if extra:
                raise ValueError(f"row {i + 1} (1-based) has key(s) {extra} not in columns {cols}")

    def write(fh: IO[str]) -> None:
        w = csv.writer(fh, lineterminator="\n")
        if cols:
            w.writerow(cols)
        for r in rows:
            w.writerow([_cell(r.get(c), c) for c in cols])

    return atomic_write(path, write)


def read_csv_rows(path: str | os.PathLike[str]) -> list[dict[str, str]]:
    """Read a CSV file with a header as a list of dicts (header name → cell text, both as written).

    A UTF-8 BOM is allowed; blank lines are skipped; an empty file gives ``[]``.

    Raises
    ------
    BadInput
        Missing or unreadable file, invalid CSV, or a line with a different number of fields from the
        header.
    """
    source = os.fspath(path)
    with contextlib.closing(read_csv_records(path, source)) as records:
        first = next(records, None)
        if first is None:
            return []
        _, header = first
        out: list[dict[str, str]] = []
        for line, fields in records:
            if len(fields) != len(header):
                raise ragged_error(source, line, len(fields), len(header))
            out.append(dict(zip(header, fields, strict=True)))
    return out


def _jsonable(obj: Any) -> Any:
    """``obj`` as plain Python for :mod:`json`: NumPy scalars and arrays converted, NaN and ±inf → None."""
    if isinstance(obj, np.ndarray | np.generic):
        obj = obj.tolist() if isinstance(obj, np.ndarray) else obj.item()
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {_json_key(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, complex):
        raise TypeError(f"cannot write a complex number {obj!r} to JSON")
    raise TypeError(
        f"cannot write a {type(obj).__name__} to JSON; expected numbers, strings, bools, None, "
        "lists, dicts or NumPy arrays"
    )


def _json_key(key: Any) -> Any:
    if isinstance(key, np.generic):
        key = key.item()
    if key is None or isinstance(key, str | bool | int | float):
        return key
    raise TypeError(f"cannot use a {type(key).__name__} as a JSON object key")


def write_json(path: str | os.PathLike[str], obj: Any) -> Path:
    """Write ``obj`` as JSON (indent 2, trailing newline), atomically, creating parent folders.

    NumPy scalars and arrays become Python numbers and lists; NaN and ±inf become ``null`` (JSON has no
    spelling for them).

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    TypeError
        An object JSON cannot represent; an existing file is left as it was.
    OSError
        The file cannot be written; an existing file is left as it was.
    """
    text = json.dumps(_jsonable(obj), indent=2, allow_nan=False, ensure_ascii=False) + "\n"
    return atomic_write(path, lambda fh: fh.write(text))


# ---------------------------------------------------------------------------------------------------------
# TOML values (the writers of device and pose-law files; tomllib only reads)


def toml_value(v) -> str:
    """A TOML scalar: a bool, an integer, a float (``repr``: read back exactly) or a quoted, escaped string."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'


def toml_array(values) -> str:
    """A TOML array of floats, nested as ``values`` is (each float's ``repr``: read back exactly)."""
    a = np.asarray(values, dtype=float)
    if a.ndim == 1:
        return "[" + ", ".join(repr(float(v)) for v in a) + "]"
    return "[" + ", ".join(toml_array(b) for b in a) + "]"
