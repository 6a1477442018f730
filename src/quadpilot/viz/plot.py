"""`plot_flight`: one PNG summarising one or many recorded flights.

Panels (12×8 in at 100 dpi → 1200×800 px): the 3-D path with start markers and the target (point
or path), the position error on a log axis, x/y/z against their targets, roll/pitch/yaw in
degrees, the motor commands of one episode and the speed. Time axes show seconds since each
episode's first step. Steps not commanded by the policy (fallback, blind, ...) are shaded, and a
latched failsafe is a red dash-dot line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_output
from quadpilot.core.dynamics import ATT, MOTOR_NAMES, VEL
from quadpilot.core.mission import SUCCESS_TOLERANCE_M

from ._mpl import new_figure
from .trace import FlightTrace

SOURCE_COLOURS = {"fallback": "tab:orange", "blind": "tab:red"}
"""Shading per non-policy source; any other name is grey."""
OTHER_SOURCE_COLOUR = "tab:gray"
FAILSAFE_COLOUR = "red"
ERROR_FLOOR_M = 1e-4
"""Errors below this are drawn at it, so a log axis survives an exact zero."""
SUCCESS_TOL_M = SUCCESS_TOLERANCE_M
"""The hover bar's error tolerance, drawn for reference."""
PLOT_FORMATS = (".png", ".svg", ".pdf")


def check_plot_output(out: str | Path) -> None:
    """Raise now what `plot_flight(traces, out)` would raise about the file type and matplotlib
    (ValueError, VizUnavailable), so a command line can refuse before it flies."""
    if Path(out).suffix.lower() not in PLOT_FORMATS:
        raise ValueError(f"plot_flight: {out} must end in one of {', '.join(PLOT_FORMATS)}")
    new_figure(1.0, 1.0, 10)


