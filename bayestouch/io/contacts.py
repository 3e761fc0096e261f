"""Contact-point CSV files: reading with one-line errors, and writing that reads back bit for bit.

A file has a header line and one finger position per row:

* ``x, y, z`` (required): contact position, metres;
* ``nx, ny, nz`` (optional, all three or none): outward surface normal, any non-zero length (normalised on
  load);
* ``force`` (optional): normal contact force, newtons, ≥ 0;
* ``contact`` (optional): 1 = the finger touched the object there (a contact, as above), 0 = a finger position
  without contact (free space, known to be outside the object; its ``nx, ny, nz`` and ``force`` cells may be
  empty and are ignored). Also accepted: ``0.0``/``1.0``, ``false``/``true``, ``no``/``yes``. Without the
  column every row is a contact.

Header names are matched case-insensitively with surrounding whitespace stripped; other columns are ignored.
Every problem with a file raises :class:`~bayestouch.errors.BadInput` whose message is one line naming the file,
the problem and the expected form. Files are written atomically (:func:`bayestouch.io.files.atomic_write`) with
floats by :func:`repr`.
"""

from __future__ import annotations

import contextlib
import csv
import math
import operator
import os
from collections.abc import Sequence
from pathlib import Path
from typing import IO, NamedTuple

import numpy as np

from bayestouch.errors import BadInput, as_array, check_bool, check_path
from bayestouch.io.files import atomic_write, file_error, ragged_error, read_csv_records

__all__ = [
    "check_contact_spread",
    "contact_array",
    "contact_points_from_table",
    "COPLANAR_RATIO",
    "ContactPoints",
    "load_contact_points",
    "save_contact_points",
    "MM_MAX_ABS_M",
    "unit_hint",
    "unit_problem",
    "MM_MAX_DIAGONAL_M",
    "MIN_DIAGONAL_M",
    "MIN_NORMAL_LENGTH",
    "INWARD_COSINE",
    "check_normals_outward",
    "TYPICAL_DIAGONAL_M",
    "N_ELLIPSOID_PARAMS",
]

#: Above either limit (metres) the coordinates are taken to be millimetres.
MM_MAX_ABS_M = 2.0
MM_MAX_DIAGONAL_M = 3.5  # a 2 m cube in metres passes
#: Bounding-box diagonal (metres) of a typical contact set, the geometric middle of the size prior's 1–30 cm
#: (models/priors.toml): of the units that would make a file's numbers metres the loader accepts, the one nearer it
#: is named first
TYPICAL_DIAGONAL_M = 0.055
_OTHER_UNITS = (("centimetres", 1e2), ("millimetres", 1e3), ("micrometres", 1e6), ("nanometres", 1e9))
#: Below this bounding-box diagonal (metres) the contacts cannot be an object a finger strokes (the prior's smallest
#: semi-axis is 1 mm, models/priors.toml axis_min): the coordinates are in the wrong unit.
MIN_DIAGONAL_M = 1e-3
#: Normals shorter than this cannot be normalised.
MIN_NORMAL_LENGTH = 1e-12
#: Mean cosine between the normals and the directions from the contacts' centroid to the contacts below which the
#: normals are taken to point inwards (outward normals of a convex patch give ≥ 0; a flat patch ≈ 0)
INWARD_COSINE = -0.5
#: Parameters of the paper's n-ellipsoid: the fewest contact points that can determine one.
N_ELLIPSOID_PARAMS = 12

_POS = ("x", "y", "z")
_NORMAL = ("nx", "ny", "nz")
_FORCE = "force"
_CONTACT = "contact"
_UNITS = {"x": "metres", "y": "metres", "z": "metres", "nx": "", "ny": "", "nz": "", "force": "newtons"}
_EXPECTED_HEADER = "x,y,z[,nx,ny,nz][,force][,contact]"
#: Accepted spellings of the ``contact`` column (lower case, stripped) and their meaning.
_CONTACT_VALUES = {
    "1": True,
    "1.0": True,
    "true": True,
    "yes": True,
    "0": False,
    "0.0": False,
    "false": False,
    "no": False,
}
_CONTACT_FORM = "0 (finger position without contact) or 1 (contact)"


class _ContactPointsFields(NamedTuple):
    points: np.ndarray
    normals: np.ndarray | None = None
    force: np.ndarray | None = None
    source: str = ""
    free: np.ndarray | None = None


