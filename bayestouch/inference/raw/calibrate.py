"""Calibration of a finger from strokes over a known object: each taxel's fixed-pattern log-gain with its standard
error, and the read-out noise's scale, as a :class:`~bayestouch.io.device_file.DeviceCalibration`.

The object's surface and pose are known (an object file), so the forward model predicts every taxel's ln I
(:func:`bayestouch.physics.forward.log_current_from_distance` of the true surface's signed distances, texture and
FFD included) up to the taxel's gain. The reference taxels are unloaded: their log-gains are the medians of their
deviations from the frame's reference median. The other taxels' log-gains are the means of their residuals'
medians over strokes; their standard error is the spread of those stroke medians (shrunk towards the mean over
taxels, so a taxel whose few strokes happen to agree is not trusted beyond the others), which carries the 1/f
noise, the drift and the model's misfit between strokes, not only the white noise. Halves of strokes would be
correlated blocks: the 1/f noise then makes their spread ~30 % too small.
"""

from __future__ import annotations

import re

import numpy as np

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.inference.raw.data import (
    check_full_scale,
    host_device,
    load_raw_data,
    need_variable,
    nominal_log_gain_sd,
    open_recording,
    recording_mode,
    unloaded_current,
)
from bayestouch.inference.raw.likelihood import distance_log_current
from bayestouch.inference.raw.priors import RESPONSE_SCALE_SD
from bayestouch.io.device_file import DeviceCalibration
from bayestouch.io.runfolder import dataset_digest
from bayestouch.params import MODELS
from bayestouch.physics import noise as nz
from bayestouch.scene.surface import signed_distance

__all__ = [
    "CALIBRATION_RADIUS",
    "MIN_RESPONSE_STROKES",
    "IDENTIFIED_SHARE",
    "calibrate_device",
    "block_labels",
    "response_factor",
]

#: pad-coordinate radius (m) of the taxels calibrated: every taxel of the array
CALIBRATION_RADIUS = 1.0
#: strokes needed for the response factor's standard error (a jackknife over strokes)
MIN_RESPONSE_STROKES = 3
#: the response factor counts as calibrated when its standard error is below this share of its prior sd
IDENTIFIED_SHARE = 0.5


def block_labels(stroke_index, pieces: int = 1) -> np.ndarray:
    """Block of every frame (F,) int: each stroke of ``stroke_index (F,)`` cut into ``pieces`` runs of
    consecutive frames."""
    si = np.asarray(stroke_index)
    out = np.empty(si.size, int)
    b = 0
    for k in np.unique(si):
        idx = np.flatnonzero(si == k)
        for part in np.array_split(idx, min(pieces, idx.size)):
            out[part] = b
            b += 1
    return out


#: prior degrees of freedom of the pooled block variance in each taxel's shrunk variance (:func:`_block_estimates`)
POOL_DOF = 8.0


def _block_estimates(values, blocks) -> tuple[np.ndarray, np.ndarray]:
    """Mean over blocks of each column's block median (C,), and its standard error (C,).

    The variance of the block medians is each column's own ((B − 1) degrees of freedom) shrunk towards the mean
    over columns (:data:`POOL_DOF` degrees of freedom): with two strokes a column's own spread has one degree of
    freedom, and its median over columns is 0.45 of its mean. The error so estimated is Student-t; the standard
    error returned is that t's sd, ν/(ν − 2) times the variance (a Gaussian of it is what the fit marginalises)."""
    u = np.unique(blocks)
    if len(u) < 2:
        raise BadInput("calibration: the recording needs at least 2 strokes to estimate the gains' errors")
    med = np.stack([np.median(values[blocks == b], axis=0) for b in u])  # (B, C)
    var = med.var(axis=0, ddof=1)
    dof = len(u) - 1
    var = (dof * var + POOL_DOF * var.mean()) / (dof + POOL_DOF)
    # with an estimated variance the error is Student-t of ν = dof + POOL_DOF: match its variance ν/(ν − 2)
    nu = dof + POOL_DOF
    return med.mean(axis=0), np.sqrt(var / len(u) * nu / (nu - 2.0))


