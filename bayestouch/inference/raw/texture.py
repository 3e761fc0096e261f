"""The texture start of the raw-current level: the grating search on the residuals of the bare shape (wave vectors
1/m in each principal plane), the roughness variance per reading (1/m²), the frames a grating may lie in, and the
polished textured start θ (16,) with its prior box. The texture model itself is :mod:`bayestouch.inference.grating`;
the search is described in ``docs/texture_model.md``.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.optimize import minimize_scalar

from bayestouch.backend import jax, jnp
from bayestouch.geometry.rotation import euler_from_matrix
from bayestouch.geometry.symmetry import canonicalize_batch
from bayestouch.inference import contact as cm
from bayestouch.inference import grating as gr
from bayestouch.inference.grating import RawTexture
from bayestouch.inference.optimize import diag_scale, scaled_lbfgs
from bayestouch.inference.raw.data import RawData, on_device
from bayestouch.inference.raw.likelihood import (
    RAW_OPT_SCALE,
    STUDENT_NU,
    distance_log_current,
    jit_on_data,
    log_prob_value,
    neg_log_post_vg,
    predict_log_current,
    raw_bounds,
    raw_objective,
    response_scaled,
    slot_distances,
)

__all__ = [
    "texture_reference",
    "textured_bounds",
    "search_texture",
    "roughness_variance",
    "TextureStart",
    "canonical_theta",
    "plane_theta",
    "initial_raw_texture",
    "polish_order",
    "BY_STATISTIC",
]


def texture_reference(data: RawData) -> np.ndarray:
    """The grating's phase reference point (3,) m: the mean position of the penetrating taxels."""
    return np.asarray(data.taxel_position, float).reshape(-1, 3).mean(axis=0)


def textured_bounds(data: RawData, priors: cm.PriorParams, tp: gr.TexturePriors, orientation: float) -> cm.Bounds:
    """Prior box (16,): :func:`~bayestouch.inference.raw.likelihood.raw_bounds` and
    :func:`bayestouch.inference.grating.texture_bounds`."""
    b = raw_bounds(data, priors)
    tl, th = gr.texture_bounds(tp, orientation)
    return cm.Bounds(jnp.concatenate([b.lower, jnp.asarray(tl)]), jnp.concatenate([b.upper, jnp.asarray(th)]))


def _height_jvp(th, hh, data: RawData, finger, texture: RawTexture | None = None):
    """Linear response (F, M) of ln I to a height field ``hh (F, J)`` m at the penetrating taxels, at θ."""
    sdf = slot_distances(th[None], data, texture)[0]
    return jax.jvp(
        lambda h: response_scaled(distance_log_current(sdf - h, data, finger), data), (jnp.zeros_like(sdf),), (hh,)
    )[1]


def _pullback(th, data: RawData, finger, *, nu):
    """The bare prediction's robust score pulled back onto the penetrating taxels, c = Jᵀψ (F, J), and the
    readings' inverse variances (F, M) at θ (11,)."""
    sdf0 = slot_distances(th[None], data)[0]
    pred0, vjp = jax.vjp(
        lambda h: response_scaled(distance_log_current(sdf0 - h, data, finger), data), jnp.zeros_like(sdf0)
    )
    r = jnp.asarray(data.log_current) - pred0
    wgt = 1.0 / (jnp.exp(th[10]) * jnp.asarray(data.noise_sd)) ** 2
    return vjp((nu + 1.0) * r * wgt / (nu + r * r * wgt))[0], wgt  # ψ = d log t / d prediction


def _energy(th, data: RawData, finger, xy, kb, wgt, *, nu):
    """Predicted signal energy (K,) of unit gratings of wave vectors ``kb (K, 2)`` 1/m at in-plane foot points
    ``xy (F, J, 2)`` m, linearised at θ (cos and sin phases summed)."""
    ph = jnp.einsum("fjd,kd->kfj", xy, kb)
    out = jax.vmap(lambda hh: _height_jvp(th, hh, data, finger))(jnp.concatenate([jnp.cos(ph), jnp.sin(ph)]))
    e = jnp.sum(out * out * wgt, axis=(1, 2))
    return e[: kb.shape[0]] + e[kb.shape[0] :]


