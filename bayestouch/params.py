"""Parameter files: TOML tables in ``models/`` where every constant carries its unit and its source.

A constant is written as an inline table::

    [wire]
    diameter = { value = 100e-6, unit = "m", source = "Dynalloy F1140" }

:func:`read_section` checks that a section has exactly the expected names, that each unit is the one
the code uses (SI), that each value is a finite number inside its allowed range and that a source is
given; anything else raises :class:`~bayestouch.errors.BadInput` with one line naming the file, the
field and the expected form. :func:`build` turns a section into a frozen NamedTuple of floats (a JAX
pytree) in one call.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, NamedTuple

from bayestouch.errors import BadInput, file_problem

__all__ = ["Spec", "read_toml", "read_section", "build", "MODELS"]

_HERE = Path(__file__).resolve().parent
#: the folder of shipped parameter files: ``models/`` at the top of a checkout (an editable install), or the package
#: data ``bayestouch/models`` of an installed wheel (pyproject maps one onto the other)
MODELS = _HERE / "models" if (_HERE / "models" / "finger.toml").is_file() else _HERE.parent / "models"


class Spec(NamedTuple):
    """What a parameter must look like: its SI ``unit`` string and an allowed closed range."""

    unit: str
    lo: float = -math.inf
    hi: float = math.inf


def read_toml(path, kind: str = "parameter file", example: str = "models/finger.toml") -> dict[str, Any]:
    """Parse a TOML file; a missing or malformed file is a one-line :class:`BadInput`.

    ``kind`` and ``example`` name the file in the message ("object file …, expected a TOML file such as
    models/objects/egg.toml"). A leading UTF-8 byte-order mark (as some Windows editors save) is dropped, as the
    CSV and JSON readers drop it; TOML itself does not allow one.
    """
    p = Path(path)
    if problem := file_problem(p):
        raise BadInput(f"{kind} {p}: {problem} (expected a TOML file such as {example})")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise BadInput(f"{p}: not valid TOML ({str(e).splitlines()[0]})") from None


def read_section(doc: dict, section: str, specs: dict[str, Spec], where: str = "parameters") -> dict[str, float]:
    """Validate one ``[section]`` of a parsed parameter file.

    Parameters
    ----------
    doc : dict
        Parsed TOML.
    section : str
        Table name (dots for nested tables, e.g. ``"taxel.noise"``).
    specs : dict of str → Spec
        Every expected constant with its unit and range.
    where : str
        File name for messages.

    Returns
    -------
    dict of str → float
    """
    tab: Any = doc
    for part in section.split("."):
        tab = tab.get(part) if isinstance(tab, dict) else None
    if not isinstance(tab, dict):
        raise BadInput(f"{where}: missing table [{section}] (expected the constants {', '.join(specs)})")
    unknown = sorted(set(tab) - set(specs))
    if unknown:
        raise BadInput(f"{where} [{section}]: unknown constant(s) {', '.join(unknown)}; expected {', '.join(specs)}")
    out = {}
    for name, spec in specs.items():
        field = f"{where} [{section}] {name}"
        entry = tab.get(name)
        if entry is None:
            raise BadInput(f'{field}: missing; expected {{ value = …, unit = "{spec.unit}", source = "…" }}')
        if not isinstance(entry, dict):
            raise BadInput(
                f'{field}: expected an inline table {{ value = …, unit = "{spec.unit}", source = "…" }}, got {entry!r}'
            )
        v = entry.get("value")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise BadInput(f"{field}: value must be a finite number, got {v!r}")
        unit = entry.get("unit")
        if unit != spec.unit:
            raise BadInput(f'{field}: unit must be "{spec.unit}" (SI), got {unit!r}')
        if not isinstance(entry.get("source"), str) or not entry["source"].strip():
            raise BadInput(f"{field}: needs a source (paper, datasheet or 'assumption: …')")
        if not spec.lo <= v <= spec.hi:
            raise BadInput(f"{field}: {v:g} {unit} is outside the allowed range [{spec.lo:g}, {spec.hi:g}]")
        out[name] = float(v)
    return out


def build(cls, path, section: str, specs: dict[str, Spec]):
    """Read ``[section]`` of the TOML file ``path`` into the NamedTuple class ``cls`` (fields = specs)."""
    doc = read_toml(path)
    vals = read_section(doc, section, specs, str(path))
    return cls(**vals)
