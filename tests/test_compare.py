"""Shape comparison (geometry.compare, .symmetry, .winding): canonical form, parameter distance, IoU, Chamfer,
winding numbers."""

import itertools
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bayestouch.backend import jnp
from bayestouch.geometry import compare as cmp
from bayestouch.geometry import mesh
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry import symmetry as sym
from bayestouch.geometry import winding as wn
from bayestouch.geometry.integrals import surface_integrals
from bayestouch.geometry.rotation import euler_from_matrix

# one Monte-Carlo size and one mesh resolution throughout, so that JAX compiles each function once
N_MC = 2**15
RES = 12


def make(axes, n, angles=(0.0, 0.0, 0.0), centre=(0.0, 0.0, 0.0)):
    return ne.NEllipsoid(
        jnp.array(centre, float), jnp.array(axes, float), jnp.array(angles, float), jnp.array(float(n))
    )


def F(s, pts):
    """Inside–outside function, compiled once per power-of-two batch size."""
    return ne.evaluate(ne.inside_outside, s, pts)


def with_rotation(s, axes, R):
    """The same centre and n, new semi-axes and rotation matrix (Euler angles via euler_from_matrix)."""
    return ne.NEllipsoid(s.centre, jnp.asarray(axes, float), euler_from_matrix(jnp.asarray(R)), s.n)


def aliases(s):
    """Parameter sets of the same surface: axis permutations (det fixed by a column flip), pair flips,
    and the Euler alias (ξ, ψ, ζ) → (−ξ, ψ + π, ζ + π)."""
    R, a = np.asarray(s.rotation), np.asarray(s.axes)
    out = []
    for perm in itertools.permutations(range(3)):
        Rp = R[:, list(perm)]
        if np.linalg.det(Rp) < 0:
            Rp = Rp * np.array([1.0, 1.0, -1.0])
        for flip in ([1, 1, 1], [-1, -1, 1], [-1, 1, -1], [1, -1, -1]):
            out.append(with_rotation(s, a[list(perm)], Rp * np.array(flip, float)))
    xi, psi, zeta = np.asarray(s.angles)
    out.append(s._replace(angles=jnp.array([-xi, psi + math.pi, zeta + math.pi])))
    return out


def sphere(r, centre=(0.0, 0.0, 0.0)):
    # a tilted frame: the sphere's bounding box is then the rotated box's, a looser one
    return make((r, r, r), 2.0, angles=(0.3, 0.2, 0.1), centre=centre)


# ---------------------------------------------------------------------------------------- canonical form


def test_canonicalize_is_rule_on_a_hand_example():
    s = make((0.01, 0.02, 0.03), 3.0)  # R = I
    c = sym.canonicalize(s)
    np.testing.assert_allclose(c.axes, [0.03, 0.02, 0.01])
    # columns: ±e_z → +e_z, ±e_y → +e_y, third = e_z × e_y = −e_x
    np.testing.assert_allclose(c.rotation, [[0, 0, -1], [0, 1, 0], [1, 0, 0]], atol=1e-15)


def test_aliases_canonicalise_to_one_vector_and_one_surface(shape, rng):
    pts = np.asarray(shape.centre) + 0.03 * rng.normal(size=(512, 3))
    f0 = np.asarray(F(shape, pts))
    al = aliases(shape)
    raw = np.array([np.asarray(ne.to_vector(s)) for s in al])
    assert np.ptp(raw, axis=0).max() > 1.0  # the aliases really do differ in their parameters
    ref = np.asarray(ne.to_vector(sym.canonicalize(shape)))
    for s in al:
        np.testing.assert_allclose(F(s, pts), f0, rtol=1e-9)  # the aliases are aliases
        c = sym.canonicalize(s)
        np.testing.assert_allclose(np.asarray(ne.to_vector(c)), ref, atol=1e-9)
        np.testing.assert_allclose(F(c, pts), f0, rtol=1e-9)
    assert np.all(np.diff(ref[3:6]) <= 0)  # a ≥ b ≥ c


