"""The paper's Figure 2: alpha over training for one or more schedules; and the line styles
and legend placement shared with the report's figures."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl import Schedule

if TYPE_CHECKING:
    import jax
    from matplotlib.figure import Figure

FIGURE_FORMATS = (".png", ".svg", ".pdf")
PAPER_FIGURE = ("vanilla", "smol", "smol-reverse", "human")
"""The schedules of the paper's Figure 2, in its order."""

LEGEND_INSIDE = 10
"""Up to this many series the legend sits inside the axes; past it, below them in columns."""
DASHES = ("-", "--", ":", "-.")
MARKERS = (None, "o", "s", "^", "v", "D", "x", "+")
LABEL_CHARS = 40
"""Legend labels longer than this are shortened (with an ellipsis)."""


def series_styles(count: int) -> list[dict[str, Any]]:
    """`count` distinguishable line styles for plot(): matplotlib's 10 colours for up to 10
    series; past that, tab20's 20 colours times 4 dash patterns (80 different), then markers."""
    import matplotlib

    if count <= len(matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]):
        colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    else:
        colors = [matplotlib.colors.to_hex(c) for c in matplotlib.colormaps["tab20"].colors]
    styles = []
    for k in range(count):
        pattern, rest = divmod(k, len(colors))
        style: dict[str, Any] = {"color": colors[rest], "ls": DASHES[pattern % len(DASHES)]}
        marker = MARKERS[(pattern // len(DASHES)) % len(MARKERS)]
        if marker is not None:
            style.update(marker=marker, markevery=0.1, markersize=4)
        styles.append(style)
    return styles


def legend_label(text: str) -> str:
    """A name as a legend or title shows it: literal (no mathtext) and not too long."""
    if len(text) > LABEL_CHARS:
        text = text[: LABEL_CHARS - 1] + "…"
    return text.replace("$", r"\$")


def place_legend(figure: Figure, axes: Any, *, fontsize: float = 8, **options: Any) -> None:
    """The legend of axes' labelled lines: inside the axes for up to LEGEND_INSIDE series;
    otherwise below the plot, in as many columns as the figure's width holds, the figure
    made taller to fit it, so that any number of series fits without overlapping."""
    handles, labels = axes.get_legend_handles_labels()
    if len(labels) <= LEGEND_INSIDE:
        axes.legend(handles, labels, fontsize=fontsize, **options)
        return
    width, height = figure.get_size_inches()
    longest = max(len(label) for label in labels)
    column = 0.55 + longest * fontsize * 0.0085  # inches: the line sample, then the text
    columns = max(1, min(len(labels), int(width * 0.95 // column)))
    rows = math.ceil(len(labels) / columns)
    figure.set_size_inches(width, height + rows * fontsize * 0.022 + 0.35)
    figure.legend(handles, labels, loc="outside lower center", ncols=columns, fontsize=fontsize, **options)


def schedule_figure(
    schedules: Sequence[Schedule],
    *,
    num_phases: int = 100,
    key: jax.Array | None = None,
    smooth_points: int = 1001,
) -> Figure:
    """Draw alpha per phase (steps) and the smooth curve for each schedule, overlaid.

    A dashed vertical line marks where alpha becomes 1 for good (one line per distinct
    tail start). Each schedule has its own colour (and, past 20 schedules, dash pattern);
    past 10 schedules the legend goes below the plot. Returns the matplotlib Figure; save
    it with `save_figure(figure, path)` or `figure.savefig(path)`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import jax.numpy as jnp
    from matplotlib.figure import Figure

    figure = Figure(figsize=(7.0, 4.2), layout="constrained")
    axes = figure.add_subplot()
    smooth_t = np.linspace(0.0, 1.0, smooth_points)
    phase_starts = np.arange(num_phases + 1) / num_phases * 100
    for schedule, style in zip(schedules, series_styles(len(schedules)), strict=True):
        steps = np.asarray(schedule.phase_alphas(num_phases, key))
        label = legend_label(schedule.name)
        axes.step(phase_starts, np.append(steps, steps[-1]), where="post", lw=2.0, label=label, **style)
        curve = np.asarray(schedule.alpha(jnp.asarray(smooth_t), key))
        axes.plot(smooth_t * 100, curve, color=style["color"], ls=style["ls"], lw=1.0, alpha=0.45)
    for tail in sorted({float(s.tail_start) for s in schedules if 0 < s.tail_start < 1}):
        axes.axvline(tail * 100, color="0.3", ls="--", lw=1.0)
        axes.annotate("α = 1", xy=(tail * 100, 1.0), xytext=(4, 6), textcoords="offset points", fontsize=8, color="0.3")
    axes.axhline(1.0, color="0.7", lw=0.6, zorder=0)
    axes.set_xlim(0, 100)
    axes.set_xlabel("training progress (%)")
    axes.set_ylabel("α (actuator gear scale)")
    axes.set_title(f"Torque scaling schedules ({num_phases} phases)")
    axes.grid(alpha=0.25)
    place_legend(figure, axes, fontsize=9 if len(schedules) <= LEGEND_INSIDE else 8, frameon=False)
    return figure


def save_figure(figure: Figure, out: str | Path, *, dpi: int = 150) -> Path:
    """Save to PNG, SVG or PDF by the file's suffix, atomically: the figure is drawn into a
    temporary file beside `out` and renamed over it, so `out` is never left half-written."""
    path = Path(out)
    if path.suffix.lower() not in FIGURE_FORMATS:
        raise ValueError(
            f"unsupported figure format {path.suffix or '(none)'!r}; use one of {', '.join(FIGURE_FORMATS)}"
        )
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        figure.savefig(temporary, dpi=dpi, format=path.suffix.lower()[1:])
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return path
