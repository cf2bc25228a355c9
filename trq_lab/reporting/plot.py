"""matplotlib for the reports' figures: the Agg backend (files, no display), chosen here once,
before pyplot is imported."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
from matplotlib.colors import LogNorm  # noqa: E402

__all__ = ["LogNorm", "plt"]
