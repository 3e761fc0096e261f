"""Reading and writing contact-point files, result tables and JSON, with one-line errors.

Contact-point CSV files have a header line and one contact per row:

* ``x, y, z`` (required): contact position, metres;
* ``nx, ny, nz`` (optional, all three or none): outward surface normal, any non-zero length (normalised on
  load);
* ``force`` (optional): normal contact force, newtons, ≥ 0.

Header names are matched case-insensitively with surrounding whitespace stripped; other columns are
ignored. Every problem with a file raises :class:`~bayestouch.errors.BadInput` whose message is one line
naming the file, the problem and the expected form.

All writers are atomic: the text goes to a temporary file in the target's folder, which replaces the target
(:func:`os.replace`) only once it is complete and flushed, so a crash never leaves a half-written file and
an existing file is either the old one or the new one. Floats are written with :func:`repr`, the shortest
text that reads back to the same bits.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import operator
import os
import secrets
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np

from bayestouch.errors import BadInput

__all__ = [
    "ContactPoints",
    "load_contact_points",
    "save_contact_points",
    "write_csv_rows",
    "read_csv_rows",
    "write_json",
    "write_text",
]

#: Above either limit (metres) the coordinates are taken to be millimetres.
MM_MAX_ABS_M = 2.0
MM_MAX_DIAGONAL_M = 3.5  # a 2 m cube in metres passes
#: Normals shorter than this cannot be normalised.
MIN_NORMAL_LENGTH = 1e-12
#: Parameters of the paper's n-ellipsoid: the fewest contact points that can determine one.
N_ELLIPSOID_PARAMS = 12

_POS = ("x", "y", "z")
_NORMAL = ("nx", "ny", "nz")
_FORCE = "force"
_UNITS = {"x": "metres", "y": "metres", "z": "metres", "nx": "", "ny": "", "nz": "", "force": "newtons"}
_EXPECTED_HEADER = "x,y,z[,nx,ny,nz][,force]"


class ContactPoints(NamedTuple):
    """Contact points read from (or to be written to) a CSV file.

    Attributes
    ----------
    points : (N, 3) float, metres
        Contact positions.
    normals : (N, 3) float or None
        Unit outward normals (normalised on load), None when the file has no ``nx, ny, nz``.
    force : (N,) float, newtons, or None
        Normal contact forces, ≥ 0, None when the file has no ``force`` column.
    source : str
        Where the points came from (the file path as given).
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    force: np.ndarray | None = None
    source: str = ""


# ---------------------------------------------------------------------------------------------------------
# helpers


def _one_line(text: str) -> str:
    """``text`` with line breaks escaped, so an error message stays on one line."""
    return text.replace("\r", "\\r").replace("\n", "\\n")


def _bad(source: str, problem: str) -> BadInput:
    return BadInput(_one_line(f"{source}: {problem}"))


def _show(text: str, limit: int = 40) -> str:
    """Quoted, escaped, possibly shortened cell text for an error message."""
    if len(text) > limit:
        text = text[:limit] + "…"
    return repr(text)


def _num(v: float) -> str:
    """A number for a message: six significant digits, Python float spelling (45.0, 0.0123, 1000000.0)."""
    return repr(float(f"{float(v):.6g}"))


def _where(row: int, line: int) -> str:
    return f"data row {row}, file line {line}"


# ---------------------------------------------------------------------------------------------------------
# contact points: reading


def _read_records(path: str | os.PathLike[str], source: str) -> Iterator[tuple[int, list[str]]]:
    """(file line number, fields) for every non-blank record of a CSV file; BOM tolerated.

    A blank record (no fields, or only whitespace in every field) is skipped. File-system, decoding and
    CSV syntax problems become :class:`BadInput`.
    """
    p = Path(path)
    if not p.exists():
        raise _bad(source, "no such file (expected a CSV file with header x,y,z)")
    if p.is_dir():
        raise _bad(source, "is a folder, not a file (expected a CSV file with header x,y,z)")
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
        raise _bad(source, f"is not UTF-8 text ({err.reason} at byte {err.start}); expected a UTF-8 CSV file") from None
    except csv.Error as err:
        raise _bad(
            source, f"is not valid CSV near line {last_line + 1} ({err}); expected a comma-separated file"
        ) from None
    except OSError as err:
        raise _bad(source, f"cannot be read ({err.strerror or err}); expected a readable CSV file") from None


