"""Every figure smol-dsl draws: the paper's Figure 2 (`schedule_figure`: alpha, and every
other scheduled channel, over training), a run's metrics.png and archive.png (`save_run_figures`), and the report's
figures (`results_figure`: median and IQR over seeds; `archives_figure`: final archives side
by side); and the line styles and legend placement they share.

Figures are `matplotlib.figure.Figure`s made directly, never through pyplot, so no
matplotlib backend is selected or switched anywhere: `save_figure` (or `figure.savefig`)
renders PNG, SVG or PDF by the file's suffix. Everything is drawn from plain data (metrics
rows, numpy arrays, descriptor bounds, a run directory's record, a Schedule); nothing imports
Brax, and JAX only inside `schedule_figure`, which evaluates schedules.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib
import matplotlib.colors
import numpy as np
from matplotlib.figure import Figure

from smol_dsl.language.channels import GEAR
from smol_dsl.results.conditions import COLORS
from smol_dsl.rundir import (
    ALPHA,
    ARCHIVE_FIGURE,
    METRICS_FIGURE,
    METRICS_SCHEMA,
    SCORES,
    RunDirectoryError,
    read_run,
    scheduled_columns,
)
from smol_dsl.rundir.files import atomic_write
from smol_dsl.tasks import descriptor_bounds

if TYPE_CHECKING:
    import jax

    from smol_dsl.language.channels import Channel
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir import FinalArchive, RunRecord

FIGURE_FORMATS = (".png", ".svg", ".pdf")
PAPER_FIGURE = ("vanilla", "smol", "smol-reverse", "human")
"""The schedules of the paper's Figure 2, in its order."""

LEGEND_INSIDE = 10
"""Up to this many series the legend sits inside the axes; past it, below them in columns."""
DASHES = ("-", "--", ":", "-.")
MARKERS = (None, "o", "s", "^", "v", "D", "x", "+")
LABEL_CHARS = 40
"""Legend labels longer than this are shortened (with an ellipsis)."""
CHANNEL_PANELS = 6
"""Up to this many channels a schedule figure gives each its own panel; past it, one panel
per kind of channel (gear, mass, ...), each channel a line of steps."""


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


def schedule_figure(
    schedules: Sequence[Schedule],
    *,
    num_phases: int = 100,
    key: jax.Array | None = None,
    smooth_points: int = 1001,
) -> Figure:
    """Draw each channel per phase (steps) and its smooth curve, the schedules overlaid.

    One panel per channel of the union of the schedules' channels (in the order they are
    first declared); every schedule is drawn in every panel, a channel it does not declare
    at 1. Schedules of plain gear alone give the paper's Figure 2: one panel of alpha. A
    dashed vertical line marks where a channel reaches its final value for good (one line
    per distinct tail start). Each schedule has its own colour (and, past 20 schedules, dash
    pattern); past 10 schedules the legend goes below the plot. Past CHANNEL_PANELS
    channels, one panel per kind of channel instead (`kinds_figure`). Returns the matplotlib
    Figure; save it with `save_figure(figure, path)` or `figure.savefig(path)`.
    """
    channels = list(dict.fromkeys(channel for schedule in schedules for channel in schedule.channels))
    if len(channels) > CHANNEL_PANELS:
        return kinds_figure(schedules, channels, num_phases=num_phases, key=key)
    figure = Figure(figsize=(7.0, 4.2 if len(channels) == 1 else 1.0 + 2.5 * len(channels)), layout="constrained")
    panels = figure.subplots(len(channels), 1, sharex=True, squeeze=False)[:, 0]
    styles = series_styles(len(schedules))
    for axes, channel in zip(panels, channels, strict=True):
        _draw_channel(axes, schedules, channel, styles, num_phases=num_phases, key=key, smooth_points=smooth_points)
    panels[-1].set_xlabel("training progress (%)")
    if channels == [GEAR]:
        panels[0].set_title(f"Torque scaling schedules ({num_phases} phases)")
    else:
        figure.suptitle(f"Developmental schedules ({num_phases} phases)")
    place_legend(figure, panels[0], fontsize=9 if len(schedules) <= LEGEND_INSIDE else 8, frameon=False)
    return figure


