"""The raw-current level's data: a recording (:mod:`bayestouch.io.recording`) read into :class:`RawData` — the
known taxel positions (m) of the selected frames, the gain- and drift-corrected ln I (F, M) of the selected taxels
and their modelled noise sd — with the finger that recorded it. The model and its reductions are described in
``docs/raw_model.md``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput, file_problem, shown
from bayestouch.inference.raw.priors import RESPONSE_SCALE_SD
from bayestouch.io.device_file import DeviceCalibration, check_same_finger
from bayestouch.io.recording import check_recording, read_recording
from bayestouch.params import MODELS
from bayestouch.physics import forward as fw
from bayestouch.physics import noise as nz
from bayestouch.physics import taxel as tx
from bayestouch.physics.virtual import MAX_DEPTH_M, load_finger

__all__ = [
    "RawData",
    "open_recording",
    "check_stroke_selection",
    "need_variable",
    "recording_mode",
    "nominal_log_gain_sd",
    "HostDevice",
    "host_device",
    "unloaded_current",
    "load_raw_data",
    "commanded_points",
    "check_contact_motion",
    "MIN_CONTACT_SPAN_M",
    "MIN_FRAMES",
    "LAYOUT_TOLERANCE_M",
    "FRAME_RATE_RANGE_HZ",
    "frame_interval_problem",
    "MAX_PAD_SPEED",
    "check_taxel_layout",
    "STATIC_FIELDS",
    "split_data",
    "join_data",
    "on_device",
]

#: fewest frames with contact a raw-current fit reads (after --stride): a stride longer than the strokes left
#: one frame, a "fit" of one pad position
MIN_FRAMES = 5
#: largest difference (m) between a recording's taxel_u/taxel_v and the finger model's pad coordinates: the fit
#: places every taxel at the model's coordinates, so a recording of another layout (or order) is refused
LAYOUT_TOLERANCE_M = 1e-6
#: frame rates (Hz, the median within each stroke) a recording may have: generous bounds around any taxel read-out
#: (``simulate --rate`` takes 1 to 2000 Hz); outside, ``time`` is in another unit than seconds (ms: frames 20 s apart)
FRAME_RATE_RANGE_HZ = (0.1, 1e5)
#: fastest mean pad speed (m/s) of a stroke, contact-point path over duration: twenty times the finger's safety limit
#: (5 cm/s, bayestouch.hardware.safety) and a hundred times the paper's 1 cm/s; faster is a time unit mistake
MAX_PAD_SPEED = 1.0


class RawData(NamedTuple):
    """Everything the raw-current likelihood needs (F selected frames, M selected taxels).

    taxel_position : (F, J, 3) float, metres
        World positions of the taxels that may penetrate (within ``contact_radius``; known pad pose).
    temperature : (F,) float, kelvin
        Skin temperature.
    log_current : (F, M) float
        Measured ln(I / 1 A), divided by the fixed-pattern gains and the reference-row common drift.
    noise_sd : (F, M) float
        Modelled standard deviation of ``log_current`` (dimensionless, before the multiplier k).
    start : (F,) bool
        First selected frame of a stroke (the lag restarts at steady state).
    kernel : (M, J) float
        Pressure blur from the J penetrating taxels onto the M modelled ones.
    lag_weights : (3,) float
        (βˢ, 1 − βˢ, w₁) of the coarse-frame lag.
    frames : (F,) int
        Indices of the selected frames in the recording.
    taxels : (M,) int
        Indices of the selected taxels.
    dt : float, seconds
        Interval between selected frames.
    mode : str
        Taxel response mode of the recording ("physics" or "empirical").
    active : (P,) int or None
        Flat indices into the F·J penetrating-taxel slots whose distance is evaluated
        (:func:`~bayestouch.inference.raw.likelihood.prune_clear`); the others are taken to be clear of the surface
        (no penetration). None: every slot.
    baseline : (F, M) float or None
        The model's ln I of the selected taxels at zero pressure (the skin temperature through the lag): Δ ln I of a
        prediction is measured from it.
    response_scale : float
        The taxels' common response factor a on Δ ln I (dimensionless; a calibration's, else 1).
    response_sd : float or None
        Prior sd of a, marginalised in the likelihood; None: a is exact.
    gain_sd : (M,) float or None
        Standard deviation of each selected taxel's remaining log-gain (dimensionless) about the gain divided out of
        ``log_current``: the likelihood marginalises one offset per taxel with this prior sd
        (:func:`~bayestouch.inference.raw.likelihood.taxel_offsets`). None: the gains are known exactly.
    common_var : (F,) float or None
        Variance of the reference row's correction ĉ of each frame (dimensionless): part of ``noise_sd``² but one
        and the same error in every taxel of the frame, which a likelihood may model as such.
    common_cov : (F, F) float or None
        Covariance over frames of that common error (π/2 · the reference taxels' white, 1/f and random-walk
        covariance / their number, within each stroke; de-meaned like ĉ when the reference taxels are).
    unloaded : (F, M) float or None
        The model's current (A) of the selected taxels at zero pressure before the lag: ``baseline`` is its log
        through the lag, recomputed for every sampled lag.
    lag_stride : int
        Recorded frames per selected frame (``dt`` / the recorded interval), for the lag weights of a sampled lag.
    lag_prior : (2,) float or None
        With a range (τ_min, τ_max) s the lag is not the finger's: θ's last column is log τ, sampled, uniform in τ
        over that range, and ``lag_weights`` and ``baseline`` are recomputed from it
        (:func:`~bayestouch.inference.raw.likelihood.at_lag`). None: the lag of ``lag_weights``.
    """

    taxel_position: np.ndarray
    temperature: np.ndarray
    log_current: np.ndarray
    noise_sd: np.ndarray
    start: np.ndarray
    kernel: np.ndarray
    lag_weights: np.ndarray
    frames: np.ndarray
    taxels: np.ndarray
    dt: float
    mode: str
    active: np.ndarray | None = None
    gain_sd: np.ndarray | None = None
    baseline: np.ndarray | None = None
    response_scale: float = 1.0
    response_sd: float | None = None
    common_var: np.ndarray | None = None
    common_cov: np.ndarray | None = None
    unloaded: np.ndarray | None = None
    lag_stride: int = 1
    lag_prior: tuple[float, float] | None = None


#: :class:`RawData`'s fields that are not arrays but shape the computation (the frame interval, the taxel mode, the
#: lag's stride and prior range): static under ``jax.jit`` (:func:`split_data`)
STATIC_FIELDS = ("dt", "mode", "lag_stride", "lag_prior")


def split_data(data: RawData) -> tuple[RawData, tuple]:
    """``data`` as a jit argument: (its arrays — :data:`STATIC_FIELDS` set to None — and those fields as a hashable
    tuple). A compiled log-density that takes the arrays as an argument serves every recording of the same shapes
    (one compile), where one that closes over ``data`` bakes them in as constants and compiles again per call site.
    :func:`join_data` inverts it."""
    lag_prior = None if data.lag_prior is None else tuple(float(v) for v in data.lag_prior)
    static = (float(data.dt), str(data.mode), int(data.lag_stride), lag_prior)
    return data._replace(**dict.fromkeys(STATIC_FIELDS)), static


def join_data(arrays: RawData, static: tuple) -> RawData:
    """The :class:`RawData` that :func:`split_data` split into ``arrays`` and ``static``."""
    return arrays._replace(**dict(zip(STATIC_FIELDS, static, strict=True)))


def on_device(data: RawData) -> RawData:
    """``data`` with every NumPy array field a JAX array (of the same dtype; scalars stay Python numbers), so that
    the compiled log-densities do not copy them from NumPy at every call."""
    arrays, static = split_data(data)
    return join_data(jax.tree.map(lambda v: jnp.asarray(v) if isinstance(v, np.ndarray) else v, arrays), static)


def check_stroke_selection(strokes, recorded=None, where: str = "recording") -> np.ndarray:
    """The strokes a fit reads (a sequence of stroke indices, or one), or a one-line refusal naming ``strokes``: not
    integers ≥ 0, none at all, or (given the ``recorded`` stroke indices) a stroke the recording does not hold.

    Returns
    -------
    (S,) int
    """
    items = list(strokes) if isinstance(strokes, list | tuple | range | np.ndarray) else [strokes]
    if isinstance(strokes, np.ndarray) and strokes.ndim == 0:
        items = [strokes.item()]
    if not items or not all(isinstance(k, int | np.integer) and not isinstance(k, bool) and k >= 0 for k in items):
        raise BadInput(
            f"strokes: expected stroke indices (integers ≥ 0, e.g. [0, 2]) or None (all), got {shown(strokes)}"
        )
    if recorded is not None:
        missing = sorted(set(int(k) for k in items) - set(int(k) for k in recorded))
        if missing:
            raise BadInput(
                f"strokes: {where} has no stroke {missing[0]} (its strokes: {', '.join(map(str, recorded[:20]))})"
            )
    return np.asarray(items, int)


def open_recording(ds_or_path):
    """A recording as a dataset, and the name to give it in error messages.

    Parameters
    ----------
    ds_or_path : xarray.Dataset, str or path
        A recording (:mod:`bayestouch.io.recording`), or the path of its ``.nc`` file.

    Returns
    -------
    ds : xarray.Dataset
    where : str
        The path, or ``"recording"`` for a dataset given as such.

    Raises
    ------
    BadInput
        No such file, a file that cannot be read as netCDF, a damaged recording
        (:func:`~bayestouch.io.recording.check_recording`), or pressing depths and times no finger records
        (deeper than :data:`~bayestouch.physics.virtual.MAX_DEPTH_M`, a frame rate outside
        :data:`FRAME_RATE_RANGE_HZ`, a pad faster than :data:`MAX_PAD_SPEED`).
    """
    if not isinstance(ds_or_path, str | os.PathLike):
        if type(ds_or_path).__name__ != "Dataset" or not hasattr(ds_or_path, "variables"):  # xarray, not imported
            raise BadInput(
                f"recording: expected the path of a .nc recording or an xarray Dataset (bt.read_recording), got "
                f"{type(ds_or_path).__name__} {shown(ds_or_path, 60)}"
            )
        check_recording(ds_or_path)
        _core_variables(ds_or_path, "recording")
        _recording_kinematics(ds_or_path, "recording")
        return ds_or_path, "recording"
    p = Path(ds_or_path)
    if problem := file_problem(p):
        raise BadInput(f"recording {p}: {problem}; expected a .nc recording from bayestouch simulate")
    try:
        ds = read_recording(p)
    except Exception as e:  # not netCDF/HDF5
        raise BadInput(
            f"recording {p}: cannot be read as netCDF ({type(e).__name__}); expected a .nc recording"
        ) from None
    check_recording(ds, f"recording {p}")
    _core_variables(ds, f"recording {p}")
    _recording_kinematics(ds, str(p))
    return ds, str(p)


#: variables every use of a recording reads (the fits and the calibration), checked when it is opened, before a
#: run folder is touched: a file that lacks them (another netCDF, a posterior.nc) is refused with nothing set aside
CORE_VARIABLES = (("taxel_current", 2), ("time", 1), ("stroke_index", 1))


def _core_variables(ds, where: str) -> None:
    for name, ndim in CORE_VARIABLES:
        need_variable(ds, name, ndim, where)


def need_variable(ds, name, ndim, where):
    """The finite values of variable ``name`` of a recording, which must have ``ndim`` dimensions (else one-line
    BadInput naming the recording ``where`` and the variable)."""
    if name not in ds.variables:
        raise BadInput(f"{where}: variable '{name}' is missing; expected a bayestouch recording (bayestouch simulate)")
    v = np.asarray(ds[name].values, dtype=float)
    if v.ndim != ndim:
        raise BadInput(f"{where}: variable '{name}' has {v.ndim} dimensions, expected {ndim}")
    if not np.all(np.isfinite(v)):
        raise BadInput(f"{where}: variable '{name}' contains NaN or infinite values; expected finite numbers")
    return v


def frame_interval_problem(times) -> str | None:
    """What is wrong with one stroke's frame ``times`` (s) when their median interval puts the frame rate outside
    :data:`FRAME_RATE_RANGE_HZ` (another unit written as seconds), else None: the one check a recording on load and
    a stroke file before anything is sent share."""
    t = np.asarray(times, float)
    if t.size < 2:
        return None
    dt = float(np.median(np.diff(t)))
    lo, hi = FRAME_RATE_RANGE_HZ
    if 1.0 / hi <= dt <= 1.0 / lo:
        return None
    rate = f"{1.0 / dt:.3g} Hz" if dt > 0 else "no frame rate"
    return (
        f"puts the frames {dt:.3g} s apart ({rate}); expected a frame rate in [{lo:g}, {hi:g}] Hz with times in "
        "seconds (milliseconds written as seconds?)"
    )


def _check_kinematics(where: str, t, si, contact, depth) -> None:
    """Refuse (:class:`BadInput` naming the variable) pressing depths beyond :data:`MAX_DEPTH_M` and times whose
    frame rate lies outside :data:`FRAME_RATE_RANGE_HZ` or that move the pad faster than :data:`MAX_PAD_SPEED`
    (SI values the simulator and the finger cannot produce: another unit written under the SI one)."""
    deep = depth > MAX_DEPTH_M
    if deep.any():
        i = int(np.argmax(deep))
        raise BadInput(
            f"{where}: 'pressing_depth' holds {int(deep.sum())} value(s) deeper than {MAX_DEPTH_M:g} m (first at frame "
            f"{i}: {depth[i]:g} m), the limit of `bayestouch simulate` and `device run`; expected metres (0 or less: "
            "no contact)"
        )
    for k in np.unique(si):
        sel = np.flatnonzero(si == k)
        if sel.size < 2:
            continue
        if problem := frame_interval_problem(t[sel]):
            raise BadInput(f"{where}: 'time' {problem} in stroke {int(k)}")
        duration = float(t[sel[-1]] - t[sel[0]])
        path = float(np.sum(np.linalg.norm(np.diff(contact[sel], axis=0), axis=1)))
        if path > MAX_PAD_SPEED * duration:
            raise BadInput(
                f"{where}: 'time' moves the pad at {path / duration:.3g} m/s in stroke {int(k)} ({path:.3g} m of "
                f"'contact_point' in {duration:.3g} s); expected at most {MAX_PAD_SPEED:g} m/s with times in seconds"
            )


def _recording_kinematics(ds, where: str) -> None:
    """:func:`_check_kinematics` of a recording that has its time, stroke index, contact points and depths in their
    shapes (otherwise :func:`load_raw_data` names what is missing or misshapen)."""
    names = ("time", "stroke_index", "contact_point", "pressing_depth")
    if not all(n in ds.variables for n in names):
        return
    t, si, contact, depth = (np.asarray(ds[n].values, dtype=float) for n in names)
    if t.ndim != 1 or si.shape != t.shape or depth.shape != t.shape or contact.shape != (t.size, 3):
        return
    if all(np.all(np.isfinite(a)) for a in (t, si, contact, depth)):
        _check_kinematics(where, t, si.astype(int), contact, depth)


#: readings above the read-out's full scale by more than this factor are refused (the quantiser stops at full scale;
#: the margin leaves room for a device whose own full scale is a little above the models' value)
FULL_SCALE_MARGIN = 2.0


def check_full_scale(current, full_scale: float, where: str = "recording") -> None:
    """Refuse (:class:`BadInput` naming ``taxel_current``) readings ``current`` (A) above :data:`FULL_SCALE_MARGIN`
    × the read-out's ADC full scale ``full_scale`` (A, ``models/noise.toml`` ``adc_full_scale``): no read-out
    reports them, so the file holds another unit (milliamps written as amperes)."""
    c = np.abs(np.asarray(current, dtype=float))
    top = float(np.max(c)) if c.size else 0.0
    if top > FULL_SCALE_MARGIN * full_scale:
        raise BadInput(
            f"{where}: 'taxel_current' reaches {top:.3g} A, {top / full_scale:.3g}× the read-out's full scale "
            f"{full_scale:g} A (models/noise.toml adc_full_scale), which no read-out reports; expected amperes "
            "(another unit written as A?)"
        )


def check_taxel_layout(ds, finger, where: str = "recording") -> None:
    """Refuse (:class:`BadInput` naming the variable) a recording whose ``taxel_u``/``taxel_v`` (where it has them)
    differ from the pad coordinates of ``finger`` (its ``grid``, metres) by more than :data:`LAYOUT_TOLERANCE_M`:
    the raw-current fit places every ``taxel_current`` column at the finger model's coordinates, so a recording of
    another layout, in another unit or with its taxels in another order would be fitted as if it were this one's."""
    grid = np.asarray(finger.grid).reshape(-1, 2)
    for col, name in enumerate(("taxel_u", "taxel_v")):
        if name not in ds.variables:
            continue
        v = np.asarray(ds[name].values, dtype=float)
        want = grid[:, col]
        if v.shape != want.shape:
            raise BadInput(f"{where}: variable '{name}' has shape {v.shape}, expected ({want.size},) (taxel)")
        off = np.where(np.isfinite(v), np.abs(v - want), np.inf)
        if np.max(off) > LAYOUT_TOLERANCE_M:
            i = int(np.argmax(off))
            raise BadInput(
                f"{where}: variable '{name}' differs from the finger's taxel layout by up to {off[i]:.3g} m "
                f"(taxel {i}: {v[i]:g} m, the model's {want[i]:g} m); the fit places each taxel at the pad coordinates "
                "of the finger model (--models), so expected the same taxels in the same order, in metres"
            )


