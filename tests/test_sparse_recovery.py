"""Sparse tactile data (issue 4): the data generator, the superquadric conversions used to compare with the peer
``sage-superquadric``, and shape recovery by the contact-level posterior (benchmarks/bench_sparse.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayestouch.backend import jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.integrals import surface_integrals
from benchmarks import bench_sparse as bs


def _shape(n, axes=(0.03, 0.02, 0.015), angles=(0.7, 0.4, -1.1), centre=(0.01, -0.02, 0.005)):
    return ne.NEllipsoid(jnp.asarray(centre), jnp.asarray(axes), jnp.asarray(angles), jnp.asarray(float(n)))


def _as_sage(s: ne.NEllipsoid) -> dict:
    """The n-ellipsoid as a superquadric in sage-superquadric's parametrisation (ε1 = ε2 = 2/n)."""
    from scipy.spatial.transform import Rotation

    yaw, pitch, roll = Rotation.from_matrix(np.asarray(s.rotation)).as_euler("zyx")
    a = np.asarray(s.axes)
    c = np.asarray(s.centre)
    e = 2.0 / float(s.n)
    return {
        "a1": a[0],
        "a2": a[1],
        "a3": a[2],
        "eps1": e,
        "eps2": e,
        "cx": c[0],
        "cy": c[1],
        "cz": c[2],
        "roll": roll,
        "pitch": pitch,
        "yaw": yaw,
    }


@pytest.mark.parametrize("n", [2.0, 2.7, 4.0, 8.0])
def test_superquadric_volume_is_the_nellipsoid_volume_when_eps1_eq_eps2(n):
    s = _shape(n)
    a = np.asarray(s.axes)
    assert bs.superquadric_volume(*a, 2 / n, 2 / n) == pytest.approx(float(ne.volume(s)), rel=1e-12)


def test_superquadric_volume_ellipsoid_and_general_exponents():
    assert bs.superquadric_volume(0.03, 0.02, 0.01, 1.0, 1.0) == pytest.approx(4 / 3 * math.pi * 6e-6, rel=1e-12)
    # ε1 ≠ ε2: the closed form against the divergence-theorem volume of a fine mesh (inscribed: slightly less)
    p = {
        "a1": 0.03,
        "a2": 0.02,
        "a3": 0.01,
        "eps1": 0.4,
        "eps2": 1.3,
        "cx": 0.0,
        "cy": 0.0,
        "cz": 0.0,
        "roll": 0.3,
        "pitch": -0.2,
        "yaw": 1.0,
    }
    v_mesh = surface_integrals(*bs.superquadric_mesh(p, res=64)).volume
    v = bs.superquadric_volume(0.03, 0.02, 0.01, 0.4, 1.3)
    assert 0 < 1 - v_mesh / v < 2e-3
    # negative control: swapping the exponents is a different solid, with a clearly different volume
    assert abs(bs.superquadric_volume(0.03, 0.02, 0.01, 1.3, 0.4) / v - 1) > 0.05


def test_superquadric_mesh_lies_on_the_nellipsoid_in_sage_pose_convention():
    s = _shape(3.0)
    v, f = bs.superquadric_mesh(_as_sage(s), res=24)
    F = ne.evaluate(ne.inside_outside, s, v)
    np.testing.assert_allclose(F, 1.0, atol=1e-9)
    # negative control: the other pose convention (world = centre + Rᵀ local) puts the mesh off the surface
    from scipy.spatial.transform import Rotation

    p = _as_sage(s)
    p["yaw"], p["pitch"], p["roll"] = Rotation.from_matrix(np.asarray(s.rotation).T).as_euler("zyx")
    assert np.max(np.abs(ne.evaluate(ne.inside_outside, s, bs.superquadric_mesh(p, res=24)[0]) - 1)) > 0.1


