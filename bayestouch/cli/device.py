"""``bayestouch device simulate`` (the virtual finger on a pty), ``bayestouch device run`` (strokes on a
device, written as a recording with the schema of ``bayestouch simulate``) and ``bayestouch device recover`` (the
recording of the complete strokes in a journal a killed run left).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import stat
import sys
import threading
import time
from pathlib import Path

import numpy as np

from bayestouch.cli.args import bounded_int, check_duration_rate, out_path, terminations_as_interrupts
from bayestouch.cli.args import seed as seed_arg
from bayestouch.cli.args import segment as segment_arg
from bayestouch.errors import BadInput
from bayestouch.params import MODELS

__all__ = ["add_device_parser", "run_device", "load_stroke_file"]

_MODELS = MODELS


#: longest ``device simulate --for``, seconds (a week; leave --for out to serve until interrupted)
MAX_RUN_FOR_S = 7 * 24 * 3600.0
#: longest ``device simulate --delay`` stall, seconds (the longest --watchdog)
MAX_DELAY_S = 60.0

#: most random strokes of one ``device run`` (1000 strokes of 2 s at 50 Hz: 100,000 frames, half of what
#: ``simulate`` writes into one recording)
MAX_DEVICE_STROKES = 1000
#: longest stroke (s) of a stroke file, as ``--duration``'s cap (:func:`bayestouch.cli.args.check_duration_rate`)
MAX_STROKE_S = 600.0


def _prob(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1), got {text!r}") from None
    if not 0 <= v < 1:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1), got {v}")
    return v


def add_device_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``device`` with its ``simulate`` and ``run`` subcommands to an argparse ``subparsers``."""
    dp = subparsers.add_parser(
        "device",
        help="the finger over a serial line: virtual finger and stroke runner",
        description="Hardware adapter (protocol: bayestouch/hardware/PROTOCOL.md). "
        "`device simulate` serves a virtual finger on a pseudo-terminal; `device run` drives "
        "a finger (real port, pty or pyserial URL) and writes a recording.",
    )
    sub = dp.add_subparsers(dest="device_command", metavar="DEVICE_COMMAND")

    sp = sub.add_parser(
        "simulate",
        help="virtual finger on a pseudo-terminal (forward model behind the protocol)",
        description="Open a pseudo-terminal and answer the finger protocol with the forward model. "
        "Runs until interrupted (or --for seconds).",
    )
    sp.add_argument("--print-port", action="store_true", help="print the pty path alone on stdout")
    sp.add_argument(
        "--link",
        type=Path,
        default=None,
        help="also keep a symbolic link at this path pointing to the pty (survives --disconnect-after); a new "
        "path, a dangling link or a link to a pty (an existing file or folder is refused, never replaced)",
    )
    sp.add_argument(
        "--object",
        type=Path,
        default=_MODELS / "objects" / "egg.toml",
        help="object TOML touched (default models/objects/egg.toml)",
    )
    sp.add_argument("--models", type=Path, default=_MODELS, help="parameter folder (default models/)")
    sp.add_argument("--seed", type=seed_arg, default=0, help="fixed pattern and noise seed (default 0)")
    sp.add_argument(
        "--model",
        choices=["forward", "synthetic"],
        default="forward",
        help="frame model: the physics forward model (default) or a fast synthetic one (tests)",
    )
    sp.add_argument("--speed", type=float, default=1.0, help="real-time factor (default 1; 0 = as fast as possible)")
    sp.add_argument("--max-force", type=float, default=1.0, help="device contact force limit, N (default 1)")
    sp.add_argument("--watchdog", type=float, default=1.0, help="heartbeat watchdog, seconds (default 1)")
    sp.add_argument("--drop", type=_prob, default=0.0, help="fault: probability of dropping each byte sent")
    sp.add_argument("--corrupt", type=_prob, default=0.0, help="fault: probability of corrupting each byte sent")
    sp.add_argument(
        "--delay",
        type=float,
        default=0.0,
        help=f"fault: stall the outgoing stream this many seconds, before 5%% of the packets (0 to {MAX_DELAY_S:g})",
    )
    sp.add_argument("--inbound-faults", action="store_true", help="drop/corrupt received bytes too")
    sp.add_argument(
        "--disconnect-after",
        type=int,
        default=None,
        metavar="N",
        help="fault: close the pty after N frames (once) and open a new one",
    )
    sp.add_argument("--stuck-heater", action="store_true", help="fault: the wires stay powered after a stroke")
    sp.add_argument(
        "--bend-spread",
        type=float,
        default=0.0,
        metavar="FACTOR",
        help="give the finger bending constants of its own, drawn (with --seed) at FACTOR times their stated spread "
        "(physics.pose.FingerSpread; 1 = as uncertain as the models say), while its pose estimate keeps the models' "
        "constants: guarded strokes then touch millimetres off the commanded lines and carrier strokes where its "
        "own bend puts the pad (default 0: the models' constants, no bending pose error; at most 3)",
    )
    sp.add_argument(
        "--for",
        dest="run_for",
        type=float,
        default=None,
        metavar="SECONDS",
        help=f"stop after this many seconds, more than 0 and at most {MAX_RUN_FOR_S:g} (a week) (default: until "
        "interrupted)",
    )

    rp = sub.add_parser(
        "run",
        help="run strokes on a finger and write a recording (.nc)",
        description="Connect to a finger (a port path, a pty from `device simulate`, or a pyserial "
        "URL), run strokes, and write a recording with the schema of `bayestouch simulate`. Strokes "
        "come from --stroke-file or are random sections of --object (like `simulate`).",
    )
    rp.add_argument("--port", required=True, help="serial port path or pyserial URL (loop://, socket://HOST:PORT)")
    rp.add_argument("--out", required=True, type=out_path, help="recording to write (.nc)")
    rp.add_argument("--overwrite", action="store_true", help="replace an existing --out recording")
    rp.add_argument(
        "--strokes",
        type=bounded_int(1, MAX_DEVICE_STROKES),
        default=1,
        help=f"number of random strokes (default 1; at most {MAX_DEVICE_STROKES} in one recording)",
    )
    rp.add_argument(
        "--stroke-file",
        type=Path,
        default=None,
        help='JSON stroke plans: {"strokes": [{"time": [s], "contact": [[x,y,z] m], "normal": '
        '[[nx,ny,nz]], "depth": m, "hold_currents": [A,A,A] (optional)}]}',
    )
    rp.add_argument(
        "--object",
        type=Path,
        default=_MODELS / "objects" / "egg.toml",
        help="object model the random strokes follow (default models/objects/egg.toml)",
    )
    rp.add_argument("--seed", type=seed_arg, default=0, help="seed of the random strokes (default 0)")
    rp.add_argument("--duration", type=float, default=2.0, help="seconds per stroke at 1 cm/s (default 2)")
    rp.add_argument("--rate", type=float, default=50.0, help="frames per second (default 50)")
    rp.add_argument("--depth", type=float, default=3e-4, help="pressing depth in metres (default 3e-4)")
    rp.add_argument("--currents", default="0.15,0.05,0.05", help="wire hold currents, A (default 0.15,0.05,0.05)")
    rp.add_argument("--timeout", type=float, default=0.3, help="seconds to wait for an answer before a retry")
    rp.add_argument(
        "--segment",
        type=segment_arg,
        default=None,
        help="packets on a lossy link (protocol 1.2): auto (default: parts of 48 bytes once whole packets do not get "
        "through), 0 (always whole) or a part size in bytes",
    )
    rp.add_argument(
        "--journal",
        type=Path,
        default=None,
        help="file receiving every packet as it arrives (default OUT.journal, removed on success)",
    )
    rp.add_argument("--quiet", action="store_true", help="no progress bar")

    bp = sub.add_parser(
        "calibrate-bending",
        help="a finger's pad-pose error law from guarded strokes over a known object (a pose-law .toml)",
        description="Run guarded strokes with tilted approaches over a known object in its fixture (a sphere of a "
        "few centimetres is best) and condition the law of the pad's pose error on where they touched: fingers "
        "drawn about the models' bending constants, holding the strokes' currents, and the posterior of their "
        "leading components. Writes the pose-law file that `bayestouch explore --port --pose-law` marginalises.",
    )
    bp.add_argument("--port", required=True, help="serial port path or pyserial URL (a pty of `device simulate`)")
    bp.add_argument(
        "--object",
        required=True,
        help="the known object: a name in models/objects (sphere, ...) or a TOML file, in the finger's world frame",
    )
    bp.add_argument("--out", required=True, type=out_path, help="pose-law file to write (.toml)")
    bp.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    bp.add_argument(
        "--strokes", type=bounded_int(1, 64), default=6, help="calibration strokes of 20 approaches (default 6)"
    )
    bp.add_argument("--draws", type=bounded_int(9, 1000), default=64, help="fingers drawn for the law (default 64)")
    bp.add_argument("--seed", type=seed_arg, default=0, help="seed of the strokes and the drawn fingers (default 0)")
    bp.add_argument("--timeout", type=float, default=0.3, help="seconds to wait for an answer before a retry")

    cp = sub.add_parser(
        "recover",
        help="rebuild a recording (.nc) from the journal of a device run",
        description="Write the recording of the complete strokes in a journal (OUT.journal of `device run`, kept "
        "when a run fails or is killed): every stroke command the run sent with all of its frames, as the run "
        "would have written them. Incomplete strokes are named and left out.",
    )
    cp.add_argument("journal", type=Path, help="the journal file (OUT.journal)")
    cp.add_argument("--out", required=True, type=out_path, help="recording to write (.nc)")
    cp.add_argument("--overwrite", action="store_true", help="replace an existing --out recording (set aside)")
    return dp


