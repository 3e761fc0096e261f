"""The one place where the core's array backend is configured.

Every core module imports ``jax`` and ``jnp`` from here, so float64 is enabled exactly once, before
any array is created.

This is process-wide: JAX has one ``jax_enable_x64`` switch, and the likelihoods need float64 (a contact residual of
0.3 mm on a 30 mm object is 1e-2 of the coordinates, and the evidence of 10⁵ readings sums terms whose float32
rounding exceeds the differences between models). In a notebook that also runs float32 JAX code, importing any
fitting, geometry or physics module of bayestouch turns float64 on for it too; give such code explicit dtypes
(``jnp.asarray(x, dtype=jnp.float32)``). ``import bayestouch`` alone does not load JAX (its API loads lazily).
"""

from __future__ import annotations

import gc
import hashlib
import os
import platform
import re
import sys
from pathlib import Path

import jax
import jaxlib
import numpy as np

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402  (must follow the x64 switch)

__all__ = [
    "jax",
    "jnp",
    "pad_pow2",
    "enable_compilation_cache",
    "build_tag",
    "prune_compilation_cache",
    "CACHE_MAX_BYTES",
    "memory_maps",
    "release_compiled",
]

#: the persistent compilation cache's bound (all JAX builds' subfolders together), bytes
CACHE_MAX_BYTES = 2 * 1024**3
#: the name of a :func:`build_tag` subfolder
_BUILD = re.compile(r"jax[^-]+-jaxlib[^-]+-")


