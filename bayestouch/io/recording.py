"""Recordings: simulated (or measured) strokes as netCDF files via xarray, with units on every variable.

Layout: dimension ``frame`` (all strokes one after another), ``taxel``, ``wire``, ``xyz``, ``stroke``; the
coordinates ``time`` s and ``stroke_index`` along ``frame`` and ``taxel_u``/``taxel_v`` m (pad coordinates) along
``taxel`` (so ``ds.taxel_current.isel(taxel=0).plot(x="time")`` has a time axis), with CF's global
``Conventions``. Files written before these were coordinates are read the same way (:func:`read_recording`).
Variables (SI units in the ``units`` attribute, UDUNITS spelling): ``taxel_current`` A
(measured), ``taxel_current_clean`` A (noise-free, simulations only), ``pressure`` Pa, ``contact_force`` N,
``contact_point`` m, ``contact_normal`` 1, ``wire_current`` A, ``wire_temperature`` K,
``skin_temperature`` K, ``finger_tip_position`` m (finger-base frame), ``finger_curvature`` m-1,
``taxel_reference`` (1 = unloaded reference taxel),
``stroke_depth`` m.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from bayestouch.errors import BadInput, check_bool, check_path
from bayestouch.io.files import atomic_path, utc_stamp

__all__ = [
    "MAX_FRAMES",
    "UNITS",
    "PHYSICAL_RANGES",
    "COORDINATES",
    "CONVENTIONS",
    "DIMS",
    "build_dataset",
    "with_coordinates",
    "write_recording",
    "read_recording",
    "check_recording",
]

#: most frames of one simulated recording (a frame holds every taxel's current and the finger's state: 200,000
#: frames of a 16 × 16 skin are ~0.5 GB in memory)
MAX_FRAMES = 200_000
#: variables stored as coordinates (along ``frame`` and ``taxel``)
COORDINATES = ("time", "stroke_index", "taxel_u", "taxel_v")
#: the CF version the files follow (global attribute ``Conventions``)
CONVENTIONS = "CF-1.10"

UNITS = {
    "time": "s",
    "stroke_index": "1",
    "taxel_current": "A",
    "taxel_current_clean": "A",
    "pressure": "Pa",
    "contact_force": "N",
    "friction_force": "N",
    "pressing_depth": "m",
    "contact_point": "m",
    "contact_normal": "1",
    "wire_current": "A",
    "wire_temperature": "K",
    "skin_temperature": "K",
    "finger_tip_position": "m",
    "finger_curvature": "m-1",
    "taxel_u": "m",
    "taxel_v": "m",
    "taxel_reference": "1",
    "stroke_depth": "m",
}

DESCRIPTIONS = {
    "taxel_current": "measured taxel current (lagged, noisy, quantised)",
    "taxel_current_clean": "taxel current before noise (simulation only)",
    "pressure": "contact pressure at each taxel",
    "contact_force": "normal contact force of the pad",
    "pressing_depth": "depth of the pad centre below the surface (imposed, or solved for the force)",
    "friction_force": "tangential force resisting the motion (eq. 20, smooth Coulomb cap)",
    "contact_point": "commanded contact point of the pad centre on the true surface",
    "contact_normal": "outward surface normal at the contact point",
    "wire_current": "current in each NiTi wire",
    "wire_temperature": "temperature of each NiTi wire",
    "skin_temperature": "temperature of the skin at the taxels",
    "finger_tip_position": "fingertip position in the finger-base frame (constant-curvature model)",
    "finger_curvature": "rod curvature vector (u_x, u_y)",
    "taxel_reference": "1 for unloaded reference taxels used for drift compensation",
    "stroke_depth": "pressing depth of each stroke",
}


#: the dimensions of each variable of a recording, in order (a variable stored another way round is refused by
#: :func:`check_recording`)
DIMS = {
    "time": ("frame",),
    "stroke_index": ("frame",),
    "taxel_current": ("frame", "taxel"),
    "taxel_current_clean": ("frame", "taxel"),
    "pressure": ("frame", "taxel"),
    "contact_force": ("frame",),
    "friction_force": ("frame",),
    "pressing_depth": ("frame",),
    "contact_point": ("frame", "xyz"),
    "contact_normal": ("frame", "xyz"),
    "wire_current": ("frame", "wire"),
    "wire_temperature": ("frame", "wire"),
    "skin_temperature": ("frame",),
    "finger_tip_position": ("frame", "xyz"),
    "finger_curvature": ("frame", "uv"),
    "taxel_u": ("taxel",),
    "taxel_v": ("taxel",),
    "taxel_reference": ("taxel",),
    "stroke_depth": ("stroke",),
}
_DIM_NAMES = {d for dims in DIMS.values() for d in dims}


def build_dataset(frames: dict[str, np.ndarray], taxel_u, taxel_v, reference, depths, attrs: dict):
    """An ``xarray.Dataset`` from per-frame arrays (keys of :data:`UNITS`, first axis = frame)."""
    data = {}
    for k, v in frames.items():
        data[k] = xr.Variable(DIMS[k], np.asarray(v), {"units": UNITS[k], "long_name": DESCRIPTIONS.get(k, k)})
    data["taxel_u"] = xr.Variable(("taxel",), np.asarray(taxel_u), {"units": "m"})
    data["taxel_v"] = xr.Variable(("taxel",), np.asarray(taxel_v), {"units": "m"})
    data["taxel_reference"] = xr.Variable(
        ("taxel",), np.asarray(reference, dtype=np.int8), {"units": "1", "long_name": DESCRIPTIONS["taxel_reference"]}
    )
    data["stroke_depth"] = xr.Variable(
        ("stroke",), np.asarray(depths, float), {"units": "m", "long_name": DESCRIPTIONS["stroke_depth"]}
    )
    coords = {"xyz": ["x", "y", "z"], "wire": [1, 2, 3], "uv": ["u_x", "u_y"]}
    ds = xr.Dataset(data, coords=coords, attrs={"Conventions": CONVENTIONS, **{k: str(v) for k, v in attrs.items()}})
    return with_coordinates(ds)


def with_coordinates(ds):
    """``ds`` with the :data:`COORDINATES` it holds as coordinates (files written when they were variables)."""
    return ds.set_coords([k for k in COORDINATES if k in ds.data_vars])


def write_recording(ds, path, *, overwrite: bool = False, replace: bool | None = None) -> Path:
    """Write a dataset as netCDF (h5netcdf engine) atomically (:func:`bayestouch.io.files.atomic_path`).

    Parameters
    ----------
    ds : xarray.Dataset
    path : path
    overwrite : bool
        Replace a recording already at ``path`` (only once the new one is complete). Without it a file already at
        ``path``, or one that appears there while this one is written, is kept and this recording written beside
        it as ``NAME.<UTC time>.nc``, with a :class:`BadInput` naming both: never replaced by accident, never
        lost.
    replace : bool, optional
        The former name of ``overwrite`` (kept for scripts that pass it).

    Returns
    -------
    pathlib.Path
    """
    check_path(path, "path")
    path = Path(path)
    if path.is_dir():  # a folder: the recording went beside it as FOLDER.<time> (tenth review)
        raise BadInput(f"{path} is a folder; expected a recording file name ending in .nc")
    if not hasattr(ds, "to_netcdf"):
        raise BadInput(f"ds: expected an xarray.Dataset (a recording), got {type(ds).__name__}")
    check_bool(overwrite, "overwrite")  # "no" is truthy: taken as True it replaced the recording there
    if replace is not None:
        check_bool(replace, "replace")
    overwrite = bool(overwrite if replace is None else replace)
    if not overwrite and path.exists():
        # neither replaced nor lost: this recording goes beside the one there (a device run's strokes are data)
        kept = path.with_name(f"{path.stem}.{utc_stamp()}{path.suffix}")
        with atomic_path(kept, replace=False) as tmp:
            ds.to_netcdf(tmp, engine="h5netcdf")
        raise BadInput(
            f"{path} already exists and is kept; this recording was written to {kept} (pass overwrite=True to "
            "replace it)"
        )
    # atomic_path: a temporary file of the usual umask-derived mode (mkstemp's 0600 made recordings unreadable to
    # the group where every other output is not), fsynced before it replaces the old file
    with atomic_path(path, replace=overwrite) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    return path


def read_recording(path):
    """Open a recording (``xarray.Dataset``, loaded into memory).

    Raises
    ------
    BadInput
        ``path`` is not a path, is missing, a folder, or not a netCDF (HDF5) file.
    """
    check_path(path, "path")
    p = Path(path)
    if not p.exists():
        raise BadInput(f"{p}: no such recording")
    if p.is_dir():
        raise BadInput(f"{p} is a folder; expected a recording (.nc) file")
    try:
        with xr.open_dataset(p, engine="h5netcdf") as ds:
            return with_coordinates(ds.load())
    except (OSError, ValueError) as e:
        raise BadInput(f"{p}: not a recording (a netCDF file written by bayestouch): {e}") from None


#: the physically possible range of each recorded quantity (SI units): a value outside, or a non-finite one, is a
#: damaged recording, not a measurement. Taxel currents are ~1e-8 to 1e-6 A (models/taxels.toml); a non-zero
#: magnitude below 1 fA is beneath any read-out's resolution (a float reinterpreted from damaged bytes).
PHYSICAL_RANGES = {
    "time": (-1e6, 1e6),
    "taxel_current": (-1e-2, 1e-2),
    "contact_force": (0.0, 1e3),
    "friction_force": (-1e3, 1e3),
    "pressing_depth": (-0.1, 0.1),
    "contact_point": (-2.0, 2.0),  # as contact files (io.contacts.MM_MAX_ABS_M): beyond, millimetres
    "wire_current": (-10.0, 10.0),
    "wire_temperature": (200.0, 1000.0),  # −73 °C to 727 °C: NiTi degrades far below the top
    "skin_temperature": (200.0, 500.0),
    "finger_tip_position": (-2.0, 2.0),
    "stroke_depth": (-0.1, 0.1),
}
#: smallest non-zero taxel current magnitude a read-out can report, A
CURRENT_FLOOR_A = 1e-15


def check_recording(ds, where: str = "recording") -> None:
    """Raise :class:`~bayestouch.errors.BadInput` naming the first variable of ``ds`` whose dimensions are not those
    of :data:`DIMS` (e.g. ``taxel_current`` stored (taxel, frame)), or that holds a non-finite value, a value outside
    :data:`PHYSICAL_RANGES` or (taxel currents) a non-zero magnitude below :data:`CURRENT_FLOOR_A`, with how many
    values and the first frame; ``where`` names the recording.

    A variable whose dimensions bear none of the recording's names (a file written by other software) is left to
    the shape checks of its reader."""
    for name in list(ds.variables):
        dims, want = tuple(str(d) for d in ds[name].dims), DIMS.get(str(name))
        if want is not None and dims != want and set(dims) & _DIM_NAMES:
            turned = " (transposed?)" if sorted(dims) == sorted(want) else ""
            raise BadInput(
                f"{where}: variable '{name}' has dimensions {dims}; expected {want}{turned} as `bayestouch "
                "simulate` writes it"
            )
    for name in list(ds.variables):
        unit = ds[name].attrs.get("units")
        if name in UNITS and unit is not None and str(unit) != UNITS[name]:
            raise BadInput(f"{where}: '{name}' is in {unit!r}; expected {UNITS[name]!r} (recordings are in SI units)")
    for name, (lo, hi) in PHYSICAL_RANGES.items():
        if name not in ds:
            continue
        v = np.asarray(ds[name].values, dtype=float)
        unit = UNITS.get(name, "")
        bad = ~np.isfinite(v)
        what = "non-finite"
        if not bad.any():
            bad = (v < lo) | (v > hi)
            what = f"outside [{lo:g}, {hi:g}] {unit}"
        if not bad.any() and name == "taxel_current":
            bad = (v != 0) & (np.abs(v) < CURRENT_FLOOR_A)
            what = f"non-zero below {CURRENT_FLOOR_A:g} A (below any read-out's resolution)"
        if bad.any():
            first = tuple(int(i) for i in np.argwhere(bad)[0])
            raise BadInput(
                f"{where}: '{name}' holds {int(bad.sum())} {what} value(s) (first at index {first}): a damaged "
                "recording, not a measurement"
            )
    if "taxel_current" in ds:
        cur = np.asarray(ds["taxel_current"].values, dtype=float)
        if cur.ndim == 2 and cur.shape[0] >= 2 and cur.shape[1] and np.all(np.ptp(cur, axis=0) == 0):
            raise BadInput(
                f"{where}: 'taxel_current' never changes: every taxel reads the same value in all {cur.shape[0]} "
                f"frames (e.g. {cur[0, 0]:g} A); a dead or frozen read-out carries no signal"
            )
        negative = np.mean(cur < 0) if cur.size else 0
        if negative > 0.5:
            raise BadInput(
                f"{where}: 'taxel_current' is negative in {negative:.0%} of its values; the taxels' drain "
                "currents are positive (a sign flipped in the read-out?)"
            )
    if "contact_normal" in ds:
        short = ~(np.linalg.norm(np.asarray(ds["contact_normal"].values, dtype=float), axis=-1) > 0.5)
        if short.any():
            raise BadInput(
                f"{where}: 'contact_normal' has {int(short.sum())} vector(s) that are not unit normals "
                f"(first at frame {int(np.argmax(short))}); expected unit outward normals"
            )
    if "stroke_index" in ds and ds["stroke_index"].ndim == 1 and ds["stroke_index"].size:
        k = np.asarray(ds["stroke_index"].values)
        runs = k[np.r_[True, k[1:] != k[:-1]]]
        first = np.zeros(len(runs), bool)
        first[np.unique(runs, return_index=True)[1]] = True
        if not first.all():  # a run of a stroke seen before (linear: a hostile file may hold a run per frame)
            again = runs[np.argmin(first)]
            raise BadInput(
                f"{where}: 'stroke_index' {again} comes back after other strokes; expected each stroke's frames "
                "one after another (contiguous)"
            )
    if "time" in ds and "stroke_index" in ds:
        t = np.asarray(ds["time"].values, dtype=float)
        k = np.asarray(ds["stroke_index"].values)
        stalled = (k[1:] == k[:-1]) & ~(np.diff(t) > 0)
        if stalled.any():
            i = int(np.argmax(stalled)) + 1
            raise BadInput(
                f"{where}: 'time' does not increase within stroke {int(k[i])} (frame {i}: {t[i - 1]:g} s then "
                f"{t[i]:g} s); expected strictly increasing times within each stroke"
            )