#: the options that shape ``device run``'s random strokes, with their defaults (refused beside ``--stroke-file``)
RANDOM_STROKE_DEFAULTS = {
    "strokes": 1,
    "object": _MODELS / "objects" / "egg.toml",
    "seed": 0,
    "duration": 2.0,
    "rate": 50.0,
    "depth": 3e-4,
}
#: the keys of one stroke of a ``--stroke-file`` (``hold_currents`` optional)
STROKE_KEYS = ("time", "contact", "normal", "depth", "hold_currents")


class _DuplicateKey(Exception):
    pass


def _unique_keys(pairs):
    out = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(repr(k))
        out[k] = v
    return out


def load_stroke_file(path: Path, hold_currents) -> list:
    """Stroke plans from a JSON file (see ``device run --help``); raises BadInput naming the problem."""
    from bayestouch.hardware.safety import StrokePlan

    try:
        # a byte-order mark is allowed, as in a CSV; a key given twice is refused (JSON keeps the last, silently)
        doc = json.loads(Path(path).read_text(encoding="utf-8-sig"), object_pairs_hook=_unique_keys)
    except _DuplicateKey as e:
        raise BadInput(f"--stroke-file {path}: the key {e} appears twice in one object; give each once") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise BadInput(
            f"--stroke-file {path}: cannot be read as JSON ({type(e).__name__}); expected "
            '{"strokes": [{"time", "contact", "normal", "depth"}]}'
        ) from None
    items = doc.get("strokes") if isinstance(doc, dict) else None
    if not isinstance(items, list) or not items:
        raise BadInput(f'--stroke-file {path}: expected an object with a non-empty list "strokes"')
    if len(items) > MAX_DEVICE_STROKES:
        raise BadInput(
            f"--stroke-file {path}: {len(items)} strokes; at most {MAX_DEVICE_STROKES} in one recording "
            "(split the file)"
        )
    if set(doc) != {"strokes"}:
        raise BadInput(
            f'--stroke-file {path}: unknown key(s) {sorted(set(doc) - {"strokes"})}; expected only "strokes"'
        )
    plans = []
    for i, s in enumerate(items):
        if not isinstance(s, dict):
            raise BadInput(f"--stroke-file {path}: stroke {i} is a {type(s).__name__}; expected an object")
        unknown = sorted(set(s) - set(STROKE_KEYS))
        if unknown:
            # a misspelt key (hold_current) would otherwise leave its default in place without a word
            raise BadInput(
                f"--stroke-file {path}: stroke {i}: unknown key(s) {unknown}; expected {', '.join(STROKE_KEYS)}"
            )
        try:
            plans.append(
                StrokePlan(
                    np.asarray(s["time"], float),
                    np.asarray(s["contact"], float),
                    np.asarray(s["normal"], float),
                    float(s["depth"]),
                    np.asarray(s.get("hold_currents", hold_currents), float),
                )
            )
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise BadInput(
                f"--stroke-file {path}: stroke {i} needs numeric time, contact, normal and depth "
                f"({type(e).__name__}: {e})"
            ) from None
    _check_stroke_times(plans, f"--stroke-file {path}")
    _check_stroke_geometry(plans, f"--stroke-file {path}")
    return plans