def _draw_channel(
    axes: Any,
    schedules: Sequence[Schedule],
    channel: Channel,
    styles: Sequence[dict[str, Any]],
    *,
    num_phases: int,
    key: jax.Array | None,
    smooth_points: int,
) -> None:
    """One channel's panel of `schedule_figure`: every schedule's steps and smooth curve."""
    import jax.numpy as jnp  # the schedules are JAX functions

    smooth_t = np.linspace(0.0, 1.0, smooth_points)
    phase_starts = np.arange(num_phases + 1) / num_phases * 100
    for schedule, style in zip(schedules, styles, strict=True):
        curve = schedule.curve(channel, or_standard=True)  # a schedule without the channel: flat at 1
        steps = np.asarray(curve.phase_values(num_phases, key))
        label = legend_label(schedule.name)
        axes.step(phase_starts, np.append(steps, steps[-1]), where="post", lw=2.0, label=label, **style)
        smooth = np.asarray(curve.value(jnp.asarray(smooth_t), key))
        axes.plot(smooth_t * 100, smooth, color=style["color"], ls=style["ls"], lw=1.0, alpha=0.45)
    gear = channel == GEAR
    symbol = "α" if gear else channel.name
    tails = {
        (float(curve.tail_start), curve.final)
        for curve in (schedule.curve(channel) for schedule in schedules if channel in schedule.channels)
        if 0 < curve.tail_start < 1
    }
    for tail, final in sorted(tails):
        axes.axvline(tail * 100, color="0.3", ls="--", lw=1.0)
        text = legend_label(f"{symbol} = {final:g}")
        offset, align = ((4, 6), "left") if gear else ((-4, 6), "right")  # other channels' names are longer
        axes.annotate(
            text, xy=(tail * 100, final), xytext=offset, textcoords="offset points", ha=align, fontsize=8, color="0.3"
        )
    axes.axhline(1.0, color="0.7", lw=0.6, zorder=0)
    axes.set_xlim(0, 100)
    if not gear:
        axes.margins(y=0.12)  # room above a final value at the top of the panel for its label
    axes.set_ylabel("α (actuator gear scale)" if gear else f"{legend_label(channel.name)} (factor)")
    axes.grid(alpha=0.25)


def kinds_figure(
    schedules: Sequence[Schedule], channels: Sequence[Channel], *, num_phases: int, key: jax.Array | None
) -> Figure:
    """Schedules of many channels: one panel per kind of channel, every channel of that kind
    (of every schedule) a line of its per-phase steps, labelled `schedule: channel` (the
    channel alone for one schedule); past LEGEND_INSIDE lines the panel's title counts them
    instead of a legend (one of hundreds of entries would be taller than any plot)."""
    kinds = list(dict.fromkeys(channel.kind for channel in channels))
    figure = Figure(figsize=(7.0, 1.0 + 2.8 * len(kinds)), layout="constrained")
    panels = figure.subplots(len(kinds), 1, sharex=True, squeeze=False)[:, 0]
    phase_starts = np.arange(num_phases + 1) / num_phases * 100
    for axes, kind in zip(panels, kinds, strict=True):
        series = [
            (schedule, channel) for schedule in schedules for channel in schedule.channels if channel.kind == kind
        ]
        styles = series_styles(len(series))
        values = {schedule.name: np.asarray(schedule.phase_values(num_phases, key)) for schedule in schedules}
        for (schedule, channel), style in zip(series, styles, strict=True):
            steps = values[schedule.name][:, schedule.channels.index(channel)]
            label = legend_label(channel.name if len(schedules) == 1 else f"{schedule.name}: {channel.name}")
            axes.step(phase_starts, np.append(steps, steps[-1]), where="post", lw=1.2, label=label, **style)
        axes.axhline(1.0, color="0.7", lw=0.6, zorder=0)
        axes.set_xlim(0, 100)
        axes.set_ylabel(f"{kind} (factor)")
        axes.grid(alpha=0.25)
        if len(series) <= LEGEND_INSIDE:
            axes.legend(fontsize=7, frameon=False)
        else:
            axes.set_title(f"{len(series)} {kind} channels", fontsize=9)
    panels[-1].set_xlabel("training progress (%)")
    figure.suptitle(f"Developmental schedules ({num_phases} phases, {len(channels)} channels)")
    return figure


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


