"""A run's figures: metrics over evaluations, and the final archive as a 2-D map."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from smol_dsl import Schedule
from smol_dsl.runner.config import RunConfig
from smol_dsl.tasks import Task

PANELS = (("max_fitness", "max fitness"), ("coverage", "coverage (%)"), ("qd_score", "QD score"))


def metrics_figure(rows: list[dict[str, Any]], config: RunConfig, schedule: Schedule, title: str) -> Any:
    """Max fitness, coverage and QD score over training evaluations, with alpha below;
    a dashed line where alpha becomes 1 for good."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from smol_dsl.runner.run import alpha_one_evaluations

    figure = Figure(figsize=(11, 3.4), layout="constrained")
    axes = figure.subplots(1, len(PANELS) + 1)
    evaluations = np.asarray([r["evaluations"] for r in rows], dtype=float)
    first_tail_phase = config.num_phases - schedule.tail_phases(config.num_phases)
    alpha_one = alpha_one_evaluations(rows, first_tail_phase)
    for ax, (name, label) in zip(axes, (*PANELS, ("alpha", "α")), strict=True):
        values = np.asarray([r[name] for r in rows], dtype=float)
        ax.plot(evaluations, values, lw=1.4, drawstyle="steps-post" if name == "alpha" else "default")
        if alpha_one is not None and 0 < alpha_one:
            ax.axvline(alpha_one, color="0.3", ls="--", lw=1.0)
        ax.set_xlabel("evaluations")
        ax.set_ylabel(label)
        ax.grid(alpha=0.25)
    figure.suptitle(title)
    return figure


def draw_archive(
    ax: Any,
    centroids: np.ndarray,
    fitnesses: np.ndarray,
    low: tuple[float, ...],
    high: tuple[float, ...],
    *,
    pixels: int = 400,
    vmin: float | None = None,
    vmax: float | None = None,
) -> Any:
    """Draw a 2-D archive on ax: each CVT cell (its Voronoi region, rasterised by nearest
    centroid) coloured by its elite's fitness; empty cells are left blank. Returns the image."""
    from scipy.spatial import cKDTree

    xs = np.linspace(low[0], high[0], pixels)
    ys = np.linspace(low[1], high[1], pixels)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    _, cell = cKDTree(np.asarray(centroids)).query(grid)
    fitnesses = np.asarray(fitnesses, dtype=float).reshape(-1)
    image = np.where(fitnesses[cell] > -np.inf, fitnesses[cell], np.nan).reshape(pixels, pixels)
    shown = ax.imshow(
        image,
        origin="lower",
        extent=(low[0], high[0], low[1], high[1]),
        aspect="auto",
        cmap="viridis",
        vmin=vmin,
        vmax=vmax,
    )
    filled = fitnesses > -np.inf
    ax.scatter(*np.asarray(centroids)[~filled].T, s=2, color="0.75", label="empty cell")
    ax.set_xlabel("descriptor 1")
    ax.set_ylabel("descriptor 2")
    return shown


def archive_figure(repertoire: Any, task: Task, title: str, *, pixels: int = 400) -> Any:
    """The final archive as a 2-D map, coloured by fitness, with its coverage."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=(5.6, 4.8), layout="constrained")
    ax = figure.add_subplot()
    fitnesses = np.asarray(repertoire.fitnesses).reshape(-1)
    shown = draw_archive(ax, repertoire.centroids, fitnesses, task.descriptor_low, task.descriptor_high, pixels=pixels)
    figure.colorbar(shown, ax=ax, label="fitness")
    coverage = 100 * (fitnesses > -np.inf).mean()
    ax.set_title(f"{title}\ncoverage {coverage:.1f}%", fontsize=10)
    return figure


def save_run_figures(
    directory: Path, rows: list[dict[str, Any]], repertoire: Any, task: Task, config: RunConfig, schedule: Schedule
) -> None:
    """metrics.png and archive.png in the run directory, each written atomically (a run
    killed meanwhile leaves no half-written image)."""
    from smol_dsl.plotting import legend_label, save_figure

    title = f"{task.name} - {legend_label(schedule.name)} - seed {config.seed}"
    save_figure(metrics_figure(rows, config, schedule, title), directory / "metrics.png", dpi=120)
    if task.descriptor_size == 2:
        save_figure(archive_figure(repertoire, task, title), directory / "archive.png", dpi=120)