def _ragged(source: str, line: int, k: int, h: int, row: int | None = None) -> BadInput:
    """Error for a line with ``k`` fields under a header of ``h``."""
    data_row = f" (data row {row})" if row is not None else ""
    return _bad(
        source,
        f"file line {line} has {k} field{'s' if k != 1 else ''} but the header has {h}"
        f"{data_row}; expected {h} comma-separated fields on every line",
    )


def _parse_header(fields: list[str], source: str) -> dict[str, int]:
    """Column index of each recognised column (``x``, ``y``, ``z``, ``nx``, ``ny``, ``nz``, ``force``)."""
    names = [s.strip().lower() for s in fields]
    known = (*_POS, *_NORMAL, _FORCE)
    index: dict[str, int] = {}
    for i, name in enumerate(names):
        if name in known:
            if name in index:
                raise _bad(
                    source,
                    f"column {name!r} appears twice in the header; expected each of {_EXPECTED_HEADER} at most once",
                )
            index[name] = i
    missing = [c for c in _POS if c not in index]
    if missing:
        found = ",".join(s.strip() for s in fields)
        if all(_is_number(s) for s in fields):
            raise _bad(
                source,
                f"has no header line (first line {_show(found)} is numbers); expected a "
                f"header line {_EXPECTED_HEADER} before the data",
            )
        hint = ""
        if len(fields) == 1 and any(sep in fields[0] for sep in ";\t|"):
            hint = " (is the file separated by ';' or tabs? expected commas)"
        raise _bad(
            source,
            f"missing column(s) {','.join(missing)} (found {_show(found, 80)})"
            f"{hint}; expected a header {_EXPECTED_HEADER}",
        )
    have_normals = [c for c in _NORMAL if c in index]
    if 0 < len(have_normals) < 3:
        lacking = [c for c in _NORMAL if c not in index]
        raise _bad(
            source,
            f"has normal column(s) {','.join(have_normals)} but not {','.join(lacking)}; "
            "expected all of nx,ny,nz or none",
        )
    return index


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _parse_cell(text: str, col: str, row: int, line: int, source: str) -> float:
    unit = f" in {_UNITS[col]}" if _UNITS[col] else ""
    s = text.strip()
    if not s:
        raise _bad(source, f"{_where(row, line)}, column {col} is empty; expected a number{unit}")
    try:
        v = float(s)
    except ValueError:
        raise _bad(
            source, f"{_where(row, line)}, column {col}: {_show(s)} is not a number; expected a decimal number{unit}"
        ) from None
    if not math.isfinite(v):
        raise _bad(source, f"{_where(row, line)}, column {col} is {s} (not finite); expected a finite number{unit}")
    return v


