"""A fit's output folder: a finished result is never overwritten by accident, and a chain is resumed only by the run
that made it.

Every fit writes ``run.json`` into its folder before anything else: the level (contact or raw), a SHA-256 of each
input array and the options that shape the posterior (noise model, priors, walkers, seed …). A later fit into the
same folder

* without ``resume`` or ``overwrite`` is refused when the folder holds a result (``summary.json``, ``chain.h5`` or
  ``posterior.nc``): one line naming the folder and the two ways on;
* with ``resume`` is refused when its fingerprint differs from the folder's, naming what differs (the data, or each
  option with both values), so another object's points or a changed seed never continue a chain;
* with ``overwrite`` first moves the old run's outputs into ``replaced-<UTC time>/`` inside the folder, so the folder
  never shows an old summary beside a new chain and an interrupted new run loses nothing;
* while another process writes into the same folder is refused (an exclusive lock on ``.bayestouch.lock``, held
  until :func:`release_run_folder` or the process's end).

Every other command that writes an ``--out`` folder (explore, experiment, texture-id, sbc, reproduce-paper, demo,
and fit itself around its checks) holds the same lock for its whole run with :func:`locked_run_folder`: two runs
into one folder at once are refused in one line naming the pid of the run that holds it. The lock is the kernel's
(``fcntl.flock``): it goes with the process that holds it, so a killed run leaves no stale lock behind.

A run folder without ``run.json`` (deleted, or written before fingerprints existed) is refused by ``resume``: nothing
shows its data and options.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sys
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from bayestouch.errors import BadInput
from bayestouch.io.files import move_aside, write_json
from bayestouch.io.occupancy import OCCUPANCY_FILE

try:  # POSIX; elsewhere run folders are not locked
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None

__all__ = [
    "FINGERPRINT_FILE",
    "OUTPUTS",
    "RESULT_FILES",
    "OPTIMUM_FILE",
    "dataset_digest",
    "differences",
    "fingerprint",
    "prepare_run_folder",
    "release_run_folder",
    "locked_run_folder",
    "locked_output_file",
    "every_earlier_file",
    "LOCK_FILE",
]

#: the file holding a run's fingerprint
FINGERPRINT_FILE = "run.json"
#: files whose presence means the folder holds a run (finished or resumable)
RESULT_FILES = ("summary.json", "chain.h5", "posterior.nc")
#: a contact fit's optimum check (its optimum and Laplace covariance), kept beside smc.npz: a resume reads it back
OPTIMUM_FILE = "optimum.npz"
#: files of a run interrupted after its tempering stage (resumable from them)
STAGE_FILES = ("smc.npz", *(f"smc_parts{k}.npz" for k in range(1, 5)))
#: every file of a fit's run folder: what ``overwrite`` removes before the new run starts, what
#: :meth:`bayestouch.api.Fit.save` copies
OUTPUTS = (
    *RESULT_FILES,
    "mean_shape.ply",
    "uncertainty_mesh.ply",
    "smc.npz",
    OPTIMUM_FILE,
    OCCUPANCY_FILE,
    *(f"smc_parts{k}.npz" for k in range(1, 5)),  # the parts fit's per-K tempering, K = 1 … parts.MAX_PARTS
    FINGERPRINT_FILE,
)


def _digest(value) -> str | None:
    if value is None:
        return None
    if isinstance(value, bytes):
        return hashlib.sha256(value).hexdigest()
    a = np.ascontiguousarray(np.asarray(value, dtype=np.float64))
    h = hashlib.sha256(str(a.shape).encode())
    h.update(a.tobytes())
    return h.hexdigest()


def dataset_digest(ds) -> bytes:
    """SHA-256 (32 bytes) of an ``xarray.Dataset``'s variables (names, dtypes, shapes, values) and attributes: the
    identity of a recording, whether it was read from a file or built in memory."""
    h = hashlib.sha256()
    for name in sorted(map(str, ds.variables)):
        a = np.asarray(ds[name].values)
        h.update(f"{name}|{a.dtype}|{a.shape}|".encode())
        h.update(repr(a.tolist()).encode() if a.dtype.kind == "O" else np.ascontiguousarray(a).tobytes())
    h.update(repr(sorted((str(k), str(v)) for k, v in ds.attrs.items())).encode())
    return h.digest()


def _plain(value: Any) -> Any:
    """Options as JSON round-trips them (tuples as lists, NumPy scalars as Python numbers, inf as a string)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return repr(value)
    return value