class ContactPoints(_ContactPointsFields):
    """Contact points read from (or to be written to) a CSV file.

    The fields are checked on construction (a one-line :class:`BadInput` naming the field): points that are not
    a finite (N, 3) array, normals or force of another length than the points, text for any array, a source that
    is not a string. The arrays are kept as given.

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
    free : (K, 3) float, metres, or None
        Finger positions without contact (rows with ``contact`` = 0: free space, outside the object), None
        when the file has no ``contact`` column or no such rows.
    """

    __slots__ = ()

    def __new__(cls, points, normals=None, force=None, source: str = "", free=None):
        n = len(as_array(points, "ContactPoints.points", (None, 3), "an (N, 3) array (metres)"))
        if normals is not None:
            as_array(normals, "ContactPoints.normals", (n, 3), f"an ({n}, 3) array like points, or None")
        if force is not None:
            as_array(force, "ContactPoints.force", (n,), f"an ({n},) array (newtons), or None")
        if free is not None:
            as_array(free, "ContactPoints.free", (None, 3), "a (K, 3) array (metres), or None")
        if not isinstance(source, str):
            raise BadInput(f"ContactPoints.source: expected a str (where the points came from), got {source!r:.60}")
        return super().__new__(cls, points, normals, force, source, free)


# ---------------------------------------------------------------------------------------------------------
# helpers


def _show(text: str, limit: int = 40) -> str:
    """Quoted, escaped, possibly shortened cell text for an error message."""
    if len(text) > limit:
        text = text[:limit] + "…"
    return repr(text)


def unit_hint(max_abs: float, diagonal: float | None) -> str:
    """What coordinates written in an unknown unit look like, and how to give metres, for a one-line message:
    ``"look like centimetres or millimetres (largest |value| 4.5, bounding-box diagonal 8.7); give metres (divide
    by 100 if they are centimetres, divide by 1000 if they are millimetres)"``.

    Parameters
    ----------
    max_abs, diagonal : float
        Largest absolute coordinate and bounding-box diagonal as written (unknown unit); ``diagonal`` None for one
        point (a centre), which has none: the units are then judged on ``max_abs`` alone.

    Returns
    -------
    str
        Names at most two units (centimetres, millimetres, micrometres, nanometres) whose quotient the loader would
        accept as metres (within the metre limits, at least :data:`MIN_DIAGONAL_M` across), the one whose diagonal
        is nearer :data:`TYPICAL_DIAGONAL_M` (in log) first; "some unit other than metres" when none fits.
    """
    size = max_abs if diagonal is None else diagonal
    fits = [
        (unit, factor)
        for unit, factor in _OTHER_UNITS
        if max_abs / factor <= MM_MAX_ABS_M and MIN_DIAGONAL_M <= size / factor <= MM_MAX_DIAGONAL_M
    ]
    fits.sort(key=lambda uf: abs(np.log(size / uf[1] / TYPICAL_DIAGONAL_M)))
    if fits:
        how = ", ".join(f"divide by {f:g} if they are {u}" for u, f in fits[:2])
        names = " or ".join(u for u, _ in fits[:2])
    else:
        how, names = "e.g. divide by 1000", "some unit other than metres"
    extent = "" if diagonal is None else f", bounding-box diagonal {_num(diagonal)}"
    return f"look like {names} (largest |value| {_num(max_abs)}{extent}); give metres ({how})"


def unit_problem(points) -> str:
    """What is wrong with the unit of coordinates ``points (N, 3)`` (finite) read as metres: :func:`unit_hint` when
    their largest absolute value exceeds :data:`MM_MAX_ABS_M` or their bounding-box diagonal
    :data:`MM_MAX_DIAGONAL_M`, else ``""``."""
    p = np.asarray(points, dtype=float)
    max_abs = float(np.max(np.abs(p)))
    with np.errstate(over="ignore", invalid="ignore"):  # values near 1e308: the span overflows, and is refused
        diagonal = float(np.linalg.norm(np.ptp(p, axis=0)))
    if max_abs > MM_MAX_ABS_M or diagonal > MM_MAX_DIAGONAL_M:
        return unit_hint(max_abs, None if len(p.reshape(-1, 3)) == 1 else diagonal)
    return ""


