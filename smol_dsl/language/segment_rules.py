"""Steps 6 to 9 of verification (docs/language.md section 6): each segment's proven range
held against the language's rules and against what the file declares.

`smol_dsl.language.verify` proves each piece's extrema, monotonicity and float32 error;
here a segment's pieces, taken together, must stay above 0 and within float32's safe range,
within the channel's declared `bounds`, and go the way a segment declared `increasing` or
`decreasing` goes. Each failure is a located ScheduleError whose message says whether an
extremum was reached or is only an interval-arithmetic bound.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language.channels import CHANNEL_KINDS
from smol_dsl.language.float32_limits import SAFE_MAX, SAFE_MIN
from smol_dsl.language.symbolic import SymbolicCurve, SymbolicSegment, number_text, percent

if TYPE_CHECKING:
    from smol_dsl.language.certificates import PieceCertificate

AT_ZERO = {
    "gear": "would switch them off or reverse them",
    "mass": "would make the links weightless, or of negative mass",
    "friction": "would make contacts frictionless, or push bodies along",
    "gravity": "would switch gravity off, or reverse it",
}
"""What a factor of 0 or less would do to each kind of channel, for the hint of the positivity rule."""


def _fail(message: str, span: Span, hint: str) -> ScheduleError:
    return ScheduleError(message, span=span, hint=hint)


@dataclass(frozen=True)
class SegmentRange:
    """A segment's proven range over its pieces, and how messages word it: an extremum that is
    only an interval-arithmetic bound is said to be one, not claimed to be reached."""

    low: float
    high: float
    error: float
    """The largest float32 error bound of its pieces."""
    goes_down: str
    reaches: str
    loose: str
    """What a hint adds where an extremum is only a bound."""

    @classmethod
    def of(cls, pieces: list[PieceCertificate]) -> SegmentRange:
        lowest = min(pieces, key=lambda p: p.minimum)
        highest = max(pieces, key=lambda p: p.maximum)
        loose = (
            ""
            if lowest.exact and highest.exact
            else (
                "; its exact extrema could not be found, and the interval-arithmetic bound is not tight enough: "
                "simplify the expression or split the segment"
            )
        )
        return cls(
            low=lowest.minimum,
            high=highest.maximum,
            error=max(p.float32_error for p in pieces),
            goes_down="goes down to" if lowest.exact else "could not be shown to stay above its bound of",
            reaches="reaches" if highest.exact else "could not be shown to stay below its bound of",
            loose=loose,
        )


def _scales(curve: SymbolicCurve) -> str:
    """What the channel's factor scales, for hints: `alpha scales the actuators' gear` for plain
    gear (the paper's name for it), else in the channel's own words."""
    if not curve.named:
        return "alpha scales the actuators' gear"
    return f"{curve.channel.name} scales {CHANNEL_KINDS[curve.channel.kind].scales}"


def above_zero(curve: SymbolicCurve, segment: SymbolicSegment, proven: SegmentRange) -> None:
    """6. The minimum is strictly positive."""
    if not proven.low > 0:
        raise _fail(
            f"{curve.quantity} must stay above 0, but {segment.describe()} {proven.goes_down} {proven.low:.6g}",
            segment.span,
            f"{_scales(curve)}; 0 or less {AT_ZERO[curve.channel.kind]}" + proven.loose,
        )


def finite_in_float32(curve: SymbolicCurve, segment: SymbolicSegment, proven: SegmentRange) -> None:
    """7. The value minus its float32 error stays positive, and its range lies within float32's
    safe range (each piece's error bound is its shape's `float32_error`)."""
    where, q, low, high, error = segment.describe(), curve.quantity, proven.low, proven.high, proven.error
    if not low - error > 0:
        raise _fail(
            f"{q} must stay above 0, but in float32 {where} may go down to {low - error:.3g} "
            f"(exactly it goes down to {low:.6g}, with rounding errors up to {error:.3g})",
            segment.span,
            "the expression loses too much precision in 32-bit floats: simplify it or rescale its parts",
        )
    if low < SAFE_MIN:
        raise _fail(
            f"{where} {proven.goes_down} {q} = {low:.3g}, too small for float32",
            segment.span,
            f"{_scales(curve)}; a value this small is 0 in 32-bit floats",
        )
    if high + error > SAFE_MAX:
        raise _fail(
            f"{where} {proven.reaches} {q} = {high:.3g}, beyond float32's safe range (2**120, about 1.3e36)",
            segment.span,
            f"use a modest {q}",
        )


def declared_bounds(curve: SymbolicCurve, segment: SymbolicSegment, proven: SegmentRange) -> None:
    """8. LO <= minimum and maximum <= HI, where the channel declares `bounds LO .. HI`."""
    if curve.bounds is None:
        return
    where, q, low, high = segment.describe(), curve.quantity, proven.low, proven.high
    lo, hi, _ = curve.bounds
    lo_f, hi_f = float(lo), float(hi)
    declared = f"`bounds {number_text(lo)} .. {number_text(hi)}`"
    if low < lo_f:
        raise _fail(
            f"{where} {proven.goes_down} {q} = {low:.6g}, {lo_f - low:.6g} below the declared bound {lo_f:.6g}",
            segment.span,
            f"raise the segment's values, or widen {declared}" + proven.loose,
        )
    if high > hi_f:
        raise _fail(
            f"{where} {proven.reaches} {q} = {high:.6g}, {high - hi_f:.6g} above the declared bound {hi_f:.6g}",
            segment.span,
            f"lower the segment's values, or widen {declared}" + proven.loose,
        )


def declared_monotonicity(
    curve: SymbolicCurve, segment: SymbolicSegment, pieces: list[PieceCertificate], proven: SegmentRange
) -> None:
    """9. Every piece of a segment declared `increasing` or `decreasing` is constant or goes that way."""
    if segment.monotone is None:
        return
    broken = [p for p in pieces if p.monotone not in {"constant", segment.monotone}]
    if not broken:
        return
    where = segment.describe()
    if all(p.monotone == "unknown" for p in broken):
        raise _fail(
            f"could not prove that {where} is {segment.monotone}",
            segment.span,
            "neither sympy nor interval arithmetic could decide the sign of the derivative; "
            f"simplify the expression, split the segment, or remove `{segment.monotone}`",
        )
    if any(p.monotone == "random" for p in broken):
        detail = "a random segment is not monotone"
    else:
        detail = (
            f"{curve.quantity} goes from {number_text(segment.value_at('start'))} at {percent(segment.start)} to "
            f"{number_text(segment.value_at('end'))} at {percent(segment.end)}, ranging over "
            f"{proven.low:.6g} .. {proven.high:.6g}"
        )
    raise _fail(
        f"{where} is declared {segment.monotone} but is not: {detail}",
        segment.span,
        f"fix the values, or remove `{segment.monotone}` if the shape is intended",
    )
