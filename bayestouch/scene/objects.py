"""Scene objects: an n-ellipsoid base (eq. 4–6) whose surface is displaced along its normal by defects
(bumps, shallows, cracks), read from TOML parameter files in ``models/objects``.

The displaced surface is y' = y + h(y) n(y) with y on the base surface and h a sum of defect height
functions (metres, positive outward). The texture height field of the physics issue adds to h.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bayestouch.backend import jax, jnp, pad_pow2
from bayestouch.errors import BadInput, check_path, file_problem, shown
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import nellipsoid_mesh
from bayestouch.params import MODELS, read_toml
from bayestouch.scene.surface import Defects, Surface, Texture, defect_height, ffd_displacement
from bayestouch.scene.surface import height as _surface_height

__all__ = [
    "OBJECTS_DIR",
    "resolve_object",
    "Defect",
    "TextureSpec",
    "FFDSpec",
    "SceneObject",
    "build_surface",
    "defect_arrays",
    "load_object",
    "object_from_dict",
    "DEFECT_KINDS",
    "WAVELENGTH_RANGE_M",
]

DEFECT_KINDS = ("bump", "shallow", "crack")


@dataclass(frozen=True)
class Defect:
    """A surface defect.

    Attributes
    ----------
    kind : {"bump", "shallow", "crack"}
    centre : (3,) float, metres
        Centre of a bump or shallow; start of a crack (world frame, on or near the surface).
    end : (3,) float, metres or None
        End of a crack.
    radius : float, metres
        Gaussian width (σ) of a bump or shallow; half-width (σ) of a crack.
    depth : float, metres
        Height of a bump (> 0); depth of a shallow or crack (> 0, applied inward).
    """

    kind: str
    centre: tuple[float, float, float]
    radius: float
    depth: float
    end: tuple[float, float, float] | None = None

    def height(self, y: np.ndarray) -> np.ndarray:
        """Height (N,) in metres, outward positive, at base-surface points ``y (N, 3)`` in metres."""
        return np.asarray(defect_height(defect_arrays((self,)), jnp.asarray(y, dtype=jnp.float64)))


@dataclass(frozen=True)
class TextureSpec:
    """Texture of an object (see :class:`bayestouch.scene.surface.Texture`): metres and radians; the
    roughness is a sum of ``modes`` cosines with random directions, wavelengths around ``wavelength``
    and phases drawn from ``seed``."""

    amplitude: float
    wavelength: float
    orientation: float = 0.0
    roughness: float = 0.0
    seed: int = 0
    modes: int = 16


@dataclass(frozen=True)
class FFDSpec:
    """An FFD lattice of the true surface: ``dims`` control points, box = principal extent × (1 + margin),
    displacements (l, m, k, 3) metres in the principal frame."""

    dims: tuple[int, int, int]
    displacement: np.ndarray
    margin: float = 0.15


@dataclass(frozen=True)
class SceneObject:
    """An object to touch: n-ellipsoid base plus defects.

    Attributes
    ----------
    name : str
    shape : NEllipsoid
        The base surface (SI units).
    defects : tuple of Defect
    description : str
    source : Path or None
        The TOML file it came from.
    """

    name: str
    shape: ne.NEllipsoid
    defects: tuple[Defect, ...] = field(default=())
    description: str = ""
    source: Path | None = None
    texture: TextureSpec | None = None
    ffd: FFDSpec | None = None

    def __post_init__(self) -> None:
        # a host-side container (never built on tracers): its fields are checked once, here
        if not isinstance(self.name, str):
            raise BadInput(f"SceneObject.name: expected a str, got {type(self.name).__name__} {self.name!r:.60}")
        ne.check_shape(self.shape, "SceneObject.shape")
        if not isinstance(self.defects, tuple) or not all(isinstance(d, Defect) for d in self.defects):
            raise BadInput(f"SceneObject.defects: expected a tuple of Defect, got {self.defects!r:.60}")
        for name, kind in (("texture", TextureSpec), ("ffd", FFDSpec)):
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                raise BadInput(f"SceneObject.{name}: expected a {kind.__name__} or None, got {value!r:.60}")

    def surface(self) -> Surface:
        """The true surface as a JAX pytree (for :func:`bayestouch.scene.surface.signed_distance`)."""
        return build_surface(self)

    def height(self, y) -> np.ndarray:
        """Total height (N,) in metres (texture + defects) at base-surface points ``y (N, 3)`` (world)."""
        y = np.asarray(y, float).reshape(-1, 3)
        if not self.defects and self.texture is None:
            return np.zeros(len(y))
        return _padded(_height_jit, self.surface(), y)

    def displace(self, y) -> np.ndarray:
        """Base-surface points (N, 3) in metres → points of the true surface (heights along the base
        normal, then the FFD lattice)."""
        y = np.asarray(y, float).reshape(-1, 3)
        heights = bool(self.defects) or self.texture is not None
        if not heights and self.ffd is None:
            return y
        surf = self.surface()
        if heights:
            y = y + _padded(_height_jit, surf, y)[:, None] * ne.evaluate(ne.normals, self.shape, y)
        if self.ffd is not None:
            y = _padded(_ffd_world_jit, surf, y)
        return y

    def mesh(self, res: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """Watertight mesh of the true surface: (vertices (V, 3) metres, faces (F, 3))."""
        v, f = nellipsoid_mesh(self.shape, res)
        return self.displace(v), f


@jax.jit
def _height_jit(surf: Surface, y):
    return _surface_height(surf, ne.to_local(surf.shape, y))


@jax.jit
def _ffd_world_jit(surf: Surface, y):
    loc = ne.to_local(surf.shape, y)
    return ne.to_world(surf.shape, loc + ffd_displacement(surf, loc))


def _padded(fn, surf: Surface, y: np.ndarray) -> np.ndarray:
    """Call a jitted ``fn(surf, points)`` on points padded to a power of two (few compiled sizes)."""
    return np.asarray(fn(surf, jnp.asarray(pad_pow2(y, min_size=256))))[: len(y)]


def build_surface(obj: SceneObject) -> Surface:
    """:class:`Surface` pytree of a scene object."""
    s = obj.shape
    axes = np.asarray(s.axes)
    if obj.ffd is not None:
        half = axes * (1.0 + obj.ffd.margin)
        disp = jnp.asarray(obj.ffd.displacement)
    else:
        half = axes * 1.15
        disp = jnp.zeros((1, 1, 1, 3))  # no lattice
    t = obj.texture
    if t is None:
        tex = Texture(jnp.array(0.0), jnp.array(1.0), jnp.array(0.0), jnp.array(0.0), jnp.zeros((0, 3)), jnp.zeros(0))
    else:
        rng = np.random.default_rng(t.seed)
        k = rng.normal(size=(t.modes, 3))
        k /= np.linalg.norm(k, axis=1, keepdims=True)
        k *= (2 * np.pi / t.wavelength) * rng.uniform(0.5, 2.0, size=(t.modes, 1))
        tex = Texture(
            jnp.array(t.amplitude),
            jnp.array(t.wavelength),
            jnp.array(t.orientation),
            jnp.array(t.roughness),
            jnp.asarray(k),
            jnp.asarray(rng.uniform(0, 2 * np.pi, t.modes)),
        )
    return Surface(s, jnp.asarray(-half), jnp.asarray(half), disp, tex, defect_arrays(obj.defects))


def defect_arrays(d: tuple[Defect, ...]) -> Defects:
    """The :class:`~bayestouch.scene.surface.Defects` arrays of a tuple of :class:`Defect`."""
    return Defects(
        jnp.array([1.0 if x.kind == "bump" else -1.0 for x in d]).reshape(-1),
        jnp.array([1.0 if x.kind == "crack" else 0.0 for x in d]).reshape(-1),
        jnp.array([x.centre for x in d]).reshape(-1, 3),
        jnp.array([x.end if x.end is not None else x.centre for x in d]).reshape(-1, 3),
        jnp.array([x.radius for x in d]).reshape(-1),
        jnp.array([x.depth for x in d]).reshape(-1),
    )


#: the tables an object file may hold
_TOP_KEYS = ("object", "shape", "defects", "texture", "ffd")
#: smallest semi-axis of an object file, metres (the contact prior's axis_min, models/priors.toml)
AXIS_MIN_M = 1e-3
#: an object must lie within ±WORKSPACE_M metres of the origin on every axis (the recordings' contact_point range)
WORKSPACE_M = 2.0
#: most control points per axis of an object's FFD lattice
FFD_DIM_MAX = 16
#: a texture's wavelength range, metres: 10 µm (far below a taxel pitch) to 5 cm (a wave longer than the pad is no
#: texture); object files and the texture library (:mod:`bayestouch.scene.textures`) both hold to it
WAVELENGTH_RANGE_M = (1e-5, 0.05)
#: largest |angle| of an object file, radians: one full turn (a value beyond it is most likely degrees)
ANGLE_MAX_RAD = 2 * np.pi


def _known(d: dict, keys: tuple, where: str, table: str) -> None:
    """Refuse a key of ``d`` that is not in ``keys`` (a typo would otherwise be ignored silently)."""
    unknown = [k for k in d if k not in keys]
    if unknown:
        at = f" {table}" if table else ""
        raise BadInput(f"{where}{at}: unknown key {unknown[0]!r}; expected one of {', '.join(keys)}")


def _vec3(d: dict, key: str, where: str) -> tuple[float, float, float]:
    v = d.get(key)
    if not (
        isinstance(v, list)
        and len(v) == 3
        and all(isinstance(x, int | float) and not isinstance(x, bool) and np.isfinite(x) for x in v)
    ):
        raise BadInput(f"{where}: '{key}' must be a list of three finite numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _num(d: dict, key: str, where: str, *, positive: bool = True, default=None) -> float:
    v = d.get(key, default)
    if not isinstance(v, int | float) or isinstance(v, bool) or not np.isfinite(v):
        raise BadInput(f"{where}: '{key}' must be a finite number, got {v!r}")
    if positive and not v > 0:
        raise BadInput(f"{where}: '{key}' must be > 0, got {v}")
    return float(v)


def _radians(values, key: str, where: str) -> None:
    """Refuse an angle of ``values`` beyond ±:data:`ANGLE_MAX_RAD` (degrees given for radians)."""
    big = [float(v) for v in values if abs(v) > ANGLE_MAX_RAD]
    if big:
        raise BadInput(
            f"{where}: '{key}' must be within ±2π (±{ANGLE_MAX_RAD:.4g}), got {big[0]:g}: radians expected; "
            f"{big[0]:g} looks like degrees"
        )


def _int(d: dict, key: str, where: str, lo: int, hi: int, default: int) -> int:
    v = d.get(key, default)
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise BadInput(f"{where}: '{key}' must be an integer in [{lo}, {hi}], got {v!r}")
    return int(v)


#: largest exponent of an object file: n = 100 is a box to within 1 % of its edge, and |q|^n of the points the
#: simulator evaluates (|q| up to a few) stays finite in float64 far beyond it (at n ≈ 3000 it does not)
N_MAX = 100.0


def object_from_dict(doc: dict, where: str = "object", source: Path | None = None) -> SceneObject:
    """Build a :class:`SceneObject` from a parsed TOML document (see ``models/objects/*.toml``)."""
    _known(doc, _TOP_KEYS, where, "")
    meta = doc.get("object", {})
    if not isinstance(meta, dict):
        raise BadInput(f"{where}: 'object' must be a table [object] with name and description, got {meta!r}")
    _known(meta, ("name", "description"), where, "[object]")
    shape = doc.get("shape")
    if not isinstance(shape, dict):
        raise BadInput(f"{where}: missing table [shape] with centre_m, axes_m, angles_rad, n")
    _known(shape, ("centre_m", "axes_m", "angles_rad", "n"), where, "[shape]")
    centre = _vec3(shape, "centre_m", f"{where} [shape]")
    axes = _vec3(shape, "axes_m", f"{where} [shape]")
    if min(axes) <= 0:
        raise BadInput(f"{where} [shape]: 'axes_m' must all be > 0 metres, got {list(axes)}")
    if max(axes) > 2.0:
        raise BadInput(f"{where} [shape]: 'axes_m' {list(axes)} look like millimetres; give metres")
    if min(axes) < AXIS_MIN_M:
        raise BadInput(
            f"{where} [shape]: 'axes_m' {list(axes)} has a semi-axis below {AXIS_MIN_M * 1e3:g} mm, smaller than "
            "the finger's pad can touch; give metres"
        )
    if max(abs(c) for c in centre) + max(axes) > WORKSPACE_M:
        raise BadInput(
            f"{where} [shape]: 'centre_m' {list(centre)} puts the object beyond ±{WORKSPACE_M:g} m, the workspace "
            "recordings are checked against; give metres"
        )
    angles = _vec3(shape, "angles_rad", f"{where} [shape]") if "angles_rad" in shape else (0.0, 0.0, 0.0)
    _radians(angles, "angles_rad", f"{where} [shape]")
    n = _num(shape, "n", f"{where} [shape]")
    if not 1.0 <= n <= N_MAX:
        raise BadInput(
            f"{where} [shape]: 'n' must be in [1, {N_MAX:g}] (convex n-ellipsoid; {N_MAX:g} is already a box), got {n}"
        )
    defects = []
    listed = doc.get("defects", [])
    if not (isinstance(listed, list) and all(isinstance(d, dict) for d in listed)):
        raise BadInput(f"{where}: 'defects' must be tables [[defects]] with kind, centre_m, radius_m, depth_m")
    for i, d in enumerate(listed):
        w = f"{where} [[defects]] #{i + 1}"
        _known(d, ("kind", "centre_m", "radius_m", "depth_m", "end_m"), where, f"[[defects]] #{i + 1}")
        kind = d.get("kind")
        if kind not in DEFECT_KINDS:
            raise BadInput(f"{w}: 'kind' must be one of {', '.join(DEFECT_KINDS)}, got {kind!r}")
        end = _vec3(d, "end_m", w) if kind == "crack" else None
        defect = Defect(kind, _vec3(d, "centre_m", w), _num(d, "radius_m", w), _num(d, "depth_m", w), end)
        if defect.depth > min(axes) or defect.radius > max(axes):
            raise BadInput(
                f"{w}: 'depth_m' must not exceed the smallest semi-axis ({min(axes):g} m) nor 'radius_m' the largest "
                f"({max(axes):g} m), got depth {defect.depth:g} and radius {defect.radius:g}"
            )
        defects.append(defect)
    s = ne.NEllipsoid(jnp.array(centre), jnp.array(axes), jnp.array(angles), jnp.array(n))
    texture = None
    if "texture" in doc:
        t, w = doc["texture"], f"{where} [texture]"
        if not isinstance(t, dict):
            raise BadInput(f"{w}: 'texture' must be a table [texture] with wavelength_m, amplitude_m, …, got {t!r}")
        _known(
            t, ("amplitude_m", "wavelength_m", "orientation_rad", "roughness_m", "seed", "modes"), where, "[texture]"
        )
        texture = TextureSpec(
            _num(t, "amplitude_m", w, positive=False, default=0.0),
            _num(t, "wavelength_m", w),
            _num(t, "orientation_rad", w, positive=False, default=0.0),
            _num(t, "roughness_m", w, positive=False, default=0.0),
            _int(t, "seed", w, 0, 2**63 - 1, 0),
            _int(t, "modes", w, 1, 4096, 16),
        )
        lo, hi = WAVELENGTH_RANGE_M
        if not lo <= texture.wavelength <= hi:
            raise BadInput(f"{w}: 'wavelength_m' must be in [{lo:g}, {hi:g}] metres, got {texture.wavelength:g}")
        _radians((texture.orientation,), "orientation_rad", w)
        if min(texture.amplitude, texture.roughness) < 0:
            raise BadInput(
                f"{w}: amplitude_m and roughness_m must be ≥ 0 metres (a depth, not a sign), got "
                f"{texture.amplitude} and {texture.roughness}"
            )
        if max(texture.amplitude, texture.roughness) > 0.2 * min(axes):
            raise BadInput(f"{w}: amplitude_m/roughness_m must stay below a fifth of the smallest axis (metres)")
    ffd = None
    if "ffd" in doc:
        f, w = doc["ffd"], f"{where} [ffd]"
        if not isinstance(f, dict):
            raise BadInput(f"{w}: 'ffd' must be a table [ffd] with dims, amplitude_m, seed, margin, got {f!r}")
        _known(f, ("dims", "amplitude_m", "seed", "margin"), where, "[ffd]")
        dims = f.get("dims")
        if not (
            isinstance(dims, list)
            and len(dims) == 3
            and all(isinstance(x, int) and not isinstance(x, bool) and 2 <= x <= FFD_DIM_MAX for x in dims)
        ):
            raise BadInput(f"{w}: 'dims' must be three integers from 2 to {FFD_DIM_MAX} like [4, 4, 3], got {dims!r}")
        amp = _num(f, "amplitude_m", w, positive=False, default=0.0)
        if amp < 0:
            raise BadInput(f"{w}: 'amplitude_m' is the sd of the control-point displacements, ≥ 0 metres, got {amp}")
        if amp > 0.2 * min(axes):
            raise BadInput(
                f"{w}: 'amplitude_m' {amp:g} m must stay below a fifth of the smallest semi-axis ({min(axes):g} m)"
            )
        rng = np.random.default_rng(_int(f, "seed", w, 0, 2**63 - 1, 0))
        ffd = FFDSpec(tuple(dims), amp * rng.standard_normal((*dims, 3)), _num(f, "margin", w, default=0.15))
    return SceneObject(
        str(meta.get("name", source.stem if source else "object")),
        s,
        tuple(defects),
        str(meta.get("description", "")),
        source,
        texture,
        ffd,
    )


#: the shipped objects (``egg``, ``sphere``, ``box``, ``cylinder`` ...), by name
OBJECTS_DIR = MODELS / "objects"


def resolve_object(name: str, models=None) -> Path:
    """An object name or a TOML path → the file; BadInput if missing.

    A name (``egg``) is ``objects/egg.toml`` of the parameter folder ``models`` when that folder has it (a user's
    folder overrides), else the shipped ``models/objects/egg.toml``.
    """
    if not str(name).strip() or str(name).strip() == ".":
        raise BadInput("object: got an empty name; expected an object name like egg or a path to a .toml file")
    p = Path(name)
    if p.suffix == ".toml":
        if problem := file_problem(p):
            raise BadInput(f"object {p}: {problem} (expected a TOML object file like models/objects/egg.toml)")
        return p
    folders = [Path(models) / "objects"] if models is not None else []
    for folder in [*folders, OBJECTS_DIR]:
        q = folder / f"{name}.toml"
        if q.is_file():
            return q
    if p.is_dir():
        raise BadInput(f"object {p}: is a folder; expected an object name like egg or a path to a .toml file")
    known = sorted({x.stem for folder in [*folders, OBJECTS_DIR] for x in folder.glob("*.toml")})
    raise BadInput(
        f"object: unknown object {str(name)!r}; expected one of {', '.join(known)} or a path to a .toml file"
    )


def load_object(path, models=None) -> SceneObject:
    """Read an object TOML file (metres, radians), or an object by name (``"egg"``: from ``models/objects`` when
    that parameter folder has it, else the shipped one; :func:`resolve_object`); a bad file raises
    :class:`BadInput` naming the field."""
    if not isinstance(path, str | os.PathLike) or not isinstance(os.fspath(path), str):
        raise BadInput(
            f"path: expected a path or an object name (e.g. 'egg'), got {type(path).__name__} {shown(path, 60)}"
        )
    if models is not None:
        check_path(models, "models")
    p = Path(path) if Path(path).suffix == ".toml" else resolve_object(str(path), models)
    return object_from_dict(read_toml(p, "object file", "models/objects/egg.toml"), str(p), p)
