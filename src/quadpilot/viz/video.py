"""`render_flight_video`: one recorded flight as a small animation (.gif, or .mp4 with ffmpeg).

Rendered after the flight from the recorded trace, never inside a control loop: each frame is a
full matplotlib draw (tens of ms). Frames are taken from the trace at `fps / speed` per simulated
second (the sample at or just before each frame time), so a 5 s flight at 25 fps is 126 frames
whatever the control rate.

Left, a 3-D view: the quadrotor as its two diagonal arms and four rotor discs (front rotors red,
rear blue, so the heading reads), rotated by its attitude; a dotted drop line to the floor; a
fading trail of the last `trail_s` seconds over the faint whole path; the target (a star, or a
dashed path with a moving dot). When the true arm is under 4 % of the view's width the vehicle is
drawn with arms ×3 (`geometry.display_arm`), and the frame says so. Right, the position error and
the motor commands over the whole flight, with a cursor at the current time.

The drawing of one flight (`FlightScene`) also makes each panel of `montage.render_montage`. A
.gif is written with one palette for all its frames and each frame's unchanged pixels stored as
transparent (`gif_writer_class`): 3–7× smaller than matplotlib's PillowWriter, same look.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_output
from quadpilot.core.dynamics import ATT, POS

from ._mpl import MATPLOTLIB_MISSING, VizUnavailable, new_figure
from .geometry import arm_length_of, body_points, display_arm, rotor_discs
from .plot import (
    ERROR_FLOOR_M,
    FAILSAFE_COLOUR,
    OTHER_SOURCE_COLOUR,
    SOURCE_COLOURS,
    merged_spans,
    set_cube_limits,
)
from .trace import POLICY, FlightTrace

VIDEO_FORMATS = (".gif", ".mp4")
ROTOR_RADIUS = 0.5
"""Drawn rotor disc radius as a fraction of the (drawn) arm: a 5-inch propeller on the seed
vehicle's 0.105 m arm is 0.6 of it; a little smaller keeps the discs apart."""
MOTOR_COLOURS = ("tab:red", "tab:blue", "tab:purple", "tab:cyan")
MIN_VIEW_HALF = 0.25
"""m, the 3-D view is at least this far on each side of the flight's centre."""
TRAIL_SEGMENTS = 60


def frame_indices(trace: FlightTrace, fps: float, speed: float = 1.0) -> np.ndarray:
    """Index into the trace of each video frame: frame k shows simulated time k·speed/fps since the
    start, using the latest sample at or before it. floor(duration·fps/speed) + 1 frames."""
    return indices_at(trace, frame_times(trace.duration, fps, speed))


def frame_times(duration: float, fps: float, speed: float = 1.0) -> np.ndarray:
    """Simulated time (s since the start) shown by each frame of a video of `duration` simulated
    seconds: k·speed/fps for k = 0 … floor(duration·fps/speed)."""
    if not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    if not (speed > 0 and math.isfinite(speed)):
        raise ValueError(f"speed must be a positive number, got {speed!r}")
    n_frames = math.floor(duration * fps / speed + 1e-9) + 1
    return np.arange(n_frames) * (speed / fps)


def indices_at(trace: FlightTrace, tau: np.ndarray) -> np.ndarray:
    """Index of the latest sample of `trace` at or before each time `tau` (s since its start);
    times past its end give its last sample (a flight that ended early holds its last picture)."""
    return np.clip(np.searchsorted(trace.time, np.asarray(tau) + 1e-9, side="right") - 1, 0, trace.n - 1)


def check_video_output(out: str | Path) -> None:
    """Raise now what `render_flight_video(trace, out)` would raise about the file type and the
    writer (ValueError for a bad suffix, VizUnavailable without matplotlib, pillow or ffmpeg), so a
    command line can refuse before it flies rather than after."""
    suffix = Path(out).suffix.lower()
    if suffix not in VIDEO_FORMATS:
        raise ValueError(f"render_flight_video: {out} must end in .gif or .mp4")
    _writer(suffix, 25)


