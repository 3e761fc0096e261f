"""Shape from touch on objects that are not one superquadric (issue "Objects that are not one superquadric").

Truths (:func:`object_mesh`; lengths in metres): watertight triangle meshes built by constructive solid geometry
(``trimesh.boolean`` with the manifold3d engine) and by deforming superquadric meshes, eight kinds with their
dimensions drawn per set, a Haar-random orientation and a centre in [−5, 5] cm³:

* ``snowman``: two spheres, radii r₁ ~ U[15, 25] mm and U[0.5, 0.8] r₁, overlapping (centres U[0.6, 0.85] of the
  radii's sum apart) — a union of two n-ellipsoids, the parts model's own family;
* ``dumbbell``: two spheres r ~ U[12, 18] mm whose centres are U[45, 65] mm apart, joined by a bar of radius
  U[0.35, 0.5] r;
* ``mug``: a cylinder R ~ U[18, 28] mm, height U[1.3, 2] R, hollowed from the top (wall U[3, 5] mm, floor 4 mm),
  with a torus handle (major radius U[0.45, 0.6] R, tube 3.5 mm) on its side — a concavity and a hole;
* ``hammer``: a box head U[50, 70] × U[16, 24] × U[16, 24] mm on a cylindrical handle of radius U[5, 7] mm
  and length U[60, 90] mm;
* ``l_block``: two boxes, U[40, 60] × U[15, 25] × U[15, 25] mm each, at right angles sharing one end;
* ``bent``: an n-ellipsoid (n ~ U[2, 4], semi-axes U[30, 45], U[10, 16], U[10, 16] mm) bent about its second axis
  with radius U[1, 2] times its long semi-axis;
* ``tapered``: an n-ellipsoid (n ~ U[2, 4], semi-axes U[15, 25], U[15, 25], U[25, 40] mm) whose cross-section
  shrinks linearly along its third axis to U[0.3, 0.6] of its size at the top;
* ``bitten``: a sphere r ~ U[20, 30] mm minus a sphere of U[0.5, 0.8] r centred U[0.8, 1.05] r from its centre
  (a deep concavity).

Touch data, as :mod:`benchmarks.bench_user_sets` draws them on a superquadric: M ~ U{60..100} contacts on
K ~ U{4..8} strokes, each a great-circle arc of directions of U[0.6, 1.4] rad inside a cap of half-angle
U[100°, 180°] about a random approach direction, centred on the mesh's centre of mass; the contact of a direction
d is where a finger coming from outside along −d first meets the mesh (the first ray hit from the centre + 0.5 m
d), so a hollow or a handle is touched where a finger would touch it. 0.3 mm Gaussian noise per coordinate;
a fraction U[0, 0.15] of the contacts displaced U[3, 10] mm along the face normal, inwards or outwards (each
redrawn until it lies on its side of the surface); 5 free-space finger positions 3–30 mm out along each stroke's
approach (tilted up to 30° from the normal; redrawn until outside the mesh by its winding number). A displacement
that ends on the wrong side whatever its length (a contact in a concave corner) is not made.

Methods on the same points: bayestouch's default fit (:func:`bayestouch.inference.run.run_contact_fit`, the
free-space positions given, every setting its default), bayestouch's parts fit (``fit --parts auto``:
:func:`bayestouch.inference.parts_run.run_parts_fit`, one or two n-ellipsoids by the evidence, its mean surface
the occupancy's 0.5 level set), sage-superquadric's default least-squares fit, and the Gaussian-process implicit
surface of :mod:`bayestouch.inference.gpis`.

Metrics: Chamfer distance to the true mesh (exact surface distances, :func:`bayestouch.geometry.compare
.chamfer_surfaces`) over the object's size s, the mean half-extent of its oriented bounding box (for an
n-ellipsoid, about its mean semi-axis, the normalisation of ``bench_user_sets``); |V̂/V − 1|; for bayestouch the
coverage of the 90 % volume interval and the converged fits. Medians with bootstrap 95 % intervals, proportions
with Wilson intervals.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from benchmarks import bench_user_sets as us

#: object kinds, in the order the sets cycle through them
KINDS = ("snowman", "dumbbell", "mug", "hammer", "l_block", "bent", "tapered", "bitten")
CENTRE_RANGE_M = 0.05
POINTS_RANGE = (60, 100)
STROKES_RANGE = (4, 8)
ARC_RANGE_RAD = (0.6, 1.4)
CAP_RANGE_DEG = (100.0, 180.0)
NOISE_M = 3e-4
OUTLIER_FRACTION_MAX = 0.15
OUTLIER_RANGE_M = (3e-3, 1e-2)
FREE_PER_STROKE = 5
FREE_RANGE_M = (3e-3, 3e-2)
FREE_TILT_MAX_RAD = math.radians(30.0)
#: distance from the centre of mass at which a simulated finger starts its approach, metres
RAY_START_M = 0.5
MAX_REDRAWS = 200
CHAMFER_COUNT = 4000
METHODS = ("bayestouch", "bayestouch-parts", "sage", "gpis")
RESULTS = Path(__file__).resolve().parent / "results"


class ObjectSet(NamedTuple):
    """One non-superquadric object and a touch data set on it (:func:`make_object_set`).

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    vertices : (V, 3) float, metres
    faces : (F, 3) int
        The watertight true mesh, outward oriented.
    volume : float, m³
    size : float, metres
        Mean half-extent of the oriented bounding box.
    points : (M, 3) float, metres
        Contacts in stroke order, noise and displaced contacts included.
    outlier_sign : (M,) int
        +1 displaced outwards, −1 inwards, 0 not displaced.
    free_space : (K, 3) float, metres
        Finger positions outside the object.
    stroke : (M,) int
    seed : int
    """

    kind: str
    vertices: np.ndarray
    faces: np.ndarray
    volume: float
    size: float
    points: np.ndarray
    outlier_sign: np.ndarray
    free_space: np.ndarray
    stroke: np.ndarray
    seed: int


def _union(parts):
    import trimesh

    return trimesh.boolean.union(parts, engine="manifold")


def _difference(a, b):
    import trimesh

    return trimesh.boolean.difference([a, b], engine="manifold")


def _superquadric(axes, n, res: int = 40):
    import trimesh

    from bayestouch.backend import jnp
    from bayestouch.geometry import nellipsoid as ne
    from bayestouch.geometry.mesh import nellipsoid_mesh

    s = ne.NEllipsoid(jnp.zeros(3), jnp.asarray(axes, float), jnp.zeros(3), jnp.asarray(float(n)))
    v, f = nellipsoid_mesh(s, res)
    return trimesh.Trimesh(np.asarray(v), np.asarray(f), process=True)


def object_mesh(kind: str, rng: np.random.Generator):
    """A watertight true mesh of ``kind`` (:data:`KINDS`) in its own frame, dimensions drawn from ``rng``
    (module docstring), metres.

    Returns
    -------
    trimesh.Trimesh

    Raises
    ------
    ValueError
        An unknown kind.
    """
    import trimesh
    from trimesh.creation import box, cylinder, icosphere, torus

    mm = 1e-3
    u = rng.uniform
    if kind == "snowman":
        r1 = u(15, 25) * mm
        r2 = u(0.5, 0.8) * r1
        gap = u(0.6, 0.85) * (r1 + r2)
        mesh = _union([icosphere(4, r1), icosphere(4, r2).apply_translation([0, 0, gap])])
    elif kind == "dumbbell":
        r = u(12, 18) * mm
        sep = u(45, 65) * mm
        bar = cylinder(u(0.35, 0.5) * r, sep, sections=48)
        mesh = _union(
            [
                icosphere(4, r).apply_translation([0, 0, -sep / 2]),
                icosphere(4, r).apply_translation([0, 0, sep / 2]),
                bar,
            ]
        )
    elif kind == "mug":
        R = u(18, 28) * mm
        h = u(1.3, 2.0) * R
        wall = u(3, 5) * mm
        body = cylinder(R, h, sections=64)
        hollow = cylinder(R - wall, h, sections=64).apply_translation([0, 0, 4 * mm])
        major = u(0.45, 0.6) * R
        handle = torus(major, 3.5 * mm, major_sections=48, minor_sections=16)
        handle.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))
        handle.apply_translation([R + major - 0.6 * 3.5 * mm, 0, 0])
        mesh = _union([_difference(body, hollow), handle])
    elif kind == "hammer":
        head = box([u(50, 70) * mm, u(16, 24) * mm, u(16, 24) * mm])
        r, length = u(5, 7) * mm, u(60, 90) * mm
        handle = cylinder(r, length, sections=48).apply_translation([0, 0, -length / 2])
        mesh = _union([head, handle])
    elif kind == "l_block":
        a = box([u(40, 60) * mm, u(15, 25) * mm, u(15, 25) * mm])
        e = a.extents
        b = box([u(15, 25) * mm, e[1], u(40, 60) * mm])
        b.apply_translation([e[0] / 2 - b.extents[0] / 2, 0, b.extents[2] / 2 - e[2] / 2])
        mesh = _union([a, b])
    elif kind == "bent":
        ax = np.array([u(30, 45), u(10, 16), u(10, 16)]) * mm
        mesh = _superquadric(ax, u(2, 4))
        rad = u(1, 2) * ax[0]
        v = mesh.vertices.copy()
        t = v[:, 0] / rad
        mesh = trimesh.Trimesh(
            np.column_stack([(rad - v[:, 2]) * np.sin(t), v[:, 1], rad - (rad - v[:, 2]) * np.cos(t)]), mesh.faces
        )
    elif kind == "tapered":
        ax = np.array([u(15, 25), u(15, 25), u(25, 40)]) * mm
        mesh = _superquadric(ax, u(2, 4))
        top = u(0.3, 0.6)
        v = mesh.vertices.copy()
        k = 1.0 + (top - 1.0) * (v[:, 2] / ax[2] + 1.0) / 2.0
        v[:, :2] *= k[:, None]
        mesh = trimesh.Trimesh(v, mesh.faces)
    elif kind == "bitten":
        r = u(20, 30) * mm
        bite = icosphere(4, u(0.5, 0.8) * r).apply_translation([u(0.8, 1.05) * r, 0, 0])
        mesh = _difference(icosphere(4, r), bite)
    else:
        raise ValueError(f"object_mesh: unknown kind {kind!r}; expected one of {KINDS}")
    if not mesh.is_watertight or mesh.volume <= 0:
        raise RuntimeError(f"object_mesh: the {kind} mesh is not a watertight solid")
    return mesh


def _first_hits(mesh, origins, directions):
    """First intersection (N, 3) m of each ray with ``mesh`` and the hit face's outward normal (N, 3); NaN rows
    for rays that miss."""
    locs, ray_idx, tri_idx = mesh.ray.intersects_location(origins, directions, multiple_hits=True)
    hits = np.full((len(origins), 3), np.nan)
    normals = np.full((len(origins), 3), np.nan)
    if len(ray_idx):
        dist = np.einsum("ij,ij->i", locs - origins[ray_idx], directions[ray_idx])
        order = np.lexsort((dist, ray_idx))
        first = order[np.r_[True, ray_idx[order][1:] != ray_idx[order][:-1]]]
        hits[ray_idx[first]] = locs[first]
        normals[ray_idx[first]] = mesh.face_normals[tri_idx[first]]
    return hits, normals


def make_object_set(seed: int, kind: str | None = None, noise_m: float = NOISE_M) -> ObjectSet:
    """A random object of ``kind`` (default: drawn) and a sparse, one-sided, contaminated touch set on it
    (module docstring); independent streams of ``np.random.default_rng(seed)`` for the object, the strokes, the
    noise, the displaced contacts and the free space.

    Parameters
    ----------
    seed : int
    kind : str, optional
        One of :data:`KINDS`.
    noise_m : float, metres
        Contact (and free-space) noise sd.

    Returns
    -------
    ObjectSet
    """
    from bayestouch.geometry.winding import mesh_inside

    r_obj, r_strokes, r_noise, r_out, r_free = np.random.default_rng(seed).spawn(5)
    kind = KINDS[int(r_obj.integers(len(KINDS)))] if kind is None else kind
    mesh = object_mesh(kind, r_obj)
    R = us.random_rotations(r_obj, 1)[0]
    mesh.apply_translation(-mesh.center_mass)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = r_obj.uniform(-CENTRE_RANGE_M, CENTRE_RANGE_M, 3)
    mesh.apply_transform(T)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    centre = np.asarray(mesh.center_mass)
    size = float(np.mean(mesh.bounding_box_oriented.primitive.extents) / 2.0)

    m = int(r_strokes.integers(POINTS_RANGE[0], POINTS_RANGE[1] + 1))
    k = int(r_strokes.integers(STROKES_RANGE[0], STROKES_RANGE[1] + 1))
    cap = math.radians(r_strokes.uniform(*CAP_RANGE_DEG))
    h = us.unit(r_strokes.normal(size=3))
    arcs = r_strokes.uniform(*ARC_RANGE_RAD, k)
    counts = us.stroke_counts(m, arcs)
    surf, nrm = [], []
    for a, c in zip(arcs, counts, strict=True):
        for _ in range(MAX_REDRAWS):
            d = us.stroke_directions(r_strokes, h, cap, a, c)
            p, n_ = _first_hits(mesh, centre + RAY_START_M * d, -d)
            if np.all(np.isfinite(p)):
                break
        else:
            raise RuntimeError("make_object_set: no stroke meets the object")
        surf.append(p)
        nrm.append(n_)
    surf, nrm = np.concatenate(surf), np.concatenate(nrm)
    stroke = np.repeat(np.arange(k), counts)
    noise = r_noise.normal(0.0, noise_m, surf.shape)
    pts = surf + noise

    frac = r_out.uniform(0.0, OUTLIER_FRACTION_MAX)
    idx = np.sort(r_out.choice(m, int(round(frac * m)), replace=False))
    sign = np.where(r_out.uniform(size=len(idx)) < 0.5, 1, -1)
    todo = np.ones(len(idx), bool)
    for _ in range(MAX_REDRAWS):
        if not todo.any():
            break
        j = idx[todo]
        pts[j] = surf[j] + noise[j] + (sign[todo] * r_out.uniform(*OUTLIER_RANGE_M, len(j)))[:, None] * nrm[j]
        inside = mesh_inside(V, F, pts[idx]) if len(idx) else np.zeros(0, bool)
        todo = np.where(sign > 0, inside, ~inside)
    # a contact in a concave corner whose displacement ends in the other part of the solid whatever its length
    # stays where it was, not displaced
    j = idx[todo]
    pts[j] = surf[j] + noise[j]
    outlier_sign = np.zeros(m, int)
    outlier_sign[idx] = np.where(todo, 0, sign)

    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tilt = r_free.uniform(0.0, FREE_TILT_MAX_RAD, k)
    side = us.unit(np.cross(nrm[first], r_free.normal(size=(k, 3))))
    along = nrm[first] * np.cos(tilt)[:, None] + side * np.sin(tilt)[:, None]
    dist = np.linspace(*FREE_RANGE_M, FREE_PER_STROKE)
    ideal = (surf[first][:, None, :] + dist[None, :, None] * along[:, None, :]).reshape(-1, 3)
    free = ideal.copy()
    todo = np.ones(len(free), bool)
    for _ in range(MAX_REDRAWS):
        if not todo.any():
            break
        free[todo] = ideal[todo] + r_free.normal(0.0, noise_m, (int(todo.sum()), 3))
        todo = mesh_inside(V, F, free)
    else:  # a position in a hollow that the approach line crosses back into the solid: dropped
        free = free[~todo]
    return ObjectSet(kind, V, F, float(mesh.volume), size, pts, outlier_sign, free, stroke, int(seed))


def make_object_sets(count: int, seed: int = 0) -> list[ObjectSet]:
    """``count`` sets with seeds ``1000 seed + i``, the kinds cycling through :data:`KINDS`."""
    return [make_object_set(1000 * int(seed) + i, KINDS[i % len(KINDS)]) for i in range(int(count))]


# ---------------------------------------------------------------------------------------- methods


def mesh_metrics(estimate, volume: float, d: ObjectSet, seed: int = 0) -> dict:
    """Chamfer / size and volume error of an estimate (NEllipsoid or (vertices, faces)) against the true mesh."""
    from bayestouch.geometry.compare import chamfer_surfaces

    ch, se = chamfer_surfaces(estimate, (d.vertices, d.faces), count=CHAMFER_COUNT, seed=seed)
    return {
        "volume_est_m3": float(volume),
        "volume_error": abs(float(volume) / d.volume - 1.0),
        "chamfer_m": ch,
        "chamfer_se_m": se,
        "chamfer_ratio": ch / d.size,
    }


def fit_parts(d: ObjectSet, seed: int = 0) -> dict:
    """bayestouch's parts fit (:func:`bayestouch.inference.parts_run.run_parts_fit`, ``parts="auto"``, every
    other setting its default) of the set's contacts and free space, timed; its mean surface read back from
    ``mean_shape.ply``.

    Returns
    -------
    dict
        ``summary``, ``seconds``, ``mesh`` ((vertices, faces) or None).
    """
    import trimesh

    from bayestouch.inference.parts_run import run_parts_fit

    with tempfile.TemporaryDirectory(prefix="bt-parts-") as tmp:
        t0 = time.perf_counter()
        summary = run_parts_fit(d.points, Path(tmp) / "run", seed=seed, free=d.free_space, progress=False)
        seconds = time.perf_counter() - t0
        ply = Path(tmp) / "run" / "mean_shape.ply"
        mesh = None
        if ply.is_file():
            m = trimesh.load(ply, process=False)
            mesh = (np.asarray(m.vertices), np.asarray(m.faces))
    return {"summary": summary, "seconds": seconds, "mesh": mesh}


def _reach(s: dict) -> float:
    """The posterior median of the surface's reach beyond the contacts (``diagnostics.reach``; NaN without it)."""
    r = s["diagnostics"].get("reach")
    return float(r["median"]) if r else float("nan")