def check_normals_outward(
    points, normals, where: str = "normals", fix: str = "negate nx,ny,nz, or fit without them (--ignore-normals)"
) -> None:
    """Refuse normals that point inwards: the mean cosine between each normal and the direction from the contacts'
    centroid to its contact below :data:`INWARD_COSINE` (a sign-convention mistake; the likelihood expects outward
    normals and would otherwise report a meaningless shape).

    Parameters
    ----------
    points : (N, 3) float, metres
    normals : (N, 3) float
    where : str
        Names the normals in the message (a file, an argument).
    fix : str
        What the message tells the user to do.

    Raises
    ------
    BadInput
    """
    p = np.asarray(points, float)
    n = np.asarray(normals, float)
    if p.ndim != 2 or n.shape != p.shape or p.shape[1:] != (3,):
        raise BadInput(f"{where}: expected one normal per contact, an ({len(p)}, 3) array; got shape {n.shape}")
    r = p - p.mean(axis=0)
    length = np.linalg.norm(r, axis=1) * np.linalg.norm(n, axis=1)
    ok = length > 0
    if not ok.any():
        return
    cos = np.sum(r[ok] * n[ok], axis=1) / length[ok]
    if float(cos.mean()) < INWARD_COSINE:
        raise BadInput(
            f"{where}: the normals point inwards (towards the contacts' centroid at {100 * (cos < 0).mean():.0f} % "
            f"of the contacts, mean cosine {cos.mean():.2f}); expected outward normals: {fix}"
        )


def _num(v: float) -> str:
    """A number for a message: six significant digits, Python float spelling (45.0, 0.0123, 1000000.0)."""
    return repr(float(f"{float(v):.6g}"))


def _where(row: int, line: int | None) -> str:
    """Where a cell is, for messages (``line`` None: a table, not a file)."""
    return f"data row {row}" if line is None else f"data row {row}, file line {line}"


# ---------------------------------------------------------------------------------------------------------
# reading


def _parse_header(fields: list[str], source: str) -> dict[str, int]:
    """Column index of each recognised column (``x``, ``y``, ``z``, ``nx``, ``ny``, ``nz``, ``force``,
    ``contact``)."""
    names = [s.strip().lower() for s in fields]
    known = (*_POS, *_NORMAL, _FORCE, _CONTACT)
    index: dict[str, int] = {}
    for i, name in enumerate(names):
        if name in known:
            if name in index:
                raise file_error(
                    source,
                    f"column {name!r} appears twice in the header; expected each of {_EXPECTED_HEADER} at most once",
                )
            index[name] = i
    missing = [c for c in _POS if c not in index]
    if missing:
        found = ",".join(s.strip() for s in fields)
        if all(_is_number(s) for s in fields):
            raise file_error(
                source,
                f"has no header line (first line {_show(found)} is numbers); expected a "
                f"header line {_EXPECTED_HEADER} before the data",
            )
        hint = ""
        if len(fields) == 1 and any(sep in fields[0] for sep in ";\t|"):
            hint = " (is the file separated by ';' or tabs? expected commas)"
        raise file_error(
            source,
            f"missing column(s) {','.join(missing)} (found {_show(found, 80)})"
            f"{hint}; expected a header {_EXPECTED_HEADER}",
        )
    have_normals = [c for c in _NORMAL if c in index]
    if 0 < len(have_normals) < 3:
        lacking = [c for c in _NORMAL if c not in index]
        raise file_error(
            source,
            f"has normal column(s) {','.join(have_normals)} but not {','.join(lacking)}; "
            "expected all of nx,ny,nz or none",
        )
    return index


def _is_number(text: str) -> bool:
    if "_" in text:
        return False
    try:
        float(text)
    except ValueError:
        return False
    return True


def _parse_cell(text: str, col: str, row: int, line: int, source: str) -> float:
    unit = f" in {_UNITS[col]}" if _UNITS[col] else ""
    s = text.strip()
    if not s:
        raise file_error(source, f"{_where(row, line)}, column {col} is empty; expected a number{unit}")
    try:
        if "_" in s:  # Python reads "1_0" as 10: a digit-group separator is no CSV number
            raise ValueError(s)
        v = float(s)
    except ValueError:
        raise file_error(
            source, f"{_where(row, line)}, column {col}: {_show(s)} is not a number; expected a decimal number{unit}"
        ) from None
    if not math.isfinite(v):
        raise file_error(
            source, f"{_where(row, line)}, column {col} is {s} (not finite); expected a finite number{unit}"
        )
    return v


