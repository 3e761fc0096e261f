"""Scene objects: an n-ellipsoid base (eq. 4–6) whose surface is displaced along its normal by defects
(bumps, shallows, cracks), read from TOML parameter files in ``models/objects``.

The displaced surface is y' = y + h(y) n(y) with y on the base surface and h a sum of defect height
functions (metres, positive outward). The texture height field of the physics issue adds to h.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bayestouch._jax import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import nellipsoid_mesh

__all__ = ["Defect", "SceneObject", "load_object", "object_from_dict", "DEFECT_KINDS"]

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
        c = np.asarray(self.centre)
        if self.kind == "crack":
            e = np.asarray(self.end)
            d = e - c
            t = np.clip(((y - c) @ d) / (d @ d), 0.0, 1.0)
            r2 = np.sum((y - (c + t[:, None] * d)) ** 2, axis=1)
        else:
            r2 = np.sum((y - c) ** 2, axis=1)
        g = np.exp(-0.5 * r2 / self.radius**2)
        return self.depth * g if self.kind == "bump" else -self.depth * g


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

    def height(self, y) -> np.ndarray:
        """Total defect height (N,) in metres at base-surface points ``y (N, 3)``."""
        y = np.asarray(y, float)
        h = np.zeros(len(y))
        for d in self.defects:
            h += d.height(y)
        return h

    def displace(self, y) -> np.ndarray:
        """Base-surface points (N, 3) in metres → points of the displaced (true) surface."""
        y = np.asarray(y, float)
        if not self.defects:
            return y
        nrm = ne.evaluate(ne.normals, self.shape, y)
        return y + self.height(y)[:, None] * nrm

    def mesh(self, res: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """Watertight mesh of the true surface: (vertices (V, 3) metres, faces (F, 3))."""
        v, f = nellipsoid_mesh(self.shape, res)
        return self.displace(v), f


def _vec3(d: dict, key: str, where: str) -> tuple[float, float, float]:
    v = d.get(key)
    if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, int | float) for x in v)):
        raise BadInput(f"{where}: '{key}' must be a list of three numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _num(d: dict, key: str, where: str, *, positive: bool = True, default=None) -> float:
    v = d.get(key, default)
    if not isinstance(v, int | float) or isinstance(v, bool):
        raise BadInput(f"{where}: '{key}' must be a number, got {v!r}")
    if positive and not v > 0:
        raise BadInput(f"{where}: '{key}' must be > 0, got {v}")
    return float(v)


def object_from_dict(doc: dict, where: str = "object", source: Path | None = None) -> SceneObject:
    """Build a :class:`SceneObject` from a parsed TOML document (see ``models/objects/*.toml``)."""
    meta = doc.get("object", {})
    shape = doc.get("shape")
    if not isinstance(shape, dict):
        raise BadInput(f"{where}: missing table [shape] with centre_m, axes_m, angles_rad, n")
    centre = _vec3(shape, "centre_m", f"{where} [shape]")
    axes = _vec3(shape, "axes_m", f"{where} [shape]")
    if min(axes) <= 0:
        raise BadInput(f"{where} [shape]: 'axes_m' must all be > 0 metres, got {list(axes)}")
    if max(axes) > 2.0:
        raise BadInput(f"{where} [shape]: 'axes_m' {list(axes)} look like millimetres; give metres")
    angles = _vec3(shape, "angles_rad", f"{where} [shape]") if "angles_rad" in shape else (0.0, 0.0, 0.0)
    n = _num(shape, "n", f"{where} [shape]")
    if n < 1.0:
        raise BadInput(f"{where} [shape]: 'n' must be ≥ 1 (convex n-ellipsoid), got {n}")
    defects = []
    for i, d in enumerate(doc.get("defects", [])):
        w = f"{where} [[defects]] #{i + 1}"
        kind = d.get("kind")
        if kind not in DEFECT_KINDS:
            raise BadInput(f"{w}: 'kind' must be one of {', '.join(DEFECT_KINDS)}, got {kind!r}")
        end = _vec3(d, "end_m", w) if kind == "crack" else None
        defects.append(Defect(kind, _vec3(d, "centre_m", w), _num(d, "radius_m", w), _num(d, "depth_m", w), end))
    s = ne.NEllipsoid(jnp.array(centre), jnp.array(axes), jnp.array(angles), jnp.array(n))
    return SceneObject(str(meta.get("name", source.stem if source else "object")), s, tuple(defects),
                       str(meta.get("description", "")), source)


def load_object(path) -> SceneObject:
    """Read an object TOML file (metres, radians); a bad file raises :class:`BadInput` naming the field."""
    p = Path(path)
    if not p.is_file():
        raise BadInput(f"object file {p} does not exist (expected a TOML file such as models/objects/egg.toml)")
    try:
        doc = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise BadInput(f"{p}: not valid TOML ({str(e).splitlines()[0]})") from None
    return object_from_dict(doc, str(p), p)
