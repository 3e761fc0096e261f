"""Figures of results (matplotlib, imported lazily with the non-interactive Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_table2"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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
    plt = _pyplot()
    eps_levels = sorted({r["epsilon"] for r in rows})
    fig, axes = plt.subplots(len(eps_levels), 2, figsize=(11, 4.2 * len(eps_levels)), squeeze=False)
    for i, eps in enumerate(eps_levels):
        sub = [r for r in rows if r["epsilon"] == eps]
        sizes = [r["ffd_size"] for r in sub]
        x = np.arange(len(sub))
        ax = axes[i, 0]
        ax.bar(x - 0.27, [r["bp_minus_x_percent"] for r in sub], 0.27, label="ours", color="C0")
        ax.bar(x, [r.get("paper_bp_minus_x_percent", np.nan) for r in sub], 0.27, label="paper", color="C1")
        if any("defect_free_bp_minus_x_percent" in r for r in sub):
            ax.bar(x + 0.27, [r.get("defect_free_bp_minus_x_percent", np.nan) for r in sub], 0.27,
                   label="ours, plate without defects", color="C2")
        ax.set_yscale("log")
        ax.set_xticks(x, sizes)
        ax.set_ylabel("‖BP − X‖ (%)")
        ax.set_title(f"ε = {eps:g}: least-squares error of the FFD fit")
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, frameon=False)
        ax = axes[i, 1]
        for k, (key, label) in enumerate([("eps_v", "ε_V"), ("eps_a", "ε_A"), ("eps_i", "ε_I")]):
            ax.plot(x, [abs(r[key]) for r in sub], "o-", color=f"C{k}", label=f"{label} ours")
            ax.plot(x, [abs(r.get(f"paper_{key}", np.nan)) for r in sub], "s--", color=f"C{k}", alpha=0.6,
                    label=f"{label} paper")
        ax.set_yscale("log")
        ax.set_xticks(x, sizes)
        ax.set_ylabel("|relative error|")
        ax.set_title(f"ε = {eps:g}: volume, area, inertia (eq. 11–13)")
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, frameon=False)
    fig.tight_layout()
    path = Path(out) / "table2.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
