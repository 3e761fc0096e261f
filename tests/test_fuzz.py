"""Semantic fuzzing of both ends of the wire protocol: well-formed packets with hostile contents
(bayestouch.hardware.fuzz). The suite runs a few thousand cases; ``python -m bayestouch.hardware.fuzz 100000``
the long run."""

import numpy as np

from bayestouch.hardware import protocol as pr
from bayestouch.hardware.device import FingerDevice
from bayestouch.hardware.frame_models import GuardedModel
from bayestouch.hardware.fuzz import fuzz, hostile_command
from bayestouch.hardware.simulator import VirtualDevice, command_refusal
from bayestouch.params import MODELS
from bayestouch.scene.objects import load_object


def test_hostile_commands_and_frames_are_judged_without_an_exception():
    """3000 hostile commands and frames: no end raises, every accepted command and frame is finite (asserted in
    fuzz), and the generator makes both kinds (negative control: a fuzz that produced only refusals, or only
    accepted frames, would test nothing)."""
    out = fuzz(3000, seed=1)
    assert out["ack"] > 10 and out["nak"] > 1000
    assert 10 < out["carrier_ack"] < out["carriers"] - 1000
    assert 100 < out["bad_frames"] < out["frames"]


def test_the_virtual_finger_answers_every_hostile_command_and_stays_alive(tmp_path):
    """120 hostile STROKE / PROBE_STROKE commands sent over the pty: each is answered (never silence, which is
    what a killed device thread gives), with ACK exactly when the protocol's checks pass and NAK 2 otherwise; a
    status request is answered at the end."""
    sim = VirtualDevice(GuardedModel(load_object(MODELS / "objects" / "sphere.toml")), link=tmp_path / "finger")
    sim.start()
    dev = FingerDevice(str(tmp_path / "finger"), journal=tmp_path / "j.journal", retries=3).open()
    rng = np.random.default_rng(7)
    try:
        verdicts = []
        for i in range(120):
            msg = hostile_command(rng, 1000 + i)
            rep = dev._command(msg)
            expected = "nak" if command_refusal(msg, sim.limits) is not None else "ack"
            verdicts.append(expected)
            if expected == "ack":
                assert isinstance(rep, pr.Ack)
                dev._command(pr.Abort())
            else:
                assert isinstance(rep, pr.Nak) and rep.code == 2, rep
        assert isinstance(dev._command(pr.StatusRequest()), pr.Status)
        assert "nak" in verdicts
    finally:
        dev.close()
        sim.close()
