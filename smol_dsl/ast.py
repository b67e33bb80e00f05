"""The typed syntax tree of a `.sched` file, as the parser builds it.

Every node carries the `Span` of the text it came from, so that later stages (symbolic
compilation and verification) can point at the offending text.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from typing import Literal

from smol_dsl.errors import Span

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
class Constant:
    value: Expr


@dataclass(frozen=True)
class Linear:
    start: Expr
    end: Expr


@dataclass(frozen=True)
class Bell:
    start: Expr
    peak: Expr
    peak_at: Expr
    end: Expr
    width: Expr | None


@dataclass(frozen=True)
class Random:
    low: Expr
    high: Expr
    every: Expr | None


@dataclass(frozen=True)
class Expression:
    body: Expr


@dataclass(frozen=True)
class Tail:
    pass


Shape = Constant | Linear | Bell | Random | Expression | Tail


@dataclass(frozen=True)
class Segment:
    start: Expr
    end: Expr
    shape: Shape
    monotone: Literal["increasing", "decreasing"] | None
    span: Span
    kind_span: Span


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
