"""Syntax tree -> exact sympy: constants, positions, and each segment through its shape's unit.

Expressions are built node by node from the syntax tree; no text from a `.sched` file is
ever handed to `eval`, `sympify` or `parse_expr`. What a segment's shape means is its unit's
business (`smol_dsl.language.shapes`): the compiler checks the segment's extent and hands the
unit a `SegmentContext` to read its values with.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import sympy as sp

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language import tree
from smol_dsl.language.channels import GEAR
from smol_dsl.language.grammar import reserved_words
from smol_dsl.language.symbolic import (
    MAX_RANDOM_DRAWS,
    MIN_SEGMENT,
    ChannelPlace,
    SymbolicCurve,
    SymbolicProgram,
    SymbolicSegment,
    T,
    number_text,
    percent,
)

MAX_EXPONENT = 10_000
MAX_SEGMENTS = 1_000
"""Segments of a file, all channels together; evaluation stays memory-linear, verification
takes about 1 ms each."""

FUNCTIONS: dict[str, tuple[Callable[..., sp.Expr], int | None]] = {
    "exp": (sp.exp, 1),
    "log": (sp.log, 1),
    "sqrt": (sp.sqrt, 1),
    "sin": (sp.sin, 1),
    "cos": (sp.cos, 1),
    "tanh": (sp.tanh, 1),
    "abs": (sp.Abs, 1),
    "min": (sp.Min, None),
    "max": (sp.Max, None),
}
CONSTANTS: dict[str, sp.Expr] = {"pi": sp.pi, "e": sp.E}


class _Builder:
    """Builds sympy expressions from syntax-tree expressions under a scope of names."""

    def __init__(self) -> None:
        self.constants: dict[str, sp.Expr] = dict(CONSTANTS)

    def define(self, let: tree.Let) -> None:
        reserved = reserved_words()
        if let.name in reserved:
            raise ScheduleError(
                f"`{let.name}` is a reserved word",
                span=let.span,
                hint="choose another name for this constant; reserved: " + ", ".join(sorted(reserved)),
            )
        if let.name in self.constants or let.name in FUNCTIONS or let.name in ("t", "u"):
            what = "a built-in name" if let.name not in self.constants or let.name in CONSTANTS else "already defined"
            raise ScheduleError(
                f"`{let.name}` is {what}",
                span=let.span,
                hint="choose another name for this constant",
            )
        self.constants[let.name] = self.constant(let.value, what=f"`let {let.name}`")

    def constant(self, node: tree.Expr, *, what: str) -> sp.Expr:
        """A constant real number (no t): the value of a let, a position, an alpha level."""
        return _finite_real(self.build(node, variables={}), node, what)

    def build(self, node: tree.Expr, variables: dict[str, sp.Expr]) -> sp.Expr:
        if isinstance(node, tree.Number):
            return sp.Rational(node.value.numerator, node.value.denominator)
        if isinstance(node, tree.Name):
            if node.id in variables:
                return variables[node.id]
            if node.id in self.constants:
                return self.constants[node.id]
            raise self._unknown_name(node, variables)
        if isinstance(node, tree.Unary):
            operand = self.build(node.operand, variables)
            if node.op == "-":
                return -operand
            if node.op == "%":
                return operand / 100
            return operand
        if isinstance(node, tree.Binary):
            left = self.build(node.left, variables)
            right = self.build(node.right, variables)
            if node.op == "+":
                return left + right
            if node.op == "-":
                return left - right
            if node.op == "*":
                return left * right
            if node.op == "/":
                if right.is_zero:
                    raise ScheduleError("division by zero", span=node.span, hint="the divisor here is 0")
                return left / right
            return _power(left, right, node)
        if isinstance(node, tree.Call):
            return self._call(node, variables)
        raise TypeError(f"unknown expression node {node!r}")

    def _call(self, node: tree.Call, variables: dict[str, sp.Expr]) -> sp.Expr:
        if node.function not in FUNCTIONS:
            close = difflib.get_close_matches(node.function, list(FUNCTIONS), n=1)
            hint = f"did you mean `{close[0]}`? " if close else ""
            raise ScheduleError(
                f"unknown function `{node.function}`",
                span=Span(node.span.line, node.span.column, len(node.function)),
                hint=hint + "the functions are " + ", ".join(FUNCTIONS),
            )
        function, arity = FUNCTIONS[node.function]
        args = [self.build(a, variables) for a in node.args]
        if arity is not None and len(args) != arity:
            raise ScheduleError(
                f"`{node.function}` takes {arity} argument, not {len(args)}",
                span=node.span,
                hint=f"write `{node.function}(x)`",
            )
        if arity is None and len(args) < 2:
            raise ScheduleError(
                f"`{node.function}` takes two or more arguments, not {len(args)}",
                span=node.span,
                hint=f"write `{node.function}(a, b)`",
            )
        return function(*args)

    def _unknown_name(self, node: tree.Name, variables: dict[str, sp.Expr]) -> ScheduleError:
        known = list(self.constants) + list(variables)
        close = difflib.get_close_matches(node.id, known, n=1)
        if node.id in ("t", "u"):
            hint = f"`{node.id}` is only defined inside an `expr` segment"
        elif node.id in reserved_words():
            hint = f"`{node.id}` is a keyword of the language, not a value" + (
                "; alpha = 1 is written `1`" if node.id == "tail" else ""
            )
        elif node.id.lower() in ("nan", "inf", "infinity"):
            hint = "alpha and positions must be finite numbers"
        elif close:
            hint = f"did you mean `{close[0]}`?"
        else:
            hint = "define it first with `let " + node.id + " = ...`"
        return ScheduleError(f"unknown name `{node.id}`", span=node.span, hint=hint)


def _power(base: sp.Expr, exponent: sp.Expr, node: tree.Binary) -> sp.Expr:
    # Exact arithmetic would happily try 10**10**10; refuse powers that cannot be a
    # sensible alpha before sympy starts computing them.
    if exponent.is_number:
        magnitude = abs(float(exponent.evalf(20))) if exponent.is_real else math.inf
        if magnitude > MAX_EXPONENT or (
            base.is_number
            and base.is_real
            and not base.is_zero
            and abs(math.log10(abs(float(base.evalf(20))) or 1e-300)) * magnitude > 400
        ):
            raise ScheduleError(
                "power out of range",
                span=node.span,
                hint="the result of this power is far beyond any sensible alpha",
            )
    if base.is_zero and exponent.is_number and exponent.is_negative:
        raise ScheduleError("division by zero", span=node.span, hint="0 raised to a negative power")
    return sp.Pow(base, exponent)


def _finite_real(value: sp.Expr, node: tree.Expr, what: str) -> sp.Expr:
    try:
        number = complex(value.evalf(30))
    except (TypeError, ValueError):
        number = complex(math.nan)
    if value.is_real and value.is_finite and not math.isfinite(number.real):
        raise ScheduleError(
            f"{what} is {sp.N(value, 3)}, out of range",
            span=node.span,
            hint="values must stay below about 1e300 in size; alpha is a modest factor like 1.5",
        )
    if value.has(sp.zoo, sp.nan, sp.oo, -sp.oo) or not math.isfinite(number.real) or abs(number.imag) > 0:
        raise ScheduleError(
            f"{what} is not a finite real number (it is {value})",
            span=node.span,
            hint="check for a log or square root of a negative number, or a division by zero",
        )
    if abs(number.real) > 1e300:
        raise ScheduleError(f"{what} is out of range ({number.real:.3g})", span=node.span, hint="use a modest value")
    return value


def _position(builder: _Builder, node: tree.Expr, what: str) -> sp.Rational:
    value = builder.constant(node, what=what)
    if not value.is_Rational:
        raise ScheduleError(
            f"{what} must be a plain percentage or fraction, not {value}",
            span=node.span,
            hint="write positions like `90%` or `0.9`",
        )
    if value < 0 or value > 1:
        raise ScheduleError(
            f"{what} is {percent(value)}, outside the run",
            span=node.span,
            hint="positions are fractions of the run from 0% to 100%: write `90%` or `0.9`, not `90`",
        )
    return value


@dataclass(frozen=True)
class SegmentContext:
    """What a shape's unit compiles its segment with: the segment's place in the file and
    extent, and the constants in scope. Its methods raise located errors that name the segment."""

    index: int
    start: sp.Rational
    end: sp.Rational
    span: Span
    """The whole segment's text."""
    builder: _Builder
    owner: str = ""
    """` of mass` when messages name the segment's channel."""
    final: sp.Expr = sp.S.One
    """The channel's final value (what `tail` means)."""

    @property
    def label(self) -> str:
        """`segment 3` (`segment 3 of mass`): how messages name the segment."""
        return f"segment {self.index + 1}{self.owner}"

    @property
    def u(self) -> sp.Expr:
        """Progress within the segment, (t - start) / (end - start): 0 at its start, 1 at its end."""
        return (T - self.start) / (self.end - self.start)

    def value(self, node: tree.Expr, what: str) -> sp.Expr:
        """A constant real value, e.g. `value(node, "peak")` for "the peak of segment 3"."""
        return self.builder.constant(node, what=f"the {what} of {self.label}")

    def position(self, node: tree.Expr, what: str) -> sp.Rational:
        """An exact position in the run (a fraction in [0, 1]), e.g. "the peak position of segment 3"."""
        return _position(self.builder, node, f"the {what} of {self.label}")

    def formula(self, node: tree.Expr) -> sp.Expr:
        """An expression of `t` (the run's progress) and `u` (the segment's)."""
        return self.builder.build(node, {"t": T, "u": self.u})


