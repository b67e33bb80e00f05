"""Schedule figures: every scheduled channel of one or more schedules over training, its
per-phase steps and smooth curve (`schedule_figure`; the paper's Figure 2 for plain gear,
`smol-dsl plot`), or, for schedules of many channels, one panel per kind of channel
(`kinds_figure`); a paced schedule with its envelope, and runs' bodies as they trained
(`Trajectory`). JAX is imported only when drawing, to evaluate the schedules.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.figure import Figure

from smol_dsl.language.channels import GEAR
from smol_dsl.language.pacing_certificate import envelope
from smol_dsl.results.figures import LEGEND_INSIDE, legend_label, place_legend, series_styles

if TYPE_CHECKING:
    import jax

    from smol_dsl.language.channels import Channel
    from smol_dsl.language.schedule import Schedule

PAPER_FIGURE = ("vanilla", "smol", "smol-reverse", "human")
"""The schedules of the paper's Figure 2, in its order."""
CHANNEL_PANELS = 6
"""Up to this many channels a schedule figure gives each its own panel; past it, one panel
per kind of channel (gear, mass, ...), each channel a line of steps."""


@dataclass(frozen=True)
class Trajectory:
    """The body a run trained in at every phase (`RunRecord.phase_bodies`), to draw beside
    the schedules: its label, its schedule's channels and the (phases, channels) bodies."""

    label: str
    channels: tuple[Channel, ...]
    bodies: np.ndarray


def schedule_figure(
    schedules: Sequence[Schedule],
    *,
    num_phases: int = 100,
    key: jax.Array | None = None,
    smooth_points: int = 1001,
    trajectories: Sequence[Trajectory] = (),
) -> Figure:
    """Draw each channel per phase (steps) and its smooth curve, the schedules overlaid; a
    paced schedule's channel also with its envelope (the band of values it can have in each
    phase whatever the run's metrics, and its latest trajectory, dotted), and each of
    `trajectories` (the bodies runs trained in) as a line of steps of its own.

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
    channels += [c for run in trajectories for c in run.channels if c not in channels]
    if len(channels) > CHANNEL_PANELS:
        return kinds_figure(schedules, channels, num_phases=num_phases, key=key)
    figure = Figure(figsize=(7.0, 4.2 if len(channels) == 1 else 1.0 + 2.5 * len(channels)), layout="constrained")
    panels = figure.subplots(len(channels), 1, sharex=True, squeeze=False)[:, 0]
    styles = series_styles(len(schedules) + len(trajectories))
    for axes, channel in zip(panels, channels, strict=True):
        _draw_channel(
            axes,
            schedules,
            channel,
            styles[: len(schedules)],
            num_phases=num_phases,
            key=key,
            smooth_points=smooth_points,
        )
        _draw_trajectories(axes, trajectories, channel, styles[len(schedules) :], num_phases)
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
        clock = schedule.clock_of(channel)
        if clock is not None:  # paced: every value a run can have in each phase, and the slowest run's
            assert schedule.pacing is not None
            rows = envelope(schedule.pacing.clocks[clock], steps, schedule.tail_phase(num_phases))
            least, most = (np.append(values, values[-1]) for values in np.asarray([r[2:] for r in rows]).T)
            axes.fill_between(phase_starts, least, most, step="post", color=style["color"], alpha=0.15, lw=0)
            latest = np.asarray([steps[low] for low, *_ in rows])
            axes.step(phase_starts, np.append(latest, latest[-1]), where="post", lw=1.0, ls=":", color=style["color"])
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


def _draw_trajectories(
    axes: Any, trajectories: Sequence[Trajectory], channel: Channel, styles: Sequence[dict[str, Any]], num_phases: int
) -> None:
    """Each run's body in this channel per phase (1 where its schedule does not declare it)."""
    for run, style in zip(trajectories, styles, strict=True):
        phases = len(run.bodies)
        values = run.bodies[:, run.channels.index(channel)] if channel in run.channels else np.ones(phases)
        starts = np.arange(phases + 1) / phases * 100
        axes.step(starts, np.append(values, values[-1]), where="post", lw=2.6, label=legend_label(run.label), **style)


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
