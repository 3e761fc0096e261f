"""The bending chain that places the pad (bayestouch.physics.pose): wire currents → hysteresis → bend → tip pose →
pad pose → contact with the object."""

import numpy as np
import pytest

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.physics import bending as bd
from bayestouch.physics import pose, sma
from bayestouch.scene.objects import SceneObject


@pytest.fixture(scope="module")
def wire():
    return sma.load_wire()


@pytest.fixture(scope="module")
def rod():
    return bd.load_rod()


@pytest.fixture(scope="module")
def loop(wire, rod):
    return pose.hysteresis_loop(wire, rod)


def test_unpowered_wires_leave_the_rod_straight(wire, rod):
    """No current: the three wires pull equally, the tip stays at (0, 0, L) on the base's axis."""
    path = pose.tip_path(wire, rod, np.zeros((50, 3)), 0.05)
    np.testing.assert_allclose(path.tip_position, np.tile([0.0, 0.0, rod.length], (50, 1)), atol=1e-9)
    np.testing.assert_allclose(path.martensite, 1.0)


def test_loop_is_a_hysteresis_loop(loop):
    """The swept wire's deflection rises on heating and falls on cooling, and at every current inside the
    transformation range the cooling branch lies above the heating one (the austenite persists until the wire is
    cooled below the forward transformation): a loop of positive area that a model without hysteresis (the same
    path both ways) would not have."""
    n = len(loop.current) // 2
    up, down = loop.deflection[:n], loop.deflection[n:][::-1]  # both at increasing current
    assert np.all(np.diff(up) > -1e-6) and np.all(np.diff(down) > -1e-6)
    span = up.max()
    assert span > 0.015  # ~19 mm: a 6 cm rod bent by one wire's full transformation
    gap = down - up
    assert gap.min() > -1e-4 * span
    area = np.trapezoid(gap, loop.current[:n])  # m·A
    assert area > 0.1 * span * (loop.current[n - 1] - loop.current[0])
    # where does each branch cross half the span: heating later (higher current) than cooling
    i_up = np.interp(0.5 * span, up, loop.current[:n])
    i_down = np.interp(0.5 * span, down, loop.current[:n])
    assert i_up - i_down > 0.01  # amperes


def test_heating_branch_follows_brinson_at_the_stress_the_bend_puts_on_the_wire(wire, rod):
    """At half transformation on heating the cosine kinetics give T = (A_s + A_f)/2 + σ/C_A (Brinson 1993, with
    A_s = 34.5 °C, A_f = 49 °C, C_A = 13.8 MPa/K of models/finger.toml), σ the stress the bend puts on the heated
    wire at that moment (~170 MPa here, not the 136 MPa of the straight rod): the chain feeds the bend's stress back
    into the kinetics. At the straight rod's stress the half-way temperature would be 2.4 K lower."""
    n = 2400
    cur = np.zeros((n, 3))
    cur[:, 0] = np.linspace(0.0, float(sma.max_steady_current(wire)), n)
    path = pose.tip_path(wire, rod, cur, 0.05)
    xi = path.martensite[:, 0]
    k = int(np.argmax(xi < 0.5))
    f = (0.5 - xi[k - 1]) / (xi[k] - xi[k - 1])
    T_half = path.wire_temperature[k - 1, 0] + f * (path.wire_temperature[k, 0] - path.wire_temperature[k - 1, 0])
    sigma = path.stress[k - 1, 0]  # the stress the step into frame k ran under
    expected = 0.5 * (wire.A_s + wire.A_f) + sigma / wire.C_A
    assert sigma > 150e6
    assert T_half == pytest.approx(expected, abs=1.0)
    straight = bd.curvature_equilibrium(rod, wire, jnp.full(3, wire.ambient), jnp.ones(3)).stress[0]
    assert abs(T_half - (0.5 * (wire.A_s + wire.A_f) + float(straight) / wire.C_A)) > 2.0


def test_pad_path_is_base_pose_times_tip_pose(wire, rod):
    """The pad centre is base position + base rotation · tip position, and its tangent the rotated tip tangent:
    checked against the tip path itself and, with no current, against the straight rod along the base's axis."""
    cur = np.zeros((40, 3))
    cur[:, 1] = 0.15
    th = 0.7
    R = np.array([[1, 0, 0], [0, np.cos(th), -np.sin(th)], [0, np.sin(th), np.cos(th)]])
    base = np.array([0.01, -0.02, 0.1])
    pp = pose.pad_path(wire, rod, cur, 0.05, base, R)
    np.testing.assert_allclose(pp.centre, base + pp.tip.tip_position @ R.T, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(pp.tangent, axis=1), 1.0, atol=1e-9)
    assert np.linalg.norm(pp.tip.tip_position[-1, :2]) > 1e-3  # it bent
    still = pose.pad_path(wire, rod, np.zeros((5, 3)), 0.05, base, R)
    np.testing.assert_allclose(still.centre, np.tile(base + R @ [0, 0, rod.length], (5, 1)), atol=1e-9)
    with pytest.raises(BadInput, match="base_rotation"):
        pose.pad_path(wire, rod, cur, 0.05, base, 2 * R)


