"""Syntax tree -> exact sympy: the `let` constants, each channel's section, and the limits of a file.

Expressions are built by a `Scope` (`smol_dsl.language.expressions`). What a segment's shape
means is its unit's business (`smol_dsl.language.shapes`): the compiler checks the segment's
extent and hands the unit a `SegmentContext` to read its values with.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import sympy as sp

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language.channels import GEAR
from smol_dsl.language.expressions import Scope
from smol_dsl.language.grammar import reserved_words
from smol_dsl.language.pacing import Pacing, compile_pace
from smol_dsl.language.shapes import SegmentContext
from smol_dsl.language.symbolic import (
    MAX_RANDOM_DRAWS,
    MIN_SEGMENT,
    ChannelPlace,
    SymbolicCurve,
    SymbolicProgram,
    SymbolicSegment,
    number_text,
    percent,
)

if TYPE_CHECKING:
    from smol_dsl.language import tree

MAX_SEGMENTS = 1_000
"""Segments of a file, all channels together; evaluation stays memory-linear, verification
takes about 1 ms each."""


def _segment(
    scope: Scope, index: int, node: tree.Segment, owner: str, final: sp.Expr, quantity: str
) -> SymbolicSegment:
    label = f"segment {index + 1}{owner}"
    start = scope.position(node.start, f"the start of {label}")
    end = scope.position(node.end, f"the end of {label}")
    if end <= start:
        raise ScheduleError(
            f"{label} is empty: it runs from {percent(start)} to {percent(end)}",
            span=node.span,
            hint="a segment's end must come after its start, e.g. `0% .. 90%`",
        )
    if end - start < MIN_SEGMENT:
        raise ScheduleError(
            f"{label} is too short: {percent(start)} .. {percent(end)} is less than 2**-24 of the run",
            span=node.span,
            hint="progress t is a 32-bit float, which cannot tell positions this close apart near the end "
            "of the run; make the segment at least 1e-5% long, or remove it",
        )
    unit = node.shape.unit
    context = SegmentContext(index, start, end, node.span, scope, owner, final)
    compiled = unit.compile(context, *node.shape.args)
    return SymbolicSegment(
        index=index,
        shape=unit,
        start=start,
        end=end,
        pieces=compiled.pieces,
        monotone=node.monotone,
        span=node.span,
        params=compiled.params,
        draws=compiled.draws,
        owner=owner,
        quantity=quantity,
    )


def _final(scope: Scope, section: tree.Section) -> sp.Expr:
    """The channel's declared final value (1 if none), a positive constant."""
    if section.final is None:
        return sp.Integer(1)
    name = section.channel.name
    value = scope.constant(section.final.value, what=f"the final value of {name}")
    if not value > 0:
        raise ScheduleError(
            f"the final value of {name} must be above 0, not {number_text(value)}",
            span=section.final.span,
            hint=f"`final` is {name}'s factor on the standard body at the end of the run, e.g. `final 0.5`",
        )
    return value


def _bounds(scope: Scope, section: tree.Section) -> tuple[sp.Expr, sp.Expr, Span] | None:
    if section.bounds is None:
        return None
    low = scope.constant(section.bounds.low, what="the lower bound")
    high = scope.constant(section.bounds.high, what="the upper bound")
    if high < low:
        raise ScheduleError(
            f"bounds are reversed: {number_text(low)} .. {number_text(high)}",
            span=section.bounds.span,
            hint=f"write `bounds {number_text(high)} .. {number_text(low)}`",
        )
    return (low, high, section.bounds.span)