def plot_flight(
    traces: FlightTrace | Sequence[FlightTrace],
    out: str | Path,
    title: str = "",
    *,
    commands_of: int = 0,
    max_labels: int = 5,
    dpi: int = 100,
) -> Path:
    """Draw `traces` (one or many episodes, overlaid) into `out` and return its path.

    out: a .png (also .svg or .pdf); parent directories are created. commands_of: index of the
    episode whose motor commands are drawn. max_labels: episodes named in the legend; the rest are
    summarised as "+k more". Raises VizUnavailable without matplotlib, ValueError on bad input.
    """
    traces = _as_traces(traces)
    out = Path(out)
    check_plot_output(out)
    if not -len(traces) <= commands_of < len(traces):
        raise ValueError(f"plot_flight: commands_of={commands_of}, but there are {len(traces)} traces")

    fig = new_figure(12.0, 8.0, dpi)
    gs = fig.add_gridspec(
        3,
        3,
        width_ratios=(1.1, 1.0, 1.0),
        left=0.055,
        right=0.985,
        bottom=0.065,
        top=0.93 if title else 0.965,
        wspace=0.3,
        hspace=0.32,
    )
    ax3d = fig.add_subplot(gs[0:2, 0], projection="3d")
    ax_err = fig.add_subplot(gs[2, 0])
    ax_xyz = [fig.add_subplot(gs[i, 1], sharex=ax_err) for i in range(3)]
    ax_att = fig.add_subplot(gs[0, 2], sharex=ax_err)
    ax_cmd = fig.add_subplot(gs[1, 2], sharex=ax_err)
    ax_spd = fig.add_subplot(gs[2, 2], sharex=ax_err)
    time_axes = [ax_err, *ax_xyz, ax_att, ax_cmd, ax_spd]

    n = len(traces)
    colours = _episode_colours(n)
    alpha = 1.0 if n == 1 else max(0.2, min(0.85, 3.0 / n))
    lw = 1.2 if n <= 5 else 0.8
    names = [tr.label or f"episode {k}" for k, tr in enumerate(traces)]

    # Shading and failsafe lines first, so the curves sit on top of them.
    shade_alpha = 0.25 if n == 1 else max(0.05, 0.25 / math.sqrt(n))
    kinds: set[str] = set()
    any_failsafe = False
    for k, tr in enumerate(traces):
        spans = merged_spans(tr)
        kinds.update(src for _, _, src in spans)
        for ax in time_axes:
            if ax is ax_cmd and k != commands_of % n:  # the commands panel shows one episode
                continue
            a = 0.25 if ax is ax_cmd else shade_alpha
            for t0, t1, src in spans:
                ax.axvspan(t0, t1, color=SOURCE_COLOURS.get(src, OTHER_SOURCE_COLOUR), alpha=a, lw=0)
            if tr.failsafe_time is not None:
                any_failsafe = True
                ax.axvline(tr.failsafe_time, color=FAILSAFE_COLOUR, ls="-.", lw=1.0)

    _draw_path_3d(ax3d, traces, colours, alpha, lw, names, max_labels)

    targets_drawn: list[np.ndarray] = []
    for k, tr in enumerate(traces):
        c, time, pos = colours[k], tr.time, tr.position
        ax_err.semilogy(time, np.maximum(tr.error, ERROR_FLOOR_M), color=c, alpha=alpha, lw=lw)
        new_fixed = not tr.moving_target and not any(np.allclose(tr.target, d) for d in targets_drawn)
        if new_fixed:
            targets_drawn.append(tr.target)
        for i, ax in enumerate(ax_xyz):
            ax.plot(time, pos[:, i], color=c, alpha=alpha, lw=lw)
            if tr.moving_target:
                ax.plot(time, tr.target[:, i], color="k", ls="--", lw=0.9, alpha=min(1.0, alpha + 0.1))
            elif new_fixed and len(targets_drawn) <= 10:
                ax.axhline(tr.target[i], color="k", ls="--", lw=0.9)
        t_att, att = _break_wraps(time, np.degrees(tr.states[:, ATT]))
        for i, angle_colour in enumerate(("tab:blue", "tab:orange", "tab:green")):
            ax_att.plot(t_att, att[:, i], color=angle_colour, alpha=alpha, lw=lw)
        ax_spd.plot(time, np.linalg.norm(tr.states[:, VEL], axis=1), color=c, alpha=alpha, lw=lw)

    sel = traces[commands_of]
    for i, (motor, mc) in enumerate(zip(MOTOR_NAMES, ("tab:red", "tab:blue", "tab:purple", "tab:cyan"), strict=True)):
        ax_cmd.plot(sel.time, sel.commands[:, i], color=mc, lw=0.9, label=f"{i} {motor.replace('_', '-')}")

    # Labels and legends.
    ax_err.axhline(SUCCESS_TOL_M, color="0.4", ls=":", lw=0.9)
    ax_err.set_ylabel("‖p − target‖ [m]")
    from matplotlib.ticker import NullFormatter

    ax_err.yaxis.set_minor_formatter(NullFormatter())  # under a decade, log minor labels crowd the axis
    ax_err.set_title("position error (dotted: 5 cm)", fontsize=9)
    for ax, axis in zip(ax_xyz, "xyz", strict=True):
        ax.set_ylabel(f"{axis} [m]")
    ax_xyz[0].set_title("position (dashed: target)", fontsize=9)
    ax_att.set_ylabel("angle [deg]")
    ax_att.set_title("attitude", fontsize=9)
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    ax_att.legend(
        [Line2D([], [], color=c) for c in ("tab:blue", "tab:orange", "tab:green")],
        ["roll", "pitch", "yaw"],
        fontsize=7,
        ncol=3,
        loc="upper right",
    )
    ax_cmd.set_ylim(-0.03, 1.03)
    ax_cmd.set_ylabel("ω/ω_max")
    ax_cmd.set_title(f"motor commands, {names[commands_of]}", fontsize=9)
    ax_cmd.legend(fontsize=6, ncol=4, loc="lower center", columnspacing=0.8, handlelength=1.2, borderaxespad=0.2)
    ax_spd.set_ylabel("‖v‖ [m/s]")
    ax_spd.set_title("speed", fontsize=9)
    for ax in (ax_err, ax_xyz[2], ax_spd):
        ax.set_xlabel("time since start [s]")
    handles = [Patch(color=SOURCE_COLOURS.get(s, OTHER_SOURCE_COLOUR), alpha=0.4, label=s) for s in sorted(kinds)]
    if any_failsafe:
        handles.append(Line2D([], [], color=FAILSAFE_COLOUR, ls="-.", label="failsafe"))
    if handles:
        ax_err.legend(handles=handles, fontsize=7, loc="upper right")
    end = max(tr.duration for tr in traces)
    ax_err.set_xlim(0.0, end if end > 0 else 1.0)
    for ax in time_axes:
        ax.grid(True, lw=0.4, alpha=0.5)
        ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title, fontsize=11)

    _save(fig, out, dpi)
    return out


def _save(fig, out: Path, dpi: int) -> None:
    """Write atomically (temp file in the same folder, then rename). A PNG is stored with a
    256-colour palette: overlaid translucent curves make a true-colour PNG two to three times
    larger (a 10-episode figure 270 KB → 60 KB) with no visible difference. Pillow comes with
    matplotlib; without it the PNG is written in true colour."""
    fmt = out.suffix.lower()[1:]
    try:
        from PIL import Image
    except ImportError:
        Image = None
    with atomic_output(out) as tmp:
        if fmt == "png" and Image is not None:
            fig.canvas.draw()
            rgb = Image.fromarray(np.asarray(fig.canvas.buffer_rgba())).convert("RGB")
            rgb.quantize(256, method=Image.Quantize.FASTOCTREE).save(tmp, format="png", optimize=True, dpi=(dpi, dpi))
        else:
            fig.savefig(tmp, dpi=dpi, format=fmt)


