"""Texture of the raw-current level: a sinusoidal grating (amplitude, wavelength, orientation, phase) and a random
roughness (RMS), on the n-ellipsoid, as the scene's texture height field (:func:`bayestouch.scene.surface.height`)
defines them: the five parameters appended to the raw level's 11 (u, v m, log λ log m, orientation rad,
log roughness log m), their prior, the textured signed distance (W, P) m, the grating's peak search in a plane and
the roughness fields. The model and its search: ``docs/texture_model.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import minimize

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference.contact import principal_frame, shape_of
from bayestouch.params import MODELS, Spec, build

__all__ = [
    "TEXTURE_NAMES",
    "TEXTURE_NATURAL_NAMES",
    "RawTexture",
    "distance_batch",
    "foot_points",
    "grating_peaks",
    "refine_peak",
    "roughness_fields",
    "texture_natural",
    "scene_uv",
    "TexturePriors",
    "load_texture_priors",
    "texture_bounds",
    "texture_log_prior",
]

#: sampled texture parameters (after the raw level's 11)
TEXTURE_NAMES = ("tex_u", "tex_v", "log_wavelength", "orientation", "log_roughness")
#: their summary names: m, m, rad, rad, m
TEXTURE_NATURAL_NAMES = ("amplitude", "wavelength", "orientation", "phase", "roughness")

_TWO_PI = 2.0 * np.pi


TEXTURE_PRIOR_SPECS = {
    "amplitude_scale": Spec("m", 1e-9, 1.0),
    "wavelength_min": Spec("m", 1e-6, 1.0),
    "wavelength_max": Spec("m", 1e-5, 10.0),
    "roughness_min": Spec("m", 1e-12, 1.0),
    "roughness_max": Spec("m", 1e-9, 1.0),
}


class TexturePriors(NamedTuple):
    """``[texture_priors]`` of ``models/priors.toml`` (metres)."""

    amplitude_scale: float
    wavelength_min: float
    wavelength_max: float
    roughness_min: float
    roughness_max: float


def load_texture_priors(path=None) -> TexturePriors:
    """Read ``[texture_priors]`` of ``models/priors.toml`` (or ``path``)."""
    p = MODELS / "priors.toml" if path is None else path
    tp = build(TexturePriors, p, "texture_priors", TEXTURE_PRIOR_SPECS)
    if not (tp.wavelength_min < tp.wavelength_max and tp.roughness_min < tp.roughness_max):
        raise BadInput(
            f"{p} [texture_priors]: expected wavelength_min < wavelength_max and roughness_min < roughness_max (metres)"
        )
    return tp


def texture_bounds(tp: TexturePriors, orientation: float) -> tuple[np.ndarray, np.ndarray]:
    """Box (lower, upper) (5,) of the texture parameters: u, v within ±5 A₀, log λ and log σ_r in the prior's
    range, o in [o₀ − π/2, o₀ + π/2) around the search's ``orientation`` o₀ (rad)."""
    A = 5.0 * tp.amplitude_scale
    lo = np.array([-A, -A, np.log(tp.wavelength_min), orientation - np.pi / 2, np.log(tp.roughness_min)])
    hi = np.array([A, A, np.log(tp.wavelength_max), orientation + np.pi / 2, np.log(tp.roughness_max)])
    return lo, hi


def texture_log_prior(th, amplitude_scale: float):
    """Log-density (up to a constant) of the texture part of θ (…, ≥ 16) inside its box: u, v ~ N(0, A₀²) with
    A₀ = ``amplitude_scale`` (m); log λ, o and log σ_r uniform."""
    return -0.5 * (th[..., 11] ** 2 + th[..., 12] ** 2) / amplitude_scale**2