def nominal_log_gain_sd(finger) -> float:
    """Spread of the taxels' log-gains that ``models/noise.toml`` states for any device, σ_Φ / V_T (dimensionless;
    0.78 for σ_Φ = 20 mV at 296 K): what is known of an uncalibrated finger's gains."""
    return float(finger.noise.barrier_spread / tx.thermal_voltage(finger.noise.temperature))


class HostDevice(NamedTuple):
    """The finger as a host that has only ``models/`` and the device file knows it (:func:`host_device`).

    finger : Finger
        The models' constants with the calibrated gains (or 1 for every taxel).
    log_gain_sd : (N,) float
        Remaining sd of each taxel's log-gain (dimensionless).
    response_scale : float
        The taxels' common response factor on Δ ln I (dimensionless).
    response_sd : float
        Its remaining sd.
    """

    finger: object
    log_gain_sd: np.ndarray
    response_scale: float
    response_sd: float

    def with_lag(self, lag: float) -> HostDevice:
        """The same host assuming the taxels' response lag ``lag`` (s)."""
        return self._replace(finger=self.finger._replace(taxels=self.finger.taxels._replace(lag=float(lag))))


def recording_mode(ds, where: str, calibration: DeviceCalibration | None = None) -> str:
    """The taxel mode a recording was made in (its ``mode`` attribute, default ``physics``); :class:`BadInput`
    naming ``where`` for another value, or when ``calibration`` was made in another mode or on another finger (when
    the recording and the device file both name their finger, attribute ``finger``)."""
    mode = str(ds.attrs.get("mode", "physics"))
    if mode not in tx.MODES:
        raise BadInput(f"{where}: attribute 'mode' is {mode!r}, expected one of {tx.MODES}")
    if calibration is not None and calibration.mode != mode:
        raise BadInput(f"calibration: made in the {calibration.mode} taxel mode; {where} is in the {mode} mode")
    check_same_finger(calibration, ds.attrs.get("finger"), f"{where} was recorded by")
    return mode


