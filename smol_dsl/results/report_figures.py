"""The report's figures, across runs grouped by schedule: the scores' median and
interquartile range over seeds against training evaluations (`results_figure`), how much of
the archive each change of body keeps (`reevaluation_figure`), the bodies runs trained in
where some run is paced (`bodies_figure`), and final archives side by
side on one colour scale (`archives_figure`); each schedule in its paper colour
(`schedule_styles`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import matplotlib
import numpy as np
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from smol_dsl.results.archive_maps import archive_view, draw_archive
from smol_dsl.results.conditions import COLORS
from smol_dsl.results.figures import LEGEND_INSIDE, legend_label, place_legend, series_styles
from smol_dsl.rundir import METRICS_SCHEMA, SCORES

if TYPE_CHECKING:
    from smol_dsl.rundir import FinalArchive, RunRecord

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
    taken = {to_hex(COLORS[name]) for name in names if name in COLORS}
    cycle = [to_hex(color) for color in matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]]
    free = iter([color for color in cycle if color not in taken] * len(names))  # never a paper colour shown
    return [{"color": COLORS[name] if name in COLORS else next(free)} for name in names]


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
    phases = np.arange(1, run.config.num_phases)  # every boundary; a paced run's held ones are NaN
    before, kept, filled = (np.full(len(phases), np.nan) for _ in range(3))
    for row in rows:
        at = row["phase"] - 1
        before[at] = row["reevaluated"] or np.nan
        kept[at], filled[at] = row["kept"], row["kept"] + row["moved"]
    return phases, {"kept": 100 * kept / before, "filled": 100 * filled / before}


def bodies_figure(groups: Mapping[str, Sequence[RunRecord]], title: str) -> Figure | None:
    """The body each run trained in at every phase, one panel per scheduled factor (alpha,
    mass, ...): per schedule every run's (thin) and the median and interquartile range over
    seeds, so that a paced schedule's realised curves show beside the others' fixed ones.
    None when no run is paced (every run's body is then its schedule's curve)."""
    if not any(run.paced for runs in groups.values() for run in runs):
        return None
    columns = list(dict.fromkeys(name for runs in groups.values() for run in runs for name in run.body_columns))
    figure = Figure(figsize=(max(7.0, 4.2 * len(columns) + 1), 3.6), layout="constrained")
    axes = np.atleast_1d(figure.subplots(1, len(columns)))
    for ax, column in zip(axes, columns, strict=True):
        for (name, runs), style in zip(groups.items(), schedule_styles(list(groups)), strict=True):
            curves = np.stack([run.phase_column(column) for run in runs])
            phases = np.arange(curves.shape[1])
            for curve in curves:
                ax.step(phases, curve, where="post", color=style["color"], lw=0.6, alpha=0.35)
            low, median, high = np.percentile(curves, [25, 50, 75], axis=0)
            ax.step(phases, median, where="post", lw=1.6, label=legend_label(f"{name} ({len(runs)})"), **style)
            ax.fill_between(phases, low, high, step="post", color=style["color"], alpha=0.2, lw=0)
        ax.set_xlabel("phase")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel(METRICS_SCHEMA[column].label if column in METRICS_SCHEMA.names else column)
        ax.grid(alpha=0.25)
    place_legend(figure, axes[0], title="schedule (runs)", title_fontsize=8)
    figure.suptitle(title)
    return figure


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
            # markers: a paced schedule's boundaries where its runs held are gaps (NaN)
            ax.plot(phases, median, lw=1.4, marker="o", ms=2.5, label=legend_label(f"{name} ({len(shares)})"), **style)
            ax.fill_between(phases, low, high, color=style["color"], alpha=0.2, lw=0)
        ax.set_xlabel("phase boundary (the phase it starts)")
        ax.set_ylabel(label)
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.25)
    place_legend(figure, axes[0], title="schedule (runs)", title_fontsize=8)
    figure.suptitle(title)
    return figure


def archives_figure(
    panels: Sequence[tuple[str, int, FinalArchive]],
    low: Sequence[float],
    high: Sequence[float],
    title: str,
    *,
    scale: tuple[float, float] | None = None,
    pixels: int = 300,
) -> Figure:
    """Final archives side by side, in rows of up to ARCHIVE_COLUMNS, on one colour scale
    (`scale`, or the panels' own fitnesses): one panel per (schedule name, seed, archive),
    titled with the name, seed and coverage (for 1 or more than 2 descriptors, the title
    says what the maps show)."""
    filled = np.concatenate([archive.fitnesses[archive.filled] for _, _, archive in panels])
    vmin, vmax = (float(filled.min()), float(filled.max())) if filled.size else (None, None)
    if scale is not None:
        vmin, vmax = scale
    columns = min(len(panels), ARCHIVE_COLUMNS)
    rows = math.ceil(len(panels) / columns)
    figure = Figure(figsize=(3.6 * columns + 1.0, 3.6 * rows + 0.4), layout="constrained")
    axes = np.atleast_1d(figure.subplots(rows, columns)).reshape(-1)
    shown = None
    for ax, (name, seed, archive) in zip(axes, panels, strict=False):
        shown = draw_archive(ax, archive.centroids, archive.fitnesses, low, high, pixels=pixels, vmin=vmin, vmax=vmax)
        coverage = 100 * archive.filled.mean()
        ax.set_title(f"{legend_label(name)}, seed {seed}\ncoverage {coverage:.1f}%", fontsize=9)
    for ax in axes[len(panels) :]:
        ax.set_axis_off()
    if shown is not None:
        figure.colorbar(shown, ax=list(axes[: len(panels)]), label="fitness", shrink=min(1.0, 2.5 / rows))
    view = archive_view(len(low))
    figure.suptitle(f"{title} ({view})" if view else title)
    return figure
