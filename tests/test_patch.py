"""Contact patch: the superellipse of eq. 16–18 and its fit to pressure maps."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.physics import patch as P
from bayestouch.physics import skin as S


def synthetic(a, b, n, angle, centre, pitch=1e-4, half=5e-3, binary=False):
    """Pressure map whose level set p = 1e4 Pa is the superellipse (smooth cone) or a binary indicator."""
    xs = np.arange(-half, half + pitch / 2, pitch)
    X, Y = np.meshgrid(xs, xs)
    dx, dy = X - centre[0], Y - centre[1]
    u = math.cos(angle) * dx + math.sin(angle) * dy
    v = -math.sin(angle) * dx + math.cos(angle) * dy
    rho = (np.abs(u / a) ** n + np.abs(v / b) ** n) ** (1 / n)
    p = 2e4 * (rho < 1) if binary else 1e4 * np.clip(2 - rho, 0, None)
    return p, xs, xs


def test_level_function_on_eq17_curve():
    a, b, n = 3e-3, 2e-3, 3.0
    th = np.linspace(0.01, np.pi / 2 - 0.01, 50)
    x, y = a * np.cos(th) ** (2 / n), b * np.sin(th) ** (2 / n)  # eq. 17, first quadrant
    np.testing.assert_allclose(np.asarray(P.superellipse(a, b, n, x, y)), 1.0, rtol=1e-12)
    assert float(P.superellipse(a, b, n, 0.0, 0.0)) == 0.0
    assert float(P.superellipse(a, b, n, -a, 0.5 * b)) > 1.0


def test_area_limits_and_eq18():
    a, b = 3e-3, 2e-3
    assert float(P.superellipse_area(a, b, 2.0)) == pytest.approx(math.pi * a * b, rel=1e-12)
    assert float(P.superellipse_area(a, b, 1.0)) == pytest.approx(2 * a * b, rel=1e-12)
    assert float(P.superellipse_area(a, b, 1e6)) == pytest.approx(4 * a * b, rel=1e-5)
    ns = jnp.logspace(-0.5, 1.5, 25)
    np.testing.assert_allclose(
        np.asarray(P.superellipse_area_eq18(a, b, ns)), np.asarray(P.superellipse_area(a, b, ns)), rtol=1e-12
    )
    # eq. 18's integral 4b ∫0^a (1 − (x/a)^n)^(1/n) dx, by quadrature
    for n in (0.7, 2.6, 5.0):
        integral = 4 * b * quad(lambda x, n=n: (1 - (x / a) ** n) ** (1 / n), 0, a, epsabs=0, epsrel=1e-12)[0]
        assert float(P.superellipse_area(a, b, n)) == pytest.approx(integral, rel=1e-8)


@pytest.mark.parametrize("binary", [False, True])
@pytest.mark.parametrize(
    "a,b,n,deg", [(3e-3, 2e-3, 3.0, 25.0), (2.5e-3, 1.5e-3, 2.0, -60.0), (3e-3, 2.2e-3, 5.0, 80.0)]
)
def test_fit_recovers_superellipse(a, b, n, deg, binary):
    centre = (0.4e-3, -0.3e-3)
    p, xs, ys = synthetic(a, b, n, math.radians(deg), centre, binary=binary)
    fit = P.fit_patch(p, xs, ys, 1e4)
    assert fit.a == pytest.approx(a, rel=0.02) and fit.b == pytest.approx(b, rel=0.02)
    assert fit.n == pytest.approx(n, abs=0.2)
    assert abs(math.degrees(fit.angle) - deg) < 2.0
    np.testing.assert_allclose(fit.centre, centre, atol=2e-5)
    assert fit.area == pytest.approx(float(P.superellipse_area(a, b, n)), rel=0.03)


def test_fit_canonical_axes():
    # b > a with the long axis along y: reported as a ≥ b with the angle of the long axis
    p, xs, ys = synthetic(1.5e-3, 3e-3, 2.5, 0.0, (0.0, 0.0))
    fit = P.fit_patch(p, xs, ys, 1e4)
    assert fit.a == pytest.approx(3e-3, rel=0.02) and fit.b == pytest.approx(1.5e-3, rel=0.02)
    assert abs(abs(math.degrees(fit.angle)) - 90.0) < 2.0 and -math.pi / 2 < fit.angle <= math.pi / 2


def test_patch_from_sphere_pressure_map_is_round_and_grows_with_load():
    params = S.load_skin()
    R, pitch = 6.5e-3, 1e-4
    xs = np.arange(-6e-3, 6e-3 + pitch / 2, pitch)
    X, Y = np.meshgrid(xs, xs)
    sizes = []
    for d0 in (0.15e-3, 0.3e-3):
        sdf = np.sqrt(X**2 + Y**2 + (R - d0) ** 2) - R
        p = np.asarray(S.pressure_map(params, S.penetration(sdf, params.s), pitch))
        fit = P.fit_patch(p, xs, xs, 1e3)
        assert fit.n == pytest.approx(2.0, abs=0.05) and fit.a == pytest.approx(fit.b, rel=1e-3)
        np.testing.assert_allclose(fit.centre, 0.0, atol=1e-6)
        sizes.append(fit.a)
    assert sizes[1] > sizes[0]  # Table 1's trend: the patch grows with the load


def test_fit_bad_input():
    p, xs, ys = synthetic(2e-3, 1e-3, 2.0, 0.0, (0.0, 0.0))
    with pytest.raises(BadInput, match="above threshold"):
        P.fit_patch(p, xs, ys, 1e9)
    with pytest.raises(BadInput, match=r"\(H, W\)"):
        P.fit_patch(p, xs[:-1], ys, 1e4)
    with pytest.raises(BadInput, match="increasing"):
        P.fit_patch(p, xs[::-1], ys, 1e4)
