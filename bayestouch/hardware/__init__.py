"""The hardware adapter: wire protocol, safety limits, the pyserial client and the virtual finger on a pty.

Submodules are imported lazily (``import bayestouch.hardware`` loads none of them; ``bayestouch.hardware.FingerDevice``
imports the client with pyserial and the physics it needs on first use):

- :mod:`~bayestouch.hardware.protocol` — bytes ↔ messages, pure (spec: ``PROTOCOL.md``);
- :mod:`~bayestouch.hardware.safety` — limits and stroke-plan checks;
- :mod:`~bayestouch.hardware.device` — :class:`FingerDevice`, the client;
- :mod:`~bayestouch.hardware.simulator` — :class:`VirtualDevice`, the virtual finger;
- :mod:`~bayestouch.hardware.frame_models` — what the virtual finger streams (:class:`ForwardModel` and others);
- :mod:`~bayestouch.cli.device` — ``bayestouch device simulate`` and ``bayestouch device run``.
"""

from __future__ import annotations

import importlib

__all__ = [
    "PROTOCOL_VERSION",
    "FingerDevice",
    "DeviceError",
    "HeaterFault",
    "VirtualDevice",
    "Faults",
    "SyntheticModel",
    "ForwardModel",
    "GuardedModel",
    "ProbePlan",
    "ProbeData",
    "CarrierData",
    "Limits",
    "StrokePlan",
    "UnsafePlan",
    "check_plan",
    "check_carrier",
    "plan_from_stroke",
    "read_journal",
    "build_recording",
]

_WHERE = {
    "PROTOCOL_VERSION": "protocol",
    "FingerDevice": "device",
    "DeviceError": "device",
    "HeaterFault": "device",
    "read_journal": "device",
    "build_recording": "device",
    "VirtualDevice": "simulator",
    "Faults": "simulator",
    "SyntheticModel": "frame_models",
    "ForwardModel": "frame_models",
    "GuardedModel": "frame_models",
    "ProbePlan": "device",
    "ProbeData": "device",
    "CarrierData": "device",
    "Limits": "safety",
    "StrokePlan": "safety",
    "UnsafePlan": "safety",
    "check_plan": "safety",
    "check_carrier": "safety",
    "plan_from_stroke": "safety",
}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"bayestouch.hardware.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'bayestouch.hardware' has no attribute {name!r}")