def load_contact_points(path: str | os.PathLike[str], *, min_points: int = N_ELLIPSOID_PARAMS) -> ContactPoints:
    """Read contact points from a CSV file with a header line.

    Parameters
    ----------
    path : str or path-like
        CSV file, UTF-8 (a BOM is allowed), comma-separated. Required columns ``x, y, z`` (metres);
        optional ``nx, ny, nz`` (all three or none; any non-zero length) and ``force`` (newtons, ≥ 0).
        Header names are case-insensitive and may carry surrounding whitespace; other columns are ignored;
        blank lines are skipped.
    min_points : int, optional
        Fewest data rows accepted (default 12, the parameters of the n-ellipsoid).

    Returns
    -------
    ContactPoints
        ``points`` (N, 3) float metres; ``normals`` (N, 3) float unit vectors or None; ``force`` (N,) float
        newtons or None; ``source`` the path as a string.

    Raises
    ------
    BadInput
        One line naming the file, the problem (with data row, file line and column where they apply) and
        the expected form: missing/unreadable file, no header, missing or partial columns, ragged rows,
        non-numeric or non-finite values, too few points, coordinates that look like millimetres (largest
        ``|x|, |y|, |z|`` > 2 m or bounding-box diagonal > 2 m), all points identical, zero-length normals,
        negative force.
    """
    source = os.fspath(path)
    if isinstance(source, bytes):
        source = os.fsdecode(source)
    try:
        min_points = operator.index(min_points)
    except TypeError:
        raise BadInput(f"min_points must be an integer ≥ 0, got {min_points!r}") from None
    if min_points < 0:
        raise BadInput(f"min_points must be an integer ≥ 0, got {min_points}")

    with contextlib.closing(_read_records(path, source)) as records:
        first = next(records, None)
        if first is None:
            raise _bad(source, f"is empty (no header line); expected a CSV file with header {_EXPECTED_HEADER}")
        _, header = first
        index = _parse_header(header, source)
        columns = [c for c in (*_POS, *_NORMAL, _FORCE) if c in index]
        n_fields = len(header)

        values: list[list[float]] = []
        lines: list[int] = []
        for row, (line, fields) in enumerate(records, start=1):
            if len(fields) != n_fields:
                raise _ragged(source, line, len(fields), n_fields, row)
            values.append([_parse_cell(fields[index[c]], c, row, line, source) for c in columns])
            lines.append(line)

    n = len(values)
    if n < max(min_points, 1):
        need = max(min_points, 1)
        why = f" (the {need} parameters of the n-ellipsoid)" if need == N_ELLIPSOID_PARAMS else ""
        raise _bad(
            source,
            f"has {n} point(s); need at least {need} point{'s' if need != 1 else ''}{why}; "
            f"expected one contact per line after the header {_EXPECTED_HEADER}",
        )

    table = np.asarray(values, dtype=np.float64).reshape(n, len(columns))
    col = {c: j for j, c in enumerate(columns)}
    points = np.ascontiguousarray(table[:, [col[c] for c in _POS]])

    max_abs = float(np.max(np.abs(points)))
    diagonal = float(np.linalg.norm(np.ptp(points, axis=0)))
    if max_abs > MM_MAX_ABS_M or diagonal > MM_MAX_DIAGONAL_M:
        raise _bad(
            source,
            f"x,y,z look like millimetres (largest |value| {_num(max_abs)}, bounding-box "
            f"diagonal {_num(diagonal)}); give metres (e.g. divide by 1000), within "
            f"±{MM_MAX_ABS_M} m and a bounding-box diagonal ≤ {MM_MAX_DIAGONAL_M} m",
        )
    if diagonal == 0.0:
        at = ", ".join(_num(v) for v in points[0])
        raise _bad(
            source, f"all {n} points are identical ({at}); expected contact points spread over the object's surface"
        )

    normals = None
    if "nx" in col:
        raw = np.ascontiguousarray(table[:, [col[c] for c in _NORMAL]])
        length = np.linalg.norm(raw, axis=1)
        short = np.flatnonzero(~(length >= MIN_NORMAL_LENGTH))
        if short.size:
            i = int(short[0])
            raise _bad(
                source,
                f"{_where(i + 1, lines[i])}, columns nx,ny,nz: normal has zero length "
                f"({_num(length[i])}; {short.size} row(s) in all); expected a non-zero normal vector",
            )
        # normals already of unit length to within a few ulp are kept bit for bit, so that saving and
        # reloading a loaded file gives identical arrays
        unit = np.abs(length - 1.0) <= 4 * np.finfo(np.float64).eps
        normals = raw / np.where(unit, 1.0, length)[:, None]

    force = None
    if _FORCE in col:
        force = np.ascontiguousarray(table[:, col[_FORCE]])
        negative = np.flatnonzero(force < 0)
        if negative.size:
            i = int(negative[0])
            raise _bad(
                source,
                f"{_where(i + 1, lines[i])}, column force is {_num(force[i])} N, negative "
                f"({negative.size} row(s) in all); expected force ≥ 0 newtons",
            )

    return ContactPoints(points=points, normals=normals, force=force, source=source)


# ---------------------------------------------------------------------------------------------------------
# atomic writing


