"""A schedule's channel targets checked against a task's body: every actuator and link a
`channel gear[...]` or `channel mass[...]` line names is one the task has."""

from __future__ import annotations

import difflib
from collections.abc import Collection, Mapping, Sequence
from typing import TYPE_CHECKING

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language.channels import CHANNEL_KINDS

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule


def check_targets(
    schedule: Schedule,
    targets: Mapping[str, Collection[str]] | None,
    task: str,
    listing: Mapping[str, str] | None = None,
) -> None:
    """`Schedule.check_targets`: a located ScheduleError for a target the task's body lacks."""

    for channel in schedule.channels:
        if not channel.targets:
            continue
        place = schedule.curve(channel).place
        assert place is not None, "a channel with targets has a `channel` line"
        part = CHANNEL_KINDS[channel.kind].part or "parts"
        if targets is None:
            raise ScheduleError(
                f"task {task} does not list its {part}, so `{channel.name}` cannot name them",
                span=_joined(place.target_spans),
                hint=f"write `channel {channel.kind}` to scale all of them, or use a task that lists its body",
                source=schedule.source,
                path=schedule.path,
            )
        known = list(targets.get(part, ()))
        unknown = [target for target in place.written if target not in known]
        if not unknown:
            continue
        target = unknown[0]
        close = _closest(target, known)
        what = (listing or {}).get(part, f"{part}: {', '.join(known)}")
        other = next((p for p, names in targets.items() if p != part and target in names), None)
        elsewhere = f"`{target}` is one of {task}'s {other}, and {channel.kind}[...] names {part}; " * bool(other)
        raise ScheduleError(
            f"task {task} has no {part} named `{target}`",
            span=place.target_spans[place.written.index(target)],
            hint=elsewhere + (f"did you mean `{close}`? " if close else "") + f"{task}'s {what}",
            source=schedule.source,
            path=schedule.path,
        )


def _closest(target: str, known: Sequence[str]) -> str | None:
    """The known name a mistyped target most likely means: the longest one it starts with
    (`thigh` for `thigh_joint`), else the shortest one that starts with it (`thigh_joint`
    for `thigh`), else the closest spelling."""
    shorter = [name for name in known if target.startswith(name)]
    if shorter:
        return max(shorter, key=len)
    longer = [name for name in known if name.startswith(target)]
    if longer:
        return min(longer, key=len)
    close = difflib.get_close_matches(target, list(known), n=1)
    return close[0] if close else None


def _joined(spans: Sequence[Span]) -> Span:
    """One span from the first to the last of spans on one line."""
    first, last = spans[0], spans[-1]
    if first.line != last.line:
        return first
    return Span(first.line, first.column, last.column + last.length - first.column)
