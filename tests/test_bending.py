"""Three-wire bending and constant-curvature pose (physics.md §2; Webster & Jones 2010)."""

import math
import re

import numpy as np
import pytest
from jax.test_util import check_grads

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS
from bayestouch.physics import bending as bd
from bayestouch.physics import sma

C0 = 273.15


@pytest.fixture(scope="module")
def rod():
    return bd.load_rod()


@pytest.fixture(scope="module")
def wire():
    return sma.load_wire()


def _pose_flat(rod):
    return jax.jit(lambda u: jnp.concatenate([a.ravel() for a in bd.tip_pose(rod, u)]))


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@jax.jit
def _tangent(rod, u, s):
    """dp/ds of the backbone at arc length s."""
    return jax.jacfwd(lambda si: bd.backbone(rod, u, si[None])[0])(s)


def test_shipped_rod_loads(rod, wire):
    assert (rod.length, rod.radius, rod.wire_radius, rod.EI) == (0.06, 0.005, 0.003, 7e-4)
    assert 3e-4 <= rod.EI <= 1.5e-3  # physics.md §2 adjustment
    assert rod.wire_area == pytest.approx(float(sma.wire_area(wire)), rel=1e-12)


@pytest.mark.parametrize(
    "pattern,repl,needle",
    [
        (r'^(EI = \{ value = 7e-4, unit = )"N m\^2"', r'\1"N mm^2"', 'EI: unit must be "N m^2"'),
        (r"^(wire_radius = \{ value = )0\.003", r"\g<1>0.006", "must be less than radius"),
        (r'^(theta0 = \{ value = 0\.0, unit = "rad"), source = "[^"]*"', r'\1, source = ""', "needs a source"),
    ],
)
def test_bad_rod_file_is_rejected(tmp_path, pattern, repl, needle):
    text = (MODELS / "finger.toml").read_text(encoding="utf-8")
    new, n = re.subn(pattern, repl, text, count=1, flags=re.M)
    assert n == 1
    f = tmp_path / "finger.toml"
    f.write_text(new, encoding="utf-8")
    with pytest.raises(BadInput) as e:
        bd.load_rod(f)
    assert needle in str(e.value) and "[rod]" in str(e.value)


# ---------------------------------------------------------------- pose


def test_straight_limit(rod):
    p, R = bd.tip_pose(rod, jnp.zeros(2))
    assert np.allclose(np.asarray(p), [0.0, 0.0, rod.length], atol=1e-15, rtol=0)
    assert np.allclose(np.asarray(R), np.eye(3), atol=1e-15, rtol=0)
    # tiny curvature: first-order tip deflection u L²/2, no loss of digits
    p, _ = bd.tip_pose(rod, jnp.array([1e-6, -2e-6]))
    assert np.allclose(np.asarray(p[:2]), [0.5e-6 * rod.length**2, -1e-6 * rod.length**2], rtol=1e-9, atol=0)


@pytest.mark.parametrize("phi", [0.0, 0.7, -2.0])
def test_quarter_circle(rod, phi):
    L = rod.length
    k = math.pi / (2 * L)
    p, R = bd.tip_pose(rod, jnp.array([k * math.cos(phi), k * math.sin(phi)]))
    a = 2 * L / math.pi
    assert np.allclose(np.asarray(p), [a * math.cos(phi), a * math.sin(phi), a], atol=1e-15)
    assert np.allclose(np.asarray(R), _rz(phi) @ _ry(math.pi / 2) @ _rz(-phi), atol=1e-14)


def test_rotation_is_the_arc_frame(rod):
    rng = np.random.default_rng(3)
    for u in rng.normal(scale=20.0, size=(4, 2)):
        u = jnp.asarray(u)
        p, R = bd.tip_pose(rod, u)
        R = np.asarray(R)
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-14) and np.linalg.det(R) == pytest.approx(1.0)
        tangent = _tangent(rod, u, jnp.asarray(rod.length))
        assert np.allclose(R[:, 2], np.asarray(tangent), atol=1e-12)
        kappa, phi = float(jnp.linalg.norm(u)), math.atan2(float(u[1]), float(u[0]))
        assert np.allclose(R, _rz(phi) @ _ry(kappa * rod.length) @ _rz(-phi), atol=1e-13)


def test_backbone_preserves_arc_length(rod):
    u = jnp.array([18.0, -9.0])  # ~70° bend
    s = jnp.linspace(0.0, rod.length, 2001)
    pts = np.asarray(bd.backbone(rod, u, s))
    assert np.allclose(pts[0], 0.0) and np.allclose(pts[-1], np.asarray(bd.tip_pose(rod, u)[0]), atol=1e-15)
    assert np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)) == pytest.approx(rod.length, rel=1e-7)
    speed = jax.vmap(_tangent, in_axes=(None, None, 0))(rod, u, s[::100])
    assert np.allclose(np.linalg.norm(np.asarray(speed), axis=1), 1.0, atol=1e-12)
    # constant curvature: every point lies on the circle of radius 1/κ about the centre (u/κ², 0)
    kappa = float(jnp.linalg.norm(u))
    centre = np.array([float(u[0]), float(u[1]), 0.0]) / kappa**2
    assert np.allclose(np.linalg.norm(pts - centre, axis=1), 1.0 / kappa, rtol=1e-12)