def host_device(models: Path = MODELS, calibration: DeviceCalibration | None = None) -> HostDevice:
    """The finger as a host that has only ``models`` and the device file knows it.

    Parameters
    ----------
    models : path
        Parameter folder (``finger.toml``, ``skin.toml``, ``taxels.toml``, ``noise.toml``).
    calibration : DeviceCalibration, optional
        From ``bayestouch calibrate`` (:func:`bayestouch.io.device_file.read_device_file`).

    Returns
    -------
    HostDevice
        Gains exp(``calibration.log_gain``) with their standard errors, or 1 for every taxel with
        :func:`nominal_log_gain_sd` (never a simulator's fixed pattern); the response factor and its sd from the
        calibration, or 1 ± :data:`~bayestouch.inference.raw.priors.RESPONSE_SCALE_SD`.
    """
    finger = load_finger(Path(models)).finger
    n = int(np.asarray(finger.gains).size)
    scale, scale_sd = 1.0, RESPONSE_SCALE_SD
    if calibration is None:
        gains, sd = np.ones(n), np.full(n, nominal_log_gain_sd(finger))
    else:
        if np.size(calibration.log_gain) != n:
            raise BadInput(f"calibration: it calibrates {np.size(calibration.log_gain)} taxels, the finger has {n}")
        gains, sd = np.exp(np.asarray(calibration.log_gain, float)), np.asarray(calibration.log_gain_sd, float)
        if calibration.response_scale_sd is not None:
            scale, scale_sd = float(calibration.response_scale), float(calibration.response_scale_sd)
    finger = finger._replace(gains=jnp.asarray(gains).reshape(np.shape(finger.gains)))
    return HostDevice(finger, sd, scale, scale_sd)


