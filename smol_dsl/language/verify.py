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

The certificate's types are in `smol_dsl.language.certificates`; the checks of each
segment's proven range (steps 6 to 9) in `smol_dsl.language.segment_rules`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from itertools import pairwise
from typing import TYPE_CHECKING

import sympy as sp

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language.certificates import MIN_TAIL, Certificate, JoinCertificate, PieceCertificate
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
from smol_dsl.language.segment_rules import (
    SegmentRange,
    above_zero,
    declared_bounds,
    declared_monotonicity,
    finite_in_float32,
)
from smol_dsl.language.symbolic import (
    Piece,
    SymbolicCurve,
    SymbolicProgram,
    SymbolicSegment,
    number_text,
    percent,
)

if TYPE_CHECKING:
    from smol_dsl.language.channels import Channel


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
        proven = SegmentRange.of(own)
        above_zero(curve, segment, proven)  # 6
        finite_in_float32(curve, segment, proven)  # 7
        declared_bounds(curve, segment, proven)  # 8
        declared_monotonicity(curve, segment, own, proven)  # 9
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


def _joins(curve: SymbolicCurve) -> tuple[JoinCertificate, ...]:
    """11. The jump at each boundary, continuous where sympy proves it exactly 0; a join next
    to a random segment is random."""
    joins = []
    for before, after in pairwise(curve.segments):
        if any(s.draws is not None and not s.shape.is_constant(s, curve.final) for s in (before, after)):
            joins.append(JoinCertificate(float(after.start), False, None))
            continue
        jump = after.value_at("start") - before.value_at("end")
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
