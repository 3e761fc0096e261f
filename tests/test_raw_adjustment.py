"""The curvature adjustment's map of raw-level draws (bayestouch.inference.raw.adjustment) and its prior box."""

import numpy as np
import pytest

from bayestouch.backend import jnp
from bayestouch.inference import contact as cm
from bayestouch.inference.raw.adjustment import OUTSIDE_PRIOR_WARN, Adjustment
from bayestouch.inference.raw.fit import adjustment_warnings


def _box(d=11):
    lo, hi = -np.ones(d), np.ones(d)
    lo[list(cm.ANGLE_COLUMNS)], hi[list(cm.ANGLE_COLUMNS)] = [0.0, 0.0, -np.pi], [np.pi, np.pi, np.pi]
    return cm.Bounds(jnp.asarray(lo), jnp.asarray(hi))


def test_a_widened_map_stays_in_the_prior_box_and_says_how_much_left_it():
    """Draws N(0, 0.1²) widened 20× (sd 2 against a box of ±1): the affine map alone puts ~62 % of each coordinate
    (and nearly every draw) outside; the bounded map keeps every non-angle coordinate in the box, wraps the angles
    into theirs, and leaves draws the map kept inside unchanged."""
    rng = np.random.default_rng(0)
    flat = 0.1 * rng.standard_normal((4000, 11))
    flat[:, 6:9] = [1.5, 1.0, 0.5]
    b = _box()
    adj = Adjustment(flat.mean(0), 20.0 * np.eye(11), {}, np.asarray(b.lower), np.asarray(b.upper))
    free = adj.unbounded(flat)
    assert np.abs(free[:, :6]).max() > 5  # the control: the affine map alone leaves the box
    out = adj(flat)
    keep = [0, 1, 2, 3, 4, 5, 9, 10]
    assert np.all(out[:, keep] >= -1) and np.all(out[:, keep] <= 1)
    assert np.all((out[:, 6] >= 0) & (out[:, 6] <= np.pi) & (out[:, 7] >= 0) & (out[:, 7] < np.pi))
    inside = ~adj.outside(flat)
    np.testing.assert_allclose(out[inside][:, keep], free[inside][:, keep])
    assert adj.outside(flat).mean() > 0.99
    small = Adjustment(flat.mean(0), 1.5 * np.eye(11), {}, np.asarray(b.lower), np.asarray(b.upper))
    assert small.outside(flat).mean() == 0.0
    np.testing.assert_allclose(small(flat)[:, keep], small.unbounded(flat)[:, keep])


@pytest.mark.parametrize(("share", "warned"), [(0.0, False), (OUTSIDE_PRIOR_WARN / 2, False), (0.3, True)])
def test_a_posterior_pushed_out_of_the_box_is_a_warning(share, warned):
    summary = {"model": {"adjustment": {"outside_prior": share, "sd_ratio": [2.0, 14.9]}}}
    got = adjustment_warnings(summary)
    assert bool(got) is warned
    if warned:
        assert "30 % of the draws outside the prior box" in got[0] and "14.9x" in got[0]
    assert adjustment_warnings({"model": {"adjustment": "none: intervals assume independent readings"}}) == []
