"""The texture model of the raw-current level (bayestouch.inference.grating): the textured signed distance against
the scene's, the parameterisation's symmetry, the grating search on synthetic data (with a noise-only negative
control), the roughness family's normalisation and the prior file's checks."""

import dataclasses

import numpy as np
import pytest

from bayestouch.backend import jnp
from bayestouch.errors import BadInput
from bayestouch.inference import grating as gr
from bayestouch.params import MODELS

EGG = MODELS / "objects" / "egg.toml"


def _egg_points(rng, n=4000, spread=1e-3):
    """World points within ``spread`` m of the egg's surface."""
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.scene.objects import load_object

    obj = load_object(EGG)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s = obj.shape
    loc = d / np.sum(np.abs(d / np.asarray(s.axes)) ** float(s.n), axis=1, keepdims=True) ** (1 / float(s.n))
    pts = np.asarray(ne.to_world(s, jnp.asarray(loc))) + rng.normal(scale=spread, size=(n, 3))
    return obj, pts


def _theta(obj, u, v, lam, o, rough=1e-6):
    s = obj.shape
    return np.asarray(
        [
            *np.asarray(s.centre),
            *np.log(np.asarray(s.axes)),
            *np.asarray(s.angles),
            np.log(float(s.n)),
            0.0,
            u,
            v,
            np.log(lam),
            o,
            np.log(rough),
        ]
    )


def _hom(p):
    return jnp.asarray(np.concatenate([p.T, np.ones((1, len(p)))]))


def test_textured_distance_equals_the_scene_surface():
    """With the truth's (u, v) (:func:`scene_uv`), the sampled grating is the scene's grating to < 1e-8 m; without
    a reference point it is the bare n-ellipsoid's first-order distance; a wrong wavelength is far off."""
    from bayestouch.scene import surface as sf
    from bayestouch.scene.objects import build_surface

    obj, pts = _egg_points(np.random.default_rng(0))
    surf = build_surface(obj)
    grating_only = surf._replace(texture=surf.texture._replace(roughness=jnp.array(0.0)))
    scene = np.asarray(sf.signed_distance(grating_only, jnp.asarray(pts)))
    t = obj.texture
    ref = pts.mean(axis=0) + np.array([3e-3, -2e-3, 1e-3])
    u, v = gr.scene_uv(obj.shape, t.amplitude, t.wavelength, t.orientation, ref)
    th = _theta(obj, u, v, t.wavelength, t.orientation)
    mine = np.asarray(gr.distance_batch(jnp.asarray(th)[None], _hom(pts), ref))[0]
    # equal formulas evaluated in another order: ~1e-18 m on most points, ~1e-8 m near the tips of the long axis,
    # where two of the three |q|^(n−1) terms are tiny (against the 1 µm contact smoothing length)
    assert np.abs(mine - scene).max() < 3e-8 and np.median(np.abs(mine - scene)) < 1e-15
    bare_scene = surf._replace(texture=surf.texture._replace(amplitude=jnp.array(0.0), roughness=jnp.array(0.0)))
    bare = np.asarray(gr.distance_batch(jnp.asarray(th)[None], _hom(pts)))[0]
    assert np.abs(bare - np.asarray(sf.signed_distance(bare_scene, jnp.asarray(pts)))).max() < 1e-9
    # negative control: 2 % off in wavelength puts the grating out of phase over the egg (~15 periods from the
    # reference): errors of the order of the 50 µm amplitude
    th[13] += np.log(1.02)
    off = np.asarray(gr.distance_batch(jnp.asarray(th)[None], _hom(pts), ref))[0]
    assert np.abs(off - scene).max() > 0.5 * t.amplitude


def test_orientation_alias_is_the_same_surface_and_summarises_alike():
    """(o + π, −u, v) is the same grating: equal distances and equal natural parameters (orientation reduced to
    [0, π)); a different phase is not."""
    obj, pts = _egg_points(np.random.default_rng(1), n=500)
    ref = pts.mean(axis=0)
    a = _theta(obj, 3e-5, -4e-5, 2e-3, 0.4)
    b = a.copy()
    b[11], b[14] = -a[11], a[14] + np.pi
    c = a.copy()
    c[14] = a[14] - 3 * np.pi  # an odd number of half turns the other way
    c[11] = -a[11]
    d = np.asarray(gr.distance_batch(jnp.asarray(np.stack([a, b, c])), _hom(pts), ref))
    np.testing.assert_allclose(d[1], d[0], atol=1e-12)
    np.testing.assert_allclose(d[2], d[0], atol=1e-12)
    nat = gr.texture_natural(np.stack([a, b, c]))
    np.testing.assert_allclose(nat[1], nat[0], atol=1e-12)
    np.testing.assert_allclose(nat[2], nat[0], atol=1e-12)
    assert 0 <= nat[0, 2] < np.pi
    np.testing.assert_allclose(nat[0, 0], 5e-5)  # amplitude = hypot(u, v)
    np.testing.assert_allclose(nat[0, 3], np.arctan2(-4e-5, 3e-5))
    # negative control: swapping u and v (another phase) changes the surface
    e = a.copy()
    e[11], e[12] = a[12], a[11]
    de = np.asarray(gr.distance_batch(jnp.asarray(e)[None], _hom(pts), ref))[0]
    assert np.abs(de - d[0]).max() > 1e-5


