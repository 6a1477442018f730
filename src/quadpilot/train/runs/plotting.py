"""curves.png: a training run's learning curves, drawn from its metrics.csv (`runs.runlog`).

matplotlib is imported when a figure is drawn, and only its Agg canvas (no pyplot, no global
backend switch). `train` keeps its own plotting (docs/architecture.md: `train` does not import
`viz`).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_write

from .runlog import COLUMNS, read_metrics

PANELS = (("ep_return", "episode return"), ("ep_length", "episode length (steps)"), ("success_rate", "success"))
"""curves.png's panels by default (PPO's): (column, axis label[, log scale[, (column, label) on a second axis]])."""


def plot_curves(
    metrics_path: str | os.PathLike,
    out_path: str | os.PathLike,
    title: str = "",
    radii: tuple[float, ...] = (),
    columns: tuple[str, ...] = COLUMNS,
    panels: tuple = PANELS,
) -> Path:
    """curves.png: the `panels` of metrics.csv (header `columns`) against environment steps, the
    success panel with the deterministic evaluations (--eval-every) on the same axes, and the
    curriculum stage where there is one (`radii`: the radius of each stage, for the axis labels).
    Uses the Agg canvas directly (no pyplot, no global backend switch)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    m = read_metrics(metrics_path, columns)
    x = m["global_step"]
    panels = list(panels)
    if np.isfinite(m["curriculum_stage"]).any():
        panels.append(("curriculum_stage", "curriculum stage"))
    fig = Figure(figsize=(8, 2.2 * len(panels)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (key, label, *more) in zip(axes, panels, strict=True):
        log, twin = (*more, False, None)[:2]
        if key == "curriculum_stage":
            ax.step(x, m[key], where="post", color="C3")
            seen = {
                int(s): r for s, r in zip(m[key], m["target_radius"], strict=True) if np.isfinite(s) and np.isfinite(r)
            }
            labels = {**seen, **dict(enumerate(radii))}
            ax.set_yticks(sorted(labels), [f"{s} ({labels[s]:g} m)" for s in sorted(labels)])
            ax.set_ylim(-0.3, max(labels) + 0.3)
        else:
            (ax.semilogy if log else ax.plot)(x, m[key], lw=1.2)
        if key == "success_rate":
            ax.set_ylim(-0.02, 1.02)
            ev = np.isfinite(m["eval_success_rate"])
            if ev.any():
                ev_label = "deterministic evaluation"
                ax.plot(x[ev], m["eval_success_rate"][ev], "o-", ms=3, lw=1, color="C2", label=ev_label)
                ax.lines[0].set_label("training episodes")
                ax.legend(loc="lower right", fontsize=8)
        if twin:
            ax2 = ax.twinx()
            ax2.plot(x, m[twin[0]], lw=1, color="C1")
            ax2.set_ylabel(twin[1], color="C1")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("environment steps")
    if title:
        fig.suptitle(title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return atomic_write(out_path, lambda f: f.write(buf.getvalue()))