def build_tag(cpuinfo: str | os.PathLike = "/proc/cpuinfo") -> str:
    """The name of this machine's and JAX build's part of a compilation cache: JAX and jaxlib versions, the machine
    architecture and a hash of the CPU's instruction-set features (the ``flags`` line of ``cpuinfo``, Linux's
    ``/proc/cpuinfo``; the processor's name where there is none).

    JAX's cache keys hold jaxlib's version and the platform but not the CPU's features, and XLA compiles CPU code for
    the host's: a cache folder shared between hosts (a home folder on a cluster's network file system) would
    otherwise hand one machine's compiled programs to another. The versions keep each JAX build's programs in a
    folder of their own, which can be deleted once that build is gone.
    """
    features = platform.processor()
    try:
        with open(cpuinfo, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith(("flags", "Features")):
                    features = " ".join(sorted(line.split(":", 1)[1].split()))
                    break
    except OSError:
        pass
    digest = hashlib.sha256(features.encode()).hexdigest()[:12]
    return f"jax{jax.__version__}-jaxlib{jaxlib.__version__}-{platform.machine()}-{digest}"


def enable_compilation_cache() -> str | None:
    """Keep compiled XLA programs on disk between runs of the command line (JAX's persistent compilation cache).

    A first contact-level fit in a fresh process spends ~10 s compiling about a hundred programs (the likelihood,
    its gradient, the evolutionary search, the summaries' maps and many small array operations); later runs read
    them back. The folder is ``$BAYESTOUCH_JAX_CACHE`` when set (``~`` expands; ``0``, ``false``, ``no``, ``off`` or
    an empty value disable the cache; ``1``, ``true``, ``yes``, ``on`` keep the default), else
    ``$XDG_CACHE_HOME/bayestouch/jax`` (``~/.cache/bayestouch/jax``); programs go into its subfolder
    :func:`build_tag`, one per JAX build and CPU. A value that cannot be a folder (a file) is said on stderr and the
    cache stays off. The folder is kept under :data:`CACHE_MAX_BYTES` (:func:`prune_compilation_cache`, at every
    call). It takes effect only if nothing has been compiled yet in the process; results are identical with or
    without it.

    Returns
    -------
    str or None
        The cache folder (the :func:`build_tag` subfolder), or None when disabled or not writable.
    """
    env = os.environ.get("BAYESTOUCH_JAX_CACHE")
    word = None if env is None else env.strip().lower()
    if word in ("", "0", "false", "no", "off"):
        return None
    default = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bayestouch" / "jax"
    base = default if word in (None, "1", "true", "yes", "on") else Path(env.strip()).expanduser()
    folder = base / build_tag()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        print(
            f"bayestouch: BAYESTOUCH_JAX_CACHE: {base} cannot be a cache folder ({e.strerror}); compiling without the "
            "cache (expected a folder, or 0 to turn it off)",
            file=sys.stderr,
        )
        return None
    prune_compilation_cache(base, CACHE_MAX_BYTES)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return str(folder)


def prune_compilation_cache(base: str | os.PathLike, max_bytes: int = CACHE_MAX_BYTES, keep: float = 0.75) -> int:
    """Keep a compilation cache folder under ``max_bytes``: when its programs (JAX's ``*-cache`` files in every
    :func:`build_tag` subfolder together; nothing else in the folder is read or deleted) pass it, the least recently
    used are deleted until ``keep`` of it is left.

    JAX's own bound (``jax_compilation_cache_max_size``) needs the ``filelock`` package and rescans the folder at
    every write; without one the folder grows by every new program of every JAX build (a build's subfolder outlives
    the build, :func:`build_tag`). "Used" is a file's later access or modification time. A program deleted while
    another process reads it is compiled again there (JAX turns the failed read into a warning and a compilation).

    Parameters
    ----------
    base : path
        The cache's folder (the parent of the :func:`build_tag` subfolders).
    max_bytes : int
        The bound, bytes.
    keep : float
        The share of ``max_bytes`` left after pruning, in (0, 1].

    Returns
    -------
    int
        Bytes deleted.
    """
    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep: expected a share of max_bytes in (0, 1], got {keep}")
    files = []
    try:  # only the build subfolders' programs: a folder given as the cache may hold other things
        subfolders = [e.path for e in os.scandir(base) if e.is_dir(follow_symlinks=False) and _BUILD.match(e.name)]
    except OSError:
        return 0
    for sub in subfolders:
        try:
            entries = list(os.scandir(sub))
        except OSError:  # deleted meanwhile by another process
            continue
        for e in entries:
            try:
                if e.is_file(follow_symlinks=False) and e.name.endswith(("-cache", "-atime")):
                    st = e.stat(follow_symlinks=False)
                    files.append((max(st.st_atime, st.st_mtime), st.st_size, e.path))
            except OSError:
                continue
    total = sum(size for _, size, _ in files)
    if total <= max_bytes:
        return 0
    freed = 0
    for _, size, path in sorted(files, key=lambda f: f[0]):
        if total - freed <= keep * max_bytes:
            break
        try:
            os.unlink(path)
        except OSError:
            continue
        freed += size
    return freed


def memory_maps(maps: str | os.PathLike = "/proc/self/maps", limit: str | os.PathLike = "/proc/sys/vm/max_map_count"):
    """This process's memory maps and the kernel's limit on them (Linux's ``vm.max_map_count``).

    Returns
    -------
    (int, int) or None
        (maps in use, maps allowed); None where the system does not say (not Linux).
    """
    try:
        with open(limit, encoding="ascii") as fh:
            allowed = int(fh.read().split()[0])
        with open(maps, "rb") as fh:
            used = sum(1 for _ in fh)
    except (OSError, ValueError, IndexError):
        return None
    return used, allowed


def release_compiled(fraction: float = 0.5) -> bool:
    """Drop JAX's in-memory compiled programs when this process's memory maps pass ``fraction`` of the kernel's limit.

    XLA's CPU backend maps ~18 memory regions for every compiled program (its kernels' code, constants and data) and
    keeps every program a jitted function has compiled, one per shape and static argument, for the life of the
    process. Linux allows a process ``vm.max_map_count`` maps (65,530 by default), about 3,500 programs; past that the
    next compilation or compilation-cache read fails inside LLVM ("Cannot allocate memory") and the process dies
    (a segmentation fault or an abort), whatever it was doing. A notebook session, a benchmark or a test worker that
    runs many fits of different sizes gets there. Each fit and experiment trial calls this first (not each stroke of
    an exploration, whose virtual finger may be running): once the maps pass the threshold, ``jax.clear_caches()``
    releases them and programs are compiled again (or read back from the persistent cache,
    :func:`enable_compilation_cache`) when next called. Results are unchanged.

    Parameters
    ----------
    fraction : float
        The share of the limit above which the programs are dropped, in [0, 1] (0: always).

    Returns
    -------
    bool
        Whether the programs were dropped. Never where :func:`memory_maps` cannot tell.
    """
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction: expected a share of the limit in [0, 1], got {fraction}")
    maps = memory_maps()
    if maps is None or maps[0] <= fraction * maps[1]:
        return False
    jax.clear_caches()
    gc.collect()  # the executables go with their last Python reference
    return True


def pad_pow2(a, fill=None, min_size: int = 1) -> np.ndarray:
    """Rows of ``a`` (NumPy edge) padded to the next power of two, at least ``min_size``.

    Jitted functions called on arrays of varying length (paths, data sets, posterior draws) then compile
    for a handful of sizes instead of every length. Slice the result's first ``len(a)`` rows back out.

    Parameters
    ----------
    a : (m, ...) array
    fill : array broadcastable to one row, optional
        Value of the padding rows; default the first row of ``a`` (ones when ``a`` is empty), which keeps
        the padding inside the domain of the function.
    min_size : int

    Returns
    -------
    (size, ...) float ndarray
    """
    a = np.asarray(a, dtype=np.float64)
    m = len(a)
    size = max(min_size, 1 << max(m - 1, 0).bit_length())
    out = np.empty((size, *a.shape[1:]))
    out[:m] = a
    out[m:] = (a[0] if m else 1.0) if fill is None else fill
    return out
