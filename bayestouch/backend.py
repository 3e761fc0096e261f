"""The one place where the core's array backend is configured.

Every core module imports ``jax`` and ``jnp`` from here, so float64 is enabled exactly once, before
any array is created.

This is process-wide: JAX has one ``jax_enable_x64`` switch, and the likelihoods need float64 (a contact residual of
0.3 mm on a 30 mm object is 1e-2 of the coordinates, and the evidence of 10⁵ readings sums terms whose float32
rounding exceeds the differences between models). In a notebook that also runs float32 JAX code, importing any
fitting, geometry or physics module of bayestouch turns float64 on for it too; give such code explicit dtypes
(``jnp.asarray(x, dtype=jnp.float32)``). ``import bayestouch`` alone does not load JAX (its API loads lazily).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402  (must follow the x64 switch)

__all__ = ["jax", "jnp", "pad_pow2", "enable_compilation_cache"]


def enable_compilation_cache() -> str | None:
    """Keep compiled XLA programs on disk between runs of the command line (JAX's persistent compilation cache).

    A first contact-level fit in a fresh process spends ~10 s compiling about a hundred programs (the likelihood,
    its gradient, the evolutionary search, the summaries' maps and many small array operations); later runs read
    them back. The folder is ``$BAYESTOUCH_JAX_CACHE`` when set (``~`` expands; ``0``, ``false``, ``no``, ``off`` or
    an empty value disable the cache; ``1``, ``true``, ``yes``, ``on`` keep the default), else
    ``$XDG_CACHE_HOME/bayestouch/jax`` (``~/.cache/bayestouch/jax``). A value that cannot be a folder (a file) is
    said on stderr and the cache stays off. It takes effect only if nothing has been compiled yet in the process;
    results are identical with or without it.

    Returns
    -------
    str or None
        The cache folder, or None when disabled or not writable.
    """
    env = os.environ.get("BAYESTOUCH_JAX_CACHE")
    word = None if env is None else env.strip().lower()
    if word in ("", "0", "false", "no", "off"):
        return None
    default = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bayestouch" / "jax"
    base = default if word in (None, "1", "true", "yes", "on") else Path(env.strip()).expanduser()
    try:
        base.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        print(
            f"bayestouch: BAYESTOUCH_JAX_CACHE: {base} cannot be a cache folder ({e.strerror}); compiling without the "
            "cache (expected a folder, or 0 to turn it off)",
            file=sys.stderr,
        )
        return None
    jax.config.update("jax_compilation_cache_dir", str(base))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return str(base)


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
