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

import numpy as np

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.inference.raw.data import host_finger, load_raw_data, open_recording, unloaded_current
from bayestouch.io.device_file import DeviceCalibration
from bayestouch.io.runfolder import dataset_digest
from bayestouch.params import MODELS
from bayestouch.physics import forward as fw
from bayestouch.physics import noise as nz
from bayestouch.scene.surface import signed_distance

__all__ = ["CALIBRATION_RADIUS", "calibrate_device", "block_labels"]

#: pad-coordinate radius (m) of the taxels calibrated: every taxel of the array
CALIBRATION_RADIUS = 1.0


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
    finger, _ = host_finger(models)
    mode = str(ds.attrs.get("mode", "physics"))
    cur = np.asarray(ds["taxel_current"].values, float)
    temp, t = (np.asarray(ds[v].values, float) for v in ("skin_temperature", "time"))
    si = np.asarray(ds["stroke_index"].values, int)
    ref = np.asarray(finger.reference).ravel().astype(bool)
    if cur.ndim != 2 or cur.shape[1] != ref.size:
        raise BadInput(f"{where}: variable 'taxel_current' must be (frame, {ref.size}) for this finger")
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
    sdf = signed_distance(obj.surface(), jnp.asarray(data.taxel_position))
    pred = fw.log_current_from_distance(
        f1,
        sdf,
        jnp.asarray(data.kernel),
        jnp.asarray(data.temperature),
        jnp.asarray(data.start),
        jnp.asarray(data.lag_weights),
        data.mode,
    )
    r = np.asarray(data.log_current) - np.asarray(pred)
    if not np.all(np.isfinite(r)):
        raise BadInput(f"{where}: the forward model of the object gives no finite currents; is it the touched one?")
    g, s = _block_estimates(r, block_labels(si[data.frames]))
    log_gain[data.taxels], log_gain_sd[data.taxels] = g, s
    k = float(np.median(np.abs(r - g) / np.asarray(data.noise_sd)) / 0.6745)
    info = {
        "object": object_name or obj.name,
        "recording": dataset_digest(ds).hex(),
        "strokes": int(np.unique(si[data.frames]).size),
        "frames": int(len(data.frames)),
    }
    return DeviceCalibration(log_gain, log_gain_sd, k, mode, info)