# ---------------------------------------------------------------------------- a run's figures
def metrics_figure(run: RunRecord, title: str) -> Figure:
    """Max fitness, coverage and QD score over training evaluations, with the body beside
    them (alpha, and every other scheduled channel's factor); a dashed line where the body
    becomes the final one for good."""
    rows = run.rows
    figure = Figure(figsize=(11, 3.4), layout="constrained")
    axes = figure.subplots(1, len(SCORES) + 1)
    evaluations = np.asarray([r["evaluations"] for r in rows], dtype=float)
    for ax, name in zip(axes[: len(SCORES)], SCORES, strict=True):
        ax.plot(evaluations, np.asarray([r[name] for r in rows], dtype=float), lw=1.4)
        ax.set_ylabel(METRICS_SCHEMA[name].axis_label)
    body = scheduled_columns(run.channels)  # one line per scheduled channel's column
    for column in body:
        values = np.asarray([r[column] for r in rows], dtype=float)
        axes[-1].plot(evaluations, values, lw=1.4, drawstyle="steps-post", label=column)
    axes[-1].set_ylabel(METRICS_SCHEMA[ALPHA].axis_label if body == (ALPHA,) else "factor")
    if 1 < len(body) <= LEGEND_INSIDE:
        axes[-1].legend(fontsize=7)
    elif len(body) > LEGEND_INSIDE:  # a legend of every channel would not fit beside the scores
        axes[-1].set_title(f"{len(body)} channels", fontsize=9)
    final_from = run.final_body_evaluations()
    for ax in axes:
        if final_from is not None and 0 < final_from:
            ax.axvline(final_from, color="0.3", ls="--", lw=1.0)
        ax.set_xlabel("evaluations")
        ax.grid(alpha=0.25)
    figure.suptitle(title)
    return figure


def _fitness_image(
    ax: Any, image: np.ndarray, low: Sequence[float], high: Sequence[float], vmin: Any, vmax: Any
) -> Any:
    """An image of fitness over the first two descriptors' box (NaN: nothing there)."""
    extent = (low[0], high[0], low[1], high[1])
    return ax.imshow(image, origin="lower", extent=extent, aspect="auto", cmap="viridis", vmin=vmin, vmax=vmax)


def archive_view(dimensions: int) -> str:
    """What an archive map shows of a D-descriptor archive, for titles ("" for 2-D)."""
    if dimensions == 1:
        return "fitness along the descriptor"
    if dimensions > 2:
        return f"descriptors 1-2 of {dimensions}, best per bin"
    return ""


def draw_archive(
    ax: Any,
    centroids: np.ndarray,
    fitnesses: np.ndarray,
    low: Sequence[float],
    high: Sequence[float],
    *,
    pixels: int = 400,
    vmin: float | None = None,
    vmax: float | None = None,
) -> Any:
    """Draw an archive on ax, coloured by its elites' fitnesses; returns what a colorbar takes.

    2 descriptors: each CVT cell (its Voronoi region, rasterised by nearest centroid), empty
    ones blank with a grey dot. 1: each cell's elite's fitness over the cell's interval of the
    descriptor, empty cells as grey ticks along the bottom. More: the projection on the first
    two descriptors, binned, each bin coloured by the best elite whose centroid falls in it
    (`archive_view` says so for titles).
    """
    centroids = np.asarray(centroids, dtype=float).reshape(len(np.asarray(fitnesses).reshape(-1)), -1)
    fitnesses = np.asarray(fitnesses, dtype=float).reshape(-1)
    if centroids.shape[1] == 1:
        return _draw_archive_1d(ax, centroids[:, 0], fitnesses, low[0], high[0], vmin=vmin, vmax=vmax)
    if centroids.shape[1] > 2:
        return _draw_archive_projected(ax, centroids[:, :2], fitnesses, low, high, vmin=vmin, vmax=vmax)
    from scipy.spatial import cKDTree

    xs = np.linspace(low[0], high[0], pixels)
    ys = np.linspace(low[1], high[1], pixels)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    _, cell = cKDTree(centroids).query(grid)
    image = np.where(fitnesses[cell] > -np.inf, fitnesses[cell], np.nan).reshape(pixels, pixels)
    shown = _fitness_image(ax, image, low, high, vmin, vmax)
    filled = fitnesses > -np.inf
    ax.scatter(*centroids[~filled].T, s=2, color="0.75", label="empty cell")
    ax.set_xlabel("descriptor 1")
    ax.set_ylabel("descriptor 2")
    return shown


