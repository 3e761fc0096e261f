"""Raw-current likelihood level: the forward model predicts every selected taxel's current along the recorded
strokes, and the read-out noise model gives the likelihood of the corrected ln I readings (F frames × M taxels).
θ is (11,): centre m, log semi-axes log m, Euler angles rad, log n, log k (noise multiplier); (16,) with the
texture (grating u, v m, log λ log m, orientation rad, log roughness log m; :mod:`bayestouch.inference.grating`).

One job per module: :mod:`~bayestouch.inference.raw.data` (the recording read into :class:`RawData`),
:mod:`~bayestouch.inference.raw.likelihood` (prediction, likelihood, prior box, pruning),
:mod:`~bayestouch.inference.raw.texture` (the grating search and textured start),
:mod:`~bayestouch.inference.raw.adjustment` (the sandwich adjustment),
:mod:`~bayestouch.inference.raw.calibrate` (the finger's gains from strokes over a known object),
:mod:`~bayestouch.inference.raw.fit` (the start, the posterior model and :func:`run_raw_fit`).
The model's derivation and measured figures: ``docs/raw_model.md``.
"""

from bayestouch.inference.raw.adjustment import ADJUST_BLOCK_S, Adjustment, curvature_adjustment
from bayestouch.inference.raw.calibrate import calibrate_device
from bayestouch.inference.raw.data import RawData, host_finger, load_raw_data, nominal_log_gain_sd, unloaded_current
from bayestouch.inference.raw.fit import (
    BARE_STRIDE,
    DETECT_NATS,
    MISFIT_K,
    RAW_PREDICTIVE_DRAWS,
    RAW_PROPOSAL_NU,
    TEXTURE_STRIDE,
    initial_raw_theta,
    misfit_warnings,
    raw_model,
    run_raw_fit,
)
from bayestouch.inference.raw.likelihood import (
    PRUNE_MARGIN,
    RAW_NATURAL_NAMES,
    RAW_PARAM_NAMES,
    RAW_TEXTURE_NATURAL_NAMES,
    RAW_TEXTURE_PARAM_NAMES,
    STUDENT_NU,
    load_raw_priors,
    make_raw_log_prob,
    predict_log_current,
    predict_readings,
    prune_clear,
    prune_clearance,
    raw_bounds,
    raw_log_likelihood,
    raw_log_prob,
    raw_log_prob_batch,
    reading_log_lik,
    taxel_offsets,
)
from bayestouch.inference.raw.texture import (
    TextureStart,
    canonical_theta,
    initial_raw_texture,
    plane_theta,
    roughness_variance,
    search_texture,
    texture_reference,
    textured_bounds,
)

__all__ = [
    "RawData",
    "RAW_PARAM_NAMES",
    "RAW_NATURAL_NAMES",
    "load_raw_data",
    "predict_log_current",
    "raw_log_likelihood",
    "raw_log_prob",
    "make_raw_log_prob",
    "raw_bounds",
    "initial_raw_theta",
    "raw_model",
    "run_raw_fit",
    "misfit_warnings",
    "MISFIT_K",
    "load_raw_priors",
    "RAW_PREDICTIVE_DRAWS",
    "STUDENT_NU",
    "RAW_TEXTURE_PARAM_NAMES",
    "RAW_TEXTURE_NATURAL_NAMES",
    "raw_log_prob_batch",
    "search_texture",
    "initial_raw_texture",
    "TextureStart",
    "roughness_variance",
    "textured_bounds",
    "texture_reference",
    "canonical_theta",
    "plane_theta",
    "RAW_PROPOSAL_NU",
    "curvature_adjustment",
    "Adjustment",
    "DETECT_NATS",
    "TEXTURE_STRIDE",
    "BARE_STRIDE",
    "ADJUST_BLOCK_S",
    "prune_clear",
    "prune_clearance",
    "PRUNE_MARGIN",
    "host_finger",
    "nominal_log_gain_sd",
    "unloaded_current",
    "reading_log_lik",
    "taxel_offsets",
    "predict_readings",
    "calibrate_device",
]
