"""The true surface as a JAX pytree: signed distance (contact), heights, FFD, gradients."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from jax.test_util import check_grads

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.scene.objects import FFDSpec, SceneObject, load_object, object_from_dict
from bayestouch.scene.surface import signed_distance

OBJ = Path(__file__).parent.parent / "models" / "objects"


def test_sphere_distance_is_exact():
    s = ne.NEllipsoid(jnp.array([0.01, -0.02, 0.0]), jnp.full(3, 0.02), jnp.array([0.3, 0.2, 0.1]), jnp.array(2.0))
    surf = SceneObject("s", s).surface()
    x = np.random.default_rng(0).normal(0, 0.03, (200, 3)) + [0.01, -0.02, 0.0]
    exact = np.linalg.norm(x - [0.01, -0.02, 0.0], axis=1) - 0.02
    assert np.allclose(np.asarray(signed_distance(surf, jnp.asarray(x))), exact, atol=1e-12)


def test_flat_face_distance_is_euclidean():
    """1 mm above the plate's top face, far from the centre, φ = 1 mm (a radial distance would say ≈ 6 mm)."""
    plate = replace(load_object(OBJ / "graphite_plate.toml"), defects=())
    x = jnp.array([[0.03, 0.01, 0.006], [-0.02, 0.0, -0.0055]])
    phi = np.asarray(signed_distance(plate.surface(), x))
    assert np.allclose(phi, [1e-3, 0.5e-3], rtol=0.01)  # the face bulges by 9 µm at x = 3 cm (n = 10)


@pytest.mark.parametrize("name", ["graphite_plate", "egg"])
def test_true_surface_has_zero_distance(name):
    obj = load_object(OBJ / f"{name}.toml")
    v, _ = obj.mesh(24)
    phi = np.asarray(signed_distance(obj.surface(), jnp.asarray(v)))
    scale = float(np.min(np.asarray(obj.shape.axes)))
    assert np.abs(phi).max() < 2e-3 * scale  # first-order distance: exact on the surface up to O(h²κ)
    assert float(signed_distance(obj.surface(), obj.shape.centre)) < -0.5 * scale  # inside is negative


def test_defects_change_distance_by_their_depth():
    plate = load_object(OBJ / "graphite_plate.toml")
    bump = next(d for d in plate.defects if d.kind == "bump")
    base = replace(plate, defects=())
    top = jnp.asarray(bump.centre) + jnp.array([0.0, 0.0, 0.002])
    diff = float(signed_distance(base.surface(), top) - signed_distance(plate.surface(), top))
    assert diff == pytest.approx(bump.depth, rel=0.02)


def test_ffd_moves_the_surface():
    s = ne.NEllipsoid(jnp.zeros(3), jnp.full(3, 0.02), jnp.zeros(3), jnp.array(2.0))
    disp = np.zeros((2, 2, 2, 3))
    disp[..., 2] = 1e-3  # every control point up 1 mm: a pure translation
    obj = SceneObject("s", s, ffd=FFDSpec((2, 2, 2), disp))
    x = jnp.array([[0.0, 0.0, 0.025], [0.01, 0.0, 0.0]])
    phi = np.asarray(signed_distance(obj.surface(), x))
    assert np.allclose(phi, [0.025 - 0.021, np.hypot(0.01, 0.001) - 0.02], atol=1e-9)
    v = obj.displace(np.array([[0.0, 0.0, 0.02]]))
    assert np.allclose(v, [[0.0, 0.0, 0.021]])


def test_gradients_and_vmap():
    egg = load_object(OBJ / "egg.toml")
    surf = egg.surface()
    x = jnp.asarray(egg.mesh(8)[0][:20]) * 1.01

    def f(amp, axes):
        tex = surf.texture._replace(amplitude=amp)
        return jnp.sum(signed_distance(surf._replace(texture=tex, shape=surf.shape._replace(axes=axes)), x))

    check_grads(f, (surf.texture.amplitude, surf.shape.axes), order=1, modes=["rev"], eps=1e-7)
    batch = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), surf)
    out = jax.vmap(signed_distance, in_axes=(0, None))(batch, x)
    assert out.shape == (2, 20) and np.allclose(out[0], out[1])


def test_bad_texture_and_ffd_tables():
    base = {"shape": {"centre_m": [0, 0, 0], "axes_m": [0.03, 0.02, 0.01], "n": 2.0}}
    with pytest.raises(BadInput, match="wavelength_m"):
        object_from_dict({**base, "texture": {"amplitude_m": 1e-5}}, "o.toml")
    with pytest.raises(BadInput, match="a fifth"):
        object_from_dict({**base, "texture": {"amplitude_m": 0.005, "wavelength_m": 0.001}}, "o.toml")
    with pytest.raises(BadInput, match="dims"):
        object_from_dict({**base, "ffd": {"dims": [4, 1, 3]}}, "o.toml")