def _as_traces(traces) -> list[FlightTrace]:
    if isinstance(traces, FlightTrace):
        return [traces]
    traces = list(traces)
    if not traces:
        raise ValueError("plot_flight: no traces to draw")
    bad = [type(t).__name__ for t in traces if not isinstance(t, FlightTrace)]
    if bad:
        raise ValueError(f"plot_flight: expected FlightTrace objects, got {sorted(set(bad))}")
    return traces


def _episode_colours(n: int) -> list:
    from matplotlib import colormaps

    if n <= 10:
        cmap = colormaps["tab10"]
        return [cmap(k) for k in range(n)]
    cmap = colormaps["viridis"]
    return [cmap(k / (n - 1)) for k in range(n)]


def merged_spans(tr: FlightTrace, gap_s: float = 0.05) -> list[tuple[float, float, str]]:
    """Non-policy spans with same-source runs closer than `gap_s` joined: a source flickering every
    step would otherwise be hundreds of rectangles per panel."""
    merged: list[tuple[float, float, str]] = []
    for t0, t1, src in tr.non_policy_spans():
        if merged and merged[-1][2] == src and t0 - merged[-1][1] <= gap_s:
            merged[-1] = (merged[-1][0], t1, src)
        else:
            merged.append((t0, t1, src))
    return merged


def _break_wraps(time: np.ndarray, deg: np.ndarray, jump: float = 180.0) -> tuple[np.ndarray, np.ndarray]:
    """Insert a NaN row wherever an angle jumps by more than `jump` degrees between steps (yaw
    wrapping at ±180°), so the plot shows a gap instead of a vertical line."""
    if len(time) < 2:
        return time, deg
    cut = np.nonzero((np.abs(np.diff(deg, axis=0)) > jump).any(axis=1))[0] + 1
    if cut.size == 0:
        return time, deg
    return np.insert(time, cut, np.nan), np.insert(deg, cut, np.nan, axis=0)


def _draw_path_3d(ax, traces: list[FlightTrace], colours, alpha: float, lw: float, names, max_labels: int) -> None:
    from matplotlib.lines import Line2D

    pts = []
    fixed_targets: list[np.ndarray] = []
    for k, tr in enumerate(traces):
        pos = tr.position
        label = names[k] if k < max_labels else None
        ax.plot(pos[:, 0], pos[:, 1], pos[:, 2], color=colours[k], alpha=alpha, lw=lw, label=label)
        first = pos[np.isfinite(pos).all(axis=1)][0]
        ax.scatter(*first, color=colours[k], marker="o", s=18, alpha=min(1.0, alpha + 0.2), depthshade=False)
        pts.append(pos)
        if tr.moving_target:
            ax.plot(*tr.target.T, color="k", ls="--", lw=0.9, alpha=min(1.0, alpha + 0.1))
            pts.append(tr.target)
        elif not any(np.allclose(tr.target, d) for d in fixed_targets) and len(fixed_targets) < 20:
            fixed_targets.append(tr.target)
    for target in fixed_targets:
        ax.scatter(*target, color="k", marker="*", s=90, depthshade=False, zorder=5)
        pts.append(target[None])
    set_cube_limits(ax, np.concatenate(pts), zoom=1.05)
    ax.set_xlabel("x [m]", fontsize=8, labelpad=-2)
    ax.set_ylabel("y [m]", fontsize=8, labelpad=-2)
    ax.set_zlabel("z [m]", fontsize=8, labelpad=-2)
    ax.tick_params(labelsize=7, pad=0)
    ax.set_title("path (o start, ★/dashed target)", fontsize=9)
    handles, labels = ax.get_legend_handles_labels()
    if len(traces) > max_labels:
        handles.append(Line2D([], [], color="none"))
        labels.append(f"+{len(traces) - max_labels} more")
    if len(traces) > 1 or traces[0].label:
        ax.legend(handles, labels, fontsize=7, loc="upper left")


def set_cube_limits(
    ax, pts: np.ndarray, min_half: float = 0.15, margin: float = 1.08, pad: float = 0.0, zoom: float = 1.0
) -> float:
    """Equal scales on the three axes: a cube around the finite points, half width
    max(largest half range, min_half)·margin + pad. Returns the half width."""
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2
    half = max(float((hi - lo).max()) / 2, min_half) * margin + pad
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1), zoom=zoom)
    return half
