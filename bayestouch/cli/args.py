"""Argument types shared by the commands (argparse ``type=``; a bad value is a one-line usage error, exit 2) and
the output-folder check."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import tempfile
from collections.abc import Iterator
from pathlib import Path

from bayestouch.errors import BadInput

__all__ = [
    "seed",
    "segment",
    "positive_int",
    "size_list",
    "one_size",
    "size_range",
    "eps_list",
    "check_out",
    "other_results",
    "other_results_error",
    "check_duration_rate",
    "terminations_as_interrupts",
    "RESULT_FILES",
    "COMMAND_RESULTS",
    "COMMAND_OUTPUTS",
    "out_path",
    "bounded_int",
    "stat",
]


def seed(text: str) -> int:
    """A random seed: an integer in [0, 2³²), the range NumPy's and emcee's generators accept."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed in [0, 2**32), got {text!r}") from None
    if not 0 <= v < 2**32:
        raise argparse.ArgumentTypeError(f"expected an integer seed in [0, 2**32), got {v}")
    return v


def positive_int(text: str) -> int:
    """A count: an integer ≥ 1."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def segment(text: str) -> int | None:
    """``--segment``: ``auto`` (None), 0 (whole packets) or a PART size in bytes (protocol revision 1.2)."""
    from bayestouch.hardware.protocol import MAX_PACKET, MIN_SEGMENT

    expected = f"expected auto, 0 (whole packets) or a part size of {MIN_SEGMENT}–{MAX_PACKET} bytes"
    if text.strip().lower() == "auto":
        return None
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{expected}, got {text!r}") from None
    if v != 0 and not MIN_SEGMENT <= v <= MAX_PACKET:
        raise argparse.ArgumentTypeError(f"{expected}, got {v}")
    return v


def _named_twice(items: list, shown: list[str], what: str) -> None:
    """Refuse a comma list that names one value twice (``items`` compared, ``shown`` as the user wrote them): each
    entry is a run of its own, and a duplicate runs it again and writes its rows twice."""
    twice = [shown[i] for i, v in enumerate(items) if v in items[:i]]
    if twice:
        raise argparse.ArgumentTypeError(f"{', '.join(dict.fromkeys(twice))} named twice; name each {what} once")


def size_list(text: str) -> list[str]:
    """FFD lattice sizes like ``7x7x7,6x6x3`` (each ≥ 2, each once), lower-cased."""
    sizes = [s.strip().lower() for s in text.split(",") if s.strip()]
    if not sizes:  # an empty list fell back to the defaults without a word
        raise argparse.ArgumentTypeError(f"expected at least one size like 6x6x3, got {text!r}")
    for s in sizes:
        parts = s.split("x")
        if len(parts) != 3 or not all(p.isdigit() and int(p) >= 2 for p in parts):
            raise argparse.ArgumentTypeError(f"FFD sizes must look like 6x6x3 (each ≥ 2), got {s!r}")
    _named_twice([tuple(int(p) for p in s.split("x")) for s in sizes], sizes, "size")
    return sizes


def one_size(text: str) -> tuple[int, int, int]:
    """One FFD lattice size like ``3x3x3``."""
    sizes = size_list(text)
    if len(sizes) != 1:
        raise argparse.ArgumentTypeError(f"expected one lattice size like 3x3x3, got {text!r}")
    return tuple(int(p) for p in sizes[0].split("x"))


def eps_list(text: str) -> list[float]:
    """Comma-separated perturbation levels in [0, 0.5), each once."""
    shown = [s.strip() for s in text.split(",") if s.strip()]
    try:
        eps = [float(s) for s in shown]
    except ValueError:
        raise argparse.ArgumentTypeError(f"epsilons must be comma-separated numbers, got {text!r}") from None
    if not eps:
        raise argparse.ArgumentTypeError(f"expected at least one perturbation level like 0,0.001, got {text!r}")
    if any(not 0 <= e < 0.5 for e in eps):
        raise argparse.ArgumentTypeError(f"epsilons must lie in [0, 0.5), got {eps}")
    _named_twice(eps, shown, "perturbation level")
    return eps


def out_path(text: str) -> Path:
    """An ``--out`` path that can be written: not empty (an empty one would write into the current folder), not a
    symbolic link to nothing (dangling or a loop), below a folder (not a file) in which a file can be created."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a file or folder name, got an empty path")
    path = Path(text)
    try:
        path.exists()  # a name the file system refuses (a component over its length limit, …)
    except OSError as e:
        raise argparse.ArgumentTypeError(f"{text[:80]}{'…' if len(text) > 80 else ''}: {e.strerror}") from None
    if path.is_symlink() and not path.exists():
        raise argparse.ArgumentTypeError(f"{text} is a symbolic link to nothing (dangling, or a loop)")
    base = next((a for a in path.absolute().parents if a.exists()), None)
    if base is None or not base.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: {base} is not a folder; expected a path below a folder")
    try:
        fd, probe = tempfile.mkstemp(dir=base, prefix=".bayestouch-probe-")
    except OSError as e:
        raise argparse.ArgumentTypeError(f"{text}: cannot create files in {base} ({e.strerror})") from None
    os.close(fd)
    os.unlink(probe)
    return path


