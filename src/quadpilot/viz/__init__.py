"""Drawings of recorded flights: a summary PNG (`plot_flight`), an animation
(`render_flight_video`) and several flights side by side on one clock (`render_montage`), from
`FlightTrace`s recorded by quad-sitl or an in-process evaluation.

Imports NumPy, `quadpilot.core` and `quadpilot.atomic_files` only; matplotlib is imported inside
the drawing functions, so `import quadpilot.viz` works without it and the functions raise
`VizUnavailable` with what to install. Figures use their own Agg canvas: no pyplot, no
`matplotlib.use`, no global state.

    from quadpilot.viz import FlightTrace, plot_flight, render_flight_video, render_montage
    traces = [FlightTrace.from_episode_log(log, target=(0, 0, 2)) for log in logs]
    plot_flight(traces, "flight.png", title="hover, 10 episodes")
    render_flight_video(traces[0], "flight.gif")
    render_montage(traces[:3], ["first", "second", "third"], "montage.gif")
"""

from ._mpl import VizUnavailable
from .geometry import body_points, display_arm
from .montage import render_montage
from .plot import check_plot_output, plot_flight
from .trace import FlightTrace
from .video import check_video_output, frame_indices, render_flight_video

__all__ = [
    "FlightTrace",
    "VizUnavailable",
    "body_points",
    "check_plot_output",
    "check_video_output",
    "display_arm",
    "frame_indices",
    "plot_flight",
    "render_flight_video",
    "render_montage",
]
