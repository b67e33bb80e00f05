"""Syntax tree -> exact sympy objects: constants, segment pieces and the Piecewise alpha(t).

Expressions are built node by node from the syntax tree; no text from a `.sched` file is
ever handed to `eval`, `sympify` or `parse_expr`.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from typing import Literal

import sympy as sp

from smol_dsl import ast
from smol_dsl.errors import ScheduleError, Span

T = sp.Symbol("t", real=True)
"""Training progress, 0 at the start of the run and 1 at its end."""
U = sp.Symbol("u", real=True)
"""Progress within the current segment (0 at its start, 1 at its end); only in `expr`."""

DEFAULT_RANDOM_EVERY = sp.Rational(1, 100)  # "a new alpha every schedule step" (1%)
MAX_RANDOM_DRAWS = 1_000_000
"""Random draws of a whole schedule (all its random segments together)."""
MAX_EXPONENT = 10_000
MAX_SEGMENTS = 1_000
"""Segments of a schedule; evaluation stays memory-linear, verification takes about 1 ms each."""
MIN_SEGMENT = sp.Rational(1, 2**24)
"""Shortest segment (and distance of a bell's peak from its ends): float32's resolution of t near 1."""
MIN_BELL_WIDTH, MAX_BELL_WIDTH = sp.Rational(1, 2**100), sp.Integer(2**100)

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
RESERVED_WORDS = frozenset(
    "name description let bounds extinction continuous constant linear bell random expr tail "
    "at width every increasing decreasing".split()
)

ShapeKind = Literal["constant", "linear", "bell", "random", "expr", "tail"]


@dataclass(frozen=True)
class Piece:
    """One smooth piece of alpha(t) on [start, end]: a segment, or half of a bell."""

    expr: sp.Expr
    start: sp.Rational
    end: sp.Rational
    label: str


@dataclass(frozen=True)
class RandomDraws:
    """A random segment: alpha = low + (high - low) * u[k], u[k] ~ U[0, 1), k = bin of t."""

    low: sp.Expr
    high: sp.Expr
    every: sp.Rational
    count: int
    draw: sp.Function


@dataclass(frozen=True)
class BellParams:
    start: sp.Expr
    peak: sp.Expr
    peak_at: sp.Rational
    end: sp.Expr
    width: sp.Expr


@dataclass(frozen=True)
class SymbolicSegment:
    """A segment of the schedule, exact: its interval [start, end) and its pieces."""

    index: int
    kind: ShapeKind
    start: sp.Rational
    end: sp.Rational
    pieces: tuple[Piece, ...]
    monotone: Literal["increasing", "decreasing"] | None
    span: Span
    random: RandomDraws | None = None
    bell: BellParams | None = None

    @property
    def expr(self) -> sp.Expr:
        """alpha(t) on this segment as one sympy expression (Piecewise for a bell)."""
        if len(self.pieces) == 1:
            return self.pieces[0].expr
        return sp.Piecewise(*[(p.expr, T < p.end) for p in self.pieces[:-1]], (self.pieces[-1].expr, True))

    def describe_range(self) -> str:
        return f"{percent(self.start)} .. {percent(self.end)}"


@dataclass(frozen=True)
class SymbolicProgram:
    name: str | None
    description: str | None
    segments: tuple[SymbolicSegment, ...]
    bounds: tuple[sp.Expr, sp.Expr, Span] | None
    extinction: sp.Expr
    extinction_span: Span | None
    continuous: bool

    @property
    def piecewise(self) -> sp.Piecewise:
        """alpha(t) on [0, 1] as one sympy Piecewise (random draws appear as functions)."""
        parts = [(s.expr, T < s.end) for s in self.segments[:-1]]
        parts.append((self.segments[-1].expr, True))
        return sp.Piecewise(*parts)


def percent(value: sp.Expr | Fraction | float) -> str:
    """Format a fraction of the run as a percentage: 9/10 -> '90%'."""
    number = float(value) * 100
    whole = math.isclose(number, round(number), abs_tol=1e-9) and (number == 0 or abs(number) >= 1e-6)
    text = str(round(number)) if whole else f"{number:.6g}"
    return f"{text}%"


def number_text(value: sp.Expr) -> str:
    """Short decimal text of an exact real number."""
    return f"{float(value):.6g}"


class _Builder:
    """Builds sympy expressions from syntax-tree expressions under a scope of names."""

    def __init__(self) -> None:
        self.constants: dict[str, sp.Expr] = dict(CONSTANTS)

    def define(self, let: ast.Let) -> None:
        if let.name in RESERVED_WORDS:
            raise ScheduleError(
                f"`{let.name}` is a reserved word",
                span=let.span,
                hint="choose another name for this constant; reserved: " + ", ".join(sorted(RESERVED_WORDS)),
            )
        if let.name in self.constants or let.name in FUNCTIONS or let.name in ("t", "u"):
            what = "a built-in name" if let.name not in self.constants or let.name in CONSTANTS else "already defined"
            raise ScheduleError(
                f"`{let.name}` is {what}",
                span=let.span,
                hint="choose another name for this constant",
            )
        self.constants[let.name] = self.constant(let.value, what=f"`let {let.name}`")

    def constant(self, node: ast.Expr, *, what: str) -> sp.Expr:
        """A constant real number (no t): the value of a let, a position, an alpha level."""
        return _finite_real(self.build(node, variables={}), node, what)

    def build(self, node: ast.Expr, variables: dict[str, sp.Expr]) -> sp.Expr:
        if isinstance(node, ast.Number):
            return sp.Rational(node.value.numerator, node.value.denominator)
        if isinstance(node, ast.Name):
            if node.id in variables:
                return variables[node.id]
            if node.id in self.constants:
                return self.constants[node.id]
            raise self._unknown_name(node, variables)
        if isinstance(node, ast.Unary):
            operand = self.build(node.operand, variables)
            if node.op == "-":
                return -operand
            if node.op == "%":
                return operand / 100
            return operand
        if isinstance(node, ast.Binary):
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
        if isinstance(node, ast.Call):
            return self._call(node, variables)
        raise TypeError(f"unknown expression node {node!r}")

    def _call(self, node: ast.Call, variables: dict[str, sp.Expr]) -> sp.Expr:
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

    def _unknown_name(self, node: ast.Name, variables: dict[str, sp.Expr]) -> ScheduleError:
        known = list(self.constants) + list(variables)
        close = difflib.get_close_matches(node.id, known, n=1)
        if node.id in ("t", "u"):
            hint = f"`{node.id}` is only defined inside an `expr` segment"
        elif node.id in RESERVED_WORDS:
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


def _span(node: ast.Expr) -> Span:
    return node.span


def _power(base: sp.Expr, exponent: sp.Expr, node: ast.Binary) -> sp.Expr:
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


def _finite_real(value: sp.Expr, node: ast.Expr, what: str) -> sp.Expr:
    try:
        number = complex(value.evalf(30))
    except (TypeError, ValueError):
        number = complex(math.nan)
    if value.is_real and value.is_finite and not math.isfinite(number.real):
        raise ScheduleError(
            f"{what} is {sp.N(value, 3)}, out of range",
            span=_span(node),
            hint="values must stay below about 1e300 in size; alpha is a modest factor like 1.5",
        )
    if value.has(sp.zoo, sp.nan, sp.oo, -sp.oo) or not math.isfinite(number.real) or abs(number.imag) > 0:
        raise ScheduleError(
            f"{what} is not a finite real number (it is {value})",
            span=_span(node),
            hint="check for a log or square root of a negative number, or a division by zero",
        )
    if abs(number.real) > 1e300:
        raise ScheduleError(f"{what} is out of range ({number.real:.3g})", span=_span(node), hint="use a modest value")
    return value


def _position(builder: _Builder, node: ast.Expr, what: str) -> sp.Rational:
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


def _shape_kind(shape: ast.Shape) -> ShapeKind:
    return {
        ast.Constant: "constant",
        ast.Linear: "linear",
        ast.Bell: "bell",
        ast.Random: "random",
        ast.Expression: "expr",
        ast.Tail: "tail",
    }[type(shape)]  # type: ignore[return-value]


def _gaussian(t: sp.Expr, centre: sp.Expr, width: sp.Expr) -> sp.Expr:
    return sp.exp(-((t - centre) ** 2) / (2 * width**2))


def bell_half(a: sp.Expr, p: sp.Expr, m: sp.Expr, w: sp.Expr, x: sp.Expr, t: sp.Expr = T) -> sp.Expr:
    """Half a bell: equals `a` at t = x and `p` at t = m, Gaussian-shaped in between."""
    g_x = _gaussian(x, m, w)
    return a + (p - a) * (_gaussian(t, m, w) - g_x) / (1 - g_x)


def _segment(builder: _Builder, index: int, node: ast.Segment) -> SymbolicSegment:
    label = f"segment {index + 1}"
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
    shape = node.shape
    kind = _shape_kind(shape)

    def value(expr: ast.Expr, what: str) -> sp.Expr:
        return builder.constant(expr, what=f"the {what} of {label}")

    common = dict(index=index, kind=kind, start=start, end=end, monotone=node.monotone, span=node.span)
    if isinstance(shape, ast.Tail):
        piece = Piece(sp.Integer(1), start, end, "tail")
        return SymbolicSegment(pieces=(piece,), **common)
    if isinstance(shape, ast.Constant):
        piece = Piece(value(shape.value, "value"), start, end, "constant")
        return SymbolicSegment(pieces=(piece,), **common)
    if isinstance(shape, ast.Linear):
        a, b = value(shape.start, "start value"), value(shape.end, "end value")
        expr = a + (b - a) * (T - start) / (end - start)
        return SymbolicSegment(pieces=(Piece(sp.expand(expr), start, end, "linear"),), **common)
    if isinstance(shape, ast.Expression):
        variables = {"t": T, "u": (T - start) / (end - start)}
        expr = builder.build(shape.body, variables)
        return SymbolicSegment(pieces=(Piece(expr, start, end, "expr"),), **common)
    if isinstance(shape, ast.Bell):
        a, p, z = value(shape.start, "start value"), value(shape.peak, "peak"), value(shape.end, "end value")
        m = _position(builder, shape.peak_at, f"the peak position of {label}")
        if not start < m < end:
            raise ScheduleError(
                f"the peak of {label} is at {percent(m)}, outside the segment {percent(start)} .. {percent(end)}",
                span=shape.peak_at.span,
                hint="put the peak strictly inside the segment",
            )
        if min(m - start, end - m) < MIN_SEGMENT:
            raise ScheduleError(
                f"the peak of {label} at {percent(m)} is too close to the segment's end",
                span=shape.peak_at.span,
                hint="progress t is a 32-bit float; keep the peak at least 1e-5% of the run inside the segment",
            )
        if shape.width is None:
            w = (end - start) / 4
        else:
            w = value(shape.width, "width")
            if not w > 0:
                raise ScheduleError(
                    f"the width of {label} must be positive, not {number_text(w)}",
                    span=shape.width.span,
                    hint="the width is a fraction of the run, e.g. `width 15%`",
                )
            if not MIN_BELL_WIDTH <= w <= MAX_BELL_WIDTH:
                raise ScheduleError(
                    f"the width of {label} is {number_text(w)}, outside 1e-30 .. 1e30",
                    span=shape.width.span,
                    hint="the width is a fraction of the run, e.g. `width 15%`; far narrower is a spike no "
                    "phase sees, far wider is the same as a parabola",
                )
        pieces = (
            Piece(bell_half(a, p, m, w, start), start, m, "bell to peak"),
            Piece(bell_half(z, p, m, w, end), m, end, "bell from peak"),
        )
        return SymbolicSegment(pieces=pieces, bell=BellParams(a, p, m, z, w), **common)
    assert isinstance(shape, ast.Random)
    low, high = value(shape.low, "low end"), value(shape.high, "high end")
    if high < low:
        raise ScheduleError(
            f"the range of {label} is reversed: {number_text(low)} .. {number_text(high)}",
            span=shape.low.span,
            hint=f"write `random {number_text(high)} .. {number_text(low)}`",
        )
    if shape.every is None:
        every = DEFAULT_RANDOM_EVERY
    else:
        every = _position(builder, shape.every, f"the resolution of {label}")
        if every <= 0:
            raise ScheduleError(
                f"the resolution of {label} must be positive",
                span=shape.every.span,
                hint="`every 1%` draws a new alpha every 1% of the run",
            )
    count = math.ceil(Fraction(int((end - start).p), int((end - start).q)) / Fraction(int(every.p), int(every.q)))
    if count > MAX_RANDOM_DRAWS:
        raise ScheduleError(
            f"{label} would need {count} random draws",
            span=shape.every.span if shape.every is not None else node.span,
            hint=f"use a coarser resolution; at most {MAX_RANDOM_DRAWS} draws per segment",
        )
    draw = sp.Function(f"u_{index + 1}")
    expr = low + (high - low) * draw(sp.floor((T - start) / every))
    return SymbolicSegment(
        pieces=(Piece(expr, start, end, "random"),),
        random=RandomDraws(low, high, every, count, draw),
        **common,
    )


def compile_program(program: ast.Program) -> SymbolicProgram:
    """Build the exact sympy form of a parsed program; raise ScheduleError on bad values."""
    builder = _Builder()
    for let in program.lets:
        builder.define(let)
    if not program.segments:
        raise ScheduleError(
            "the schedule has no segments",
            span=Span(1, 1),
            hint="add segments covering 0%..100%, e.g. `0% .. 90%: linear 1.5 -> 1` and `90% .. 100%: tail`",
        )
    if len(program.segments) > MAX_SEGMENTS:
        raise ScheduleError(
            f"the schedule has {len(program.segments)} segments, more than {MAX_SEGMENTS}",
            span=program.segments[MAX_SEGMENTS].span,
            hint=f"a schedule has at most {MAX_SEGMENTS} segments; for many values use "
            "`random LOW .. HIGH every STEP`, or an `expr` segment",
        )
    segments = tuple(_segment(builder, i, s) for i, s in enumerate(program.segments))
    draws = 0
    for segment in segments:
        draws += segment.random.count if segment.random is not None else 0
        if draws > MAX_RANDOM_DRAWS:
            raise ScheduleError(
                f"the random segments need {draws} draws or more, more than {MAX_RANDOM_DRAWS} in all",
                span=segment.span,
                hint="use coarser resolutions (`every 1%`) or fewer random segments",
            )
    bounds = None
    if program.bounds is not None:
        low = builder.constant(program.bounds.low, what="the lower bound")
        high = builder.constant(program.bounds.high, what="the upper bound")
        if high < low:
            raise ScheduleError(
                f"bounds are reversed: {number_text(low)} .. {number_text(high)}",
                span=program.bounds.span,
                hint=f"write `bounds {number_text(high)} .. {number_text(low)}`",
            )
        bounds = (low, high, program.bounds.span)
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
        segments=segments,
        bounds=bounds,
        extinction=extinction,
        extinction_span=extinction_span,
        continuous=program.continuous,
    )