def test_sparse_set_generator_facts():
    for seed in range(6):
        d = bs.make_sparse_set(seed, outliers=seed % 2 == 1)
        m = len(d.points)
        assert 35 <= m <= 100 and 2 <= d.strokes <= 5
        assert 0 < d.coverage <= (1 - math.cos(math.radians(bs.CAP_DEG))) / 2 + 1e-12
        a = np.asarray(d.truth.axes)
        assert np.all((a >= 0.015) & (a <= 0.05)) and 2 <= float(d.truth.n) <= 5
        dist = np.abs(ne.evaluate(bs.distance_to_surface, d.truth, d.points))
        good = dist[~d.outlier]
        # 0.3 mm isotropic noise: the distance along the normal is |N(0, 0.3 mm)| to first order, so the RMS is
        # 0.3 mm within sampling error (≈ 0.3/√(2·30) ≈ 13 %, a 25 % band is ≈ 2 standard errors)
        assert 0.75 * bs.NOISE_M < np.sqrt(np.mean(good**2)) < 1.25 * bs.NOISE_M
        if seed % 2:
            assert d.outlier.sum() == round(bs.OUTLIER_FRACTION * m)
            # outliers are 1–10 mm away (random directions may be partly tangential: at least ~0.1 mm off)
            assert np.median(dist[d.outlier]) > 1e-3 and np.max(dist[d.outlier]) < 1.1e-2
        else:
            assert not d.outlier.any()
    a, b = bs.make_sparse_set(7), bs.make_sparse_set(7)
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.allclose(bs.make_sparse_set(8).points[:35], a.points[:35])


def test_sparse_set_cap_controls_coverage_and_wraps_round_the_object():
    """The cap parameter does what it says: it bounds the coverage, coverage grows with it, the shapes do not depend
    on it, and at 180° the strokes reach round to the far side, while under 90° they cannot."""
    from scipy.spatial import Delaunay

    from bayestouch.errors import BadInput

    caps = (80.0, 100.0, 140.0, 180.0)
    seeds = range(12)
    sets = {c: [bs.make_sparse_set(s, cap_deg=c) for s in seeds] for c in caps}
    for c in caps:
        # every direction lies within the cap: coverage ≤ (1 − cos cap)/2 (noise does not enter the coverage)
        assert all(0 < d.coverage <= (1 - math.cos(math.radians(c))) / 2 + 1e-12 for d in sets[c])
    med = [np.median([d.coverage for d in sets[c]]) for c in caps]
    assert np.all(np.diff(med) > 0.05), med
    # paired data: the same true shape and number of points at every cap, different points
    a, b = sets[100.0][3], sets[180.0][3]
    np.testing.assert_array_equal(np.asarray(a.truth.axes), np.asarray(b.truth.axes))
    assert len(a.points) == len(b.points) and not np.allclose(a.points, b.points)
    # the default cap is CAP_DEG (the existing sets unchanged)
    np.testing.assert_array_equal(bs.make_sparse_set(5).points, bs.make_sparse_set(5, cap_deg=bs.CAP_DEG).points)

    def surrounds_centre(d):
        # the true centre inside the convex hull of the points: data on both sides of every plane through it
        return Delaunay(d.points).find_simplex(np.asarray(d.truth.centre)) >= 0

    # cap 180°: directions beyond 90° from the approach direction in every set (measured: coverage ≥ 0.55 over 40
    # seeds), and most sets hold the centre inside their hull (measured 8 of 12)
    assert all(d.coverage > 0.5 for d in sets[180.0])
    assert sum(surrounds_centre(d) for d in sets[180.0]) >= len(seeds) // 2
    # negative control: under 90° every point lies in the open half-space in front of the centre (the cap's rim is
    # ≥ 15 mm × sin 10° ≈ 2.6 mm off the plane, ≫ the 0.3 mm noise), so no hull can hold the centre
    assert not any(surrounds_centre(d) for d in sets[80.0])
    for bad in (0.0, -10.0, 181.0, float("nan")):
        with pytest.raises(BadInput, match="cap_deg"):
            bs.make_sparse_set(0, cap_deg=bad)


def test_bench_caps_from_argument_and_environment(monkeypatch):
    from bayestouch.errors import BadInput

    monkeypatch.delenv("BAYESTOUCH_SPARSE_CAP", raising=False)
    assert bs._caps(None) == bs.BENCH_CAPS == (bs.CALIBRATED_CAP_DEG, bs.CAP_DEG)
    assert bs._caps(140) == (140.0,) and bs._caps([180, 100]) == (180.0, 100.0)
    monkeypatch.setenv("BAYESTOUCH_SPARSE_CAP", "160, 120")
    assert bs._caps(None) == (160.0, 120.0)
    assert bs._caps(100) == (100.0,)  # the argument wins over the environment
    for bad in ("wide", "0", "100,200"):
        monkeypatch.setenv("BAYESTOUCH_SPARSE_CAP", bad)
        with pytest.raises(BadInput, match="CAP|cap_deg"):
            bs._caps(None)


#: emcee steps per fit in the slow test (32 walkers, about 15–20 autocorrelation times; burn-in discarded)
STEPS = 1000
#: (seed, outliers) of the slow test's sets: 100 points on 5 strokes each, the richest data issue 4 describes. The
#: thresholds are the issue's targets, not Monte-Carlo tolerances; on sparser sets (2–3 strokes) the posterior's own
#: 90 % interval of the volume spans ±30–60 %, and the benchmark (benchmarks/bench_sparse.py) reports how often they
#: are met there
SETS = ((101, False), (102, False), (103, True))