def _curve(scope: Scope, section: tree.Section, named: bool, segments_before: int) -> SymbolicCurve:
    """One channel's section, compiled; `segments_before` counts the file's earlier segments."""
    owner = f" of {section.channel.name}" if named else ""
    if not section.segments:
        if section.line is None:
            raise ScheduleError(
                "the schedule has no segments",
                span=Span(1, 1),
                hint="add segments covering 0%..100%, e.g. `0% .. 90%: linear 1.5 -> 1` and `90% .. 100%: tail`",
            )
        raise ScheduleError(
            f"channel {section.channel.name} has no segments",
            span=section.line.span,
            hint="add segments covering 0%..100% below this line, e.g. `0% .. 90%: linear 0.5 -> 1` "
            "and `90% .. 100%: tail`, or delete the line",
        )
    if segments_before + len(section.segments) > MAX_SEGMENTS:
        total = segments_before + len(section.segments)
        raise ScheduleError(
            f"the schedule has {total} segments, more than {MAX_SEGMENTS}",
            span=section.segments[MAX_SEGMENTS - segments_before].span,
            hint=f"a schedule has at most {MAX_SEGMENTS} segments (all channels together); for many values use "
            "`random LOW .. HIGH every STEP`, or an `expr` segment",
        )
    final = _final(scope, section)
    segments = tuple(
        _segment(scope, i, s, owner, final, section.channel.quantity) for i, s in enumerate(section.segments)
    )
    place = None
    if section.line is not None:
        place = ChannelPlace(section.line.span, section.line.target_spans, section.line.written)
    return SymbolicCurve(
        channel=section.channel,
        segments=segments,
        continuous=section.continuous,
        final=final,
        named=named,
        place=place,
    )


def compile_program(program: tree.Program) -> SymbolicProgram:
    """Build the exact sympy form of a parsed program; raise ScheduleError on bad values."""
    scope = Scope(reserved_words())
    for let in program.lets:
        scope.define(let)
    named = len(program.sections) > 1 or program.sections[0].channel != GEAR
    curves = []
    segments_before = 0
    for section in program.sections:
        curves.append(_curve(scope, section, named, segments_before))
        segments_before += len(section.segments)
    draws = 0
    for curve in curves:
        for segment in curve.segments:
            draws += segment.draws.count if segment.draws is not None else 0
            if draws > MAX_RANDOM_DRAWS:
                raise ScheduleError(
                    f"the random segments need {draws} draws or more, more than {MAX_RANDOM_DRAWS} in all",
                    span=segment.span,
                    hint="use coarser resolutions (`every 1%`) or fewer random segments",
                )
    curves = [replace(curve, bounds=_bounds(scope, section)) for curve, section in zip(curves, program.sections)]
    extinction: sp.Expr = sp.Integer(0)
    extinction_span = None
    if program.extinction is not None:
        extinction_span = program.extinction.span
        extinction = scope.constant(program.extinction.probability, what="the extinction probability")
        if not 0 <= extinction <= 1:
            raise ScheduleError(
                f"the extinction probability is {number_text(extinction)}, outside 0 .. 1",
                span=extinction_span,
                hint="write it as a probability, e.g. `extinction 0.05` or `extinction 5%`",
            )
    return SymbolicProgram(
        name=program.name,
        description=program.description,
        curves=tuple(curves),
        extinction=extinction,
        extinction_span=extinction_span,
        pacing=_pacing(scope, program, curves),
    )


def _pacing(scope: Scope, program: tree.Program, curves: list[SymbolicCurve]) -> Pacing | None:
    """The file's clocks: one per `pace` line (the file's first), and the clock each channel
    reads: its own `pace` line's, else the file's, else none (the budget's). A paced channel
    has no random segment: its draws are laid out on the budget's clock."""
    clocks, channel_clocks = [], []
    shared = None
    if program.pace is not None:
        clocks.append(compile_pace(scope, program.pace))
        shared = 0
    for section, curve in zip(program.sections, curves):
        clock = shared
        if section.pace is not None:
            clocks.append(compile_pace(scope, section.pace))
            clock = len(clocks) - 1
        if clock is not None:
            random = next((segment for segment in curve.segments if segment.draws is not None), None)
            if random is not None:
                pace = section.pace or program.pace
                assert pace is not None
                raise ScheduleError(
                    f"{curve.channel.name} is paced and has a `random` segment, which pacing does not support",
                    span=pace.span,
                    hint=f"a random segment's draws follow the budget's phases (segment on line {random.span.line}); "
                    "pace a channel without random segments, or drop the `pace` line",
                )
        channel_clocks.append(clock)
    if not clocks:
        return None
    return Pacing(tuple(clocks), tuple(channel_clocks))
