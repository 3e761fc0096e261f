"""The symmetries of the n-ellipsoid's parameters: one canonical parameter vector per surface, and distances
between parameters modulo the symmetries that remain.

Parameter vectors ``(x_G, y_G, z_G, a, b, c, xi, psi, zeta, n)`` of
:func:`~bayestouch.geometry.nellipsoid.to_vector`, shape (..., 10): metres, radians, dimensionless. NumPy at
this edge. The aliases removed and the canonical rule are described in ``docs/geometry.md``.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from bayestouch.backend import jax, jnp, pad_pow2
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.nellipsoid import NEllipsoid
from bayestouch.geometry.rotation import euler_from_matrix, rotation_matrix

__all__ = [
    "AXIS_RTOL",
    "canonicalize",
    "canonicalize_batch",
    "rotation_matrices",
    "proper_signed_permutations",
    "param_distance",
    "aliases",
    "align_batch",
]

#: relative tolerance under which two semi-axes count as equal in :func:`param_distance`
AXIS_RTOL = 1e-6


# ---------------------------------------------------------------------------------------- canonical form

_rotation_batch = jax.jit(jax.vmap(rotation_matrix))
# euler_from_matrix works element-wise on the trailing dimension of a (3, 3, S) stack
_euler_batch = jax.jit(lambda R: euler_from_matrix(jnp.moveaxis(R, 0, -1)).T)


def rotation_matrices(angles) -> np.ndarray:
    """(S, 3) Euler angles (ξ, ψ, ζ) in radians → (S, 3, 3) rotation matrices of eq. 2 (one compiled program per
    power-of-two batch size)."""
    angles = np.asarray(angles, dtype=np.float64)
    return np.asarray(_rotation_batch(jnp.asarray(pad_pow2(angles, fill=0.0))))[: len(angles)]


def _canonical_rotation(axes: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sort (S, 3) semi-axes descending, permute the columns of (S, 3, 3) R alike and fix their signs."""
    order = np.argsort(-axes, axis=1, kind="stable")
    axes = np.take_along_axis(axes, order, axis=1)
    R = np.take_along_axis(R, order[:, None, :], axis=2)
    cols = R[:, :, :2]  # (S, 3, 2)
    big = np.argmax(np.abs(cols), axis=1)  # (S, 2) row of the largest |entry|
    sign = np.sign(np.take_along_axis(cols, big[:, None, :], axis=1))
    cols = cols * np.where(sign == 0, 1.0, sign)
    third = np.cross(cols[:, :, 0], cols[:, :, 1])
    return axes, np.concatenate([cols, third[:, :, None]], axis=2)


