"""Figures written to files without pyplot: a :class:`matplotlib.figure.Figure` renders itself, so the library never
switches the user's backend (a notebook's inline plots keep working after a fit, an experiment or a report) and
leaves no figure open in pyplot's global list."""

from __future__ import annotations

from matplotlib.figure import Figure

__all__ = ["figure", "subplots"]


def figure(*, figsize=None, constrained_layout: bool = False) -> Figure:
    """A new figure (``figsize`` in inches) outside pyplot; ``fig.savefig`` writes it."""
    return Figure(figsize=figsize, layout="constrained" if constrained_layout else None)


def subplots(nrows: int = 1, ncols: int = 1, *, figsize=None, constrained_layout: bool = False, **kwargs):
    """``(figure, axes)`` as ``pyplot.subplots`` returns them, outside pyplot (``kwargs``: ``squeeze``,
    ``gridspec_kw``, ``sharex`` …)."""
    fig = figure(figsize=figsize, constrained_layout=constrained_layout)
    return fig, fig.subplots(nrows, ncols, **kwargs)