def _calibration(s: dict, d: ObjectSet) -> dict:
    """A bayestouch run's volume interval against the truth, its convergence and warnings (``bt_`` columns)."""
    vol = s["derived"]["volume_m3"]
    return {
        "bt_volume_covered": bool(vol["q05"] <= d.volume <= vol["q95"]),
        "bt_volume_q05_m3": vol["q05"],
        "bt_volume_q95_m3": vol["q95"],
        "bt_converged": bool(s["diagnostics"]["converged"]),
        "bt_max_r_hat": float(s["diagnostics"]["max_r_hat"]),
        "bt_reach": _reach(s),
        "bt_extrapolated": bool(s["diagnostics"].get("extrapolated", False)),
        "bt_warnings": "; ".join(s["diagnostics"].get("warnings", [])),
    }


def fit_set(d: ObjectSet, method: str, index: int = 0) -> dict:
    """Fit one set with one method: its CSV row (the set's description, ``seconds``, :func:`mesh_metrics`' keys,
    NaN with ``error`` set when the method failed; for bayestouch its volume interval's coverage, ``converged``
    and its warnings)."""
    if method not in METHODS:
        raise ValueError(f"fit_set: unknown method {method!r}; expected one of {METHODS}")
    row = {
        "set": index,
        "seed": d.seed,
        "kind": d.kind,
        "method": method,
        "points": len(d.points),
        "strokes": int(d.stroke.max() + 1),
        "outlier_fraction": float(np.mean(d.outlier_sign != 0)),
        "size_m": d.size,
        "volume_m3": d.volume,
        "error": "",
    }
    nan = float("nan")
    failed = dict.fromkeys(("volume_est_m3", "volume_error", "chamfer_m", "chamfer_se_m", "chamfer_ratio"), nan)
    try:
        if method == "bayestouch":
            fit = us.fit_bayestouch_default(d.points, seed=d.seed, free=d.free_space)
            s = fit["summary"]
            vol = s["derived"]["volume_m3"]
            row["seconds"] = fit["seconds"]
            row.update(mesh_metrics(us.mean_shape(s), vol["mean"], d, seed=index))
            row.update(_calibration(s, d))
        elif method == "bayestouch-parts":
            fit = fit_parts(d, seed=d.seed)
            s = fit["summary"]
            vol = s["derived"]["volume_m3"]
            row["seconds"] = fit["seconds"]
            if fit["mesh"] is None:
                row.update(failed, error="bayestouch-parts: no mean surface")
            else:
                row.update(mesh_metrics(fit["mesh"], vol["mean"], d, seed=index))
            row.update(_calibration(s, d), bt_parts=int(s["model"]["parts"]))
        elif method == "sage":
            from benchmarks.bench_sparse import fit_sage

            sq = fit_sage(d.points)
            row["seconds"] = sq["seconds"]
            row.update(mesh_metrics(sq["mesh"], sq["volume"], d, seed=index))
        else:
            from bayestouch.inference.gpis import fit_gpis

            t0 = time.perf_counter()
            g = fit_gpis(d.points)
            row["seconds"] = time.perf_counter() - t0
            if not np.isfinite(g.volume):
                row.update(failed, error="gpis: the GP mean has no zero crossing on the grid")
            else:
                row.update(mesh_metrics((g.vertices, g.faces), g.volume, d, seed=index))
    except Exception as exc:  # noqa: BLE001 - a method's crash is a result of the benchmark, recorded as such
        row.setdefault("seconds", nan)
        row.update(failed, error=f"{type(exc).__name__}: {exc}"[:200])
    return row


