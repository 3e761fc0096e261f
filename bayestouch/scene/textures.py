"""The texture library: K physical texture samples on one known test object, and straight strokes over its face.

The library (``models/textures.toml``, :func:`load_library`) gives each texture's grating amplitude and
wavelength (metres), orientation (radians) and roughness (metres) on the graphite plate's shape without defects.
A stroke (:class:`StrokeSpec`, :func:`plate_stroke`) is a straight, position-controlled line over the plate's flat
top face (metres, m/s, Hz), commanded on the nominal (untextured) surface. Texture identification is described in
``docs/texture_identification.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.params import MODELS, read_toml
from bayestouch.scene.objects import WAVELENGTH_RANGE_M, SceneObject, TextureSpec, build_surface, object_from_dict
from bayestouch.scene.strokes import Stroke, stroke_from_path
from bayestouch.scene.surface import Surface, Texture

__all__ = [
    "LIBRARY",
    "TextureLibrary",
    "load_library",
    "library_from_dict",
    "LARGE_LIBRARY",
    "generate_library",
    "library_toml",
    "StrokeSpec",
    "plate_stroke",
    "random_stroke_spec",
]

#: the shipped texture library
LIBRARY = MODELS / "textures.toml"
#: the shipped large library (:func:`generate_library` with its defaults, written by :func:`library_toml`)
LARGE_LIBRARY = MODELS / "textures_large.toml"
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


#: the fields of a ``[[texture]]`` table
_TEXTURE_KEYS = ("name", "amplitude_m", "wavelength_m", "orientation_rad", "roughness_m", "seed")


def _known_keys(table: dict, known: set, where: str) -> None:
    """:class:`BadInput` naming the first key of ``table`` that is not in ``known`` (a misspelt field was ignored,
    its default taken, exit 0)."""
    unknown = sorted(k for k in table if k not in known)
    if unknown:
        raise BadInput(f"{where}: unknown key '{unknown[0]}'; expected {', '.join(sorted(known))}")


def library_from_dict(doc: dict, where: str = "texture library", source: Path | None = None) -> TextureLibrary:
    """Build a :class:`TextureLibrary` from a parsed TOML document (see ``models/textures.toml``).

    Parameters
    ----------
    doc : dict
        ``[library]`` (``modes``), ``[object]`` with ``[object.shape]`` (metres, radians) and at least two
        ``[[texture]]`` tables (``name``, ``amplitude_m``, ``wavelength_m``, ``orientation_rad``, ``roughness_m``,
        ``seed``).
    where : str
        Names the document in error messages.
    source : Path, optional
        The file it came from.

    Returns
    -------
    TextureLibrary

    Raises
    ------
    BadInput
        A bad field, naming the table, the entry and the field.
    """
    _known_keys(doc, {"library", "object", "texture"}, where)
    lib = doc.get("library")
    if not isinstance(lib, dict) or "modes" not in lib:
        # a file without it was read with 16 modes: a typo'd table name ([libary]) went unnoticed
        raise BadInput(f"{where}: needs a table [library] with modes = N (the roughness's wave count, 1–256)")
    _known_keys(lib, {"description", "modes"}, f"{where} [library]")
    modes = lib["modes"]
    if not isinstance(modes, int) or isinstance(modes, bool) or not 1 <= modes <= 256:
        raise BadInput(f"{where} [library]: 'modes' must be an integer in [1, 256], got {modes!r}")
    obj = doc.get("object")
    if not isinstance(obj, dict) or not isinstance(obj.get("shape"), dict):
        raise BadInput(f"{where}: missing table [object.shape] with centre_m, axes_m, angles_rad, n (metres)")
    meta = {k: v for k, v in obj.items() if k != "shape"}
    base = object_from_dict({"object": meta, "shape": obj["shape"]}, f"{where} [object]", source)
    entries = doc.get("texture")
    if not isinstance(entries, list) or len(entries) < 2:
        got = (
            f"{len(entries)} ({', '.join(repr(str(e.get('name', '?'))) for e in entries if isinstance(e, dict))})"
            if isinstance(entries, list) and entries
            else ("a table [texture], not [[texture]]" if isinstance(entries, dict) else "none")
        )
        raise BadInput(f"{where}: needs at least two [[texture]] tables, got {got}")
    names, specs = [], []
    cmin = float(np.min(np.asarray(base.shape.axes)))
    for i, t in enumerate(entries):
        w = f"{where} [[texture]] #{i + 1}"
        if not isinstance(t, dict):
            raise BadInput(f"{w}: expected a table [[texture]] with name, wavelength_m, amplitude_m, …, got {t!r}")
        name = t.get("name")
        if not isinstance(name, str) or not name or name in names:
            raise BadInput(f"{w}: 'name' must be a unique non-empty string, got {name!r}")
        w = f"{where} [[texture]] '{name}'"
        _known_keys(t, set(_TEXTURE_KEYS), w)
        amp = _number(t, "amplitude_m", w, 0.0, 5e-4, default=0.0)
        lam = _number(t, "wavelength_m", w, *WAVELENGTH_RANGE_M)
        ori = _number(t, "orientation_rad", w, -2 * np.pi, 2 * np.pi, default=0.0)
        rough = _number(t, "roughness_m", w, 0.0, 5e-4, default=0.0)
        seed = t.get("seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise BadInput(f"{w}: 'seed' must be a non-negative integer, got {seed!r}")
        if max(amp, rough) > 0.2 * cmin:
            raise BadInput(f"{w}: 'amplitude_m'/'roughness_m' must stay below a fifth of the object's smallest axis")
        spec = TextureSpec(amp, lam, ori, rough, seed, modes)
        if spec in specs:
            raise BadInput(
                f"{w}: the same texture as '{names[specs.index(spec)]}' (every field alike); a library's textures "
                "must differ"
            )
        names.append(name)
        specs.append(spec)
    return TextureLibrary(tuple(names), tuple(specs), base, source)


def generate_library(count: int = 100, twins: int = 20, seed: int = 0) -> dict:
    """A library document (the :func:`library_from_dict` form) of ``count`` drawn textures and ``twins`` close
    copies of some of them, on the shipped library's test object.

    Each drawn texture is, with probabilities 0.3 / 0.45 / 0.25, only rough (RMS roughness log-uniform in
    5–40 µm, correlation length log-uniform in 0.5–4 mm), a grating (period log-uniform in 0.5–4 mm, amplitude
    log-uniform in 10–100 µm, orientation uniform in [0, π)) or a grating with roughness (both): the ranges of
    ``models/textures.toml``, drawn continuously so that neighbours in the library differ by any amount. A twin
    copies one drawn texture (its roughness realisation too) and changes one property by a small factor — the
    amplitude or roughness by 5–20 %, the period by 3–10 %, or the orientation by 5–15° — the close pairs a
    library of real samples has (Fishel & Loeb 2012 used 117 textures, several pairs of them nearly alike).

    Parameters
    ----------
    count : int
        Drawn textures (≥ 2).
    twins : int
        Close copies (0 ≤ twins ≤ count).
    seed : int
        Seed of the draw (``np.random.default_rng(seed)``).

    Returns
    -------
    dict
        ``library``, ``object`` and ``texture`` tables.
    """
    if count < 2 or not 0 <= twins <= count:
        raise BadInput(f"generate_library: need count ≥ 2 and 0 ≤ twins ≤ count, got {count} and {twins}")
    rng = np.random.default_rng(seed)
    base = read_toml(LIBRARY, "texture library", "models/textures.toml")

    def logu(lo: float, hi: float) -> float:
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))

    entries = []
    for i in range(count):
        kind = rng.choice(3, p=[0.3, 0.45, 0.25])
        t = {"amplitude_m": 0.0, "wavelength_m": 0.0, "orientation_rad": 0.0, "roughness_m": 0.0}
        if kind == 0:
            t.update(roughness_m=logu(5e-6, 40e-6), wavelength_m=logu(0.5e-3, 4e-3))
        else:
            t.update(amplitude_m=logu(10e-6, 100e-6), wavelength_m=logu(0.5e-3, 4e-3))
            t["orientation_rad"] = float(rng.uniform(0.0, np.pi))
            if kind == 2:
                t["roughness_m"] = logu(5e-6, 40e-6)
        t = {"name": f"t{i:03d}_" + ("rough", "grating", "grating_rough")[kind], **t, "seed": 1000 + i}
        entries.append(t)
    for j, i in enumerate(rng.choice(count, size=twins, replace=False)):
        t = dict(entries[i])
        grating = t["amplitude_m"] > 0
        what = rng.choice(["size", "period", "orientation"] if grating else ["size", "period"])
        sign = float(rng.choice([-1.0, 1.0]))
        if what == "size":
            key = "amplitude_m" if grating else "roughness_m"
            t[key] *= 1.0 + sign * rng.uniform(0.05, 0.20)
        elif what == "period":
            t["wavelength_m"] *= 1.0 + sign * rng.uniform(0.03, 0.10)
        else:
            t["orientation_rad"] = float(np.mod(t["orientation_rad"] + sign * np.deg2rad(rng.uniform(5, 15)), np.pi))
        t["name"] = f"{entries[i]['name']}_twin{j:02d}_{what}"
        entries.append(t)
    return {
        "library": {
            "description": f"{count} drawn textures and {twins} close twins (generate_library seed {seed})",
            "modes": base["library"]["modes"],
        },
        "object": base["object"],
        "texture": entries,
    }


def library_toml(doc: dict, header: str = "") -> str:
    """TOML text of a library document (:func:`generate_library`), each line of ``header`` as a comment."""

    def value(v) -> str:
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, bool):
            return str(v).lower()
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines = [f"# {h}".rstrip() for h in header.splitlines()]
    lines += ["", "[library]"] + [f"{k} = {value(v)}" for k, v in doc["library"].items()]
    obj = {k: v for k, v in doc["object"].items() if k != "shape"}
    lines += ["", "[object]"] + [f"{k} = {value(v)}" for k, v in obj.items()]
    lines += ["", "[object.shape]"] + [f"{k} = {value(v)}" for k, v in doc["object"]["shape"].items()]
    for t in doc["texture"]:
        lines += ["", "[[texture]]"] + [f"{k} = {value(v)}" for k, v in t.items()]
    return "\n".join(lines) + "\n"


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
    """The :class:`Stroke` of ``spec`` on the untextured top face of ``obj``, displaced along its direction.

    Parameters
    ----------
    obj : SceneObject
        The test object (only its base shape is used).
    spec : StrokeSpec
    shift : float, metres
        Displacement along the stroke (the start-phase error of the truth; 0 for the commanded stroke).

    Returns
    -------
    Stroke
        T = round(length / speed · rate) frames.
    """
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
    """A stroke of uniform direction whose whole path (± 1 mm) stays within the flat central part of the face.

    Parameters
    ----------
    obj : SceneObject
        The test object.
    rng : numpy Generator
        Draws the direction, then the start.
    speed : float, m/s
    depth : float, metres
    length : float, metres
    rate : float, Hz

    Returns
    -------
    StrokeSpec
    """
    a, b, _ = (float(v) for v in np.asarray(obj.shape.axes))
    phi = rng.uniform(0.0, 2 * np.pi)
    d = np.array([np.cos(phi), np.sin(phi)])
    half = np.array([_FLAT_FRACTION * a, _FLAT_FRACTION * b])
    lo = np.maximum(-half, -half - d * length) + 1e-3
    hi = np.minimum(half, half - d * length) - 1e-3
    return StrokeSpec(tuple(rng.uniform(lo, hi)), float(phi), speed, depth, length, rate)
