"""Lazy matplotlib access. Nothing global is touched: figures are `matplotlib.figure.Figure`
objects with their own Agg canvas, never pyplot, never `matplotlib.use`."""

from __future__ import annotations

MATPLOTLIB_MISSING = "plotting needs matplotlib: pip install 'quadpilot[train]' (or pip install matplotlib)"


class VizUnavailable(RuntimeError):
    """A plotting or video dependency (matplotlib, pillow, ffmpeg) is missing; the message says
    what to install or what to do instead."""


def new_figure(width_in: float, height_in: float, dpi: float):
    """A Figure with an Agg canvas attached, independent of pyplot and of the global backend."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as e:
        raise VizUnavailable(MATPLOTLIB_MISSING) from e
    fig = Figure(figsize=(width_in, height_in), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig
