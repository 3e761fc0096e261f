"""n-ellipsoid (eq. 2, 4–6), meshes, area-uniform sampling and the surface integrals (eq. 11–13)."""

import math

import numpy as np
import pytest
from jax.test_util import check_grads
from scipy import stats
from scipy.special import ellipeinc, ellipkinc

from bayestouch.backend import jax, jnp
from bayestouch.geometry import mesh
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.integrals import relative_errors, surface_integrals
from bayestouch.geometry.rotation import euler_from_matrix, rot_x, rot_z, rotation_matrix


def make(axes, n, angles=(0.0, 0.0, 0.0), centre=(0.0, 0.0, 0.0)):
    return ne.NEllipsoid(
        jnp.array(centre, float), jnp.array(axes, float), jnp.array(angles, float), jnp.array(float(n))
    )


def ellipsoid_area(a, b, c):
    """Exact area of an ellipsoid a ≥ b ≥ c via incomplete elliptic integrals (Legendre)."""
    a, b, c = sorted((a, b, c), reverse=True)
    if a == c:
        return 4 * math.pi * a**2
    phi = math.acos(c / a)
    m = a**2 * (b**2 - c**2) / (b**2 * (a**2 - c**2))
    s = math.sin(phi)
    return 2 * math.pi * c**2 + 2 * math.pi * a * b / s * (ellipeinc(phi, m) * s**2 + ellipkinc(phi, m) * (1 - s**2))


# ---------------------------------------------------------------- rotations (eq. 2)


def test_rotation_is_eq2_product():
    xi, psi, zeta = 0.4, -1.2, 2.5
    R = np.asarray(rotation_matrix(jnp.array([xi, psi, zeta])))
    c, s = math.cos, math.sin
    Rz = lambda t: np.array([[c(t), -s(t), 0], [s(t), c(t), 0], [0, 0, 1]])  # noqa: E731
    Rx = lambda t: np.array([[1, 0, 0], [0, c(t), -s(t)], [0, s(t), c(t)]])  # noqa: E731
    np.testing.assert_allclose(R, Rz(zeta) @ Rx(xi) @ Rz(psi), atol=1e-15)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(rot_z(jnp.array(0.3)) @ rot_x(jnp.array(0.0)), Rz(0.3), atol=1e-15)


def test_euler_round_trip_and_poles(rng):
    for _ in range(50):
        ang = np.array([rng.uniform(0.01, math.pi - 0.01), rng.uniform(-3.1, 3.1), rng.uniform(-3.1, 3.1)])
        np.testing.assert_allclose(euler_from_matrix(rotation_matrix(jnp.array(ang))), ang, atol=1e-9)
    for xi in (0.0, math.pi):  # gimbal poles: only the matrix is defined, and it must round-trip
        R = rotation_matrix(jnp.array([xi, 0.7, -0.2]))
        np.testing.assert_allclose(rotation_matrix(euler_from_matrix(R)), R, atol=1e-12)


# ---------------------------------------------------------------- implicit surface


def test_surface_points_satisfy_eq4(shape, rng):
    Y = ne.unit_nsphere(jnp.asarray(rng.normal(size=(200, 3))), shape.n)
    np.testing.assert_allclose(jnp.sum(jnp.abs(Y) ** shape.n, axis=1), 1.0, rtol=1e-12)
    x = ne.surface_point(shape, Y)
    np.testing.assert_allclose(ne.inside_outside(shape, x), 1.0, rtol=1e-12)
    np.testing.assert_allclose(ne.radial_distance(shape, x), 0.0, atol=1e-15)


def test_radial_distance_exact_for_sphere(rng):
    s = make((0.02, 0.02, 0.02), 2.0, centre=(0.1, -0.2, 0.3))
    p = np.asarray(s.centre) + rng.normal(0, 0.03, (100, 3))
    np.testing.assert_allclose(
        ne.radial_distance(s, p), np.linalg.norm(p - np.asarray(s.centre), axis=1) - 0.02, atol=1e-15
    )


