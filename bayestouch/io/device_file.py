"""The device file: what ``bayestouch calibrate`` learned about one finger, for the fits of its recordings.

A real finger's taxels differ from one another (the ZnO barrier heights scatter, so each taxel's current carries
its own fixed-pattern gain) and the device sends nothing that says by how much. A calibration on a known object
estimates each taxel's log-gain with its standard error; a fit given the file (``fit --calibration DEVICE.toml``)
divides the gains out and marginalises what remains of each taxel's log-gain with that standard error, so the
device's remaining uncertainty reaches the shape posterior. The file is TOML::

    [device]
    format = 1
    taxels = 256
    mode = "empirical"            # taxel response mode of the calibration recording
    noise_scale = 1.3             # residual sd / modelled read-out sd at the calibration (dimensionless)
    object = "sphere"
    finger = "virtual finger 3"   # the finger calibrated (the recording's ``finger`` attribute), where it names one
    recording = "sha256 of the recording's arrays"
    strokes = 2
    frames = 202
    software = "bayestouch 0.1.0"

    [gains]
    log_gain = [...]              # ln of each taxel's gain (dimensionless), reference taxels' median 0
    log_gain_sd = [...]           # its standard error

    [response]
    scale = 1.12                  # the taxels' common response to pressure over the models' (Δ ln I factor)
    scale_sd = 0.004              # its standard error

The response factor multiplies every taxel's Δ ln I (empirical S_p, or the physics mode's load fraction and skin
modulus, which only act through it); strokes of one constant pressure leave it to its prior, and the file then
has no ``[response]`` table.

Log-gains are relative: a common factor of every taxel is the reference row's and cancels in the fit's
reference-drift correction.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.errors import BadInput, file_problem
from bayestouch.io.files import toml_array, toml_value, write_text
from bayestouch.params import read_toml

__all__ = [
    "DEVICE_FORMAT",
    "DeviceCalibration",
    "write_device_file",
    "read_device_file",
    "check_same_finger",
    "device_calibration",
    "device_file_text",
]

#: version of the device-file layout written by :func:`write_device_file`
DEVICE_FORMAT = 1
_MODES = ("physics", "empirical")


class DeviceCalibration(NamedTuple):
    """One finger's calibration.

    log_gain : (N,) float
        ln of each taxel's fixed-pattern gain (dimensionless), relative: the reference taxels' median is 0.
    log_gain_sd : (N,) float
        Standard error of ``log_gain`` (> 0).
    noise_scale : float
        Residual sd over the modelled read-out sd at the calibration (dimensionless, within the fit's prior box
        [0.1, 1e4] of ``models/priors.toml``).
    mode : str
        Taxel response mode of the calibration recording ("physics" or "empirical").
    info : dict
        Provenance: object, recording digest, strokes, frames, software (strings and integers).
    response_scale : float
        The taxels' common Δ ln I over the models' (dimensionless, > 0).
    response_scale_sd : float or None
        Its standard error; None: not calibrated (the fit keeps its prior).
    """

    log_gain: np.ndarray
    log_gain_sd: np.ndarray
    noise_scale: float
    mode: str
    info: dict
    response_scale: float = 1.0
    response_scale_sd: float | None = None


def write_device_file(path, cal: DeviceCalibration) -> Path:
    """Write ``cal`` to ``path`` (TOML, atomically; the module docstring gives the layout); refused
    (:class:`BadInput`) when :func:`read_device_file` would refuse it."""
    return write_text(path, device_file_text(cal))


def device_file_text(cal: DeviceCalibration) -> str:
    """The TOML text of ``cal``, checked as :func:`read_device_file` checks a file (:class:`BadInput`)."""
    head = {
        "format": DEVICE_FORMAT,
        "taxels": int(np.size(cal.log_gain)),
        "mode": cal.mode,
        "noise_scale": float(cal.noise_scale),
        **{k: v for k, v in cal.info.items() if isinstance(v, str | int | float) and k not in ("format", "taxels")},
    }
    lines = [
        "# bayestouch device file: per-taxel log-gains of one finger from `bayestouch calibrate` (dimensionless)",
        "[device]",
        *(f"{k} = {toml_value(v)}" for k, v in head.items()),
        "",
        "[gains]",
        f"log_gain = {toml_array(cal.log_gain)}",
        f"log_gain_sd = {toml_array(cal.log_gain_sd)}",
        "",
    ]
    if cal.response_scale_sd is not None:
        lines += [
            "[response]",
            f"scale = {float(cal.response_scale)!r}",
            f"scale_sd = {float(cal.response_scale_sd)!r}",
            "",
        ]
    text = "\n".join(lines)
    # what is written is what read_device_file accepts: a calibration the data do not determine (a taxel whose gain
    # has no spread, a zero noise scale) is refused here rather than written for `fit` to refuse later
    device_calibration(tomllib.loads(text), "calibration")
    return text


#: the range of the [response] entries: a sensitivity scale (relative to the models' constants) and its sd
_RESPONSE_RANGE = {"scale": (1e-3, 1e3), "scale_sd": (1e-6, 10.0)}
#: the keys each table of a device file may hold (anything else, a misspelt ``[responce]`` say, is refused rather
#: than ignored): [device] holds the calibration's mode and noise scale and the provenance that
#: :func:`bayestouch.inference.raw.calibrate.calibrate_device` records
_KNOWN = {
    "device": (
        "format",
        "taxels",
        "mode",
        "noise_scale",
        "object",
        "recording",
        "strokes",
        "frames",
        "software",
        "response",
        "finger",
    ),
    "gains": ("log_gain", "log_gain_sd"),
    "response": ("scale", "scale_sd"),
}


def _noise_scale_range() -> tuple[float, float]:
    """The box of the fit's noise multiplier k, ``[raw_priors]`` noise_scale_min and noise_scale_max of
    ``models/priors.toml`` (dimensionless): a device file's noise scale outside it is one no fit can hold."""
    # imported here: bayestouch.inference.raw imports this module
    from bayestouch.inference.raw.priors import load_raw_priors

    pri = load_raw_priors()
    return float(pri["noise_scale_min"]), float(pri["noise_scale_max"])


