"""The forward model: pad geometry, contact, pressure → current, noise, finger drive, recordings."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from jax.test_util import check_grads

from bayestouch.backend import jax, jnp
from bayestouch.cli import main
from bayestouch.io.recording import UNITS, read_recording
from bayestouch.physics import forward as fw
from bayestouch.physics import taxel as tx
from bayestouch.physics.finger import drive
from bayestouch.physics.virtual import load_finger
from bayestouch.scene.objects import load_object

ROOT = Path(__file__).parent.parent
VF = load_finger(seed=0)
F = VF.finger
RHO_MIN = float(np.min(np.linalg.norm(np.asarray(F.grid), axis=-1)))
PLATE = replace(load_object(ROOT / "models" / "objects" / "graphite_plate.toml"), defects=())


def _flat_stroke(depth, n=5, z=0.005):
    """A straight stroke along x on the plate's top face (z = 5 mm), 1 cm/s at 50 Hz."""
    x = 0.002 * np.arange(n) / n
    contact = np.stack([x, np.zeros(n), np.full(n, z)], 1)
    return (
        jnp.asarray(contact),
        jnp.tile(jnp.array([0.0, 0.0, 1.0]), (n, 1)),
        jnp.tile(jnp.array([1.0, 0.0, 0.0]), (n, 1)),
        jnp.asarray(depth),
    )


def test_pad_geometry():
    x = np.asarray(fw.pad_points(F, jnp.zeros(3), jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 0.0, 0.0]), 3e-4))
    R = float(F.tip_radius)
    centre = np.array([0.0, 0.0, R - 3e-4])
    assert np.allclose(np.linalg.norm(x - centre, axis=-1), R, atol=1e-15)  # on the tip sphere
    # the pad centre is pressed 0.3 mm deep; the innermost taxels sit ρ_min off it
    lift = R * (1 - np.cos(RHO_MIN / R))
    assert x[..., 2].min() == pytest.approx(-3e-4 + lift, abs=1e-12)
    # u runs along the direction of motion
    row = x[8]
    assert np.all(np.diff(row[:, 0]) > 0) and np.all(row[:, 1] > 0)  # row 8 lies at v > 0


def test_no_contact_gives_unstrained_current():
    surf = PLATE.surface()
    cur, p, delta, force, _ = fw.clean_currents(surf, F, _flat_stroke(3e-4, z=0.008), 300.0, 0.02, "physics")
    assert float(jnp.max(delta)) < 1e-8 and float(jnp.max(force)) < 1e-6
    i0 = float(tx.taxel_current(F.taxels, 0.0, 300.0, mode="physics"))
    assert np.allclose(np.asarray(cur), i0, rtol=1e-6)


def test_force_grows_with_depth_and_centre_penetration_equals_depth():
    surf = PLATE.surface()
    forces = []
    for d in (1e-4, 2e-4, 3e-4, 4e-4):
        _, p, delta, force, _ = fw.clean_currents(surf, F, _flat_stroke(d), 300.0, 0.02, "physics")
        lift = float(F.tip_radius) * (1 - np.cos(RHO_MIN / float(F.tip_radius)))
        assert float(jnp.max(delta)) == pytest.approx(d - lift, abs=1e-6)  # flat face: penetration = depth
        forces.append(float(force[2]))
    assert np.all(np.diff(forces) > 0)
    # sphere on a Winkler layer: F ∝ δ² (physics.md §3); the densifying foam makes it a little stiffer
    ratio = forces[3] / forces[1]
    assert 3.5 < ratio < 5.0


def test_reference_taxels_see_no_pressure_and_current_tracks_pressure():
    surf = PLATE.surface()
    cur, p, *_ = fw.clean_currents(surf, F, _flat_stroke(3e-4, n=40), 300.0, 0.02, "empirical")
    ref = np.asarray(F.reference).ravel()
    p_last = np.asarray(p[-1]).ravel()
    assert np.all(p_last[ref] == 0)
    c = np.asarray(cur[-1])
    # empirical mode, lag settled (40 frames = 0.8 s ≫ τ = 0.15 s): ln I − ln I0 = S_p p
    i0 = float(tx.taxel_current(F.taxels, 0.0, 300.0, mode="empirical"))
    np.testing.assert_allclose(np.log(c / i0), float(F.taxels.sensitivity) * p_last, rtol=0.01, atol=1e-4)


def test_skin_temperature_shifts_currents():
    surf = PLATE.surface()
    c300 = fw.clean_currents(surf, F, _flat_stroke(3e-4), 300.0, 0.02, "physics")[0]
    c301 = fw.clean_currents(surf, F, _flat_stroke(3e-4), 301.0, 0.02, "physics")[0]
    rel = float(jnp.mean(c301 / c300)) - 1
    assert 0.06 < rel < 0.11  # d ln I/dT ≈ 6–11 %/K (physics.md §0)


def test_noise_is_seeded_and_measured_current_is_close():
    surf = PLATE.surface()
    st = _flat_stroke(3e-4, n=20)
    a = fw.simulate_jit(surf, st, F, jax.random.PRNGKey(1), dt=0.02)
    b = fw.simulate_jit(surf, st, F, jax.random.PRNGKey(1), dt=0.02)
    c = fw.simulate_jit(surf, st, F, jax.random.PRNGKey(2), dt=0.02)
    assert np.array_equal(np.asarray(a.taxel_current), np.asarray(b.taxel_current))
    assert not np.array_equal(np.asarray(a.taxel_current), np.asarray(c.taxel_current))
    rel = np.median(np.abs(np.asarray(a.taxel_current) / np.asarray(a.clean_current) - 1))
    assert rel < 0.5  # fixed pattern σ(ln G) ≈ 0.4–1: the right order, not a different signal


