"""The texture indicator J(I) of eq. 3 against closed forms."""

import numpy as np
import pytest

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import nellipsoid_mesh
from bayestouch.geometry.texture import (
    indicator_energy,
    indicator_seeds,
    solve_indicator,
    texture_indicator,
)


def _flat_square(m=12, side=0.02):
    u, v = np.meshgrid(np.linspace(0, side, m + 1), np.linspace(0, side, m + 1), indexing="ij")
    verts = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1)
    idx = np.arange(verts.shape[0]).reshape(m + 1, m + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return verts, faces


@pytest.mark.parametrize("p,q", [(1.0, 2.0), (2.0, 1.0), (0.5, 3.0)])
def test_energy_exact_for_linear_field(p, q):
    verts, faces = _flat_square()
    g = np.array([30.0, -40.0, 0.0])  # |g| = 50 per metre
    w = np.full(len(faces), 0.7)
    J = float(indicator_energy(verts, faces, w, verts @ g, p, q))
    assert J == pytest.approx(0.7**p * 50.0**q * 0.02**2, rel=1e-12)


def test_energy_is_differentiable():
    verts, faces = _flat_square(6)
    w = np.linspace(0.5, 1.5, len(faces))
    I = np.sin(verts[:, 0] * 200.0)
    f = lambda I: indicator_energy(verts, faces, w, I, 1.0, 2.0)  # noqa: E731
    grad = np.asarray(jax.grad(f)(jnp.asarray(I)))
    e = np.zeros_like(I)
    e[20] = 1e-6
    fd = (float(f(I + e)) - float(f(I - e))) / 2e-6
    assert grad[20] == pytest.approx(fd, rel=1e-6)


def test_harmonic_indicator_between_latitude_caps():
    """q = 2, w = 1 on a sphere, I = 0 on the cap θ ≤ θ1 and 1 on θ ≥ θ2: J = 2π / ln(tan(θ2/2)/tan(θ1/2)),
    independent of the radius (conformal invariance)."""
    R = 0.03
    s = ne.NEllipsoid(jnp.zeros(3), jnp.full(3, R), jnp.zeros(3), jnp.array(2.0))
    verts, faces = nellipsoid_mesh(s, 40)
    theta = np.arccos(np.clip(verts[:, 2] / R, -1, 1))
    t1, t2 = 0.6, 2.2
    seeds = np.where(theta <= t1, 0, np.where(theta >= t2, 1, -1))
    w = np.ones(len(faces))
    I, _ = solve_indicator(verts, faces, w, seeds, 1.0, 2.0)
    J = float(indicator_energy(verts, faces, w, I, 1.0, 2.0))
    # the discrete caps are the vertex sets, slightly larger than the circles: compare with the
    # caps actually seeded
    t1_eff = theta[seeds == 0].max()
    t2_eff = theta[seeds == 1].min()
    exact = 2 * np.pi / np.log(np.tan(t2_eff / 2) / np.tan(t1_eff / 2))
    assert J == pytest.approx(exact, rel=0.03)
    # minimiser: any other field with the same seeds has higher energy
    I2 = I.copy()
    I2[seeds < 0] = np.clip(I2[seeds < 0] + 0.05 * np.sin(7 * verts[seeds < 0, 0] / R), 0, 1)
    assert float(indicator_energy(verts, faces, w, I2, 1.0, 2.0)) > J


def test_total_variation_limit_cuts_at_shortest_circle():
    """q = 1 (TV): the minimiser jumps on the shortest separating curve, J → its length 2πR sin θ."""
    R = 0.03
    s = ne.NEllipsoid(jnp.zeros(3), jnp.full(3, R), jnp.zeros(3), jnp.array(2.0))
    verts, faces = nellipsoid_mesh(s, 32)
    theta = np.arccos(np.clip(verts[:, 2] / R, -1, 1))
    seeds = np.where(theta <= 0.5, 0, np.where(theta >= 2.0, 1, -1))
    I, it = solve_indicator(verts, faces, np.ones(len(faces)), seeds, 1.0, 1.0, max_iter=200)
    J = float(indicator_energy(verts, faces, np.ones(len(faces)), I, 1.0, 1.0))
    shortest = 2 * np.pi * R * np.sin(theta[seeds == 0].max())
    assert it > 1
    assert shortest * 0.97 < J < shortest * 1.10
    # harmonic (q = 2) field measured with q = 1 is worse: TV really minimised something
    I2, _ = solve_indicator(verts, faces, np.ones(len(faces)), seeds, 1.0, 2.0)
    assert float(indicator_energy(verts, faces, np.ones(len(faces)), I2, 1.0, 1.0)) > J


def test_seeds_and_single_label():
    verts, faces = _flat_square(4)
    data = verts[[0, 5, 24]] + 1e-5
    res = np.array([0.0, 1e-3, 2e-3])
    seeds = indicator_seeds(verts, data, res, tol=1.5e-3)
    assert seeds[0] == 0 and seeds[5] == 0 and seeds[24] == 1 and (seeds >= 0).sum() == 3
    # off-surface wins on a shared vertex
    seeds = indicator_seeds(verts, verts[[3, 3]], np.array([0.0, 1.0]), tol=0.5)
    assert seeds[3] == 1
    # all points on the surface: I ≡ 0, J = 0
    out = texture_indicator(verts, faces, verts[:10], np.zeros(10), tol=1e-4)
    assert out.J == 0.0 and not out.I.any()


def test_better_fit_lowers_j(shape):
    """J shrinks when the residuals shrink (the J_fin / J0 ratio of Table 2), and is positive when some
    points are off the surface."""
    verts, faces = nellipsoid_mesh(shape, 24)
    rng = np.random.default_rng(3)
    data = verts[rng.choice(len(verts), 300, replace=False)]
    big = rng.normal(0, 1e-3, 300)
    J_big = texture_indicator(verts, faces, data, big, tol=1e-3).J
    J_small = texture_indicator(verts, faces, data, 0.1 * big, tol=1e-3).J
    assert J_big > 0 and J_small < J_big