def _canonical_rows(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S, 10) parameter vectors → canonical (S, 10) vectors and their (S, 3, 3) rotation matrices."""
    axes, R = _canonical_rotation(flat[:, 3:6], rotation_matrices(flat[:, 6:9]))
    # pad to a power of two so that the compiled Euler extraction is reused across batch sizes
    angles = np.asarray(_euler_batch(jnp.asarray(pad_pow2(R, fill=np.eye(3)))))[: len(R)]
    return np.concatenate([flat[:, 0:3], axes, angles, flat[:, 9:10]], axis=1), R


def canonicalize_batch(V) -> np.ndarray:
    """Canonical parameter vectors (see :func:`canonicalize`) of many n-ellipsoids at once.

    Meant for summarising posterior samples, whose raw Euler angles and axis order wander between the
    aliases of the same surface.

    Parameters
    ----------
    V : (..., 10) float
        Rows ``(x_G, y_G, z_G, a, b, c, xi, psi, zeta, n)`` of :func:`~bayestouch.geometry.nellipsoid.to_vector`
        (metres, radians, dimensionless).

    Returns
    -------
    (..., 10) float ndarray
        Same surfaces; semi-axes descending, Euler angles of the canonical rotation
        (ξ ∈ [0, π], ψ, ζ ∈ (−π, π]); centre and n unchanged.
    """
    V = np.asarray(V, dtype=np.float64)
    if V.shape[-1] != 10:
        raise ValueError(f"expected parameter vectors of length 10, got shape {V.shape}")
    return _canonical_rows(V.reshape(-1, 10))[0].reshape(V.shape)


def canonicalize(shape: NEllipsoid) -> NEllipsoid:
    """A unique representative of the surface of ``shape`` among its aliases.

    The rule: semi-axes sorted descending (a ≥ b ≥ c; ties keep their order), the columns of R permuted
    alike; the first two columns' signs chosen so that each one's entry of largest magnitude is positive;
    the third column is their cross product (det R = +1); the Euler angles are recomputed from that R with
    :func:`~bayestouch.geometry.rotation.euler_from_matrix`. The result describes the same surface (same
    inside–outside function) and is idempotent.

    The representative is unique when the semi-axes are distinct and no column has two entries of equal
    magnitude (any sign rule is discontinuous somewhere). With equal semi-axes the permutations among them
    remain; :func:`param_distance` minimises over them. For n = 2 with equal axes the symmetry is continuous
    (a spheroid), and no discrete rule removes it.

    Parameters
    ----------
    shape : NEllipsoid
        A single shape (centre (3,) m, axes (3,) m, angles (3,) rad, n).

    Returns
    -------
    NEllipsoid
    """
    v = np.asarray(ne.to_vector(shape), dtype=np.float64)
    return ne.from_vector(canonicalize_batch(v))


# ---------------------------------------------------------------------------------------- aligned aliases


def _euler_near(R: np.ndarray, ref_angles: np.ndarray) -> np.ndarray:
    """Euler angles (S, 3) rad of rotations ``R (S, 3, 3)``: of the two Euler triples of each, (ξ, ψ, ζ) and
    (−ξ, ψ + π, ζ + π), the one nearer ``ref_angles (3,)`` on the circle, shifted by multiples of 2π to lie within
    π of it."""
    ang = np.asarray(_euler_batch(jnp.asarray(pad_pow2(R, fill=np.eye(3)))))[: len(R)]
    twin = np.column_stack([-ang[:, 0], ang[:, 1] + np.pi, ang[:, 2] + np.pi])
    d, d_twin = (np.mod(a - ref_angles + np.pi, 2 * np.pi) - np.pi for a in (ang, twin))
    better = np.sum(d_twin * d_twin, axis=1) < np.sum(d * d, axis=1)
    return ref_angles + np.where(better[:, None], d_twin, d)


def aliases(v) -> np.ndarray:
    """The 24 parameter vectors (24, D) of one n-ellipsoid's surface: its frame R times each proper signed
    permutation with the semi-axes permuted alike.

    Parameters
    ----------
    v : (D ≥ 9,) float
        Semi-axes (or any per-axis function of them, e.g. their logs) at 3:6 and Euler angles (ξ, ψ, ζ) rad at
        6:9, as in :func:`~bayestouch.geometry.nellipsoid.to_vector` or the contact level's θ; other entries are
        copied.
    """
    v = np.asarray(v, dtype=np.float64)
    R = rotation_matrices(v[None, 6:9])[0]
    out = np.repeat(v[None], len(_PROPER), axis=0)
    out[:, 3:6] = v[3:6][_PERMS]
    out[:, 6:9] = _euler_near(R[None] @ _PROPER, v[6:9])
    return out


def align_batch(V, ref) -> np.ndarray:
    """Each row of ``V`` rewritten as the alias of its surface whose frame is nearest the frame of ``ref``.

    Sampled Euler angles and axis labels wander between the 24 aliases of a surface (:func:`aliases`); a cloud of
    draws of one compact posterior can therefore be scattered over many copies of it in parameter space. Aligned,
    it is one compact cloud (the alias R P maximising trace(R_refᵀ R P) over the proper signed permutations P,
    its Euler triple the one nearest ``ref``'s angles, unwrapped to within π of them). Each alias map preserves
    the Haar measure on rotations, so aligned posterior draws are draws of the posterior restricted to the copy
    about ``ref``.

    Parameters
    ----------
    V : (S, D ≥ 9) float
        Rows as :func:`aliases`' ``v``.
    ref : (D ≥ 9,) float

    Returns
    -------
    (S, D) float
        The same surfaces.
    """
    V = np.asarray(V, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    R = rotation_matrices(V[:, 6:9])
    R_ref = rotation_matrices(ref[None, 6:9])[0]
    score = np.einsum("ki,skj,gji->sg", R_ref, R, _PROPER)  # trace(R_refᵀ R P)
    g = np.argmax(score, axis=1)
    out = V.copy()
    out[:, 3:6] = np.take_along_axis(V[:, 3:6], _PERMS[g], axis=1)
    out[:, 6:9] = _euler_near(R @ _PROPER[g], ref[6:9])
    return out


# ---------------------------------------------------------------------------------------- parameter distance


def proper_signed_permutations() -> tuple[np.ndarray, np.ndarray]:
    """The 24 signed permutation matrices with determinant +1.

    Returns
    -------
    matrices : (24, 3, 3) float
        ``P`` with ``P[perm[j], j] = ±1``: ``R P`` has column j equal to ±column ``perm[j]`` of R.
    perms : (24, 3) int
    """
    mats, perms = [], []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            P = np.zeros((3, 3))
            P[list(perm), [0, 1, 2]] = signs
            if np.linalg.det(P) > 0:
                mats.append(P)
                perms.append(perm)
    return np.array(mats), np.array(perms)


_PROPER, _PERMS = proper_signed_permutations()


def _symmetries(axes: np.ndarray) -> np.ndarray:
    """The proper signed permutations that leave diag(axes) unchanged (to :data:`AXIS_RTOL`); (G, 3, 3)."""
    tol = AXIS_RTOL * np.max(np.abs(axes))
    keep = np.all(np.abs(axes[_PERMS] - axes) <= tol, axis=1)
    return _PROPER[keep]


def _rotation_angle(M: np.ndarray) -> np.ndarray:
    """Angle (rad) of rotation matrices (..., 3, 3), accurate also for small angles: ‖M − I‖_F = 2√2 sin(θ/2)."""
    f = np.linalg.norm(M - np.eye(3), axis=(-2, -1))
    return 2.0 * np.arcsin(np.clip(f / (2.0 * math.sqrt(2.0)), 0.0, 1.0))


def param_distance(s1: NEllipsoid, s2: NEllipsoid) -> dict[str, float]:
    """Distances between the parameters of two n-ellipsoids, modulo the symmetries of their surfaces.

    Both shapes are canonicalised (:func:`canonicalize`); the rotation angle is then minimised over the
    symmetries left: the sign flips of pairs of axes (always) and the permutations among axes equal to a
    relative tolerance of :data:`AXIS_RTOL`, i.e. over ``R1 P1`` and ``R2 P2`` for proper signed permutations
    ``P1``, ``P2`` that leave each shape's diag(a, b, c) unchanged. The continuous symmetry of a spheroid
    (n = 2 with two equal axes) is not taken into account; compare such shapes with
    :func:`~bayestouch.geometry.compare.iou` or :func:`~bayestouch.geometry.compare.chamfer` instead.

    Parameters
    ----------
    s1, s2 : NEllipsoid

    Returns
    -------
    dict
        ``centre``: ‖u1 − u2‖, m; ``axes``: max_i |a1_i − a2_i| / max(a1_i, a2_i), dimensionless (axes in
        canonical, descending order); ``rotation``: the smallest angle of R1ᵀ R2 over the symmetries, rad,
        in [0, π]; ``n``: |n1 − n2|.
    """
    V, (R1, R2) = _canonical_rows(np.stack([np.asarray(ne.to_vector(s), dtype=np.float64) for s in (s1, s2)]))
    a1, a2 = V[:, 3:6]
    G1, G2 = _symmetries(a1), _symmetries(a2)
    # (R1 P1)^T R2 P2 = P1^T (R1^T R2) P2 for every pair of symmetries
    M = np.einsum("aji,jk,bkl->abil", G1, R1.T @ R2, G2)
    return {
        "centre": float(np.linalg.norm(V[0, 0:3] - V[1, 0:3])),
        "axes": float(np.max(np.abs(a1 - a2) / np.maximum(a1, a2))),
        "rotation": float(np.min(_rotation_angle(M))),
        "n": float(abs(V[0, 9] - V[1, 9])),
    }