def test_gradient_with_respect_to_shape_and_texture():
    egg = load_object(ROOT / "models" / "objects" / "egg.toml")
    surf = egg.surface()
    from bayestouch.scene.strokes import random_strokes

    st = fw.stroke_arrays(random_strokes(egg, 1, seed=2, duration=0.1, rate=50.0)[0])

    def total(axes, amp):
        s = surf._replace(shape=surf.shape._replace(axes=axes), texture=surf.texture._replace(amplitude=amp))
        cur, p, *_ = fw.clean_currents(s, F, st, 300.0, 0.02, "empirical")
        return jnp.sum(p) * 1e-3

    g = jax.grad(total, argnums=(0, 1))(surf.shape.axes, surf.texture.amplitude)
    assert np.all(np.isfinite(np.asarray(g[0]))) and abs(float(g[1])) > 0
    check_grads(
        lambda a: total(a, surf.texture.amplitude), (surf.shape.axes,), order=1, modes=["rev"], eps=1e-7, rtol=1e-3
    )


def test_finger_drive():
    sym = drive(VF.wire, VF.rod, [0.1, 0.1, 0.1], 20, 0.02)
    asym = drive(VF.wire, VF.rod, [0.16, 0.05, 0.05], 20, 0.02)
    assert np.linalg.norm(sym.curvature[-1]) < 1e-6  # equal wires: no bend
    assert 5.0 < np.linalg.norm(asym.curvature[-1]) < 20.0  # tens of degrees over 6 cm
    amb = float(VF.wire.ambient)
    assert np.all(asym.skin_temperature > amb) and np.all(asym.skin_temperature < asym.wire_temperature.max())
    from bayestouch.errors import BadInput

    with pytest.raises(BadInput, match="wire currents"):
        drive(VF.wire, VF.rod, [0.5, 0.0, 0.0], 5, 0.02)


def test_simulate_cli_writes_recording(tmp_path, capsys):
    out = tmp_path / "rec.nc"
    egg = str(ROOT / "models" / "objects" / "egg.toml")
    assert (
        main(
            [
                "simulate",
                "--object",
                egg,
                "--strokes",
                "2",
                "--seed",
                "3",
                "--out",
                str(out),
                "--duration",
                "0.5",
                "--quiet",
            ]
        )
        == 0
    )
    ds = read_recording(out)
    for name, unit in UNITS.items():
        assert ds[name].attrs["units"] == unit
    assert ds["taxel_current"].shape == (2 * 26, 256)
    assert set(np.unique(ds["stroke_index"].values)) == {0, 1} and np.all(np.diff(ds["time"].values) > 0)
    assert float(ds["contact_force"].max()) > 0.01
    # bad inputs: one line, exit 2, the earlier recording untouched
    before = out.read_bytes()
    for args, needle in [
        (["--currents", "0.9,0,0"], "wire currents"),
        (["--duration", "-1"], "--duration"),
        (["--object", str(tmp_path / "none.toml")], "no such file"),
    ]:
        argv = ["simulate", "--object", egg, "--out", str(out), "--quiet", *args]
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and "\n" not in err
    assert out.read_bytes() == before


def test_friction_sticks_then_slides():
    surf = PLATE.surface()
    st = _flat_stroke(3e-4, n=40)
    fr = fw.simulate(surf, st, F, jax.random.PRNGKey(0), dt=0.02, noise=False)
    ft, fn = np.asarray(fr.friction), np.asarray(fr.force)
    assert ft[0] == 0.0 and np.all(np.diff(ft[:5]) > 0)  # stuck: grows with the distance slid
    assert ft[-1] == pytest.approx(float(F.skin.mu) * fn[-1], rel=1e-3)  # sliding: Coulomb cap μ F_n


def test_force_controlled_stroke_holds_the_force(tmp_path):
    egg = load_object(ROOT / "models" / "objects" / "egg.toml")
    from bayestouch.scene.strokes import random_strokes

    st = fw.stroke_arrays(random_strokes(egg, 1, seed=4, duration=0.3, rate=50.0)[0])
    surf = egg.surface()
    d = fw.depths_for_force(surf, F, st, 0.07)
    _, p, delta, force, _ = fw.clean_currents(surf, F, (*st[:3], d), 300.0, 0.02, "physics")
    f_el = np.asarray(fw.elastic_force(F, p))
    assert np.allclose(f_el, 0.07, rtol=1e-6)
    assert np.ptp(np.asarray(d)) > 0  # the egg's curvature changes along the path: so does the depth
    out = tmp_path / "f.nc"
    assert (
        main(
            [
                "simulate",
                "--object",
                str(ROOT / "models/objects/egg.toml"),
                "--out",
                str(out),
                "--force",
                "0.07",
                "--duration",
                "0.2",
                "--quiet",
            ]
        )
        == 0
    )
    ds = read_recording(out)
    assert ds["pressing_depth"].attrs["units"] == "m" and float(ds["pressing_depth"].min()) > 0