def _height_power(th, data: RawData, finger, hh, texture, *, nu):
    """Σ over fields of the squared linear response (F, M) to height fields ``hh (K, F, J)`` m at θ."""
    return jnp.sum(jax.vmap(lambda h: _height_jvp(th, h, data, finger, texture))(hh) ** 2, axis=0)


def _bare_prediction(th, data: RawData, finger, *, nu):
    """The bare shape's prediction (F, M) at θ, at the data's response factor."""
    return response_scaled(predict_log_current(th, data, finger), data)


def _grating_jacobian(th, data: RawData, finger, zero: RawTexture, *, nu):
    """∂ ln I / ∂(u, v) (F, M, 2) at θ (16,) with u = v = 0."""
    return jax.jacfwd(lambda uv: response_scaled(predict_log_current(th.at[11:13].set(uv), data, finger, zero), data))(
        jnp.zeros(2)
    )


_pullback_jit = jit_on_data(_pullback)
_energy_jit = jit_on_data(_energy)
_height_power_jit = jit_on_data(_height_power)
_bare_prediction_jit = jit_on_data(_bare_prediction)
_grating_jacobian_jit = jit_on_data(_grating_jacobian)


def search_texture(
    theta0,
    data: RawData,
    finger,
    tp: gr.TexturePriors,
    nu: float = STUDENT_NU,
    count: int = 5,
    rings: int = 24,
    directions: int = 32,
    planes=(0, 1, 2),
):
    """Grating candidates from the residuals of the bare-shape estimate ``theta0`` (11,), by the generalised
    likelihood-ratio statistic of a grating of wave vector k in the sampled frame's x–y plane, linearised at
    θ₀: |C(k)|²/A(k) with C(k) = Σ_p c_p e^{−i k·y_p}, where c = Jᵀψ is the robust (Student-t) score ψ of the
    residuals pulled back onto the penetrating taxels' foot points y_p (one vector–Jacobian product of ln I in a
    height field, J), and A(k) = ‖J cos(k·y)‖²_W + ‖J sin(k·y)‖²_W the predicted signal energy of a unit
    grating (W: the readings' inverse variances). C comes from one FFT
    (:func:`bayestouch.inference.grating.grating_peaks`); A, which varies with k only on the scale of the pad
    and the lag's memory, is computed on a polar grid of ``rings`` log-spaced |k| × ``directions`` angles and
    interpolated. A alone matters: the taxel lattice, the skin's blur and the response lag pass some wave
    vectors far better than others, and the plain power |C|² peaks at their aliases. Each peak of the FFT grid is
    then refined off the grid (:func:`bayestouch.inference.grating.refine_peak`).

    Each principal plane of ``planes`` (0: x–y, 1: x–z, 2: y–z of θ₀'s frame) is searched in the frame
    :func:`plane_theta` makes it the x–y plane; ``count`` peaks each.

    Returns
    -------
    list of (plane, wavelength m, orientation rad, statistic)
    """
    th = jnp.asarray(np.asarray(theta0, float)[:11])
    data = on_device(data)
    c, wgt = _pullback_jit(th, data, finger, nu=nu)
    c = np.asarray(c).ravel()
    x = np.asarray(data.taxel_position, float).reshape(-1, 3)
    foot = gr.foot_points(theta0, x)  # principal frame of θ₀
    s = cm.shape_of(np.asarray(theta0, float))
    yref = (texture_reference(data) - np.asarray(s.centre)) @ np.asarray(s.rotation)

    # A(k) on a polar grid: one linearised forward per (k, cos | sin), in batches; the linearisation is the same
    # for every plane (one surface), only the points' in-plane coordinates differ
    logk = np.linspace(np.log(2 * np.pi / tp.wavelength_max), np.log(2 * np.pi / tp.wavelength_min), rings)
    ang = np.arange(directions) * np.pi / directions
    kv = (np.exp(logk)[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], -1)[None]).reshape(-1, 2)
    nb = 16
    kp = jnp.asarray(np.concatenate([kv, np.repeat(kv[-1:], -len(kv) % nb, 0)]))

    found = []
    for plane in planes:
        P = _PLANES[plane]
        xy = (foot @ P)[:, :2] - (yref @ P)[:2]  # coordinates in the frame R P (plane_theta's)
        xy_j = jnp.asarray(xy.reshape(np.shape(data.taxel_position)[:2] + (2,)))
        A = np.concatenate(
            [np.asarray(_energy_jit(th, data, finger, xy_j, kp[i : i + nb], wgt, nu=nu)) for i in range(0, len(kp), nb)]
        )[: len(kv)]
        A = A.reshape(rings, directions)
        # periodic in angle with period π (A(k) = A(−k)): pad one column each side
        interp = RegularGridInterpolator(
            (logk, np.concatenate([[ang[-1] - np.pi], ang, [np.pi]])),
            np.log(np.concatenate([A[:, -1:], A, A[:, :1]], axis=1)),
            bounds_error=False,
            fill_value=None,
        )

        def norm(kx, ky, interp=interp):
            kk = np.clip(np.hypot(kx, ky), np.exp(logk[0]), np.exp(logk[-1]))
            return np.exp(interp(np.column_stack([np.log(kk), np.arctan2(ky, kx) % np.pi])))

        peaks = gr.grating_peaks(c, xy, tp.wavelength_min, tp.wavelength_max, norm=norm, count=count)
        found += [(plane, *gr.refine_peak(c, xy, lam, o, norm)) for lam, o, _ in peaks]
    return found


