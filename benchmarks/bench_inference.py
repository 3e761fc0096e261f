"""Contact-level log-probability throughput (issue 4's first target: ≥ 100,000 evaluations/s for 1000 points
at a batch of 64 on 2 cores)."""

from __future__ import annotations

import numpy as np

from bayestouch._jax import jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_surface
from bayestouch.inference.contact import make_log_prob
from benchmarks.harness import best_of


def bench_contact_log_prob():
    truth = ne.NEllipsoid(jnp.array([0.0, 0.0, 0.0]), jnp.array([0.03, 0.022, 0.022]), jnp.array([0.4, 0.3, -0.5]),
                          jnp.array(2.2))
    rng = np.random.default_rng(0)
    pts = sample_surface(truth, 1000, seed=0) + rng.normal(0, 3e-4, (1000, 3))
    f, bounds = make_log_prob(pts)
    theta0 = np.concatenate([[0, 0, 0], np.log([0.03, 0.022, 0.022]), [0.4, 0.3, -0.5], [np.log(2.2)],
                             [np.log(3e-4)]])
    W = theta0 + 1e-3 * rng.normal(size=(64, 11))
    f(W)
    t = best_of(lambda: f(W), repeat=10, number=20)
    return [{"metric": "contact log-probability evaluations/s", "value": 64 / t, "unit": "1/s", "points": 1000,
             "batch": 64, "target": 100000}]