def bounded_int(low: int, high: int):
    """An argparse type: an integer in [low, high] (a count whose memory or time grows with it has a stated
    limit instead of a MemoryError or an hours-long silence)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer from {low} to {high}, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected an integer from {low} to {high}, got {value}")
        return value

    return parse


def stat(value, spec: str) -> str:
    """A diagnostic (R-hat, ESS) for a one-line report: ``format(value, spec)``, or ``n/a`` when a chain too short
    left it undefined (None or NaN)."""
    if value is None or value != value:
        return "n/a"
    return format(value, spec)


#: files that hold a finished result of some command (fit, experiment, texture-id, sbc, reproduce-paper, explore):
#: an ``--out`` folder holding one is another run's, refused unless ``--overwrite`` (which sets them aside)
RESULT_FILES = (
    "summary.json",
    "run.json",
    "posterior.nc",
    "chain.h5",
    "results.csv",
    "experiment.json",
    "sbc.json",
    "table2.csv",
    "explore.json",
    "points.csv",
    "recording.nc",
)


#: files another command leaves as its finished result in its --out folder (explore, experiment, sbc,
#: reproduce-paper, demo; glob patterns): a fit or a demo into that folder is refused unless --overwrite sets them
#: aside
COMMAND_RESULTS = (
    "explore.json",
    "summary_*.json",
    "results.csv",
    "experiment.json",
    "sbc.json",
    "table1.csv",
    "table2.csv",
    "demo.json",
    "report.html",
)
#: what goes with those results (figures, tables, the device's journal and recording, the demo's strokes), set aside
#: with them by --overwrite
COMMAND_OUTPUTS = (
    "explore.png",
    "points.csv",
    "device.journal",
    "recording.nc",
    "error_vs_strokes.png",
    "accuracy_vs_strokes.png",
    "sbc_ranks.png",
    "table1.md",
    "table2.md",
    "table2.png",
    "patch_summary.json",
    "strokes",
)


def check_out(path: Path, overwrite: bool | None = None, command: str = "", inputs=()) -> Path:
    """The output folder ``--out``, created; a path that exists and is not a folder is bad input.

    With ``overwrite`` given (a command with ``--overwrite``), a folder that holds a finished result
    (:data:`RESULT_FILES`) is refused unless ``overwrite``, which moves those files into ``replaced-<UTC>/``
    (:func:`bayestouch.io.files.move_aside`): a command never writes over another run's results. ``inputs``, the
    command's own input files, stay where they are (an object or library kept in the output folder)."""
    if path.exists() and not path.is_dir():
        raise BadInput(f"--out {path} exists and is not a folder")
    if overwrite is not None and path.is_dir():
        held = [path / n for n in RESULT_FILES if (path / n).exists()]
        if held and not overwrite:
            raise BadInput(
                f"--out {path} already holds {held[0].name} (a finished result); pass --overwrite to set it aside, "
                "or choose another folder"
            )
        from bayestouch.io.files import set_aside
        from bayestouch.io.runfolder import every_earlier_file

        set_aside(every_earlier_file(path, inputs) if held else [], command)
    path.mkdir(parents=True, exist_ok=True)
    return path