def roughness_variance(theta, data: RawData, finger, texture: RawTexture, count: int = 128, seed: int = 0):
    """v (F, M), 1/m²: the variance of each reading's ln I per unit roughness RMS², by Monte Carlo over ``count``
    unit-RMS fields of the scene's roughness family (:func:`bayestouch.inference.grating.roughness_fields`, at the
    grating wavelength of ``theta`` (16,)) through the forward model linearised in the height at ``theta``."""
    th = jnp.asarray(np.asarray(theta, float))
    F, J = np.shape(data.taxel_position)[:2]
    foot = gr.foot_points(theta, np.asarray(data.taxel_position, float).reshape(-1, 3))
    fields = gr.roughness_fields(foot, float(np.exp(theta[13])), count, np.random.default_rng(seed))
    data = on_device(data)
    acc = np.zeros(np.shape(data.log_current))
    for chunk in np.array_split(fields, max(1, count // 16)):
        acc += np.asarray(_height_power_jit(th, data, finger, jnp.asarray(chunk.reshape(-1, F, J)), texture))
    return acc / count


class TextureStart(NamedTuple):
    """Result of :func:`initial_raw_texture`.

    theta : (16,) float
        The polished textured optimum.
    texture : RawTexture
    bounds : Bounds
        The prior box (16,).
    gain : float
        Log-posterior of the best grating (roughness at its floor) minus the bare shape's, both polished on the same
        data, nats: the evidence for a grating.
    candidates : list of (plane, wavelength m, orientation rad, statistic)
        :func:`search_texture`'s, in each principal plane (0: x–y, 1: x–z, 2: y–z, :func:`plane_theta`).
    neg_log_post : callable
        θ (16,) → (value, gradient) of the negative log-posterior (jitted), for
        :func:`~bayestouch.inference.optimize.laplace`.
    """

    theta: np.ndarray
    texture: RawTexture
    bounds: cm.Bounds
    gain: float
    candidates: list
    neg_log_post: object


def _reduce_psi(th: np.ndarray) -> np.ndarray:
    """ψ into [0, π) (the prior box): ψ + π flips the signs of the principal x and y axes, a symmetry of the
    centrally symmetric n-ellipsoid."""
    th = th.copy()
    th[7] = th[7] % np.pi
    return th


def canonical_theta(theta) -> np.ndarray:
    """θ (11,) with its n-ellipsoid in the canonical frame (a ≥ b ≥ c along x, y, z;
    :func:`bayestouch.geometry.symmetry.canonicalize`, ψ reduced into [0, π)): the same surface, so the same
    likelihood."""
    th = np.asarray(theta, float)[:11].copy()
    v = np.concatenate([th[:3], np.exp(th[3:6]), th[6:9], [np.exp(th[9])]])
    c = canonicalize_batch(v[None])[0]
    th[3:6], th[6:9] = np.log(c[3:6]), c[6:9]
    return _reduce_psi(th)


#: candidates of the texture search that :func:`initial_raw_texture` polishes for their search statistic alone,
#: beside the ``polish`` best by the linearised fit: the linearised amplitude of a real grating can put it below
#: near-zero aliases (bench_mismatch scenario 10: the 1.99 mm grating, statistic 2,655 against the next 1,180, ranked
#: 11th of 15, 2,300 nats below a 5.2 mm pattern of 3 µm)
BY_STATISTIC = 2

#: the principal planes a grating may lie in, as the proper signed permutations that make each the x–y plane:
#: (x, y), (x, z) and (y, z) of the canonical frame
_PLANES = (np.eye(3), np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]]))