def test_canonicalize_idempotent_proper_and_sign_rule(shape, rng):
    for _ in range(20):
        s = make(
            rng.uniform(0.01, 0.04, 3),
            rng.uniform(1.5, 5.0),
            angles=(rng.uniform(0, math.pi), rng.uniform(-3, 3), rng.uniform(-3, 3)),
        )
        c = sym.canonicalize(s)
        np.testing.assert_allclose(ne.to_vector(sym.canonicalize(c)), ne.to_vector(c), atol=1e-9)
        R = np.asarray(c.rotation)
        assert np.linalg.det(R) == pytest.approx(1.0)
        for j in (0, 1):
            assert R[np.argmax(np.abs(R[:, j])), j] > 0
        pts = rng.normal(size=(256, 3)) * 0.03
        np.testing.assert_allclose(F(c, pts), F(s, pts), rtol=1e-9)


def test_canonicalize_batch_matches_rows(shape, rng):
    rows = [np.asarray(ne.to_vector(s)) for s in aliases(shape)]
    for _ in range(10):
        rows.append(
            np.concatenate(
                [rng.normal(size=3) * 0.01, rng.uniform(0.01, 0.04, 3), rng.uniform(-4, 4, 3), [rng.uniform(1.5, 5.0)]]
            )
        )
    V = np.array(rows)
    out = sym.canonicalize_batch(V)
    assert isinstance(out, np.ndarray) and out.shape == V.shape
    for v, o in zip(V, out, strict=True):
        np.testing.assert_allclose(o, ne.to_vector(sym.canonicalize(ne.from_vector(v))), atol=1e-12)
    np.testing.assert_allclose(sym.canonicalize_batch(V[:12].reshape(3, 4, 10)), out[:12].reshape(3, 4, 10))
    np.testing.assert_allclose(out[:25], np.broadcast_to(out[0], (25, 10)), atol=1e-9)  # the aliases


def test_align_batch_gathers_every_alias_into_one_vector():
    """The 24 aliases of a shape (:func:`sym.aliases`), their angles shifted by whole turns and by the Euler twin
    (−ξ, ψ + π, ζ + π), aligned to one of them, are that one vector; each alias is the same surface (negative
    control: before alignment the rows spread by radians)."""
    v = np.array([0.01, -0.02, 0.03, 0.04, 0.025, 0.012, 0.9, 0.4, -1.1, 3.5])
    al = sym.aliases(v)
    pts = np.random.default_rng(0).normal(0, 0.03, (64, 3))
    f0 = np.asarray(F(ne.from_vector(v), pts))
    for row in al:
        np.testing.assert_allclose(np.asarray(F(ne.from_vector(row), pts)), f0, rtol=1e-9)
    rng = np.random.default_rng(1)
    shifted = al.copy()
    shifted[:, 6:9] += 2 * np.pi * rng.integers(-2, 3, (24, 3))
    twin = rng.random(24) < 0.5
    shifted[twin, 6], shifted[twin, 7], shifted[twin, 8] = (
        -shifted[twin, 6],
        shifted[twin, 7] + np.pi,
        shifted[twin, 8] + np.pi,
    )
    assert np.ptp(shifted[:, 3:9], axis=0).max() > 3.0
    ref = al[5]
    out = sym.align_batch(shifted, ref)
    np.testing.assert_allclose(out, np.broadcast_to(ref, out.shape), atol=1e-9)
    # a slightly perturbed cloud stays compact and near the reference, in its own alias
    cloud = np.repeat(v[None], 200, axis=0)
    cloud[:, 6:9] += rng.normal(0, 0.05, (200, 3))
    mixed = np.array([sym.aliases(c)[k] for c, k in zip(cloud, rng.integers(0, 24, 200), strict=True)])
    got = sym.align_batch(mixed, ref)
    assert np.abs(got[:, 6:9] - ref[6:9]).max() < 0.5
    assert np.allclose(got[:, 3:6], ref[3:6])


# ---------------------------------------------------------------------------------------- parameter distance


def test_param_distance_of_aliases_is_zero(shape):
    for s in aliases(shape):
        d = sym.param_distance(shape, s)
        assert max(d.values()) < 1e-9, d