def render_flight_video(
    trace: FlightTrace,
    out: str | Path,
    fps: int = 25,
    arm_length: float | str | None = None,
    speed: float = 1.0,
    *,
    size_px: tuple[int, int] = (480, 360),
    dpi: int = 100,
    trail_s: float = 2.0,
    exaggerate: float | None = None,
) -> Path:
    """Render `trace` into `out` (.gif with pillow, .mp4 with ffmpeg) and return its path.

    arm_length: the vehicle's arm in m, or a `core.params` preset name; None is the seed vehicle
    (quad-sitl's default airframe). speed: simulated seconds per video second. exaggerate: the arm
    drawing factor; None chooses ×3 when the vehicle would be too small to see, else ×1.
    The file is written atomically (a temporary file in the same folder, then renamed).
    Raises VizUnavailable without matplotlib, or for .mp4 without ffmpeg; ValueError on bad input.
    """
    if not isinstance(trace, FlightTrace):
        raise ValueError(f"render_flight_video: expected one FlightTrace, got {type(trace).__name__}")
    out = Path(out)
    writer = checked_animation_writer("render_flight_video", out, fps, size_px, trail_s, exaggerate)
    arm = arm_length_of(arm_length)
    frames = frame_indices(trace, fps, speed)

    width, height = size_px
    fig = new_figure(width / dpi, height / dpi, dpi)
    scene = FlightScene(fig, trace, arm, trail_s, exaggerate)

    with atomic_output(out) as tmp, writer.saving(fig, str(tmp), dpi):
        for k in frames:
            scene.update(int(k))
            writer.grab_frame()
    return out


def checked_animation_writer(who: str, out: Path, fps, size_px, trail_s, exaggerate):
    """Check the options every animation takes; returns the matplotlib writer for `out`."""
    suffix = out.suffix.lower()
    if suffix not in VIDEO_FORMATS:
        raise ValueError(f"{who}: {out} must end in .gif or .mp4")
    if isinstance(fps, bool) or not isinstance(fps, int) or fps < 1:
        raise ValueError(f"{who}: fps must be a positive integer, got {fps!r}")
    if not (len(size_px) == 2 and all(isinstance(v, int) and v >= 16 for v in size_px)):
        raise ValueError(f"{who}: size_px must be two integers ≥ 16 (width, height), got {size_px!r}")
    if suffix == ".mp4" and (size_px[0] % 2 or size_px[1] % 2):
        raise ValueError(f"{who}: an .mp4 needs an even width and height, got {size_px!r}")
    if not (trail_s >= 0 and math.isfinite(trail_s)):
        raise ValueError(f"{who}: trail_s must be ≥ 0 seconds, got {trail_s!r}")
    if exaggerate is not None and not (exaggerate > 0 and math.isfinite(exaggerate)):
        raise ValueError(f"{who}: exaggerate must be a positive number or None, got {exaggerate!r}")
    return _writer(suffix, fps)


def _writer(suffix: str, fps: int):
    try:
        from matplotlib import animation
    except ImportError as e:
        raise VizUnavailable(MATPLOTLIB_MISSING) from e
    if suffix == ".gif":
        try:
            import PIL  # noqa: F401  (matplotlib depends on pillow; say so if it is gone anyway)
        except ImportError as e:
            raise VizUnavailable("a .gif needs pillow: pip install pillow") from e
        return gif_writer_class()(fps=fps)
    if not animation.FFMpegWriter.isAvailable():
        raise VizUnavailable(
            "an .mp4 needs ffmpeg, which is not on PATH: install ffmpeg (e.g. apt-get install ffmpeg), "
            "or write a .gif instead (e.g. flight.gif)"
        )
    # yuv420p: the pixel format every player accepts (needs even width and height).
    return animation.FFMpegWriter(fps=fps, extra_args=["-pix_fmt", "yuv420p"])


GIF_COLOURS = 253
"""Colours of a GIF's shared palette besides pure white and black (one index stays free for
transparency: 256 in all)."""
NEAR_WHITE_BLACK = 8
"""Palette colours this close (per channel) to white or black are replaced by exact white or black."""


