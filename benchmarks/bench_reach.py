"""How far true surfaces reach beyond the contacts that touched them: the reference for the contact fit's
extrapolation warning (:data:`bayestouch.inference.reach.REACH_LIMIT`).

A fit warns when its surface runs farther from every contact than REACH_LIMIT times the contacts' span
(:func:`bayestouch.inference.reach.surface_reach`). Here the same measure is taken of the true surfaces of the
benchmark sets themselves: the 50 users'-like n-ellipsoid sets of ``bench_user_sets`` (seed 0; the truth's
surface at the fit's own cube-sphere directions) and the 16 non-superquadric objects of ``bench_objects`` (seed 0;
20,000 area-uniform points of the true mesh). A correct posterior reaches about as far as its truth, so the largest
truth reach says where a warning stops being a false alarm on such data. No fit is run (seconds).

Outputs ``benchmarks/results/reach.json`` (every set's truth reach) and the harness rows.
"""

from __future__ import annotations

import json

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from bayestouch.inference.reach import REACH_LIMIT, contact_span, surface_reach
from bayestouch.io.files import write_text
from benchmarks.bench_objects import make_object_sets
from benchmarks.bench_user_sets import make_user_sets
from benchmarks.harness import RESULTS

#: sets of each benchmark (their own counts) and the true mesh's surface points per object set
USER_SETS = 50
OBJECT_SETS = 16
MESH_POINTS = 20_000


def truth_reach_user_sets(count: int = USER_SETS) -> np.ndarray:
    """The reach (count,) of each users'-like set's true n-ellipsoid beyond its contacts."""
    out = []
    for d in make_user_sets(count, seed=0):
        t = d.truth
        theta = np.concatenate([np.asarray(t.centre), np.log(np.asarray(t.axes)), np.asarray(t.angles)])
        out.append(surface_reach(d.points, np.append(theta, np.log(float(t.n)))[None])[0])
    return np.array(out)


def truth_reach_object_sets(count: int = OBJECT_SETS) -> tuple[np.ndarray, list[str]]:
    """The reach (count,) of each object set's true mesh beyond its contacts, and the sets' kinds."""
    out, kinds = [], []
    for d in make_object_sets(count, seed=0):
        surface, _ = trimesh.sample.sample_surface(trimesh.Trimesh(d.vertices, d.faces), MESH_POINTS, seed=0)
        out.append(cKDTree(d.points).query(surface)[0].max() / contact_span(d.points))
        kinds.append(d.kind)
    return np.array(out), kinds


def bench_reach() -> list[dict]:
    """The truths' reach on both benchmarks' sets: median, largest and how many exceed REACH_LIMIT."""
    users = truth_reach_user_sets()
    objects, kinds = truth_reach_object_sets()
    doc = {
        "reach_limit": REACH_LIMIT,
        "user_sets": {"reach": users.tolist()},
        "object_sets": {"reach": objects.tolist(), "kind": kinds},
    }
    rows = []
    for name, r in (("user_sets", users), ("object_sets", objects)):
        doc[name].update(
            {"median": float(np.median(r)), "max": float(r.max()), "above_limit": int((r > REACH_LIMIT).sum())}
        )
        rows += [
            {
                "metric": f"true surface's reach beyond the contacts, median ({name})",
                "value": float(np.median(r)),
                "unit": "spans",
                "sets": len(r),
            },
            {
                "metric": f"true surface's reach beyond the contacts, largest ({name})",
                "value": float(r.max()),
                "unit": "spans",
                "sets": len(r),
            },
            {
                "metric": f"true surfaces reaching beyond REACH_LIMIT {REACH_LIMIT} ({name})",
                "value": int((r > REACH_LIMIT).sum()),
                "unit": "sets",
                "sets": len(r),
            },
        ]
    write_text(RESULTS / "reach.json", json.dumps(doc, indent=2) + "\n")
    return rows