def _check_known(doc: dict, where: str) -> None:
    """Refuse (:class:`BadInput`, one line) a table or key of a parsed device file that :data:`_KNOWN` lacks."""
    tables = [f"[{t}]" for t in _KNOWN]
    unknown = [f"[{k}]" if isinstance(v, dict) else k for k, v in doc.items() if k not in _KNOWN]
    if unknown:
        raise BadInput(
            f"{where}: unknown table(s) {', '.join(unknown)}; expected {', '.join(tables)} (as `bayestouch "
            "calibrate` writes them)"
        )
    for table, keys in _KNOWN.items():
        tab = doc.get(table)
        extra = [k for k in tab if k not in keys] if isinstance(tab, dict) else []
        if extra:
            raise BadInput(f"{where}: [{table}] unknown key(s) {', '.join(extra)}; expected {', '.join(keys)}")


def check_same_finger(
    calibration: DeviceCalibration | None, finger, source: str, *, field: str = "calibration", note: str = ""
) -> None:
    """Refuse (:class:`BadInput`) a device file calibrated on another finger than ``finger`` (the name a recording
    carries, or the simulated finger's), where both name one (a blank name names none).

    ``source`` says whose finger ``finger`` is ("REC.nc was recorded by"), ``field`` names the device file in the
    message and ``note`` follows the name (" (--seed 0)")."""
    calibrated = str((calibration.info.get("finger") if calibration is not None else None) or "").strip()
    actual = str(finger or "").strip()
    if calibrated and actual and calibrated != actual:
        raise BadInput(
            f"{field}: made on {calibrated}; {source} {actual}{note} (each finger's taxel gains are its own: expected "
            "the device file calibrated on that finger)"
        )


def read_device_file(path, n_taxels: int | None = None) -> DeviceCalibration:
    """Read a device file written by :func:`write_device_file`.

    Parameters
    ----------
    path : path
    n_taxels : int, optional
        The finger's taxel count; a file for another array is refused.

    Raises
    ------
    BadInput
        A missing or unreadable file, a table or key the layout does not have, or a field that is absent or out of
        range (one line naming it); the noise scale must lie in the fit's prior box of ``models/priors.toml``.
    """
    p = Path(path)
    where = f"device file {p}"
    if problem := file_problem(p):
        raise BadInput(f"{where}: {problem}; expected the TOML written by `bayestouch calibrate`")
    doc = read_toml(p, "device file", "DEVICE.toml from `bayestouch calibrate`")
    cal = device_calibration(doc, where)
    if n_taxels is not None and np.size(cal.log_gain) != int(n_taxels):
        raise BadInput(f"{where}: calibrates {np.size(cal.log_gain)} taxels, but the finger has {int(n_taxels)}")
    return cal