# ---------------------------------------------------------------------------------------- summary


def summarise(rows: list[dict], seed: int = 0) -> dict:
    """Per method: bootstrap medians (95 % intervals) of Chamfer / size and volume error (a failed fit counts as
    +inf), time median and p95; for bayestouch methods the Wilson interval of the 90 % volume coverage and the
    converged count. Per kind: each method's median Chamfer / size."""
    out = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        rs = [r for r in rows if r["method"] == method]
        fin = [r for r in rs if not r["error"]]

        def block(key, rs=rs):
            med, lo, hi = us.bootstrap_median([r[key] if np.isfinite(r[key]) else np.inf for r in rs], seed=seed)
            return {"median": med, "ci95": [lo, hi]}

        secs = np.array([r["seconds"] for r in rs if np.isfinite(r.get("seconds", np.nan))])
        s = {
            "sets": len(rs),
            "failed": len(rs) - len(fin),
            "chamfer_ratio": block("chamfer_ratio"),
            "volume_error": block("volume_error"),
            "seconds": {
                "median": float(np.median(secs)) if secs.size else float("nan"),
                "p95": float(np.quantile(secs, 0.95)) if secs.size else float("nan"),
            },
            "by_kind": {
                k: float(np.median([r["chamfer_ratio"] for r in rs if r["kind"] == k]))
                for k in dict.fromkeys(r["kind"] for r in rs)
            },
        }
        if fin and "bt_volume_covered" in fin[0]:
            kc = sum(bool(r["bt_volume_covered"]) for r in fin)
            lo, hi = us.wilson_interval(kc, len(fin))
            s["volume_coverage_90"] = {"k": kc, "n": len(fin), "fraction": kc / len(fin), "wilson95": [lo, hi]}
            s["converged"] = sum(bool(r["bt_converged"]) for r in fin)
        if fin and np.isfinite(fin[0].get("bt_reach", np.nan)):
            s["extrapolated"] = _extrapolation(fin)
        if fin and "bt_parts" in fin[0]:
            s["parts_chosen"] = {str(k): sum(int(r["bt_parts"]) == k for r in fin) for k in (1, 2, 3, 4)}
        out[method] = s
    return out


