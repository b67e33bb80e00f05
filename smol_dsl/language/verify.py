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
from smol_dsl.language.symbolic import Piece, SymbolicProgram, SymbolicSegment, T, number_text, percent

MIN_TAIL = sp.Rational(1, 10)
"""The last 10% of the run must be at alpha = 1 (the paper's fair-comparison rule)."""


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
    """The result of verifying a schedule: bounds, tail, joins, and each piece."""

    minimum: float
    maximum: float
    tail_start: float
    joins: tuple[JoinCertificate, ...]
    pieces: tuple[PieceCertificate, ...]
    bounds: tuple[float, float] | None
    extinction: float
    float32_error: float = 0.0

    @property
    def tail_fraction(self) -> float:
        return 1.0 - self.tail_start

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary of the certificate."""
        return json.loads(json.dumps(asdict(self)))

    def __str__(self) -> str:
        lines = [
            f"  alpha in [{self.minimum:.6g}, {self.maximum:.6g}]   alpha > 0: proven"
            + (f"   bounds {self.bounds[0]:.6g} .. {self.bounds[1]:.6g}: proven" if self.bounds else ""),
            f"  tail: alpha == 1 from {percent(self.tail_start)} to 100% "
            f"({percent(self.tail_fraction)} of the run, at least {percent(MIN_TAIL)} required): proven",
            "  pieces:",
        ]
        for p in self.pieces:
            extent = f"{percent(p.start)} .. {percent(p.end)}"
            note = "" if p.exact else "  (interval enclosure)"
            lines.append(
                f"    #{p.segment:<2} {extent:<16} {p.kind:<15} alpha {p.minimum:.6g} .. {p.maximum:.6g}"
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
        lines.append(f"  float32: every value finite, alpha within {self.float32_error:.2g} of exact and > 0: proven")
        return "\n".join(lines)


def _fail(message: str, span: Span, hint: str) -> ScheduleError:
    return ScheduleError(message, span=span, hint=hint)


def _check_coverage(segments: tuple[SymbolicSegment, ...]) -> None:
    first = segments[0]
    if first.start != 0:
        raise _fail(
            f"the segments leave 0% .. {percent(first.start)} uncovered",
            first.span,
            f"start the first segment at 0%, or add a segment `0% .. {percent(first.start)}: ...`",
        )
    for before, after in pairwise(segments):
        if after.start > before.end:
            raise _fail(
                f"gap between {percent(before.end)} and {percent(after.start)}",
                after.span,
                f"segment {before.index + 1} (line {before.span.line}) ends at {percent(before.end)} "
                f"but segment {after.index + 1} starts at {percent(after.start)}; "
                f"start it at {percent(before.end)}",
            )
        if after.start < before.end:
            raise _fail(
                f"overlap between {percent(after.start)} and {percent(min(before.end, after.end))}",
                after.span,
                f"segment {before.index + 1} (line {before.span.line}) runs to {percent(before.end)} "
                f"but segment {after.index + 1} starts at {percent(after.start)}; "
                f"segments must be in order and must not overlap",
            )
    last = segments[-1]
    if last.end != 1:
        raise _fail(
            f"the segments leave {percent(last.end)} .. 100% uncovered",
            last.span,
            f"end the last segment at 100%, or add `{percent(last.end)} .. 100%: tail`",
        )


def tail_start(segments: tuple[SymbolicSegment, ...]) -> sp.Rational:
    """Where alpha becomes identically 1 for good; raise if that leaves under MIN_TAIL."""
    start = sp.Integer(1)
    for segment in reversed(segments):
        if not segment.shape.is_one(segment):
            break
        start = segment.start
    if 1 - start < MIN_TAIL:
        last = segments[-1]
        have = "no alpha = 1 tail" if start == 1 else f"alpha == 1 only from {percent(start)}"
        raise _fail(
            f"the schedule must end with alpha = 1 over at least the final {percent(MIN_TAIL)} of the run; "
            f"it has {have}",
            last.span,
            "the paper compares every schedule on the same body at the end: "
            f"finish with `{percent(1 - MIN_TAIL)} .. 100%: tail` (or any alpha == 1 segment starting "
            f"at {percent(1 - MIN_TAIL)} or earlier)",
        )
    return start


def _value_at(segment: SymbolicSegment, where: Literal["start", "end"]) -> sp.Expr:
    piece = segment.pieces[0] if where == "start" else segment.pieces[-1]
    return piece.expr.subs(T, segment.start if where == "start" else segment.end)


def _joins(segments: tuple[SymbolicSegment, ...]) -> tuple[JoinCertificate, ...]:
    joins = []
    for before, after in pairwise(segments):
        if any(s.draws is not None and not s.shape.is_one(s) for s in (before, after)):
            joins.append(JoinCertificate(float(after.start), False, None))
            continue
        jump = _value_at(after, "start") - _value_at(before, "end")
        joins.append(JoinCertificate(float(after.start), is_zero(jump), real(jump) or 0.0))
    return tuple(joins)


def _verify_piece(segment: SymbolicSegment, piece: Piece) -> PieceCertificate:
    found, monotone = segment.shape.prove(segment, piece) or _prove(segment, piece)
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


def _prove(segment: SymbolicSegment, piece: Piece) -> tuple[Extrema, Monotone]:
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
            f"alpha is not real everywhere on {where}: {violation}",
            segment.span,
            "keep square roots and powers of non-negative values, logarithms of positive values, "
            "and divisions away from zero, over the whole segment",
        )
    if found is None:
        raise _fail(
            f"alpha is not finite and real everywhere on {where}",
            segment.span,
            "check for a division by zero, or a log or square root of a negative number, inside the segment",
        )
    return found, monotone


def _check_rules(program: SymbolicProgram, segment: SymbolicSegment, pieces: list[PieceCertificate]) -> None:
    where = segment.describe()
    lowest = min(pieces, key=lambda p: p.minimum)
    highest = max(pieces, key=lambda p: p.maximum)
    low, high = lowest.minimum, highest.maximum
    # Where an extremum is only an interval-arithmetic bound, say so rather than claim
    # that alpha reaches it.
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
            f"alpha must stay above 0, but in float32 {where} may go down to {low - error:.3g} "
            f"(exactly it goes down to {low:.6g}, with rounding errors up to {error:.3g})",
            segment.span,
            "the expression loses too much precision in 32-bit floats: simplify it or rescale its parts",
        )
    if low > 0 and low < SAFE_MIN:
        raise _fail(
            f"{where} {goes_down} alpha = {low:.3g}, too small for float32",
            segment.span,
            "alpha scales the actuators' gear; a value this small is 0 in 32-bit floats",
        )
    if not low > 0:
        raise _fail(
            f"alpha must stay above 0, but {where} {goes_down} {low:.6g}",
            segment.span,
            "alpha scales the actuators' gear; 0 or less would switch them off or reverse them" + loose,
        )
    if high + error > SAFE_MAX:
        raise _fail(
            f"{where} {reaches} alpha = {high:.3g}, beyond float32's safe range (2**120, about 1.3e36)",
            segment.span,
            "use a modest alpha",
        )
    if program.bounds is not None:
        lo, hi, _ = program.bounds
        lo_f, hi_f = float(lo), float(hi)
        if low < lo_f:
            raise _fail(
                f"{where} {goes_down} alpha = {low:.6g}, {lo_f - low:.6g} below the declared bound {lo_f:.6g}",
                segment.span,
                f"raise the segment's values, or widen `bounds {number_text(lo)} .. {number_text(hi)}`" + loose,
            )
        if high > hi_f:
            raise _fail(
                f"{where} {reaches} alpha = {high:.6g}, {high - hi_f:.6g} above the declared bound {hi_f:.6g}",
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
                    f"alpha goes from {number_text(first_value)} at {percent(segment.start)} to "
                    f"{number_text(last_value)} at {percent(segment.end)}, ranging over "
                    f"{low:.6g} .. {high:.6g}"
                )
            raise _fail(
                f"{where} is declared {segment.monotone} but is not: {detail}",
                segment.span,
                f"fix the values, or remove `{segment.monotone}` if the shape is intended",
            )


def verify(program: SymbolicProgram) -> Certificate:
    """Prove the language's rules for a compiled program; raise ScheduleError on the first failure."""
    segments = program.segments
    _check_coverage(segments)
    pieces: list[PieceCertificate] = []
    for segment in segments:
        own = [_verify_piece(segment, piece) for piece in segment.pieces]
        _check_rules(program, segment, own)
        pieces.extend(own)
    start_of_tail = tail_start(segments)
    joins = _joins(segments)
    if program.continuous:
        for join, after in zip(joins, segments[1:]):
            if not join.continuous:
                jump = "a random value" if join.jump is None else f"a jump of {join.jump:+.6g}"
                raise _fail(
                    f"the schedule is declared continuous but has {jump} at {percent(join.position)}",
                    after.span,
                    "make each segment start at the value where the previous one ends, or drop `continuous`",
                )
    bounds = None if program.bounds is None else (float(program.bounds[0]), float(program.bounds[1]))
    return Certificate(
        minimum=min(p.minimum for p in pieces),
        maximum=max(p.maximum for p in pieces),
        tail_start=float(start_of_tail),
        joins=joins,
        pieces=tuple(pieces),
        bounds=bounds,
        extinction=float(program.extinction),
        float32_error=max(p.float32_error for p in pieces),
    )
