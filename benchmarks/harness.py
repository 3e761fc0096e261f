"""A small benchmark harness.

Every ``benchmarks/bench_*.py`` module defines functions ``bench_*()`` that return a list of result
dicts ``{"metric": str, "value": float, "unit": str, ...extra}``. The harness runs them, adds the
machine description, and writes ``benchmarks/results/<module>.json`` plus one Markdown table
``benchmarks/results/README.md`` over all modules.
"""

from __future__ import annotations

import importlib
import json
import multiprocessing as mp
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

from bayestouch.io.files import write_text

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"


def machine() -> dict:
    import jax
    import numpy

    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "jax_backend": jax.default_backend(),
        "numpy": numpy.__version__,
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def worker_init() -> None:
    """Initializer of a benchmark's worker processes: one BLAS thread each (the workers share the machine's cores)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def pool_rows(fn, count: int, workers: int) -> list:
    """The rows ``fn(k)`` (each a list) for k in ``range(count)``, flattened in the order they arrive, on ``workers``
    spawned processes (:func:`worker_init`; 1: in this process, in order). ``fn`` is a module-level function."""
    rows: list = []
    if workers > 1:
        with mp.get_context("spawn").Pool(workers, initializer=worker_init) as pool:
            for r in pool.imap_unordered(fn, range(count)):
                rows += r
    else:
        for k in range(count):
            rows += fn(k)
    return rows


def cli_fit(csv: Path, out: Path, seed: int, cache) -> tuple[dict | None, float, int, str]:
    """``bayestouch fit CSV --out OUT --seed SEED --quiet`` in a fresh process (one BLAS thread, the JAX compilation
    cache ``cache``, a folder or "0" for none): the run's summary (None when the process failed), the process's wall
    time (s, interpreter start and imports included), its exit code and its stderr's tail."""
    env = {**os.environ, "BAYESTOUCH_JAX_CACHE": str(cache), "OMP_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "bayestouch.cli", "fit", str(csv), "--out", str(out), "--seed", str(seed), "--quiet"],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    wall = time.perf_counter() - t0
    summary = json.loads((out / "summary.json").read_text()) if proc.returncode == 0 else None
    return summary, wall, proc.returncode, proc.stderr[-300:]


def best_of(fn, repeat: int = 5, number: int = 1) -> float:
    """Best wall-clock seconds per call of ``fn`` over ``repeat`` rounds of ``number`` calls."""
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t) / number)
    return best


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far, MiB (Linux reports KiB)."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / 1024.0 if sys.platform != "darwin" else r / 2**20


def run(names: list[str] | None = None) -> dict[str, list[dict]]:
    RESULTS.mkdir(exist_ok=True)
    mods = sorted(p.stem for p in HERE.glob("bench_*.py"))
    if names:
        unknown = sorted(set(names) - set(mods))
        if unknown:
            raise SystemExit(f"benchmarks: unknown module(s) {unknown}; have {mods}")
        mods = [m for m in mods if m in names]
    info = machine()
    for m in mods:
        mod = importlib.import_module(f"benchmarks.{m}")
        results = []
        for fname in sorted(n for n in dir(mod) if n.startswith("bench_")):
            print(f"[bench] {m}.{fname} ...", flush=True)
            t0 = time.perf_counter()
            for r in getattr(mod, fname)():
                results.append({"benchmark": fname, **r})
            print(f"[bench] {m}.{fname} done in {time.perf_counter() - t0:.1f} s", flush=True)
        write_text(RESULTS / f"{m}.json", json.dumps({"machine": info, "results": results}, indent=2) + "\n")
    table = _markdown(info)
    write_text(RESULTS / "README.md", table)
    print(table)
    from benchmarks.readme import missing, update_readme

    changed = update_readme()
    print(f"[bench] README.md {'updated' if changed else 'unchanged'}; rows without results: {missing() or 'none'}")
    return {}


def _cell(text) -> str:
    """A Markdown table cell: its pipes escaped, so that a metric such as "median |z|" stays in one column."""
    return str(text).replace("|", "\\|")


def _markdown(info: dict) -> str:
    lines = [
        "# Benchmark results",
        "",
        f"Machine: {info['platform']}, {info['cpu_count']} CPUs, Python {info['python']}, "
        f"JAX {info['jax']} ({info['jax_backend']}); {info['date']}. Written by `make bench`.",
        "",
        "| module | benchmark | metric | value | unit | notes |",
        "|---|---|---|---|---|---|",
    ]
    for path in sorted(RESULTS.glob("bench_*.json")):
        doc = json.loads(path.read_text())
        for r in doc["results"]:
            extra = {k: v for k, v in r.items() if k not in ("benchmark", "metric", "value", "unit")}
            notes = ", ".join(f"{k}={v}" for k, v in extra.items())
            v = r["value"]
            cells = [path.stem, r["benchmark"], r["metric"], f"{v:.4g}", r["unit"], notes]
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"