def _parse_contact(text: str, row: int, line: int, source: str) -> bool:
    """The ``contact`` cell: True for a contact (1), False for a finger position without contact (0)."""
    s = text.strip()
    if not s:
        raise file_error(source, f"{_where(row, line)}, column contact is empty; expected {_CONTACT_FORM}")
    value = _CONTACT_VALUES.get(s.lower())
    if value is None:
        raise file_error(
            source, f"{_where(row, line)}, column contact: {_show(s)} is not 0 or 1; expected {_CONTACT_FORM}"
        )
    return value


#: contacts whose thinnest spread (smallest singular value of the centred points) is at most this fraction of their
#: widest lie in one plane to rounding: exactly flat data, which no posterior over a closed shape can use (a real
#: flat face, touched with 0.1 mm of noise over 5 cm, is at 2e-3 and is fitted)
COPLANAR_RATIO = 1e-6


def check_contact_spread(points, where: str, axis_max: float) -> None:
    """Refuse (:class:`BadInput` naming ``where``) contacts ``points`` (M, 3) m that no fitted object can hold: a
    span over twice the prior's largest semi-axis ``axis_max`` (m; contacts in millimetres, or several objects),
    or points in one plane or on one line (:data:`COPLANAR_RATIO`)."""
    p = np.asarray(points, dtype=float)
    half = 0.5 * float(np.max(np.ptp(p, axis=0)))
    if half > axis_max:
        max_abs = float(np.max(np.abs(p)))
        with np.errstate(over="ignore", invalid="ignore"):
            diagonal = float(np.linalg.norm(np.ptp(p, axis=0)))
        raise BadInput(
            f"{where}: the contacts span {2 * half:.3g} m, more than twice the prior's largest semi-axis "
            f"({axis_max:g} m, models/priors.toml axis_max): no object the fit can represent holds them; "
            f"unless they hold several objects, the coordinates {unit_hint(max_abs, diagonal)}"
        )
    sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    if sv[-1] <= COPLANAR_RATIO * sv[0]:
        raise BadInput(
            f"{where}: the contacts lie in one plane (or on one line): their thinnest spread is "
            f"{sv[-1] / np.sqrt(len(p)):.2g} m over a spread of {sv[0] / np.sqrt(len(p)):.2g} m; expected contacts "
            "on a curved surface (points on a flat face alone say nothing of the object's depth)"
        )


def contact_array(points, where: str = "points", min_points: int = N_ELLIPSOID_PARAMS) -> np.ndarray:
    """Contact points given as an array, or a one-line refusal naming ``where``: not a finite (M, 3) array of
    numbers (a path, text, NaN), fewer than ``min_points`` (default the n-ellipsoid's 12 parameters), all identical,
    or in one plane (:func:`check_contact_spread`; no closed shape is determined by them).

    Returns
    -------
    (M, 3) float, metres
    """
    a = as_array(points, where, (None, 3), f"an (M ≥ {min_points}, 3) array (metres)")
    if len(a) < min_points:
        raise BadInput(
            f"{where}: expected at least {min_points} points (the parameters of the n-ellipsoid), got {len(a)}"
        )
    if not np.any(np.ptp(a, axis=0)):
        raise BadInput(f"{where}: all {len(a)} points are identical; expected points spread over the object's surface")
    check_contact_spread(a, where, np.inf)
    return a