def test_param_distance_components(shape):
    d = sym.param_distance(shape, shape._replace(centre=shape.centre + jnp.array([0.0, 1e-3, 0.0])))
    assert d["centre"] == pytest.approx(1e-3, rel=1e-9)
    assert d["axes"] < 1e-12 and d["rotation"] < 1e-7 and d["n"] == 0.0
    # a world rotation by 0.1 rad about an arbitrary axis, given in an aliased parameterisation
    k = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    Q = np.eye(3) + math.sin(0.1) * K + (1 - math.cos(0.1)) * K @ K
    R = np.asarray(shape.rotation)
    turned = with_rotation(shape, np.asarray(shape.axes)[[1, 0, 2]], Q @ R[:, [1, 0, 2]] * [1, 1, -1])
    d = sym.param_distance(shape, turned)
    assert d["rotation"] == pytest.approx(0.1, rel=1e-9)
    assert d["centre"] == 0.0 and d["axes"] < 1e-12
    d = sym.param_distance(shape, shape._replace(axes=shape.axes * 1.01, n=shape.n + 0.5))
    assert d["axes"] == pytest.approx(0.01 / 1.01, rel=1e-9) and d["n"] == pytest.approx(0.5)


def test_param_distance_equal_axes_permutation():
    # square cross-section (a = b, n = 4): a quarter turn about the c axis is a symmetry
    s = make((0.02, 0.02, 0.01), 4.0, angles=(0.4, 0.3, -0.2))
    R = np.asarray(s.rotation)
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    t = with_rotation(s, s.axes, R @ quarter)
    pts = np.random.default_rng(3).normal(size=(256, 3)) * 0.02
    np.testing.assert_allclose(F(t, pts), F(s, pts), rtol=1e-9)
    assert sym.param_distance(s, t)["rotation"] < 1e-7
    # with unequal axes the same turn is a real rotation of π/2
    u = make((0.03, 0.02, 0.01), 4.0, angles=(0.4, 0.3, -0.2))
    assert sym.param_distance(u, with_rotation(u, u.axes, R @ quarter))["rotation"] == pytest.approx(math.pi / 2)


# ---------------------------------------------------------------------------------------- IoU


def test_iou_of_a_shape_with_itself_and_its_alias_is_one(shape):
    assert cmp.iou(shape, shape, count=N_MC) == (1.0, 0.0)
    assert cmp.iou(shape, aliases(shape)[7], count=N_MC) == (1.0, 0.0)


def test_iou_concentric_and_offset_spheres():
    # seed 0: the estimates must lie within 4 standard errors of the exact values
    j, se = cmp.iou(sphere(0.02), sphere(0.03), count=4 * N_MC, seed=0)
    assert 0 < se < 0.01
    assert abs(j - (2 / 3) ** 3) < 4 * se
    # two spheres of radius r a distance d apart: lens volume π (4r + d)(2r − d)² / 12
    r, d = 0.02, 0.015
    lens = math.pi * (4 * r + d) * (2 * r - d) ** 2 / 12
    exact = lens / (2 * 4 / 3 * math.pi * r**3 - lens)
    j, se = cmp.iou(sphere(r), sphere(r, centre=(d, 0.0, 0.0)), count=4 * N_MC, seed=0)
    assert abs(j - exact) < 4 * se


def test_iou_of_disjoint_shapes_is_zero(shape):
    far = shape._replace(centre=shape.centre + jnp.array([0.07, 0.0, 0.0]))  # > 2 √(a² + b² + c²)
    assert cmp.iou(shape, far, count=N_MC) == (0.0, 0.0)


# ---------------------------------------------------------------------------------------- Chamfer


def test_chamfer_identical_and_translated_points(rng):
    p = rng.normal(size=(512, 3))
    assert cmp.chamfer(p, p) == 0.0
    assert cmp.chamfer(p, p[::-1]) == 0.0
    # each point's translate is within |t|, so every nearest-neighbour distance is at most |t|
    t = np.array([0.003, -0.004, 0.0])
    assert 0 < cmp.chamfer(p, p + t) <= 0.005
    # by hand: A = {0}, B = {1, 3} on a line: ½ (1 + (1 + 3) / 2) = 1.5
    assert cmp.chamfer([[0.0, 0, 0]], [[1.0, 0, 0], [3.0, 0, 0]]) == pytest.approx(1.5)


def test_chamfer_of_concentric_spheres():
    r1, r2, n = 0.02, 0.03, 4000
    gap = r2 - r1
    ch = cmp.chamfer_shapes(sphere(r1), sphere(r2), count=n, seed=0)
    # every inner point is at least `gap` from the outer sphere; sampling adds A / (2π n gap) per direction
    excess = (4 * math.pi * (r1**2 + r2**2) / 2) / (2 * math.pi * n * gap)
    assert gap - 1e-12 <= ch <= gap + 2 * excess
    assert 2 * excess < 0.01 * gap


