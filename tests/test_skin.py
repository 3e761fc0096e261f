"""Auxetic skin: closed forms (Hertz, bonded layer, Winkler sphere), pressure map and blur, Hunt–Crossley
against the paper's eq. 19, friction (eq. 20 with a Coulomb cap), gradients and the parameter file."""

import math

import numpy as np
import pytest
from jax.test_util import check_grads

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.params import MODELS
from bayestouch.physics import skin as S


@pytest.fixture(scope="module")
def params():
    return S.load_skin()


@pytest.fixture(scope="module")
def linear(params):
    return params._replace(k_d=0.0)


def grid(half, pitch):
    xs = np.arange(-half, half + pitch / 2, pitch)
    X, Y = np.meshgrid(xs, xs)
    return xs, X, Y


# ---------------------------------------------------------------- parameter file


def test_shipped_file_loads(params):
    assert isinstance(params, S.SkinParams)
    assert params.E == 100e3 and params.nu == -0.185 and params.h == 2e-3 and params.s == 1e-6
    assert params.rho == 118.0  # the paper's 0.118 g/cm³
    text = (MODELS / "skin.toml").read_text(encoding="utf-8")
    assert text.count("source =") == len(S.SKIN_SPECS)


def test_wrong_unit_is_bad_input(tmp_path):
    text = (MODELS / "skin.toml").read_text(encoding="utf-8")
    bad = text.replace('h = { value = 2e-3, unit = "m"', 'h = { value = 2, unit = "mm"')
    assert bad != text
    f = tmp_path / "skin.toml"
    f.write_text(bad, encoding="utf-8")
    with pytest.raises(BadInput) as e:
        S.load_skin(f)
    assert "[skin] h" in str(e.value) and 'unit must be "m"' in str(e.value) and "\n" not in str(e.value)


def test_out_of_range_poisson_is_bad_input(tmp_path):
    text = (MODELS / "skin.toml").read_text(encoding="utf-8")
    f = tmp_path / "skin.toml"
    f.write_text(text.replace("value = -0.185", "value = 0.5"), encoding="utf-8")
    with pytest.raises(BadInput, match="nu"):
        S.load_skin(f)


# ---------------------------------------------------------------- penetration


def test_penetration_is_smooth_relu():
    s = 1e-6
    phi = jnp.array([-1e-3, -1e-4, 0.0, 1e-4])
    d = np.asarray(S.penetration(phi, s))
    np.testing.assert_allclose(d[:2], [1e-3, 1e-4], rtol=1e-12)  # deep inside: δ = −φ
    assert d[2] == pytest.approx(s * math.log(2.0), rel=1e-12)
    assert 0.0 < d[3] < 1e-40  # far outside: ~ s·e^(−100)


def test_penetration_gradients():
    phi = jnp.array([-3e-6, -1e-6, 0.0, 0.5e-6, 2e-6])
    # checked in micrometres (finite differences need O(1) inputs); same function, rescaled
    check_grads(lambda z: S.penetration(z * 1e-6, 1e-6) / 1e-6, (phi / 1e-6,), order=2, modes=("fwd", "rev"))
    g = jax.grad(lambda f: jnp.sum(S.penetration(f, 1e-6)))(phi)
    assert np.all(np.asarray(g) < 0) and float(g[2]) == pytest.approx(-0.5)


# ---------------------------------------------------------------- closed forms


def test_hertz_hand_case():
    # E* = 0.75 MPa / (1 − 0.25) = 1 MPa; a³ = 3·1 N·(4/3 mm)/(4·1 MPa) = 1e-9 m³ → a = 1 mm;
    # p0 = 3·1 N / (2π·1 mm²) = 1.5/π MPa.
    a, p0 = S.hertz(1.0, 4e-3 / 3, 0.75e6, 0.5)
    assert float(a) == pytest.approx(1e-3, rel=1e-12)
    assert float(p0) == pytest.approx(1.5e6 / math.pi, rel=1e-12)
    a8, _ = S.hertz(8.0, 4e-3 / 3, 0.75e6, 0.5)
    assert float(a8) == pytest.approx(2e-3, rel=1e-12)  # a ∝ F^(1/3)


