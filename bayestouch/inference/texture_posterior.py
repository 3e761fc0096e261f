"""The discrete texture posterior: p(k | strokes) over the K textures of a library from each stroke's raw currents.

A recorded stroke is read as :class:`~bayestouch.inference.raw.RawData` (F frames, M taxels: corrected ln I and its
noise sd, dimensionless; taxel positions in metres). Texture k enters only through the signed distance at the known
taxel positions, then the forward chain :func:`bayestouch.physics.forward.log_current_from_distance`; each taxel's
standardised residuals are whitened over frames (:func:`frame_whitener`) before a Student-t. The start phase is
marginalised over a grid of G shifts (metres). Derivation and measurements: ``docs/texture_identification.md``.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from bayestouch.backend import jax, jnp
from bayestouch.inference.densities import student_t_logpdf
from bayestouch.inference.raw import HostDevice, RawData, load_raw_data
from bayestouch.io.recording import build_dataset
from bayestouch.physics import forward as fw
from bayestouch.physics import noise as nz
from bayestouch.scene.surface import Surface, signed_distance

__all__ = [
    "COMMON_OFFSET_SD",
    "read_stroke",
    "frame_whitener",
    "texture_log_likelihood",
    "offset_projection",
    "texture_means",
    "stroke_evidence",
    "update_posterior",
    "batch_posterior",
]

COMMON_OFFSET_SD = 1.0
"""Prior sd (ln I, dimensionless) of the offset common to all taxels of a stroke that the de-meaned reference row
leaves in the readings: a skin-temperature reading error of ΔT kelvin moves it by 0.065 ΔT (the unstrained M–S–M
current's temperature slope, both taxel modes), the gains' nominal spread is 0.8."""


def read_stroke(
    frames: dict,
    finger,
    mode: str,
    *,
    radius: float,
    contact_radius: float,
    device: HostDevice | None = None,
) -> RawData:
    """Read one recorded stroke as the identifier does: every frame (``stride=1``, the forward model's exact lag).

    Parameters
    ----------
    frames : dict of str → array
        One stroke's frames (:class:`bayestouch.physics.plate_strokes.PlateRecording` ``.frames``).
    finger : Finger or None
        A device known exactly (its gains taken as they are: simulator checks only); None with ``device``.
    device : HostDevice, optional
        The device as a host knows it (:func:`bayestouch.inference.raw.host_device`: the models' constants, the
        gains of a device file or unit gains with their spread); the data then carry each taxel's remaining
        log-gain sd, which :func:`texture_log_likelihood` marginalises.
    mode : {"empirical", "physics"}
        Taxel response mode.
    radius, contact_radius : float, metres
        Taxel selection of :func:`bayestouch.inference.raw.load_raw_data`.

    Returns
    -------
    RawData
        Corrected ln I and its noise sd at the commanded (known) taxel positions.
    """
    if (finger is None) == (device is None):
        raise ValueError("read_stroke: give either finger (known exactly) or device (as a host knows it)")
    known = device.finger if finger is None else finger
    grid = np.asarray(known.grid).reshape(-1, 2)
    ds = build_dataset(
        frames,
        grid[:, 0],
        grid[:, 1],
        np.asarray(known.reference).ravel(),
        [float(frames["pressing_depth"][0])],
        {"mode": mode},
    )
    data, _ = load_raw_data(
        ds,
        stride=1,
        radius=radius,
        contact_radius=contact_radius,
        finger=finger,
        device=device,
        demean_reference=device is not None,
    )
    return data


def frame_whitener(data: RawData, finger) -> np.ndarray:
    """Inverse Cholesky factor L⁻¹ (F, F) of the frame-to-frame correlation of one stroke's standardised readings.

    The read-out noise of ln I (:func:`bayestouch.physics.noise.add_noise`) is not independent over frames: its 1/f
    part is a sum of 9 OU processes (covariance Σ_c v_c a_c^|i−j|, a_c = exp(−2π f_c dt)) and the per-taxel
    random walk adds d² min(t_i, t_j). Treating the readings as independent (as
    :mod:`bayestouch.inference.raw` does) over-counts slowly varying differences: measured on 1 s strokes, the
    per-taxel means of the standardised residuals vary 15× more than independence allows, which made confident
    wrong decisions where the texture signal is below the noise (physics taxel mode). Here the per-reading sd
    ``data.noise_sd`` standardises, and the correlation R = D^(-1/2) Σ D^(-1/2) of the median taxel's covariance
    (white part from ``noise_sd`` minus the modelled 1/f and walk variances) is whitened: z̃ = L⁻¹ z with R = L Lᵀ.
    One R serves all taxels (the white part varies little between them); exact for Gaussian noise of that
    covariance.

    Parameters
    ----------
    data : RawData
        One stroke, F frames ``data.dt`` seconds apart.
    finger : Finger
        Its noise model.

    Returns
    -------
    (F, F) float
    """
    F = len(data.temperature)
    t = np.arange(F) * float(data.dt)
    flick = nz.flicker_autocovariance(finger.noise, t[:, None] - t[None, :])
    d2 = float(finger.noise.drift_local) ** 2
    walk = d2 * np.minimum(t[:, None], t[None, :])
    total = np.median(np.asarray(data.noise_sd) ** 2, axis=1)
    white = np.maximum(total - np.diag(flick) - d2 * t, 1e-3 * total)
    cov = np.diag(white) + flick + walk
    d = np.sqrt(np.diag(cov))
    L = np.linalg.cholesky(cov / np.outer(d, d))
    return np.linalg.solve(L, np.eye(F))


def _arrays(data: RawData) -> tuple:
    return (
        jnp.asarray(data.temperature),
        jnp.asarray(data.start),
        jnp.asarray(data.kernel),
        jnp.asarray(data.lag_weights),
    )


def _predict(surf: Surface, x, data_arrays, finger, mode: str):
    """ln I (F, M) predicted for surface ``surf`` at taxel positions ``x (F, J, 3)`` (raw.predict_log_current's
    chain with the textured signed distance)."""
    temp, start, kernel, lw = data_arrays
    return fw.log_current_from_distance(finger, signed_distance(surf, x), kernel, temp, start, lw, mode)


def offset_projection(z, u, precision, common_precision=None):
    """Whitened standardised residuals ``z (F, M)`` with each taxel's unknown log-gain offset δ_m ~ N(0, 1/
    ``precision_m``), and optionally one offset c ~ N(0, 1/``common_precision``) shared by all taxels, taken out;
    and the offsets' prior term (any array module).

    A taxel whose gain is not known reads ln I + δ_m (+ c) in every frame; whitened and standardised, the offsets
    add (δ_m + c) u_m, u = L⁻¹(1/sd) (F, M). For Gaussian readings the offsets' joint posterior mean is, with
    a_m = u_mᵀu_m, b_m = u_mᵀz_m and q_m = 1/(precision_m + a_m): ĉ = Σ_m precision_m q_m b_m /
    (common_precision + Σ_m precision_m q_m a_m) (each δ_m profiled out), δ̂_m = q_m (b_m − ĉ a_m); and the
    marginal likelihood is that of z_m − (δ̂_m + ĉ) u_m times exp(−½ (Σ_m precision_m δ̂_m² + common_precision ĉ²)),
    up to a factor of the data alone (the posterior precision's determinant, the same for every hypothesis).
    Returns (z − (δ̂ + ĉ) u (F, M), −½ (Σ_m precision_m δ̂_m² + common_precision ĉ²))."""
    a = jnp.sum(u * u, axis=0)
    b = jnp.sum(u * z, axis=0)
    q = 1.0 / (precision + a)
    if common_precision is None:
        c, prior = 0.0, 0.0
    else:
        c = jnp.sum(precision * q * b) / (common_precision + jnp.sum(precision * q * a))
        prior = -0.5 * common_precision * c * c
    delta = q * (b - c * a)
    return z - (delta + c)[None] * u, prior - 0.5 * jnp.sum(precision * delta * delta)


def _ll_grid(surfs: Surface, x, arrays, y, sd, whiten, shifts, tangent, finger, mode, nu, gain_prec, common_prec):
    u = whiten @ (1.0 / sd)

    def one_texture(tex):
        surf = surfs._replace(texture=tex)

        def one_shift(o):
            pred = _predict(surf, x + o * tangent, arrays, finger, mode)
            z = whiten @ jnp.where(jnp.isfinite(pred), (y - pred) / sd, 1e6)
            if gain_prec is None:
                return jnp.sum(student_t_logpdf(z, 1.0, nu))
            z, prior = offset_projection(z, u, gain_prec, common_prec)
            return jnp.sum(student_t_logpdf(z, 1.0, nu)) + prior

        return jax.vmap(one_shift)(shifts)

    return jax.lax.map(one_texture, surfs.texture)


_ll_grid_jit = jax.jit(_ll_grid, static_argnames=("mode", "nu"))


def texture_log_likelihood(
    surfs: Surface,
    data: RawData,
    finger,
    shifts,
    tangent,
    *,
    nu: float = 4.0,
    noise_scale: float = 1.0,
    correlated: bool = True,
    common_offset_sd: float | None = COMMON_OFFSET_SD,
) -> np.ndarray:
    """Log-likelihood (K, G) of one recorded stroke under every texture k and start-phase shift g.

    Parameters
    ----------
    surfs : Surface
        :meth:`bayestouch.scene.textures.TextureLibrary.surfaces` (texture fields with a leading axis K).
    data : RawData
        From :func:`read_stroke` (commanded taxel positions, corrected ln I, its sd). When it carries each taxel's
        remaining log-gain sd (``data.gain_sd``: read with a host's device), the per-taxel offsets are taken out
        (:func:`offset_projection`), so no hypothesis is scored with gains the host does not know, and with them
        one offset common to all taxels, sd ``common_offset_sd``: the stroke mean of the reference row, which
        :func:`read_stroke`'s de-meaning leaves out of ĉ and a skin-temperature reading error moves (0.065 per
        kelvin; a loaded taxel's ln I depends on temperature beyond that by < 5e-6 per kelvin at 50 kPa).
    finger : Finger
        The device the predictions use (a host's: its gains do not enter the predicted ln I).
    shifts : (G,) float, metres
        Shifts of the pad along the stroke.
    tangent : (3,) float
        Unit stroke direction (world frame).
    nu : float
        Student-t degrees of freedom.
    noise_scale : float
        Multiplier on ``data.noise_sd``.
    correlated : bool
        Whiten the standardised residuals over frames (:func:`frame_whitener`) before the Student-t; the
        log-likelihood is then that of the whitened residuals (its Jacobian, −Σ log diag L per taxel, is the same
        for every hypothesis and left out, like the Student-t's −log s).
    common_offset_sd : float or None
        Prior sd of the common offset (ln I); None takes the reference row's stroke mean as known, which holds
        only for a skin-temperature reading without error.

    Returns
    -------
    (K, G) float
        Up to a constant common to all (k, g) when ``correlated``.
    """
    F = len(data.temperature)
    whiten = frame_whitener(data, finger) if correlated else np.eye(F)
    out = _ll_grid_jit(
        surfs,
        jnp.asarray(data.taxel_position),
        _arrays(data),
        jnp.asarray(data.log_current),
        noise_scale * jnp.asarray(data.noise_sd),
        jnp.asarray(whiten),
        jnp.asarray(shifts, dtype=float),
        jnp.asarray(tangent, dtype=float),
        finger,
        data.mode,
        float(nu),
        None if data.gain_sd is None else jnp.asarray(1.0 / np.asarray(data.gain_sd, float) ** 2),
        None if data.gain_sd is None or common_offset_sd is None else jnp.asarray(1.0 / float(common_offset_sd) ** 2),
    )
    return np.asarray(out)


def _means(surfs: Surface, x, arrays, finger, mode):
    return jax.lax.map(lambda tex: _predict(surfs._replace(texture=tex), x, arrays, finger, mode), surfs.texture)


_means_jit = jax.jit(_means, static_argnames=("mode",))


def texture_means(surfs: Surface, data: RawData, finger) -> np.ndarray:
    """Noise-free predicted ln I (K, F·M) of every texture at zero shift (the commanded taxel positions).

    Parameters
    ----------
    surfs : Surface
        Texture fields with a leading axis K.
    data : RawData
        F frames, M taxels.
    finger : Finger

    Returns
    -------
    (K, F·M) float
        Rows in the order of ``data.log_current.ravel()``.
    """
    out = _means_jit(surfs, jnp.asarray(data.taxel_position), _arrays(data), finger, data.mode)
    return np.asarray(out).reshape(out.shape[0], -1)


def stroke_evidence(ll) -> np.ndarray:
    """log p(stroke | k) (K,) from the grid ``ll`` (K, G): the uniform-prior average over shifts, in log space."""
    ll = np.asarray(ll, float)
    return logsumexp(ll, axis=1) - np.log(ll.shape[1])


def update_posterior(log_post, evidence) -> np.ndarray:
    """One Bayes step: normalised log p(k | strokes, this stroke) (K,) from log p(k | strokes) and log p(stroke | k)
    (both (K,))."""
    z = np.asarray(log_post, float) + np.asarray(evidence, float)
    return z - logsumexp(z)


def batch_posterior(log_prior, evidences) -> np.ndarray:
    """Normalised log posterior (K,) after all strokes at once: log prior (K,) + Σ_s log p(stroke_s | k) (S, K)
    − log Z."""
    z = np.asarray(log_prior, float) + np.sum(np.atleast_2d(evidences), axis=0)
    return z - logsumexp(z)