# ---------------------------------------------------------------------------------------- winding numbers


def test_mesh_inside_sphere_away_from_the_surface(rng):
    r = 0.03
    v, f = mesh.nellipsoid_mesh(sphere(r, centre=(0.01, 0.0, -0.02)), RES)
    p = rng.uniform(-1.25 * r, 1.25 * r, size=(4000, 3))
    rad = np.linalg.norm(p, axis=1)
    p = p[np.abs(rad - r) > 0.02 * r] + [0.01, 0.0, -0.02]  # the inscribed mesh lies within 0.3 % of r
    truth = np.linalg.norm(p - [0.01, 0.0, -0.02], axis=1) < r
    assert 0.2 < truth.mean() < 0.8
    np.testing.assert_array_equal(wn.mesh_inside(v, f, p), truth)
    np.testing.assert_array_equal(wn.mesh_inside(v, f, p[:500], beta=None), truth[:500])
    w = wn.winding_number(v, f[:, ::-1], p)  # inward orientation: −1 inside
    np.testing.assert_allclose(w, -truth.astype(float), atol=0.02)


def test_fast_winding_number_matches_exact(shape, rng):
    v, f = mesh.nellipsoid_mesh(shape, RES)
    p = np.asarray(shape.centre) + rng.normal(size=(800, 3)) * 0.02
    exact = wn.winding_number(v, f, p, beta=None)
    np.testing.assert_allclose(exact, np.round(exact), atol=1e-9)  # closed mesh: integers
    np.testing.assert_allclose(wn.winding_number(v, f, p), exact, atol=0.02)
    np.testing.assert_allclose(wn.winding_number(v, f, p, beta=4.0), exact, atol=2e-3)
    # an open mesh (a hole of 200 triangles): fractional values, still matched
    fo = f[:-200]
    exact = wn.winding_number(v, fo, p, beta=None)
    assert np.abs(exact - np.round(exact)).max() > 0.1
    np.testing.assert_allclose(wn.winding_number(v, fo, p), exact, atol=0.02)


def test_iou_of_inscribed_mesh_is_its_volume_fraction(shape):
    # the mesh's vertices lie on the convex solid, so mesh ⊂ solid and IoU = V_mesh / V_solid
    v, f = mesh.nellipsoid_mesh(shape, RES)
    frac = surface_integrals(v, f).volume / float(ne.volume(shape))
    j, se = cmp.iou_mesh(v, f, shape, count=N_MC, seed=0)
    assert 1 - frac > 5 * se  # coarse enough for the deficit to be resolved
    assert abs(j - frac) < 4 * se


# ---------------------------------------------------------------------------------------- everything


def test_compare_shapes(shape):
    out = cmp.compare_shapes(shape, aliases(shape)[5], count=N_MC)
    assert max(abs(out[k]) for k in ("eps_v", "eps_a", "eps_i")) < 1e-3
    assert (out["iou"], out["iou_se"]) == (1.0, 0.0)
    assert max(out["param_distance"].values()) < 1e-9
    assert 0 < out["chamfer"] < 1e-3  # independent samples of one surface: about their spacing
    big = shape._replace(axes=shape.axes * 1.01)
    out = cmp.compare_shapes(big, shape, count=N_MC)
    assert out["eps_v"] == pytest.approx(1.01**3 - 1, rel=1e-3)
    assert out["eps_a"] == pytest.approx(1.01**2 - 1, rel=1e-3)
    assert out["iou"] == pytest.approx(1 / 1.01**3, abs=4 * out["iou_se"])
    v, f = mesh.nellipsoid_mesh(shape, RES)
    out = cmp.compare_shapes((v, f), shape, count=N_MC)
    assert "param_distance" not in out
    assert out["eps_v"] < 0 and out["iou"] < 1


# ---------------------------------------------------------------------------------------- exact surface distances

CHAMFER_N = 4000  # points per call of nellipsoid_distance here: the loop's CHAMFER_COUNT (one compiled batch size)