def test_inside_outside_sign(shape):
    c = np.asarray(shape.centre)
    assert ne.inside_outside(shape, jnp.asarray(c + 1e-4)) < 1
    assert ne.inside_outside(shape, jnp.asarray(c + 0.1)) > 1
    assert ne.radial_distance(shape, jnp.asarray(c + 0.1)) > 0


def test_normals_are_gradient_direction(shape, rng):
    x = mesh.sample_surface(shape, 50, seed=rng)
    g = jax.vmap(jax.grad(lambda p: ne.inside_outside(shape, p)))(jnp.asarray(x))
    g = g / jnp.linalg.norm(g, axis=1, keepdims=True)
    np.testing.assert_allclose(ne.normals(shape, x), g, atol=1e-10)
    # outward: the normal points away from the centre
    assert np.all(np.einsum("ij,ij->i", np.asarray(ne.normals(shape, x)), x - np.asarray(shape.centre)) > 0)


def test_gradients_wrt_parameters(shape, rng):
    p = jnp.asarray(mesh.sample_surface(shape, 20, seed=rng) * 1.05)
    check_grads(
        lambda v: ne.radial_distance(ne.from_vector(v), p),
        (ne.to_vector(shape),),
        order=1,
        modes=("fwd", "rev"),
        eps=1e-6,
        atol=1e-6,
        rtol=1e-5,
    )


def test_vmap_over_parameter_sets(shape, rng):
    V = jnp.asarray(np.asarray(ne.to_vector(shape)) * (1 + 0.05 * rng.normal(size=(8, 10))))
    p = jnp.asarray(rng.normal(0, 0.03, (30, 3)))
    batched = jax.jit(jax.vmap(lambda v: ne.inside_outside(ne.from_vector(v), p)))(V)
    for i in range(8):
        np.testing.assert_allclose(batched[i], ne.inside_outside(ne.from_vector(V[i]), p), rtol=1e-13)


# ---------------------------------------------------------------- closed forms


@pytest.mark.parametrize("n", [1.0, 2.0, 3.5, 10.0])
def test_closed_form_volume(n):
    s = make((0.03, 0.02, 0.01), n)
    expected = 8 * 0.03 * 0.02 * 0.01 * math.gamma(1 + 1 / n) ** 3 / math.gamma(1 + 3 / n)
    assert float(ne.volume(s)) == pytest.approx(expected, rel=1e-13)
    if n == 1.0:  # octahedron
        assert float(ne.volume(s)) == pytest.approx(4 / 3 * 0.03 * 0.02 * 0.01, rel=1e-13)
    if n == 2.0:
        assert float(ne.volume(s)) == pytest.approx(4 / 3 * math.pi * 0.03 * 0.02 * 0.01, rel=1e-13)


def test_box_limit():
    # n → ∞: the volume tends to 8abc and the mesh area to 8(ab + bc + ca)
    a, b, c = 0.03, 0.02, 0.01
    vols = [float(ne.volume(make((a, b, c), n))) / (8 * a * b * c) for n in (10, 40, 400)]
    assert vols[0] < vols[1] < vols[2] < 1 and vols[2] == pytest.approx(1.0, rel=5e-3)
    si = surface_integrals(*mesh.nellipsoid_mesh(make((a, b, c), 200.0), 48))
    assert si.area == pytest.approx(8 * (a * b + b * c + c * a), rel=1e-2)
    assert si.volume == pytest.approx(8 * a * b * c, rel=1e-2)


def test_second_moment_of_ellipsoid():
    a, b, c = 0.03, 0.02, 0.01
    S = np.asarray(ne.second_moment(make((a, b, c), 2.0)))
    V = 4 / 3 * math.pi * a * b * c
    np.testing.assert_allclose(S, np.diag([V * a**2 / 5, V * b**2 / 5, V * c**2 / 5]), rtol=1e-13, atol=1e-30)


# ---------------------------------------------------------------- meshes and eq. 11–13


