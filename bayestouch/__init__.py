"""bayestouch: probabilistic inference for tactile shape and texture sensing.

The public API is imported lazily (``import bayestouch`` stays quick; JAX loads on first use).
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_API = {
    "BadInput": "bayestouch.errors",
    "NEllipsoid": "bayestouch.geometry.nellipsoid",
    "nellipsoid_mesh": "bayestouch.geometry.mesh",
    "sample_surface": "bayestouch.geometry.mesh",
    "surface_integrals": "bayestouch.geometry.integrals",
    "fit_two_step": "bayestouch.geometry.ffd",
    "texture_indicator": "bayestouch.geometry.texture",
    "compare_shapes": "bayestouch.geometry.compare",
    "SceneObject": "bayestouch.scene.objects",
    "load_object": "bayestouch.scene.objects",
    "random_paths": "bayestouch.scene.paths",
    "ContactPoints": "bayestouch.io",
    "load_contact_points": "bayestouch.io",
    "save_contact_points": "bayestouch.io",
    "fit_nellipsoid_de": "bayestouch.paper",
    "refine_ffd": "bayestouch.paper",
    "reproduce_table2": "bayestouch.paper",
}

__all__ = ["__version__", *sorted(_API)]


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'bayestouch' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_API))
