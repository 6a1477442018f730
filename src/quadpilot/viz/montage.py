"""`render_montage`: several flights side by side in one animation, on one clock.

Made for a "learning montage" (the same start state flown by the early, middle and final policy
snapshots of a training run: `python -m quadpilot.studies.learning_montage`), but any flights will do. Each
panel is the video module's drawing (`video.FlightScene`, layout "below"): the 3-D view with the
quadrotor, its trail and the target, and under it the position error over the whole flight with a
cursor. A title strip on top of each panel holds its label (e.g. training steps and error).

The panels share what makes them comparable: one time axis, one error axis and, when the flights
cover similar ground, one 3-D view containing them all (a flight that wandered metres away would
shrink the others to dots, so then each panel gets its own view; its axis ticks give the scale).
Frame k shows simulated time k·speed/fps in every panel; a flight that ended earlier (a crash)
holds its last picture and says when it ended.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_output

from ._mpl import new_figure
from .geometry import arm_length_of
from .plot import ERROR_FLOOR_M
from .trace import FlightTrace
from .video import MIN_VIEW_HALF, FlightScene, checked_animation_writer, frame_times, indices_at

TITLE_HEIGHT = 0.13
"""Fraction of the figure's height above the panels for their titles (two lines of 7 pt at 300 px)."""
SHARE_VIEW_RATIO = 3.0
"""share_view="auto": one view for all panels unless the largest flight's extent is more than
this many times the smallest's."""


def render_montage(
    traces: Sequence[FlightTrace],
    labels: Sequence[str] | None,
    out: str | Path,
    fps: int = 15,
    arm_length: float | str | None = None,
    speed: float = 1.0,
    *,
    size_px: tuple[int, int] = (720, 320),
    dpi: int = 100,
    trail_s: float = 2.0,
    exaggerate: float | None = None,
    share_view: bool | str = "auto",
) -> Path:
    """Render `traces` side by side into `out` (.gif with pillow, .mp4 with ffmpeg); returns it.

    labels: one title per trace (newlines allowed; None: each trace's own label). The video lasts
    as long as the longest flight: floor(max duration·fps/speed) + 1 frames. share_view: True, one
    3-D view around every flight and target (comparable sizes); False, each panel its own; "auto"
    (default), shared unless the flights' extents differ more than `SHARE_VIEW_RATIO` times.
    arm_length, speed, trail_s, exaggerate: as `render_flight_video`. Written atomically.
    Raises VizUnavailable without matplotlib (or ffmpeg for .mp4); ValueError on bad input.
    """
    if isinstance(traces, FlightTrace) or not isinstance(traces, Sequence) or not traces:
        raise ValueError("render_montage: expected a non-empty list of FlightTraces")
    bad = [type(t).__name__ for t in traces if not isinstance(t, FlightTrace)]
    if bad:
        raise ValueError(f"render_montage: every entry must be a FlightTrace, got {bad}")
    if labels is None:
        labels = [t.label for t in traces]
    if isinstance(labels, str) or len(labels) != len(traces):
        raise ValueError(f"render_montage: {len(traces)} traces need {len(traces)} labels, got {labels!r}")
    out = Path(out)
    writer = checked_animation_writer("render_montage", out, fps, size_px, trail_s, exaggerate)
    arm = arm_length_of(arm_length)

    t_end = max(t.duration for t in traces)
    tau = frame_times(t_end, fps, speed)
    if share_view not in (True, False, "auto"):
        raise ValueError(f"render_montage: share_view must be True, False or 'auto', got {share_view!r}")
    points = [np.concatenate([t.position, t.target_path]) for t in traces]
    if share_view == "auto":
        extents = [_extent(p) for p in points]
        share_view = max(extents) <= SHARE_VIEW_RATIO * min(extents)
    view = np.concatenate(points) if share_view else None
    errors = np.concatenate([t.error for t in traces])
    errors = np.maximum(errors[np.isfinite(errors)], ERROR_FLOOR_M)
    error_ylim = (float(errors.min()) / 1.5, float(errors.max()) * 1.5) if errors.size else None

    width, height = size_px
    fig = new_figure(width / dpi, height / dpi, dpi)
    n = len(traces)
    scenes = []
    for i, (trace, label) in enumerate(zip(traces, labels, strict=True)):
        rect = (i / n, 0.0, 1.0 / n, 1.0 - TITLE_HEIGHT)
        scene = FlightScene(
            fig,
            trace,
            arm,
            trail_s,
            exaggerate,
            rect=rect,
            layout="below",
            view_points=view,
            error_ylim=error_ylim,
            t_end=t_end,
            show_label=False,
        )
        scenes.append((scene, indices_at(trace, tau), trace.duration))
        fig.text((i + 0.5) / n, 0.985, str(label), ha="center", va="top", fontsize=7, linespacing=1.15)
        if i:  # a hairline between panels
            fig.add_artist(_vline(fig, i / n))

    with atomic_output(out) as tmp, writer.saving(fig, str(tmp), dpi):
        for k, now in enumerate(tau):
            for scene, idx, duration in scenes:
                scene.update(int(idx[k]), ended=now > duration + 1e-9)
            writer.grab_frame()
    return out


def _extent(points: np.ndarray) -> float:
    """Half the largest side of the box around the finite points, at least the smallest view's
    (`MIN_VIEW_HALF`), so a perfect hover does not count as zero."""
    pts = points[np.isfinite(points).all(axis=1)]
    return max(float((pts.max(axis=0) - pts.min(axis=0)).max()) / 2, MIN_VIEW_HALF)


def _vline(fig, x: float):
    from matplotlib.lines import Line2D

    return Line2D([x, x], [0.03, 0.97], transform=fig.transFigure, color="0.8", lw=0.6)