def fingerprint(level: str, data: Mapping[str, Any], options: Mapping[str, Any]) -> dict:
    """The fingerprint of a run: ``level`` (e.g. ``"contact"``), a SHA-256 of each input in ``data`` (arrays, in
    float64, or raw ``bytes`` such as a recording file's; None for an absent input) and the ``options`` (JSON
    values)."""
    return {
        "level": str(level),
        "data_sha256": {str(k): _digest(v) for k, v in data.items()},
        "options": _plain(dict(options)),
    }


def _changed(name: str, was, now) -> str:
    """One phrase for an option that differs; a table of settings (the priors) names only its entries that
    differ (the whole table, 17 entries twice, buried the one changed)."""
    if isinstance(was, dict) and isinstance(now, dict):
        keys = sorted(k for k in was.keys() | now.keys() if was.get(k) != now.get(k))
        parts = [f"{k} {was.get(k)!r} (now {now.get(k)!r})" for k in keys[:3]]
        return f"{name}: " + ", ".join(parts) + (" …" if len(keys) > 3 else "")
    return f"{name} {was!r} (now {now!r})"


def differences(old: dict, new: dict) -> list[str]:
    """What differs between a recorded fingerprint ``old`` (as read back from JSON) and ``new``
    (:func:`fingerprint`), one phrase each: ``"other points"``, ``"seed 0 (now 7)"`` …; empty when they agree.
    Runs of another kind (level) differ in that alone: their options are not comparable."""
    if old.get("level") != new["level"]:
        return [f"a {old.get('level')}-level run, not {new['level']}"]
    out = []
    old_data = old.get("data_sha256", {})
    for k, v in new["data_sha256"].items():
        if k not in old_data:
            out.append(f"no {k} (this run has it)")
        elif old_data[k] != v:
            out.append(f"other {k}")
    for k in old_data.keys() - new["data_sha256"].keys():
        out.append(f"{k} (this run lacks it)")
    old_opt = old.get("options", {})
    for k, v in new["options"].items():
        if k in old_opt and old_opt[k] != v:
            out.append(_changed(k, old_opt[k], v))
        elif k not in old_opt:
            out.append(f"{k} at its default (now {v!r})")  # an option the earlier run's key left out
    for k in old_opt.keys() - new["options"].keys():  # an option the run had that this one does not
        out.append(f"{k} {old_opt[k]!r} (now at its default)")
    return out


#: the switches as the messages name them: the command line's flag and the Python keyword (run_contact_fit,
#: bayestouch.fit and the command line share these checks)
RESUME, OVERWRITE = "--resume (resume=True)", "--overwrite (overwrite=True)"