def test_pose_gradients(rod):
    f = _pose_flat(rod)
    for u in ([5.0, -3.0], [0.0, 0.0], [1e-7, 2e-7]):
        check_grads(f, (jnp.array(u),), order=1, modes=("fwd", "rev"), eps=1e-4)
    # curvature of the tip height at the straight pose: z = L sinc(κL) ≈ L − κ²L³/6
    H = jax.jit(jax.hessian(lambda u: bd.tip_pose(rod, u)[0][2]))(jnp.zeros(2))
    assert np.allclose(np.asarray(H), -(rod.length**3) / 3 * np.eye(2), rtol=1e-10)


# ---------------------------------------------------------------- curvature from forces


def test_symmetric_stresses_do_not_bend(rod):
    c = bd.curvature_from_stresses(rod, jnp.full(3, 150e6))
    assert float(c.kappa) < 1e-12 * rod.wire_radius * rod.wire_area * 150e6 / rod.EI + 1e-12


@pytest.mark.parametrize("i", [0, 1, 2])
def test_one_wire_bends_toward_itself(rod, i):
    sig = 172e6
    c = bd.curvature_from_stresses(rod, jnp.zeros(3).at[i].set(sig))
    assert float(c.kappa) == pytest.approx(rod.wire_radius * rod.wire_area * sig / rod.EI, rel=1e-12)
    theta = float(bd.wire_angles(rod)[i])
    assert math.remainder(float(c.phi) - theta, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
    # the wire on the inside of the bend shortens
    eps = np.asarray(bd.wire_strains(rod, 0.04, c.u))
    assert eps[i] < 0.04 and np.all(np.delete(eps, i) > 0.04)


def test_closed_form_matches_vector_sum(rod):
    s = np.array([210e6, 95e6, 160e6])
    c = bd.curvature_from_stresses(rod, jnp.asarray(s))
    k = rod.wire_radius * rod.wire_area / rod.EI * math.sqrt(np.sum(s**2) - s[0] * s[1] - s[1] * s[2] - s[2] * s[0])
    th = np.asarray(bd.wire_angles(rod))
    phi = math.atan2(np.sum(s * np.sin(th)), np.sum(s * np.cos(th)))
    assert float(c.kappa) == pytest.approx(k, rel=1e-12) and float(c.phi) == pytest.approx(phi, abs=1e-12)


# ---------------------------------------------------------------- equilibrium with Brinson wires


def test_equilibrium_cold_and_hot(rod, wire):
    cold = bd.curvature_equilibrium(rod, wire, jnp.full(3, wire.ambient))
    assert float(cold.kappa) < 1e-10
    # the cold pre-strained wires sit on the detwinning plateau
    assert np.all((np.asarray(cold.stress) > wire.sigma_s_cr) & (np.asarray(cold.stress) < wire.sigma_f_cr))
    hot = C0 + 90.0
    for i in range(3):
        T = jnp.full(3, wire.ambient).at[i].set(hot)
        eq = bd.curvature_equilibrium(rod, wire, T)
        theta = float(bd.wire_angles(rod)[i])
        assert math.remainder(float(eq.phi) - theta, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        angle = math.degrees(float(bd.bend_angle(rod, eq.u)))
        assert 20.0 < angle < 45.0  # physics.md §2: EI_eff chosen so full actuation gives 20–45°
        # moment balance and the wire law hold at the returned state
        assert np.abs(np.asarray(eq.residual)).max() < 1e-12
        assert np.allclose(np.asarray(eq.strain), np.asarray(bd.wire_strains(rod, wire.prestrain, eq.u)))
        assert np.allclose(np.asarray(sma.quasi_static_strain(wire, eq.stress, T)), np.asarray(eq.strain), rtol=1e-10)
        # the heated wire is austenite at its stress and pulls hardest
        sig = np.asarray(eq.stress)
        assert hot > wire.A_f + sig[i] / wire.C_A and sig[i] == sig.max()
        # within the stroke ceiling κ_max = ε_L / r (physics.md §2 limits)
        assert float(eq.kappa) < wire.eps_L / rod.wire_radius


def test_equilibrium_gradient_matches_finite_differences(rod, wire):
    T = jnp.array([C0 + 62.0, C0 + 30.0, wire.ambient])  # wire 1 mid-transformation

    def f(T):
        return bd.curvature_equilibrium(rod, wire, T).u

    J = np.asarray(jax.jacfwd(f)(T))
    h = 1e-3
    J_fd = np.stack(
        [(np.asarray(f(T.at[j].add(h))) - np.asarray(f(T.at[j].add(-h)))) / (2 * h) for j in range(3)], axis=1
    )
    assert np.allclose(J, J_fd, rtol=1e-5, atol=1e-8)
    assert J[0, 0] > 0.1  # heating wire 1 (at θ = 0) bends further toward +x


def test_given_martensite_fraction_replaces_the_heating_branch(rod, wire):
    # ξ from the time-domain simulation (which carries the hysteresis) is used as given: an austenitic wire 1
    # bends the finger even at 30 °C, where the major heating branch (below A_s) leaves it straight, and a
    # martensitic one at 90 °C does not
    T = jnp.array([C0 + 30.0, wire.ambient, wire.ambient])
    straight = bd.curvature_equilibrium(rod, wire, T)
    held = bd.curvature_equilibrium(rod, wire, T, xi=jnp.array([0.0, 1.0, 1.0]))
    cold_hot = bd.curvature_equilibrium(rod, wire, T.at[0].set(C0 + 90.0), xi=jnp.ones(3))
    assert math.degrees(float(bd.bend_angle(rod, straight.u))) < 1.0
    assert math.degrees(float(bd.bend_angle(rod, held.u))) > 20.0
    assert math.degrees(float(bd.bend_angle(rod, cold_hot.u))) < 2.0
