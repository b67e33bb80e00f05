"""The typed syntax tree of a `.sched` file, as the parser builds it.

Every node carries the `Span` of the text it came from, so that later stages (symbolic
compilation and verification) can point at the offending text.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from typing import TYPE_CHECKING, Literal

from smol_dsl.errors import Span

if TYPE_CHECKING:
    from smol_dsl.language.shapes import Shape

# ---------------------------------------------------------------- expressions


@dataclass(frozen=True)
class Number:
    value: Fraction
    text: str
    span: Span


@dataclass(frozen=True)
class Name:
    id: str
    span: Span


@dataclass(frozen=True)
class Call:
    function: str
    args: tuple[Expr, ...]
    span: Span


@dataclass(frozen=True)
class Unary:
    op: Literal["-", "+", "%"]
    operand: Expr
    span: Span


@dataclass(frozen=True)
class Binary:
    op: Literal["+", "-", "*", "/", "**"]
    left: Expr
    right: Expr
    span: Span


Expr = Number | Name | Call | Unary | Binary

# ---------------------------------------------------------------- segments


@dataclass(frozen=True)
class SegmentShape:
    """A segment's shape as written: its unit in the shape registry and the values of its
    grammar rule, in order (None for an optional value left out)."""

    unit: Shape
    args: tuple[Expr | None, ...]


@dataclass(frozen=True)
class Segment:
    start: Expr
    end: Expr
    shape: SegmentShape
    monotone: Literal["increasing", "decreasing"] | None
    span: Span


# ---------------------------------------------------------------- directives


@dataclass(frozen=True)
class Let:
    name: str
    value: Expr
    span: Span


@dataclass(frozen=True)
class Bounds:
    low: Expr
    high: Expr
    span: Span


@dataclass(frozen=True)
class Extinction:
    probability: Expr
    span: Span


@dataclass(frozen=True)
class Program:
    """A whole `.sched` file: its directives in order and its segments in order."""

    name: str | None = None
    description: str | None = None
    lets: tuple[Let, ...] = ()
    bounds: Bounds | None = None
    extinction: Extinction | None = None
    continuous: bool = False
    segments: tuple[Segment, ...] = field(default_factory=tuple)