def prepare_run_folder(out, fp: dict, *, resume: bool, overwrite: bool = False) -> Path:
    """Check ``out`` for a fit with fingerprint ``fp`` (:func:`fingerprint`) and record ``fp`` there (module
    docstring).

    Parameters
    ----------
    out : path
        The run folder (created when missing).
    fp : dict
    resume : bool
        Continue the run in ``out``: refused when its fingerprint differs.
    overwrite : bool
        Replace a run in ``out``: its outputs are first moved into ``out/replaced-<UTC time>/``.

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    BadInput
        ``out`` is a file; it holds a run and neither ``resume`` nor ``overwrite`` is given; ``resume`` with a
        different fingerprint; both ``resume`` and ``overwrite``.
    """
    out = Path(out)
    if resume and overwrite:
        raise BadInput(f"{RESUME} and {OVERWRITE} exclude each other: continue the run in the folder, or replace it")
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    _lock(out)
    held = [f for f in RESULT_FILES if (out / f).exists()]
    # an interrupted run's finished tempering is a run too: a fresh start would delete it
    started = [f for f in STAGE_FILES if (out / f).exists()]
    old = None
    path = out / FINGERPRINT_FILE
    if path.exists():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            old = {}
        if not (isinstance(old, dict) and "level" in old and "options" in old) and resume:
            raise BadInput(
                f"{RESUME}: {path} is damaged (not a run fingerprint), so nothing shows the run in {out} was made "
                f"with these data and options; {OVERWRITE} to start it again, or choose another folder"
            )
    if resume and old is None and (held or (out / "smc.npz").exists()):
        # a run without its fingerprint: nothing shows it was made with these data and options (continuing it
        # with other data reported the old object's shape, exit 0)
        raise BadInput(
            f"{RESUME}: {out} holds a run ({', '.join(held) or 'smc.npz'}) but no {FINGERPRINT_FILE}, so nothing "
            f"shows it was made with these data and options; {OVERWRITE} to start it again, or choose another folder"
        )
    if resume and not held and not (out / "smc.npz").exists():
        print(f"bayestouch: --resume: {out} holds no run yet; starting one", file=sys.stderr)
    if resume and held and "chain.h5" not in held:  # a finished run keeps smc.npz too: it does not make one resumable
        # a finished run whose chain is gone cannot be continued: a fresh chain would replace its results
        raise BadInput(
            f"{RESUME}: {out} holds a run ({', '.join(held)}) but not its chain.h5, so it cannot be continued; "
            f"{OVERWRITE} to start again (its results are set aside), or choose another folder"
        )
    if resume and old is not None and (held or (out / "smc.npz").exists()):
        diff = differences(old, fp)
        if diff:
            raise BadInput(
                f"{RESUME}: {out} holds a run made with {'; '.join(diff)}; resume it with its own data and "
                f"options, or choose another folder (or {OVERWRITE} to replace it)"
            )
    elif not resume and (held or started):
        if not overwrite:
            raise BadInput(
                f"--out {out} already holds a run ({', '.join(held + started)}); pass {RESUME} to continue it, "
                f"{OVERWRITE} to replace it, or choose another folder"
            )
        # set aside, not deleted: an interrupted or failed new run leaves the old result where the user finds it
        aside = move_aside(out, [out / name for name in OUTPUTS if (out / name).exists()])
        print(f"bayestouch: --overwrite: the previous run is kept in {aside} until you delete it", file=sys.stderr)
    write_json(path, fp)
    return out


#: the lock file that marks a run folder as in use by a process (``fcntl.flock``, released when it exits); it holds
#: the pid of the process that took it, for the message that refuses a second run
LOCK_FILE = ".bayestouch.lock"
#: this process's locks: the folder's resolved path -> the lock file's descriptor
_LOCKS: dict[str, int] = {}
#: how many :func:`locked_run_folder` blocks of this process hold each folder (:func:`release_run_folder` leaves
#: such a folder locked: a fit inside ``bayestouch demo`` does not free the demo's folder)
_HELD: dict[str, int] = {}


def _holder(path: Path) -> str:
    """`` (pid N)`` of the process named in the lock file ``path``, or nothing when it names none."""
    try:
        pid = path.read_text(encoding="ascii").strip()
    except (OSError, ValueError):
        return ""
    return f" (pid {pid})" if pid.isdigit() else ""


def _acquire(path: Path, refusal: str, parent: Path) -> int:
    """An exclusive ``flock`` on the lock file ``path`` (created, in ``parent``, re-created when a holder that
    gave it up removed it meanwhile), holding this process's pid; :class:`BadInput` ``refusal`` + the holder's pid
    when another process holds it. Returns the open descriptor."""
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except FileNotFoundError:  # the folder was removed by a run that gave it up empty meanwhile
            parent.mkdir(parents=True, exist_ok=True)
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise BadInput(refusal.replace("{holder}", _holder(path))) from None
        try:  # the file is still the lock file (not removed by a holder that gave it up meanwhile)
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except OSError:
            same = False
        if same:
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode("ascii"))
    return fd