class RawTexture(NamedTuple):
    """What the textured raw likelihood needs beyond :class:`~bayestouch.inference.raw.data.RawData`.

    ref : (3,) float, metres
        World reference point of the grating's phase.
    rough_var : (F, M) float, 1/m²
        Variance of each reading's ln I per unit roughness RMS² (:func:`roughness_fields` through the
        linearised forward model).
    amplitude_scale : float, metres
        A₀, the sd of the N(0, A₀²) prior of u and v.
    """

    ref: np.ndarray
    rough_var: np.ndarray
    amplitude_scale: float


def distance_batch(th, hom, ref=None):
    """Signed distance (W, P) m of points to the surfaces of walkers ``th (W, D)``: the n-ellipsoid's first-order
    distance (the contact level's batched kernel, :func:`bayestouch.inference.contact.principal_frame`, float64), minus
    the grating height at the foot point when ``ref`` is given (``th`` then holds the texture parameters at 11–14).

    Parameters
    ----------
    th : (W, D) float
        Raw-level parameter vectors (centre m, log axes, Euler angles rad, log n, …).
    hom : (4, P) float
        Homogeneous world points (x, y, z, 1), metres.
    ref : (3,) float, metres, optional
        Phase reference point (:class:`RawTexture`).

    Notes
    -----
    float64 throughout: float32 powers round the distance by ~2 nm (6e-8 of the coordinates), which over ~10⁵
    readings whose posterior sd is ~50 nm makes the log-density jitter by ~0.1–0.4 nat between neighbouring θ:
    enough to stall an optimiser.

    The grating coordinate s = (x − d n̂ − x_ref)·d_w, d_w = R (cos o, sin o, 0) the grating direction in the world
    and n̂ the outward unit normal (foot point, principal-frame form), needs no world-frame normal: with
    x − c = R (a ∘ q) and n̂ = R (sign q ∘ v)/√ss (the kernel's own q, v and ss),
    (x − x_ref)·d_w = (c − x_ref)·d_w + a₁q₁ cos o + a₂q₂ sin o and n̂·d_w = (sign q₁ v₁ cos o + sign q₂ v₂ sin o)/√ss.
    Equal to the world-frame form to rounding, in about half the time (no per-point rotation or normalisation).
    """
    f = principal_frame(th, hom)
    if ref is None:
        return f.d
    o = th[:, 14]
    co, so = jnp.cos(o)[:, None], jnp.sin(o)[:, None]
    d_world = f.R[:, :, 0] * co + f.R[:, :, 1] * so  # (W, 3)
    base = jnp.sum((th[:, 0:3] - jnp.asarray(ref)[None]) * d_world, axis=1)[:, None]
    q, v = f.q, f.v
    n_dot = (jnp.sign(q[:, 0]) * v[:, 0] * co + jnp.sign(q[:, 1]) * v[:, 1] * so) / jnp.sqrt(f.ss + 1e-300)
    s = base + f.a[:, 0:1] * co * q[:, 0] + f.a[:, 1:2] * so * q[:, 1] - f.d * n_dot
    ph = s * (_TWO_PI * jnp.exp(-th[:, 13]))[:, None]
    return f.d - (th[:, 11][:, None] * jnp.sin(ph) + th[:, 12][:, None] * jnp.cos(ph))


@jax.jit
def _foot(theta, points):
    s = shape_of(theta)
    y = ne.to_local(s, points)
    dist, grad, gnorm = ne.first_order_distance(s, y)
    return y - (dist / gnorm)[:, None] * grad


def foot_points(theta, points) -> np.ndarray:
    """Foot points (P, 3) m, in the principal frame of the shape θ (≥ 10,), of world ``points (P, 3)`` m."""
    return np.asarray(_foot(jnp.asarray(np.asarray(theta, float)[:10]), jnp.asarray(points, jnp.float64)))


def _significant(weights, xy):
    """The weights (P',) and points (P', 2) whose weight exceeds 1e-6 of the largest (the rest add nothing)."""
    w, p = np.asarray(weights, float), np.asarray(xy, float)
    if w.size and np.abs(w).max() > 0:
        keep = np.abs(w) > 1e-6 * np.abs(w).max()
        w, p = w[keep], p[keep]
    return w, p


