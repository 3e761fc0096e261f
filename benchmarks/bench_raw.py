"""Raw-current level (issue 4, level 2): log-density throughput at a batch of 32 walkers (bare shape at strides 5
and 1, textured at stride 2), and the end-to-end ``run_raw_fit`` of the standard scenario (the textured egg, 10
strokes, seed 3, empirical taxel mode) with the texture sampled (``texture="auto"``, the default) and without
(``texture="off"``), the response lag sampled (the default): diagnostics, the volume error and the texture parameters
and the lag against the truth. Target (issue 4):
the posterior in under 2 minutes on 2 cores.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from bayestouch.params import MODELS
from benchmarks.harness import best_of

W = 32
EGG = MODELS / "objects" / "egg.toml"


def _recording(mode: str = "empirical", strokes: int = 10, seed: int = 3):
    """The standard scenario, as ``bayestouch simulate --object egg.toml --strokes 10 --seed 3 --mode MODE``."""
    from bayestouch.physics.virtual import load_finger, recording_dataset
    from bayestouch.scene.objects import load_object
    from bayestouch.scene.strokes import random_strokes

    obj = load_object(EGG)
    vf = load_finger(MODELS, seed=seed)
    st = random_strokes(obj, strokes, seed=seed)
    return recording_dataset(obj, st, vf, seed, mode=mode, attrs={"object": "egg", "seed": seed}), obj


def _truth(obj):
    s = obj.shape
    return np.asarray(
        [*np.asarray(s.centre), *np.log(np.asarray(s.axes)), *np.asarray(s.angles), np.log(float(s.n)), np.log(8.0)]
    )


def _texture_truth(obj, data):
    from bayestouch.inference import grating as gr
    from bayestouch.inference import raw

    t = obj.texture
    u, v = gr.scene_uv(obj.shape, t.amplitude, t.wavelength, t.orientation, raw.texture_reference(data))
    return np.concatenate(
        [_truth(obj)[:10], [np.log(1.0), u, v, np.log(t.wavelength), t.orientation, np.log(t.roughness)]]
    )


def bench_raw_log_prob(ds_obj=None):
    from bayestouch.inference import contact as cm
    from bayestouch.inference import grating as gr
    from bayestouch.inference import raw

    ds, obj = ds_obj or _recording()
    out = []
    for stride, textured in ((5, False), (1, False), (2, True)):
        data, finger = raw.load_raw_data(ds, stride=stride)
        if textured:
            tp = gr.load_texture_priors()
            tex = gr.RawTexture(raw.texture_reference(data), np.zeros(np.shape(data.log_current)), tp.amplitude_scale)
            th0 = _texture_truth(obj, data)
            b = raw.textured_bounds(data, cm.load_priors(), tp, float(th0[14]))
            f, _, _ = raw.make_raw_log_prob(data, finger, texture=tex, bounds=b)
        else:
            th0 = _truth(obj)
            f, _, _ = raw.make_raw_log_prob(data, finger)
        th = th0 + 1e-9 * np.random.default_rng(0).normal(size=(W, th0.size))
        f(th)
        t = best_of(lambda f=f, th=th: f(th), repeat=3, number=3)
        F, M = data.log_current.shape
        out.append(
            {
                "metric": f"raw-current log-density evaluations/s ({'textured, ' if textured else ''}stride {stride})",
                "value": W / t,
                "unit": "1/s",
                "batch": W,
                "frames": int(F),
                "taxels": int(M),
                "penetration_taxels": int(data.taxel_position.shape[1]),
                "seconds_per_batch": t,
            }
        )
    return out


def bench_raw_fit(steps: int = 3000, ds_obj=None):
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.inference import raw
    from bayestouch.physics.taxel import load_taxels

    ds, obj = ds_obj or _recording()
    out = []
    for texture in ("auto", "off"):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            s = raw.run_raw_fit(ds, Path(tmp) / "fit", seed=0, walkers=W, steps=steps, progress=False, texture=texture)
            secs = time.perf_counter() - t0
        v_true = float(ne.volume(obj.shape))
        vol = s["derived"]["volume_m3"]
        d = s["diagnostics"]
        p = s["parameters"]
        row = {
            "metric": "raw-current posterior, standard scenario (egg, 10 strokes, seed 3, empirical), end to end, "
            f"texture={texture}",
            "value": secs,
            "unit": "s",
            "target": 120.0,
            "max_steps": steps,
            "steps": d["steps"],
            "walkers": W,
            "frames": s["model"]["frames_used"],
            "converged": d["converged"],
            "max_r_hat": d["max_r_hat"],
            "min_ess_bulk": d["min_ess_bulk"],
            "autocorr_time_max": d["autocorr_time_max"],
            "volume_rel_error": (vol["mean"] - v_true) / v_true,
            "volume_rel_sd": vol["sd"] / v_true,
            "noise_scale_mean": p["noise_scale"]["mean"],
            "texture_sampled": "amplitude" in p,
        }
        if "lag" in p:  # the finger's lag is the models' (the standard scenario's nominal finger)
            row["lag_s"] = [p["lag"]["mean"], p["lag"]["sd"], float(load_taxels().lag)]
            row["lag_starts"] = len(s["model"]["lag_starts"])
        if "amplitude" in p:
            t = obj.texture
            o = p["orientation"]["mean"]
            row.update(
                {
                    "grating_gain_nats": s["model"]["texture_search"]["grating_gain_nats"],
                    "amplitude_m": [p["amplitude"]["mean"], p["amplitude"]["sd"], t.amplitude],
                    "wavelength_m": [p["wavelength"]["mean"], p["wavelength"]["sd"], t.wavelength],
                    # from the long axis: o, or π − o when the grating's plane is the long axis with the other
                    # short axis
                    "orientation_rad": [
                        o,
                        p["orientation"]["sd"],
                        t.orientation,
                        min(abs(o - t.orientation), abs(np.pi - o - t.orientation)),
                    ],
                    "roughness_m": [p["roughness"]["mean"], p["roughness"]["sd"], t.roughness],
                }
            )
        out.append(row)
    return out


if __name__ == "__main__":
    import json

    rec = _recording()
    for r in bench_raw_log_prob(rec) + bench_raw_fit(ds_obj=rec):
        print(json.dumps(r))
