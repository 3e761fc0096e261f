"""The pose-law file: what a bending calibration (``bayestouch device calibrate-bending``) learned about one
finger's pad-pose error while it holds its currents, for the explorations it drives (``explore --pose-law``).

TOML, SI units (the law and its symbols: :mod:`bayestouch.inference.held_law`)::

    [pose_law]
    format = 1
    object = "sphere.toml"        # the known object the finger touched
    finger = "..."                # the unit, where its firmware names one
    contacts = 120
    residual_rms_m = 0.00026      # the contacts' RMS distance from the object, corrected by the law's mean
    residual_rms_prior_m = 0.0021 # ... with the nominal constants alone
    software = "bayestouch 0.1.0"

    [law]
    hold_currents_A = [0.15, 0.05, 0.05]
    grid_s = [0.0, 0.05, ...]     # (N,) times since a stroke's start
    mean_m = [[x, y, z], ...]     # (N, 3) finger-base frame
    lead_m = [[[...]]]            # (N, 3, r) leading components
    remainder_m = [[[...]]]       # (K, N, 3) the drawn fingers' remainders
    z_mean = [...]                # (r,) posterior of the components' coordinates
    z_chol = [[...]]              # (r, r) lower Cholesky factor of their covariance
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from bayestouch.errors import BadInput, file_problem
from bayestouch.inference.held_law import HeldLaw
from bayestouch.io.files import toml_array, toml_value, write_text
from bayestouch.params import read_toml

__all__ = ["POSE_LAW_FORMAT", "write_pose_law", "read_pose_law", "pose_law_text"]

#: version of the layout written by :func:`write_pose_law`
POSE_LAW_FORMAT = 1
#: the law's arrays: TOML key, HeldLaw field, dimensions
_ARRAYS = (
    ("hold_currents_A", "hold_currents", 1),
    ("grid_s", "grid", 1),
    ("mean_m", "mean", 2),
    ("lead_m", "lead", 3),
    ("remainder_m", "remainder", 3),
    ("z_mean", "z_mean", 1),
    ("z_chol", "z_chol", 2),
)
_HEAD_KEYS = ("format", "object", "finger", "contacts", "residual_rms_m", "residual_rms_prior_m", "software")


def pose_law_text(law: HeldLaw, info: dict) -> str:
    """The TOML text of ``law`` with the provenance ``info`` (keys of the module docstring's ``[pose_law]``),
    checked as :func:`read_pose_law` checks a file (:class:`BadInput`)."""
    head = {"format": POSE_LAW_FORMAT, **{k: v for k, v in info.items() if k in _HEAD_KEYS and k != "format"}}
    lines = [
        "# bayestouch pose-law file: a finger's held pad-pose error law from a bending calibration (SI units)",
        "[pose_law]",
        *(f"{k} = {toml_value(v)}" for k, v in head.items()),
        "",
        "[law]",
        *(f"{key} = {toml_array(getattr(law, field))}" for key, field, _ in _ARRAYS),
        "",
    ]
    text = "\n".join(lines)
    _law_of(tomllib.loads(text), "pose law")
    return text


def write_pose_law(path, law: HeldLaw, info: dict) -> Path:
    """Write ``law`` and its provenance to ``path`` (TOML, atomically)."""
    return write_text(path, pose_law_text(law, info))


def read_pose_law(path) -> tuple[HeldLaw, dict]:
    """The law and the provenance of a pose-law file (:func:`write_pose_law`).

    Raises
    ------
    BadInput
        A missing or unreadable file, or a field that is absent, of the wrong shape or out of range (one line).
    """
    p = Path(path)
    where = f"pose-law file {p}"
    if problem := file_problem(p):
        raise BadInput(f"{where}: {problem}; expected the TOML written by `bayestouch device calibrate-bending`")
    return _law_of(read_toml(p, "pose-law file", "LAW.toml from `bayestouch device calibrate-bending`"), where)


def _law_of(doc: dict, where: str) -> tuple[HeldLaw, dict]:
    head, tab = doc.get("pose_law"), doc.get("law")
    if not isinstance(head, dict) or not isinstance(tab, dict):
        raise BadInput(f"{where}: expected the tables [pose_law] and [law] written by `device calibrate-bending`")
    if head.get("format") != POSE_LAW_FORMAT:
        raise BadInput(f"{where}: [pose_law] format is {head.get('format')!r}, expected {POSE_LAW_FORMAT}")
    arrays = {}
    for key, field, ndim in _ARRAYS:
        v = tab.get(key)
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            a = np.zeros(0)
        if v is None or a.ndim != ndim or a.size == 0 or not np.all(np.isfinite(a)):
            raise BadInput(f"{where}: [law] {key} must be a finite {ndim}-dimensional array of numbers")
        arrays[field] = a
    g, mu, lead, rem, zm, zc = (arrays[k] for k in ("grid", "mean", "lead", "remainder", "z_mean", "z_chol"))
    N, r = len(g), len(zm)
    if arrays["hold_currents"].shape != (3,) or np.any(arrays["hold_currents"] < 0):
        raise BadInput(f"{where}: [law] hold_currents_A must be three currents ≥ 0 in amperes")
    if g[0] != 0 or np.any(np.diff(g) <= 0):
        raise BadInput(f"{where}: [law] grid_s must rise from 0 s")
    shapes = {"mean_m": (mu.shape, (N, 3)), "lead_m": (lead.shape, (N, 3, r)), "z_chol": (zc.shape, (r, r))}
    if rem.ndim != 3 or rem.shape[1:] != (N, 3):
        raise BadInput(f"{where}: [law] remainder_m must have shape (K, {N}, 3), got {rem.shape}")
    for key, (got, want) in shapes.items():
        if got != want:
            raise BadInput(f"{where}: [law] {key} must have shape {want} (the grid's and z_mean's), got {got}")
    if np.any(np.triu(zc, 1) != 0) or np.any(np.diag(zc) <= 0):
        raise BadInput(f"{where}: [law] z_chol must be lower triangular with a positive diagonal")
    for k in ("residual_rms_m", "residual_rms_prior_m"):
        v = head.get(k)
        if v is not None and not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise BadInput(f"{where}: [pose_law] {k} must be a distance ≥ 0 in metres, got {v!r}")
    info = {k: v for k, v in head.items() if k != "format"}
    return HeldLaw(arrays["hold_currents"], g, mu, lead, rem, zm, zc), info