def plane_theta(theta, plane: int) -> np.ndarray:
    """θ (11,) in the frame whose x–y plane is principal plane ``plane`` (0: x–y, 1: x–z, 2: y–z) of θ's frame: the
    same surface, the axes and rotation permuted (R' = R P, det P = 1)."""
    th = np.asarray(theta, float)[:11].copy()
    P = _PLANES[plane]
    R = np.asarray(cm.shape_of(th).rotation) @ P
    perm = np.argmax(np.abs(P), axis=0)  # new axis j is old axis perm[j]
    th[3:6] = th[3:6][perm]
    th[6:9] = np.asarray(euler_from_matrix(jnp.asarray(R)))
    return _reduce_psi(th)


def polish_order(statistics, polish: int, by_statistic: int = BY_STATISTIC) -> list[int]:
    """Indices of the texture candidates :func:`initial_raw_texture` polishes, given their search ``statistics``
    in the order of their linearised log-posteriors (best first): the ``polish`` first and the ``by_statistic``
    with the largest statistic, each once, in ranked order."""
    top = set(range(min(polish, len(statistics))))
    strongest = sorted(range(len(statistics)), key=lambda i: -statistics[i])[:by_statistic]
    return sorted(top | set(strongest))


def initial_raw_texture(
    theta0,
    data: RawData,
    finger,
    priors: cm.PriorParams,
    tp: gr.TexturePriors,
    nu: float = STUDENT_NU,
    count: int = 5,
    seed: int = 0,
    polish: int = 6,
):
    """Textured start from the bare-shape estimate ``theta0`` (11,), on ``data`` of a known device (the residuals of
    the search hold no per-taxel offsets or response factor: with those marginalised, call
    :func:`bayestouch.inference.raw.fit.texture_start`, which fixes them first).

    1. The bare shape is polished on ``data`` (L-BFGS-B, :func:`~bayestouch.inference.optimize.scaled_lbfgs`) and
       put in the canonical frame (:func:`canonical_theta`).
    2. Each principal plane (x–y, x–z, y–z) is searched for ``count`` grating candidates (:func:`search_texture` in
       the frame :func:`plane_theta` makes that plane its x–y plane): the grating's plane fixes the frame where
       the shape alone does not (the egg's b = c). The orientation is measured from the first axis of that plane.
    3. Each candidate's amplitude and phase (u, v) are the weighted least-squares fit of the forward model
       linearised in (u, v), with the noise multiplier k profiled out.
    4. The ``polish`` best, and the :data:`BY_STATISTIC` strongest by the search's statistic
       (:func:`polish_order`), are ranked by short L-BFGS-B runs over all parameters but the roughness (held at its
       floor): a few strokes leave aliases ~5–10 % apart in wavelength nearly as good, and the linearised ranking,
       done in a frame the grating's plane may be tilted from and at a lag the fit has not yet found, can put one
       first, or put the grating itself below near-zero patterns. The best is polished to convergence; its gain
       over the polished bare shape is the evidence for a grating.
    5. The roughness variance :func:`roughness_variance` is computed there, and all 16 parameters are polished
       again from a roughness of a fifth of the amplitude.

    Returns
    -------
    TextureStart
    """
    # the bare shape polished on these data (θ₀ may come from other frames): its residuals then hold no first-order
    # shape misfit for the search to mistake for a grating, and its log-posterior is the baseline of the gain
    data = on_device(data)
    bare_b = raw_bounds(data, priors)
    bare_fn = raw_objective(data, finger, bare_b, nu=nu)
    theta0, f_bare = scaled_lbfgs(
        bare_fn, canonical_theta(theta0), np.asarray(bare_b.lower), np.asarray(bare_b.upper), RAW_OPT_SCALE[:11]
    )
    theta0 = canonical_theta(theta0)
    ref = texture_reference(data)
    frames = [plane_theta(theta0, p) for p in range(len(_PLANES))]
    cands = search_texture(theta0, data, finger, tp, nu, count, planes=range(len(_PLANES)))
    zero = RawTexture(ref, np.zeros(np.shape(data.log_current)), tp.amplitude_scale)
    pred0 = _bare_prediction_jit(jnp.asarray(theta0), data, finger, nu=nu)
    w = (1.0 / (np.exp(theta0[10]) * np.asarray(data.noise_sd)) ** 2).ravel()
    r = (np.asarray(data.log_current) - np.asarray(pred0)).ravel()  # the textured prediction at u = v = 0

    def jac_uv(th):  # ∂ ln I / ∂(u, v) at u = v = 0, (F, M, 2)
        return _grating_jacobian_jit(th, data, finger, zero, nu=nu)

    def value(t, b, tex):
        return log_prob_value(t, data, finger, b, tex, nu=nu)

    def profile_k(th, b, tex):  # max over the noise multiplier log k of the log-posterior at θ's other entries
        def neg(lk):
            return -float(value(jnp.asarray(th).at[10].set(lk), b, tex))

        res = minimize_scalar(
            neg, bounds=(float(b.lower[10]), float(b.upper[10])), method="bounded", options={"xatol": 1e-3}
        )
        return -float(res.fun), float(res.x)

    ranked = []
    for p, lam, o, stat in cands:
        b = textured_bounds(data, priors, tp, o)
        th = np.concatenate([frames[p], [0.0, 0.0, np.log(lam), o, np.log(tp.roughness_min)]])
        X = np.asarray(jac_uv(jnp.asarray(th))).reshape(-1, 2)
        uv = np.linalg.lstsq(X.T @ (w[:, None] * X), X.T @ (w * r), rcond=None)[0]
        th[11:13] = np.clip(uv, np.asarray(b.lower)[11:13], np.asarray(b.upper)[11:13])
        val, th[10] = profile_k(th, b, zero)
        ranked.append((val, th, b, stat))
    ranked.sort(key=lambda x: -x[0])

    # the linearised ranking can put an alias first: a few strokes leave wavelengths ~5–10 % apart nearly as good
    # while the grating's plane is tilted from the search frame's (the egg's frame is fixed about its long axis only
    # to ~4° by four strokes). Short L-BFGS-B runs (roughness at its floor, all else free) from the ``polish`` best
    # rank them; the best is polished to convergence.
    # one compiled program for every box and both roughness models (b and tex are arguments, not constants)
    def fn_any(t, b, tex):
        return neg_log_post_vg(t, data, finger, b, tex, nu=nu)

    fn0 = partial(fn_any, tex=zero)

    def floored(b):  # the box with the roughness held at its floor
        lo, hi = np.array(b.lower), np.array(b.upper)
        hi[15] = lo[15]
        return lo, hi

    sc = None
    best = None
    for i in polish_order([r[3] for r in ranked], polish):
        _, th, b, _ = ranked[i]
        lo, hi = floored(b)
        sc = diag_scale(partial(fn0, b=b), th, lo, hi, RAW_OPT_SCALE) if sc is None else sc
        th, f = scaled_lbfgs(partial(fn0, b=b), th, lo, hi, sc, maxiter=25, rounds=1, rescale=False)
        if best is None or -f > best[0]:
            best = (-f, th, b)
    _, th, b = best
    th, f = scaled_lbfgs(partial(fn0, b=b), th, *floored(b), RAW_OPT_SCALE)
    gain = f_bare - f  # the evidence for the grating: against the bare shape polished on the same data
    lo, hi = np.array(b.lower), np.array(b.upper)
    tex = zero._replace(rough_var=roughness_variance(th, data, finger, zero, seed=seed))
    th[15] = np.clip(np.log(max(np.hypot(th[11], th[12]) / 5.0, tp.roughness_min * 10)), lo[15], hi[15])
    fn = partial(fn_any, b=b, tex=tex)
    th, _ = scaled_lbfgs(fn, th, lo, hi, RAW_OPT_SCALE)
    return TextureStart(th, tex, b, gain, cands, fn)