def unloaded_current(finger, temperature, time, stroke_index, mode: str) -> np.ndarray:
    """Unloaded taxel current (F,) A at the skin ``temperature (F,)`` K through the taxels' response lag, each
    stroke (``stroke_index (F,)``) starting at steady state, as the reference taxels see it; ``time (F,)`` s."""
    temperature, time, stroke_index = (np.asarray(a) for a in (temperature, time, stroke_index))
    nF = temperature.size
    unloaded = np.asarray(
        tx.taxel_current(finger.taxels, jnp.zeros((nF, 1)), jnp.asarray(temperature)[:, None], mode=mode)
    )[:, 0]
    out = np.empty_like(unloaded)
    for k in np.unique(stroke_index):
        sel = np.flatnonzero(stroke_index == k)
        dts = np.diff(time[sel])
        dt = float(np.median(dts)) if dts.size else 0.02
        out[sel] = np.asarray(tx.first_order_lag(unloaded[sel, None], dt, float(finger.taxels.lag)))[:, 0]
    return out


def load_raw_data(
    ds_or_path,
    *,
    models: Path = MODELS,
    stride: int = 5,
    radius: float = 4.5e-3,
    contact_radius: float = 3.2e-3,
    strokes=None,
    finger=None,
    calibration: DeviceCalibration | None = None,
    device: HostDevice | None = None,
    demean_reference: bool = False,
):
    """Read a recording into :class:`RawData` with the finger as a host knows it (:func:`host_device`).

    Parameters
    ----------
    ds_or_path : xarray.Dataset or path
        A recording (:mod:`bayestouch.io.recording`).
    models : path
        Parameter folder of the finger (``finger.toml``, ``skin.toml``, ``taxels.toml``, ``noise.toml``).
    stride : int
        Use every ``stride``-th frame of each stroke (≥ 1).
    radius : float, metres
        Model the taxels within this pad-coordinate distance of the pad centre.
    contact_radius : float, metres
        Taxels that may touch the object (penetration computed), ≤ ``radius``; the others get pressure only
        through the blur.
    strokes : sequence of int, optional
        Use only these strokes (default all).
    finger : Finger, optional
        A device known exactly: its gains and response taken as they are, nothing marginalised.
    calibration : DeviceCalibration, optional
        The device file of this finger (its taxel mode is checked against the recording's); without ``finger`` or
        ``device`` the host's device is :func:`host_device` of ``models`` and ``calibration``, and without it unit
        gains with the nominal spread. Nothing of the recording but its readings, kinematics and response mode is
        read (no simulator seed).
    device : HostDevice, optional
        The host's device (:func:`host_device`) to reuse between loads of one recording.
    demean_reference : bool
        Take each reference taxel's mean over the frames out before the per-frame median ĉ (for gains not known
        exactly: each reference taxel then reads its own log-gain offset, ~0.8 against a reading noise of ~1e-3, so
        the median is one and the same taxel in every frame, with one taxel's noise instead of the π/2 · σ²/n the
        reading variance assumes). The constant this leaves in ĉ is one more per-taxel offset, which the texture
        identifier marginalises (:func:`bayestouch.inference.texture_posterior.read_stroke` sets it).

    Returns
    -------
    (RawData, Finger)

    Raises
    ------
    BadInput
        A recording :func:`open_recording` refuses, a variable that is missing or misshapen, or a taxel layout
        (``taxel_u``, ``taxel_v``) other than the finger's (:func:`check_taxel_layout`).
    """
    ds, where = open_recording(ds_or_path)
    if int(stride) < 1:
        raise BadInput(f"stride must be an integer ≥ 1, got {stride}")
    if not radius > 0:
        raise BadInput(f"radius must be positive (metres), got {radius}")
    cur = need_variable(ds, "taxel_current", 2, where)
    contact = need_variable(ds, "contact_point", 2, where)
    normal = need_variable(ds, "contact_normal", 2, where)
    depth = need_variable(ds, "pressing_depth", 1, where)
    temp = need_variable(ds, "skin_temperature", 1, where)
    t = need_variable(ds, "time", 1, where)
    si = need_variable(ds, "stroke_index", 1, where).astype(int)
    nF, nT = cur.shape
    for name, v in (("contact_point", contact), ("contact_normal", normal)):
        if v.shape != (nF, 3):
            raise BadInput(f"{where}: variable '{name}' has shape {v.shape}, expected ({nF}, 3) (frame, xyz)")
    for name, v in (("pressing_depth", depth), ("skin_temperature", temp), ("time", t), ("stroke_index", si)):
        if v.shape != (nF,):
            raise BadInput(f"{where}: variable '{name}' has shape {v.shape}, expected ({nF},) (frame)")
    mode = recording_mode(ds, where, calibration)
    if device is None and finger is None:
        device = host_device(Path(models), calibration)
    if device is not None:
        finger = device.finger
    N = int(np.asarray(finger.reference).size)
    if nT != N:
        raise BadInput(f"{where}: variable 'taxel_current' has {nT} taxels, expected {N} (the finger's array)")
    check_taxel_layout(ds, finger, where)
    check_full_scale(cur, float(finger.noise.adc_full_scale), where)
    ref = np.asarray(finger.reference).ravel().astype(bool)
    if "taxel_reference" in ds.variables and not np.array_equal(np.asarray(ds["taxel_reference"].values) != 0, ref):
        raise BadInput(f"{where}: variable 'taxel_reference' differs from the finger's reference taxels")

    # -- pad pose of every frame (known kinematics), tangent from successive contact points within a stroke
    tangent = np.zeros_like(contact)
    for k in np.unique(si):
        sel = si == k
        tangent[sel] = np.gradient(contact[sel], axis=0) if sel.sum() > 1 else np.array([1.0, 0.0, 0.0])
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-30)
    use_strokes = np.unique(si) if strokes is None else check_stroke_selection(strokes, np.unique(si), where)
    frames, start = [], []
    for k in use_strokes:
        idx = np.flatnonzero((si == k) & (depth > 0))
        if idx.size == 0:
            continue
        idx = idx[::stride]
        frames.append(idx)
        start.append(np.arange(idx.size) == 0)
    if not frames:
        raise BadInput(f"{where}: no frames with contact (pressing_depth > 0) in the selected strokes")
    frames, start = np.concatenate(frames), np.concatenate(start)
    if frames.size < MIN_FRAMES:
        raise BadInput(
            f"{where}: stride {stride} leaves {frames.size} frame(s) with contact; a fit needs at least {MIN_FRAMES} "
            "(use a smaller --stride)"
        )
    dts = np.diff(t[si == si[frames[0]]])
    dt_fine = float(np.median(dts)) if dts.size else 0.02

    grid = np.asarray(finger.grid).reshape(-1, 2)
    rho = np.hypot(grid[:, 0], grid[:, 1])
    taxels = np.flatnonzero((rho <= radius) & ~ref)
    pen = np.flatnonzero((rho <= min(contact_radius, radius)) & ~ref)
    if pen.size == 0:
        raise BadInput(
            f"radius {radius:g} m, contact_radius {contact_radius:g} m select no taxels; expected "
            "distances of a few taxel pitches"
        )
    x = jax.vmap(lambda c, n, tg, d: fw.pad_points(finger, c, n, tg, d))(
        jnp.asarray(contact[frames]),
        jnp.asarray(normal[frames]),
        jnp.asarray(tangent[frames]),
        jnp.asarray(depth[frames]),
    )
    x = np.asarray(x).reshape(len(frames), -1, 3)[:, pen]

    # -- data: gain- and drift-corrected log currents, and their modelled noise
    gains = np.asarray(finger.gains).ravel()
    floor = float(nz.adc_lsb(finger.noise))
    meas = np.maximum(cur[frames], floor)
    lnI = np.log(meas) - np.log(gains)
    # the unloaded current at the skin temperature, through the taxels' response lag exactly as the reference
    # taxels see it (each stroke starts at steady state, as the forward model does); without the lag a warming
    # skin leaves a drift bias of ~1e-3 in ln I over a 1 s stroke, twice the reading noise
    unloaded = unloaded_current(finger, temp, t, si, mode)[frames]
    flick = float(nz.flicker_autocovariance(finger.noise, 0.0))
    white = (np.asarray(nz.noise_std(finger.noise, jnp.asarray(meas))) / meas) ** 2
    # median over the reference taxels: one read-out glitch on a reference taxel must not shift every taxel
    ref_dev = lnI[:, ref] - np.log(unloaded)[:, None]
    if demean_reference:
        ref_dev = ref_dev - ref_dev.mean(axis=0)
    c_hat = np.median(ref_dev, axis=1)
    s_ref = 0.5 * np.pi * (np.mean(white[:, ref], axis=1) + flick) / ref.sum()  # variance of a median: π/2 · σ²/n
    t_first = {k: t[np.flatnonzero(si == k)[0]] for k in np.unique(si[frames])}
    t_in = t[frames] - np.array([t_first[k] for k in si[frames]])
    var = white[:, taxels] + flick + float(finger.noise.drift_local) ** 2 * t_in[:, None] + s_ref[:, None]
    kernel = np.asarray(finger.kernel)[np.ix_(taxels, pen)]
    lw = np.asarray(tx.coarse_lag_weights(dt_fine, float(finger.taxels.lag), int(stride)))
    data = RawData(
        x,
        temp[frames],
        lnI[:, taxels] - c_hat[:, None],
        np.sqrt(var),
        start,
        kernel,
        lw,
        frames,
        taxels,
        dt_fine * stride,
        mode,
    )
    # 1 m clear of any surface: zero pressure
    free_current = fw.current_from_distance(finger, jnp.ones(x.shape[:2]), jnp.asarray(kernel), data.temperature, mode)
    baseline = jnp.log(tx.coarse_lag(free_current, jnp.asarray(start), jnp.asarray(lw)))
    # the error of ĉ over frames: the median of n reference taxels' noise (π/2 · σ²/n per frame, the same factor on
    # the slow parts), independent between strokes, de-meaned with the reference taxels
    sf = si[frames]
    ref_cov = nz.frame_covariance(finger.noise, np.mean(white[:, ref], axis=1), t_in)  # lags within a stroke
    common_cov = 0.5 * np.pi / ref.sum() * ref_cov * (sf[:, None] == sf[None, :])
    if demean_reference:
        centre = np.eye(len(frames)) - 1.0 / len(frames)
        common_cov = centre @ common_cov @ centre
    data = data._replace(
        baseline=np.asarray(baseline),
        common_var=s_ref,
        common_cov=common_cov,
        unloaded=np.asarray(free_current),
        lag_stride=int(stride),
    )
    if device is not None:
        data = data._replace(
            gain_sd=np.asarray(device.log_gain_sd, float).ravel()[taxels],
            response_scale=float(device.response_scale),
            response_sd=float(device.response_sd),
        )
    return data, finger