def response_factor(residual, delta, noise_sd, blocks, gain_sd: float) -> tuple[float, float]:
    """The taxels' common response factor's departure b = a − 1 from 1, and its standard error.

    The readings are modelled as r = b Δ + δ_k + ε with each taxel's offset δ_k ~ N(0, ``gain_sd``²) and ε of sd
    ``noise_sd``: b̂ is the generalised least-squares estimate with the offsets marginalised (no prior on b). Its
    error is the larger of the least-squares one (scaled by the residuals' robust sd over the modelled) and the
    jackknife over blocks (strokes), which carries the correlated noise; with fewer than
    :data:`MIN_RESPONSE_STROKES` blocks it is infinite (not calibrated).

    Parameters
    ----------
    residual, delta, noise_sd : (F, M) float
        Readings less the prediction at a = 1, the prediction's Δ ln I, the modelled reading sd.
    blocks : (F,) int
    gain_sd : float

    Returns
    -------
    (float, float)
    """
    w = 1.0 / noise_sd**2

    def estimate(keep):
        wk = w * keep[:, None]
        A = 1.0 / gain_sd**2 + wk.sum(axis=0)

        def inner(x, z):
            return float(np.sum((wk * x * z).sum(axis=0) - (wk * x).sum(axis=0) * (wk * z).sum(axis=0) / A))

        dd = inner(delta, delta)
        return (inner(delta, residual) / dd if dd > 0 else 0.0), dd

    b, dd = estimate(np.ones(len(blocks), bool))
    u = np.unique(blocks)
    if len(u) < MIN_RESPONSE_STROKES or not dd > 0:
        return 0.0, float("inf")
    k = float(np.median(np.abs(residual - b * delta - np.median(residual - b * delta, axis=0)) / noise_sd) / 0.6745)
    sd_ls = k / np.sqrt(dd)
    jack = np.array([estimate(blocks != v)[0] for v in u])
    sd_jack = float(np.sqrt((len(u) - 1) / len(u) * np.sum((jack - jack.mean()) ** 2)))
    return float(b), float(max(sd_ls, sd_jack))


#: response factors a calibration accepts: the nominal S_p is uncertain by a factor ~1.2 (models/taxels.toml); a
#: factor outside this range (or negative) means the readings were not made on the object where the recording
#: places it
RESPONSE_PLAUSIBLE = (0.1, 10.0)
#: largest noise multiplier k (robust residual sd / modelled read-out sd) a calibration accepts: 1 for the finger of
#: models/, ~1–2 for fingers whose 1/f level and drift differ within their stated uncertainty
#: (benchmarks/bench_mismatch.py); beyond it the readings were not made on the object as placed
MISFIT_NOISE_SCALE = 5.0


