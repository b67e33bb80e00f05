"""Symbolic verification of a schedule and the certificate it produces.

Every check is done with exact sympy arithmetic over each piece's real interval: extrema
from critical points (`sympy.calculus.util.minimum`/`maximum`), monotonicity from the sign
of the derivative, reality from the domains of roots, logarithms and divisions. Where sympy
cannot find critical points, a rigorous enclosure by interval arithmetic is used instead
and the certificate says so (see `smol_dsl.language.prover`). Nothing is sampled. A shape
whose pieces' extrema follow from its parameters (a bell, a random range) proves them itself
(`Shape.prove`).

The certificate also covers the float32 program that evaluates alpha: each shape bounds its
error (`Shape.float32_error`); a formula's sub-expressions are proven to stay in float32's
range, with an error bound (`smol_dsl.language.float32`), and alpha minus that error stays
positive.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from itertools import pairwise
from typing import Any, Literal

import sympy as sp

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language.channels import CHANNEL_KINDS, GEAR, Channel
from smol_dsl.language.float32_limits import SAFE_MAX, SAFE_MIN
from smol_dsl.language.prover import (
    Extrema,
    Monotone,
    VerificationTimeoutError,
    domain_violation,
    extrema,
    is_zero,
    real,
    simplified,
    slope_sign,
)
from smol_dsl.language.symbolic import (
    Piece,
    SymbolicCurve,
    SymbolicProgram,
    SymbolicSegment,
    T,
    number_text,
    percent,
)

MIN_TAIL = sp.Rational(1, 10)
"""The last 10% of the run must be at alpha = 1, or each channel at its final value (the
paper's fair-comparison rule)."""

AT_ZERO = {
    "gear": "would switch them off or reverse them",
    "mass": "would make the links weightless, or of negative mass",
    "friction": "would make contacts frictionless, or push bodies along",
    "gravity": "would switch gravity off, or reverse it",
}
"""What a factor of 0 or less would do to each kind of channel, for the hint of the positivity rule."""


@dataclass(frozen=True)
class PieceCertificate:
    """What was proven about one smooth piece of alpha(t)."""

    segment: int
    kind: str
    start: float
    end: float
    minimum: float
    maximum: float
    monotone: Monotone
    exact: bool  # False when extrema come from an interval enclosure
    float32_error: float = 0.0  # |float32 alpha - exact alpha| <= this, everywhere on the piece


@dataclass(frozen=True)
class JoinCertificate:
    """Continuity where one segment meets the next."""

    position: float
    continuous: bool
    jump: float | None  # None for a random segment (its value there is a random draw)


@dataclass(frozen=True)
class Certificate:
    """The result of verifying one channel of a schedule: bounds, tail, joins, and each piece.

    `str` writes its values as `alpha` for plain gear (the paper's name), else by the
    channel's name: `tail: mass == 0.5 from 90% ...`.
    """

    minimum: float
    maximum: float
    tail_start: float
    joins: tuple[JoinCertificate, ...]
    pieces: tuple[PieceCertificate, ...]
    bounds: tuple[float, float] | None
    extinction: float
    float32_error: float = 0.0
    channel: Channel = GEAR
    final: float = 1.0
    """The channel's value over its tail."""

    @property
    def tail_fraction(self) -> float:
        return 1.0 - self.tail_start

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary of the certificate (the channel as its name)."""
        data = asdict(self)
        data["channel"] = self.channel.name
        return json.loads(json.dumps(data))

    def __str__(self) -> str:
        q = self.channel.quantity
        lines = [
            f"  {q} in [{self.minimum:.6g}, {self.maximum:.6g}]   {q} > 0: proven"
            + (f"   bounds {self.bounds[0]:.6g} .. {self.bounds[1]:.6g}: proven" if self.bounds else ""),
            f"  tail: {q} == {self.final:.6g} from {percent(self.tail_start)} to 100% "
            f"({percent(self.tail_fraction)} of the run, at least {percent(MIN_TAIL)} required): proven",
            "  pieces:",
        ]
        for p in self.pieces:
            extent = f"{percent(p.start)} .. {percent(p.end)}"
            note = "" if p.exact else "  (interval enclosure)"
            lines.append(
                f"    #{p.segment:<2} {extent:<16} {p.kind:<15} {q} {p.minimum:.6g} .. {p.maximum:.6g}"
                f"   {p.monotone}{note}"
            )
        if self.joins:
            words = []
            for j in self.joins:
                if j.jump is None:
                    words.append(f"{percent(j.position)} random")
                elif j.continuous:
                    words.append(f"{percent(j.position)} continuous")
                else:
                    words.append(f"{percent(j.position)} jump {j.jump:+.6g}")
            lines.append("  joins: " + ", ".join(words))
        lines.append(f"  extinction: {self.extinction:g}")
        lines.append(f"  float32: every value finite, {q} within {self.float32_error:.2g} of exact and > 0: proven")
        return "\n".join(lines)


def _fail(message: str, span: Span, hint: str) -> ScheduleError:
    return ScheduleError(message, span=span, hint=hint)


def verify(program: SymbolicProgram) -> dict[Channel, Certificate]:
    """Prove the language's rules for every channel of a compiled program, in declared order;
    raise ScheduleError on the first failure."""
    return {curve.channel: verify_curve(curve, program.extinction) for curve in program.curves}


def verify_curve(curve: SymbolicCurve, extinction: sp.Expr = sp.S.Zero) -> Certificate:
    """Prove the language's rules for one channel's curve, in the order of docs/language.md
    section 6; raise ScheduleError on the first failure."""
    _coverage(curve)  # 1
    pieces: list[PieceCertificate] = []
    for segment in curve.segments:
        own = [_piece(curve, segment, piece) for piece in segment.pieces]  # 2-5 on each piece
        proven = _SegmentRange.of(own)
        _above_zero(curve, segment, proven)  # 6
        _finite_in_float32(curve, segment, proven)  # 7
        _declared_bounds(curve, segment, proven)  # 8
        _declared_monotonicity(curve, segment, own, proven)  # 9
        pieces.extend(own)
    start_of_tail = tail_start(curve)  # 10
    joins = _joins(curve)  # 11
    _declared_continuity(curve, joins)  # 12
    bounds = None if curve.bounds is None else (float(curve.bounds[0]), float(curve.bounds[1]))
    return Certificate(
        minimum=min(p.minimum for p in pieces),
        maximum=max(p.maximum for p in pieces),
        tail_start=float(start_of_tail),
        joins=joins,
        pieces=tuple(pieces),
        bounds=bounds,
        extinction=float(extinction),
        float32_error=max(p.float32_error for p in pieces),
        channel=curve.channel,
        final=float(curve.final),
    )


# ---------------------------------------------------------------- 1. coverage


def _coverage(curve: SymbolicCurve) -> None:
    """The segments start at 0, end at 1, and meet without gaps or overlaps."""
    segments = curve.segments
    of = f" of {curve.channel.name}" if curve.named else ""
    inside = f" in {curve.channel.name}" if curve.named else ""
    first = segments[0]
    if first.start != 0:
        raise _fail(
            f"the segments{of} leave 0% .. {percent(first.start)} uncovered",
            first.span,
            f"start the first segment at 0%, or add a segment `0% .. {percent(first.start)}: ...`",
        )
    for before, after in pairwise(segments):
        if after.start > before.end:
            raise _fail(
                f"gap between {percent(before.end)} and {percent(after.start)}{inside}",
                after.span,
                f"segment {before.index + 1} (line {before.span.line}) ends at {percent(before.end)} "
                f"but segment {after.index + 1} starts at {percent(after.start)}; "
                f"start it at {percent(before.end)}",
            )
        if after.start < before.end:
            raise _fail(
                f"overlap between {percent(after.start)} and {percent(min(before.end, after.end))}{inside}",
                after.span,
                f"segment {before.index + 1} (line {before.span.line}) runs to {percent(before.end)} "
                f"but segment {after.index + 1} starts at {percent(after.start)}; "
                f"segments must be in order and must not overlap",
            )
    last = segments[-1]
    if last.end != 1:
        raise _fail(
            f"the segments{of} leave {percent(last.end)} .. 100% uncovered",
            last.span,
            f"end the last segment at 100%, or add `{percent(last.end)} .. 100%: tail`",
        )


# ---------------------------------------------------------------- 2-5. each piece


def _piece(curve: SymbolicCurve, segment: SymbolicSegment, piece: Piece) -> PieceCertificate:
    """A piece's extrema and monotonicity, from its shape's own proof or from steps 2-5, and
    the bound on its float32 error (the evidence of step 7)."""
    found, monotone = segment.shape.prove(segment, piece) or _prove(curve, segment, piece)
    error = segment.shape.float32_error(segment, piece, found.low, found.high)
    return PieceCertificate(
        segment.index + 1,
        piece.label,
        float(piece.start),
        float(piece.end),
        found.low,
        found.high,
        monotone,
        found.exact,
        error,
    )


def _prove(curve: SymbolicCurve, segment: SymbolicSegment, piece: Piece) -> tuple[Extrema, Monotone]:
    """Steps 2-5 by sympy, or interval arithmetic where sympy fails, within their time budgets."""
    with _budget(segment):
        _domain(curve, segment, piece)
        expr = _simplification(piece)
        found = _range(curve, segment, piece, expr)
        return found, _monotonicity(piece, expr)


@contextlib.contextmanager
def _budget(segment: SymbolicSegment) -> Iterator[None]:
    """A proof that runs out of time, or of stack, as a located error."""
    where = segment.describe()
    try:
        yield
    except VerificationTimeoutError:
        raise _fail(
            f"could not verify {where} within the time limit",
            segment.span,
            "sympy could not bound this expression quickly; simplify it or split the segment",
        ) from None
    except RecursionError:
        raise _fail(f"{where} is too deeply nested to verify", segment.span, "simplify the expression") from None


def _domain(curve: SymbolicCurve, segment: SymbolicSegment, piece: Piece) -> None:
    """2. The value is real on the piece's whole closed interval, on the expression as written."""
    violation = domain_violation(piece.expr, piece.start, piece.end)
    if violation is not None:
        raise _fail(
            f"{curve.quantity} is not real everywhere on {segment.describe()}: {violation}",
            segment.span,
            "keep square roots and powers of non-negative values, logarithms of positive values, "
            "and divisions away from zero, over the whole segment",
        )


def _simplification(piece: Piece) -> sp.Expr:
    """3. The piece as sympy simplifies it, where that is no more complex: what steps 4 and 5 prove."""
    return simplified(piece.expr)


def _range(curve: SymbolicCurve, segment: SymbolicSegment, piece: Piece, expr: sp.Expr) -> Extrema:
    """4. The exact minimum and maximum, or an interval enclosure; finite and real."""
    found = extrema(expr, piece.start, piece.end)
    if found is None:
        raise _fail(
            f"{curve.quantity} is not finite and real everywhere on {segment.describe()}",
            segment.span,
            "check for a division by zero, or a log or square root of a negative number, inside the segment",
        )
    return found


def _monotonicity(piece: Piece, expr: sp.Expr) -> Monotone:
    """5. From the sign of the derivative: proven, refuted by a witness, or unknown."""
    return slope_sign(expr, piece.start, piece.end)


# ---------------------------------------------------------------- 6-9. each segment


@dataclass(frozen=True)
class _SegmentRange:
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
    def of(cls, pieces: list[PieceCertificate]) -> _SegmentRange:
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


def _above_zero(curve: SymbolicCurve, segment: SymbolicSegment, proven: _SegmentRange) -> None:
    """6. The minimum is strictly positive."""
    if not proven.low > 0:
        raise _fail(
            f"{curve.quantity} must stay above 0, but {segment.describe()} {proven.goes_down} {proven.low:.6g}",
            segment.span,
            f"{_scales(curve)}; 0 or less {AT_ZERO[curve.channel.kind]}" + proven.loose,
        )


def _finite_in_float32(curve: SymbolicCurve, segment: SymbolicSegment, proven: _SegmentRange) -> None:
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


def _declared_bounds(curve: SymbolicCurve, segment: SymbolicSegment, proven: _SegmentRange) -> None:
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


def _declared_monotonicity(
    curve: SymbolicCurve, segment: SymbolicSegment, pieces: list[PieceCertificate], proven: _SegmentRange
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
            f"{curve.quantity} goes from {number_text(_value_at(segment, 'start'))} at {percent(segment.start)} to "
            f"{number_text(_value_at(segment, 'end'))} at {percent(segment.end)}, ranging over "
            f"{proven.low:.6g} .. {proven.high:.6g}"
        )
    raise _fail(
        f"{where} is declared {segment.monotone} but is not: {detail}",
        segment.span,
        f"fix the values, or remove `{segment.monotone}` if the shape is intended",
    )


# ---------------------------------------------------------------- 10-12. the whole curve


def tail_start(curve: SymbolicCurve) -> sp.Rational:
    """10. Where the curve becomes identically its final value for good; raise if that leaves
    under MIN_TAIL."""
    segments = curve.segments
    start = sp.Integer(1)
    for segment in reversed(segments):
        if not segment.shape.is_constant(segment, curve.final):
            break
        start = segment.start
    if 1 - start < MIN_TAIL:
        last = segments[-1]
        if not curve.named:
            have = "no alpha = 1 tail" if start == 1 else f"alpha == 1 only from {percent(start)}"
            raise _fail(
                f"the schedule must end with alpha = 1 over at least the final {percent(MIN_TAIL)} of the run; "
                f"it has {have}",
                last.span,
                "the paper compares every schedule on the same body at the end: "
                f"finish with `{percent(1 - MIN_TAIL)} .. 100%: tail` (or any alpha == 1 segment starting "
                f"at {percent(1 - MIN_TAIL)} or earlier)",
            )
        q, final = curve.quantity, number_text(curve.final)
        have = f"no {q} = {final} tail" if start == 1 else f"{q} == {final} only from {percent(start)}"
        declared = "its declared final value" if curve.final != 1 else "its final value (1 unless it declares `final`)"
        raise _fail(
            f"{curve.channel.name} must end at {declared}, {q} = {final}, over at least the final "
            f"{percent(MIN_TAIL)} of the run; it has {have}",
            last.span,
            "every channel ends on its final body, so that runs compare on the same body: finish the section "
            f"with `{percent(1 - MIN_TAIL)} .. 100%: tail` (`tail` is {final} here), or any {q} == {final} "
            f"segment starting at {percent(1 - MIN_TAIL)} or earlier",
        )
    return start


def _value_at(segment: SymbolicSegment, where: Literal["start", "end"]) -> sp.Expr:
    piece = segment.pieces[0] if where == "start" else segment.pieces[-1]
    return piece.expr.subs(T, segment.start if where == "start" else segment.end)


def _joins(curve: SymbolicCurve) -> tuple[JoinCertificate, ...]:
    """11. The jump at each boundary, continuous where sympy proves it exactly 0; a join next
    to a random segment is random."""
    joins = []
    for before, after in pairwise(curve.segments):
        if any(s.draws is not None and not s.shape.is_constant(s, curve.final) for s in (before, after)):
            joins.append(JoinCertificate(float(after.start), False, None))
            continue
        jump = _value_at(after, "start") - _value_at(before, "end")
        joins.append(JoinCertificate(float(after.start), is_zero(jump), real(jump) or 0.0))
    return tuple(joins)


def _declared_continuity(curve: SymbolicCurve, joins: tuple[JoinCertificate, ...]) -> None:
    """12. Every join is continuous, where the channel declares `continuous`."""
    if not curve.continuous:
        return
    subject = f"{curve.channel.name} is" if curve.named else "the schedule is"
    for join, after in zip(joins, curve.segments[1:]):
        if not join.continuous:
            jump = "a random value" if join.jump is None else f"a jump of {join.jump:+.6g}"
            raise _fail(
                f"{subject} declared continuous but has {jump} at {percent(join.position)}",
                after.span,
                "make each segment start at the value where the previous one ends, or drop `continuous`",
            )
