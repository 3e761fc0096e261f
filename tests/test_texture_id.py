"""Texture identification (issue 5): library validation, recovered truth, a sub-noise negative control, the
sequential = batch Bayes round trip, the EIG bound's closed forms, and a small seeded experiment."""

import json
import tomllib

import numpy as np
import pytest

from bayestouch.cli import main as cli_main
from bayestouch.errors import BadInput
from bayestouch.inference import texture_posterior as tp
from bayestouch.inference.densities import student_t_logpdf
from bayestouch.inference.raw import HostDevice, host_device
from bayestouch.physics.virtual import load_finger
from bayestouch.planning import texture_id as ti
from bayestouch.planning.eig import eig_pairwise
from bayestouch.planning.experiment import wilson_interval
from bayestouch.scene import textures as tx


@pytest.fixture(scope="module")
def vf():
    return load_finger(seed=0)


@pytest.fixture(scope="module")
def lib():
    return tx.load_library()


#: a calibrated device's response sd (bayestouch calibrate over the sphere at 3 depths: 0.0016–0.0023): with the
#: nominal ±RESPONSE_SCALE_SD a 5.7 % amplitude difference is within the response's own uncertainty
CALIBRATED_RESPONSE_SD = 2e-3


def _doc():
    return tomllib.loads(tx.LIBRARY.read_text())


def test_library_loads(lib):
    assert len(lib) >= 20
    assert len(set(lib.names)) == len(lib)
    amps = np.array([s.amplitude for s in lib.specs])
    lams = np.array([s.wavelength for s in lib.specs])
    assert amps.max() == pytest.approx(1e-4) and lams.min() == pytest.approx(5e-4) and lams.max() == pytest.approx(4e-3)
    assert any(s.amplitude == 0 and s.roughness > 0 for s in lib.specs)  # some only rough
    assert len({s.orientation for s in lib.specs}) >= 3  # anisotropic gratings in several directions
    surf = lib.surfaces()
    assert surf.texture.amplitude.shape == (len(lib),)
    assert lib.subset(5).names == lib.names[:5]


@pytest.mark.parametrize(
    "edit,field",
    [
        (lambda d: d["texture"][3].update(amplitude_m=-1e-5), "amplitude_m"),
        (lambda d: d["texture"][2].pop("wavelength_m"), "wavelength_m"),
        (lambda d: d["texture"][4].update(name=d["texture"][0]["name"]), "name"),
        (lambda d: d["texture"][1].update(seed=1.5), "seed"),
        (lambda d: d["object"]["shape"].update(axes_m=[45.0, 25.0, 5.0]), "axes_m"),
        (lambda d: d.update(texture=d["texture"][:1]), "[[texture]]"),
        # issue 24, tenth review: a file without [library] (or a misspelt one) was read with 16 modes
        (lambda d: d.pop("library"), "needs a table [library] with modes"),
        (lambda d: d["library"].pop("modes"), "needs a table [library] with modes"),
        # issue 24, ninth review: a misspelt key took its default (rough5 became smooth's twin, exit 0) ...
        (lambda d: d["texture"][1].update(roughnes_m=d["texture"][1].pop("roughness_m")), "unknown key 'roughnes_m'"),
        (lambda d: d["library"].update(mode=16), "unknown key 'mode'"),
        (lambda d: d.update(textures=[]), "unknown key 'textures'"),
        # ... and two identical textures could never be told apart
        (lambda d: d["texture"][2].update({k: v for k, v in d["texture"][1].items() if k != "name"}), "the same"),
    ],
)
def test_bad_library_names_the_field(edit, field):
    doc = _doc()
    edit(doc)
    with pytest.raises(BadInput, match=field.replace("[", r"\[").replace("]", r"\]")):
        tx.library_from_dict(doc)


def test_one_texture_library_is_named_not_dumped():
    """Issue 24, tenth review: a one-texture library was refused by printing its whole table."""
    doc = _doc()
    doc["texture"] = doc["texture"][:1]
    with pytest.raises(BadInput, match=r"at least two \[\[texture\]\] tables, got 1 \('smooth'\)$"):
        tx.library_from_dict(doc)


