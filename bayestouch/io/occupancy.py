"""The posterior occupancy grid of a run folder (``occupancy.npz``): the probability, over posterior draws, that a
point of space lies inside the object, on a regular grid — for grasp planning, collision checks or plots, whatever
the shape model.

File: NumPy ``.npz`` with ``x``, ``y``, ``z`` (grid coordinates, metres, increasing), ``probability``
(len(x), len(y), len(z)) in [0, 1] (indexing ``ij``) and ``draws`` (how many posterior draws it averages).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from bayestouch.errors import BadInput, check_path
from bayestouch.io.files import atomic_path

__all__ = ["OCCUPANCY_FILE", "Occupancy", "write_occupancy", "load_occupancy"]

#: the occupancy grid's file name in a run folder
OCCUPANCY_FILE = "occupancy.npz"


class Occupancy(NamedTuple):
    """Posterior probability of occupancy on a grid.

    Attributes
    ----------
    x, y, z : (nx,), (ny,), (nz,) float, metres
        Increasing grid coordinates.
    probability : (nx, ny, nz) float
        Fraction of the posterior draws inside which each grid point lies.
    draws : int
        Number of posterior draws averaged (the Monte-Carlo sd of a probability p is √(p(1 − p)/draws)).
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    probability: np.ndarray
    draws: int

    def at(self, points) -> np.ndarray:
        """Occupancy probability at query points, trilinear between grid points, 0 outside the grid.

        Parameters
        ----------
        points : (N, 3) or (3,) float, metres
            Query points (one point as a (3,) sequence).

        Returns
        -------
        (N,) float
            The probability at each point ((1,) for one point).

        Raises
        ------
        BadInput
            ``points`` not real numbers (text, complex, bools, a ragged nesting), of another shape, or not finite.
        """
        expected = "expected (N, 3) or (3,) query points as real numbers in metres"
        try:
            p = np.asarray(points)
            if p.dtype.kind not in "iufO":  # text, complex, bools …
                raise TypeError(p.dtype)
            p = p.astype(np.float64)
        except (TypeError, ValueError):  # also a ragged nesting
            raise BadInput(f"points: {expected}, got {_given(points)}") from None
        if p.ndim not in (1, 2) or p.shape[-1] != 3:
            raise BadInput(f"points: {expected}, got shape {p.shape}")
        p = p.reshape(-1, 3)
        if not np.all(np.isfinite(p)):
            raise BadInput(f"points: hold NaN or infinite values; {expected} (finite)")
        f = RegularGridInterpolator((self.x, self.y, self.z), self.probability, bounds_error=False, fill_value=0.0)
        return f(p)

    def volume(self, level: float = 0.5) -> float:
        """Volume (m³) of the grid cells whose occupancy probability is at least ``level``."""
        cell = np.diff(self.x).mean() * np.diff(self.y).mean() * np.diff(self.z).mean()
        return float(np.count_nonzero(self.probability >= level) * cell)


def _given(value) -> str:
    """``value``'s type and the start of its repr, on one line (for messages)."""
    return f"{type(value).__name__} " + " ".join(repr(value)[:60].split())


def write_occupancy(path: str | os.PathLike[str], occ: Occupancy) -> Path:
    """Write ``occ`` to ``path`` atomically (a kill leaves the old file or the new one). Returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, x=occ.x, y=occ.y, z=occ.z, probability=occ.probability.astype(np.float32), draws=occ.draws)
    return path


def load_occupancy(path: str | os.PathLike[str]) -> Occupancy:
    """Read an occupancy grid: ``path`` is the ``.npz`` file or a run folder holding ``occupancy.npz``.

    Raises
    ------
    BadInput
        The file is missing or not an occupancy grid (one line naming what is wrong).
    """
    check_path(path, "path")
    path = Path(path)
    if path.is_dir():
        path = path / OCCUPANCY_FILE
    if not path.is_file():
        raise BadInput(
            f"{path}: no occupancy grid here (every finished fit writes {OCCUPANCY_FILE} in its run folder; an "
            "interrupted one writes it when continued with --resume)"
        )
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError):  # numpy's reason for a file of another kind offers to unpickle it: not repeated
        raise BadInput(
            f"{path}: not an occupancy grid (expected a NumPy .npz archive with x, y, z, probability, draws)"
        ) from None
    if not isinstance(z, np.lib.npyio.NpzFile):  # a single .npy array
        raise BadInput(
            f"{path}: not an occupancy grid (expected a NumPy .npz archive with x, y, z, probability, draws)"
        )
    try:
        with z:
            occ = Occupancy(
                np.asarray(z["x"], float),
                np.asarray(z["y"], float),
                np.asarray(z["z"], float),
                np.asarray(z["probability"], float),
                int(z["draws"]),
            )
    except (OSError, ValueError, KeyError, TypeError) as exc:
        # numpy's reason for an object array advises loading it unsafely (allow_pickle): not passed on
        reason = "it holds Python objects" if "pickle" in str(exc) else f"{type(exc).__name__}: {exc}"
        raise BadInput(f"{path}: not an occupancy grid (expected x, y, z, probability, draws): {reason}") from None
    shape = (occ.x.size, occ.y.size, occ.z.size)
    if occ.probability.shape != shape or min(shape) < 2:
        raise BadInput(f"{path}: probability has shape {occ.probability.shape}, expected {shape} with every side ≥ 2")
    if not np.all((occ.probability >= 0) & (occ.probability <= 1)):  # also false for NaN
        raise BadInput(f"{path}: probability holds values outside [0, 1] (or NaN); a damaged occupancy grid")
    for name, axis in (("x", occ.x), ("y", occ.y), ("z", occ.z)):
        if not (np.all(np.isfinite(axis)) and np.all(np.diff(axis) > 0)):
            raise BadInput(f"{path}: axis {name} is not finite and increasing; a damaged occupancy grid")
    return occ
