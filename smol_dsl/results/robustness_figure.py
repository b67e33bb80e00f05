"""The figure of `smol-dsl robustness`'s measurements: what survives, median and IQR over
seeds per schedule, against the body factor for each perturbed channel (all of its families
on one axis), and for the other perturbations (the float path, other physics, other starts)
side by side (`robustness_figure`; `robustness_images` as robustness.png and .pdf). Imports
no JAX.
"""

from __future__ import annotations

import io
import warnings
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MaxNLocator

from smol_dsl.results.figures import legend_label, place_legend
from smol_dsl.results.report_figures import schedule_styles
from smol_dsl.results.robustness_tables import quartiles

if TYPE_CHECKING:
    from smol_dsl.results.robustness import Robustness

SURVIVAL_PANELS = (
    ("kept_share", "elites that kept their cell\n(% of the cells filled before)"),
    ("filled_share", "cells still filled\n(% of the cells filled before)"),
)


def robustness_figure(robustness: Robustness) -> Figure:
    """What survives, median (line or point) and IQR (band or bar) over seeds, one colour per
    schedule: per body channel, the elites that kept their cell and the cells still filled
    against the factor (every factor of its families); for the others (the float path, other
    physics, other starts), the same shares, averaged over each run's samples, side by side."""
    channels = robustness.channels
    others = [p for p in robustness.perturbations if not any(p in families for families in channels.values())]
    rows = len(channels) + (1 if others else 0)
    figure = Figure(figsize=(5.2 * len(SURVIVAL_PANELS), 3.4 * rows), layout="constrained")
    axes = np.asarray(figure.subplots(rows, len(SURVIVAL_PANELS), squeeze=False))
    styles = schedule_styles(robustness.schedules)
    for row_axes, channel in zip(axes, channels, strict=False):
        samples = robustness.channel_samples(channel)
        factors = np.asarray([row.factor for row in samples])
        for ax, (value, label) in zip(row_axes, SURVIVAL_PANELS, strict=True):
            for name, style in zip(robustness.schedules, styles, strict=True):
                values = np.stack([robustness.per_run(row.perturbation, row.sample, value)[name] for row in samples])
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    low, median, high = np.nanpercentile(values, [25, 50, 75], axis=1)
                shown = legend_label(f"{name} ({values.shape[1]})")
                ax.plot(factors, median, marker=".", lw=1.5, label=shown, **style)
                ax.fill_between(factors, low, high, color=style["color"], alpha=0.2, lw=0)
            ax.axvline(1.0, color="0.5", ls=":", lw=1.0)
            ax.xaxis.set_major_locator(MaxNLocator(6))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
            ax.set_xlabel(f"{channel} factor (times the final body's)")
            ax.set_ylabel(label)
    if others:
        width = 0.8 / max(1, len(robustness.schedules))
        for ax, (value, label) in zip(axes[-1], SURVIVAL_PANELS, strict=True):
            for number, (name, style) in enumerate(zip(robustness.schedules, styles, strict=True)):
                for place, perturbation in enumerate(others):
                    runs = robustness.mean_over_samples(perturbation, value)[name]
                    low, median, high = quartiles(np.asarray(list(runs.values()), dtype=float))
                    x = place - 0.4 + width * (number + 0.5)
                    ax.bar(x, median, width * 0.9, color=style["color"], alpha=0.6, label=None if place else name)
                    ax.errorbar([x], [median], yerr=[[median - low], [high - median]], color="0.2", capsize=2, lw=1)
            ax.set_xticks(range(len(others)), [f"{p} (final body)" for p in others])
            ax.set_ylabel(label)
    for ax in axes.flat:
        ax.set_ylim(0, 105)
        ax.grid(alpha=0.25)
    place_legend(figure, axes[0][0], title="schedule (runs)" if channels else "schedule", title_fontsize=8)
    figure.suptitle(f"{robustness.task}: what survives a change (median and IQR over seeds)")
    return figure


def robustness_images(robustness: Robustness) -> dict[str, bytes]:
    """The figure as robustness.png and robustness.pdf, by name."""
    figure = robustness_figure(robustness)
    files = {}
    for suffix in ("png", "pdf"):
        image = io.BytesIO()
        figure.savefig(image, format=suffix, dpi=130)
        files[f"robustness.{suffix}"] = image.getvalue()
    return files