def calibrate_device(recording, obj, *, models=MODELS, object_name: str | None = None) -> DeviceCalibration:
    """Estimate the finger's per-taxel log-gains from a recording of strokes over the known ``obj``.

    Parameters
    ----------
    recording : path or xarray.Dataset
        Strokes over ``obj`` (``bayestouch simulate`` or ``bayestouch device run``).
    obj : SceneObject
        The touched object, in the recording's world frame (metres).
    models : path
        The finger's parameter folder (its nominal constants).
    object_name : str, optional
        Recorded in the calibration's provenance (default ``obj.name``).

    Returns
    -------
    DeviceCalibration
        Log-gains relative to the reference taxels' median, standard errors, the residual noise scale.
    """
    ds, where = open_recording(recording)
    named = str(ds.attrs.get("object", ""))
    if re.fullmatch(r"[\w.-]+", named) and named != obj.name:  # a simulated recording names its object
        raise BadInput(
            f"object: {where} was recorded over {named!r}, not {obj.name!r}; the gains would be measured against the "
            f"wrong surface (expected the object the strokes touched: {named})"
        )
    finger = host_device(models).finger
    mode = recording_mode(ds, where)
    cur = need_variable(ds, "taxel_current", 2, where)
    temp, t = (need_variable(ds, v, 1, where) for v in ("skin_temperature", "time"))
    si = need_variable(ds, "stroke_index", 1, where).astype(int)
    ref = np.asarray(finger.reference).ravel().astype(bool)
    if cur.ndim != 2 or cur.shape[1] != ref.size:
        raise BadInput(f"{where}: variable 'taxel_current' must be (frame, {ref.size}) for this finger")
    check_full_scale(cur, float(finger.noise.adc_full_scale), where)
    floor = float(nz.adc_lsb(finger.noise))

    # reference taxels: unloaded, so their deviation from the frame's reference median is their log-gain
    z = np.log(np.maximum(cur[:, ref], floor)) - np.log(unloaded_current(finger, temp, t, si, mode))[:, None]
    dev = z - np.median(z, axis=1, keepdims=True)
    g_ref, s_ref = _block_estimates(dev, block_labels(si))
    g_ref -= np.median(g_ref)
    log_gain, log_gain_sd = np.zeros(ref.size), np.zeros(ref.size)
    log_gain[ref], log_gain_sd[ref] = g_ref, s_ref

    # the other taxels: residuals of the true surface's prediction with the reference gains divided out
    f1 = finger._replace(gains=jnp.asarray(np.exp(log_gain)).reshape(np.shape(finger.gains)))
    data, _ = load_raw_data(ds, models=models, stride=1, radius=CALIBRATION_RADIUS, finger=f1)
    pred = distance_log_current(signed_distance(obj.surface(), jnp.asarray(data.taxel_position)), data, f1)
    r = np.asarray(data.log_current) - np.asarray(pred)
    if not np.all(np.isfinite(r)):
        raise BadInput(f"{where}: the forward model of the object gives no finite currents; is it the touched one?")
    blocks = block_labels(si[data.frames])
    delta = np.asarray(pred) - np.asarray(data.baseline)  # Δ ln I of the known surface
    b, b_sd = response_factor(r, delta, np.asarray(data.noise_sd), blocks, nominal_log_gain_sd(finger))
    identified = b_sd < IDENTIFIED_SHARE * RESPONSE_SCALE_SD
    if identified and not RESPONSE_PLAUSIBLE[0] <= 1.0 + b <= RESPONSE_PLAUSIBLE[1]:
        # negated normals or an object placed elsewhere gave "[response] scale must be in [0.001, 1000]": a field of
        # a file the user never wrote
        raise BadInput(
            f"{where}: the readings do not fit the object where the recording puts it: the taxels' response to its "
            f"pressure comes out at {1.0 + b:.3g} times the nominal (expected {RESPONSE_PLAUSIBLE[0]:g}–"
            f"{RESPONSE_PLAUSIBLE[1]:g}); check the object (--object), its position and the contact normals"
        )
    if identified:
        r = r - b * delta
    g, s = _block_estimates(r, blocks)
    if identified:  # the response factor's error moves each taxel's offset by its mean Δ ln I
        s = np.hypot(s, b_sd * delta.mean(axis=0))
    log_gain[data.taxels], log_gain_sd[data.taxels] = g, s
    k = float(np.median(np.abs(r - g) / np.asarray(data.noise_sd)) / 0.6745)
    if k > MISFIT_NOISE_SCALE:  # negated normals: the response unidentified, k 26, and the file written
        raise BadInput(
            f"{where}: the readings do not fit the object where the recording puts it: after the gains, the "
            f"residuals are {k:.3g} times the modelled read-out noise (expected about 1, at most "
            f"{MISFIT_NOISE_SCALE:g}); check the object (--object), its position and the contact normals"
        )
    info = {
        "object": object_name or obj.name,
        "recording": dataset_digest(ds).hex(),
        "strokes": int(np.unique(si[data.frames]).size),
        "frames": int(len(data.frames)),
        **({"finger": str(ds.attrs["finger"])} if str(ds.attrs.get("finger", "")).strip() else {}),
    }
    if identified:
        return DeviceCalibration(log_gain, log_gain_sd, k, mode, info, 1.0 + b, b_sd)
    signal, noise = float(np.max(np.abs(delta))), float(np.median(np.asarray(data.noise_sd)))
    if signal < noise:  # the physics mode's piezotronic response: Δ ln I ~ 1e-4 at these depths
        info["response"] = (
            f"not identified: the pressure signal of these strokes (largest |Δ ln I| {signal:.2g}) is below the "
            f"read-out noise ({noise:.2g} in ln I) in the {mode} taxel mode"
        )
    else:
        info["response"] = "not identified by these strokes (record strokes at several depths or over a curved object)"
    return DeviceCalibration(log_gain, log_gain_sd, k, mode, info)
