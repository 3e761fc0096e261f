"""How far does a fitted surface reach beyond the contacts? A check that says when a contact-level posterior's shape
is the model family's extrapolation rather than the data's.

Contacts pin the surface only near themselves. Elsewhere the n-ellipsoid family decides where the surface goes:
from one side of an object the family extends the touched patch into a whole body, which is right when the object
belongs to the family and can be centimetres wrong when it does not (a tapered bottle fitted as a 20-cm ellipsoid
through its touched end). The posterior's intervals cannot say which: they are conditional on the family.
:func:`surface_reach` measures the part they rest on alone, as the largest distance from the surface to its
nearest contact over the contacts' span (their largest extent along their principal axes), at posterior draws.
For contacts on a spherical cap of half-angle α ≤ 90° and the sphere itself, that is cos(α/2) / sin α: 0.71 for a
hemisphere, 1.31 at 45°, 1.93 at 30°. Above :data:`REACH_LIMIT` the fit says so (``docs/contact_model.md``,
"Extrapolation").
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import cube_sphere
from bayestouch.inference import contact as cm

__all__ = ["REACH_LIMIT", "REACH_DRAWS", "REACH_RES", "contact_span", "surface_reach"]

#: a fit reports its shape as extrapolated when the posterior median of :func:`surface_reach` exceeds this: the
#: surface then runs farther from every contact than 1.5 times the contacts' own extent (a sphere touched within a
#: cap of half-angle 39° reaches 1.5). The true surfaces of the benchmark sets reach at most 1.12 (users'-like sets)
#: and 1.38 (non-superquadric objects; ``benchmarks/bench_reach.py``); how the warning splits the fits of
#: ``benchmarks/bench_objects.py``: ``docs/contact_model.md``, "Extrapolation"
REACH_LIMIT = 1.5
#: posterior draws the reach is computed at, and the cube-sphere resolution of the surface points at each
#: (6·16² + 2 = 1,538 directions, about 6° apart)
REACH_DRAWS = 64
REACH_RES = 16


def contact_span(points) -> float:
    """The extent (metres) of contacts ``points (M, 3)`` m: the largest range of their coordinates along their
    principal axes (0 for fewer than two distinct points)."""
    p = np.asarray(points, float)
    if len(p) < 2:
        return 0.0
    c = p - p.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    return float(np.max(np.ptp(c @ vt.T, axis=0)))


@jax.jit
def _surfaces(thetas, directions):
    """Surface points (K, P, 3) m of the n-ellipsoids θ (K, ≥ 10) in the directions (P, 3) of their own frames."""

    def one(t):
        s = cm.shape_of(t[:10])
        return ne.surface_point(s, ne.unit_nsphere(directions, s.n))

    return jax.vmap(one)(thetas)


def surface_reach(points, thetas, seed: int = 0) -> np.ndarray:
    """The reach of posterior draws beyond contacts ``points (M, 3)`` m: for each of at most :data:`REACH_DRAWS`
    draws of ``thetas (N, ≥ 10)`` (the sampled parametrisation of :func:`bayestouch.inference.contact.shape_of`),
    chosen with ``seed``, the largest distance from its surface to the nearest contact over
    :func:`contact_span` (dimensionless).

    Returns
    -------
    (K,) float
        One reach per draw used; empty when the contacts have no extent.
    """
    p = np.asarray(points, float)
    th = np.asarray(thetas, float).reshape(-1, np.shape(thetas)[-1])
    span = contact_span(p)
    if span <= 0 or len(th) == 0:
        return np.zeros(0)
    rng = np.random.default_rng([seed, 0x5EAC])
    pick = rng.choice(len(th), min(REACH_DRAWS, len(th)), replace=False)
    # a fixed number of rows (padded with the first draw): one compiled program whatever the chain's length
    rows = np.concatenate([th[pick], np.repeat(th[pick[:1]], REACH_DRAWS - len(pick), axis=0)])
    dirs, _ = cube_sphere(REACH_RES)
    surf = np.asarray(_surfaces(jnp.asarray(rows[:, :10]), jnp.asarray(dirs)))[: len(pick)]
    d, _ = cKDTree(p).query(surf.reshape(-1, 3))
    return d.reshape(len(pick), -1).max(axis=1) / span