def test_bonded_layer_and_tangential_ratio():
    # physics.md §3: M/E = 1.061 (ν = −0.185), 1.35 (ν = 0.3); k_t/k_n = 0.58 vs 0.29
    assert float(S.bonded_layer_modulus(1.0, -0.185)) == pytest.approx(1.185 / (0.815 * 1.37), rel=1e-12)
    assert float(S.bonded_layer_modulus(1.0, -0.185)) == pytest.approx(1.061, abs=5e-4)
    assert float(S.bonded_layer_modulus(1.0, 0.3)) == pytest.approx(0.7 / (1.3 * 0.4), rel=1e-12)
    assert float(S.tangential_stiffness_ratio(-0.185)) == pytest.approx(0.578, abs=5e-4)
    assert float(S.tangential_stiffness_ratio(0.3)) == pytest.approx(0.286, abs=5e-4)
    for nu in (-0.5, -0.185, 0.0, 0.3):
        ratio = S.shear_modulus(1.0, nu) / S.bonded_layer_modulus(1.0, nu)
        assert float(S.tangential_stiffness_ratio(nu)) == pytest.approx(float(ratio), rel=1e-12)


def test_winkler_sphere(params):
    R = 6.5e-3
    F1, a1 = S.winkler_sphere(1e-4, R, params)
    F2, a2 = S.winkler_sphere(2e-4, R, params)
    assert float(F2 / F1) == pytest.approx(4.0, rel=1e-12)  # F ∝ δ²
    assert float(a1) == pytest.approx(math.sqrt(2 * R * 1e-4), rel=1e-12)
    assert float(a2) == pytest.approx(math.sqrt(2 * R * 2e-4), rel=1e-12)
    # physics.md §3 "our case": E = 100 kPa, h = 2 mm, R = 6.5 mm, F = 0.09 N → δ0 ≈ 0.28 mm, a ≈ 2 mm
    M = 100e3 * 1.185 / (0.815 * 1.37)
    d0 = math.sqrt(0.09 * 2e-3 / (math.pi * M * R))
    F, a = S.winkler_sphere(d0, R, params)
    assert float(F) == pytest.approx(0.09, rel=1e-12)
    assert d0 == pytest.approx(0.288e-3, rel=2e-3) and float(a) == pytest.approx(1.936e-3, rel=1e-3)
    assert M * d0 / 2e-3 == pytest.approx(15.3e3, rel=2e-3)  # p_max, Pa


# ---------------------------------------------------------------- foam law and blur


def test_foam_stress(params, linear):
    M = float(S.bonded_layer_modulus(params.E, params.nu))
    eps = jnp.array([0.0, 0.05, 0.2, 0.5])
    np.testing.assert_allclose(np.asarray(S.foam_stress(linear, eps)), M * np.asarray(eps), rtol=1e-12)
    half = params.eps_d / 2  # (1 − ε/ε_D)^(−1) = 2 at ε = ε_D/2 with k_d = 1
    assert float(S.foam_stress(params, half)) == pytest.approx(2 * M * half, rel=1e-12)
    # C¹ across the cap at 0.9 ε_D and finite (still increasing) beyond ε_D
    ec = 0.9 * params.eps_d
    ds = jax.grad(lambda e: S.foam_stress(params, e))
    assert float(ds(ec - 1e-9)) == pytest.approx(float(ds(ec + 1e-9)), rel=1e-6)
    beyond = np.asarray(S.foam_stress(params, jnp.array([params.eps_d, 1.2 * params.eps_d])))
    assert np.all(np.isfinite(beyond)) and beyond[1] > beyond[0]


def test_blur_conserves_force(params):
    pitch = 0.5e-3  # w = 1.41 mm = 2.8 taxels; the load sits ≥ 8.8 w from every edge
    rng = np.random.default_rng(3)
    p = np.zeros((60, 64))
    p[25:35, 27:37] = rng.uniform(0.0, 2e4, (10, 10))
    out = S.gaussian_blur(p, S.blur_width(params), pitch)
    assert float(jnp.sum(out)) == pytest.approx(p.sum(), rel=1e-10)
    assert float(out.max()) < 0.5 * p.max()  # it does spread