def _check_stroke_times(plans, where: str) -> None:
    """Refuse, before anything is sent, stroke times that are not seconds (a frame rate outside the recordings' own
    range), a stroke longer than ``--duration``'s cap, and more frames than a recording holds (a stroke file in
    milliseconds ran 33 minutes of heated wires, and was refused only by the fit afterwards)."""
    from bayestouch.inference.raw.data import frame_interval_problem
    from bayestouch.io.recording import MAX_FRAMES

    frames = 0
    for i, p in enumerate(plans):
        t = p.time
        if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)):
            continue  # shapes and finiteness: the safety check's
        if problem := frame_interval_problem(t):
            raise BadInput(f"{where}: stroke {i}: 'time' {problem}")
        if t[-1] - t[0] > MAX_STROKE_S:
            raise BadInput(
                f"{where}: stroke {i} lasts {t[-1] - t[0]:.4g} s; at most {MAX_STROKE_S:g} s (as --duration), times "
                "in seconds"
            )
        frames += t.size
    if frames > MAX_FRAMES:
        raise BadInput(f"{where}: {frames} frames in all; at most {MAX_FRAMES} in one recording (split the file)")


def _check_stroke_geometry(plans, where: str) -> None:
    """Refuse strokes whose contacts are not in metres or whose normals point into the object, as a contact file's
    are refused (the safety check would call millimetres "beyond ±10 m" or a speed limit, and would press an
    inward-normal stroke from inside the object); shapes and finiteness are left to the safety check."""
    from bayestouch.io.contacts import check_normals_outward, unit_problem

    good = [
        p for p in plans if p.contact.ndim == 2 and p.contact.shape[1:] == (3,) and p.normal.shape == p.contact.shape
    ]
    if not good:
        return
    contact = np.vstack([p.contact for p in good])
    normal = np.vstack([p.normal for p in good])
    if not (np.all(np.isfinite(contact)) and np.all(np.isfinite(normal))):
        return
    if hint := unit_problem(contact):
        raise BadInput(f"{where}: the strokes' contact points {hint}")
    check_normals_outward(contact, normal, f"{where}: normal", fix="negate every stroke's normal")