@pytest.mark.parametrize("n", [2.2, 12.0])
def test_nellipsoid_distance_is_never_beaten_by_a_dense_sample(rng, n):
    s = make((0.03, 0.02, 0.015), n, angles=(0.4, 0.3, -0.5), centre=(0.001, -0.002, 0.003))
    x = mesh.sample_surface(s, CHAMFER_N, rng) + 0.004 * rng.normal(size=(CHAMFER_N, 3))  # within a few mm, both sides
    d = cmp.nellipsoid_distance(s, x)
    # the nearest of M surface samples is an upper bound on the distance, too large by about their spacing
    m = 100_000
    dense = mesh.sample_surface(s, m, rng)
    bound = cKDTree(dense).query(x)[0]
    spacing = math.sqrt(float(mesh.triangle_areas(*mesh.nellipsoid_mesh(s, 48)).sum()) / m)
    # a foot point at least as close as every sample: the global minimum (for box-like shapes a rare point, ~1 in
    # 4000 at n = 12, stops at a stationary point near an edge, off by < 1e-4 of the axis)
    assert np.mean(d <= bound + 1e-9) >= 0.999
    assert np.max(d - bound) < 1e-4 * 0.03
    assert np.median(bound - d) < spacing
    # negative control: the first-order distance is not exact off the surface
    local = np.asarray(ne.to_local(s, jnp.asarray(x)))
    d1 = np.abs(np.asarray(ne.first_order_distance(s, jnp.asarray(local))[0]))
    assert np.max(np.abs(d1 - d)) > 1e-5


def test_mesh_distance_is_the_minimum_over_all_triangles(rng):
    v, f = mesh.nellipsoid_mesh(make((0.03, 0.02, 0.015), 4.0, angles=(0.4, 0.3, -0.5)), 8)
    x = np.concatenate([rng.normal(size=(200, 3)) * 0.02, rng.normal(size=(20, 3)) * 0.2])  # near and far
    tri = v[f]
    P = np.repeat(x, len(f), axis=0)
    T = np.tile(tri, (len(x), 1, 1))
    brute = np.linalg.norm(mesh._closest_on_triangles(P, T[:, 0], T[:, 1], T[:, 2]) - P, axis=1)
    brute = brute.reshape(len(x), len(f)).min(axis=1)
    np.testing.assert_allclose(cmp.mesh_distance(v, f, x, k=2), brute, rtol=0, atol=1e-15)


def test_chamfer_surfaces_of_a_shape_with_itself_is_zero():
    s = make((0.03, 0.022, 0.022), 2.2, angles=(0.4, 0.3, -0.5))
    axis = 0.0247
    ch, se = cmp.chamfer_surfaces(s, s, count=CHAMFER_N, seed=0)
    assert 0.0 <= ch < 1e-4 * axis
    v, f = mesh.nellipsoid_mesh(s, 24)
    assert cmp.chamfer_surfaces((v, f), (v, f), count=CHAMFER_N, seed=0)[0] < 1e-4 * axis
    # negative control: the point-cloud Chamfer distance has a floor of about half the sample spacing
    assert cmp.chamfer_shapes(s, s, count=CHAMFER_N, seed=0) > 0.01 * axis


def test_chamfer_surfaces_of_concentric_spheres_is_the_radius_difference():
    r1, r2 = 0.02, 0.023
    ch, se = cmp.chamfer_surfaces(sphere(r1), make((r2, r2, r2), 2.0, angles=(1.0, 2.0, 3.0)), count=CHAMFER_N)
    assert ch == pytest.approx(r2 - r1, rel=1e-9)  # every point is exactly r2 − r1 from the other sphere
    assert se < 1e-12


def test_chamfer_surfaces_of_shifted_spheres_matches_the_integral():
    r, t = 0.02, 0.002
    ch, se = cmp.chamfer_surfaces(sphere(r), sphere(r, centre=(0.0, t, 0.0)), count=CHAMFER_N, seed=1)
    # a point at polar cosine u (uniform on [−1, 1] by area) about the shift is | √(r² − 2rtu + t²) − r | away
    u = np.linspace(-1.0, 1.0, 200_001)
    exact = np.trapezoid(np.abs(np.sqrt(r * r - 2 * r * t * u + t * t) - r), u) / 2.0
    assert abs(ch - exact) < 4 * se  # 4 standard errors of the Monte-Carlo mean: a false alarm ~1e-4
    assert se < 0.05 * exact
    # negative control: the same metric does not mistake the shift for no change, or for the shift itself
    assert abs(ch - t) > 10 * se and ch > 20 * se
