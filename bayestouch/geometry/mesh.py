"""Triangulated surfaces: watertight cube-sphere meshes of n-ellipsoids, area-uniform sampling,
closest points on a mesh, and conversion to trimesh.

Meshes are plain arrays: ``vertices (V, 3) float, metres`` and ``faces (F, 3) int`` with outward
(counter-clockwise seen from outside) orientation. NumPy at this edge.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from bayestouch.backend import jnp
from bayestouch.errors import BadInput, check_int, shown
from bayestouch.geometry.nellipsoid import NEllipsoid, check_shape, project_to_surface, surface_point, unit_nsphere

__all__ = [
    "cube_sphere",
    "nellipsoid_mesh",
    "triangle_areas",
    "sample_mesh",
    "sample_surface",
    "closest_points",
    "to_trimesh",
    "as_rng",
    "check_res",
    "MAX_MESH_RES",
]

#: finest cube-sphere resolution of a mesh (cells per cube edge): 512 gives 1.6 million vertices and 3.1 million
#: triangles in a few seconds; 10⁶ ended in a MemoryError
MAX_MESH_RES = 512


def as_rng(seed) -> np.random.Generator:
    """A ``np.random.Generator`` from an int seed ≥ 0 (or a sequence of them, or a ``SeedSequence``), a Generator
    (returned as is) or None (fresh entropy); anything else (text, a float, a negative number) is refused in one
    line naming ``seed``."""
    if isinstance(seed, np.random.Generator):
        return seed
    if not isinstance(seed, bool | np.bool_ | float | np.floating):
        try:
            return np.random.default_rng(seed)
        except (TypeError, ValueError):
            pass
    raise BadInput(f"seed: expected an integer ≥ 0, a numpy Generator or None, got {shown(seed)}")


def check_res(res, name: str = "res") -> int:
    """``res`` as an int, or a one-line refusal naming ``name`` when it is not a cube-sphere resolution from 1 to
    :data:`MAX_MESH_RES` cells per cube edge."""
    return check_int(res, name, 1, MAX_MESH_RES, "an integer resolution (cells per cube edge)")


@lru_cache(maxsize=32)
def _cube_topology(res: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer lattice points on the surface of the cube {0..res}³ and outward triangles."""
    if res < 1:
        raise ValueError(f"resolution must be a positive integer, got {res}")
    i, j = np.meshgrid(np.arange(res + 1), np.arange(res + 1), indexing="ij")
    quads = []
    pts = []
    offset = 0
    for axis in range(3):
        u_ax, v_ax = [a for a in range(3) if a != axis]
        for side in (0, res):
            p = np.zeros((res + 1, res + 1, 3), dtype=np.int64)
            p[..., axis] = side
            p[..., u_ax] = i
            p[..., v_ax] = j
            idx = offset + np.arange((res + 1) ** 2).reshape(res + 1, res + 1)
            a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
            c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
            t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
            # orientation: (u, v, axis) right-handed ⇒ CCW seen from +axis; flip for the low side
            right_handed = (u_ax, v_ax, axis) in ((0, 1, 2), (1, 2, 0), (2, 0, 1))
            if right_handed != (side == res):
                t = t[:, ::-1]
            quads.append(t)
            pts.append(p.reshape(-1, 3))
            offset += (res + 1) ** 2
    pts = np.concatenate(pts)
    tris = np.concatenate(quads)
    uniq, inverse = np.unique(pts, axis=0, return_inverse=True)
    return uniq, inverse.ravel()[tris]


def cube_sphere(res: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions on the cube [−1, 1]³ (equi-angular grid) and outward faces; a watertight sphere topology.

    Parameters
    ----------
    res : int
        Cells per cube edge; the mesh has 6·res² quads (12·res² triangles) and 6·res² + 2 vertices.

    Returns
    -------
    directions : (V, 3) float
    faces : (F, 3) int
    """
    lattice, faces = _cube_topology(int(res))
    t = np.tan(np.pi / 4 * (2.0 * lattice / res - 1.0))
    t[np.abs(lattice * 2 - res) == res] = np.sign(lattice * 2 - res)[np.abs(lattice * 2 - res) == res]
    return t, faces.copy()


def nellipsoid_mesh(s: NEllipsoid, res: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Watertight triangle mesh of the n-ellipsoid ``s`` (eq. 4–6), metres.

    Parameters
    ----------
    s : NEllipsoid
    res : int
        Cells per cube edge, 1 to :data:`MAX_MESH_RES`.

    Returns
    -------
    vertices : (6·res² + 2, 3) float, metres
    faces : (12·res², 3) int, outward
    """
    check_shape(s)
    d, faces = cube_sphere(check_res(res))
    Y = unit_nsphere(jnp.asarray(d), s.n)
    return np.asarray(surface_point(s, Y)), faces


def triangle_areas(vertices, faces) -> np.ndarray:
    """Areas (F,) of the triangles, m²."""
    v = np.asarray(vertices)
    e1 = v[faces[:, 1]] - v[faces[:, 0]]
    e2 = v[faces[:, 2]] - v[faces[:, 0]]
    return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)


