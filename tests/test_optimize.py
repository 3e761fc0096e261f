"""``bayestouch.inference.optimize.lockstep_lbfgs``: K L-BFGS-B runs whose steps share one batched call."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.optimize import minimize

from bayestouch.inference.optimize import lockstep_lbfgs


def _rosenbrock(x):
    """Value and gradient of the 4-D Rosenbrock function at the rows of x (k, 4): row-wise, so a row's value does
    not depend on the others."""
    x = np.atleast_2d(x)
    a, b = x[:, :-1], x[:, 1:]
    v = np.sum(100.0 * (b - a**2) ** 2 + (1 - a) ** 2, axis=1)
    g = np.zeros_like(x)
    g[:, :-1] += -400.0 * a * (b - a**2) - 2 * (1 - a)
    g[:, 1:] += 200.0 * (b - a**2)
    return v, g


def _one(x):
    v, g = _rosenbrock(x)
    return float(v[0]), g[0]


BOX = [(-2.0, 2.0)] * 3 + [(None, None)]


def _starts(k=6, seed=0):
    return list(np.random.default_rng(seed).uniform(-1.5, 1.5, (k, 4)))


def test_each_run_takes_the_steps_it_takes_alone_in_the_calls_of_the_longest():
    starts = _starts()
    calls = []

    def batch(x):
        calls.append(len(x))
        return _rosenbrock(x)

    got = lockstep_lbfgs(batch, starts, BOX, maxiter=500)
    alone = [minimize(_one, s, jac=True, method="L-BFGS-B", bounds=BOX, options={"maxiter": 500}) for s in starts]
    for g, a in zip(got, alone, strict=True):
        assert np.array_equal(g.x, a.x) and g.fun == a.fun and g.nfev == a.nfev and g.nit == a.nit
    assert all(g.success and np.abs(_one(g.x)[1][3]) < 1e-4 for g in got)  # converged (x₄ is unbounded)
    # one call per step of the longest run, not one per step of every run; the batch shrinks as runs finish
    assert len(calls) == max(a.nfev for a in alone) < sum(a.nfev for a in alone) / 2
    assert calls[0] == len(starts) and calls[-1] == 1


def test_a_deadline_stops_every_run_at_the_best_point_it_had_reached():
    starts = _starts(3)

    def slow(x):
        time.sleep(0.01)
        return _rosenbrock(x)

    got = lockstep_lbfgs(slow, starts, BOX, deadline=time.perf_counter() + 0.15)
    for g, s in zip(got, starts, strict=True):
        assert not g.success and g.message == "stopped at the deadline"
        assert g.fun < _one(s)[0] and g.fun == _one(g.x)[0]  # moved downhill; the value is the point's
    past = lockstep_lbfgs(_rosenbrock, starts, BOX, deadline=time.perf_counter() - 1.0)
    assert all(np.array_equal(g.x, s) and g.fun == np.inf for g, s in zip(past, starts, strict=True))


def test_a_failure_of_the_batch_or_of_one_run_reaches_the_caller_without_a_hang():
    n = {"calls": 0}

    def failing(x):
        n["calls"] += 1
        if n["calls"] == 5:
            raise FloatingPointError("the density failed")
        return _rosenbrock(x)

    with pytest.raises(FloatingPointError, match="density failed"):
        lockstep_lbfgs(failing, _starts(), BOX)

    # one run fails in its own thread (SciPy refuses a start of another length than its bounds)
    with pytest.raises(ValueError):
        lockstep_lbfgs(_rosenbrock, [*_starts(3), np.zeros(3)], BOX)


def test_run_bounds_hold_a_coordinate_where_each_run_says_and_match_the_runs_alone():
    starts = _starts(3)
    held = [[(v, v) if j == 1 else b for j, b in enumerate(BOX)] for v in (0.3, -0.5, 1.2)]
    got = lockstep_lbfgs(_rosenbrock, starts, BOX, maxiter=500, run_bounds=held)
    for g, s, h in zip(got, starts, held, strict=True):
        a = minimize(_one, s, jac=True, method="L-BFGS-B", bounds=h, options={"maxiter": 500})
        assert g.x[1] == h[1][0] and np.array_equal(g.x, a.x) and g.fun == a.fun
    # negative control: without them the coordinate moves to the minimum's 1
    free = lockstep_lbfgs(_rosenbrock, starts, BOX, maxiter=500)
    assert all(abs(g.x[1] - 1.0) < 1e-3 for g in free)
    with pytest.raises(ValueError, match="run_bounds"):
        lockstep_lbfgs(_rosenbrock, starts, BOX, run_bounds=held[:2])