def load_contact_points(path: str | os.PathLike[str], *, min_points: int = N_ELLIPSOID_PARAMS) -> ContactPoints:
    """Read contact points from a CSV file with a header line.

    Parameters
    ----------
    path : str or path-like
        CSV file, UTF-8 (a BOM is allowed), comma-separated. Required columns ``x, y, z`` (metres);
        optional ``nx, ny, nz`` (all three or none; any non-zero length), ``force`` (newtons, ≥ 0) and
        ``contact`` (1 = contact, 0 = finger position without contact, whose ``nx, ny, nz`` and ``force``
        cells may be empty and are ignored; also ``0.0``/``1.0``, ``false``/``true``, ``no``/``yes``).
        Header names are case-insensitive and may carry surrounding whitespace; other columns are ignored;
        blank lines are skipped.
    min_points : int, optional
        Fewest contacts accepted (default 12, the parameters of the n-ellipsoid); rows with ``contact`` = 0
        do not count.

    Returns
    -------
    ContactPoints
        ``points`` (N, 3) float metres; ``normals`` (N, 3) float unit vectors or None; ``force`` (N,) float
        newtons or None; ``source`` the path as a string; ``free`` (K, 3) float metres, the rows with
        ``contact`` = 0, or None when there are none.

    Raises
    ------
    BadInput
        One line naming the file, the problem (with data row, file line and column where they apply) and
        the expected form: missing/unreadable file, no header, missing or partial columns, ragged rows,
        non-numeric or non-finite values, a ``contact`` value other than 0 or 1, too few contacts,
        coordinates that look like millimetres (largest ``|x|, |y|, |z|`` > 2 m or bounding-box diagonal
        > 3.5 m, free positions included), all contacts identical, zero-length normals, negative force.
    """
    if not isinstance(path, bytes):
        check_path(path, "path")
    source = os.fspath(path)
    if isinstance(source, bytes):
        source = os.fsdecode(source)
    try:
        min_points = operator.index(min_points)
    except TypeError:
        raise BadInput(f"min_points must be an integer ≥ 0, got {min_points!r}") from None
    if min_points < 0:
        raise BadInput(f"min_points must be an integer ≥ 0, got {min_points}")

    with contextlib.closing(read_csv_records(path, source)) as records:
        first = next(records, None)
        if first is None:
            raise file_error(source, f"is empty (no header line); expected a CSV file with header {_EXPECTED_HEADER}")
        _, header = first
        return _contacts_from_records(header, records, source, min_points)


