"""Figures of results (matplotlib, imported lazily with the non-interactive Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayestouch.geometry import nellipsoid as ne
from bayestouch.report import canvas

__all__ = [
    "plot_table2",
    "plot_shape",
    "plot_errors",
    "plot_taxel_frames",
    "plot_patch_posterior",
    "plot_trace",
    "plot_pair",
]


def plot_table2(rows: list[dict], out) -> Path:
    """``table2.png``: ‖BP − X‖ and ε_V, ε_A, ε_I per FFD size, ours beside the paper's (log scale).

    Parameters
    ----------
    rows : list of dict
        From :func:`bayestouch.paper.reproduce_table2`.
    out : path-like
        Folder to write into.

    Returns
    -------
    Path of the figure.
    """
    eps_levels = sorted({r["epsilon"] for r in rows})
    fig, axes = canvas.subplots(len(eps_levels), 2, figsize=(11, 4.2 * len(eps_levels)), squeeze=False)
    for i, eps in enumerate(eps_levels):
        sub = [r for r in rows if r["epsilon"] == eps]
        sizes = [r["ffd_size"] for r in sub]
        x = np.arange(len(sub))
        ax = axes[i, 0]
        ax.bar(x - 0.27, [r["bp_minus_x_percent"] for r in sub], 0.27, label="ours", color="C0")
        ax.bar(x, [r.get("paper_bp_minus_x_percent", np.nan) for r in sub], 0.27, label="paper", color="C1")
        if any("defect_free_bp_minus_x_percent" in r for r in sub):
            ax.bar(
                x + 0.27,
                [r.get("defect_free_bp_minus_x_percent", np.nan) for r in sub],
                0.27,
                label="ours, plate without defects",
                color="C2",
            )
        ax.set_yscale("log")
        ax.set_xticks(x, sizes)
        ax.set_ylabel("‖BP − X‖ (%)")
        ax.set_title(f"ε = {eps:g}: least-squares error of the FFD fit")
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, frameon=False)
        ax = axes[i, 1]
        for k, (key, label) in enumerate([("eps_v", "ε_V"), ("eps_a", "ε_A"), ("eps_i", "ε_I")]):
            ax.plot(x, [abs(r[key]) for r in sub], "o-", color=f"C{k}", label=f"{label} ours")
            ax.plot(
                x,
                [abs(r.get(f"paper_{key}", np.nan)) for r in sub],
                "s--",
                color=f"C{k}",
                alpha=0.6,
                label=f"{label} paper",
            )
        ax.set_yscale("log")
        ax.set_xticks(x, sizes)
        ax.set_ylabel("|relative error|")
        ax.set_title(f"ε = {eps:g}: volume, area, inertia (eq. 11–13)")
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, frameon=False)
    fig.tight_layout()
    path = Path(out) / "table2.png"
    fig.savefig(path, dpi=120)
    return path


def _save(fig, out, name: str) -> Path:
    path = Path(out) / name
    fig.savefig(path, dpi=100)
    return path


def plot_shape(out, truth, mean_mesh, spread, points, draws, *, name: str = "shape.png") -> Path:
    """The object and the posterior mean shape with its uncertainty.

    Left: the posterior mean surface coloured by its spread, with the contact points. Right: sections through the
    object's centre in the world's x–y, x–z and y–z planes: the true surface, the posterior mean, and thin
    outlines of posterior draws.

    Parameters
    ----------
    out : path-like
        Folder to write into.
    truth : NEllipsoid or None
        The true object's base shape (texture is far below the figure's resolution); ``None`` when unknown.
    mean_mesh : (vertices (U, 3), faces (G, 3))
        The posterior mean shape, metres.
    spread : (U,) float, metres
        Per-vertex posterior spread of the surface along its normal (``uncertainty_mesh.ply``'s ``spread``).
    points : (M, 3) float, metres
        Contact points.
    draws : list of NEllipsoid
        Posterior draws to outline (a few tens).

    Returns
    -------
    Path of the figure.
    """
    import matplotlib as mpl

    mv, mf = (np.asarray(a) for a in mean_mesh)
    points = np.asarray(points).reshape(-1, 3)
    face_spread = 1e3 * np.asarray(spread)[mf].mean(axis=1)
    norm = mpl.colors.Normalize(vmin=0.0, vmax=max(float(face_spread.max()), 1e-6))
    cmap = mpl.colormaps["viridis"]
    fig = canvas.figure(figsize=(15, 4.6), constrained_layout=True)
    gs = fig.add_gridspec(1, 4, width_ratios=[1.3, 1, 1, 1])
    ax = fig.add_subplot(gs[0, 0], projection="3d")
    surf = ax.plot_trisurf(*(1e3 * mv.T), triangles=mf, linewidth=0, antialiased=False, shade=False)
    surf.set_facecolor(cmap(norm(face_spread)))
    if len(points):
        ax.scatter(*(1e3 * points.T), s=4, color="crimson", depthshade=False, label="contacts")
        ax.legend(loc="upper left", fontsize=8)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_box_aspect((1, 1, 1))
    fig.colorbar(
        mpl.cm.ScalarMappable(norm=norm, cmap=cmap),
        ax=ax,
        shrink=0.6,
        location="left",
        label="posterior spread of the surface (mm)",
    )
    centre = mv.mean(axis=0)
    half = 1.25 * np.abs(mv - centre).max()
    g = np.linspace(-half, half, 161)
    A, B = np.meshgrid(g, g)
    for k, (i, j, label) in enumerate([(0, 1, "x–y"), (0, 2, "x–z"), (1, 2, "y–z")]):
        axk = fig.add_subplot(gs[0, k + 1])
        pts = np.tile(centre, (A.size, 1))
        pts[:, i] += A.ravel()
        pts[:, j] += B.ravel()

        X, Y = 1e3 * (centre[i] + A), 1e3 * (centre[j] + B)
        for d in draws:
            axk.contour(
                X,
                Y,
                ne.evaluate(ne.inside_outside, d, pts).reshape(A.shape),
                levels=[1.0],
                colors="C0",
                linewidths=0.4,
                alpha=0.35,
            )
        if truth is not None:
            axk.contour(
                X,
                Y,
                ne.evaluate(ne.inside_outside, truth, pts).reshape(A.shape),
                levels=[1.0],
                colors="k",
                linewidths=1.2,
                linestyles="--",
            )
        near = np.abs(points[:, 3 - i - j] - centre[3 - i - j]) < 0.15 * half
        axk.plot(1e3 * points[near, i], 1e3 * points[near, j], ".", color="crimson", ms=3)
        axk.set_aspect("equal")
        axk.set_xlabel(f"{'xyz'[i]} (mm)")
        axk.set_ylabel(f"{'xyz'[j]} (mm)")
        axk.set_title(f"{label} section through the centre", fontsize=9)
    handles = [
        mpl.lines.Line2D([], [], color="C0", lw=0.8, label="posterior draws"),
        mpl.lines.Line2D([], [], color="crimson", marker=".", ls="", label="contacts near the plane"),
    ]
    if truth is not None:
        handles.insert(0, mpl.lines.Line2D([], [], color="k", ls="--", label="true object"))
    fig.legend(handles=handles, loc="lower right", fontsize=8, ncol=3)
    return _save(fig, out, name)


def plot_errors(out, records, *, true_volume: float | None = None, name: str = "errors.png") -> Path:
    """Error against strokes: Chamfer distance and volume error of the point estimate, and the volume's
    posterior mean ± 2 sd against the truth.

    Parameters
    ----------
    records : list of StrokeRecord
        :class:`bayestouch.planning.loop.StrokeRecord` of each stroke (stroke 0 is the scout).
    true_volume : float, m³, optional
    """
    k = np.array([r.stroke for r in records])
    fig, (a1, a2) = canvas.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    a1.plot(k, [r.chamfer for r in records], "o-", label="Chamfer / mean semi-axis")
    a1.plot(k, [r.volume_error for r in records], "s-", label="|V̂/V − 1|")
    a1.set_yscale("log")
    a1.set_xlabel("stroke (0 = scout)")
    a1.set_title("errors of the point estimate")
    a1.legend()
    m = 1e6 * np.array([r.volume_mean for r in records])
    s = 1e6 * np.array([r.volume_sd for r in records])
    a2.fill_between(k, m - 2 * s, m + 2 * s, alpha=0.3, label="posterior mean ± 2 sd")
    a2.plot(k, m, "o-")
    if true_volume is not None:
        a2.axhline(1e6 * true_volume, color="k", ls="--", label="truth")
    a2.set_xlabel("stroke (0 = scout)")
    a2.set_ylabel("volume (cm³)")
    a2.set_title("volume posterior")
    a2.legend()
    return _save(fig, out, name)


def plot_taxel_frames(out, recording, *, gains=None, max_strokes: int = 6, name: str = "taxel_currents.png") -> Path:
    """Taxel current images: Δ ln I of the most loaded frame of each stroke over the pad.

    Parameters
    ----------
    recording : xarray.Dataset
        A recording of :mod:`bayestouch.io.recording`.
    gains : (N,) float, optional
        The device's fixed-pattern gains (its calibration, ``Finger.gains``); divided out when given. Δ ln I is
        taken relative to the median of the unloaded reference rows (``taxel_reference``) of the same frame, so skin
        temperature and drift, common to all taxels, cancel.
    max_strokes : int
        Strokes shown (the first ones).
    """
    cur = np.asarray(recording["taxel_current"].values)
    force = np.asarray(recording["contact_force"].values)
    stroke = np.asarray(recording["stroke_index"].values)
    ref = np.asarray(recording["taxel_reference"].values).astype(bool)
    u, v = 1e3 * np.asarray(recording["taxel_u"].values), 1e3 * np.asarray(recording["taxel_v"].values)
    logs = np.log(np.clip(cur, 1e-30, None))
    if gains is not None:
        logs = logs - np.log(np.asarray(gains, float).ravel())
    ids = np.unique(stroke)[:max_strokes]
    frames = [np.flatnonzero(stroke == s)[int(np.argmax(force[stroke == s]))] for s in ids]
    images = [logs[f] - np.median(logs[f, ref] if ref.any() else logs[f]) for f in frames]
    hi = max(float(np.quantile(np.abs(np.concatenate(images)), 0.995)), 1e-6)
    size = (2.5 * len(ids) + 1.2, 2.9)
    fig, axes = canvas.subplots(1, len(ids), figsize=size, squeeze=False, constrained_layout=True)
    im = None
    for ax, s, f, d in zip(axes[0], ids, frames, images, strict=True):
        im = ax.tripcolor(u, v, d, shading="gouraud", cmap="RdBu_r", vmin=-hi, vmax=hi)
        ax.plot(u[ref], v[ref], ".", ms=1.5, color="0.3")
        ax.set_aspect("equal")
        ax.set_title(f"stroke {s}: {1e3 * force[f]:.0f} mN", fontsize=9)
        ax.set_xlabel("u (mm)")
    axes[0, 0].set_ylabel("v (mm)")
    fig.colorbar(im, ax=axes[0].tolist(), label="Δ ln I", shrink=0.9)
    return _save(fig, out, name)


def plot_patch_posterior(out, post, *, draws: int = 40, name: str = "contact_patch.png") -> Path:
    """One contact patch: superellipse outlines (eq. 16) of posterior draws over the pad, and the marginals of
    a, b and n.

    Parameters
    ----------
    post : PatchPosterior
        :func:`bayestouch.inference.patch.patch_posterior`'s result.
    """
    d = post.draws
    rng = np.random.default_rng(0)
    idx = rng.choice(len(d["a"]), size=min(draws, len(d["a"])), replace=False)
    t = np.linspace(0, 2 * np.pi, 200)
    fig, axes = canvas.subplots(1, 4, figsize=(14, 3.4), constrained_layout=True)
    ax = axes[0]
    for i in idx:
        a, b, n, phi = d["a"][i], d["b"][i], d["n"][i], d["angle"][i]
        x = a * np.sign(np.cos(t)) * np.abs(np.cos(t)) ** (2 / n)
        y = b * np.sign(np.sin(t)) * np.abs(np.sin(t)) ** (2 / n)
        xu = d["u0"][i] + x * np.cos(phi) - y * np.sin(phi)
        yv = d["v0"][i] + x * np.sin(phi) + y * np.cos(phi)
        ax.plot(1e3 * xu, 1e3 * yv, color="C0", alpha=0.25, lw=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel("u (mm)")
    ax.set_ylabel("v (mm)")
    ax.set_title(f"patch outlines, {len(idx)} draws")
    for ax, key, scale, label in [
        (axes[1], "a", 1e3, "a (mm)"),
        (axes[2], "b", 1e3, "b (mm)"),
        (axes[3], "n", 1.0, "n"),
    ]:
        ax.hist(scale * np.asarray(d[key]), bins=40, color="C0", alpha=0.8)
        q = post.summary["parameters"][key]
        for k in ("q05", "q95"):
            ax.axvline(scale * q[k], color="k", ls=":")
        ax.set_xlabel(label)
        ax.set_yticks([])
    axes[1].set_title("marginals with 90 % intervals")
    return _save(fig, out, name)


def plot_trace(out, idata, var_names, *, max_chains: int = 32, name: str = "trace.png") -> Path:
    """Trace plot of ``var_names`` from the ``posterior`` group of ``idata`` (ArviZ ``InferenceData``): each
    walker's chain (right) and the pooled marginal (left), with R-hat in the title."""
    import arviz as az  # imports matplotlib.pyplot: loaded with matplotlib, on first plot

    post = idata.posterior
    rhat = az.rhat(post[list(var_names)])
    fig, axes = canvas.subplots(
        len(var_names),
        2,
        figsize=(11, 1.7 * len(var_names)),
        squeeze=False,
        gridspec_kw={"width_ratios": [1, 3]},
        constrained_layout=True,
    )
    for k, v in enumerate(var_names):
        x = np.asarray(post[v].values)  # (chain, draw)
        axes[k, 0].hist(x.ravel(), bins=50, color="C0", alpha=0.8)
        axes[k, 0].set_yticks([])
        axes[k, 0].set_title(f"{v}   R-hat {float(rhat[v]):.4f}", fontsize=9, loc="left")
        for c in range(min(max_chains, x.shape[0])):
            axes[k, 1].plot(np.asarray(post["draw"].values), x[c], lw=0.4, alpha=0.35)
        axes[k, 1].set_ylabel(v)
    axes[-1, 1].set_xlabel("step (after burn-in)")
    return _save(fig, out, name)


def plot_pair(out, idata, var_names, *, max_points: int = 3000, name: str = "pair.png") -> Path:
    """Pair plot of ``var_names`` (thinned scatter and marginals), from the ``posterior`` group of ``idata``."""
    post = idata.posterior
    cols = [np.asarray(post[v].values).ravel() for v in var_names]
    rng = np.random.default_rng(0)
    idx = rng.choice(len(cols[0]), size=min(max_points, len(cols[0])), replace=False)
    k = len(var_names)
    fig, axes = canvas.subplots(k, k, figsize=(2.1 * k, 2.1 * k), constrained_layout=True)
    for i in range(k):
        for j in range(k):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(cols[i], bins=40, color="C0", alpha=0.8)
                ax.set_yticks([])
            else:
                ax.scatter(cols[j][idx], cols[i][idx], s=1, alpha=0.3, color="C0")
            if i == k - 1:
                ax.set_xlabel(var_names[j])
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(var_names[i])
            elif j != i:
                ax.set_yticklabels([])
    return _save(fig, out, name)
