"""The one place where the core's array backend is configured.

Every core module imports ``jax`` and ``jnp`` from here, so float64 is enabled exactly once, before
any array is created.
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402  (must follow the x64 switch)

__all__ = ["jax", "jnp"]