def test_point_load_spreads_with_variance_w2(params):
    w = float(S.blur_width(params))
    assert w == pytest.approx(math.hypot(1e-3, 1e-3), rel=1e-12)  # √((h/2)² + ℓ_b²)
    pitch = 1e-4
    xs, X, Y = grid(8e-3, pitch)
    p = np.zeros(X.shape)
    c = len(xs) // 2
    p[c, c] = 1.0
    out = np.asarray(S.gaussian_blur(p, w, pitch))
    m = out / out.sum()
    assert out.sum() == pytest.approx(1.0, rel=1e-6)
    assert (m * X**2).sum() == pytest.approx(w**2, rel=1e-4)
    assert (m * Y**2).sum() == pytest.approx(w**2, rel=1e-4)
    assert abs((m * X * Y).sum()) < 1e-12 * w**2
    # radially symmetric Gaussian: the value at distance w from the centre is e^(−1/2) of the peak
    k = round(w / pitch)
    assert out[c, c + k] / out[c, c] == pytest.approx(math.exp(-0.5 * (k * pitch / w) ** 2), rel=1e-9)


def test_pressure_map_integrates_to_winkler_force(linear):
    R, d0, pitch = 6.5e-3, 0.288e-3, 1e-4
    xs, X, Y = grid(8e-3, pitch)
    F_w = float(S.winkler_sphere(d0, R, linear)[0])
    parabolic = np.clip(d0 - (X**2 + Y**2) / (2 * R), 0.0, None)
    F_par = float(S.total_force(S.pressure_map(linear, parabolic, pitch), pitch))
    assert F_par == pytest.approx(F_w, rel=2e-3)
    # the chain: sphere SDF → smooth penetration → pressure; the SDF is the normal (not vertical) gap
    sdf = np.sqrt(X**2 + Y**2 + (R - d0) ** 2) - R
    p = S.pressure_map(linear, S.penetration(sdf, linear.s), pitch)
    assert float(S.total_force(p, pitch)) == pytest.approx(F_w, rel=0.04)
    # blurred peak lies below the local Winkler peak Mδ0/h, by a large factor at w ≈ 0.7 a
    M = float(S.bonded_layer_modulus(linear.E, linear.nu))
    assert float(p.max()) < 0.5 * M * d0 / linear.h


def test_densification_stiffens_contact(params, linear):
    R, d0, pitch = 6.5e-3, 0.288e-3, 2e-4
    xs, X, Y = grid(8e-3, pitch)
    delta = np.clip(d0 - (X**2 + Y**2) / (2 * R), 0.0, None)
    F_lin = float(S.total_force(S.pressure_map(linear, delta, pitch), pitch))
    F_den = float(S.total_force(S.pressure_map(params, delta, pitch), pitch))
    assert 1.0 < F_den / F_lin < 1.0 / (1.0 - d0 / params.h / params.eps_d)


def test_pressure_map_gradients(params):
    rng = np.random.default_rng(0)
    delta = jnp.asarray(rng.uniform(0.0, 4e-4, (6, 7)))
    # checked with δ in mm and p in kPa (finite differences need O(1) numbers); same function, rescaled
    check_grads(
        jax.jit(lambda d: S.pressure_map(params, d * 1e-3, 2e-4) / 1e3), (delta / 1e-3,), order=1, modes=("fwd", "rev")
    )

    def by_params(v):  # E [100 kPa], h [mm], ℓ_b [mm] traced: the blur width is differentiable too
        q = params._replace(E=v[0] * 1e5, h=v[1] * 1e-3, ell_b=v[2] * 1e-3)
        return S.pressure_map(q, delta, 2e-4) / 1e3

    check_grads(
        jax.jit(by_params),
        (jnp.array([params.E / 1e5, params.h / 1e-3, params.ell_b / 1e-3]),),
        order=1,
        modes=("fwd", "rev"),
    )


def test_cosserat_stiffening_bounded(params):
    assert float(S.cosserat_stiffening(params, 2e-3)) == pytest.approx(1 + 0.04 * 0.25, rel=1e-12)
    assert float(S.cosserat_stiffening(params, 1e-6)) == 1.4


# ---------------------------------------------------------------- normal and tangential force