def check_port(port: str) -> None:
    """Refuse a ``--port`` path that names no character device (a folder, a plain file, a FIFO, nothing) with
    :class:`BadInput`; URLs (``scheme://``) are left to pyserial."""
    if "://" in port:
        return
    expected = (
        "expected a serial port path (e.g. the pty printed by `bayestouch device simulate`) or a pyserial URL like "
        "socket://HOST:PORT"
    )
    try:
        mode = os.stat(port).st_mode
    except OSError:
        raise BadInput(f"--port {port}: no such device; {expected}") from None
    if not stat.S_ISCHR(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a plain file"
        raise BadInput(f"--port {port} is {kind}, not a serial device; {expected}")


def _currents(text: str):
    try:
        cur = [float(x) for x in text.split(",")]
    except ValueError:
        raise BadInput(f"--currents must be three numbers in amperes like 0.15,0.05,0.05, got {text!r}") from None
    if len(cur) != 3:
        raise BadInput(f"--currents must be three numbers in amperes, got {len(cur)}")
    return cur


def _simulate(args) -> int:
    from bayestouch.hardware.frame_models import ForwardModel, GuardedModel, SyntheticModel
    from bayestouch.hardware.safety import load_limits
    from bayestouch.hardware.simulator import Faults, VirtualDevice

    if not args.speed >= 0:
        raise BadInput(f"--speed must be ≥ 0 (0 = as fast as possible), got {args.speed}")
    if not (0 < args.max_force <= 2.0):
        raise BadInput(f"--max-force must be in (0, 2] newtons, got {args.max_force}")
    if not (0.05 <= args.watchdog <= 60):
        raise BadInput(f"--watchdog must be in [0.05, 60] seconds, got {args.watchdog}")
    if args.disconnect_after is not None and args.disconnect_after < 1:
        raise BadInput(f"--disconnect-after must be ≥ 1 frames, got {args.disconnect_after}")
    if not (0 <= args.delay <= MAX_DELAY_S):
        raise BadInput(f"--delay must be in [0, {MAX_DELAY_S:g}] seconds, got {args.delay}")
    if not (0 <= args.bend_spread <= 3):
        raise BadInput(f"--bend-spread must be in [0, 3] (times the constants' stated spread), got {args.bend_spread}")
    if args.run_for is not None and not (0 < args.run_for <= MAX_RUN_FOR_S):
        raise BadInput(
            f"--for must be in (0, {MAX_RUN_FOR_S:g}] seconds (a week; leave it out to run until interrupted), got "
            f"{args.run_for}"
        )
    faults = Faults(
        args.drop,
        args.corrupt,
        args.delay,
        0.05,
        args.disconnect_after,
        args.stuck_heater,
        args.inbound_faults,
        args.seed,
    )
    limits = load_limits(args.models, max_force=args.max_force, watchdog=args.watchdog)
    from bayestouch.scene.objects import resolve_object

    resolve_object(args.object, args.models)  # a bad --object is named before the pty opens (one line, no status)
    sim = VirtualDevice(None, limits=limits, speed=args.speed, faults=faults, link=args.link)
    try:
        port = sim.open()
    except BadInput as e:  # the link's path ("link PATH: ..."), named as the option
        raise BadInput(f"--{e}") from None
    if args.print_port:
        print(port, flush=True)
    print(
        f"virtual finger on {port}" + (f" (link {args.link})" if args.link else "") + "; loading the model",
        file=sys.stderr,
        flush=True,
    )
    stop = threading.Event()
    old = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        from bayestouch.scene.objects import load_object

        finger = _drawn_finger(args) if args.bend_spread > 0 else None
        if args.model == "synthetic":
            # guarded strokes (bayestouch explore --port) find the object; the frames come from the fast model
            obj = load_object(args.object, args.models)
            sim.model = GuardedModel(obj, SyntheticModel(seed=args.seed), seed=args.seed, finger=finger)
        else:
            sim.model = ForwardModel(load_object(args.object, args.models), args.models, seed=args.seed)
            if finger is not None:
                sim.model.vf = sim.model.vf._replace(wire=finger[0], rod=finger[1])
            threading.Thread(target=_warm_up, args=(sim.model, args), daemon=True).start()
        sim.start()
        print(f"serving {args.model} model, speed {args.speed:g}× (Ctrl-C to stop)", file=sys.stderr, flush=True)
        t0 = time.monotonic()
        while not stop.wait(0.2):
            if args.run_for is not None and time.monotonic() - t0 > args.run_for:
                break
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, old)
        sim.close(timeout=2.0)
    print(f"virtual finger stopped: {sim.stats}", file=sys.stderr)
    return 0