def test_pad_contact_on_a_sphere_is_the_overlap():
    """A pad of radius R centred at distance d from a ball of radius r touches it at the ball's surface point
    towards the pad, with normal along that direction and depth R − (d − r) (negative: clear of the ball)."""
    r, R = 0.03, 0.007
    ball = SceneObject("ball", ne.NEllipsoid(jnp.zeros(3), jnp.full(3, r), jnp.zeros(3), jnp.asarray(2.0)))
    surf = ball.surface()
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(20, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    d = r + R + rng.uniform(-2e-3, 1e-3, 20)
    contact, normal, depth = pose.pad_contact(surf, d[:, None] * dirs, R)
    np.testing.assert_allclose(contact, r * dirs, atol=1e-7)
    np.testing.assert_allclose(normal, dirs, atol=1e-6)
    np.testing.assert_allclose(depth, R - (d - r), atol=1e-7)


@pytest.mark.parametrize(
    ("currents", "needle"),
    [
        (np.zeros((4, 2)), r"shape \(T, 3\)"),
        (np.full((4, 3), -0.01), r"within \[0,"),
        (np.full((4, 3), np.nan), "finite"),
        (np.full((4, 3), 1.0), r"within \[0,"),
    ],
)
def test_bad_current_programs_are_refused(wire, rod, currents, needle):
    with pytest.raises(BadInput, match=needle):
        pose.tip_path(wire, rod, currents, 0.05)


def test_strokes_through_the_chain_touch_where_the_bent_rod_puts_the_pad(wire, rod):
    """A base carried straight over a ball with the rod pointing down: with the wires cold the pad presses the
    designed 0.5 mm at the top and the taxels feel it; with one wire heated the same base path puts the pad
    millimetres away (the tip swings sideways and up) — the contact comes from the pose, not from a commanded point
    on the surface. Contacts lie on the ball either way, and a pad clear of it gets no force."""
    from bayestouch.backend import jax
    from bayestouch.physics import forward
    from bayestouch.physics.virtual import load_finger

    vf = load_finger()
    R_pad = float(vf.finger.tip_radius)
    r = 0.03
    surf = SceneObject("ball", ne.NEllipsoid(jnp.zeros(3), jnp.full(3, r), jnp.zeros(3), jnp.asarray(2.0))).surface()
    T = 60
    down = np.diag([1.0, -1.0, -1.0])  # rod along world −z
    base = np.column_stack([np.linspace(-0.02, 0.02, T), np.zeros(T), np.full(T, r + R_pad - 5e-4 + rod.length)])
    cold = pose.pad_path(wire, rod, np.zeros((T, 3)), 0.05, base, down)
    arrays = pose.chain_stroke_arrays(surf, cold, R_pad)
    contact, _, _, depth = (np.asarray(a) for a in arrays)
    mid = T // 2
    np.testing.assert_allclose(depth, R_pad - (np.linalg.norm(cold.centre, axis=1) - r), atol=1e-7)
    assert depth.max() == pytest.approx(5e-4, abs=5e-6)  # the designed overlap at the top (x = ±0.34 mm: −1.6 µm)
    np.testing.assert_allclose(np.linalg.norm(contact, axis=1), r, atol=1e-7)
    frames = forward.simulate(surf, arrays, vf.finger, jax.random.PRNGKey(0), noise=False)
    force = np.asarray(frames.force)
    assert force[mid] > 0.05 and np.all(force[depth < -1e-3] < 1e-6)

    heated = np.zeros((T, 3))
    heated[:, 0] = 0.15
    warm = pose.pad_path(wire, rod, heated, 0.05, base, down, T0=360.0, xi0=0.0)
    c2 = np.asarray(pose.chain_stroke_arrays(surf, warm, R_pad)[0])
    np.testing.assert_allclose(np.linalg.norm(c2, axis=1), r, atol=1e-7)
    assert np.median(np.linalg.norm(warm.centre - cold.centre, axis=1)) > 5e-3


@pytest.mark.parametrize(("kappa", "phi"), [(5.0, 0.0), (8.0, 1.0), (10.0, -1.0)])
def test_currents_for_a_bend_reach_it_from_cold(wire, rod, kappa, phi):
    """Round trip: the currents the inverse gives, held from cold through the dynamic chain, settle at the target
    curvature (within 1 %); one wire for a bend towards it, two for a bend between two wires."""
    target = kappa * np.array([np.cos(phi), np.sin(phi)])
    currents, _, reached = pose.currents_for_bend(wire, rod, target)
    assert np.linalg.norm(reached - target) < 0.02 * kappa
    path = pose.tip_path(wire, rod, np.tile(currents, (600, 1)), 0.05)  # 30 s: many thermal time constants
    np.testing.assert_allclose(path.curvature[-1], target, atol=0.01 * kappa)
    assert np.sum(currents > 0.05) == (1 if phi == 0.0 else 2)


def test_a_bend_beyond_reach_is_refused(wire, rod):
    with pytest.raises(BadInput, match=r"curvature: 30 1/m at 45° is beyond the finger's reach"):
        pose.currents_for_bend(wire, rod, 30.0 * np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)]))
    with pytest.raises(BadInput, match="curvature: expected two finite values"):
        pose.currents_for_bend(wire, rod, [np.nan, 1.0])