def other_results(out: Path, *, own=(), keep=(), patterns=(*RESULT_FILES, *COMMAND_RESULTS)) -> list[Path]:
    """What in the folder ``out`` another command made: files matching ``patterns`` (glob patterns; default
    :data:`RESULT_FILES` and :data:`COMMAND_RESULTS`) and, when there is one, the :data:`COMMAND_OUTPUTS` that go
    with them; the command's ``own`` file names and the ``keep`` paths (its input files) excepted. Empty when ``out``
    holds no other command's result or is no folder."""
    out = Path(out)
    if not out.is_dir():
        return []
    kept = {Path(k).resolve() for k in keep if k is not None}

    def foreign(p: Path) -> bool:
        return p.name not in own and p.resolve() not in kept

    found = sorted({p for pat in patterns for p in out.glob(pat) if p.is_file() and foreign(p)})
    if not found:
        return []
    return sorted(set(found) | {out / n for n in COMMAND_OUTPUTS if (out / n).exists() and foreign(out / n)})


def other_results_error(out: Path, found: list[Path], patterns=(*RESULT_FILES, *COMMAND_RESULTS)) -> BadInput:
    """The one-line refusal of an ``--out`` holding another command's results ``found`` (:func:`other_results`),
    naming up to four of them."""
    names = sorted({p.name for p in found if any(p.match(pat) for pat in patterns)})
    return BadInput(
        f"--out {out} already holds the results of another command ({', '.join(names[:4])}"
        f"{' …' if len(names) > 4 else ''}); pass --overwrite to set them aside, or choose another folder"
    )


@contextlib.contextmanager
def terminations_as_interrupts() -> Iterator[None]:
    """While the block runs, SIGTERM (a scheduler, ``kill``) and SIGHUP (a closed terminal) raise
    :class:`KeyboardInterrupt` as Ctrl-C does, so a command handles all three alike (one line, exit 130, what was
    finished kept) instead of dying silently; a signal that ``nohup`` set to be ignored stays ignored, and outside
    the main thread nothing is installed. The earlier handlers are restored afterwards."""

    def terminated(signum, frame):
        raise KeyboardInterrupt

    old = {}
    for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is None or signal.getsignal(sig) is signal.SIG_IGN:  # nohup: the user asked for hangups ignored
            continue
        try:
            old[sig] = signal.signal(sig, terminated)
        except ValueError:  # not the main thread: no handler can be installed there
            pass
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def check_duration_rate(duration: float, rate: float) -> None:
    """``--duration`` (s) and ``--rate`` (frames/s) of random strokes: each in range and at least 2 frames a
    stroke (:class:`BadInput` naming the options)."""
    if not (0 < duration <= 600):
        raise BadInput(f"--duration must be in (0, 600] seconds, got {duration}")
    if not (1 <= rate <= 2000):
        raise BadInput(f"--rate must be in [1, 2000] frames per second, got {rate}")
    if duration * rate < 2:
        raise BadInput(
            f"--duration {duration:g} s at --rate {rate:g} Hz gives fewer than 2 frames per stroke; "
            "give a longer --duration or a higher --rate"
        )


def size_range(text: str) -> tuple[float, float]:
    """An object-size range ``MIN:MAX`` in metres with 0 < MIN < MAX, e.g. ``0.01:0.1``."""
    parts = text.split(":")
    try:
        lo, hi = (float(p) for p in parts) if len(parts) == 2 else (float("nan"),) * 2
    except ValueError:
        lo = hi = float("nan")
    if not (lo > 0 and hi > lo and hi < float("inf")):
        raise argparse.ArgumentTypeError(f"expected MIN:MAX metres with 0 < MIN < MAX (e.g. 0.01:0.1), got {text!r}")
    return lo, hi