def _drawn_finger(args):
    """The bending constants (wire, rod) of ``--bend-spread``: drawn with ``--seed`` about the models' (said on
    stderr)."""
    import numpy as np

    from bayestouch.physics import bending, pose, sma

    wire, rod = sma.load_wire(args.models / "finger.toml"), bending.load_rod(args.models / "finger.toml")
    w, r = pose.draw_finger(np.random.default_rng(args.seed), wire, rod, pose.FingerSpread().widened(args.bend_spread))
    print(
        f"bending constants drawn at {args.bend_spread:g}x their spread: EI x{r.EI / rod.EI:.3f}, pre-strain "
        f"{w.prestrain:.4f}, transformation temperatures {w.A_s - wire.A_s:+.2f} K, film coefficient "
        f"x{w.convection / wire.convection:.3f}, ambient {w.ambient - wire.ambient:+.2f} K",
        file=sys.stderr,
        flush=True,
    )
    return w, r


def _warm_up(model, args) -> None:
    """Compile the forward model for the default stroke shape while no client is connected yet."""
    from bayestouch.hardware.safety import plan_from_stroke
    from bayestouch.scene.strokes import random_strokes

    try:
        st = random_strokes(model.obj, 1, seed=args.seed)[0]
        model(plan_from_stroke(st), -1)
    except Exception:  # warming up is optional
        pass