def _contacts_from_records(header: list[str], records, source: str, min_points: int) -> ContactPoints:
    """The checks and parsing of :func:`load_contact_points` after the header: ``records`` yields ``(line,
    fields)`` (``line`` None for a table, not a file), the cells as text."""
    index = _parse_header(header, source)
    columns = [c for c in (*_POS, *_NORMAL, _FORCE) if c in index]
    has_contact = _CONTACT in index
    n_fields = len(header)

    values: list[list[float]] = []  # contacts: the cells of `columns`
    rows: list[int] = []  # their data rows and file lines, for messages
    lines: list[int] = []
    free_values: list[list[float]] = []  # finger positions without contact: x, y, z
    for row, (line, fields) in enumerate(records, start=1):
        if len(fields) != n_fields:
            raise ragged_error(source, line, len(fields), n_fields, row)
        if has_contact and not _parse_contact(fields[index[_CONTACT]], row, line, source):
            free_values.append([_parse_cell(fields[index[c]], c, row, line, source) for c in _POS])
            continue
        values.append([_parse_cell(fields[index[c]], c, row, line, source) for c in columns])
        rows.append(row)
        lines.append(line)

    n, k = len(values), len(free_values)
    if n < max(min_points, 1):
        need = max(min_points, 1)
        why = f" (the {need} parameters of the n-ellipsoid)" if need == N_ELLIPSOID_PARAMS else ""
        if has_contact:
            have = f"{n} contact point(s) (rows with contact = 1; {k} without contact)"
            wanted = f"{need} contact point{'s' if need != 1 else ''}"
        else:
            have, wanted = f"{n} point(s)", f"{need} point{'s' if need != 1 else ''}"
        raise file_error(
            source,
            f"has {have}; need at least {wanted}{why}; "
            f"expected one contact per line after the header {_EXPECTED_HEADER}",
        )

    table = np.asarray(values, dtype=np.float64).reshape(n, len(columns))
    col = {c: j for j, c in enumerate(columns)}
    points = np.ascontiguousarray(table[:, [col[c] for c in _POS]])
    free = np.asarray(free_values, dtype=np.float64).reshape(k, 3) if k else None

    # a file in millimetres is in millimetres throughout: free positions count too
    every = points if free is None else np.vstack([points, free])
    if hint := unit_problem(every):
        raise file_error(
            source, f"x,y,z {hint}, within ±{MM_MAX_ABS_M} m and a bounding-box diagonal ≤ {MM_MAX_DIAGONAL_M} m"
        )
    with np.errstate(over="ignore", invalid="ignore"):
        span = float(np.linalg.norm(np.ptp(points, axis=0)))
    if 0 < span < MIN_DIAGONAL_M:
        raise file_error(
            source,
            f"the contact points span only {_num(span)} m (bounding-box diagonal); the objects a finger strokes are "
            f"at least {MIN_DIAGONAL_M * 1e3:g} mm across: give metres (a file in millimetres divided twice?)",
        )
    if not np.any(np.ptp(points, axis=0)):
        at = ", ".join(_num(v) for v in points[0])
        what = "contact points" if has_contact else "points"
        raise file_error(
            source, f"all {n} {what} are identical ({at}); expected contact points spread over the object's surface"
        )

    distinct = len(np.unique(points, axis=0))
    if distinct < min_points:
        raise file_error(
            source,
            f"only {distinct} distinct points among {n} (rows repeated); need at least {min_points} distinct "
            "contact points",
        )

    normals = None
    if "nx" in col:
        raw = np.ascontiguousarray(table[:, [col[c] for c in _NORMAL]])
        with np.errstate(over="ignore"):
            length = np.linalg.norm(raw, axis=1)
        huge = ~np.isfinite(length)
        if huge.any():  # vectors of ~1e300: scaled by their largest component before their length overflows
            raw[huge] /= np.max(np.abs(raw[huge]), axis=1, keepdims=True)
            length[huge] = np.linalg.norm(raw[huge], axis=1)
        short = np.flatnonzero(~(length >= MIN_NORMAL_LENGTH))
        if short.size:
            i = int(short[0])
            raise file_error(
                source,
                f"{_where(rows[i], lines[i])}, columns nx,ny,nz: normal has zero length "
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
            raise file_error(
                source,
                f"{_where(rows[i], lines[i])}, column force is {_num(force[i])} N, negative "
                f"({negative.size} row(s) in all); expected force ≥ 0 newtons",
            )

    return ContactPoints(points=points, normals=normals, force=force, source=source, free=free)


def _cell_text(v) -> str:
    """A table cell as the CSV text :func:`load_contact_points` parses (missing values: empty; floats exact)."""
    if v is None:
        return ""
    if isinstance(v, bool | np.bool_):
        return "1" if v else "0"
    if isinstance(v, float | np.floating):
        return "" if math.isnan(v) else repr(float(v))
    if isinstance(v, int | np.integer):
        return str(int(v))
    try:  # pandas' NA, NaT …
        if v != v:
            return ""
    except (TypeError, ValueError):
        pass
    return str(v)


def contact_points_from_table(table, where: str = "data", *, min_points: int = N_ELLIPSOID_PARAMS) -> ContactPoints:
    """Contact points from a table with named columns (a ``pandas.DataFrame``), read by name as
    :func:`load_contact_points` reads a CSV file's columns, with the same checks.

    Parameters
    ----------
    table : object with ``columns`` and ``itertuples`` (a ``pandas.DataFrame``)
        Columns ``x, y, z`` (metres, required), ``nx, ny, nz`` (all or none), ``force`` (newtons) and ``contact``
        (1/0, True/False); names case-insensitive, other columns ignored, missing cells (NaN) as empty cells.
    where : str
        The argument's name, for messages.
    min_points : int, optional
        Fewest contacts accepted.

    Returns
    -------
    ContactPoints
        As :func:`load_contact_points`, with ``source`` = ``where``.

    Raises
    ------
    BadInput
        One line naming ``where``: no ``x, y, z`` columns (naming the table's columns), or any problem
        :func:`load_contact_points` refuses (naming the data row and column).
    """
    header = [str(c) for c in table.columns]
    names = {h.strip().lower() for h in header}
    missing = [c for c in _POS if c not in names]
    if missing:
        have = ", ".join(_show(h, 30) for h in header[:12]) + (", …" if len(header) > 12 else "")
        raise BadInput(
            f"{where}: a table without column(s) {','.join(missing)} (its columns: {have or 'none'}); expected "
            f"columns {_EXPECTED_HEADER} (metres), named, in any order"
        )
    records = ((None, [_cell_text(v) for v in row]) for row in table.itertuples(index=False, name=None))
    return _contacts_from_records(header, records, where, min_points)


# ---------------------------------------------------------------------------------------------------------
# writing


def save_contact_points(
    path: str | os.PathLike[str],
    cp_or_points: ContactPoints | np.ndarray | Sequence[Sequence[float]],
    normals: np.ndarray | None = None,
    force: np.ndarray | None = None,
    free: np.ndarray | None = None,
    *,
    overwrite: bool = False,
) -> Path:
    """Write contact points to a CSV file that :func:`load_contact_points` reads back bit for bit.

    Parameters
    ----------
    path : str or path-like
        Target file; parent folders are created; written atomically.
    cp_or_points : ContactPoints or (N, 3) float, metres
        The contact points, or a :class:`ContactPoints` whose normals, force and free positions are written
        too.
    normals : (N, 3) float, optional
        Outward normals, written as given (non-zero length). Not allowed together with a
        :class:`ContactPoints` that has normals.
    force : (N,) float, newtons, optional
        Contact forces, ≥ 0. Not allowed together with a :class:`ContactPoints` that has force.
    free : (K, 3) float, metres, optional
        Finger positions without contact (free space, outside the object). Not allowed together with a
        :class:`ContactPoints` that has free positions.
    overwrite : bool
        Replace an existing file at ``path`` (default: refused, the file is left as it was).

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    BadInput
        Wrong shapes, non-finite values, zero-length normals, negative force (naming ``points``,
        ``normals``, ``force`` or ``free``), an existing file without ``overwrite``; nothing is written.
    OSError
        The file cannot be written; an existing file is left as it was.

    Notes
    -----
    Header ``x,y,z[,nx,ny,nz][,force][,contact]``; values by :func:`repr`, the shortest text that reads back
    to the same float. The ``contact`` column is written only when there are free positions (K > 0): the N
    contacts first with ``contact`` = 1, then the K free positions with ``contact`` = 0 and empty normal and
    force cells. Without free positions the file has no ``contact`` column.
    """
    check_bool(overwrite, "overwrite")
    if not overwrite and Path(path).exists():
        raise BadInput(f"{path} already exists; pass overwrite=True to replace it, or choose another file")
    if isinstance(cp_or_points, ContactPoints):
        if normals is not None and cp_or_points.normals is not None:
            raise BadInput("normals given both in the ContactPoints and as an argument; expected one of them")
        if force is not None and cp_or_points.force is not None:
            raise BadInput("force given both in the ContactPoints and as an argument; expected one of them")
        if free is not None and cp_or_points.free is not None:
            raise BadInput("free given both in the ContactPoints and as an argument; expected one of them")
        normals = cp_or_points.normals if normals is None else normals
        force = cp_or_points.force if force is None else force
        free = cp_or_points.free if free is None else free
        cp_or_points = cp_or_points.points
    pts = as_array(cp_or_points, "points", (None, 3), "an (N, 3) array (metres)")
    n = len(pts)
    columns = list(_POS)
    parts = [pts]
    if normals is not None:
        nrm = as_array(normals, "normals", (n, 3), f"an ({n}, 3) array like points")
        short = np.flatnonzero(~(np.linalg.norm(nrm, axis=1) >= MIN_NORMAL_LENGTH))
        if short.size:
            raise BadInput(
                f"normals must have non-zero length, row {int(short[0]) + 1} (1-based) is {nrm[short[0]].tolist()}"
            )
        columns += _NORMAL
        parts.append(nrm)
    if force is not None:
        f = as_array(force, "force", (n,), f"an ({n},) array (newtons)")
        negative = np.flatnonzero(f < 0)
        if negative.size:
            raise BadInput(
                f"force must be ≥ 0 newtons, row {int(negative[0]) + 1} (1-based) is {float(f[negative[0]])}"
            )
        columns.append(_FORCE)
        parts.append(f[:, None])
    table = np.hstack(parts) if n else np.empty((0, len(columns)))
    free_pts = np.empty((0, 3))
    if free is not None:
        free_pts = as_array(free, "free", (None, 3), "a (K, 3) array (metres)")
    blank = [""] * (len(columns) - len(_POS))  # a free row's normal and force cells
    if len(free_pts):
        columns.append(_CONTACT)

    def write(fh: IO[str]) -> None:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        mark = ["1"] if len(free_pts) else []
        for r in table.tolist():
            w.writerow([repr(v) for v in r] + mark)
        for r in free_pts.tolist():
            w.writerow([repr(v) for v in r] + blank + ["0"])

    return atomic_write(path, write)