def device_calibration(doc: dict, where: str) -> DeviceCalibration:
    """The :class:`DeviceCalibration` of a parsed device file ``doc``; raises :class:`BadInput` (``where`` named)
    on a table or key the layout does not have, or a field that is absent or out of range."""
    dev, gains = doc.get("device"), doc.get("gains")
    if not isinstance(dev, dict) or not isinstance(gains, dict):
        raise BadInput(f"{where}: expected the tables [device] and [gains] written by `bayestouch calibrate`")
    _check_known(doc, where)
    if dev.get("format") != DEVICE_FORMAT:
        raise BadInput(f"{where}: [device] format is {dev.get('format')!r}, expected {DEVICE_FORMAT}")
    mode = dev.get("mode")
    if mode not in _MODES:
        raise BadInput(f"{where}: [device] mode is {mode!r}, expected one of {_MODES}")
    k = dev.get("noise_scale")
    if not isinstance(k, int | float) or isinstance(k, bool) or not (math.isfinite(k) and k > 0):
        # 0 would declare the read-out noiseless: a likelihood of unbounded precision
        raise BadInput(f"{where}: [device] noise_scale must be a finite number > 0, got {k!r}")
    lo, hi = _noise_scale_range()
    if not lo <= k <= hi:
        raise BadInput(
            f"{where}: [device] noise_scale must be in [{lo:g}, {hi:g}] (the fit's prior box for the residual sd over "
            f"the modelled read-out sd, models/priors.toml), got {k!r}"
        )
    arrays = {}
    for name in ("log_gain", "log_gain_sd"):
        v = gains.get(name)
        if (
            not isinstance(v, list)
            or not v
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        ):
            raise BadInput(f"{where}: [gains] {name} must be a list of numbers (one per taxel)")
        a = np.asarray(v, float)
        if not np.all(np.isfinite(a)):
            raise BadInput(f"{where}: [gains] {name} holds NaN or infinite values; expected finite numbers")
        arrays[name] = a
    lg, sd = arrays["log_gain"], arrays["log_gain_sd"]
    if sd.shape != lg.shape:
        raise BadInput(
            f"{where}: [gains] log_gain has {lg.size} values and log_gain_sd {sd.size}; expected one of each per taxel"
        )
    if not np.all(sd > 0):
        raise BadInput(
            f"{where}: [gains] log_gain_sd must be positive for every taxel ({int(np.sum(~(sd > 0)))} are not: "
            "readings without spread between strokes do not determine a gain)"
        )
    if np.any(np.abs(lg) > 20):
        raise BadInput(f"{where}: [gains] log_gain has |values| over 20 (gains beyond e^±20); expected ln of a gain")
    n = dev.get("taxels")
    if n is not None and n != lg.size:  # a header that disagrees with its own lists: an edited or mixed-up file
        raise BadInput(f"{where}: [device] taxels is {n!r}, but [gains] holds {lg.size} values per list")
    resp, scale, scale_sd = doc.get("response"), 1.0, None
    if resp is not None:
        if not isinstance(resp, dict):
            raise BadInput(f"{where}: [response] must be a table with scale and scale_sd")
        vals = []
        for name in ("scale", "scale_sd"):
            v = resp.get(name)
            lo, hi = _RESPONSE_RANGE[name]
            if not isinstance(v, int | float) or isinstance(v, bool) or not (math.isfinite(v) and lo <= v <= hi):
                raise BadInput(f"{where}: [response] {name} must be a number in [{lo:g}, {hi:g}], got {v!r}")
            vals.append(float(v))
        scale, scale_sd = vals
    info = {k: v for k, v in dev.items() if k not in ("mode", "noise_scale")}
    return DeviceCalibration(lg, sd, float(k), str(mode), info, scale, scale_sd)