def sample_mesh(vertices, faces, count: int, seed=None) -> tuple[np.ndarray, np.ndarray]:
    """Points uniform by area on a triangle mesh.

    Returns
    -------
    points : (count, 3) float, metres
    face_index : (count,) int
    """
    rng = as_rng(seed)
    v = np.asarray(vertices)
    w = triangle_areas(v, faces)
    fi = rng.choice(len(faces), size=count, p=w / w.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s1 = np.sqrt(r1)
    b0, b1, b2 = 1 - s1, s1 * (1 - r2), s1 * r2
    tri = v[faces[fi]]
    pts = b0[:, None] * tri[:, 0] + b1[:, None] * tri[:, 1] + b2[:, None] * tri[:, 2]
    return pts, fi


#: most points :func:`sample_surface` draws at once (10⁷ points: 240 MB; 10¹² ended in a MemoryError)
MAX_SURFACE_POINTS = 10_000_000


def sample_surface(s: NEllipsoid, count: int, seed=None, res: int = 48) -> np.ndarray:
    """Points uniform by surface area on the n-ellipsoid ``s`` (not uniform in its parameters).

    Draws uniformly on a fine inscribed mesh, then moves each point radially onto the exact surface;
    the density error is of the order of the mesh's relative area error (≈ 1e-3 at ``res = 48``).

    Parameters
    ----------
    s : NEllipsoid or SceneObject
        The shape (a scene object's ``shape`` is used).
    count : int
        Number of points, 1 to :data:`MAX_SURFACE_POINTS`.
    seed : int, np.random.Generator or None
    res : int
        Resolution of the inscribed mesh (:func:`nellipsoid_mesh`).

    Returns
    -------
    (count, 3) float, metres
    """
    if not isinstance(s, NEllipsoid):
        if isinstance(getattr(s, "shape", None), NEllipsoid):  # a SceneObject: its n-ellipsoid
            s = s.shape
        else:
            raise BadInput(
                f"shape: expected an NEllipsoid (or a SceneObject, whose shape is used), got {type(s).__name__}"
            )
    if isinstance(count, bool) or not isinstance(count, int | np.integer) or not 1 <= count <= MAX_SURFACE_POINTS:
        raise BadInput(f"count: expected an integer number of points from 1 to {MAX_SURFACE_POINTS:,}, got {count!r}")
    rng = as_rng(seed)  # a bad seed refused before the mesh is made
    v, f = nellipsoid_mesh(s, res)
    pts, _ = sample_mesh(v, f, count, rng)
    return np.asarray(project_to_surface(s, jnp.asarray(pts)))


def _closest_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p, all (N, 3); Ericson, RTCD §5.1.5."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        out = a + ab * v[:, None] + ac * w[:, None]
        # edge regions
        # a degenerate triangle (two equal corners: booleans and scans produce them) has a zero-length edge, whose
        # denominator (its squared length: d1 − d3 = |ab|², d2 − d6 = |ac|², the bc one |bc|²) is 0: that edge's
        # region is skipped, the others hold the closest point, never NaN
        vab = np.where(d1 != d3, d1 / (d1 - d3), 0.0)
        e_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0) & (d1 != d3)
        out = np.where(e_ab[:, None], a + ab * vab[:, None], out)
        wac = np.where(d2 != d6, d2 / (d2 - d6), 0.0)
        e_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0) & (d2 != d6)
        out = np.where(e_ac[:, None], a + ac * wac[:, None], out)
        den_bc = (d4 - d3) + (d5 - d6)
        wbc = np.where(den_bc != 0, (d4 - d3) / den_bc, 0.0)
        e_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0) & (den_bc != 0)
        out = np.where(e_bc[:, None], b + (c - b) * wbc[:, None], out)
    # vertex regions
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    return out


def closest_points(
    vertices, faces, points, k: int = 12, *, exact: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points on a triangle mesh to query points.

    Candidates are the ``k`` triangles whose centroids are nearest (exact for meshes whose triangles
    are small compared with the distance structure, as ours are; raise ``k`` for coarse meshes). With ``exact``,
    the answer is the closest point over all triangles: the candidates give an upper bound D on the distance, and
    every triangle whose centroid lies farther than D + r_max (r_max the largest centroid-to-vertex distance of any
    triangle) is farther than D, so a point is done once its k-th nearest centroid lies beyond D + r_max; for the
    points where it does not, k is doubled.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    points : (N, 3) float, metres
    k : int
        (Initial) number of candidate triangles per point.
    exact : bool

    Returns
    -------
    closest : (N, 3) float, metres
    distance : (N,) float, metres
    face_index : (N,) int
    """
    v = np.asarray(vertices, dtype=float)
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    tri = v[np.asarray(faces, dtype=np.int64)]
    cen = tri.mean(axis=1)
    tree = cKDTree(cen)
    r_max = float(np.max(np.linalg.norm(tri - cen[:, None, :], axis=2))) if exact and len(tri) else 0.0
    closest, dist, face = np.empty_like(p), np.full(len(p), np.inf), np.zeros(len(p), dtype=np.int64)
    todo = np.arange(len(p))
    k = int(k)
    while todo.size:
        kk = int(min(k, len(tri)))
        dc, cand = tree.query(p[todo], k=kk)
        dc, cand = dc.reshape(len(todo), kk), cand.reshape(len(todo), kk)
        T = tri[cand.ravel()]
        q = _closest_on_triangles(np.repeat(p[todo], kk, axis=0), T[:, 0], T[:, 1], T[:, 2]).reshape(len(todo), kk, 3)
        d = np.linalg.norm(q - p[todo][:, None, :], axis=2)
        best = np.argmin(d, axis=1)
        rows = np.arange(len(todo))
        closest[todo], dist[todo], face[todo] = q[rows, best], d[rows, best], cand[rows, best]
        if not exact:
            break
        done = (dc[:, -1] > d[rows, best] + r_max) | (kk == len(tri))
        todo = todo[~done]
        k *= 2
    return closest, dist, face


def to_trimesh(vertices, faces):
    """A ``trimesh.Trimesh`` from vertices in metres and faces."""
    return trimesh.Trimesh(vertices=np.asarray(vertices), faces=np.asarray(faces), process=False)
