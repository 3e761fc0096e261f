"""Geometry throughput: inside–outside evaluations (eq. 4–6) for a batch of parameter sets."""

from __future__ import annotations

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from benchmarks.harness import best_of


def _params(batch: int, rng) -> jnp.ndarray:
    v = np.column_stack(
        [
            rng.normal(0, 0.005, (batch, 3)),
            rng.uniform(0.01, 0.04, (batch, 3)),
            rng.uniform(-np.pi, np.pi, (batch, 3)),
            rng.uniform(1.5, 8.0, batch),
        ]
    )
    return jnp.asarray(v)


def bench_inside_outside():
    """1000 points × a batch of 64 parameter sets, jit + vmap, float64 on CPU."""
    rng = np.random.default_rng(0)
    pts = jnp.asarray(rng.uniform(-0.05, 0.05, (1000, 3)))
    V = _params(64, rng)
    f = jax.jit(jax.vmap(lambda v: ne.inside_outside(ne.from_vector(v), pts)))
    f(V).block_until_ready()
    t = best_of(lambda: f(V).block_until_ready(), repeat=20, number=20)
    out = [
        {"metric": "inside_outside evaluations/s", "value": 64 * 1000 / t, "unit": "1/s", "points": 1000, "batch": 64}
    ]
    g = jax.jit(jax.vmap(lambda v: ne.radial_distance(ne.from_vector(v), pts)))
    g(V).block_until_ready()
    t = best_of(lambda: g(V).block_until_ready(), repeat=20, number=20)
    out.append(
        {"metric": "radial_distance evaluations/s", "value": 64 * 1000 / t, "unit": "1/s", "points": 1000, "batch": 64}
    )
    h = jax.jit(jax.vmap(jax.grad(lambda v: jnp.sum(ne.radial_distance(ne.from_vector(v), pts) ** 2))))
    h(V).block_until_ready()
    t = best_of(lambda: h(V).block_until_ready(), repeat=20, number=10)
    out.append(
        {
            "metric": "gradient of Σ radial² per parameter set",
            "value": t / 64 * 1e6,
            "unit": "µs",
            "points": 1000,
            "batch": 64,
        }
    )
    return out