def grating_peaks(weights, xy, lam_min: float, lam_max: float, *, norm=None, count: int = 5, oversample: int = 2):
    """Strongest wave vectors of the matched-filter statistic |C(k)|²/A(k), C(k) = Σ_p c_p e^{−i k·y_p}, over
    the plane, at all k of a zero-padded FFT grid at once.

    Parameters
    ----------
    weights : (P,) float
        c_p (any unit).
    xy : (P, 2) float, metres
        Point coordinates in the plane.
    lam_min, lam_max : float, metres
        Wavelength range searched (2π/|k|).
    norm : callable, optional
        ``norm(kx, ky) → A`` (arrays of wave-vector components, 1/m): the energy of a unit grating's predicted
        signal (the generalised likelihood-ratio statistic's denominator); default 1.
    count : int
        Number of peaks returned (local maxima, strongest first, k and −k counted once).
    oversample : int
        Zero-padding factor of the FFT (finer k sampling than the data extent's resolution).

    Returns
    -------
    peaks : list of (wavelength m, orientation rad in [0, π), statistic)

    Notes
    -----
    C is computed by cloud-in-cell gridding at 4 points per shortest period and a real FFT, corrected for the
    gridding's transfer function sinc²(k_x h/2) sinc²(k_y h/2).
    """
    w, p = _significant(weights, xy)
    h = lam_min / 4.0
    lo = p.min(axis=0) - 2 * h
    ext = float((p.max(axis=0) - lo).max() + 2 * h)
    n = int(min(2 ** np.ceil(np.log2(max(ext / h, 16) * oversample)), 4096))
    h = max(h, ext * oversample / n)
    g = (p - lo) / h
    i0 = np.floor(g).astype(int)
    f = g - i0
    grid = np.zeros((n, n))
    for dx in (0, 1):
        for dy in (0, 1):
            wx = f[:, 0] if dx else 1 - f[:, 0]
            wy = f[:, 1] if dy else 1 - f[:, 1]
            np.add.at(grid, (np.clip(i0[:, 0] + dx, 0, n - 1), np.clip(i0[:, 1] + dy, 0, n - 1)), w * wx * wy)
    power = np.abs(np.fft.rfft2(grid)) ** 2  # (n, n//2 + 1): ky ≥ 0, the other half is its mirror
    kx = (np.fft.fftfreq(n, d=h) * _TWO_PI)[:, None]
    ky = (np.fft.rfftfreq(n, d=h) * _TWO_PI)[None, :]
    kk = np.hypot(kx, ky)
    ok = (kk >= _TWO_PI / lam_max) & (kk <= _TWO_PI / lam_min) & ((ky > 0) | (kx > 0))
    cic = (np.sinc(kx * h / _TWO_PI) * np.sinc(ky * h / _TWO_PI)) ** 4  # |transfer|², np.sinc(x) = sin(πx)/(πx)
    stat = np.zeros_like(power)
    ii, jj = np.nonzero(ok)
    den = np.ones(ii.size) if norm is None else np.asarray(norm(kx[ii, 0], ky[0, jj]), float)
    stat[ii, jj] = power[ii, jj] / (cic[ii, jj] * np.maximum(den, 1e-300))
    full = np.concatenate([stat, np.zeros((n, n - stat.shape[1]))], axis=1)  # periodic n × n for the rolls
    is_max = np.ones(full.shape, bool)
    for sx in (-1, 0, 1):
        for sy in (-1, 0, 1):
            if sx or sy:
                is_max &= full >= np.roll(np.roll(full, sx, 0), sy, 1)
    cand = np.flatnonzero((is_max[:, : stat.shape[1]] & ok).ravel())
    cand = cand[np.argsort(stat.ravel()[cand])[::-1][:count]]
    out = []
    for c in cand:
        i, j = np.unravel_index(c, stat.shape)
        out.append((float(_TWO_PI / kk[i, j]), float(np.arctan2(ky[0, j], kx[i, 0]) % np.pi), float(stat[i, j])))
    return out


