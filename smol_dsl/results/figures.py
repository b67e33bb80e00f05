"""What every figure smol-dsl draws shares: line styles that keep many series apart
(`series_styles`), legend labels and placement (`legend_label`, `place_legend`) and saving
(`save_figure`). The figures themselves: `schedule_figures` (the paper's Figure 2),
`run_figures` (a run's metrics.png and archive.png), `archive_maps` (an archive as a map)
and `report_figures` (the report's, across runs).

Figures are `matplotlib.figure.Figure`s made directly, never through pyplot, so no
matplotlib backend is selected or switched anywhere: `save_figure` (or `figure.savefig`)
renders PNG, SVG or PDF by the file's suffix. Everything is drawn from plain data (metrics
rows, numpy arrays, descriptor bounds, a run directory's record, a Schedule); nothing imports
Brax, and JAX only inside `schedule_figure`, which evaluates schedules.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib
import matplotlib.colors

from smol_dsl.rundir.files import atomic_write

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FIGURE_FORMATS = (".png", ".svg", ".pdf")

LEGEND_INSIDE = 10
"""Up to this many series the legend sits inside the axes; past it, below them in columns."""
DASHES = ("-", "--", ":", "-.")
MARKERS = (None, "o", "s", "^", "v", "D", "x", "+")
LABEL_CHARS = 40
"""Legend labels longer than this are shortened (with an ellipsis)."""


def series_styles(count: int) -> list[dict[str, Any]]:
    """`count` distinguishable line styles for plot(): matplotlib's 10 colours for up to 10
    series; past that, tab20's 20 colours times 4 dash patterns (80 different), then markers."""
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


def save_figure(figure: Figure, out: str | Path, *, dpi: int = 150) -> Path:
    """Save to PNG, SVG or PDF by the file's suffix, atomically (`rundir.files.atomic_write`),
    so `out` is never left half-written."""
    path = Path(out)
    if path.suffix.lower() not in FIGURE_FORMATS:
        raise ValueError(
            f"unsupported figure format {path.suffix or '(none)'!r}; use one of {', '.join(FIGURE_FORMATS)}"
        )
    atomic_write(path, lambda file: figure.savefig(file, dpi=dpi, format=path.suffix.lower()[1:]))
    return path