def test_bad_toml_file(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text("[library\nmodes = 16\n")
    with pytest.raises(BadInput, match="not valid TOML"):
        tx.load_library(p)
    with pytest.raises(BadInput, match="no such file"):
        tx.load_library(tmp_path / "missing.toml")


@pytest.mark.slow
def test_noise_free_truth_is_the_maximum(lib, vf):
    """Noise, temperature offset and shift off: the true texture's predicted ln I equals the data (to rounding),
    so its log-likelihood at zero shift is the Student-t maximum (F·M readings at log t(0; 1) after whitening), and
    every other texture and shift is lower."""
    small = lib.subset(5)
    surfs = small.surfaces()
    st = ti.IdSettings(noise=False, temperature_sd=0.0, shift_range=0.0)
    grid = ti.IdSettings().shifts()  # the experiment's grid (one compiled size for the whole file)
    g0 = int(np.flatnonzero(grid == 0.0)[0])
    rng = np.random.default_rng(3)
    spec = tx.random_stroke_spec(small.base, rng)
    for k in (0, 4):
        data, tangent, shift = ti.record_stroke(small.object(k), spec, vf, rng, st)
        assert shift == 0.0
        assert data.gain_sd is not None  # read as a host reads it: the gains unknown, marginalised
        # the response factor taken as known: its marginal's determinant would lower every hypothesis by its own
        # Occam factor (½ log(1 + gᵀPg/precision)), which the exact maximum below leaves out
        ll = tp.texture_log_likelihood(surfs, data._replace(response_sd=None), host_device().finger, grid, tangent)
        best = float(np.asarray(student_t_logpdf(0.0, 1.0, 4.0))) * np.size(data.log_current)  # whitened, unit scale
        assert ll[k, g0] == pytest.approx(best, abs=1e-4)
        assert np.unravel_index(np.argmax(ll), ll.shape) == (k, g0)
        others = np.delete(ll, k, axis=0)
        assert others.max() < best - 10.0


def test_whitened_noise_is_independent_over_frames(lib, vf):
    """Residuals of the true texture (noise on, shift and temperature offset off) after :func:`frame_whitener`:
    each taxel's mean over F frames has variance 1/F if the frame correlation is modelled right. Over M ≈ 100
    taxels the sample variance has relative sd √(2/M) ≈ 0.14, so F·var ∈ (0.5, 1.6) is a > 3σ band. Negative
    control: without whitening the same means vary ≫ 1/F (the slow 1/f components). Taxels with an ADC glitch
    (|z| > 6, probability 1e-4 a reading) are left out: the Student-t, not this check, handles them."""
    small = lib.subset(5)
    st = ti.IdSettings(shift_range=0.0, temperature_sd=0.0)
    rng = np.random.default_rng(21)
    spec = tx.random_stroke_spec(small.base, rng)
    data, _, _ = ti.record_stroke(small.object(2), spec, vf, rng, st, finger=vf.finger)  # the noise model
    mu = tp.texture_means(small.surfaces(), data, vf.finger)[2].reshape(np.shape(data.log_current))
    z = (np.asarray(data.log_current) - mu) / np.asarray(data.noise_sd)
    z = z[:, np.all(np.abs(z) < 6, axis=0)]
    F, M = z.shape
    assert M > 80
    zw = tp.frame_whitener(data, vf.finger) @ z
    assert 0.5 < F * zw.mean(axis=0).var() < 1.6
    assert 0.8 < zw.var() < 1.2
    assert F * z.mean(axis=0).var() > 5.0


def test_sub_noise_pair_stays_undecided(lib, vf):
    """Negative control. The truth A (2 mm grating, 30 µm) and a twin A' 0.2 nm higher, among three clearly different
    textures. The twins' predictions differ by D = Σ (δ/s)² ≪ 1 over all readings, so under the model
    log p(A)/p(A') ~ N(D/2, D): |log ratio| ≤ D/2 + 4√D (4σ), and p(A | A or A') stays within 1/(1 + e^{±that})
    of 1/2, while the three others are excluded with confidence (the same strokes do decide between distinct
    textures)."""
    doc = _doc()
    by = {t["name"]: t for t in doc["texture"]}
    g = dict(by["grating2_a30"])
    doc["texture"] = [
        g,
        {**g, "name": "twin", "amplitude_m": g["amplitude_m"] + 2e-10},
        by["grating2_a10"],
        by["grating2_a30_o90"],
        by["rough15_l1.5"],
    ]
    five = tx.library_from_dict(doc)
    surfs = five.surfaces()
    st = ti.IdSettings()
    rng = np.random.default_rng(11)
    log_post, D = np.full(5, -np.log(5)), 0.0
    for _ in range(3):
        spec = tx.random_stroke_spec(five.base, rng)
        data, tangent, _ = ti.record_stroke(five.object(0), spec, vf, rng, st)
        mu = tp.texture_means(surfs, data, vf.finger)
        D += float(np.sum(((mu[0] - mu[1]) / np.asarray(data.noise_sd).ravel()) ** 2))
        ll = tp.texture_log_likelihood(surfs, data, vf.finger, st.shifts(), tangent)
        log_post = tp.update_posterior(log_post, tp.stroke_evidence(ll))
    post = np.exp(log_post)
    assert D < 0.05  # below the noise floor by construction
    bound = D / 2 + 4 * np.sqrt(D)
    p_twin = post[0] / (post[0] + post[1])
    assert 1 / (1 + np.exp(bound)) < p_twin < 1 / (1 + np.exp(-bound))
    assert post[0] + post[1] > 0.999  # the distinct textures are ruled out
    assert post.max() < 0.95  # so no decision at the 0.95 threshold


def test_sequential_update_equals_batch():
    rng = np.random.default_rng(0)
    prior = np.log(rng.dirichlet(np.ones(7)))
    ev = rng.normal(0.0, 50.0, size=(4, 7))
    seq = prior
    for e in ev:
        seq = tp.update_posterior(seq, e)
        assert np.exp(seq).sum() == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(seq, tp.batch_posterior(prior, ev), atol=1e-9)
    assert not np.allclose(seq, tp.batch_posterior(prior, ev[:3]), atol=1e-3)  # the last stroke mattered
    # shifting one stroke's evidence by a constant (texture-independent likelihood factor) changes nothing
    assert np.allclose(tp.batch_posterior(prior, ev + np.array([[3.0], [0], [0], [-7.0]])), seq, atol=1e-9)


def test_stroke_evidence_is_the_shift_average():
    ll = np.log(np.array([[1.0, 3.0], [2.0, 2.0]])) - 1000.0
    assert np.allclose(tp.stroke_evidence(ll), np.log([2.0, 2.0]) - 1000.0)


def test_eig_pairwise_limits():
    sd = np.ones(3)
    far = np.array([[0.0, 0, 0], [1e3, 0, 0]])
    assert eig_pairwise([0.5, 0.5], far, sd) == pytest.approx(np.log(2), abs=1e-9)  # fully separable: H(k)
    assert eig_pairwise([0.5, 0.5], np.zeros((2, 3)), sd) == pytest.approx(0.0, abs=1e-12)  # identical
    assert eig_pairwise([1.0, 0.0], far, sd) == pytest.approx(0.0, abs=1e-12)  # already certain
    p = [0.2, 0.3, 0.5]
    near = np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]])
    v = eig_pairwise(p, near, sd)
    assert 0 < v < -np.sum(np.array(p) * np.log(p))


