"""Cost of marginalising the FFD lattice analytically at the contact level (DESIGN.md §3.6), against the rigid
n-ellipsoid log-probability, for 1000 points at a batch of 32 walkers."""

from __future__ import annotations

import numpy as np

from bayestouch.geometry.mesh import sample_surface
from bayestouch.inference import contact as cm
from bayestouch.inference import ffd_marginal as fm
from benchmarks.harness import best_of

THETA = np.concatenate([[0, 0, 0], np.log([0.03, 0.022, 0.022]), [0.4, 0.3, -0.5], [np.log(2.2)], [np.log(3e-4)]])


def bench_ffd_marginal():
    import jax.numpy as jnp

    rng = np.random.default_rng(0)
    pts = sample_surface(cm.shape_of(jnp.asarray(THETA)), 1000, seed=0) + rng.normal(0, 3e-4, (1000, 3))
    W = THETA + 1e-3 * rng.normal(size=(32, 11))
    rows = []
    f, _ = cm.make_log_prob(pts, nu=np.inf)
    f(W)
    t = best_of(lambda: f(W), repeat=5, number=5)
    rows.append(
        {
            "metric": "rigid Gaussian log-probability evaluations/s",
            "value": 32 / t,
            "unit": "1/s",
            "points": 1000,
            "batch": 32,
            "lattice": "none",
            "sampled_dimension": 11,
        }
    )
    for dims in ((3, 3, 3), (4, 4, 4), (5, 5, 5)):
        g, _ = fm.make_ffd_log_prob(pts, dims)
        g(W)
        t = best_of(lambda g=g: g(W), repeat=3, number=2)
        k = int(np.prod(dims))
        rows.append(
            {
                "metric": "FFD-marginal log-probability evaluations/s",
                "value": 32 / t,
                "unit": "1/s",
                "points": 1000,
                "batch": 32,
                "lattice": "x".join(map(str, dims)),
                "sampled_dimension": 11,
                "dimension_if_sampled": 11 + 3 * k,
            }
        )
    return rows