def _draw_archive_1d(
    ax: Any,
    centroids: np.ndarray,
    fitnesses: np.ndarray,
    low: float,
    high: float,
    *,
    vmin: float | None,
    vmax: float | None,
) -> Any:
    """A 1-D archive: a segment per filled cell (its interval, at its elite's fitness)."""
    order = np.argsort(centroids)
    centres, values = centroids[order], fitnesses[order]
    edges = np.concatenate([[low], (centres[1:] + centres[:-1]) / 2, [high]])
    filled = values > -np.inf
    finite = values[filled]
    norm = matplotlib.colors.Normalize(
        vmin=vmin if vmin is not None else (finite.min() if finite.size else None),
        vmax=vmax if vmax is not None else (finite.max() if finite.size else None),
    )
    shown = ax.scatter(centres[filled], finite, c=finite, cmap="viridis", norm=norm, s=6, zorder=3)
    colours = matplotlib.colormaps["viridis"](norm(finite)) if finite.size else "C0"
    ax.hlines(finite, edges[:-1][filled], edges[1:][filled], colors=colours, lw=2)
    ax.plot(
        centres[~filled],
        np.zeros((~filled).sum()),
        "|",
        color="0.6",
        markersize=6,
        transform=ax.get_xaxis_transform(),
        label="empty cell",
    )
    ax.set_xlim(low, high)
    if vmin is not None and vmax is not None and vmax > vmin:  # a shared scale: panels side by side compare
        ax.set_ylim(vmin - 0.05 * (vmax - vmin), vmax + 0.05 * (vmax - vmin))
    ax.set_xlabel("descriptor")
    ax.set_ylabel("fitness")
    ax.grid(alpha=0.25)
    return shown


def _draw_archive_projected(
    ax: Any,
    centroids: np.ndarray,
    fitnesses: np.ndarray,
    low: Sequence[float],
    high: Sequence[float],
    *,
    vmin: float | None,
    vmax: float | None,
) -> Any:
    """An archive of more than 2 descriptors on its first two: a grid of bins (about four
    cells each), each coloured by the best elite whose centroid projects into it."""
    bins = int(np.clip(round(np.sqrt(len(fitnesses) / 4)), 4, 50))
    span = np.asarray(high[:2], dtype=float) - np.asarray(low[:2], dtype=float)
    index = np.clip(((centroids - np.asarray(low[:2])) / span * bins).astype(int), 0, bins - 1)
    best = np.full((bins, bins), -np.inf)
    np.maximum.at(best, (index[:, 1], index[:, 0]), fitnesses)
    image = np.where(best > -np.inf, best, np.nan)
    shown = _fitness_image(ax, image, low, high, vmin, vmax)
    occupied = np.zeros((bins, bins), dtype=bool)
    occupied[index[:, 1], index[:, 0]] = True
    row, column = np.nonzero(occupied & np.isnan(image))  # bins with cells, none filled
    centre = (np.stack([column, row], axis=-1) + 0.5) / bins * span + np.asarray(low[:2])
    ax.scatter(*centre.T, s=4, color="0.75", label="empty cells only")
    ax.set_xlabel("descriptor 1")
    ax.set_ylabel("descriptor 2")
    return shown


