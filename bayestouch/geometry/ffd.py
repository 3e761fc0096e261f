"""Free-form deformation (Sederberg & Parry 1986) with a trivariate Bernstein lattice, and the paper's
iterative two-step refinement (eq. 9–10).

A point x in the lattice box [lower, upper] has box coordinates s = (x − lower)/(upper − lower) ∈ [0, 1]³;
its image is X = Σ_ijk B_i^{l−1}(s₁) B_j^{m−1}(s₂) B_k^{k−1}(s₃) P_ijk, i.e. X = B P with B the (ND × NP)
deformation matrix and P the (NP × 3) control points. The lattice of uniformly spaced control points
(the paper's P₀) reproduces every point exactly (linear precision of Bernstein polynomials).
"""

from __future__ import annotations

import operator
from typing import NamedTuple

import numpy as np
from scipy.special import comb

from bayestouch.errors import BadInput, as_array, check_int, check_number, shown
from bayestouch.geometry.integrals import check_mesh
from bayestouch.geometry.mesh import closest_points

__all__ = [
    "check_dims",
    "MAX_DIMS_AXIS",
    "bernstein",
    "deformation_matrix",
    "identity_lattice",
    "deform",
    "solve_lattice",
    "FFDFit",
    "fit_two_step",
]


def bernstein(degree: int, s) -> np.ndarray:
    """Bernstein basis B_i^degree(s) for i = 0..degree; ``s (N,)`` in [0, 1] → ``(N, degree + 1)``."""
    s = np.asarray(s, dtype=float)[:, None]
    i = np.arange(degree + 1)[None, :]
    return comb(degree, i) * s**i * (1.0 - s) ** (degree - i)


#: most control points along one axis of a lattice (the paper's largest is 7; B has ND × l·m·k entries)
MAX_DIMS_AXIS = 32


def check_dims(dims, name: str = "dims") -> tuple[int, int, int]:
    """``dims`` as three ints, or a one-line refusal naming ``name``: three integer lattice sizes from 2 to
    :data:`MAX_DIMS_AXIS`."""
    try:
        sizes = [operator.index(d) for d in dims]
    except TypeError:  # not a sequence, or text / floats in it
        sizes = None
    if sizes is None or len(sizes) != 3 or not all(2 <= d <= MAX_DIMS_AXIS for d in sizes):
        raise BadInput(
            f"{name} must be three integer lattice sizes from 2 to {MAX_DIMS_AXIS} (e.g. (6, 6, 3)), got "
            f"{shown(dims, 60)}"
        )
    return tuple(sizes)


def deformation_matrix(points, lower, upper, dims) -> np.ndarray:
    """The FFD matrix B (ND × NP) for points inside the box.

    Parameters
    ----------
    points : (ND, 3) float, metres
    lower, upper : (3,) float, metres
        Opposite corners of the lattice box.
    dims : (l, m, k) int
        Control points along each box axis (the paper's "size of the FFD", e.g. 6×6×3).

    Returns
    -------
    (ND, l·m·k) float
        Rows sum to one (partition of unity); columns ordered as ``P.reshape(l, m, k, 3)``.
    """
    l, m, k = check_dims(dims)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    if np.any(upper <= lower):
        raise BadInput("upper must exceed lower on every axis")
    s = (np.asarray(points, float) - lower) / (upper - lower)
    bu, bv, bw = bernstein(l - 1, s[:, 0]), bernstein(m - 1, s[:, 1]), bernstein(k - 1, s[:, 2])
    return np.einsum("ni,nj,nk->nijk", bu, bv, bw).reshape(len(s), l * m * k)


def identity_lattice(lower, upper, dims) -> np.ndarray:
    """The paper's P₀: uniformly spaced control points of the box; ``(l·m·k, 3)`` metres."""
    l, m, k = check_dims(dims)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    g = np.stack(
        np.meshgrid(np.linspace(0, 1, l), np.linspace(0, 1, m), np.linspace(0, 1, k), indexing="ij"), axis=-1
    ).reshape(-1, 3)
    return lower + g * (upper - lower)


def deform(points, P, lower, upper, dims) -> np.ndarray:
    """Image of ``points (N, 3)`` under the lattice ``P (l·m·k, 3)``, metres."""
    return deformation_matrix(points, lower, upper, dims) @ np.asarray(P, float)


def solve_lattice(B, X, P_prior=None, ridge: float = 0.0) -> np.ndarray:
    """Step 2 of the paper's algorithm: P = argmin ‖B P − X‖² + λ‖P − P_prior‖².

    Parameters
    ----------
    B : (N, NP) float
    X : (N, 3) float, metres
    P_prior : (NP, 3) float, metres, optional
        Where control points that no datum reaches stay (needed only when ``ridge`` > 0).
    ridge : float
        λ relative to the mean diagonal of BᵀB; 0 gives plain least squares.

    Returns
    -------
    (NP, 3) float, metres
    """
    B, X = np.asarray(B, float), np.asarray(X, float)
    if ridge == 0.0:
        return np.linalg.lstsq(B, X, rcond=None)[0]
    A = B.T @ B
    lam = ridge * np.trace(A) / A.shape[0]
    prior = np.zeros((A.shape[0], 3)) if P_prior is None else np.asarray(P_prior, float)
    return np.linalg.solve(A + lam * np.eye(A.shape[0]), B.T @ X + lam * prior)