def test_grating_peaks_finds_a_hidden_grating_and_not_noise():
    """Weights carrying a 1.7 mm grating at 1.1 rad under noise of 3× its amplitude, on scattered points: the
    strongest peak is within the FFT's resolution of the truth; the same noise alone peaks far lower."""
    rng = np.random.default_rng(5)
    xy = rng.uniform(-0.02, 0.02, size=(20000, 2))
    lam, o = 1.7e-3, 1.1
    k = 2 * np.pi / lam * np.array([np.cos(o), np.sin(o)])
    noise = rng.normal(scale=3.0, size=len(xy))
    peaks = gr.grating_peaks(np.sin(xy @ k + 0.3) + noise, xy, 4e-4, 1.2e-2, count=3)
    best_lam, best_o, stat = peaks[0]
    res = 2 * np.pi / 0.04 / 2  # FFT cell of the doubled 4 cm extent, 1/m
    assert abs(2 * np.pi / best_lam - 2 * np.pi / lam) < 2 * res
    assert abs(best_o - o) < 2 * res / np.linalg.norm(k)
    null = gr.grating_peaks(noise, xy, 4e-4, 1.2e-2, count=1)[0][2]
    # the grating's power is ~ (N/2)² = 1e8 against the noise's ~ N σ² = 1.8e5 per cell (max over ~1e5 cells ≈ 12×)
    assert stat > 20 * null, (stat, null)


def test_roughness_fields_have_unit_rms_and_the_scene_wavelengths():
    """The roughness family's realisations have mean square 1 (within Monte-Carlo error) and vary on the scale of
    the wavelength: points λ/20 apart are strongly correlated, points 5λ apart are not."""
    rng = np.random.default_rng(2)
    lam = 2e-3
    y = rng.uniform(-0.03, 0.03, size=(400, 3))
    f = gr.roughness_fields(y, lam, 300, rng)
    ms = np.mean(f**2)
    # mean square of 300 × 400 values, correlated within a realisation: sd of the estimate ≲ 0.1
    assert abs(ms - 1.0) < 0.1, ms
    near = gr.roughness_fields(np.stack([y[0], y[0] + [lam / 20, 0, 0]]), lam, 500, np.random.default_rng(3))
    far = gr.roughness_fields(np.stack([y[0], y[0] + [5 * lam, 0, 0]]), lam, 500, np.random.default_rng(3))
    assert np.corrcoef(near.T)[0, 1] > 0.9
    assert abs(np.corrcoef(far.T)[0, 1]) < 0.2


def test_texture_priors_are_checked(tmp_path):
    tp = gr.load_texture_priors()
    assert tp.wavelength_min < tp.wavelength_max and tp.roughness_min < tp.roughness_max
    lo, hi = gr.texture_bounds(tp, 0.5)
    assert hi[3] - lo[3] == pytest.approx(np.pi) and lo[2] == pytest.approx(np.log(tp.wavelength_min))
    text = (
        (MODELS / "priors.toml")
        .read_text()
        .replace("wavelength_max = { value = 1.2e-2", "wavelength_max = { value = 1e-4")
    )
    bad = tmp_path / "priors.toml"
    bad.write_text(text)
    with pytest.raises(BadInput, match="wavelength_min < wavelength_max") as e:
        gr.load_texture_priors(bad)
    assert "\n" not in str(e.value)
    # a missing section is named
    bad.write_text("[priors]\n")
    with pytest.raises(BadInput, match="texture_priors"):
        gr.load_texture_priors(bad)


def test_scene_uv_matches_a_shifted_phase():
    """scene_uv's phase is the scene grating's phase at the reference point: moving the reference by a whole
    wavelength along d leaves (u, v) unchanged, by half a wavelength flips both signs."""
    from bayestouch.scene.objects import load_object

    obj = load_object(EGG)
    t = dataclasses.replace(obj.texture)
    R = np.asarray(obj.shape.rotation)
    d_world = R @ np.array([np.cos(t.orientation), np.sin(t.orientation), 0.0])
    ref = np.array([0.004, -0.002, 0.01])
    u0, v0 = gr.scene_uv(obj.shape, t.amplitude, t.wavelength, t.orientation, ref)
    u1, v1 = gr.scene_uv(obj.shape, t.amplitude, t.wavelength, t.orientation, ref + t.wavelength * d_world)
    u2, v2 = gr.scene_uv(obj.shape, t.amplitude, t.wavelength, t.orientation, ref + 0.5 * t.wavelength * d_world)
    np.testing.assert_allclose([u1, v1], [u0, v0], atol=1e-12)
    np.testing.assert_allclose([u2, v2], [-u0, -v0], atol=1e-12)
    assert np.hypot(u0, v0) == pytest.approx(t.amplitude)