def archive_figure(
    fitnesses: np.ndarray,
    centroids: np.ndarray,
    low: Sequence[float],
    high: Sequence[float],
    title: str,
    *,
    pixels: int = 400,
) -> Figure:
    """An archive as a map coloured by fitness (see `draw_archive` for 1 or more than 2
    descriptors), with its coverage."""
    figure = Figure(figsize=(5.6, 4.8), layout="constrained")
    ax = figure.add_subplot()
    fitnesses = np.asarray(fitnesses).reshape(-1)
    shown = draw_archive(ax, centroids, fitnesses, low, high, pixels=pixels)
    figure.colorbar(shown, ax=ax, label="fitness")
    coverage = 100 * (fitnesses > -np.inf).mean()
    view = archive_view(len(low))
    ax.set_title(f"{title}\ncoverage {coverage:.1f}%" + (f" ({view})" if view else ""), fontsize=10)
    return figure


def save_run_figures(directory: str | Path) -> list[Path]:
    """A finished run directory's metrics.png and, for a task with descriptors, archive.png,
    drawn from its files (`read_run`: metrics.csv, certificate.json, archive.npz), each
    written atomically (a process killed meanwhile leaves no half-written image). Returns the
    files written; a RunDirectoryError for a directory that cannot be read or a run that has
    not finished."""
    directory = Path(directory)
    run = read_run(directory)
    if not run.finished:
        raise RunDirectoryError(
            f"{directory}: the run has not finished (generation {run.final['generation']} of "
            f"{run.config.generations}); its figures are drawn once it has"
        )
    title = f"{run.task} - {legend_label(run.schedule)} - seed {run.seed}"
    written = [save_figure(metrics_figure(run, title), directory / METRICS_FIGURE, dpi=120)]
    low, high = descriptor_bounds(run.task)
    if len(low) >= 1:
        archive = run.final_archive()
        figure = archive_figure(archive.fitnesses, archive.centroids, low, high, title)
        written.append(save_figure(figure, directory / ARCHIVE_FIGURE, dpi=120))
    return written


# ---------------------------------------------------------------------------- the report's figures
ARCHIVE_COLUMNS = 4
"""Final archives per row of `archives_figure`."""


def results_figure(groups: Mapping[str, Sequence[RunRecord]], names: Sequence[str], title: str) -> Figure:
    """Median (line) and interquartile range (band) over seeds of max fitness, coverage
    and QD score against training evaluations, one colour per schedule (and, past 20, dash
    patterns; past 10 schedules the legend goes below the plots); a dashed line from where
    every schedule shown has its final body for good (alpha = 1, for plain gear)."""
    figure = Figure(figsize=(13, 3.8), layout="constrained")
    axes = figure.subplots(1, len(SCORES))
    styles = schedule_styles(names)
    # where every schedule shown has its final body for good (the paper's fair-comparison line)
    final_from = max((x for name in names if (x := groups[name][0].final_body_evaluations()) is not None), default=None)
    for ax, metric in zip(axes, SCORES, strict=True):
        for name, style in zip(names, styles, strict=True):
            runs = groups[name]
            evaluations = runs[0].curve(metric)[0]
            values = np.stack([run.curve(metric)[1] for run in runs])
            values[~np.isfinite(values)] = np.nan  # max fitness of an archive emptied by extinction
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a moment when every archive is empty
                low, median, high = np.nanpercentile(values, [25, 50, 75], axis=0)
            ax.plot(evaluations, median, lw=1.5, label=legend_label(f"{name} ({len(runs)})"), **style)
            ax.fill_between(evaluations, low, high, color=style["color"], alpha=0.2, lw=0)
        if final_from is not None:
            ax.axvline(final_from, color="0.3", ls="--", lw=1.0)
        ax.set_xlabel("evaluations")
        ax.set_ylabel(METRICS_SCHEMA[metric].axis_label)
        ax.grid(alpha=0.25)
    place_legend(figure, axes[0], title="schedule (runs)", title_fontsize=8)
    figure.suptitle(title)
    return figure


def schedule_styles(names: Sequence[str]) -> list[dict[str, Any]]:
    """A line style per schedule: the paper's colours for the paper's schedules, matplotlib's
    next ones for others; past LEGEND_INSIDE schedules, `series_styles`' colours and dashes."""
    if len(names) > LEGEND_INSIDE:
        return series_styles(len(names))
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    return [{"color": COLORS.get(name, colors[(i + len(COLORS)) % len(colors)])} for i, name in enumerate(names)]