def _map_fit(points, theta0, nu):
    """Maximum of the contact-level log-posterior with Student-t ν (inf: Gaussian) by L-BFGS-B from θ0."""
    from scipy.optimize import minimize

    from bayestouch.backend import jax
    from bayestouch.inference import contact as cm

    _, bounds = cm.make_log_prob(points, nu=nu)
    pts = jnp.asarray(points)
    vg = jax.jit(jax.value_and_grad(lambda t: -cm.log_prob(t, pts, bounds, nu)))
    lo, hi = np.asarray(bounds.lower), np.asarray(bounds.upper)

    def fg(t):
        v, g = vg(jnp.asarray(t))
        return float(v), np.asarray(g)

    res = minimize(fg, np.clip(theta0, lo, hi), jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi, strict=True)))
    return cm.shape_of(res.x)


@pytest.mark.slow
def test_sparse_posterior_holds_the_truth_and_robust_likelihood_beats_gaussian_on_outliers():
    """Sparse sets (100 points on 5 strokes over part of the object, one with 15 % outliers): every posterior's
    volume interval holds the true volume, and the point estimates stay within a regression guard.

    These are one-sided sets (the 100° cap), on which the issue's targets (median volume error ≤ 4 %, Chamfer ≤ 0.03
    of the mean semi-axis) are not expected: with strokes over one side of the object the posterior is honestly
    wide, and its median draw can be several per cent off. The benchmark (benchmarks/bench_sparse.py) reports the
    medians over more sets, at this cap and at the calibrated 180° cap, beside sage-superquadric's.
    """
    from bayestouch.geometry.symmetry import canonicalize_batch
    from bayestouch.inference import contact as cm

    errs = []
    for seed, outliers in SETS:
        d = bs.make_sparse_set(seed, outliers=outliers, n_points=100, strokes=5)
        fit = bs.fit_bayestouch(d.points, seed=seed, steps=STEPS)
        errs.append(bs.shape_errors(fit["median_volume"], fit["volume_median"], d.truth))
        vols = np.array([float(ne.volume(ne.from_vector(jnp.asarray(v)))) for v in fit["draws"][::10]])
        lo, hi = np.quantile(vols, [0.005, 0.995])  # 99 %: a calibrated posterior fails one of 3 sets w.p. 3 %
        assert lo <= float(ne.volume(d.truth)) <= hi, (seed, lo, hi, float(ne.volume(d.truth)))
    vol = np.median([e["volume_error"] for e in errs])
    ch = np.median([e["chamfer_ratio"] for e in errs])
    # negative control on the outlier set: the same optimiser from the same start, Student-t (the model's ν) against
    # a Gaussian likelihood, which the outliers (15 %, 1–10 mm ≫ 0.3 mm noise) drag off the surface. The start is
    # the truth itself (canonicalised into the prior box: the same surface), so that the control tests the
    # likelihoods and not the initialiser (from initial_theta's start the margin depends on how good that start is)
    d = bs.make_sparse_set(SETS[-1][0], outliers=True, n_points=100, strokes=5)
    priors = cm.load_priors()
    v = canonicalize_batch(np.asarray(ne.to_vector(d.truth))[None])[0]
    theta0 = np.concatenate([v[:3], np.log(v[3:6]), v[6:9], [np.log(v[9])], [np.log(bs.NOISE_M)]])
    robust, gauss = (_map_fit(d.points, theta0, nu) for nu in (float(priors.student_nu), np.inf))
    e_r, e_g = (bs.shape_errors(s, float(ne.volume(s)), d.truth) for s in (robust, gauss))
    # regression guard at about 2× the measured medians (a broken initialiser gave volume errors of 2.7 here)
    assert vol <= 0.1 and ch <= 0.1, (vol, ch)
    # measured under the box prior: Gaussian 62 volume error and 4.6 Chamfer ratio (it ran off) against Student-t's
    # 0.016 and 0.069; the size prior (models/priors.toml) now holds the Gaussian fit to plausible sizes, and it
    # lands at 0.052 and 0.084 against 0.015 and 0.069: still worse on both
    assert e_g["volume_error"] > 2 * e_r["volume_error"], (e_g, e_r)
    assert e_g["chamfer_ratio"] > 1.15 * e_r["chamfer_ratio"], (e_g, e_r)
