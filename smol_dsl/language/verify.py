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

import json
from dataclasses import asdict, dataclass
from itertools import pairwise
from typing import Any, Literal

import sympy as sp

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language.channels import CHANNEL_KINDS, GEAR, Channel
from smol_dsl.language.float32 import SAFE_MAX, SAFE_MIN
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


def _check_coverage(curve: SymbolicCurve) -> None:
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


def tail_start(curve: SymbolicCurve) -> sp.Rational:
    """Where the curve becomes identically its final value for good; raise if that leaves
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
    joins = []
    for before, after in pairwise(curve.segments):
        if any(s.draws is not None and not s.shape.is_constant(s, curve.final) for s in (before, after)):
            joins.append(JoinCertificate(float(after.start), False, None))
            continue
        jump = _value_at(after, "start") - _value_at(before, "end")
        joins.append(JoinCertificate(float(after.start), is_zero(jump), real(jump) or 0.0))
    return tuple(joins)


def _verify_piece(curve: SymbolicCurve, segment: SymbolicSegment, piece: Piece) -> PieceCertificate:
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
    """Extrema and monotonicity of a piece by sympy, or interval arithmetic where sympy fails."""
    where = segment.describe()
    try:
        violation = domain_violation(piece.expr, piece.start, piece.end)
        expr = simplified(piece.expr)
        found = extrema(expr, piece.start, piece.end) if violation is None else None
        monotone = slope_sign(expr, piece.start, piece.end) if found is not None else "unknown"
    except VerificationTimeoutError:
        raise _fail(
            f"could not verify {where} within the time limit",
            segment.span,
            "sympy could not bound this expression quickly; simplify it or split the segment",
        ) from None
    except RecursionError:
        raise _fail(f"{where} is too deeply nested to verify", segment.span, "simplify the expression") from None
    if violation is not None:
        raise _fail(
            f"{curve.quantity} is not real everywhere on {where}: {violation}",
            segment.span,
            "keep square roots and powers of non-negative values, logarithms of positive values, "
            "and divisions away from zero, over the whole segment",
        )
    if found is None:
        raise _fail(
            f"{curve.quantity} is not finite and real everywhere on {where}",
            segment.span,
            "check for a division by zero, or a log or square root of a negative number, inside the segment",
        )
    return found, monotone


def _scales(curve: SymbolicCurve) -> str:
    """`alpha scales the actuators' gear` (plain gear alone, as ever), else the channel's words."""
    if not curve.named:
        return "alpha scales the actuators' gear"
    return f"{curve.channel.name} scales {CHANNEL_KINDS[curve.channel.kind].scales}"


def _check_rules(curve: SymbolicCurve, segment: SymbolicSegment, pieces: list[PieceCertificate]) -> None:
    where = segment.describe()
    q = curve.quantity
    lowest = min(pieces, key=lambda p: p.minimum)
    highest = max(pieces, key=lambda p: p.maximum)
    low, high = lowest.minimum, highest.maximum
    # Where an extremum is only an interval-arithmetic bound, say so rather than claim
    # that the value reaches it.
    goes_down = "goes down to" if lowest.exact else "could not be shown to stay above its bound of"
    reaches = "reaches" if highest.exact else "could not be shown to stay below its bound of"
    loose = (
        ""
        if lowest.exact and highest.exact
        else (
            "; its exact extrema could not be found, and the interval-arithmetic bound is not tight enough: "
            "simplify the expression or split the segment"
        )
    )
    error = max(p.float32_error for p in pieces)
    if low > 0 and not low - error > 0:
        raise _fail(
            f"{q} must stay above 0, but in float32 {where} may go down to {low - error:.3g} "
            f"(exactly it goes down to {low:.6g}, with rounding errors up to {error:.3g})",
            segment.span,
            "the expression loses too much precision in 32-bit floats: simplify it or rescale its parts",
        )
    if low > 0 and low < SAFE_MIN:
        raise _fail(
            f"{where} {goes_down} {q} = {low:.3g}, too small for float32",
            segment.span,
            f"{_scales(curve)}; a value this small is 0 in 32-bit floats",
        )
    if not low > 0:
        raise _fail(
            f"{q} must stay above 0, but {where} {goes_down} {low:.6g}",
            segment.span,
            f"{_scales(curve)}; 0 or less {AT_ZERO[curve.channel.kind]}" + loose,
        )
    if high + error > SAFE_MAX:
        raise _fail(
            f"{where} {reaches} {q} = {high:.3g}, beyond float32's safe range (2**120, about 1.3e36)",
            segment.span,
            f"use a modest {q}",
        )
    if curve.bounds is not None:
        lo, hi, _ = curve.bounds
        lo_f, hi_f = float(lo), float(hi)
        if low < lo_f:
            raise _fail(
                f"{where} {goes_down} {q} = {low:.6g}, {lo_f - low:.6g} below the declared bound {lo_f:.6g}",
                segment.span,
                f"raise the segment's values, or widen `bounds {number_text(lo)} .. {number_text(hi)}`" + loose,
            )
        if high > hi_f:
            raise _fail(
                f"{where} {reaches} {q} = {high:.6g}, {high - hi_f:.6g} above the declared bound {hi_f:.6g}",
                segment.span,
                f"lower the segment's values, or widen `bounds {number_text(lo)} .. {number_text(hi)}`" + loose,
            )
    if segment.monotone is not None:
        allowed = {"constant", segment.monotone}
        broken = [p for p in pieces if p.monotone not in allowed]
        if broken:
            first_value = _value_at(segment, "start")
            last_value = _value_at(segment, "end")
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
                    f"{q} goes from {number_text(first_value)} at {percent(segment.start)} to "
                    f"{number_text(last_value)} at {percent(segment.end)}, ranging over "
                    f"{low:.6g} .. {high:.6g}"
                )
            raise _fail(
                f"{where} is declared {segment.monotone} but is not: {detail}",
                segment.span,
                f"fix the values, or remove `{segment.monotone}` if the shape is intended",
            )


def verify_curve(curve: SymbolicCurve, extinction: sp.Expr = sp.S.Zero) -> Certificate:
    """Prove the language's rules for one channel's curve; raise ScheduleError on the first failure."""
    segments = curve.segments
    _check_coverage(curve)
    pieces: list[PieceCertificate] = []
    for segment in segments:
        own = [_verify_piece(curve, segment, piece) for piece in segment.pieces]
        _check_rules(curve, segment, own)
        pieces.extend(own)
    start_of_tail = tail_start(curve)
    joins = _joins(curve)
    if curve.continuous:
        subject = f"{curve.channel.name} is" if curve.named else "the schedule is"
        for join, after in zip(joins, segments[1:]):
            if not join.continuous:
                jump = "a random value" if join.jump is None else f"a jump of {join.jump:+.6g}"
                raise _fail(
                    f"{subject} declared continuous but has {jump} at {percent(join.position)}",
                    after.span,
                    "make each segment start at the value where the previous one ends, or drop `continuous`",
                )
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


def verify(program: SymbolicProgram) -> dict[Channel, Certificate]:
    """Prove the language's rules for every channel of a compiled program, in declared order;
    raise ScheduleError on the first failure."""
    return {curve.channel: verify_curve(curve, program.extinction) for curve in program.curves}