REEVALUATION_PANELS = (
    ("kept", "elites that kept their cell\n(% of the cells filled before)"),
    ("filled", "cells filled after\n(% of the cells filled before)"),
)


def reevaluation_shares(run: RunRecord) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """A run's phase boundaries (the phase each starts) and, at each, the elites that kept
    their cell and the cells filled after, in % of the cells filled before (NaN where none
    was); None for a run whose metrics.csv does not count them (written before they were)."""
    rows = [row for row in run.rows if row["event"] == "reevaluate"]
    if not rows or rows[0]["reevaluated"] is None:
        return None
    before = np.asarray([row["reevaluated"] for row in rows], dtype=float)
    before[before == 0] = np.nan
    kept = np.asarray([row["kept"] for row in rows], dtype=float)
    filled = kept + np.asarray([row["moved"] for row in rows], dtype=float)
    phases = np.asarray([row["phase"] for row in rows])
    return phases, {"kept": 100 * kept / before, "filled": 100 * filled / before}


def reevaluation_figure(groups: Mapping[str, Sequence[RunRecord]], title: str) -> Figure | None:
    """At every phase boundary, per schedule, the median and interquartile range over seeds
    of the elites that kept their own cell and of the cells filled after the re-evaluation,
    both in % of the cells filled before: how much of the archive a change of body keeps.
    None when no run counts its re-evaluations (or has none: a single phase)."""
    measured = {}
    for name, runs in groups.items():
        shares = [shares for run in runs if (shares := reevaluation_shares(run)) is not None]
        if shares:
            measured[name] = shares
    if not measured:
        return None
    figure = Figure(figsize=(11, 3.8), layout="constrained")
    axes = figure.subplots(1, len(REEVALUATION_PANELS))
    for ax, (key, label) in zip(axes, REEVALUATION_PANELS, strict=True):
        for (name, shares), style in zip(measured.items(), schedule_styles(list(measured)), strict=True):
            values = np.stack([values[key] for _, values in shares])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a boundary where every archive was empty
                low, median, high = np.nanpercentile(values, [25, 50, 75], axis=0)
            phases = shares[0][0]
            ax.plot(phases, median, lw=1.4, label=legend_label(f"{name} ({len(shares)})"), **style)
            ax.fill_between(phases, low, high, color=style["color"], alpha=0.2, lw=0)
        ax.set_xlabel("phase boundary (the phase it starts)")
        ax.set_ylabel(label)
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.25)
    place_legend(figure, axes[0], title="schedule (runs)", title_fontsize=8)
    figure.suptitle(title)
    return figure


def archives_figure(
    panels: Sequence[tuple[str, int, FinalArchive]], low: Sequence[float], high: Sequence[float], title: str
) -> Figure:
    """Final archives side by side, in rows of up to ARCHIVE_COLUMNS, on one colour scale:
    one panel per (schedule name, seed, archive), titled with the name, seed and coverage
    (for 1 or more than 2 descriptors, the title says what the maps show)."""
    filled = np.concatenate([archive.fitnesses[archive.filled] for _, _, archive in panels])
    vmin, vmax = (float(filled.min()), float(filled.max())) if filled.size else (None, None)
    columns = min(len(panels), ARCHIVE_COLUMNS)
    rows = math.ceil(len(panels) / columns)
    figure = Figure(figsize=(3.6 * columns + 1.0, 3.6 * rows + 0.4), layout="constrained")
    axes = np.atleast_1d(figure.subplots(rows, columns)).reshape(-1)
    shown = None
    for ax, (name, seed, archive) in zip(axes, panels, strict=False):
        shown = draw_archive(ax, archive.centroids, archive.fitnesses, low, high, pixels=300, vmin=vmin, vmax=vmax)
        coverage = 100 * archive.filled.mean()
        ax.set_title(f"{legend_label(name)}, seed {seed}\ncoverage {coverage:.1f}%", fontsize=9)
    for ax in axes[len(panels) :]:
        ax.set_axis_off()
    if shown is not None:
        figure.colorbar(shown, ax=list(axes[: len(panels)]), label="fitness", shrink=min(1.0, 2.5 / rows))
    view = archive_view(len(low))
    figure.suptitle(f"{title} ({view})" if view else title)
    return figure