def test_wilson_interval_closed_forms():
    """0 of 10: (0, z²/(n + z²)) = (0, 0.2775); k ↔ n − k mirrors the interval; n = 0 has none."""
    lo, hi = wilson_interval(0, 10)
    assert lo == pytest.approx(0.0, abs=1e-12) and hi == pytest.approx(
        1.959963984540054**2 / (10 + 1.959963984540054**2)
    )
    assert hi == pytest.approx(0.2775, abs=1e-4)
    lo7, hi7 = wilson_interval(7, 20)
    lo13, hi13 = wilson_interval(13, 20)
    assert lo7 == pytest.approx(1 - hi13) and hi7 == pytest.approx(1 - lo13)
    assert all(np.isnan(wilson_interval(0, 0)))


@pytest.mark.slow
def test_small_experiment_identifies(tmp_path):
    """5 textures × 3 trials, seed 0: every trial decides, and at most one is wrong (the 0.95 threshold allows an
    expected 0.75 wrong decisions in 15 if the posterior is calibrated)."""
    s = ti.run_experiment(tmp_path, textures=5, trials=3, max_strokes=6, seed=0, progress=False)
    assert s["trials"] == 15
    assert s["decided_fraction"] == 1.0
    assert s["accuracy_at_decision"] >= 14 / 15
    assert s["median_strokes_to_decision"] <= 5
    rows = (tmp_path / "results.csv").read_text().splitlines()
    assert rows[0].split(",")[:7] == list(ti.COLUMNS[:7])
    assert json.loads((tmp_path / "summary.json").read_text())["trials"] == 15
    assert (tmp_path / "accuracy_vs_strokes.png").stat().st_size > 1000


