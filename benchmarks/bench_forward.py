"""Forward-model throughput: taxel frames per second of ``simulate`` (16 × 16 taxels, a batch of 64
parameter sets), the cost of its gradient, and the standard scenario (egg, 10 strokes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.physics import forward as fw
from bayestouch.physics.virtual import load_finger
from bayestouch.scene.objects import load_object
from bayestouch.scene.strokes import random_strokes
from benchmarks.harness import best_of

EGG = Path(__file__).resolve().parent.parent / "models" / "objects" / "egg.toml"


def _setup(frames: int = 50):
    egg = load_object(EGG)
    vf = load_finger()
    st = random_strokes(egg, 1, seed=0, duration=(frames - 1) / 50.0, rate=50.0)[0]
    return egg, vf, fw.stroke_arrays(st)


def bench_simulate_batch():
    egg, vf, st = _setup()
    surf = egg.surface()
    B = 64
    scale = jnp.asarray(np.random.default_rng(0).uniform(0.97, 1.03, (B, 3)))
    batch = jax.vmap(lambda s: surf._replace(shape=surf.shape._replace(axes=surf.shape.axes * s)))(scale)
    keys = jax.random.split(jax.random.PRNGKey(0), B)
    f = jax.jit(jax.vmap(lambda s, k: fw.simulate(s, st, vf.finger, k, dt=0.02, mode="physics").taxel_current))
    f(batch, keys).block_until_ready()
    t = best_of(lambda: f(batch, keys).block_until_ready(), repeat=3)
    n_frames = st[0].shape[0]
    out = [
        {
            "metric": "simulate, taxel frames/s (batch of 64 surfaces)",
            "value": B * n_frames / t,
            "unit": "1/s",
            "taxels": 256,
            "frames_per_stroke": n_frames,
            "batch": B,
        }
    ]
    g = jax.jit(
        jax.vmap(jax.grad(lambda s: jnp.sum(fw.clean_currents(s, vf.finger, st, 300.0, 0.02, "physics")[0]) * 1e6))
    )
    g(batch).shape  # noqa: B018
    jax.block_until_ready(g(batch))
    tg = best_of(lambda: jax.block_until_ready(g(batch)), repeat=3)
    out.append(
        {
            "metric": "gradient of Σ current w.r.t. the surface, per frame",
            "value": tg / (B * n_frames) * 1e6,
            "unit": "µs",
            "batch": B,
        }
    )
    out.append({"metric": "gradient / forward cost ratio (noise-free vs noisy forward)", "value": tg / t, "unit": "1"})
    return out


def bench_standard_scenario():
    egg = load_object(EGG)
    vf = load_finger()
    strokes = random_strokes(egg, 10, seed=3, duration=2.0, rate=50.0)
    surf = egg.surface()
    arrs = [fw.stroke_arrays(s) for s in strokes]
    f = jax.jit(lambda s: sum(jnp.sum(fw.clean_currents(s, vf.finger, a, 300.0, 0.02, "physics")[0]) for a in arrs))
    f(surf).block_until_ready()
    t = best_of(lambda: f(surf).block_until_ready(), repeat=3)
    return [
        {
            "metric": "standard scenario (egg, 10 strokes × 101 frames), one noise-free forward",
            "value": t * 1e3,
            "unit": "ms",
            "frames": 10 * 101,
        }
    ]