def refine_peak(weights, xy, wavelength: float, orientation: float, norm=None):
    """(wavelength m, orientation rad in [0, π), statistic) maximising |Σ_p c_p e^{−i k·y_p}|²/A(k) near a peak of
    :func:`grating_peaks`, by Nelder–Mead on (log λ, o) with the sum evaluated directly (off the FFT grid, whose
    cells are ~1 % apart in λ at 2 mm: enough to misplace a grating by half a period across the data)."""
    w, p = _significant(weights, xy)

    def neg(z):
        k = _TWO_PI * np.exp(-z[0]) * np.array([np.cos(z[1]), np.sin(z[1])])
        den = 1.0 if norm is None else float(np.asarray(norm(np.array([k[0]]), np.array([k[1]])))[0])
        return -(np.abs(np.sum(w * np.exp(-1j * (p @ k)))) ** 2) / max(den, 1e-300)

    z0 = np.array([np.log(wavelength), orientation])
    res = minimize(
        neg,
        z0,
        method="Nelder-Mead",
        options={
            "xatol": 1e-6,
            "fatol": 1e-9 * abs(neg(z0)),
            "initial_simplex": z0 + np.array([[0, 0], [0.01, 0], [0, 0.01]]),
        },
    )
    return float(np.exp(res.x[0])), float(res.x[1] % np.pi), float(-res.fun)


def roughness_fields(foot, wavelength: float, count: int, rng: np.random.Generator, modes: int = 16) -> np.ndarray:
    """Unit-RMS realisations (count, P) of the scene's roughness family at principal-frame points ``foot (P, 3)`` m.

    Each is √(2/K) Σ_k cos(k_k·y + φ_k): K = ``modes`` cosines, directions uniform on the sphere, wavenumbers
    2π/λ · U(0.5, 2) for the grating ``wavelength`` λ (m), phases uniform (as
    :func:`bayestouch.scene.objects.build_surface` draws the scene's)."""
    foot = np.asarray(foot, float)
    out = np.empty((count, foot.shape[0]))
    for r in range(count):
        k = rng.normal(size=(modes, 3))
        k /= np.linalg.norm(k, axis=1, keepdims=True)
        k *= (_TWO_PI / wavelength) * rng.uniform(0.5, 2.0, size=(modes, 1))
        out[r] = np.sqrt(2.0 / modes) * np.cos(foot @ k.T + rng.uniform(0, _TWO_PI, modes)).sum(axis=1)
    return out


def texture_natural(flat: np.ndarray) -> np.ndarray:
    """Texture columns (S, 5) of raw θ draws (S, 16): amplitude m, wavelength m, orientation rad in [0, π) (the
    sampled frame's x–y plane; u flips sign with each π of reduction), phase rad in (−π, π] at the reference
    point, roughness m."""
    u, v = flat[:, 11], flat[:, 12]
    o = flat[:, 14]
    turns = np.floor(o / np.pi)
    u = np.where(turns % 2 == 0, u, -u)
    return np.column_stack(
        [np.hypot(u, v), np.exp(flat[:, 13]), o - turns * np.pi, np.arctan2(v, u), np.exp(flat[:, 15])]
    )


def scene_uv(shape, amplitude: float, wavelength: float, orientation: float, ref) -> tuple[float, float]:
    """(u, v) m of a scene grating A sin(2π y·d/λ) (phase zero at the object's centre) with the phase referenced
    to the world point ``ref`` (3,) m, as :func:`distance_batch` uses it: the truth to compare posteriors with."""
    R = np.asarray(shape.rotation)
    yref = (np.asarray(ref, float) - np.asarray(shape.centre)) @ R
    phi = _TWO_PI * (yref[0] * np.cos(orientation) + yref[1] * np.sin(orientation)) / wavelength
    return amplitude * np.cos(phi), amplitude * np.sin(phi)