def test_cli_bad_input(tmp_path, capsys):
    assert cli_main(["texture-id", "--textures", "99", "--trials", "1", "--out", str(tmp_path)]) == 2
    assert "--textures" in capsys.readouterr().err
    afile = tmp_path / "a_file"
    afile.write_text("x")
    assert cli_main(["texture-id", "--trials", "1", "--out", str(afile)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--out" in err and "not a folder" in err


def test_identifier_never_reads_the_simulated_gains(lib):
    """No inverse crime: the same strokes over one texture by two simulated fingers whose fixed-pattern gains differ
    (seeds 0 and 1), read as a host reads them (unit gains, each taxel's offset marginalised): the evidence for every
    texture agrees to a fraction of a nat, and the truth wins. Negative control: the same readings scored with the
    unit gains taken as exact (no offsets marginalised) move the evidence by hundreds of nats between the two fingers
    and pick a wrong texture."""
    small = lib.subset(5)
    surfs = small.surfaces()
    st = ti.IdSettings(shift_range=0.0, temperature_sd=0.0)
    host = host_device()
    evidence, exact = [], []
    for finger_seed in (0, 1):
        vf_s = load_finger(seed=finger_seed)
        rng = np.random.default_rng(5)
        spec = tx.random_stroke_spec(small.base, rng)
        data, tangent, _ = ti.record_stroke(small.object(3), spec, vf_s, rng, st, host)
        ll = tp.texture_log_likelihood(surfs, data, host.finger, st.shifts(), tangent)
        evidence.append(tp.stroke_evidence(ll))
        ll0 = tp.texture_log_likelihood(surfs, data._replace(gain_sd=None), host.finger, st.shifts(), tangent)
        exact.append(tp.stroke_evidence(ll0))
    e0, e1 = (e - e.max() for e in evidence)
    assert np.argmax(e0) == 3 and np.argmax(e1) == 3
    assert np.max(np.abs(e0 - e1)) < 0.5 * np.sort(-e0)[1]  # the runner-up's gap dwarfs what the gains move
    x0, x1 = (e - e.max() for e in exact)
    assert np.max(np.abs(x0 - x1)) > 100.0
    assert np.argmax(x0) != 3 or np.argmax(x1) != 3


def test_tight_device_file_survives_a_skin_temperature_error(lib):
    """Issue 24: a correct device file (the simulated finger's own gains, sd 2e-4) and a per-stroke skin-temperature
    reading error ~ N(0, 1 K²). The de-meaned reference row leaves that error in every taxel as one common offset
    (0.065 per kelvin, against gains the file pins to 2e-4), so it must be marginalised: the truth then wins each
    of five strokes over five textures. Negative control: the same readings with the common offset taken as known
    (``common_offset_sd=None``, the identifier before this fix) pick a wrong texture in most strokes — while with no
    temperature error both agree on the truth (the marginalisation costs no decision when there is nothing to
    take out)."""
    small = lib.subset(5)
    surfs = small.surfaces()
    vf = load_finger(seed=3)
    log_gain = np.log(np.asarray(vf.finger.gains).ravel())
    tight = HostDevice(vf.finger, np.full(log_gain.size, 2e-4), 1.0, 2e-3)
    for temperature_sd in (1.0, 0.0):
        st = ti.IdSettings(shift_range=0.0, temperature_sd=temperature_sd)
        wins, old_wins = 0, 0
        for k in range(5):
            rng = np.random.default_rng(7 + k)
            spec = tx.random_stroke_spec(small.base, rng)
            data, tangent, _ = ti.record_stroke(small.object(k), spec, vf, rng, st, tight)
            data = data._replace(response_sd=None)  # the response known: the common offset alone is tried here
            ll = tp.texture_log_likelihood(surfs, data, tight.finger, st.shifts(), tangent)
            old = tp.texture_log_likelihood(surfs, data, tight.finger, st.shifts(), tangent, common_offset_sd=None)
            wins += int(np.argmax(tp.stroke_evidence(ll)) == k)
            old_wins += int(np.argmax(tp.stroke_evidence(old)) == k)
        assert wins == 5
        assert old_wins <= (1 if temperature_sd > 0 else 5) and (temperature_sd > 0 or old_wins == 5)


def test_large_library_file_is_the_generator_output():
    """``models/textures_large.toml`` is what :func:`generate_library` gives (a file edited by hand, or a generator
    changed without rewriting the file, fails), with ≥ 100 textures, the twins alike to a few per cent in one
    property."""
    doc = tomllib.loads(tx.LARGE_LIBRARY.read_text())
    gen = tx.generate_library()
    assert doc["texture"] == gen["texture"] and doc["library"] == gen["library"] and doc["object"] == gen["object"]
    lib = tx.load_library(tx.LARGE_LIBRARY)
    assert len(lib) == 120
    by = dict(zip(lib.names, lib.specs, strict=True))
    twins = [n for n in lib.names if "_twin" in n]
    assert len(twins) == 20
    for n in twins:
        a, b = by[n.split("_twin")[0]], by[n]
        changed = [f for f in ("amplitude", "wavelength", "orientation", "roughness") if getattr(a, f) != getattr(b, f)]
        assert len(changed) == 1
        f = changed[0]
        if f == "orientation":
            d = np.mod(a.orientation - b.orientation, np.pi)
            assert np.deg2rad(4.9) < min(d, np.pi - d) < np.deg2rad(15.1)
        else:
            assert 0.029 < abs(getattr(b, f) / getattr(a, f) - 1.0) < 0.201


def test_refined_shift_evidence_matches_a_fine_grid(lib):
    """Two textures 5.7 % apart in grating amplitude (a twin of the large library), one stroke over the twin.
    The likelihood in the start-phase shift is a peak ~5 µm wide, so the 25 µm grid's evidence ratio is off by
    nats; :func:`texture_evidence` refines around the peaks and must agree with the integral on a 2.5 µm grid over
    the whole range to 0.05 nats. Negative control: the 25 µm grid alone misses it by more than 2 nats."""
    big = tx.load_library(tx.LARGE_LIBRARY)
    i, j = big.names.index("t093_grating"), big.names.index("t093_grating_twin19_size")
    pair = tx.TextureLibrary((big.names[i], big.names[j]), (big.specs[i], big.specs[j]), big.base)
    surfs = pair.surfaces()
    host = host_device()
    st = ti.IdSettings()
    rng = np.random.default_rng(0)
    spec = tx.random_stroke_spec(pair.base, rng)
    data, tangent, _ = ti.record_stroke(pair.object(1), spec, load_finger(seed=0), rng, st, host)
    data = data._replace(response_sd=CALIBRATED_RESPONSE_SD)  # twins in amplitude need the response calibrated
    coarse = st.shifts()
    h = coarse[1] - coarse[0]
    fine = coarse[0] - h / 2 + (np.arange(10 * coarse.size) + 0.5) * h / 10
    reference = tp.stroke_evidence(tp.texture_log_likelihood(surfs, data, host.finger, fine, tangent))
    refined = tp.texture_evidence(surfs, data, host.finger, coarse, tangent)
    grid = tp.stroke_evidence(tp.texture_log_likelihood(surfs, data, host.finger, coarse, tangent))
    ratio = reference[1] - reference[0]
    assert ratio > 10.0  # the twin is the truth and the stroke says so
    assert abs((refined[1] - refined[0]) - ratio) < 0.05
    assert abs((grid[1] - grid[0]) - ratio) > 2.0


@pytest.mark.slow
def test_evidence_ratio_of_close_twins_is_calibrated():
    """One stroke over a texture and its twin 5.7 % lower in grating amplitude, 48 noise draws (a skin-temperature
    error on, gains unknown). For a calibrated likelihood the log evidence ratio L = log p(s | truth) −
    log p(s | twin) has var L ≈ 2 mean L (exact for Gaussian readings and nuisances that enter linearly:
    L ~ N(D/2, D); the start phase does not, so it is held at zero here). Over 48 draws the sample variance has
    relative sd √(2/47) ≈ 0.21, so var/(2 mean) ∈ (0.55, 1.6) is a band of about ±2.5 sd around 1 (measured
    0.84; the Student-t on Gaussian readings alone gives 0.85); evidence 1.6× too large (a posterior ~20 % too
    narrow in sd) falls outside it. Negative control: the reference row's per-frame error counted as independent
    noise in every taxel (``frame_common=False``, the identifier before it was modelled) gives 4.1 on the same
    draws. The response is taken as calibrated (sd 2e-3), as twins in amplitude need."""
    big = tx.load_library(tx.LARGE_LIBRARY)
    i, j = big.names.index("t093_grating"), big.names.index("t093_grating_twin19_size")
    pair = tx.TextureLibrary((big.names[i], big.names[j]), (big.specs[i], big.specs[j]), big.base)
    surfs = pair.surfaces()
    vf, host, st = load_finger(seed=0), host_device(), ti.IdSettings(shift_range=0.0)
    spec = tx.random_stroke_spec(pair.base, np.random.default_rng(11), speed=st.speed, depth=st.depth)
    ratios = {True: [], False: []}
    for rep in range(48):
        data, tangent, _ = ti.record_stroke(pair.object(1), spec, vf, np.random.default_rng(2000 + rep), st, host)
        data = data._replace(response_sd=CALIBRATED_RESPONSE_SD)  # twins in amplitude need the response calibrated
        for frame_common in ratios:
            ev = tp.texture_evidence(surfs, data, host.finger, st.shifts(), tangent, frame_common=frame_common)
            ratios[frame_common].append(ev[1] - ev[0])
    new, old = np.asarray(ratios[True]), np.asarray(ratios[False])
    assert new.mean() > 10.0
    assert 0.55 < new.var(ddof=1) / (2 * new.mean()) < 1.6
    assert old.var(ddof=1) / (2 * old.mean()) > 2.5


def test_finger_models_of_another_layout_are_refused(tmp_path):
    """Issue 24, tenth review: ``texture-id --finger-models`` with another taxel count ended in an exit 1 while the
    recording was assembled. Refused in one line before any trial, the output folder not made."""
    import re
    import shutil

    from bayestouch.params import MODELS

    models = tmp_path / "models"
    shutil.copytree(MODELS, models)
    text = (models / "taxels.toml").read_text()
    (models / "taxels.toml").write_text(
        re.sub(r"(?m)^rows = .*$", 'rows = { value = 20, unit = "1", source = "test" }', text)
    )
    with pytest.raises(
        BadInput, match=r"--finger-models .*a finger of 20×16 taxels; the identifier's \(models/\) has 16×16"
    ):
        ti.run_experiment(tmp_path / "out", textures=2, trials=1, max_strokes=1, progress=False, finger_models=models)
    assert not (tmp_path / "out").exists()


def _interrupt_after(monkeypatch, n: int):
    """Make ``run_trial`` raise KeyboardInterrupt (Ctrl-C, or SIGTERM/SIGHUP in the CLI) at its call ``n + 1``."""
    real, calls = ti.run_trial, []

    def trial(*a, **k):
        calls.append(1)
        if len(calls) > n:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(ti, "run_trial", trial)
    return calls


def _rows(path):
    from bayestouch.io.files import read_csv_rows

    return {(r["texture"], r["trial"], r["stroke"]): (r["p_true"], r["map"]) for r in read_csv_rows(path)}


def test_interrupted_run_resumes_to_the_uninterrupted_result(tmp_path, monkeypatch, capsys):
    """Issue 24, tenth review: an interrupted texture-id left results.csv that the next run called "a finished
    result", and there was no ``--resume``. Now the interruption says how many trials finished, a plain rerun names
    the folder an interrupted run, and ``--resume`` runs only the missing trials: the rows then equal an
    uninterrupted run's (each trial's randomness is its seed, texture and trial)."""
    argv = ["texture-id", "--textures", "2", "--trials", "2", "--max-strokes", "1", "--quiet"]
    assert cli_main([*argv, "--out", str(tmp_path / "whole")]) == 0
    calls = _interrupt_after(monkeypatch, 2)
    assert cli_main([*argv, "--out", str(tmp_path / "cut")]) == 130
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "2 finished trial(s)" in err and "--resume" in err
    assert not (tmp_path / "cut" / "summary.json").exists()
    assert cli_main([*argv, "--out", str(tmp_path / "cut")]) == 2
    assert "interrupted run" in capsys.readouterr().err
    monkeypatch.undo()
    calls = _interrupt_after(monkeypatch, 99)
    assert cli_main([*argv, "--out", str(tmp_path / "cut"), "--resume"]) == 0
    assert len(calls) == 2  # only the two missing trials ran
    assert _rows(tmp_path / "cut" / "results.csv") == _rows(tmp_path / "whole" / "results.csv")
    summary = json.loads((tmp_path / "cut" / "summary.json").read_text())
    assert summary["trials"] == 4 and summary["trials_kept"] == 2


def test_resume_refuses_other_settings_and_other_commands(tmp_path, capsys):
    """A resume keeps trials only of the same run: another seed, another library file or a folder of another
    command is refused in one line, and nothing in the folder changes."""
    import shutil

    lib = tmp_path / "lib.toml"
    shutil.copy(tx.LIBRARY, lib)
    out = tmp_path / "run"
    argv = ["texture-id", "--textures", "2", "--trials", "1", "--max-strokes", "1", "--quiet", "--out", str(out)]
    assert cli_main([*argv, "--library", str(lib)]) == 0
    before = (out / "results.csv").read_bytes()
    assert cli_main([*argv, "--library", str(lib), "--resume", "--seed", "3"]) == 2
    assert "--seed 0 (now 3)" in capsys.readouterr().err
    lib.write_text(lib.read_text().replace("seed = ", "seed = 1", 1))
    assert cli_main([*argv, "--library", str(lib), "--resume"]) == 2
    assert "other --library file" in capsys.readouterr().err
    assert (out / "results.csv").read_bytes() == before
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "chain.h5").write_bytes(b"x")
    assert cli_main([*argv[:-1], str(tmp_path / "fit"), "--resume"]) == 2
    assert "results of another command (chain.h5)" in capsys.readouterr().err
    assert cli_main([*argv, "--library", str(lib), "--resume", "--overwrite"]) == 2
    assert "exclude each other" in capsys.readouterr().err


def _twin_pair(name: str):
    """The library of one texture of models/textures_large.toml and its amplitude twin."""
    doc = tomllib.loads((tx.LIBRARY.parent / "textures_large.toml").read_text())
    by_name = {t["name"]: t for t in doc["texture"]}
    twin = next(t for t in doc["texture"] if t["name"].startswith(name + "_twin") and t["name"].endswith("_size"))
    return tx.library_from_dict({**doc, "texture": [by_name[name], twin]})


def _finger_with_lag(tmp_path, lag: float):
    import re
    import shutil

    from bayestouch.params import MODELS

    models = tmp_path / "models"
    shutil.copytree(MODELS, models)
    text = (models / "taxels.toml").read_text()
    (models / "taxels.toml").write_text(re.sub(r"(?m)^(lag = \{ value = )[^,]+", rf"\g<1>{lag!r}", text))
    return load_finger(models, seed=5)


def test_lag_grid_of_one_nominal_lag_is_the_plain_evidence(lib, vf):
    """texture_evidence with lags whose row is the data's own lag gives that row's evidence as without lags, to the
    quadrature's own error (the refined shift cells are those of the best lag at each shift, so they may differ by
    a cell from the single lag's: measured ≤ 2e-3 nats)."""
    from bayestouch.physics import taxel

    s = ti.IdSettings()
    dev = host_device()
    rng = np.random.default_rng(4)
    spec = tx.random_stroke_spec(lib.base, rng, speed=s.speed, depth=s.depth)
    small = lib.subset(4)
    data, tangent, _ = ti.record_stroke(small.object(2), spec, vf, rng, s, dev)
    plain = tp.texture_evidence(small.surfaces(), data, dev.finger, s.shifts(), tangent)
    lags = np.stack([taxel.coarse_lag_weights(float(data.dt), t, 1) for t in (0.11, float(dev.finger.taxels.lag))])
    grid = tp.texture_evidence(small.surfaces(), data, dev.finger, s.shifts(), tangent, lags=lags)
    assert grid.shape == (4, 2)
    np.testing.assert_allclose(grid[:, 1], plain, rtol=0, atol=1e-2)
    assert np.max(np.abs(grid[:, 0] - plain)) > 1.0  # another lag is another likelihood


def test_unknown_lag_is_marginalised_not_mistaken_for_amplitude(tmp_path):
    """Issue 21: the taxels' response lag is not calibrated, and a first-order lag attenuates a grating's signal as
    an amplitude does. On a finger of lag 0.10 s (the identifier's models/ say 0.15 s) stroking two textures 8 %
    apart in amplitude, without noise: with the lag taken as known the wrong twin wins by tens of nats; with the
    lags of the prior's range marginalised the truth wins, at the true lag, for either texture as the truth."""
    from bayestouch.physics import taxel

    pair = _twin_pair("t076_grating")
    finger = _finger_with_lag(tmp_path, 0.10)
    s = ti.IdSettings(noise=False)
    dev = host_device()
    spec = tx.random_stroke_spec(pair.base, np.random.default_rng(1), speed=0.01, depth=3e-4)
    nominal_wrong = 0
    for truth in (0, 1):
        data, tangent, _ = ti.record_stroke(pair.object(truth), spec, finger, np.random.default_rng(2), s, dev)
        known = tp.texture_evidence(pair.surfaces(), data, dev.finger, s.shifts(), tangent)
        nominal_wrong += int(np.argmax(known) != truth)
        lags = np.stack([taxel.coarse_lag_weights(float(data.dt), t, 1) for t in (0.10, 0.125, 0.15)])
        joint = tp.texture_evidence(pair.surfaces(), data, dev.finger, s.shifts(), tangent, lags=lags)
        k, lag = np.unravel_index(np.argmax(joint), joint.shape)
        assert (k, lag) == (truth, 0)
        assert joint[truth].max() - joint[1 - truth].max() > 5.0
    assert nominal_wrong >= 1  # the control: the lag taken as known decides for the twin


def test_resume_keeps_only_trials_of_the_same_candidates_and_whole(tmp_path, capsys):
    """Issue 24, eleventh review: a resume with another --textures kept rows whose posterior was over another set of
    candidates (the count was not in the key); a resume with fewer --trials replaced a finished summary with a
    subset's; damaged rows (flags 5 and 7, a trial cut short) were kept and gave an accuracy of 1.5. Each is refused
    in one line, the folder unchanged; the same resume with more --trials runs (the control)."""
    out = tmp_path / "run"
    argv = ["texture-id", "--max-strokes", "2", "--quiet", "--out", str(out)]
    assert cli_main([*argv, "--textures", "3", "--trials", "2"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for extra, needle in (
        (["--textures", "4", "--trials", "2"], "--textures 3 (now 4)"),
        (["--textures", "3", "--trials", "1"], "holds 2 trials per texture, more than --trials 1"),
        (["--textures", "3", "--trials", "2", "--full"], "--full False (now True)"),
        (["--textures", "3", "--trials", "2", "--threshold", "0.9"], "--threshold 0.95 (now 0.9)"),
    ):
        assert cli_main([*argv, *extra, "--resume"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and needle in err, err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    text = (out / "results.csv").read_text().splitlines()
    first = text[1].split(",")
    for damage, needle in (
        ({4: "5"}, "map_correct and decided must be 0 or 1"),
        ({5: "0"}, "ends at stroke 1, neither at its decision"),
        ({7: "not_the_map"}, "map_correct 1 but map is 'not_the_map'"),
    ):
        row = list(first)
        for i, v in damage.items():
            row[i] = v
        (out / "results.csv").write_text("\n".join([text[0], ",".join(row), *text[2:]]) + "\n")
        assert cli_main([*argv, "--textures", "3", "--trials", "2", "--resume"]) == 2
        assert needle in capsys.readouterr().err
    (out / "results.csv").write_text("\n".join(text) + "\n")
    assert cli_main([*argv, "--textures", "3", "--trials", "3", "--resume"]) == 0
    assert json.loads((out / "summary.json").read_text())["trials"] == 9