class FFDFit(NamedTuple):
    """Result of :func:`fit_two_step`.

    Attributes
    ----------
    P : (NP, 3) float, metres
        Final control points.
    vertices : (ND, 3) float, metres
        Deformed model points X = B P.
    iterations : int
    residual : float
        Relative least-squares error ‖B P − X^a‖ / ‖X^a‖ over the data-associated rows (the paper's
        ‖BP − X‖), measured in the frame the points are given in.
    history : list of float
        The stop-test quantity after each iteration.
    converged : bool
    """

    P: np.ndarray
    vertices: np.ndarray
    iterations: int
    residual: float
    history: list
    converged: bool


def fit_two_step(
    model_points,
    faces,
    data,
    lower,
    upper,
    dims,
    *,
    max_iter: int = 200,
    tol: float = 1e-3,
    ridge: float = 1e-4,
    patience: int = 5,
    anchor: str = "initial",
) -> FFDFit:
    """The paper's iterative two-step FFD refinement (eq. 9–10).

    Step 1: project the current model X_n on the data: for every data point the closest point of the
    deformed surface (a point of the model, with its own row of B), giving X_n^a = X_n + δX_n.
    Step 2: P_{n+1} = argmin ‖B P − X_n^a‖² + ``ridge``·‖P − P_anchor‖², X_{n+1} = B P_{n+1}. The paper
    has no ridge; with data along a few finger paths the plain least squares leaves most lattice
    directions free and the surface between the paths crumples (measured on the plate probed along 6
    paths: area error 93 % with the ridge anchored at the previous lattice, 2–8 % anchored at the
    initial one). Anchoring at the undeformed lattice is a Gaussian prior on the displacements δP.
    Stop when ‖X_{n+1} − X_n^a‖ changes by less than ``tol`` (relative) between iterations, or when it
    has not reached a new low for ``patience`` iterations; the best lattice is returned.

    Parameters
    ----------
    model_points : (ND, 3) float, metres
        Undeformed discretised surface (the n-ellipsoid), inside the box.
    faces : (F, 3) int
        Triangles of the model, for the projection.
    data : (M, 3) float, metres
        Probed points.
    lower, upper : (3,) float, metres
    dims : (l, m, k) int
    max_iter : int
    tol : float
        Relative change of the stop-test error that ends the iteration.
    ridge : float
        Tikhonov weight relative to the mean diagonal of BᵀB.
    anchor : {"initial", "previous"}
        Lattice the ridge pulls towards: the undeformed one (a prior on δP) or P_n (damping only).
    patience : int
        Stop after this many iterations without a new lowest error. The lattice with the lowest error
        is returned either way (``iterations`` counts all that ran).

    Returns
    -------
    FFDFit
    """
    X0, faces = check_mesh(model_points, faces, names=("model_points", "faces"))
    data = as_array(data, "data", (None, 3), "an (M, 3) array (metres)")
    if not len(data):
        raise BadInput("data: expected at least one probed point, got an empty (0, 3) array")
    lower = as_array(lower, "lower", (3,), "a (3,) corner (metres)")
    upper = as_array(upper, "upper", (3,), "a (3,) corner (metres)")
    check_dims(dims)
    check_int(max_iter, "max_iter", 1, None, "an integer number of iterations")
    check_int(patience, "patience", 1, None, "an integer number of iterations")
    check_number(tol, "tol", 0)
    check_number(ridge, "ridge", 0)
    if anchor not in ("initial", "previous"):
        raise BadInput(f"anchor must be 'initial' or 'previous', got {anchor!r}")
    B_model = deformation_matrix(X0, lower, upper, dims)
    P = identity_lattice(lower, upper, dims)
    P0 = P
    X = B_model @ P
    history: list[float] = []
    converged = False
    best = (np.inf, P, 0)
    iterations = 0
    for it in range(1, max_iter + 1):
        iterations = it
        # Step 1: closest points on the deformed surface, expressed at their undeformed positions
        _, _, fi = closest_points(X, faces, data)
        tri_def = X[faces[fi]]
        bary = _barycentric(data, tri_def)
        x0 = np.einsum("nk,nkd->nd", bary, X0[faces[fi]])
        B = deformation_matrix(x0, lower, upper, dims)
        Xa = data  # X_n^a = X_n + δX_n with X_n = B P at the feet of the projections
        # Step 2: least squares for the control points
        P_new = solve_lattice(B, Xa, P0 if anchor == "initial" else P, ridge)
        err = float(np.linalg.norm(B @ P_new - Xa) / np.linalg.norm(Xa))
        history.append(err)
        P = P_new
        X = B_model @ P
        if err < best[0]:
            best = (err, P, it)
        if len(history) > 1 and abs(history[-2] - history[-1]) <= tol * max(history[-2], 1e-300):
            converged = True
            break
        if it - best[2] >= patience:
            # the error has grown for `patience` iterations (projections hopping between sparse data
            # curves): stop and keep the best lattice
            converged = True
            break
    residual, P, _ = best
    X = B_model @ P
    return FFDFit(P, X, iterations, residual, history, converged)


def _barycentric(p, tri) -> np.ndarray:
    """Barycentric coordinates (N, 3) of the projections of p (N, 3) onto the planes of tri (N, 3, 3)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    bary = np.stack([1 - v - w, v, w], axis=1)
    # clamp to the triangle (the closest point lies on it) and renormalise
    bary = np.clip(bary, 0.0, 1.0)
    return bary / bary.sum(axis=1, keepdims=True)
