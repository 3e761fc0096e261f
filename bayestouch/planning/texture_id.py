"""Texture identification (issue 5): which texture of a library is the finger stroking, and after how many strokes?

Why in ``planning``: the Bayesian part is a discrete posterior over K library entries (a few lines on top of the
raw-current likelihood of :mod:`bayestouch.inference.raw`); what this module adds is the stroke-by-stroke loop,
the stroke choice and the experiment runner, the same role :mod:`bayestouch.planning.loop` and
:mod:`bayestouch.planning.experiment` play for shape.

Set-up
------
* Library: ``models/textures.toml`` (:func:`load_library`): K textures (grating amplitude, wavelength,
  orientation; roughness) on a known flat test object, the graphite plate's shape without defects.
* Strokes (:class:`StrokeSpec`, :func:`plate_stroke`): straight, position-controlled lines over the plate's flat
  top face, ``length`` long at ``speed``, pressed ``depth`` into the nominal (untextured) surface. The commanded
  path knows nothing about the texture.
* Truth (:func:`record_stroke`): the full forward model (:func:`bayestouch.physics.forward.simulate`, all noise sources,
  the device's fixed-pattern gains) on the textured object, with two nuisances the identifier does not know:
  the stroke start phase — the finger touches down ``shift`` metres along the stroke from where it was sent,
  shift ~ U(−``shift_range``, ``shift_range``) per stroke, continuous — and a skin-temperature offset
  ~ N(0, ``temperature_sd``²) K per stroke on top of the drive's modelled skin temperature.

Likelihood of one stroke under texture k (:func:`texture_log_likelihood`)
------------------------------------------------------------------------
The recorded stroke is turned into :class:`~bayestouch.inference.raw.RawData` by
:func:`~bayestouch.inference.raw.load_raw_data` (``stride=1``: every frame, so its lag recursion is the forward
model's exact one): ln I divided by the known fixed-pattern gains, minus the common log-drift ĉ_t measured by the
unloaded reference row, with the per-reading noise sd of white + 1/f + local random walk + reference-mean
variance, Student-t (ν = 4) readings. The texture hypothesis enters only through the signed distance at the
known taxel positions (:func:`bayestouch.scene.surface.signed_distance` of the textured plate), then the same
skin → taxel → lag chain as :func:`bayestouch.inference.raw.predict_log_current` (whose reference-row drift is
lagged like the readings and a median over the reference taxels, corrections first made here). One departure from
raw.py, measured: each taxel's standardised residuals are whitened over the stroke's frames with the noise
model's 1/f and random-walk correlation before the Student-t (:func:`frame_whitener`). Without the whitening
the readings are treated as independent, the slow 1/f noise counts as evidence, and where the texture signal is
below the noise (physics taxel mode) 18 of 20 trials made confident wrong decisions; with it, none.

Nuisances, and how each is handled (honestly, not with the truth):

* skin temperature and gain drift — *profiled* by the reference row. In the empirical taxel mode a temperature
  change multiplies every taxel's current by the same factor (the unstrained M–S–M current), and the common
  random walk does too; ĉ_t removes both exactly up to the reference row's own noise, whose variance is in the
  reading variance. The per-taxel random walk is in the variance, not removed.
* stroke start phase — *marginalised*: a uniform prior over a grid of G shifts along the stroke,
  p(stroke | k) = (1/G) Σ_g p(stroke | k, shift_g). The truth's shift is continuous, so the grid step
  (``shift_step``, default 25 µm, 1/20 of the finest grating period) is part of the approximation the
  experiment tests. Each stroke gets its own shift (the finger touches down anew), so strokes are independent
  given k and the posterior updates stroke by stroke: log p(k | strokes) = log prior + Σ_s log p(stroke_s | k) −
  log Z (:func:`update_posterior`).
* roughness realisation — not a nuisance here: a library entry is one physical sample (fixed seed), as in
  Fishel & Loeb 2012, where each of the 117 textures was one physical sample explored repeatedly.

Measured (20 textures, random strokes of 1 cm at 1 cm/s, 0.3 mm deep; ``benchmarks/bench_texture.py``): in the
empirical taxel mode (Δ ln I = S_p p, the mode fitted to device data) every trial decides correctly after one
stroke — the texture signal is ~200 reading sds, so the experiment's target is met with a large margin. In the
physics taxel mode (Δ ln I ≈ 3e-5 per kPa, physics.md §0) the textures' predictions differ by less than the
noise over a whole stroke: 1 of 20 trials decided within 10 strokes (correctly, grating4_a100 after 9), none
wrongly, and the MAP after 10 strokes was right in 4 of 20 (chance: 1) — barely identifiable, and the posterior
says so.

Decision rule: stop and decide argmax_k p(k | strokes) as soon as max_k p(k | strokes) ≥ ``threshold``
(default 0.95); a trial that never reaches it is "undecided" and its forced decision after ``max_strokes`` is
the MAP. Target (issue 5): ≥ 95 % correct with a median of ≤ 5 strokes (Fishel & Loeb 2012, "Bayesian
exploration for intelligent identification of textures", Front. Neurorobot. 6:4: 95.4 % on 117 textures,
median 5 exploratory movements).

Stroke choice (``policy``): ``random`` (direction uniform, speed and depth at their defaults, start anywhere on
the flat face), or ``eig``: among ``candidates`` random candidate strokes (direction, speed, depth drawn from the
candidate sets), the one maximising a discrete expected information gain about k under the current posterior.
The EIG of a candidate is the pairwise-distance lower bound of the mutual information between k and a Gaussian
observation (Kolchinsky & Tracey 2017, "Estimating mixture entropy with pairwise distances", Entropy 19:361):
I ≥ −Σ_i p_i log Σ_j p_j exp(−D_B(i, j)), D_B = ‖μ_i − μ_j‖² / 8 (Bhattacharyya distance of equal-covariance
Gaussians, residuals scaled by the modelled noise sd), with μ_k the noise-free prediction of texture k at zero
shift. Only the textures holding 99.9 % of the posterior mass are predicted.

Experiment (:func:`run_experiment`, ``bayestouch texture-id``): every texture of the first
``textures`` library entries is the truth in ``trials`` trials (seed (seed, texture, trial)); writes
``results.csv`` (:data:`COLUMNS`, one row per stroke), ``summary.json`` and ``accuracy_vs_strokes.png``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference.densities import student_t_logpdf
from bayestouch.params import MODELS, read_toml
from bayestouch.physics import forward as fw
from bayestouch.physics import noise as nz
from bayestouch.scene.objects import SceneObject, TextureSpec, build_surface
from bayestouch.scene.strokes import Stroke, stroke_from_path
from bayestouch.scene.surface import Surface, Texture, signed_distance

__all__ = [
    "LIBRARY",
    "COLUMNS",
    "TextureLibrary",
    "StrokeSpec",
    "IdSettings",
    "load_library",
    "library_from_dict",
    "plate_stroke",
    "random_stroke_spec",
    "record_stroke",
    "frame_whitener",
    "texture_log_likelihood",
    "stroke_evidence",
    "update_posterior",
    "batch_posterior",
    "eig_pairwise",
    "run_trial",
    "run_experiment",
    "summarise",
    "plot_accuracy",
]

#: the shipped texture library
LIBRARY = MODELS / "textures.toml"
#: columns of results.csv
COLUMNS = ("texture", "trial", "stroke", "p_true", "map_correct", "decided", "seconds", "map", "shift_m", "policy")
_FLAT_FRACTION = 0.6  # strokes stay within this fraction of the semi-axes (flat part of the n = 10 plate)


# ----------------------------------------------------------------------------------------------- library


@dataclass(frozen=True)
class TextureLibrary:
    """K textures on one known test object.

    Attributes
    ----------
    names : tuple of str
        Unique texture names.
    specs : tuple of TextureSpec
        Metres and radians (:class:`bayestouch.scene.objects.TextureSpec`); all with the same ``modes``.
    base : SceneObject
        The test object without texture (its shape is known to the identifier).
    source : Path or None
    """

    names: tuple[str, ...]
    specs: tuple[TextureSpec, ...]
    base: SceneObject
    source: Path | None = None

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, count: int) -> TextureLibrary:
        """The first ``count`` textures."""
        if not 2 <= count <= len(self):
            raise BadInput(f"--textures must be between 2 and {len(self)} (library size), got {count}")
        return TextureLibrary(self.names[:count], self.specs[:count], self.base, self.source)

    def object(self, k: int) -> SceneObject:
        """The test object with texture ``k``."""
        b = self.base
        return SceneObject(self.names[k], b.shape, (), b.description, b.source, self.specs[k])

    def surfaces(self) -> Surface:
        """One :class:`Surface` whose ``texture`` fields carry a leading axis K (shape, FFD, defects shared)."""
        surfs = [build_surface(self.object(k)) for k in range(len(self))]
        tex = Texture(*(jnp.stack([getattr(s.texture, f) for s in surfs]) for f in Texture._fields))
        return surfs[0]._replace(texture=tex)


def _number(d: dict, key: str, where: str, lo: float, hi: float, default=None) -> float:
    v = d.get(key, default)
    if not isinstance(v, int | float) or isinstance(v, bool):
        raise BadInput(f"{where}: '{key}' must be a number in [{lo:g}, {hi:g}] (SI units), got {v!r}")
    if not lo <= v <= hi:
        raise BadInput(f"{where}: '{key}' must be in [{lo:g}, {hi:g}] (SI units), got {v!r}")
    return float(v)


def library_from_dict(doc: dict, where: str = "texture library", source: Path | None = None) -> TextureLibrary:
    """Build a :class:`TextureLibrary` from a parsed TOML document (see ``models/textures.toml``).

    Bad fields raise :class:`BadInput` naming the table, the entry and the field.
    """
    from bayestouch.scene.objects import object_from_dict

    lib = doc.get("library", {})
    if not isinstance(lib, dict):
        raise BadInput(f"{where}: [library] must be a table with 'modes'")
    modes = int(_number(lib, "modes", f"{where} [library]", 1, 256, default=16))
    obj = doc.get("object")
    if not isinstance(obj, dict) or not isinstance(obj.get("shape"), dict):
        raise BadInput(f"{where}: missing table [object.shape] with centre_m, axes_m, angles_rad, n (metres)")
    meta = {k: v for k, v in obj.items() if k != "shape"}
    base = object_from_dict({"object": meta, "shape": obj["shape"]}, f"{where} [object]", source)
    entries = doc.get("texture")
    if not isinstance(entries, list) or len(entries) < 2:
        raise BadInput(f"{where}: needs at least two [[texture]] tables, got {0 if entries is None else entries!r}")
    names, specs = [], []
    cmin = float(np.min(np.asarray(base.shape.axes)))
    for i, t in enumerate(entries):
        w = f"{where} [[texture]] #{i + 1}"
        name = t.get("name")
        if not isinstance(name, str) or not name or name in names:
            raise BadInput(f"{w}: 'name' must be a unique non-empty string, got {name!r}")
        w = f"{where} [[texture]] '{name}'"
        amp = _number(t, "amplitude_m", w, 0.0, 5e-4, default=0.0)
        lam = _number(t, "wavelength_m", w, 1e-5, 0.05)
        ori = _number(t, "orientation_rad", w, -2 * np.pi, 2 * np.pi, default=0.0)
        rough = _number(t, "roughness_m", w, 0.0, 5e-4, default=0.0)
        seed = t.get("seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise BadInput(f"{w}: 'seed' must be a non-negative integer, got {seed!r}")
        if max(amp, rough) > 0.2 * cmin:
            raise BadInput(f"{w}: 'amplitude_m'/'roughness_m' must stay below a fifth of the object's smallest axis")
        names.append(name)
        specs.append(TextureSpec(amp, lam, ori, rough, seed, modes))
    return TextureLibrary(tuple(names), tuple(specs), base, source)


def load_library(path=LIBRARY) -> TextureLibrary:
    """Read a texture library TOML file (metres, radians); a bad file raises :class:`BadInput` naming the field."""
    p = Path(path)
    return library_from_dict(read_toml(p, "texture library", "models/textures.toml"), str(p), p)


# ----------------------------------------------------------------------------------------------- strokes


class StrokeSpec(NamedTuple):
    """A straight stroke over the flat top face of the test object (principal frame).

    start : (2,) float, metres
        Commanded start (x, y) of the pad centre.
    direction : float, radians
        Direction of motion in the principal x–y plane.
    speed : float, m/s
    depth : float, metres
        Pressing depth of the pad centre below the nominal surface.
    length : float, metres
    rate : float, Hz
        Frame rate.
    """

    start: tuple[float, float]
    direction: float
    speed: float = 0.01
    depth: float = 3e-4
    length: float = 0.01
    rate: float = 50.0


def _top_face(shape: ne.NEllipsoid, xy: np.ndarray) -> np.ndarray:
    """Principal-frame points (T, 3) of the upper face z = c (1 − |x/a|^n − |y/b|^n)^(1/n) above ``xy (T, 2)``."""
    a, b, c = (float(v) for v in np.asarray(shape.axes))
    n = float(shape.n)
    rest = 1.0 - np.abs(xy[:, 0] / a) ** n - np.abs(xy[:, 1] / b) ** n
    if np.any(rest <= 0):
        raise BadInput("stroke: leaves the object's top face; expected a start within the flat central part")
    return np.column_stack([xy, c * rest ** (1.0 / n)])


def plate_stroke(obj: SceneObject, spec: StrokeSpec, shift: float = 0.0) -> Stroke:
    """The :class:`Stroke` of ``spec`` on the untextured top face of ``obj``, displaced ``shift`` metres along
    its direction (the start-phase error of the truth; 0 for the commanded stroke)."""
    nf = int(round(spec.length / spec.speed * spec.rate))
    if nf < 2:
        raise BadInput(f"stroke: length/speed*rate gives {nf} frames; expected at least 2")
    t = np.arange(nf) / spec.rate
    d = np.array([np.cos(spec.direction), np.sin(spec.direction)])
    xy = np.asarray(spec.start, float) + (shift + spec.speed * t)[:, None] * d
    s = obj.shape
    loc = _top_face(s, xy)
    pts = np.asarray(ne.to_world(s, jnp.asarray(loc)))
    nrm = ne.evaluate(ne.normals, s, pts)
    return stroke_from_path(pts, nrm, t, spec.depth)


def random_stroke_spec(
    obj: SceneObject,
    rng: np.random.Generator,
    *,
    speed: float = 0.01,
    depth: float = 3e-4,
    length: float = 0.01,
    rate: float = 50.0,
) -> StrokeSpec:
    """A stroke of uniform direction whose whole path (± 1 mm) stays within the flat central part of the face."""
    a, b, _ = (float(v) for v in np.asarray(obj.shape.axes))
    phi = rng.uniform(0.0, 2 * np.pi)
    d = np.array([np.cos(phi), np.sin(phi)])
    half = np.array([_FLAT_FRACTION * a, _FLAT_FRACTION * b])
    lo = np.maximum(-half, -half - d * length) + 1e-3
    hi = np.minimum(half, half - d * length) - 1e-3
    return StrokeSpec(tuple(rng.uniform(lo, hi)), float(phi), speed, depth, length, rate)


# ------------------------------------------------------------------------------------------- measurement


@dataclass(frozen=True)
class IdSettings:
    """Settings of the identifier and of the simulated truth.

    Attributes
    ----------
    threshold : float
        Decide when max_k p(k | strokes) ≥ threshold.
    shift_range : float, metres
        Start-phase error of the truth ~ U(−range, range) per stroke; the identifier's prior over it.
    shift_step : float, metres
        Grid step of the marginalisation over the shift.
    temperature_sd : float, kelvin
        Per-stroke skin-temperature offset of the truth, unknown to the identifier.
    mode : {"empirical", "physics"}
        Taxel response mode of finger and identifier.
    noise : bool
        Simulate the read-out noise (False: every noise source zeroed and unit gains, for tests; the
        identifier still uses the modelled reading sd).
    nu : float
        Student-t degrees of freedom.
    noise_scale : float
        Multiplier on the modelled reading sd.
    correlated : bool
        Whiten each taxel's residuals over the frames of a stroke with the noise model's frame correlation
        (1/f and random walk, :func:`frame_whitener`); False treats readings as independent (raw.py's choice).
    radius, contact_radius : float, metres
        Taxel selection of :func:`bayestouch.inference.raw.load_raw_data`.
    speed, depth : float
        Defaults of random strokes (m/s, m).
    candidates : int
        Candidate strokes per ``eig`` decision.
    speeds, depths : tuple of float
        Candidate sets of the ``eig`` policy (m/s, m).
    """

    threshold: float = 0.95
    shift_range: float = 5e-4
    shift_step: float = 2.5e-5
    temperature_sd: float = 0.5
    mode: str = "empirical"
    noise: bool = True
    nu: float = 4.0
    noise_scale: float = 1.0
    radius: float = 4.5e-3
    contact_radius: float = 3.2e-3
    speed: float = 0.01
    depth: float = 3e-4
    correlated: bool = True
    candidates: int = 16
    speeds: tuple[float, ...] = (0.005, 0.01, 0.02)
    depths: tuple[float, ...] = (2e-4, 3e-4, 4e-4)

    def shifts(self) -> np.ndarray:
        """The shift grid (G,) metres, symmetric about 0 and including it."""
        m = int(np.floor(self.shift_range / self.shift_step + 1e-9))
        return self.shift_step * np.arange(-m, m + 1)

    def check(self) -> IdSettings:
        if not 0.5 < self.threshold < 1.0:
            raise BadInput(f"--threshold must be in (0.5, 1), got {self.threshold}")
        if self.mode not in ("empirical", "physics"):
            raise BadInput(f"--mode must be empirical or physics, got {self.mode!r}")
        if not (self.shift_range >= 0 and self.shift_step > 0):
            raise BadInput("shift_range must be ≥ 0 and shift_step > 0 (metres)")
        return self


_DRIVE_CACHE: dict = {}


def _skin_temperature(vf, n: int, dt: float) -> np.ndarray:
    from bayestouch.physics.finger import drive

    key = (id(vf.wire), n, dt)
    if key not in _DRIVE_CACHE:
        _DRIVE_CACHE[key] = np.asarray(drive(vf.wire, vf.rod, (0.15, 0.05, 0.05), n, dt).skin_temperature)
    return _DRIVE_CACHE[key]


def record_stroke(obj: SceneObject, spec: StrokeSpec, vf, rng: np.random.Generator, settings: IdSettings):
    """Simulate one stroke over the textured ``obj`` with the truth's nuisances, and read it as the identifier does.

    Parameters
    ----------
    obj : SceneObject
        The object with its true texture.
    spec : StrokeSpec
        The commanded stroke.
    vf : VirtualFinger
        :func:`bayestouch.physics.virtual.load_finger`; with ``settings.noise`` False its gains are taken as 1.
    rng : numpy Generator
        Draws the shift, the temperature offset and the noise key.

    Returns
    -------
    data : RawData
        Corrected ln I and its noise sd at the commanded (known) taxel positions.
    tangent : (3,) float
        Direction of the stroke (world frame).
    shift : float, metres
        The truth's start-phase error.
    """
    from bayestouch.inference.raw import load_raw_data
    from bayestouch.io.recording import build_dataset

    finger = _finger(vf, settings)
    shift = float(rng.uniform(-settings.shift_range, settings.shift_range))
    cmd = plate_stroke(obj, spec, 0.0)
    true = plate_stroke(obj, spec, shift)
    dt = 1.0 / spec.rate
    n = len(cmd.time)
    temp_nominal = _skin_temperature(vf, n, dt)
    temp_true = temp_nominal + rng.normal(0.0, settings.temperature_sd)
    key = jax.random.PRNGKey(int(rng.integers(2**31)))
    fr = fw.simulate_jit(
        obj.surface(),
        fw.stroke_arrays(true),
        _simulated(finger, settings),
        key,
        skin_temperature=jnp.asarray(temp_true),
        dt=dt,
        mode=settings.mode,
    )
    frames = {
        "time": cmd.time,
        "stroke_index": np.zeros(n, int),
        "taxel_current": np.asarray(fr.taxel_current),
        "contact_point": cmd.contact,
        "contact_normal": cmd.normal,
        "pressing_depth": np.full(n, cmd.depth),
        "skin_temperature": temp_nominal,
    }
    grid = np.asarray(finger.grid).reshape(-1, 2)
    ds = build_dataset(
        frames,
        grid[:, 0],
        grid[:, 1],
        np.asarray(finger.reference).ravel(),
        [cmd.depth],
        {"mode": settings.mode, "seed": 0},
    )
    data, _ = load_raw_data(ds, stride=1, radius=settings.radius, contact_radius=settings.contact_radius, finger=finger)
    return data, np.asarray(cmd.tangent[0]), shift


def _finger(vf, settings: IdSettings):
    """The device as the identifier knows it (unit gains when the noise is off)."""
    f = vf.finger
    return f if settings.noise else f._replace(gains=jnp.ones_like(f.gains))


def _simulated(finger, settings: IdSettings):
    """The device the truth is simulated with: with the noise off, every noise source is zeroed and the ADC made
    32-bit (quantisation ≤ 5e-16 A), so the same compiled :func:`~bayestouch.physics.forward.simulate` serves both
    cases; the identifier keeps the real noise model for its reading sd."""
    if settings.noise:
        return finger
    quiet = finger.noise._replace(
        bandwidth=0.0,
        flicker=0.0,
        drift_common=0.0,
        drift_local=0.0,
        offset=0.0,
        outlier_probability=0.0,
        adc_bits=32.0,
    )
    return finger._replace(noise=quiet)


# ------------------------------------------------------------------------------------------- likelihood


def frame_whitener(data, finger) -> np.ndarray:
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


def _predict(surf: Surface, x, data_arrays, finger, mode: str):
    """ln I (F, M) predicted for surface ``surf`` at taxel positions ``x (F, J, 3)`` (raw.predict_log_current's
    chain with the textured signed distance)."""
    temp, start, kernel, lw = data_arrays
    return fw.log_current_from_distance(finger, signed_distance(surf, x), kernel, temp, start, lw, mode)


def _ll_grid(surfs: Surface, x, arrays, y, sd, whiten, shifts, tangent, finger, mode, nu):
    def one_texture(tex):
        surf = surfs._replace(texture=tex)

        def one_shift(o):
            pred = _predict(surf, x + o * tangent, arrays, finger, mode)
            z = jnp.where(jnp.isfinite(pred), (y - pred) / sd, 1e6)
            return jnp.sum(student_t_logpdf(whiten @ z, 1.0, nu))

        return jax.vmap(one_shift)(shifts)

    return jax.lax.map(one_texture, surfs.texture)


_ll_grid_jit = jax.jit(_ll_grid, static_argnames=("mode", "nu"))


def texture_log_likelihood(
    surfs: Surface, data, finger, shifts, tangent, *, nu: float = 4.0, noise_scale: float = 1.0, correlated: bool = True
) -> np.ndarray:
    """Log-likelihood (K, G) of one recorded stroke under every texture k and start-phase shift g.

    Parameters
    ----------
    surfs : Surface
        :meth:`TextureLibrary.surfaces` (texture fields with a leading axis K).
    data : RawData
        From :func:`record_stroke` (commanded taxel positions, corrected ln I, its sd).
    finger : Finger
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

    Returns
    -------
    (K, G) float
        Up to a constant common to all (k, g) when ``correlated``.
    """
    F = len(data.temperature)
    whiten = frame_whitener(data, finger) if correlated else np.eye(F)
    arrays = (
        jnp.asarray(data.temperature),
        jnp.asarray(data.start),
        jnp.asarray(data.kernel),
        jnp.asarray(data.lag_weights),
    )
    out = _ll_grid_jit(
        surfs,
        jnp.asarray(data.taxel_position),
        arrays,
        jnp.asarray(data.log_current),
        noise_scale * jnp.asarray(data.noise_sd),
        jnp.asarray(whiten),
        jnp.asarray(shifts, dtype=float),
        jnp.asarray(tangent, dtype=float),
        finger,
        data.mode,
        float(nu),
    )
    return np.asarray(out)


def stroke_evidence(ll) -> np.ndarray:
    """log p(stroke | k) (K,) from the grid (K, G): the uniform-prior average over shifts, in log space."""
    from scipy.special import logsumexp

    ll = np.asarray(ll, float)
    return logsumexp(ll, axis=1) - np.log(ll.shape[1])


def update_posterior(log_post, evidence) -> np.ndarray:
    """One Bayes step: normalised log p(k | strokes, this stroke) (K,) from log p(k | strokes) and log p(stroke | k)."""
    from scipy.special import logsumexp

    z = np.asarray(log_post, float) + np.asarray(evidence, float)
    return z - logsumexp(z)


def batch_posterior(log_prior, evidences) -> np.ndarray:
    """Normalised log posterior (K,) after all strokes at once: log prior + Σ_s log p(stroke_s | k) − log Z."""
    from scipy.special import logsumexp

    z = np.asarray(log_prior, float) + np.sum(np.atleast_2d(evidences), axis=0)
    return z - logsumexp(z)


# -------------------------------------------------------------------------------------------------- EIG


def eig_pairwise(post, means, sd) -> float:
    """Lower bound (nats) of the mutual information between k ~ post and y = μ_k + N(0, diag sd²).

    Parameters
    ----------
    post : (K,) float
        Probabilities.
    means : (K, D) float
        Noise-free predictions.
    sd : (D,) float
        Noise sd of each reading.
    """
    from scipy.special import logsumexp

    p = np.asarray(post, float)
    m = np.asarray(means, float) / np.asarray(sd, float)
    d2 = np.sum((m[:, None, :] - m[None, :, :]) ** 2, axis=-1)
    keep = p > 0
    lp = np.log(np.where(keep, p, 1.0))
    inner = logsumexp(lp[None, :] - d2 / 8.0, axis=1, b=keep[None, :].astype(float))
    return float(-np.sum(np.where(keep, p * inner, 0.0)))


def _choose_eig(lib, surfs, vf, settings, rng, log_post):
    """The candidate stroke with the largest :func:`eig_pairwise` under the current posterior."""
    post = np.exp(log_post)
    order = np.argsort(post)[::-1]
    keep = order[: int(np.searchsorted(np.cumsum(post[order]), 0.999) + 1)]
    if len(keep) < 2:
        keep = order[:2]
    sub = surfs._replace(texture=jax.tree.map(lambda a: a[keep], surfs.texture))
    clean = IdSettings(**{**settings.__dict__, "noise": False, "temperature_sd": 0.0, "shift_range": 0.0})
    finger = _finger(vf, clean)
    best, best_spec = -np.inf, None
    for _ in range(settings.candidates):
        spec = random_stroke_spec(
            lib.base, rng, speed=float(rng.choice(settings.speeds)), depth=float(rng.choice(settings.depths))
        )
        data, tangent, _ = record_stroke(lib.base, spec, vf, np.random.default_rng(0), clean)
        mu = _ll_means(sub, data, finger, tangent)
        sd = settings.noise_scale * np.asarray(data.noise_sd).ravel()
        val = eig_pairwise(post[keep] / post[keep].sum(), mu, sd)
        if val > best:
            best, best_spec = val, spec
    return best_spec, best


def _ll_means(sub: Surface, data, finger, tangent) -> np.ndarray:
    arrays = (
        jnp.asarray(data.temperature),
        jnp.asarray(data.start),
        jnp.asarray(data.kernel),
        jnp.asarray(data.lag_weights),
    )
    x = jnp.asarray(data.taxel_position)
    out = _means_jit(sub, x, arrays, finger, data.mode)
    return np.asarray(out).reshape(out.shape[0], -1)


@jax.jit
def _means_empirical(sub, x, arrays, finger):
    return jax.lax.map(lambda tex: _predict(sub._replace(texture=tex), x, arrays, finger, "empirical"), sub.texture)


@jax.jit
def _means_physics(sub, x, arrays, finger):
    return jax.lax.map(lambda tex: _predict(sub._replace(texture=tex), x, arrays, finger, "physics"), sub.texture)


def _means_jit(sub, x, arrays, finger, mode):
    return (_means_empirical if mode == "empirical" else _means_physics)(sub, x, arrays, finger)


# ---------------------------------------------------------------------------------------------- trials


def run_trial(
    lib: TextureLibrary,
    true_k: int,
    trial: int,
    seed: int,
    vf,
    *,
    max_strokes: int = 10,
    settings: IdSettings = IdSettings(),
    policy: str = "random",
    stop_at_decision: bool = True,
    surfs: Surface | None = None,
) -> list[dict]:
    """Identify texture ``true_k`` stroke by stroke; one row per stroke (:data:`COLUMNS`).

    The decision is latched at the first stroke where the posterior's maximum reaches ``settings.threshold``;
    with ``stop_at_decision`` the trial ends there. Randomness: ``np.random.default_rng((seed, true_k, trial))``.
    """
    if policy not in ("random", "eig"):
        raise BadInput(f"--policy must be random or eig, got {policy!r}")
    settings = settings.check()
    surfs = lib.surfaces() if surfs is None else surfs
    rng = np.random.default_rng((int(seed), int(true_k), int(trial)))
    obj = lib.object(true_k)
    finger = _finger(vf, settings)
    shifts = settings.shifts()
    log_post = np.full(len(lib), -np.log(len(lib)))
    rows, decided = [], False
    for s in range(1, max_strokes + 1):
        t0 = time.perf_counter()
        if policy == "eig" and s > 1:
            spec, _ = _choose_eig(lib, surfs, vf, settings, rng, log_post)
        else:
            spec = random_stroke_spec(lib.base, rng, speed=settings.speed, depth=settings.depth)
        data, tangent, shift = record_stroke(obj, spec, vf, rng, settings)
        ll = texture_log_likelihood(
            surfs,
            data,
            finger,
            shifts,
            tangent,
            nu=settings.nu,
            noise_scale=settings.noise_scale,
            correlated=settings.correlated,
        )
        log_post = update_posterior(log_post, stroke_evidence(ll))
        post = np.exp(log_post)
        k_map = int(np.argmax(post))
        decided = decided or bool(post[k_map] >= settings.threshold)
        rows.append(
            {
                "texture": lib.names[true_k],
                "trial": int(trial),
                "stroke": s,
                "p_true": float(post[true_k]),
                "map_correct": int(k_map == true_k),
                "decided": int(decided),
                "seconds": time.perf_counter() - t0,
                "map": lib.names[k_map],
                "shift_m": shift,
                "policy": policy,
            }
        )
        if decided and stop_at_decision:
            break
    return rows


def summarise(rows: list[dict], max_strokes: int, threshold: float) -> dict:
    """Accuracy at decision, strokes to decision, accuracy against strokes (latched after a decision).

    A trial's outcome after s strokes is its MAP after min(s, its last stroke) strokes: after a decision
    (and the trial's end) the decision stands. Undecided trials are forced to their MAP after ``max_strokes``;
    their strokes to decision are counted as ``max_strokes`` in the median (so the median is a lower bound when
    fewer than half decided). The 95 % interval of the accuracy is Wilson's score interval.
    """
    trials: dict = {}
    for r in rows:
        trials.setdefault((r["texture"], int(r["trial"])), []).append(r)
    outcome, strokes, decided = [], [], []
    curve = np.zeros(max_strokes)
    for rs in trials.values():
        rs = sorted(rs, key=lambda r: int(r["stroke"]))
        dec = [r for r in rs if int(r["decided"])]
        last = dec[0] if dec else rs[-1]
        outcome.append(int(last["map_correct"]))
        strokes.append(int(last["stroke"]) if dec else max_strokes)
        decided.append(bool(dec))
        for s in range(1, max_strokes + 1):
            upto = [r for r in rs if int(r["stroke"]) <= s]
            curve[s - 1] += int(upto[-1]["map_correct"])
    n = len(outcome)
    acc = float(np.mean(outcome)) if n else float("nan")
    lo, hi = _wilson(int(np.sum(outcome)), n)
    dec_ok = [o for o, d in zip(outcome, decided, strict=True) if d]
    return {
        "trials": n,
        "textures": len({t for t, _ in trials}),
        "threshold": threshold,
        "max_strokes": max_strokes,
        "accuracy_at_decision": acc,
        "accuracy_95ci": [lo, hi],
        "decided_fraction": float(np.mean(decided)) if n else float("nan"),
        "accuracy_of_decided": float(np.mean(dec_ok)) if dec_ok else float("nan"),
        "median_strokes_to_decision": float(np.median(strokes)) if n else float("nan"),
        "mean_strokes_to_decision": float(np.mean(strokes)) if n else float("nan"),
        "accuracy_vs_strokes": [float(c / n) for c in curve] if n else [],
        "target": "accuracy >= 0.95 with median strokes <= 5 (Fishel & Loeb 2012: 95.4 % on 117 textures, median 5)",
    }


def _wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return float(c - h), float(c + h)


def plot_accuracy(summary: dict, path) -> Path:
    """``accuracy_vs_strokes.png``: fraction correct against strokes (latched decisions), with the target."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    acc = summary["accuracy_vs_strokes"]
    s = np.arange(1, len(acc) + 1)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot(s, acc, "o-", label=f"{summary['textures']} textures, {summary['trials']} trials")
    ax.axhline(0.95, color="k", ls="--", lw=0.8, label="target 95 %")
    ax.axvline(summary["median_strokes_to_decision"], color="C1", ls=":", label="median strokes to decision")
    ax.set_xlabel("strokes")
    ax.set_ylabel("fraction correct (MAP, latched at decision)")
    ax.set_ylim(0, 1.02)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def run_experiment(
    out,
    *,
    textures: int = 20,
    trials: int = 3,
    max_strokes: int = 10,
    seed: int = 0,
    settings: IdSettings = IdSettings(),
    policy: str = "random",
    library=LIBRARY,
    stop_at_decision: bool = True,
    progress: bool = True,
) -> dict:
    """Every one of the first ``textures`` library entries is the truth in ``trials`` trials; writes
    ``out/results.csv``, ``out/summary.json``, ``out/accuracy_vs_strokes.png``. Returns the summary."""
    from tqdm.auto import tqdm

    from bayestouch.io.files import write_csv_rows, write_text
    from bayestouch.physics.virtual import load_finger

    if trials < 1 or max_strokes < 1:
        raise BadInput(f"--trials and --max-strokes must be ≥ 1, got {trials} and {max_strokes}")
    lib = load_library(library).subset(textures)
    settings = settings.check()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    vf = load_finger(seed=int(seed))
    surfs = lib.surfaces()
    t0 = time.perf_counter()
    rows: list[dict] = []
    tasks = [(k, tr) for tr in range(trials) for k in range(len(lib))]
    for k, tr in tqdm(tasks, desc="texture trials", unit="trial", disable=not progress):
        rows += run_trial(
            lib,
            k,
            tr,
            seed,
            vf,
            max_strokes=max_strokes,
            settings=settings,
            policy=policy,
            stop_at_decision=stop_at_decision,
            surfs=surfs,
        )
        write_csv_rows(out / "results.csv", rows, COLUMNS)
    summary = summarise(rows, max_strokes, settings.threshold)
    summary.update(
        {
            "policy": policy,
            "seed": int(seed),
            "seconds": time.perf_counter() - t0,
            "library": [str(n) for n in lib.names],
            "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in settings.__dict__.items()},
        }
    )
    write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    plot_accuracy(summary, out / "accuracy_vs_strokes.png")
    return summary
