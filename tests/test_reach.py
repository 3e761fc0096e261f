"""The fit says when its surface is the model family's extrapolation rather than the data's: how far the surface
runs from every contact, over the contacts' span (bayestouch.inference.reach)."""

import json

import numpy as np
import pytest

from bayestouch.cli import main
from bayestouch.inference.reach import REACH_DRAWS, REACH_LIMIT, REACH_RES, contact_span, surface_reach


def _frame(axis):
    """A rotation (3, 3) whose third column is the unit vector ``axis``."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    x = np.cross(z, [0.3, -0.5, 0.8])
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _cap(radius, half_angle, axis, centre, rings=40, per_ring=240):
    """Points (N, 3) m on a sphere's cap of ``half_angle`` rad around ``axis``, its rim included."""
    t = np.linspace(0.0, half_angle, rings)[:, None]
    p = np.linspace(0.0, 2 * np.pi, per_ring, endpoint=False)[None]
    local = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t) * np.ones_like(p)], axis=-1)
    return centre + radius * local.reshape(-1, 3) @ _frame(axis).T


def _sphere_theta(radius, centre):
    return np.array([*centre, *np.log([radius] * 3), 0.4, 1.1, -0.7, np.log(2.0)])


def test_contact_span_is_the_largest_extent_along_the_principal_axes():
    rng = np.random.default_rng(0)
    box = rng.uniform(-1, 1, (4000, 3)) * [0.03, 0.01, 0.002]  # a 6 × 2 × 0.4 cm slab of points
    rotated = box @ _frame([1.0, 2.0, -0.5]).T + [0.1, -0.2, 0.05]
    assert contact_span(rotated) == pytest.approx(0.06, rel=0.01)
    assert contact_span(rotated[:1]) == 0.0


@pytest.mark.parametrize("degrees", [90.0, 45.0, 30.0])
def test_reach_of_a_sphere_touched_on_a_cap_is_cos_half_angle_over_sin(degrees):
    """Contacts on a cap of half-angle α of the sphere itself: the farthest surface point is the antipode, at a
    chord 2R cos(α/2) from the rim, and the cap spans 2R sin α, so the reach is cos(α/2)/sin α (0.71, 1.31, 1.93).
    The surface is taken at the cube-sphere's directions, which miss the antipode by at most half their spacing,
    h = (π/2)/(2·REACH_RES) rad, and the distance to the nearest rim point falls by at most R·h there: the reach
    lies within a relative h / (2 cos(α/2)) below the exact one, never above it."""
    a = np.radians(degrees)
    centre = np.array([0.01, -0.02, 0.03])
    pts = _cap(0.02, a, [0.4, -0.2, 0.9], centre)
    r = surface_reach(pts, _sphere_theta(0.02, centre)[None])
    assert r.shape == (1,)
    exact = np.cos(a / 2) / np.sin(a)
    h = 0.5 * np.pi / (2 * REACH_RES)
    assert exact * (1 - h / (2 * np.cos(a / 2))) <= r[0] <= exact * 1.001
    # the whole sphere touched: every surface point lies near a contact
    whole = np.concatenate([pts, _cap(0.02, np.pi - a, [-0.4, 0.2, -0.9], centre)])
    assert surface_reach(whole, _sphere_theta(0.02, centre)[None])[0] < 0.05


def test_reach_is_taken_at_the_draws_and_a_larger_surface_reaches_further():
    """Every draw gets its own reach (at most REACH_DRAWS of them), and a sphere twice the size of the touched one
    (its cap through the same contacts, the centre moved back) reaches further beyond them."""
    centre = np.zeros(3)
    pts = _cap(0.02, np.radians(60.0), [0.0, 0.0, 1.0], centre)
    small = _sphere_theta(0.02, centre)
    # the sphere of radius 4 cm through the cap's rim (at height 2 cm · cos 60° = 1 cm, radius 1.73 cm)
    h = 0.01 - np.sqrt(0.04**2 - (0.02 * np.sin(np.radians(60.0))) ** 2)
    large = _sphere_theta(0.04, np.array([0.0, 0.0, h]))
    draws = np.array([small] * 50 + [large] * 50)
    r = surface_reach(pts, draws, seed=1)
    assert len(r) == REACH_DRAWS
    assert set(np.round(r, 6)) == {round(float(surface_reach(pts, t[None])[0]), 6) for t in (small, large)}
    assert surface_reach(pts, large[None])[0] > 2 * surface_reach(pts, small[None])[0]


def _frustum(rng):
    """Contacts (160, 3) m all round a cone frustum 3 cm long whose radius grows from 4 to 13 mm, 0.1 mm noise."""
    x = np.linspace(0.0, 0.03, 10)[:, None]
    phi = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)[None]
    r = 0.004 + 0.3 * x
    pts = np.stack([x * np.ones_like(phi), r * np.cos(phi), r * np.sin(phi)], axis=-1).reshape(-1, 3)
    return pts + 1e-4 * rng.normal(size=pts.shape)


def test_a_fit_of_a_tapered_object_says_its_shape_is_extrapolated(tmp_path, capsys):
    """Contacts all round a cone frustum, an object outside the n-ellipsoid family: the family fits its taper with the
    flank of an ellipsoid many times longer than the frustum (measured: 13 cm, reach 3.2), and the fit says so on the
    command line, in summary.json and its warnings; a 2-cm sphere touched all round (the control) raises nothing."""
    rng = np.random.default_rng(3)
    v = rng.normal(size=(90, 3))
    sphere = 0.02 * v / np.linalg.norm(v, axis=1, keepdims=True) + 1e-4 * rng.normal(size=(90, 3))
    verdicts = {}
    for name, pts, budget in (("frustum", _frustum(rng), "15"), ("sphere", sphere, "8")):
        path = tmp_path / f"{name}.csv"
        np.savetxt(path, pts, delimiter=",", header="x,y,z", comments="")
        out = tmp_path / name
        assert main(["fit", str(path), "--out", str(out), "--budget", budget, "--quiet"]) == 0
        d = json.loads((out / "summary.json").read_text())["diagnostics"]
        verdicts[name] = (d["extrapolated"], d["reach"], capsys.readouterr())
    flagged, reach, said = verdicts["frustum"]
    assert flagged and reach["median"] > REACH_LIMIT and "EXTRAPOLATED" in said.out
    assert "warning: extrapolated:" in said.err
    flagged, reach, said = verdicts["sphere"]
    assert not flagged and reach["median"] < 0.3 and "EXTRAPOLATED" not in said.out
