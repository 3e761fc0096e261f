"""PLY meshes with a per-vertex quantity: the uncertainty mesh's surface spread (m).

The spread is written twice per vertex, as ``spread`` and as ``quality`` (the property MeshLab and CloudCompare
read as a scalar field); :func:`read_spread_mesh` loads it back into ``trimesh``'s ``vertex_attributes``, where
trimesh's own loader leaves it in ``metadata["_ply_raw"]``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from bayestouch.errors import BadInput, check_path, file_problem
from bayestouch.io.files import atomic_path

__all__ = ["read_spread_mesh", "write_spread_mesh"]


def write_spread_mesh(path: str | os.PathLike[str], mesh: trimesh.Trimesh, spread) -> Path:
    """Write ``mesh`` (vertices in metres, its vertex colours as they are) with ``spread (V,)`` metres as the
    vertex properties ``spread`` and ``quality`` (float32), atomically. Returns the path."""
    spread = np.asarray(spread, dtype=np.float32)
    if spread.shape != (len(mesh.vertices),):
        raise ValueError(f"spread: expected ({len(mesh.vertices)},) values, one per vertex, got {spread.shape}")
    mesh.vertex_attributes["spread"] = spread
    mesh.vertex_attributes["quality"] = spread
    with atomic_path(path) as tmp:
        mesh.export(str(tmp))
    return Path(path)


def read_spread_mesh(path: str | os.PathLike[str]) -> trimesh.Trimesh:
    """Load a PLY mesh with its per-vertex scalar properties (``spread``, ``quality``, …) in
    ``vertex_attributes`` (float arrays, one value per vertex)."""
    check_path(path, "path")
    problem = file_problem(path)
    if problem:  # a folder had been called "no such mesh file"
        raise BadInput(f"{path}: {problem} (expected a PLY mesh written by bayestouch fit)")
    path = Path(path)
    try:
        mesh = trimesh.load(path, process=False, file_type="ply")
    except Exception as e:  # trimesh raises many types on damaged files
        raise BadInput(f"{path}: not a readable PLY mesh ({type(e).__name__}: {e})") from None
    raw = mesh.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    if raw is not None and raw.dtype.names:
        skip = {"x", "y", "z", "red", "green", "blue", "alpha", "nx", "ny", "nz"}
        for name in raw.dtype.names:
            if name not in skip and raw[name].ndim == 1:
                mesh.vertex_attributes[name] = np.asarray(raw[name], dtype=float)
    return mesh
