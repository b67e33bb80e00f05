"""The exact form of a schedule: the variable t, the pieces of alpha(t), segments, each
channel's curve, and programs.

Everything here is exact sympy. `smol_dsl.language.compiler` builds it from the syntax tree
(each segment's pieces come from its shape's unit in `smol_dsl.language.shapes`),
`smol_dsl.language.verify` proves facts about it, and `smol_dsl.language.schedule`
evaluates it in JAX.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import TYPE_CHECKING, Any, Literal

import sympy as sp

from smol_dsl.language.channels import GEAR, Channel

if TYPE_CHECKING:
    from smol_dsl.errors import Span
    from smol_dsl.language.pacing import Pacing
    from smol_dsl.language.shapes import Shape

T = sp.Symbol("t", real=True)
"""Training progress, 0 at the start of the run and 1 at its end."""

MIN_SEGMENT = sp.Rational(1, 2**24)
"""Shortest segment (and distance of a bell's peak from its ends): float32's resolution of t near 1."""
MAX_RANDOM_DRAWS = 1_000_000
"""Random draws of one segment, and of a whole schedule (all its segments together)."""


@dataclass(frozen=True)
class Piece:
    """One smooth piece of alpha(t) on [start, end]: a segment, or half of a bell.

    Its label names it in the certificate: the shape's keyword, or a part of the shape.
    """

    expr: sp.Expr
    start: sp.Rational
    end: sp.Rational
    label: str


@dataclass(frozen=True)
class Draws:
    """The uniform draws in [0, 1) of a segment: `count` of them, draw k for t in
    [start + k * every, start + (k + 1) * every); symbolically `function(k)`."""

    every: sp.Rational
    count: int
    function: sp.Function


@dataclass(frozen=True)
class SymbolicSegment:
    """A segment of the schedule, exact: its interval [start, end), its shape and its pieces."""

    index: int
    shape: Shape
    start: sp.Rational
    end: sp.Rational
    pieces: tuple[Piece, ...]
    monotone: Literal["increasing", "decreasing"] | None
    span: Span
    params: Any = None
    """What the shape's unit keeps for proving and evaluating it (e.g. a bell's peak)."""
    draws: Draws | None = None
    """The random draws alpha depends on, if any."""
    owner: str = ""
    """How messages name its channel after `segment N`: `` (a file of the gear channel alone) or ` of mass`."""
    quantity: str = "alpha"
    """How messages call its channel's value: `alpha` for plain gear, else the channel's name."""

    @property
    def kind(self) -> str:
        """The shape's keyword: `linear`, `bell`, ..."""
        return self.shape.keyword

    @property
    def expr(self) -> sp.Expr:
        """alpha(t) on this segment as one sympy expression (Piecewise for several pieces)."""
        if len(self.pieces) == 1:
            return self.pieces[0].expr
        return sp.Piecewise(*[(p.expr, T < p.end) for p in self.pieces[:-1]], (self.pieces[-1].expr, True))

    def value_at(self, where: Literal["start", "end"]) -> sp.Expr:
        """The exact value at its start (of its first piece) or its end (of its last)."""
        piece = self.pieces[0] if where == "start" else self.pieces[-1]
        return piece.expr.subs(T, self.start if where == "start" else self.end)

    def describe_range(self) -> str:
        return f"{percent(self.start)} .. {percent(self.end)}"

    def describe(self) -> str:
        """How messages name the segment: `segment 2 (0% .. 90%, linear)`."""
        return f"segment {self.index + 1}{self.owner} ({self.describe_range()}, {self.kind})"


@dataclass(frozen=True)
class ChannelPlace:
    """Where a channel is declared: its `channel` line and each target's text (for errors)."""

    span: Span
    target_spans: tuple[Span, ...] = ()
    written: tuple[str, ...] = ()
    """The targets in the order written, one per span."""


@dataclass(frozen=True)
class SymbolicCurve:
    """One channel's schedule, exact: its segments, declared bounds, `continuous` and final value."""

    channel: Channel
    segments: tuple[SymbolicSegment, ...]
    bounds: tuple[sp.Expr, sp.Expr, Span] | None = None
    continuous: bool = False
    final: sp.Expr = sp.S.One
    named: bool = False
    """Whether messages name the channel (a file of several channels, or not plain gear)."""
    place: ChannelPlace | None = None
    """Its `channel` line; None for the implicit gear channel of a file without one."""

    @property
    def quantity(self) -> str:
        """How messages call its value: `alpha` for plain gear, else the channel's name."""
        return self.channel.quantity

    @property
    def piecewise(self) -> sp.Piecewise:
        """Its value on [0, 1] as one sympy Piecewise (random draws appear as functions)."""
        parts = [(s.expr, T < s.end) for s in self.segments[:-1]]
        parts.append((self.segments[-1].expr, True))
        return sp.Piecewise(*parts)


@dataclass(frozen=True)
class SymbolicProgram:
    """A compiled file: its file-level directives and each declared channel's curve, in order."""

    name: str | None
    description: str | None
    curves: tuple[SymbolicCurve, ...]
    extinction: sp.Expr
    extinction_span: Span | None
    pacing: Pacing | None = None
    """The file's `pace` lines, compiled (None: every channel on the budget's clock)."""

    @property
    def channels(self) -> tuple[Channel, ...]:
        return tuple(curve.channel for curve in self.curves)

    def curve(self, channel: Channel = GEAR) -> SymbolicCurve | None:
        """The curve of a declared channel, or None."""
        return next((curve for curve in self.curves if curve.channel == channel), None)


def percent(value: sp.Expr | Fraction | float) -> str:
    """Format a fraction of the run as a percentage: 9/10 -> '90%'."""
    number = float(value) * 100
    whole = math.isclose(number, round(number), abs_tol=1e-9) and (number == 0 or abs(number) >= 1e-6)
    text = str(round(number)) if whole else f"{number:.6g}"
    return f"{text}%"


def number_text(value: sp.Expr) -> str:
    """Short decimal text of an exact real number."""
    return f"{float(value):.6g}"
