"""A run's figures: metrics.png (max fitness, coverage and QD score over training, beside
the body's scheduled channels) and archive.png (the final archive's map), drawn from a
finished run directory's files by `save_run_figures`, which the CLI calls after `run` and
`sweep` have trained.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from smol_dsl.results.archive_maps import archive_figure
from smol_dsl.results.figures import LEGEND_INSIDE, legend_label, save_figure
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
from smol_dsl.tasks import descriptor_bounds

if TYPE_CHECKING:
    from smol_dsl.rundir import RunRecord


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