def test_mesh_is_watertight_and_outward(shape):
    v, f = mesh.nellipsoid_mesh(shape, 12)
    tm = mesh.to_trimesh(v, f)
    assert tm.is_watertight and tm.is_winding_consistent and tm.volume > 0
    assert len(v) == 6 * 12**2 + 2 and len(f) == 12 * 12**2


@pytest.mark.parametrize("n", [1.5, 2.0, 4.0, 10.0])
def test_mesh_integrals_match_closed_forms(shape, n):
    s = shape._replace(n=jnp.array(n))
    truth = surface_integrals(*mesh.nellipsoid_mesh(s, 64))
    exact_v, exact_i = float(ne.volume(s)), np.asarray(ne.second_moment(s))
    # observed discretisation error at res 64 is ≈ 3e-4 for these n (second order, see next test)
    assert truth.volume == pytest.approx(exact_v, rel=1e-3)
    assert np.linalg.norm(truth.inertia - exact_i) / np.linalg.norm(exact_i) < 1e-3


def test_mesh_integrals_converge_at_second_order(shape):
    errs = []
    for res in (8, 16, 32):
        si = surface_integrals(*mesh.nellipsoid_mesh(shape._replace(n=jnp.array(2.0)), res))
        errs.append(abs(si.volume / float(ne.volume(shape._replace(n=jnp.array(2.0)))) - 1))
    assert 3.5 < errs[0] / errs[1] < 4.5 and 3.5 < errs[1] / errs[2] < 4.5


def test_area_of_sphere_and_ellipsoid():
    for axes in ((0.02, 0.02, 0.02), (0.03, 0.02, 0.01)):
        si = surface_integrals(*mesh.nellipsoid_mesh(make(axes, 2.0, angles=(0.3, 0.2, 0.1)), 64))
        assert si.area == pytest.approx(ellipsoid_area(*axes), rel=5e-4)
    assert ellipsoid_area(0.02, 0.02 - 1e-12, 0.02 - 2e-12) == pytest.approx(4 * math.pi * 0.02**2, rel=1e-8)


def test_integrals_match_trimesh(shape):
    v, f = mesh.nellipsoid_mesh(shape, 24)
    si = surface_integrals(v, f)
    tm = mesh.to_trimesh(v, f)
    assert si.volume == pytest.approx(tm.volume, rel=1e-12)
    assert si.area == pytest.approx(tm.area, rel=1e-12)
    # trimesh gives J = ∫ (r² I − r rᵀ) dV about the centre of mass; eq. 13 is S = ∫ y yᵀ dV about 0
    J, com = tm.moment_inertia, tm.center_mass
    S = np.trace(J) / 2 * np.eye(3) - J + tm.volume * np.outer(com, com)
    np.testing.assert_allclose(si.inertia, S, rtol=1e-10, atol=1e-20)


def test_relative_errors_zero_for_identical_and_signed():
    si = surface_integrals(*mesh.nellipsoid_mesh(make((0.02, 0.02, 0.02), 2.0), 16))
    assert relative_errors(si, si) == {"eps_v": 0.0, "eps_a": 0.0, "eps_i": 0.0}
    big = surface_integrals(*mesh.nellipsoid_mesh(make((0.021, 0.021, 0.021), 2.0), 16))
    e = relative_errors(big, si)
    assert e["eps_v"] == pytest.approx(1.05**3 - 1, rel=1e-9) and e["eps_a"] == pytest.approx(1.05**2 - 1, rel=1e-9)
    assert e["eps_i"] == pytest.approx(1.05**5 - 1, rel=1e-9)


# ---------------------------------------------------------------- sampling uniform by area


