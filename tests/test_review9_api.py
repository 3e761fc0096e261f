"""Issue 24, ninth review: functions of ``bayestouch.__all__`` given arguments of the wrong form raised raw Python
errors (AttributeError, TypeError, MemoryError, a misleading timeout) or accepted them; each now refuses in one line
naming the argument, and the right form passes (the control)."""

from __future__ import annotations

import pytest

import bayestouch as bt
from bayestouch.errors import BadInput
from bayestouch.hardware.simulator import Faults, check_faults
from bayestouch.params import MODELS


def test_scene_and_geometry_functions_name_a_bad_argument():
    egg = bt.load_object("egg")
    with pytest.raises(BadInput, match="obj: expected a SceneObject"):
        bt.random_strokes("egg", 2)
    assert len(bt.random_strokes(egg, 2, seed=0)) == 2
    with pytest.raises(BadInput, match="shape: expected an NEllipsoid"):
        bt.nellipsoid_mesh("egg")
    v, f = bt.nellipsoid_mesh(egg.shape, 8)
    assert v.shape[1] == 3 and f.shape[1] == 3
    with pytest.raises(BadInput, match="count: expected an integer number of points from 1 to 10,000,000"):
        bt.sample_surface(egg.shape, 10**12)
    assert bt.sample_surface(egg.shape, 5, seed=0).shape == (5, 3)


def test_finger_and_device_arguments_are_checked():
    assert bt.load_finger(str(MODELS), seed=1).finger is not None  # a string folder is a folder
    with pytest.raises(BadInput, match=r"seed: expected an integer in \[0, 2\*\*32\)"):
        bt.load_finger(MODELS, seed=-1)
    for bad in (float("nan"), -1.0, 0.0):
        with pytest.raises(BadInput, match="--timeout: expected a positive number of seconds"):
            bt.FingerDevice("loop://", timeout=bad)
    for faults, field in (
        (Faults(drop=2.0), "drop"),
        (Faults(delay=-5.0), "delay"),
        (Faults(disconnect_after=0), "disconnect_after"),
    ):
        with pytest.raises(BadInput, match=f"Faults.{field}"):
            check_faults(faults)
    assert check_faults(Faults(drop=0.01, delay=0.5)) == Faults(drop=0.01, delay=0.5)


def test_virtual_device_speed_and_rate_are_checked():
    from bayestouch.hardware.simulator import VirtualDevice

    for kw, field in (({"speed": -1.0}, "speed"), ({"speed": float("nan")}, "speed"), ({"rate": 0.0}, "rate")):
        with pytest.raises(BadInput, match=f"{field}: expected"):
            VirtualDevice(None, **kw)


def test_experiments_need_an_output_path():
    from bayestouch.planning.texture_id import run_experiment as texture_experiment

    with pytest.raises(BadInput, match="out: expected a path"):
        bt.run_experiment(None)
    with pytest.raises(BadInput, match="out: expected a path"):
        texture_experiment(None)
