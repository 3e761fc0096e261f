"""The discrete texture posterior: p(k | strokes) over the K textures of a library from each stroke's raw currents.

A recorded stroke is read as :class:`~bayestouch.inference.raw.RawData` (F frames, M taxels: corrected ln I and its
noise sd, dimensionless; taxel positions in metres). Texture k enters only through the signed distance at the known
taxel positions, then the forward chain :func:`bayestouch.physics.forward.log_current_from_distance`; each taxel's
standardised residuals are whitened over frames (:func:`frame_whitener`) before a Student-t. The start phase is
marginalised over a grid of G shifts (metres). Derivation and measurements: ``docs/texture_identification.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import logsumexp

from bayestouch.backend import jax, jnp
from bayestouch.inference.densities import student_t_logpdf
from bayestouch.inference.raw import STUDENT_NU, HostDevice, RawData, load_raw_data
from bayestouch.io.recording import build_dataset
from bayestouch.physics import forward as fw
from bayestouch.physics import noise as nz
from bayestouch.physics import taxel as tx
from bayestouch.scene.surface import Surface, signed_distance

__all__ = [
    "COMMON_OFFSET_SD",
    "read_stroke",
    "frame_whitener",
    "texture_log_likelihood",
    "offset_projection",
    "Nuisances",
    "stroke_nuisances",
    "nuisance_projection",
    "response_projection",
    "texture_means",
    "stroke_evidence",
    "texture_evidence",
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
    slow = np.diag(nz.frame_covariance(finger.noise, np.zeros(F), t))  # the 1/f and walk variances
    total = np.median(np.asarray(data.noise_sd) ** 2, axis=1)
    cov = nz.frame_covariance(finger.noise, np.maximum(total - slow, 1e-3 * total), t)
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


class Nuisances(NamedTuple):
    """What one stroke's likelihood marginalises besides the shift, precomputed once per stroke
    (:func:`stroke_nuisances`; arrays, dimensionless).

    whiten : (F, F) float
        L⁻¹ of :func:`frame_whitener`.
    inv_sd : (F, M) float
        1 / the sd of each reading's own noise (the common ĉ error left out when it is modelled).
    u : (F, M) float
        ``whiten @ inv_sd``: a per-taxel offset's pattern in the whitened residuals.
    q : (M,) float
        1/(precision_m + u_mᵀu_m); zeros where the gains are known.
    gain_prec : (M,) float or None
        Prior precision of each taxel's log-gain offset.
    common_prec : float or None
        Prior precision of the stroke-wide common offset (only when ``frame_prec`` is None).
    frame_prec : (F, F) float or None
        Prior precision S⁻¹ of the per-frame common error e (the reference row's ĉ error, variance
        ``RawData.common_var``, plus the stroke-wide offset as a constant direction).
    frame_post_cov : (F, F) float or None
        A⁻¹, A = S⁻¹ + Σ_m E_mᵀ Q_m E_m (E_m = whiten · diag(inv_sd_m), Q_m the taxel offset's projector).
    """

    whiten: np.ndarray
    inv_sd: np.ndarray
    u: np.ndarray
    q: np.ndarray
    gain_prec: np.ndarray | None
    common_prec: float | None
    frame_prec: np.ndarray | None
    frame_post_cov: np.ndarray | None


def stroke_nuisances(
    data: RawData,
    finger,
    *,
    noise_scale: float = 1.0,
    correlated: bool = True,
    common_offset_sd: float | None = COMMON_OFFSET_SD,
    frame_common: bool = True,
) -> Nuisances:
    """The nuisance terms of one stroke (:class:`Nuisances`; arguments as :func:`texture_log_likelihood`)."""
    F, M = np.shape(data.log_current)
    var = (noise_scale * np.asarray(data.noise_sd, float)) ** 2
    cv = None if data.common_var is None or not frame_common else noise_scale**2 * np.asarray(data.common_var, float)
    if cv is not None:
        var = var - cv[:, None]
    inv_sd = 1.0 / np.sqrt(var)
    own = data._replace(noise_sd=np.sqrt(var))
    whiten = frame_whitener(own, finger) if correlated else np.eye(F)
    u = whiten @ inv_sd
    a = np.sum(u * u, axis=0)
    if data.gain_sd is None:
        gain_prec, q, kappa = None, np.zeros(M), 0.0
    else:
        gain_prec = 1.0 / np.asarray(data.gain_sd, float) ** 2
        q = 1.0 / (gain_prec + a)
        kappa = 0.0 if common_offset_sd is None else float(common_offset_sd) ** 2
    if cv is None:
        common_prec = None if kappa == 0.0 else 1.0 / kappa
        return Nuisances(whiten, inv_sd, u, q, gain_prec, common_prec, None, None)
    # S = the ĉ error's covariance over frames + κ 11ᵀ; A = S⁻¹ + V∘(inv_sd inv_sdᵀ) − Σ_m q_m t_m t_mᵀ,
    # t_m = D_m Wᵀ u_m
    if data.common_cov is None:
        S = np.diag(cv)
    else:
        S = noise_scale**2 * np.asarray(data.common_cov, float)
    S = S + kappa + 1e-9 * np.mean(cv) * np.eye(F)
    frame_prec = np.linalg.inv(S)
    t = inv_sd * (whiten.T @ u)
    A = frame_prec + (whiten.T @ whiten) * (inv_sd @ inv_sd.T) - (t * q) @ t.T
    return Nuisances(whiten, inv_sd, u, q, gain_prec, None, frame_prec, np.linalg.inv(A))


def nuisance_projection(z, nuis: Nuisances):
    """Whitened standardised residuals ``z (F, M)`` with every nuisance of :class:`Nuisances` taken out at its
    posterior mean, and their prior term (any array module; :func:`offset_projection` for the per-taxel and
    stroke-wide offsets alone).

    The reference row's correction ĉ_f of each frame is a median over a few reference taxels: its error e_f
    (variance ``RawData.common_var``) is one and the same in every taxel of frame f. Counted as independent noise
    per reading it is counted M times over, and a hypothesis whose prediction differs from another's by a pattern
    with a non-zero mean over the taxels of a frame gains evidence from it: measured on two textures 5.7 % apart
    in grating amplitude, the log evidence ratio varied over noise draws far more than the model allowed
    (var/(2·mean) 4.1 over 48 draws, where a calibrated likelihood gives 1), and one trial in 120 decided for the
    wrong twin with p(truth) = 3e-5. Here e ~ N(0, S) is marginalised with the offsets: the model is
    z_m = E_m e + δ_m u_m + noise, E_m = L⁻¹ diag(1/sd_m); with each δ_m profiled (Q_m = I − q_m u_m u_mᵀ),
    ê = A⁻¹ Σ_m E_mᵀ Q_m z_m, δ̂_m = q_m u_mᵀ (z_m − E_m ê), and for Gaussian readings the marginal likelihood is
    that of z − E ê − δ̂ u times exp(−½ (êᵀ S⁻¹ ê + Σ_m precision_m δ̂_m²)), up to a factor of the data alone.
    Measured with it: 0.84 on the same draws (``docs/texture_identification.md``).

    Returns
    -------
    residual : (F, M)
    log_factor : float
    """
    W, inv_sd, u, q = nuis.whiten, nuis.inv_sd, nuis.u, nuis.q
    if nuis.frame_prec is None:
        if nuis.gain_prec is None:
            return z, 0.0
        return offset_projection(z, u, nuis.gain_prec, nuis.common_prec)
    qz = z - u * (q * jnp.sum(u * z, axis=0))[None]
    e = nuis.frame_post_cov @ jnp.sum(inv_sd * (W.T @ qz), axis=1)
    r = z - W @ (inv_sd * e[:, None])
    log_factor = -0.5 * e @ nuis.frame_prec @ e
    if nuis.gain_prec is None:
        return r, log_factor
    delta = q * jnp.sum(u * r, axis=0)
    return r - delta[None] * u, log_factor - 0.5 * jnp.sum(nuis.gain_prec * delta * delta)


def response_projection(z, g, nuis: Nuisances, precision):
    """:func:`nuisance_projection` joined by the taxels' common response factor a = a₀ + α, α ~ N(0, 1/``precision``),
    which adds α g to the whitened residuals ``z`` (F, M), g (F, M) the whitened, standardised Δ ln I of the
    hypothesis (its prediction less the unloaded baseline).

    With P the marginal precision of the other nuisances (P z is :func:`nuisance_projection`'s residual), for
    Gaussian readings α̂ = gᵀPz / (gᵀPg + precision), and the marginal likelihood is that of the projection of
    z − α̂ g times exp(−½ precision α̂²) / √((gᵀPg + precision)/precision), up to factors of the data alone: the
    determinant depends on the hypothesis through g and is kept. Returns (residual (F, M), log factor)."""
    pg, _ = nuisance_projection(g, nuis)
    h = jnp.sum(pg * g)
    alpha = jnp.sum(pg * z) / (h + precision)
    r, log_factor = nuisance_projection(z - alpha * g, nuis)
    return r, log_factor - 0.5 * precision * alpha * alpha - 0.5 * jnp.log1p(h / precision)


def _ll_grid(surfs: Surface, x, arrays, y, nuis: Nuisances, response, shifts, tangent, finger, mode, nu):
    """(K, G, L) log-likelihood, L the rows of the lag weights ``arrays[3]`` (L, 3) (the currents before the lag
    computed once for all of them); ``response`` = (a₀, its prior precision or None, the unloaded baseline
    (F, M))."""
    a0, resp_prec, baseline = response
    temp, start, kernel, lags = arrays

    def one_texture(args):
        tex, shifts_k = args
        surf = surfs._replace(texture=tex)

        def one_shift(o):
            cur = fw.current_from_distance(finger, signed_distance(surf, x + o * tangent), kernel, temp, mode)

            def one_lag(lw):
                raw = jnp.log(tx.coarse_lag(cur, start, lw))
                ok = jnp.isfinite(raw)
                delta = jnp.where(ok, raw - baseline, 0.0)
                z = nuis.whiten @ jnp.where(ok, (y - baseline - a0 * delta) * nuis.inv_sd, 1e6)
                if resp_prec is None:
                    z, prior = nuisance_projection(z, nuis)
                else:
                    z, prior = response_projection(z, nuis.whiten @ (delta * nuis.inv_sd), nuis, resp_prec)
                return jnp.sum(student_t_logpdf(z, 1.0, nu)) + prior

            return jax.vmap(one_lag)(lags)

        return jax.vmap(one_shift)(shifts_k)

    return jax.lax.map(one_texture, (surfs.texture, shifts))


_ll_grid_jit = jax.jit(_ll_grid, static_argnames=("mode", "nu"))


def texture_log_likelihood(
    surfs: Surface,
    data: RawData,
    finger,
    shifts,
    tangent,
    *,
    nu: float = STUDENT_NU,
    noise_scale: float = 1.0,
    correlated: bool = True,
    common_offset_sd: float | None = COMMON_OFFSET_SD,
    frame_common: bool = True,
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
    shifts : (G,) or (K, G) float, metres
        Shifts of the pad along the stroke (the same for every texture, or each texture's own).
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
    frame_common : bool
        Model the reference row's per-frame error as common to every taxel of a frame (``data.common_var``,
        :func:`nuisance_projection`); False counts it as independent noise per reading (which over-counts it).

    Returns
    -------
    (K, G) float
        Up to a constant common to all (k, g) when ``correlated``.
    """
    nuis = stroke_nuisances(
        data,
        finger,
        noise_scale=noise_scale,
        correlated=correlated,
        common_offset_sd=common_offset_sd,
        frame_common=frame_common,
    )
    return _grid_log_likelihood(surfs, data, finger, shifts, tangent, nuis, nu)[..., 0]


def _grid_log_likelihood(
    surfs: Surface, data: RawData, finger, shifts, tangent, nuis: Nuisances, nu, lags=None
) -> np.ndarray:
    """:func:`texture_log_likelihood` (K, G, L) with the stroke's nuisances given (one :func:`stroke_nuisances`
    serves every grid of a stroke), for each row of the lag weights ``lags`` (L, 3) (default the data's own)."""
    K = int(np.shape(jax.tree.leaves(surfs.texture)[0])[0])
    shifts = np.broadcast_to(np.asarray(shifts, dtype=float), (K, np.shape(shifts)[-1]))
    lags = np.atleast_2d(np.asarray(data.lag_weights if lags is None else lags, dtype=float))
    temp, start, kernel, _ = _arrays(data)
    out = _ll_grid_jit(
        surfs,
        jnp.asarray(data.taxel_position),
        (temp, start, kernel, jnp.asarray(lags)),
        jnp.asarray(data.log_current),
        jax.tree.map(jnp.asarray, nuis),
        (
            jnp.asarray(float(data.response_scale)),
            None if data.response_sd is None else jnp.asarray(1.0 / float(data.response_sd) ** 2),
            jnp.asarray(data.baseline),
        ),
        jnp.asarray(shifts),
        jnp.asarray(tangent, dtype=float),
        finger,
        data.mode,
        float(nu),
    )
    return np.asarray(out)


def texture_evidence(
    surfs: Surface,
    data: RawData,
    finger,
    shifts,
    tangent,
    *,
    peaks: int = 2,
    subdivide: int = 8,
    lags=None,
    **likelihood,
) -> np.ndarray:
    """log p(stroke | k) (K,): the likelihood integrated over a uniform start-phase shift, the grid refined where
    each texture's likelihood peaks.

    A strong texture signal makes the likelihood in the shift a peak a few µm wide (measured: 5 µm at 0.5 nats
    below the top for a 44 µm grating of 2.3 mm period), narrower than the grid step (25 µm): on the grid alone
    the evidence depends on how near a node happens to fall to each texture's peak, off by up to tens of nats
    between two textures alike to a few per cent, enough to decide confidently for the wrong twin. So the grid
    ``shifts`` is a first pass: around each texture's ``peaks`` highest local maxima the node and its two
    neighbours are replaced by ``subdivide`` nodes each (the midpoint rule on cells of step/``subdivide``), and the
    evidence is the midpoint-rule integral over the grid's whole range divided by that range.

    Parameters
    ----------
    surfs, data, finger, tangent
        As :func:`texture_log_likelihood`.
    shifts : (G,) float, metres
        A uniform grid of shifts (G ≥ 3), the cell centres of the prior's support.
    peaks : int
        Local maxima refined per texture.
    subdivide : int
        Fine cells per refined grid cell.
    lags : (L, 3) float, optional
        Lag weights (:func:`bayestouch.physics.taxel.coarse_lag_weights` at ``data.dt``) of L response lags: the
        evidence of every texture under each (the taxels' lag is not calibrated, and a first-order lag attenuates a
        grating's signal by 1/√(1 + (2π f τ)²): ±10 % in τ moves a 5 Hz grating's amplitude by ∓9 %, as much as
        two textures of a library may differ). None: the data's own lag.
    **likelihood
        ``nu``, ``noise_scale``, ``correlated``, ``common_offset_sd`` of :func:`texture_log_likelihood`.

    Returns
    -------
    (K,) or (K, L) float
        Up to a constant common to all k (and lags); (K, L) when ``lags`` is given.
    """
    shifts = np.asarray(shifts, float)
    G = shifts.size
    h = float(shifts[1] - shifts[0]) if G > 1 else 0.0
    lag_rows = np.atleast_2d(np.asarray(data.lag_weights if lags is None else lags, dtype=float))
    nu = likelihood.pop("nu", STUDENT_NU)
    nuis = stroke_nuisances(data, finger, **likelihood)  # once for every grid of this stroke
    ll = _grid_log_likelihood(surfs, data, finger, shifts, tangent, nuis, nu, lag_rows)  # (K, G, L)
    if G < 3 or not np.allclose(np.diff(shifts), h) or h <= 0:
        out = stroke_evidence(ll)
        return out[:, 0] if lags is None else out
    K = ll.shape[0]
    n_cells = 3 * peaks
    weight = np.full((K, G), h)
    fine = np.zeros((K, n_cells * subdivide))
    fine_w = np.zeros_like(fine)
    offsets = (np.arange(subdivide) + 0.5) * h / subdivide - 0.5 * h
    best = ll.max(axis=2)  # the peaks of the best lag at each shift: the lags' peaks lie within a cell or two
    for k in range(K):
        row = np.concatenate([[-np.inf], best[k], [-np.inf]])
        local = np.flatnonzero((row[1:-1] >= row[:-2]) & (row[1:-1] >= row[2:]))
        top = local[np.argsort(best[k, local])[::-1][:peaks]]
        cells = sorted({c for g in top for c in (g - 1, g, g + 1) if 0 <= c < G})
        for j, c in enumerate(cells):
            weight[k, c] = 0.0
            fine[k, j * subdivide : (j + 1) * subdivide] = shifts[c] + offsets
            fine_w[k, j * subdivide : (j + 1) * subdivide] = h / subdivide
        fine[k, len(cells) * subdivide :] = shifts[0]  # padding, weight 0
    ll_fine = _grid_log_likelihood(surfs, data, finger, fine, tangent, nuis, nu, lag_rows)
    with np.errstate(divide="ignore"):
        terms = np.concatenate([ll + np.log(weight)[..., None], ll_fine + np.log(fine_w)[..., None]], axis=1)
    out = logsumexp(terms, axis=1) - np.log(G * h)
    return out[:, 0] if lags is None else out


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
    """log p(stroke | k) (K,) from the grid ``ll`` (K, G): the uniform-prior average over shifts, in log space;
    (K, L) from (K, G, L), one column per lag."""
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
