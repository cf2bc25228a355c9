"""matplotlib for the reports' figures, imported when a figure is drawn (not when a report
module is: a campaign's worker or `--no-figures` never loads it), with the Agg backend (files,
no display) chosen once, before pyplot is imported."""

from __future__ import annotations

__all__ = ["pyplot", "log_norm"]


def pyplot():
    """matplotlib.pyplot on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def log_norm(lo: float, hi: float):
    """A logarithmic colour scale from lo to hi (matplotlib.colors.LogNorm)."""
    from matplotlib.colors import LogNorm

    return LogNorm(lo, hi)