def _run(args) -> int:
    if args.out.suffix != ".nc":
        raise BadInput(f"--out {args.out}: expected a netCDF file name ending in .nc")
    if args.out.is_dir():
        raise BadInput(f"--out {args.out} is a folder; expected a .nc file name")
    if not args.port.strip():
        raise BadInput("--port: expected a serial port path or a pyserial URL, got an empty string")
    if args.strokes < 1:
        raise BadInput(f"--strokes must be ≥ 1, got {args.strokes}")
    if not (0.01 <= args.timeout <= 60):
        raise BadInput(f"--timeout must be in [0.01, 60] seconds, got {args.timeout}")
    currents = _currents(args.currents)
    if args.journal is not None and args.journal.absolute() == args.out.absolute():
        raise BadInput(f"--journal {args.journal} is the --out recording; name another file for the packets")
    if args.journal is not None and args.journal.exists():
        raise BadInput(
            f"--journal {args.journal} exists; name a new file (packets are never appended to another file, and an "
            "earlier journal is kept as it is)"
        )
    from bayestouch.hardware.safety import check_plan, load_limits, plan_from_stroke

    limits = load_limits()
    # the inputs first, then the port: a bad stroke file is named even when no device is attached
    if args.stroke_file is not None:
        given = [f"--{k.replace('_', '-')}" for k, v in RANDOM_STROKE_DEFAULTS.items() if getattr(args, k) != v]
        if given:  # they shape random strokes only: silently dropped before
            raise BadInput(f"{', '.join(given)}: not used with --stroke-file (its strokes are given in full)")
        plans = load_stroke_file(args.stroke_file, currents)
    else:
        check_duration_rate(args.duration, args.rate)
    check_port(args.port)
    if args.stroke_file is None:
        from bayestouch.scene.objects import load_object
        from bayestouch.scene.strokes import random_strokes

        obj = load_object(args.object)
        plans = [
            plan_from_stroke(s, currents)
            for s in random_strokes(
                obj, args.strokes, seed=args.seed, duration=args.duration, rate=args.rate, depth=args.depth
            )
        ]
    for i, p in enumerate(plans):  # refuse before connecting: nothing is sent for an unsafe plan
        try:
            check_plan(p, limits)
        except BadInput as e:
            raise type(e)(f"stroke {i}: {e}") from None
    from bayestouch.io.runfolder import locked_output_file

    # the recording and its journal are this run's until it ends: a second run into the same --out is refused
    with locked_output_file(args.out):
        return _run_locked(args, plans, limits)