@functools.cache
def gif_writer_class():
    """matplotlib's PillowWriter, writing a smaller GIF: one palette for every frame (median cut
    over a sample of frames, plus exact white and black so the background stays white), no
    dithering, and Pillow's `optimize`, which then stores each frame's unchanged pixels as
    transparent. Plots change little between frames, so this is 3–7× smaller than PillowWriter's
    per-frame palettes, at the same look."""
    from matplotlib import animation
    from PIL import Image

    class SharedPaletteGifWriter(animation.PillowWriter):
        def finish(self) -> None:
            frames = [f.convert("RGB") for f in self._frames]
            sample = frames[:: max(1, len(frames) // 16)]
            width, height = sample[0].size
            tile = Image.new("RGB", (width, height * len(sample)))
            for i, f in enumerate(sample):
                tile.paste(f, (0, i * height))
            quantized = tile.quantize(GIF_COLOURS, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
            used = len(quantized.getcolors(256) or [])
            found = np.asarray(quantized.getpalette()[: 3 * used], dtype=int).reshape(-1, 3)
            # Pillow maps a pixel to a palette colour through a coarse cache, so a near-white
            # entry can win over white: drop those and put white and black first.
            near = (found.min(axis=1) >= 255 - NEAR_WHITE_BLACK) | (found.max(axis=1) <= NEAR_WHITE_BLACK)
            colours = [255, 255, 255, 0, 0, 0, *found[~near].ravel().tolist()]
            palette = Image.new("P", (1, 1))
            palette.putpalette(colours)
            indexed = [f.quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
            indexed[0].save(
                self.outfile,
                save_all=True,
                append_images=indexed[1:],
                duration=int(1000 / self.fps),
                loop=0,
                optimize=True,
            )

    return SharedPaletteGifWriter


# Where a scene's parts go. Axes boxes are fractions of the scene's rectangle (x, y, width,
# height); texts are (x, y, ha, va) in the 3-D view's axes fractions; ticks: per 3-D axis at most.
# "side": one flight filling the figure, 3-D view left, error and motor panels right.
# "below": one panel of a montage: the 3-D view, the error strip under it, no motor panel.
LAYOUTS = {
    "side": {
        "view": (0.01, 0.02, 0.62, 0.96),
        "error": (0.74, 0.58, 0.245, 0.36),
        "motors": (0.74, 0.12, 0.245, 0.36),
        "clock": (0.02, 0.94, "left", "baseline"),
        "status": (0.02, 0.88, "left", "baseline"),
        "note": (0.98, 0.94, "right", "top"),
        "ticks": 4,
        "zoom": 1.12,
    },
    "below": {
        "view": (0.0, 0.25, 1.0, 0.75),
        "error": (0.2, 0.08, 0.74, 0.15),
        "motors": None,
        "clock": (0.03, 0.99, "left", "top"),
        "status": (0.03, 0.91, "left", "top"),
        "note": (0.97, 0.91, "right", "top"),
        "ticks": 3,
        "zoom": 1.08,
    },
}


def _inside(rect: tuple[float, float, float, float], box: tuple[float, float, float, float]):
    """`box` given in fractions of `rect`, in figure fractions."""
    x, y, w, h = rect
    bx, by, bw, bh = box
    return (x + bx * w, y + by * h, bw * w, bh * h)


class FlightScene:
    """The artists of one flight's drawing, created once and moved per frame.

    rect: the part of the figure it owns (figure fractions); layout: a key of `LAYOUTS`.
    view_points: (M, 3) points the 3-D view must contain (default: the flight and its target), so
    several scenes can share one view. error_ylim, t_end: shared error-axis and time-axis limits.
    show_label: write `trace.label` in the view's corner."""

    def __init__(
        self,
        fig,
        trace: FlightTrace,
        arm: float,
        trail_s: float,
        exaggerate: float | None,
        *,
        rect: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0),
        layout: str = "side",
        view_points: np.ndarray | None = None,
        error_ylim: tuple[float, float] | None = None,
        t_end: float | None = None,
        show_label: bool = True,
    ) -> None:
        from matplotlib.ticker import MaxNLocator, NullFormatter
        from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

        self.trace = trace
        time = trace.time
        pos = trace.position
        step = float(np.median(np.diff(time))) if trace.n > 1 else 0.01
        self.trail_steps = max(1, round(trail_s / step)) if step > 0 else 1
        boxes = LAYOUTS[layout]

        ax = fig.add_axes(_inside(rect, boxes["view"]), projection="3d")
        self.ax = ax
        pts = np.concatenate([pos, trace.target_path]) if view_points is None else np.asarray(view_points)
        half = set_cube_limits(ax, pts, min_half=MIN_VIEW_HALF)
        if exaggerate is None:
            self.arm, factor = display_arm(arm, 2 * half)
        else:
            self.arm, factor = arm * exaggerate, exaggerate
        ax.view_init(elev=22, azim=-60)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(boxes["ticks"]))
        ax.tick_params(labelsize=6, pad=-2)
        ax.set_xlabel("x [m]", fontsize=6, labelpad=-8)
        ax.set_ylabel("y [m]", fontsize=6, labelpad=-8)
        ax.set_zlabel("z [m]", fontsize=6, labelpad=-8)

        ax.plot(*pos.T, color="0.55", lw=0.6, alpha=0.5)
        if trace.moving_target:
            ax.plot(*trace.target.T, color="k", ls="--", lw=0.8, alpha=0.6)
            (self.target_dot,) = ax.plot([], [], [], "o", color="k", ms=4)
        else:
            ax.scatter(*trace.target, color="k", marker="*", s=60, depthshade=False)
            self.target_dot = None
        # Collections start with real geometry: add_collection3d reads it for the data limits.
        start = pos[np.isfinite(pos).all(axis=1)][0]
        level = np.zeros(12)
        level[POS] = start
        self.trail = Line3DCollection([np.stack([start, start])], linewidths=1.4)
        ax.add_collection3d(self.trail)
        (self.drop,) = ax.plot([], [], [], ls=":", color="0.4", lw=0.7)
        (self.shadow,) = ax.plot([], [], [], "o", color="0.6", ms=3)
        self.arms = [ax.plot([], [], [], color="k", lw=1.8, solid_capstyle="round")[0] for _ in range(2)]
        self.discs = Poly3DCollection(
            list(rotor_discs(level, self.arm, ROTOR_RADIUS * self.arm)),
            facecolors=["tab:red", "tab:blue", "tab:red", "tab:blue"],  # PX4 order: FR, RL, FL, RR
            edgecolors="k",
            linewidths=0.4,
            alpha=0.55,
        )
        ax.add_collection3d(self.discs)
        # pad: room for the drawn vehicle
        set_cube_limits(ax, pts, min_half=MIN_VIEW_HALF, pad=1.5 * self.arm, zoom=boxes["zoom"])
        self.floor = ax.get_zlim()[0]

        def text(where: str, **kw):
            x, y, ha, va = boxes[where]
            return ax.text2D(x, y, kw.pop("s", ""), transform=ax.transAxes, ha=ha, va=va, **kw)

        self.clock = text("clock", fontsize=7, family="monospace")
        self.status = text("status", fontsize=7, weight="bold")
        notes = [trace.label] if trace.label and show_label else []
        if factor != 1.0:
            notes.append(f"vehicle drawn ×{factor:g}")
        text("note", s="\n".join(notes), fontsize=6, color="0.3")

        end = t_end if t_end is not None else trace.duration
        end = end if end > 0 else 1.0
        ax_err = fig.add_axes(_inside(rect, boxes["error"]))
        ax_err.semilogy(time, np.maximum(trace.error, ERROR_FLOOR_M), color="tab:blue", lw=0.9)
        if error_ylim is not None:
            ax_err.set_ylim(*error_ylim)
        ax_err.set_xlim(0.0, end)
        panels = [ax_err]
        if boxes["motors"] is not None:
            ax_cmd = fig.add_axes(_inside(rect, boxes["motors"]), sharex=ax_err)
            for i, c in enumerate(MOTOR_COLOURS):
                ax_cmd.plot(time, trace.commands[:, i], color=c, lw=0.7)
            ax_cmd.set_ylim(-0.03, 1.03)
            ax_cmd.set_title("motors ω/ω_max", fontsize=7, pad=2)
            ax_cmd.set_xlabel("time [s]", fontsize=6, labelpad=1)
            ax_err.set_title("error [m]", fontsize=7, pad=2)
            ax_err.tick_params(labelbottom=False)
            panels.append(ax_cmd)
        else:
            ax_err.set_ylabel("error [m]", fontsize=6, labelpad=1)
            ax_err.set_xlabel("time [s]", fontsize=6, labelpad=1)
        for a in panels:
            a.tick_params(labelsize=6, pad=1, length=2)
            a.grid(True, lw=0.3, alpha=0.5)
            for t0, t1, src in merged_spans(trace):
                a.axvspan(t0, t1, color=SOURCE_COLOURS.get(src, OTHER_SOURCE_COLOUR), alpha=0.3, lw=0)
            if trace.failsafe_time is not None:
                a.axvline(trace.failsafe_time, color=FAILSAFE_COLOUR, ls="-.", lw=0.8)
        ax_err.yaxis.set_minor_formatter(NullFormatter())  # under a decade, log minor labels are huge
        self.cursors = [a.axvline(0.0, color="k", lw=0.8) for a in panels]

        self._ramp = np.linspace(0.05, 1.0, TRAIL_SEGMENTS)

    def update(self, k: int, ended: bool = False) -> None:
        """Draw step k of the trace. ended: the video's clock has passed the end of this flight
        (a montage panel whose flight crashed early), said in the status line."""
        tr = self.trace
        s = tr.states[k]
        now = float(tr.time[k])
        for c in self.cursors:
            c.set_xdata([now, now])
        if self.target_dot is not None:
            self.target_dot.set_data_3d(*tr.target[k : k + 1].T)
        self.clock.set_text(f"t {now:5.2f} s  err {tr.error[k] * 100:6.1f} cm")
        src = tr.sources[k] if tr.sources is not None else POLICY
        if ended:
            self.status.set_text(f"ended at {tr.duration:.2f} s")
            self.status.set_color(FAILSAFE_COLOUR)
        elif tr.failsafe_time is not None and now >= tr.failsafe_time:
            self.status.set_text("FAILSAFE")
            self.status.set_color(FAILSAFE_COLOUR)
        elif src != POLICY:
            self.status.set_text(src)
            self.status.set_color(SOURCE_COLOURS.get(src, OTHER_SOURCE_COLOUR))
        else:
            self.status.set_text("")

        lo = max(0, k - self.trail_steps)
        idx = np.unique(np.linspace(lo, k, TRAIL_SEGMENTS + 1).round().astype(int))
        trail = tr.position[idx]
        segs = np.stack([trail[:-1], trail[1:]], axis=1)
        colours = np.zeros((len(segs), 4))
        colours[:, :3] = (0.12, 0.47, 0.71)  # tab:blue
        colours[:, 3] = self._ramp[TRAIL_SEGMENTS - len(segs) :]  # oldest faintest
        self.trail.set_segments(list(segs))
        self.trail.set_color(colours)

        if not (np.isfinite(s[POS]).all() and np.isfinite(s[ATT]).all()):
            # A diverged step: keep the last drawing of the vehicle and say so.
            self.status.set_text("state not finite")
            self.status.set_color(FAILSAFE_COLOUR)
            return
        p = s[POS]
        rotors = body_points(s, self.arm)
        for arm, (i, j) in zip(self.arms, ((0, 1), (2, 3)), strict=True):  # FR–RL and FL–RR diagonals
            arm.set_data_3d(*rotors[[i, j]].T)
        self.discs.set_verts(list(rotor_discs(s, self.arm, ROTOR_RADIUS * self.arm)))
        self.drop.set_data_3d([p[0], p[0]], [p[1], p[1]], [p[2], self.floor])
        self.shadow.set_data_3d([p[0]], [p[1]], [self.floor])
