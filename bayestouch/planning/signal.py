"""The planner's predicted signal of a stroke at the contact level: for each n-ellipsoid hypothesis θ, the distance
along each approach ray of the stroke to the surface of θ.

A stroke of T rays: start points ``x0`` (T, 3) in metres a stand-off outside the believed surface, unit directions
``d`` (T, 3) (the believed inward normals) and a ray length ``t_max`` in metres. Predicted signals are (N, C, T)
metres for N hypotheses and C strokes; a ray that misses reads ``t_max``, one that starts inside reads 0. The same
rays on the true object are :func:`bayestouch.scene.raycast.true_ray_distances`. Treatment of misses and the
reason for the contact level: ``docs/planning.md``.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne

__all__ = ["predict_signals"]


@partial(jax.jit, static_argnums=(5, 6))
def _predict(vectors, starts, dirs, t_max, t_init, iters, single):
    dtype = jnp.float32 if single else jnp.float64
    return jax.vmap(lambda v: ne.ray_distances(ne.from_vector(v), starts, dirs, t_max, iters, t_init, dtype))(vectors)


def predict_signals(
    shape_vectors, starts, dirs, t_max: float, *, t_init: float = 0.0, iters: int = 10, single: bool = False
) -> np.ndarray:
    """Predicted signals of many shapes for a batch of strokes (NumPy edge, one compiled program per size).

    Parameters
    ----------
    shape_vectors : (N, 10) float
        n-ellipsoid vectors (:func:`bayestouch.geometry.nellipsoid.from_vector`; metres, radians).
    starts, dirs : (C, T, 3) float
        Ray starts (metres) and unit directions of C strokes of T rays.
    t_max : float, metres
    t_init, iters, single
        Newton's starting guess (metres), steps, and float32 arithmetic
        (:func:`bayestouch.geometry.nellipsoid.ray_distances`).

    Returns
    -------
    (N, C, T) float, metres
    """
    return np.asarray(
        _predict(
            jnp.asarray(shape_vectors, dtype=jnp.float64),
            jnp.asarray(starts, dtype=jnp.float64),
            jnp.asarray(dirs, dtype=jnp.float64),
            jnp.float64(t_max),
            jnp.float64(t_init),
            int(iters),
            bool(single),
        )
    )