def test_hunt_crossley_m1_is_eq19():
    K, lam = 800.0, 240.0  # N/m, N·s/m²
    delta = jnp.array([1e-4, 2e-4, 3e-4, 5e-4])
    ddot = jnp.array([0.01, -0.01, 0.02, 0.0])
    hc = S.hunt_crossley(K, 1.0, lam, delta, ddot)
    # eq. 19, F = kδ + b̃δ̇, with k = K and b̃ = λδ
    np.testing.assert_allclose(np.asarray(hc), np.asarray(S.kelvin_voigt(K, lam * delta, delta, ddot)), rtol=1e-13)
    # the difference from a constant b̃: no force at first touch and no pull on lift-off
    assert float(S.hunt_crossley(K, 1.0, lam, 0.0, 0.05)) == 0.0
    assert float(S.kelvin_voigt(K, lam * 2e-4, 0.0, 0.05)) > 0.0
    assert float(S.hunt_crossley(K, 1.0, lam, 2e-4, -10.0)) == 0.0


def test_hunt_crossley_power_and_map_form(params):
    K, m, delta, ddot = 1.2e5, params.hc_m, 3e-4, 0.02
    lam = K * params.hc_damping
    F = float(S.hunt_crossley(K, m, lam, delta, ddot))
    assert F == pytest.approx(K * delta**2 * (1 + params.hc_damping * ddot), rel=1e-13)
    assert float(S.damped_contact_force(K * delta**m, params.hc_damping, ddot)) == pytest.approx(F, rel=1e-13)
    assert float(S.hunt_crossley(K, m, lam, 2 * delta, 0.0)) == pytest.approx(4 * K * delta**2, rel=1e-13)


def test_friction_linear_then_capped(params):
    mu, Fn = params.mu, 0.09
    kt = float(S.tangential_stiffness(params, math.pi * (2e-3) ** 2))
    G = params.E / (2 * (1 + params.nu))
    assert kt == pytest.approx(G * math.pi * 4e-6 / params.h, rel=1e-12)
    small = 1e-3 * mu * Fn / kt
    assert float(S.friction(mu, Fn, kt, small)) == pytest.approx(kt * small, rel=1e-6)  # eq. 20, sticking
    assert float(S.friction(mu, Fn, kt, -small)) == pytest.approx(-kt * small, rel=1e-6)
    big = 100 * mu * Fn / kt
    assert float(S.friction(mu, Fn, kt, big)) == pytest.approx(mu * Fn, rel=1e-12)  # Coulomb, sliding
    assert abs(float(S.friction(mu, Fn, kt, 1e3 * big))) <= mu * Fn
    # no normal load: no friction, finite gradients
    assert float(S.friction(mu, 0.0, kt, small)) == 0.0
    g = jax.grad(lambda f, d: S.friction(mu, f, kt, d), argnums=(0, 1))(0.0, small)
    assert all(np.isfinite(float(x)) for x in g)


def test_dense_blur_matches_square_grid_and_conserves_force_on_hexagonal_pores():
    from bayestouch.physics import skin as sk_
    from bayestouch.physics import taxel as tx_

    params = sk_.load_skin()
    tp = tx_.load_taxels()
    w = sk_.blur_width(params)
    # square grid: the dense kernel reproduces the separable blur
    sq = tp._replace(hexagonal=0.0)
    lay = tx_.layout(sq)
    rng = np.random.default_rng(0)
    delta = np.zeros((16, 16))
    delta[6:10, 5:11] = rng.uniform(0, 3e-4, (4, 6))
    K = sk_.blur_kernel(lay.positions, w, tx_.cell_area(sq))
    dense = np.asarray(sk_.pressure_at_taxels(params, delta.ravel(), K)).reshape(16, 16)
    sep = np.asarray(sk_.pressure_map(params, delta, sq.pitch))
    np.testing.assert_allclose(dense, sep, rtol=1e-6, atol=1e-9 * sep.max())
    # hexagonal pores: a point load far (> 10 w) from the edges keeps its force (Σ p A_cell) to 1e-6
    tp = tp._replace(rows=40.0, cols=40.0)
    lay = tx_.layout(tp)
    K = np.asarray(sk_.blur_kernel(lay.positions, w, tx_.cell_area(tp)))
    centre = int(np.argmin(np.linalg.norm(lay.positions, axis=1)))
    assert K[:, centre].sum() == pytest.approx(1.0, abs=1e-6)
    # negative control: the wrong cell area (square) breaks the conservation by √3/2
    K_bad = np.asarray(sk_.blur_kernel(lay.positions, w, tp.pitch**2))
    assert K_bad[:, centre].sum() == pytest.approx(2 / np.sqrt(3), rel=1e-4)