def _segment(builder: _Builder, index: int, node: tree.Segment, owner: str, final: sp.Expr) -> SymbolicSegment:
    label = f"segment {index + 1}{owner}"
    start = _position(builder, node.start, f"the start of {label}")
    end = _position(builder, node.end, f"the end of {label}")
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
    context = SegmentContext(index, start, end, node.span, builder, owner, final)
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
    )


def _final(builder: _Builder, section: tree.Section) -> sp.Expr:
    """The channel's declared final value (1 if none), a positive constant."""
    if section.final is None:
        return sp.Integer(1)
    name = section.channel.name
    value = builder.constant(section.final.value, what=f"the final value of {name}")
    if not value > 0:
        raise ScheduleError(
            f"the final value of {name} must be above 0, not {number_text(value)}",
            span=section.final.span,
            hint=f"`final` is {name}'s factor on the standard body at the end of the run, e.g. `final 0.5`",
        )
    return value


def _bounds(builder: _Builder, section: tree.Section) -> tuple[sp.Expr, sp.Expr, Span] | None:
    if section.bounds is None:
        return None
    low = builder.constant(section.bounds.low, what="the lower bound")
    high = builder.constant(section.bounds.high, what="the upper bound")
    if high < low:
        raise ScheduleError(
            f"bounds are reversed: {number_text(low)} .. {number_text(high)}",
            span=section.bounds.span,
            hint=f"write `bounds {number_text(high)} .. {number_text(low)}`",
        )
    return (low, high, section.bounds.span)


def _curve(builder: _Builder, section: tree.Section, named: bool, segments_before: int) -> SymbolicCurve:
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
    final = _final(builder, section)
    segments = tuple(_segment(builder, i, s, owner, final) for i, s in enumerate(section.segments))
    place = None
    if section.line is not None:
        place = ChannelPlace(section.line.span, section.line.target_spans)
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
    builder = _Builder()
    for let in program.lets:
        builder.define(let)
    named = len(program.sections) > 1 or program.sections[0].channel != GEAR
    curves = []
    segments_before = 0
    for section in program.sections:
        curves.append(_curve(builder, section, named, segments_before))
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
    curves = [replace(curve, bounds=_bounds(builder, section)) for curve, section in zip(curves, program.sections)]
    extinction: sp.Expr = sp.Integer(0)
    extinction_span = None
    if program.extinction is not None:
        extinction_span = program.extinction.span
        extinction = builder.constant(program.extinction.probability, what="the extinction probability")
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
    )