def _run_locked(args, plans, limits) -> int:
    """The strokes of ``device run``, its options checked and ``--out`` held (:func:`_run`)."""
    from bayestouch import __version__
    from bayestouch.hardware.device import DeviceError, FingerDevice, HeaterFault, build_recording
    from bayestouch.io.files import set_aside
    from bayestouch.io.recording import write_recording

    if args.out.exists() and not args.overwrite:
        raise BadInput(f"--out {args.out} already exists; pass --overwrite to replace it, or choose another file")
    journal = args.journal or args.out.with_name(args.out.name + ".journal")
    if journal.exists() and args.journal is None:
        # an earlier run's journal (the frames of a failed run): kept under a new name, never deleted
        kept = journal.with_name(f"{journal.name}.{time.strftime('%Y%m%dT%H%M%S')}")
        journal.replace(kept)
        print(f"bayestouch device run: kept the earlier journal {journal} as {kept}", file=sys.stderr)
    t0 = time.perf_counter()
    done = []
    attrs = {
        "port": args.port,
        "seed": args.seed,
        "wire_hold_currents_A": args.currents,
        "software": f"bayestouch {__version__}",
        "object": "unknown (device)" if args.stroke_file else f"device; strokes planned on {args.object}",
    }
    dev = FingerDevice(args.port, timeout=args.timeout, journal=journal, limits=limits, segment=args.segment)
    replaced = [args.out] if args.overwrite else []  # set aside (never deleted) before the new recording is written

    written = {"strokes": 0, "at": float("-inf"), "cost": 0.0}

    def save(extra: dict) -> None:
        """Write the complete strokes so far to ``--out`` (atomically; the old file set aside before the first)."""
        t = time.perf_counter()
        set_aside(replaced, "device run")
        replaced.clear()
        write_recording(build_recording(done, dev.info, {**attrs, **extra}), args.out, overwrite=written["strokes"] > 0)
        written.update(strokes=len(done), at=time.perf_counter(), cost=time.perf_counter() - t)

    def keep(note: str) -> None:
        """Write the complete strokes so far (marked incomplete) and say where everything received is."""
        if done and written["strokes"] < len(done):
            save({"incomplete": "true"})
        kept = f" written to {args.out}" if done else ""
        got = f"everything received is in {journal}" if journal.exists() else "nothing was received"
        print(f"bayestouch device run: {note}; {len(done)} complete stroke(s){kept}; {got}", file=sys.stderr)

    with terminations_as_interrupts():  # SIGTERM, SIGHUP: handled as Ctrl-C, until what was kept is said
        try:
            with dev:
                from tqdm.auto import tqdm

                for p in tqdm(plans, desc="strokes", unit="stroke", disable=args.quiet):
                    done.append(dev.run_stroke(p))
                    # the complete strokes so far, on disk as a recording marked incomplete (a SIGKILL or a power cut
                    # leaves them readable, not only in the journal); at most every few seconds for long runs
                    if len(done) < len(plans) and time.perf_counter() - written["at"] > max(2.0, 5 * written["cost"]):
                        save({"incomplete": "true"})
                info = dev.info
        except (DeviceError, BadInput) as e:
            # a fault, or a stroke refused by the device's own limits after good ones: the good strokes are kept
            at = len(done) + 1  # the user's stroke number (1-based) in the plan or stroke file
            if isinstance(e, HeaterFault) and e.data is not None:
                done.append(e.data)  # complete: the heaters stayed on after it, so no further stroke was sent
            keep(f"error: stroke {at} of {len(plans)}: {e}")
            return 2  # the device failed or refused: one line, everything received kept (exit 1 is an internal error)
        except KeyboardInterrupt:
            keep("interrupted")
            return 130  # said once, with what was kept (not again by the command line's own Ctrl-C line)
    set_aside(replaced, "device run")
    write_recording(build_recording(done, info, attrs), args.out, overwrite=args.overwrite or written["strokes"] > 0)
    if args.journal is None:
        journal.unlink(missing_ok=True)
    n = sum(len(s.plan.time) for s in done)
    print(
        f"wrote {args.out}: {len(done)} stroke(s), {n} frames × {info.rows * info.cols} taxels from "
        f"{info.firmware} in {time.perf_counter() - t0:.1f} s (retries {dev.stats['retries']}, resent-frame "
        f"requests {dev.stats['resend_requests']}, reconnects {dev.stats['reconnects']})"
    )
    return 0


def _recover(args) -> int:
    """``device recover``: the recording of a journal's complete strokes."""
    from bayestouch import __version__
    from bayestouch.hardware.device import build_recording, strokes_from_journal
    from bayestouch.io.files import set_aside
    from bayestouch.io.recording import write_recording
    from bayestouch.io.runfolder import locked_output_file

    if args.out.suffix != ".nc":
        raise BadInput(f"--out: a recording is a netCDF file; expected a name ending in .nc, got {str(args.out)!r}")
    if args.out.exists() and not args.out.is_file():
        raise BadInput(f"--out {args.out} is a folder (or not a file); expected a .nc file name")
    if args.out.resolve() == args.journal.resolve():
        raise BadInput(f"--out {args.out} is the journal; name another file for the recording")
    got = strokes_from_journal(args.journal)
    left = f"; left out {len(got.incomplete)} incomplete: {', '.join(got.incomplete[:3])}" if got.incomplete else ""
    if got.damaged:
        left += f"; {got.damaged} damaged packet(s) dropped"
    if not got.strokes:
        raise BadInput(f"journal {args.journal}: no complete stroke in it{left}")
    with locked_output_file(args.out):
        if args.out.exists() and not args.overwrite:
            raise BadInput(f"--out {args.out} already exists; pass --overwrite to replace it, or choose another file")
        attrs = {
            "software": f"bayestouch {__version__}",
            "object": "unknown (device)",
            "recovered_from": str(args.journal),
            "wire_hold_currents_A": ",".join(f"{c:g}" for c in got.strokes[0].plan.hold_currents),
            "planned_strokes": "unknown: a journal does not record how many strokes the run planned",
        }
        if got.incomplete or got.damaged:
            attrs["incomplete"] = "true"
        if args.overwrite:
            set_aside([args.out], "device recover")
        write_recording(build_recording(got.strokes, got.info, attrs), args.out, overwrite=args.overwrite)
    n = sum(len(s.plan.time) for s in got.strokes)
    bad = f"; {got.skipped} frame(s) or guarded stroke packet(s) skipped" if got.skipped else ""
    print(
        f"wrote {args.out}: {len(got.strokes)} stroke(s), {n} frames from {args.journal}{left}{bad} (a journal does "
        "not say how many strokes were planned: compare with the stroke file)"
    )
    return 0


