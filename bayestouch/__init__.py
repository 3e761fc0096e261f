"""bayestouch: probabilistic inference for tactile shape and texture sensing.

The public API is imported lazily (``import bayestouch`` stays quick; JAX loads on first use). The first use of a
fitting, geometry or physics function turns on JAX's float64 mode for the whole process (the likelihoods need it;
:mod:`bayestouch.backend`). Messages go to ``logging.getLogger("bayestouch")``; figures never touch pyplot's backend.

In a notebook::

    import bayestouch as bt
    fit = bt.fit(points)            # (M, 3) metres, a CSV path or a recording
    fit.idata                       # ArviZ InferenceData: posterior (with volume), sample_stats, log_likelihood, …
    fit.summary()                   # pandas DataFrame with units
    fit.plot(); fit.uncertainty_mesh()
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_API = {
    "Fit": "bayestouch.api",
    "fit": "bayestouch.api",
    "simulate": "bayestouch.api",
    "calibrate": "bayestouch.api",
    "read_spread_mesh": "bayestouch.io.meshes",
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
    "ContactPoints": "bayestouch.io.contacts",
    "load_contact_points": "bayestouch.io.contacts",
    "save_contact_points": "bayestouch.io.contacts",
    "fit_nellipsoid_de": "bayestouch.paper",
    "refine_ffd": "bayestouch.paper",
    "reproduce_table2": "bayestouch.paper",
    "load_finger": "bayestouch.physics.virtual",
    "record_strokes": "bayestouch.physics.virtual",
    "random_strokes": "bayestouch.scene.strokes",
    "read_recording": "bayestouch.io.recording",
    "write_recording": "bayestouch.io.recording",
    "sample": "bayestouch.inference.sampler",
    "run_contact_fit": "bayestouch.inference.run",
    "run_raw_fit": "bayestouch.inference.raw",
    "run_parts_fit": "bayestouch.inference.parts_run",
    "load_occupancy": "bayestouch.io.occupancy",
    "patch_posterior": "bayestouch.inference.patch",
    "explore": "bayestouch.planning.loop",
    "ExploreSettings": "bayestouch.planning.loop",
    "run_experiment": "bayestouch.planning.experiment",
    "FingerDevice": "bayestouch.hardware.device",
    "VirtualDevice": "bayestouch.hardware.simulator",
    "run_demo": "bayestouch.demo",
    "write_report": "bayestouch.report.page",
}

__all__ = ["__version__", *sorted(_API)]


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'bayestouch' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_API))
