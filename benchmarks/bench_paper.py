"""The paper pipeline's cost: data, the evolutionary fit, and one Table 2 row per FFD size."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bayestouch.geometry.integrals import surface_integrals
from bayestouch.paper import TABLE2_SIZES, fit_nellipsoid_de, plate_data, table2_row
from bayestouch.scene.objects import load_object
from benchmarks.harness import peak_rss_mib

PLATE = Path(__file__).resolve().parent.parent / "models" / "objects" / "graphite_plate.toml"


def bench_table2_rows():
    plate = load_object(PLATE)
    t = time.perf_counter()
    data = plate_data(plate, 25, seed=0)
    out = [{"metric": "probe 25 paths", "value": time.perf_counter() - t, "unit": "s", "points": len(data)}]
    truth = surface_integrals(*plate.mesh(96))
    t = time.perf_counter()
    de = fit_nellipsoid_de(data, 0)
    out.append(
        {
            "metric": "differential-evolution fit",
            "value": time.perf_counter() - t,
            "unit": "s",
            "generations": de.generations,
            "points": len(data),
        }
    )
    secs = []
    for size in TABLE2_SIZES:
        row = table2_row(plate, data, truth, size, 0.0, 0, de=de)
        secs.append(row["seconds"])
        out.append(
            {
                "metric": f"Table 2 row {size} (FFD + indicators)",
                "value": row["seconds"],
                "unit": "s",
                "iterations": row["iterations"],
            }
        )
    out.append(
        {"metric": "Table 2 row, mean over sizes (DE fit shared per ε)", "value": float(np.mean(secs)), "unit": "s"}
    )
    out.append({"metric": "peak memory of the benchmark process so far", "value": peak_rss_mib(), "unit": "MiB"})
    return out
