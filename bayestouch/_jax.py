"""The one place where the core's array backend is configured.

Every core module imports ``jax`` and ``jnp`` from here, so float64 is enabled exactly once, before
any array is created.
"""

from __future__ import annotations

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402  (must follow the x64 switch)

__all__ = ["jax", "jnp", "pad_pow2"]


def pad_pow2(a, fill=None, min_size: int = 1) -> np.ndarray:
    """Rows of ``a`` (NumPy edge) padded to the next power of two, at least ``min_size``.

    Jitted functions called on arrays of varying length (paths, data sets, posterior draws) then compile
    for a handful of sizes instead of every length. Slice the result's first ``len(a)`` rows back out.

    Parameters
    ----------
    a : (m, ...) array
    fill : array broadcastable to one row, optional
        Value of the padding rows; default the first row of ``a`` (ones when ``a`` is empty), which keeps
        the padding inside the domain of the function.
    min_size : int

    Returns
    -------
    (size, ...) float ndarray
    """
    a = np.asarray(a, dtype=np.float64)
    m = len(a)
    size = max(min_size, 1 << max(m - 1, 0).bit_length())
    out = np.empty((size, *a.shape[1:]))
    out[:m] = a
    out[m:] = (a[0] if m else 1.0) if fill is None else fill
    return out