def test_sphere_samples_uniform_by_area():
    # Archimedes: for area-uniform points on a sphere, z is uniform on [−r, r]
    s = make((0.02, 0.02, 0.02), 2.0)
    z = mesh.sample_surface(s, 4000, seed=7)[:, 2] / 0.02
    assert stats.kstest(z, "uniform", args=(-1, 2)).pvalue > 0.01
    # negative control: points uniform over the cube-sphere parameters are not area-uniform
    d, _ = mesh.cube_sphere(64)
    rng = np.random.default_rng(7)
    q = d[rng.choice(len(d), 4000)]
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    cube = rng.uniform(-1, 1, (4000, 3))
    cube[np.arange(4000), rng.integers(0, 3, 4000)] = rng.choice([-1.0, 1.0], 4000)
    zc = (cube / np.linalg.norm(cube, axis=1, keepdims=True))[:, 2]
    assert stats.kstest(zc, "uniform", args=(-1, 2)).pvalue < 1e-6


def test_ellipsoid_samples_follow_area(rng):
    # the fraction of samples in a region equals that region's share of the area (within 4 binomial SEs)
    s = make((0.04, 0.015, 0.01), 2.0)
    N = 20000
    x = mesh.sample_surface(s, N, seed=rng)
    frac = np.mean(x[:, 0] > 0.02)
    v, f = mesh.nellipsoid_mesh(s, 96)
    area = mesh.triangle_areas(v, f)
    share = area[v[f].mean(axis=1)[:, 0] > 0.02].sum() / area.sum()
    assert abs(frac - share) < 4 * math.sqrt(share * (1 - share) / N)
    # and it is not the parameter-uniform share (the ends are under-weighted by area)
    assert abs(
        np.mean(np.abs(np.asarray(ne.unit_nsphere(jnp.asarray(rng.normal(size=(N, 3))), 2.0))[:, 0]) > 0.5) - share
    ) > 10 * math.sqrt(share * (1 - share) / N)


def test_sampling_is_seeded(shape):
    np.testing.assert_array_equal(mesh.sample_surface(shape, 10, seed=3), mesh.sample_surface(shape, 10, seed=3))
    assert not np.array_equal(mesh.sample_surface(shape, 10, seed=3), mesh.sample_surface(shape, 10, seed=4))


def test_closest_points_on_mesh(rng):
    s = make((0.02, 0.02, 0.02), 2.0)
    v, f = mesh.nellipsoid_mesh(s, 32)
    p = rng.normal(size=(300, 3))
    p = 0.02 * p / np.linalg.norm(p, axis=1, keepdims=True) * rng.uniform(0.5, 1.5, (300, 1))
    cp, d, fi = mesh.closest_points(v, f, p)
    # the inscribed polyhedron sags at most ≈ r·(π/64)²/2 ≈ 1e-3 r below the sphere at res 32
    np.testing.assert_allclose(d, np.abs(np.linalg.norm(p, axis=1) - 0.02), atol=1e-3 * 0.02)
    np.testing.assert_allclose(np.linalg.norm(cp - p, axis=1), d, rtol=1e-12)
    # brute force over all triangles for a few points
    tri = v[f]
    for i in range(5):
        q = mesh._closest_on_triangles(np.repeat(p[i : i + 1], len(f), 0), tri[:, 0], tri[:, 1], tri[:, 2])
        assert d[i] == pytest.approx(np.linalg.norm(q - p[i], axis=1).min(), rel=1e-12)


def test_closest_points_on_degenerate_triangles(rng):
    """A mesh from booleans holds triangles with two equal corners (a zero-length edge) or three collinear ones:
    their closest points are points of the segment they collapse to, never NaN (were NaN: 0/0 in an edge test)."""
    a = np.array([0.0, 0.0, 0.0])
    c = np.array([1.0, 0.0, 0.0])
    p = rng.normal(size=(200, 3))
    for tri in ((a, a, c), (a, c, c), (a, 0.5 * (a + c), c), (c, a, a)):
        q = mesh.closest_points(np.array(tri), np.array([[0, 1, 2]]), p)[0]
        seg = np.clip(p[:, 0], 0.0, 1.0)[:, None] * c  # closest point of the segment a–c
        np.testing.assert_allclose(q, seg, atol=1e-12)