def test_spread_widened_scales_every_sd_and_half_width():
    sp = pose.FingerSpread()
    assert sp.widened(1.0).prestrain == pytest.approx(sp.prestrain)
    w = sp.widened(2.0)
    assert (w.EI_log_sd, w.shift_sd, w.ambient) == pytest.approx((0.4, 6.0, 6.0))
    assert w.prestrain == pytest.approx((0.03, 0.05))
    assert np.log(w.convection[1] / w.convection[0]) == pytest.approx(2 * np.log(1.25 / 0.8))
    with pytest.raises(BadInput, match="factor"):
        sp.widened(0.0)


def test_drawn_fingers_follow_their_spread(wire, rod):
    """2,000 drawn fingers: log EI has sd 0.2 and the transformation shift sd 3 K (each within 5 Monte Carlo sds,
    about 0.016 relative); a spread twice as wide doubles both (the control)."""
    g = np.random.default_rng(3)
    for factor in (1.0, 2.0):
        sp = pose.FingerSpread().widened(factor)
        f = [pose.draw_finger(g, wire, rod, sp) for _ in range(2000)]
        log_ei = np.log([r.EI / rod.EI for _, r in f])
        shift = np.array([w.A_s - wire.A_s for w, _ in f])
        assert np.std(log_ei) == pytest.approx(0.2 * factor, rel=0.08)
        assert np.std(shift) == pytest.approx(3.0 * factor, rel=0.08)
        assert all(w.M_f - wire.M_f == pytest.approx(w.A_s - wire.A_s) for w, _ in f[:20])


def test_pose_error_ensemble_is_each_drawn_finger_minus_the_nominal(wire, rod):
    """Every member is a drawn finger's tip minus the nominal tip, at the recorded frames, in world axes; the same
    seed draws the same fingers."""
    cur = np.zeros((60, 3))
    cur[10:, 0] = 0.15
    cur[30:, 1] = 0.12
    frames = np.array([20, 40, 59])
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    ens = pose.pose_error_ensemble(
        wire,
        rod,
        [cur, cur[:50]],
        0.05,
        [frames, frames[:2]],
        draws=2,
        seed=5,
        rotations=np.stack([np.eye(3), R]),
        progress=True,
    )
    assert ens.shape == (2, 5, 3)
    g = np.random.default_rng(5)
    nominal = pose.tip_path(wire, rod, cur, 0.05).tip_position
    for k in range(2):
        w, r = pose.draw_finger(g, wire, rod)
        tip = pose.tip_path(w, r, cur, 0.05).tip_position
        np.testing.assert_allclose(ens[k, :3], (tip - nominal)[frames], atol=1e-12)
        tip50 = pose.tip_path(w, r, cur[:50], 0.05).tip_position - pose.tip_path(wire, rod, cur[:50], 0.05).tip_position
        np.testing.assert_allclose(ens[k, 3:], tip50[frames[:2]] @ R.T, atol=1e-12)
    assert np.max(np.abs(ens)) > 1e-4  # the drawn fingers do miss the nominal tip
    with pytest.raises(BadInput, match="frames: expected integer frame indices"):
        pose.pose_error_ensemble(wire, rod, [cur], 0.05, [np.array([60])], draws=2)
    with pytest.raises(BadInput, match="draws"):
        pose.pose_error_ensemble(wire, rod, [cur], 0.05, [frames], draws=1)


def test_with_constants_sets_the_five_and_refuses_impossible_ones(wire, rod):
    """The identity values give the nominal constants back; each value lands on its constant; a factor ≤ 0, a
    pre-strain outside (0, 0.2), a NaN or a wrong count are refused in one line."""
    w, r = pose.with_constants(wire, rod, (1.0, wire.prestrain, 0.0, 1.0, 0.0))
    assert w == wire and r == rod
    w, r = pose.with_constants(wire, rod, (2.0, 0.041, -1.5, 0.5, 2.0))
    assert (
        r.EI == pytest.approx(2 * rod.EI)
        and w.prestrain == 0.041
        and w.convection == pytest.approx(0.5 * wire.convection)
    )
    assert (w.M_f, w.M_s, w.A_s, w.A_f) == pytest.approx(
        (wire.M_f - 1.5, wire.M_s - 1.5, wire.A_s - 1.5, wire.A_f - 1.5)
    )
    assert w.ambient == pytest.approx(wire.ambient + 2.0)
    for bad in ((0.0, 0.04, 0, 1, 0), (1.0, 0.3, 0, 1, 0), (1.0, 0.04, np.nan, 1, 0), (1.0, 0.04, 0, 1)):
        with pytest.raises(BadInput, match="values: expected the five"):
            pose.with_constants(wire, rod, bad)