def run_device(args) -> int:
    """Run ``device simulate``, ``device run`` or ``device recover`` from parsed arguments; returns the exit
    code."""
    if getattr(args, "device_command", None) == "simulate":
        return _simulate(args)
    if getattr(args, "device_command", None) == "run":
        return _run(args)
    if getattr(args, "device_command", None) == "recover":
        return _recover(args)
    if getattr(args, "device_command", None) == "calibrate-bending":
        return _calibrate_bending(args)
    raise BadInput(
        "device: expected a subcommand, simulate, run, recover or calibrate-bending (see bayestouch device --help)"
    )


#: RMS distance (metres) of the calibrated contacts from the known object above which the calibration warns: three
#: times the encoders' 0.3 mm (the object is not where its file says, or the finger is not one the law can hold)
BENDING_MISFIT_M = 9e-4


def _calibrate_bending(args) -> int:
    """``device calibrate-bending``: the pose-law file of the finger at ``--port``."""
    from bayestouch import __version__
    from bayestouch.hardware.device import DeviceError, FingerDevice, finger_of
    from bayestouch.io.pose_law_file import write_pose_law
    from bayestouch.planning.device_prober import DeviceProber, calibrate_bending
    from bayestouch.scene.objects import load_object, resolve_object

    if args.out.suffix != ".toml":
        raise BadInput(f"--out {args.out}: expected a .toml pose-law file")
    if args.out.exists() and not args.overwrite:
        raise BadInput(f"--out {args.out} exists; pass --overwrite to replace it")
    if not (0.01 <= args.timeout <= 60):
        raise BadInput(f"--timeout must be in [0.01, 60] seconds, got {args.timeout}")
    check_port(args.port)
    obj = load_object(resolve_object(args.object))
    try:
        with FingerDevice(args.port, timeout=args.timeout) as dev:
            prober = DeviceProber(dev)
            print(
                f"bayestouch device calibrate-bending: {args.strokes} stroke(s) over {obj.name}, then {args.draws} "
                "drawn fingers",
                file=sys.stderr,
            )
            cond = calibrate_bending(prober, obj, strokes=args.strokes, seed=args.seed, draws=args.draws)
            named = finger_of(dev.info.firmware)
    except DeviceError as e:
        print(f"bayestouch device calibrate-bending: error: {e}; nothing written", file=sys.stderr)
        return 2
    info = {
        "object": str(args.object),
        **({"finger": named} if named else {}),
        "contacts": int(cond.contacts),
        "residual_rms_m": float(cond.residual_rms),
        "residual_rms_prior_m": float(cond.residual_rms_prior),
        "software": f"bayestouch {__version__}",
    }
    write_pose_law(args.out, cond.law, info)
    print(
        f"wrote {args.out}: {cond.contacts} contacts, their RMS distance from {obj.name} "
        f"{1e3 * cond.residual_rms_prior:.2f} mm with the models' constants, {1e3 * cond.residual_rms:.2f} mm with "
        "the calibrated law"
    )
    if cond.residual_rms > BENDING_MISFIT_M:
        print(
            f"bayestouch device calibrate-bending: warning: misfit: the contacts stay {1e3 * cond.residual_rms:.2f} mm "
            f"from {obj.name} (more than {1e3 * BENDING_MISFIT_M:.1f} mm): is the object where its file says? The law "
            "was written but does not hold this finger",
            file=sys.stderr,
        )
    return 0