#: least span (m) of a recording's contact points for a shape fit: strokes that press in place (every waypoint one
#: point) or a contact_point of zeros say nothing of a shape (the fit's bounds then collapsed: exit 1)
MIN_CONTACT_SPAN_M = 1e-3


def check_contact_motion(ds, where: str) -> None:
    """Refuse (:class:`BadInput`) a recording whose contact points (frames with contact) span less than
    :data:`MIN_CONTACT_SPAN_M`: its strokes press in place, so no shape can be fitted to them."""
    contact = need_variable(ds, "contact_point", 2, where)
    depth = need_variable(ds, "pressing_depth", 1, where)
    touched = contact[depth > 0] if contact.shape[:1] == depth.shape else contact
    span = float(np.max(np.ptp(touched, axis=0))) if len(touched) else 0.0
    if span < MIN_CONTACT_SPAN_M:
        raise BadInput(
            f"{where}: the contact points of the frames with contact span {span:.3g} m (the strokes press in place); "
            f"a shape fit needs strokes that move over the object (at least {MIN_CONTACT_SPAN_M:g} m)"
        )


def commanded_points(ds, frames) -> np.ndarray:
    """The commanded pad-centre contact points (len(frames), 3) m of the recording ``ds`` at frame indices
    ``frames`` (e.g. :attr:`RawData.frames`): the data of the contact-level initial fit, never a shape datum of the
    raw likelihood."""
    return np.asarray(ds["contact_point"].values, float)[frames]
