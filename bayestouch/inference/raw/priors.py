"""The raw level's prior constants, ``[raw_priors]`` of ``models/priors.toml``: the noise multiplier k's box and
log-sd, the sd of the taxels' common response factor when no calibration gives it, and the range of the taxels'
response lag."""

from __future__ import annotations

import numpy as np

from bayestouch.errors import BadInput
from bayestouch.params import MODELS, Spec, build

__all__ = ["RAW_PRIOR_SPECS", "load_raw_priors", "LOG_K_RANGE", "LOG_K_PRIOR_SD", "RESPONSE_SCALE_SD", "LAG_RANGE"]

RAW_PRIOR_SPECS = {
    "noise_scale_min": Spec("1", 1e-3, 1.0),
    "noise_scale_max": Spec("1", 1.0, 1e8),
    "log_noise_scale_sd": Spec("1", 1e-2, 100.0),
    "response_scale_sd": Spec("1", 1e-4, 10.0),
    "lag_min": Spec("s", 1e-6, 100.0),
    "lag_max": Spec("s", 1e-6, 100.0),
}


def load_raw_priors(path=None) -> dict[str, float]:
    """Read ``[raw_priors]`` of ``models/priors.toml`` (or ``path``): the noise multiplier k's box and log-sd,
    the response factor's sd and the response lag's range (s)."""
    where = MODELS / "priors.toml" if path is None else path
    out = build(dict, where, "raw_priors", RAW_PRIOR_SPECS)
    if not out["lag_min"] <= out["lag_max"]:
        raise BadInput(f"{where} [raw_priors]: lag_min {out['lag_min']:g} s is above lag_max {out['lag_max']:g} s")
    return out


_RAW_PRIORS = load_raw_priors()

#: box of log k (noise-scale multiplier) and the sd of its N(0, ·) prior
LOG_K_RANGE = (float(np.log(_RAW_PRIORS["noise_scale_min"])), float(np.log(_RAW_PRIORS["noise_scale_max"])))
LOG_K_PRIOR_SD = float(_RAW_PRIORS["log_noise_scale_sd"])
#: prior sd of the taxels' common response factor a on Δ ln I without a calibration (dimensionless)
RESPONSE_SCALE_SD = float(_RAW_PRIORS["response_scale_sd"])
#: range (s) of the taxels' response lag τ, uniform a priori (not calibrated: the texture identifier marginalises it)
LAG_RANGE = (float(_RAW_PRIORS["lag_min"]), float(_RAW_PRIORS["lag_max"]))