def _atomic_write(path: str | os.PathLike[str], write: Callable[[IO[str]], None]) -> Path:
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


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write a UTF-8 text file atomically (see :func:`_atomic_write`), creating parent folders."""
    return _atomic_write(path, lambda f: f.write(text))


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
# contact points: writing


def _as_array(value: Any, name: str, shape: tuple[int | None, ...], form: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInput(f"{name} must be {form} of numbers, got {type(value).__name__}") from None
    if a.ndim != len(shape) or any(s is not None and s != t for s, t in zip(shape, a.shape, strict=False)):
        raise BadInput(f"{name} must be {form}, got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a).reshape(len(a), -1).all(axis=1)) if a.size else np.empty(0, int)
    if bad.size:
        raise BadInput(f"{name} must be finite, row {int(bad[0]) + 1} (1-based) is {a[bad[0]].tolist()}")
    return a


def save_contact_points(
    path: str | os.PathLike[str],
    cp_or_points: ContactPoints | np.ndarray | Sequence[Sequence[float]],
    normals: np.ndarray | None = None,
    force: np.ndarray | None = None,
) -> Path:
    """Write contact points to a CSV file that :func:`load_contact_points` reads back bit for bit.

    Parameters
    ----------
    path : str or path-like
        Target file; parent folders are created; written atomically.
    cp_or_points : ContactPoints or (N, 3) float, metres
        The points, or a :class:`ContactPoints` whose normals and force are written too.
    normals : (N, 3) float, optional
        Outward normals, written as given (non-zero length). Not allowed together with a
        :class:`ContactPoints` that has normals.
    force : (N,) float, newtons, optional
        Contact forces, ≥ 0. Not allowed together with a :class:`ContactPoints` that has force.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    BadInput
        Wrong shapes, non-finite values, zero-length normals, negative force (naming ``points``,
        ``normals`` or ``force``); nothing is written.
    OSError
        The file cannot be written; an existing file is left as it was.

    Notes
    -----
    Header ``x,y,z[,nx,ny,nz][,force]``; values by :func:`repr`, the shortest text that reads back to the
    same float.
    """
    if isinstance(cp_or_points, ContactPoints):
        if normals is not None and cp_or_points.normals is not None:
            raise BadInput("normals given both in the ContactPoints and as an argument; expected one of them")
        if force is not None and cp_or_points.force is not None:
            raise BadInput("force given both in the ContactPoints and as an argument; expected one of them")
        normals = cp_or_points.normals if normals is None else normals
        force = cp_or_points.force if force is None else force
        cp_or_points = cp_or_points.points
    pts = _as_array(cp_or_points, "points", (None, 3), "an (N, 3) array (metres)")
    n = len(pts)
    columns = list(_POS)
    parts = [pts]
    if normals is not None:
        nrm = _as_array(normals, "normals", (n, 3), f"an ({n}, 3) array like points")
        short = np.flatnonzero(~(np.linalg.norm(nrm, axis=1) >= MIN_NORMAL_LENGTH))
        if short.size:
            raise BadInput(
                f"normals must have non-zero length, row {int(short[0]) + 1} (1-based) is {nrm[short[0]].tolist()}"
            )
        columns += _NORMAL
        parts.append(nrm)
    if force is not None:
        f = _as_array(force, "force", (n,), f"an ({n},) array (newtons)")
        negative = np.flatnonzero(f < 0)
        if negative.size:
            raise BadInput(
                f"force must be ≥ 0 newtons, row {int(negative[0]) + 1} (1-based) is {float(f[negative[0]])}"
            )
        columns.append(_FORCE)
        parts.append(f[:, None])
    table = np.hstack(parts) if n else np.empty((0, len(columns)))

    def write(fh: IO[str]) -> None:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        for r in table.tolist():
            w.writerow([repr(v) for v in r])

    return _atomic_write(path, write)


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

    return _atomic_write(path, write)


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
    with contextlib.closing(_read_records(path, source)) as records:
        first = next(records, None)
        if first is None:
            return []
        _, header = first
        out: list[dict[str, str]] = []
        for line, fields in records:
            if len(fields) != len(header):
                raise _ragged(source, line, len(fields), len(header))
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
    return _atomic_write(path, lambda fh: fh.write(text))
