"""What `smol-dsl check` says of a paced schedule, for every metric history: each clock's
condition and bound, the development steps a phase can be at, the largest jump into the
final-body tail (`pacing_text`), and per phase of a number of phases the envelope of the
values a channel can have (`envelope_text`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.language.symbolic import percent

if TYPE_CHECKING:
    from smol_dsl.errors import Span
    from smol_dsl.language.pacing import Clock
    from smol_dsl.language.schedule import Schedule


def envelope(clock: Clock | None, phase_values: np.ndarray, tail_phase: int) -> list[tuple[int, int, float, float]]:
    """Per phase: the lowest and highest development step and the lowest and highest value
    the channel can have (`phase_values`: its open-loop values per phase), whatever the
    metrics do."""
    rows = []
    for phase in range(len(phase_values)):
        low = phase if clock is None or phase >= tail_phase else clock.slowest(phase)
        reachable = np.asarray(phase_values[low : phase + 1], dtype=float)
        rows.append((low, phase, float(reachable.min()), float(reachable.max())))
    return rows


def tail_jump(clock: Clock, phase_values: np.ndarray, tail_phase: int) -> float:
    """The largest change of the channel's value at `tail_phase` over every development
    step it can have reached by then (0 where it has no phase before the tail)."""
    if tail_phase <= 0 or tail_phase >= len(phase_values):
        return 0.0
    final = float(phase_values[tail_phase])
    low = clock.slowest(tail_phase - 1)
    return max(abs(final - float(value)) for value in phase_values[low:tail_phase])


# ---------------------------------------------------------------- what `check` prints


def pacing_text(schedule: Schedule) -> str:
    """What `check` says of a schedule's pacing, proven for every metric history: each
    clock's condition and bound, the development steps a phase can be at, and the largest
    jump into the tail (from the range the curve takes before it)."""
    assert schedule.pacing is not None
    lines = []
    for index, clock in enumerate(schedule.pacing.clocks):
        channels = [channel for channel in schedule.channels if schedule.clock_of(channel) == index]
        lines.append(
            f"pace ({', '.join(c.name for c in channels)}): moves on when "
            f"{span_text(schedule.source, clock.condition_span)}, within {clock.within} phases (line {clock.span.line})"
        )
        lines.append(
            f"  waits: a body is held 1 to {clock.within} phases; in phase p the body is the curve's of phase "
            f"floor(p/{clock.within}) to p"
        )
        for channel in channels:
            curve = schedule.curve(channel)
            certificate = curve.certificate
            before_tail = [piece for piece in certificate.pieces if piece.start < float(curve.tail_start)]
            low = min((piece.minimum for piece in before_tail), default=certificate.final)
            high = max((piece.maximum for piece in before_tail), default=certificate.final)
            jump = max(abs(certificate.final - low), abs(certificate.final - high))
            owner = "" if len(channels) == 1 else " of " + channel.name
            lines.append(
                f"  tail{owner}: {channel.quantity} == {certificate.final:g} from {percent(curve.tail_start)} "
                "whatever the metrics; where development has not finished, the rest of the curve is skipped: "
                f"a jump of at most {jump:.4g} (from [{low:.4g}, {high:.4g}]): proven"
            )
    return "\n".join(lines)


def envelope_text(schedule: Schedule, num_phases: int) -> str:
    """Per phase of `num_phases`, each paced channel's lowest and highest development step
    and its value at each (the latest and earliest trajectories), the range between, and
    the largest jump into the tail, whatever the metrics do."""
    assert schedule.pacing is not None
    values = np.asarray(schedule.phase_values(num_phases))
    tail_phase = schedule.tail_phase(num_phases)
    lines = [f"envelope over {num_phases} phases (tail from phase {tail_phase}):"]
    for column, channel in enumerate(schedule.channels):
        index = schedule.clock_of(channel)
        if index is None:
            continue
        clock = schedule.pacing.clocks[index]
        lines.append(f"  {channel.name}: phase  step      {channel.quantity} latest .. earliest  (range)")
        for phase, (low, high, least, most) in enumerate(envelope(clock, values[:, column], tail_phase)):
            steps = f"{low}" if low == high else f"{low}..{high}"
            latest, earliest = float(values[low, column]), float(values[high, column])
            lines.append(f"    {phase:>5}  {steps:<8}  {latest:.4g} .. {earliest:.4g}  ({least:.4g} .. {most:.4g})")
        lines.append(f"    largest jump into the tail: {tail_jump(clock, values[:, column], tail_phase):.4g}")
    return "\n".join(lines)


def span_text(source: str, span: Span) -> str:
    """The text of `source` at `span` (within its line)."""
    lines = source.splitlines()
    line = lines[span.line - 1] if span.line - 1 < len(lines) else ""
    return line[span.column - 1 : span.column - 1 + span.length].strip()
