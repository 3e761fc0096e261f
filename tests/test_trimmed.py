"""Trimmed starts for heavily contaminated contacts (bayestouch.inference.trimmed): the screening ranks displaced
contacts last, and the concentration steps end on the undisplaced ones."""

from __future__ import annotations

import numpy as np
import pytest

from bayestouch.inference import trimmed as tr

R = 0.02  # sphere radius, metres


def _sphere_set(seed, count=120, displaced=0.4, noise=1e-5):
    """Contacts on a one-sided cap of a sphere of radius R at the origin, a fraction displaced 2-8 mm along the
    normal (either side)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(count, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u[:, 2] = np.abs(u[:, 2]) + 0.3  # one side
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    bad = rng.permutation(count) < round(displaced * count)
    shift = np.where(bad, rng.choice([-1.0, 1.0], count) * rng.uniform(2e-3, 8e-3, count), 0.0)
    pts = u * (R + shift)[:, None] + rng.normal(0.0, noise, (count, 3))
    return pts, bad


def _sphere_fit(sub, step):
    """Algebraic least-squares sphere as a θ of the contact model (n = 2)."""
    a = np.column_stack([2 * sub, np.ones(len(sub))])
    sol = np.linalg.lstsq(a, np.sum(sub * sub, axis=1), rcond=None)[0]
    c = sol[:3]
    r = np.sqrt(sol[3] + c @ c)
    return np.concatenate([c, np.log([r, r, r]), [0.0, 0.0, 0.0], [np.log(2.0)]])


def test_displaced_contacts_score_highest():
    pts, bad = _sphere_set(0, displaced=0.15)
    score = tr.local_plane_scores(pts)
    assert score.shape == (len(pts),)
    worst = np.argsort(score)[-bad.sum() :]
    # the screening is a local test: most, not all, displaced contacts rank among the worst
    assert np.mean(bad[worst]) >= 0.8
    assert np.median(score[~bad]) < 1e-3 < np.median(score[bad])  # curvature over the spacing: ~0.3 mm


def test_concentration_steps_end_on_the_undisplaced_contacts():
    pts, bad = _sphere_set(1)
    seen = []

    def fit(sub, step):
        seen.append({tuple(p) for p in sub})
        return _sphere_fit(sub, step)

    thetas = tr.trimmed_starts(pts, fit)
    assert len(thetas) == tr.STEPS
    clean = {tuple(p) for p in pts[~bad]}
    assert seen[-1] <= clean  # the last fit used undisplaced contacts only
    assert abs(np.exp(thetas[-1][3]) - R) < 2e-5 and np.linalg.norm(thetas[-1][:3]) < 2e-5
    # negative control: the same fit on every contact is pulled off by the displaced ones
    off = _sphere_fit(pts, 0)
    assert abs(np.exp(off[3]) - R) > 1e-4 or np.linalg.norm(off[:3]) > 1e-4


def test_too_few_contacts_give_no_starts_and_bad_arguments_are_refused():
    pts, _ = _sphere_set(2, count=30)
    assert tr.trimmed_starts(pts, _sphere_fit) == []  # 15 kept < MIN_KEPT
    with pytest.raises(ValueError, match="keep"):
        tr.trimmed_starts(pts, _sphere_fit, keep=0.0)
    with pytest.raises(ValueError, match="points"):
        tr.local_plane_scores(pts[:5])


def test_the_trigger_reads_the_outlier_fractions_of_the_particles():
    from bayestouch.inference.contact import param_names
    from bayestouch.inference.run import TRIM_TRIGGER, contaminated_share

    names = param_names(noise="outlier")
    rng = np.random.default_rng(3)
    particles = rng.normal(size=(500, len(names)))
    w = [names.index("w_in"), names.index("w_out")]
    particles[:, w] = rng.uniform(0.0, 0.2, (500, 2))  # mean sum 0.2
    assert abs(contaminated_share(particles, names) - 0.2) < 0.01
    particles[:, w] *= 0.5
    assert contaminated_share(particles, names) < TRIM_TRIGGER
    assert contaminated_share(particles[:, :11], param_names()) == 0.0  # no outlier model, no trimmed starts