def _fmt(x) -> str:
    return "–" if x is None else f"{x:.3g}"


def _extrapolation(rows: list[dict]) -> dict:
    """How the fit's extrapolation warning (``diagnostics.extrapolated``) splits the sets: how many it flagged, and
    the median Chamfer / size and the 90 % volume coverage of the flagged and the other sets."""
    out = {"flagged": int(sum(bool(r["bt_extrapolated"]) for r in rows)), "sets": len(rows)}
    for name, flag in (("flagged", True), ("not_flagged", False)):
        rs = [r for r in rows if bool(r["bt_extrapolated"]) == flag]
        out[f"chamfer_ratio_median_{name}"] = float(np.median([r["chamfer_ratio"] for r in rs])) if rs else None
        out[f"volume_covered_{name}"] = int(sum(bool(r["bt_volume_covered"]) for r in rs))
    out["reach_median"] = float(np.median([r["bt_reach"] for r in rows]))
    return out


def markdown_table(summary: dict, note: str = "") -> str:
    """Markdown tables of :func:`summarise`'s result."""

    def ci(b):
        return f"{b['median']:.3g} [{b['ci95'][0]:.3g}, {b['ci95'][1]:.3g}]"

    lines = ["# Shape of objects that are not one superquadric (benchmarks/bench_objects.py)", ""]
    if note:
        lines += [note, ""]
    lines += [
        "| method | sets | failed | median Chamfer / size [95 % CI] | median volume error [95 % CI] "
        "| 90 % volume coverage [Wilson 95 %] | converged | time median (s) | time p95 (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for m, s in summary.items():
        cov = s.get("volume_coverage_90")
        cov_s = f"{cov['k']}/{cov['n']} [{cov['wilson95'][0]:.2f}, {cov['wilson95'][1]:.2f}]" if cov else "–"
        conv = f"{s['converged']}/{s['sets'] - s['failed']}" if "converged" in s else "–"
        lines.append(
            f"| {m} | {s['sets']} | {s['failed']} | {ci(s['chamfer_ratio'])} | {ci(s['volume_error'])} | {cov_s} "
            f"| {conv} | {s['seconds']['median']:.3g} | {s['seconds']['p95']:.3g} |"
        )
    for m, s in summary.items():
        e = s.get("extrapolated")
        if e:
            lines += [
                "",
                f"{m}: the extrapolation warning flagged {e['flagged']}/{e['sets']} sets (median Chamfer / size "
                f"{_fmt(e['chamfer_ratio_median_flagged'])} flagged, {_fmt(e['chamfer_ratio_median_not_flagged'])} "
                f"not; volume covered {e['volume_covered_flagged']} flagged, {e['volume_covered_not_flagged']} not).",
            ]
    kinds = list(next(iter(summary.values()))["by_kind"]) if summary else []
    lines += ["", "Median Chamfer / size by kind:", "", "| kind | " + " | ".join(summary) + " |"]
    lines.append("|---|" + "---|" * len(summary))
    for k in kinds:
        lines.append(
            f"| {k} | " + " | ".join(f"{s['by_kind'].get(k, float('nan')):.3g}" for s in summary.values()) + " |"
        )
    return "\n".join(lines) + "\n"


def bench_objects(count: int | None = None, seed: int = 0, methods=METHODS, out: Path | None = RESULTS) -> list[dict]:
    """Fit every set with each method; write ``objects.csv``, ``objects.json`` and ``objects.md`` to ``out``.

    Parameters
    ----------
    count : int, optional
        Number of sets (default ``$BAYESTOUCH_OBJECT_SETS`` or 16: two of each kind). ``$BAYESTOUCH_OBJECT_SHARD``
        ``k/K`` fits the sets i ≡ k (mod K) only (run K processes at once; the last to finish writes the summary).
    seed : int
    methods : sequence of :data:`METHODS`
    out : Path or None

    Returns
    -------
    list of dict
        Result rows for :mod:`benchmarks.harness`.
    """
    from tqdm import tqdm

    from bayestouch.io.files import write_csv_rows, write_json, write_text

    count = int(os.environ.get("BAYESTOUCH_OBJECT_SETS", 16)) if count is None else int(count)
    methods = tuple(methods)
    if any(m not in METHODS for m in methods):
        raise ValueError(f"bench_objects: methods must be some of {METHODS}, got {methods}")
    shard = os.environ.get("BAYESTOUCH_OBJECT_SHARD")  # "k/K": fit only sets i with i % K == k, save the rows
    k_of = tuple(int(v) for v in shard.split("/")) if shard else (0, 1)
    sets = make_object_sets(count, seed)
    mine = [i for i in range(count) if i % k_of[1] == k_of[0]]
    rows = []
    with tqdm(total=len(mine) * len(methods), desc="objects", unit="fit") as bar:
        for i in mine:
            for method in methods:
                bar.set_postfix_str(f"{sets[i].kind} {method}")
                rows.append(fit_set(sets[i], method, i))
                bar.update()
    if shard:
        if out is None:
            return []
        write_json(Path(out) / f"objects.shard{k_of[0]}of{k_of[1]}.json", rows)
        shards = sorted(Path(out).glob(f"objects.shard*of{k_of[1]}.json"))
        if len(shards) < k_of[1]:
            return []  # the last shard to finish writes the summary
        rows = sorted((r for f in shards for r in json.loads(f.read_text())), key=lambda r: (r["set"], r["method"]))
    summary = summarise(rows, seed)
    if out is not None:
        out = Path(out)
        write_csv_rows(out / "objects.csv", rows)
        write_json(out / "objects.json", {"sets": count, "seed": seed, **summary})
        write_text(out / "objects.md", markdown_table(summary, f"{count} sets (seed {seed}), {len(KINDS)} kinds."))
    results = []
    for m, s in summary.items():
        common = {"method": m, "sets": s["sets"], "failed": s["failed"]}
        for key, label in (("chamfer_ratio", "median Chamfer / size"), ("volume_error", "median volume error")):
            results.append({"metric": label, "value": s[key]["median"], "unit": "1", "ci95": s[key]["ci95"], **common})
        results.append({"metric": "seconds per set (median)", "value": s["seconds"]["median"], "unit": "s", **common})
        if "volume_coverage_90" in s:
            p = s["volume_coverage_90"]
            results.append(
                {"metric": "90 % volume interval coverage", "value": p["fraction"], "unit": "1", **common}
                | {"wilson95": p["wilson95"]}
            )
    return results