def _lock(out: Path) -> None:
    """Hold an exclusive lock on ``out`` for this process (a second process writing into the same folder is
    refused); a folder this process already holds is not locked twice."""
    key = str(out.resolve())
    if fcntl is None or key in _LOCKS:
        return
    _LOCKS[key] = _acquire(
        out / LOCK_FILE,
        f"--out {out} is in use by another bayestouch run{{holder}}; wait for it to finish or choose another folder",
        out,
    )


def release_run_folder(out) -> None:
    """Release this process's lock on the run folder ``out`` (:func:`prepare_run_folder` takes it), unless a
    :func:`locked_run_folder` block of this process still holds the folder."""
    key = str(Path(out).resolve())
    if _HELD.get(key):
        return
    fd = _LOCKS.pop(key, None)
    if fd is not None:
        os.close(fd)


def every_earlier_file(folder, keep=()) -> list[Path]:
    """The files of ``folder`` that an overwrite sets aside once it holds a finished result: every file but the
    folder's lock and the paths in ``keep`` (the command's own inputs, such as a texture library or an object file
    kept in its output folder: set aside, the run could not read them), so no output of the earlier run (meshes,
    figures, grids) is left beside the new one. Sub-folders, such as earlier ``replaced-*/``, stay."""
    kept = {Path(k).resolve() for k in keep if k is not None}
    return sorted(p for p in Path(folder).iterdir() if p.is_file() and p.name != LOCK_FILE and p.resolve() not in kept)


@contextmanager
def locked_output_file(path) -> Iterator[Path]:
    """Hold the output file ``path`` (e.g. a recording and its journal ``path.journal``) for this process during a
    ``with`` block: a lock file ``.NAME.bayestouch.lock`` beside it (``fcntl.flock``, gone with a killed process);
    a second process asking for the same file is refused in one line naming the holder's pid (two ``device run``
    into one ``--out`` each took the other's journal for an earlier run's and one deleted it)."""
    target = Path(path)
    made = not target.parent.exists()  # a folder made only for the lock goes again when nothing else is in it
    target.parent.mkdir(parents=True, exist_ok=True)
    lock = target.parent / f".{target.name}.bayestouch.lock"
    if fcntl is None:
        yield target
        return
    fd = _acquire(
        lock,
        f"--out {target} is being written by another bayestouch run{{holder}}; wait for it to finish or choose "
        "another file",
        target.parent,
    )
    try:
        yield target
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
        os.close(fd)
        if made:
            with contextlib.suppress(OSError):  # not empty: the run wrote its recording or journal there
                target.parent.rmdir()


@contextmanager
def locked_run_folder(out) -> Iterator[Path]:
    """Hold the output folder ``out`` for this process for the duration of a ``with`` block: created when missing,
    locked (``.bayestouch.lock``) so that another process writing into it is refused, released at the block's end
    (also on an error or Ctrl-C; a killed process's lock goes with it).

    Blocks nest, and :func:`prepare_run_folder` / :func:`release_run_folder` inside the block (a fit into the same
    folder) leave it locked. A folder the block created and that holds nothing but the lock file at its end (a run
    refused before writing anything) is removed again.

    Parameters
    ----------
    out : path
        The output folder.

    Yields
    ------
    pathlib.Path
        ``out``.

    Raises
    ------
    BadInput
        ``out`` exists and is not a folder; another process holds it (one line naming its pid).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out} exists and is not a folder")
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    _lock(out)
    key = str(out.resolve())
    _HELD[key] = _HELD.get(key, 0) + 1
    try:
        yield out
    finally:
        _HELD[key] -= 1
        if not _HELD[key]:
            del _HELD[key]
            fd = _LOCKS.pop(key, None)
            if created:
                _remove_if_only_lock(out)  # while still locked: no other run holds the file being removed
            if fd is not None:
                os.close(fd)


def _remove_if_only_lock(out: Path) -> None:
    """Remove the folder ``out`` when it holds nothing but (at most) the lock file."""
    try:
        if {p.name for p in out.iterdir()} <= {LOCK_FILE}:
            (out / LOCK_FILE).unlink(missing_ok=True)
            out.rmdir()
    except OSError:
        pass
