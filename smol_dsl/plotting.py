"""The paper's Figure 2: alpha over training for one or more schedules."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.schedule import Schedule

if TYPE_CHECKING:
    import jax
    from matplotlib.figure import Figure

FIGURE_FORMATS = (".png", ".svg", ".pdf")
PAPER_FIGURE = ("vanilla", "smol", "smol-reverse", "human")
"""The schedules of the paper's Figure 2, in its order."""


def schedule_figure(
    schedules: Sequence[Schedule],
    *,
    num_phases: int = 100,
    key: jax.Array | None = None,
    smooth_points: int = 1001,
) -> Figure:
    """Draw alpha per phase (steps) and the smooth curve for each schedule, overlaid.

    A dashed vertical line marks where alpha becomes 1 for good (one line per distinct
    tail start). Returns the matplotlib Figure; save it with `figure.savefig(path)`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import jax.numpy as jnp
    from matplotlib.figure import Figure

    figure = Figure(figsize=(7.0, 4.2), layout="constrained")
    axes = figure.add_subplot()
    smooth_t = np.linspace(0.0, 1.0, smooth_points)
    phase_starts = np.arange(num_phases + 1) / num_phases * 100
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, schedule in enumerate(schedules):
        color = colors[i % len(colors)]
        steps = np.asarray(schedule.phase_alphas(num_phases, key))
        axes.step(phase_starts, np.append(steps, steps[-1]), where="post", color=color, lw=2.0, label=schedule.name)
        curve = np.asarray(schedule.alpha(jnp.asarray(smooth_t), key))
        axes.plot(smooth_t * 100, curve, color=color, lw=1.0, alpha=0.45)
    for tail in sorted({float(s.tail_start) for s in schedules if 0 < s.tail_start < 1}):
        axes.axvline(tail * 100, color="0.3", ls="--", lw=1.0)
        axes.annotate("α = 1", xy=(tail * 100, 1.0), xytext=(4, 6), textcoords="offset points", fontsize=8, color="0.3")
    axes.axhline(1.0, color="0.7", lw=0.6, zorder=0)
    axes.set_xlim(0, 100)
    axes.set_xlabel("training progress (%)")
    axes.set_ylabel("α (actuator gear scale)")
    axes.set_title(f"Torque scaling schedules ({num_phases} phases)")
    axes.grid(alpha=0.25)
    axes.legend(frameon=False, fontsize=9)
    return figure


def save_figure(figure: Figure, out: str | Path) -> Path:
    """Save to PNG, SVG or PDF by the file's suffix."""
    path = Path(out)
    if path.suffix.lower() not in FIGURE_FORMATS:
        raise ValueError(
            f"unsupported figure format {path.suffix or '(none)'!r}; use one of {', '.join(FIGURE_FORMATS)}"
        )
    figure.savefig(path, dpi=150)
    return path
