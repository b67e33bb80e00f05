"""The factors a task's physics can take, and the proof that a schedule keeps every part of
the body within them.

Factors of one kind multiply (`tasks.anatomy.resolve`), so a channel proven alone says
little about the body: `mass` and `mass[torso]` at 1e-30 each give the torso 1e-60, which
float32 holds as 0. `check_resolved_factors` bounds each actuator's gear factor and each
link's mass factor (and friction's and gravity's) by the product of the certified ranges of
the channels that reach it, and refuses, located, a schedule whose bound leaves the task's
`FactorRange` of that kind. The bound is sound (every factor is positive, so the product of
the channels' minima is at most the part's factor, and the product of their maxima at
least), if not always tight: channels at their extremes at different times are bounded as
if at the same time.

A task's ranges are measured, not guessed: `benchmarks/factor_ranges.py` rolls out random
policies under bodies scaled by powers of ten and finds, per kind, the factors at which
every rollout's fitness and descriptors stay finite; a task states a range inside that.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from smol_dsl.errors import ScheduleError
from smol_dsl.language.channels import CHANNEL_KINDS, Channel
from smol_dsl.language.float32_limits import SAFE_MAX, SAFE_MIN
from smol_dsl.tasks.anatomy import resolve, resolved_names

if TYPE_CHECKING:
    from smol_dsl.language.curve import Curve
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.tasks.anatomy import Anatomy


@dataclass(frozen=True)
class FactorRange:
    """The factors of one kind a task's physics takes: from `low` to `high`, and how that
    was found (for messages)."""

    low: float
    high: float
    found: str = "float32's safe range"

    def __post_init__(self) -> None:
        if not 0 < self.low <= 1 <= self.high < math.inf:
            raise ValueError(f"a factor range holds 1 and lies in (0, inf), not {self.low:g} .. {self.high:g}")

    def __contains__(self, value: float) -> bool:
        return self.low <= value <= self.high


FLOAT32_RANGE = FactorRange(SAFE_MIN, SAFE_MAX)
"""Where a task states no range for a kind: what float32 holds with room to spare."""


def factor_range(ranges: Mapping[str, FactorRange], kind: str) -> FactorRange:
    """A task's range for a kind of channel (float32's safe range where it states none)."""
    if kind not in CHANNEL_KINDS:
        raise ValueError(f"{kind!r} is not a channel kind; the kinds are {', '.join(CHANNEL_KINDS)}")
    return ranges.get(kind, FLOAT32_RANGE)


def reaching(anatomy: Anatomy | None, channels: Sequence[Channel], kind: str, index: int) -> list[Channel]:
    """The channels of `kind` whose factor multiplies part `index` of the kind's parts."""
    found = []
    for channel in channels:
        if channel.kind != kind:
            continue
        chosen = anatomy.indices(channel) if anatomy is not None else None
        if chosen is None or index in chosen:
            found.append(channel)
    return found


def body_problem(
    body: Mapping[Channel, float], anatomy: Anatomy | None, ranges: Mapping[str, FactorRange], task: str
) -> str | None:
    """What is wrong with a body (a factor per channel) for this task, in words, or None:
    a factor that is not a finite number above 0, or an actuator's, link's or the whole
    body's factor (the product of the channels that reach it) outside the task's range."""
    factors = {}
    for channel, value in body.items():
        try:
            factor = float(value)
        except (TypeError, ValueError):
            factor = math.nan
        if isinstance(value, bool) or not (math.isfinite(factor) and factor > 0):
            return f"{channel.name} {value!r} is not a factor: give a finite number above 0"
        factors[channel] = factor
    for kind, parts in resolve(anatomy, factors).items():
        allowed = factor_range(ranges, kind)
        for part, value in zip(resolved_names(anatomy, kind), parts, strict=True):
            if value in allowed:
                continue
            what = f"the {kind} factor" if part == kind else f"{part}'s {kind} factor"
            return (
                f"{what} would be {value:.3g}, {'above' if value > allowed.high else 'below'} what {task}'s physics "
                f"takes ({kind} factors from {allowed.low:g} to {allowed.high:g}, {allowed.found})"
            )
    return None


def check_resolved_factors(
    schedule: Schedule, anatomy: Anatomy | None, ranges: Mapping[str, FactorRange], task: str
) -> None:
    """Refuse, with a located ScheduleError, a schedule under which some actuator's, link's
    or the whole body's factor (the product of the channels that reach it) may leave the
    task's range for its kind. The targets must have been checked (`TaskSpec.check_schedule`)."""
    channels = schedule.channels
    lows = resolve(anatomy, {channel: schedule.curve(channel).certificate.minimum for channel in channels})
    highs = resolve(anatomy, {channel: schedule.curve(channel).certificate.maximum for channel in channels})
    for kind, parts in lows.items():
        allowed = factor_range(ranges, kind)
        for index, (part, low, high) in enumerate(zip(resolved_names(anatomy, kind), parts, highs[kind], strict=True)):
            if low in allowed and high in allowed:
                continue
            too_high = high not in allowed
            found = reaching(anatomy, channels, kind, index)
            _refuse(schedule, found, part, kind, task, allowed, high if too_high else low, too_high)


def _refuse(
    schedule: Schedule,
    found: list[Channel],
    part: str,
    kind: str,
    task: str,
    allowed: FactorRange,
    bound: float,
    too_high: bool,
) -> None:
    """The ScheduleError of a part whose factor may leave its range: located at the segment
    where the most extreme of its channels reaches its extreme."""
    curves = [schedule.curve(channel) for channel in found]

    def extreme(curve: Curve) -> float:
        value = curve.certificate.maximum if too_high else curve.certificate.minimum
        return abs(math.log(value)) if value > 0 else math.inf

    worst = max(curves, key=extreme)
    target = worst.certificate.maximum if too_high else worst.certificate.minimum
    piece = next(
        piece for piece in worst.certificate.pieces if (piece.maximum if too_high else piece.minimum) == target
    )
    segment = worst.segments[piece.segment - 1]
    whole = part == kind or not any(channel.targets for channel in found)  # the same for every part
    what = f"the {kind} factor" if whole else f"{part}'s {kind} factor"
    if len(found) > 1:
        terms = ", ".join(
            f"`{c.name}` ({c_curve.certificate.minimum:.3g} .. {c_curve.certificate.maximum:.3g})"
            for c, c_curve in zip(found, curves, strict=True)
        )
        product = f"the product of {terms}, "
    else:
        product = ""
    way = "up to" if too_high else "down to"
    raise ScheduleError(
        f"{what} may go {way} {bound:.3g} ({product}{'above' if too_high else 'below'} what {task}'s physics takes)",
        span=segment.span,
        hint=f"{task} takes {kind} factors from {allowed.low:g} to {allowed.high:g} ({allowed.found}); "
        f"keep {'every' if not whole else 'the'} {kind} factor within it"
        + ("; factors of one kind multiply" if len(found) > 1 else ""),
        source=schedule.source,
        path=schedule.path,
    )
