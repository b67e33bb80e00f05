"""The typed syntax tree of a `.sched` file.

The parser (`smol_dsl.language.syntax`) turns the text into statements, one node per line;
program assembly (`smol_dsl.language.assembly`) checks them and collects them into a
`Program` of channel `Section`s. Every node carries the `Span` of the text it came from, so
that later stages (symbolic compilation and verification) can point at the offending text.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    from smol_dsl.errors import Span
    from smol_dsl.language.channels import Channel
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
class Final:
    """`final V`: the channel's value over its tail (its body at the end of the run)."""

    value: Expr
    span: Span


@dataclass(frozen=True)
class StringDirective:
    """`name "..."` or `description "..."`: a file-level directive whose value is a string."""

    key: Literal["name", "description"]
    value: str
    """The string, without its quotes."""
    span: Span


@dataclass(frozen=True)
class Continuous:
    """`continuous`: the channel's joins must all be continuous."""

    span: Span


@dataclass(frozen=True)
class Targets:
    """The bracketed target list of a `channel` line, as written."""

    names: tuple[Name, ...]
    span: Span
    """The brackets included."""


@dataclass(frozen=True)
class ChannelDecl:
    """A `channel KIND[TARGETS]` line as written; assembly checks it into a `ChannelLine`."""

    kind: Name
    targets: Targets | None
    """None: no brackets."""
    span: Span


@dataclass(frozen=True)
class Comparison:
    """`LEFT OP RIGHT` in a pace condition."""

    op: Literal[">=", "<=", ">", "<"]
    left: Expr
    right: Expr
    span: Span


@dataclass(frozen=True)
class Logical:
    """`LEFT and RIGHT` or `LEFT or RIGHT` in a pace condition."""

    op: Literal["and", "or"]
    left: Condition
    right: Condition
    span: Span


Condition = Comparison | Logical


@dataclass(frozen=True)
class Pace:
    """`pace when CONDITION within N phases`: development moves on where the condition holds
    at a phase's end, or once the body has been held N phases."""

    condition: Condition
    within: Expr
    span: Span


Statement = Segment | Let | Bounds | Extinction | Final | StringDirective | Continuous | ChannelDecl | Pace
"""One line of a file, in the parser's output."""

# ---------------------------------------------------------------- the assembled program


@dataclass(frozen=True)
class ChannelLine:
    """A `channel KIND[TARGETS]` line, checked: the channel, and the spans of its parts."""

    channel: Channel
    span: Span
    """The whole line."""
    kind_span: Span
    written: tuple[str, ...] = ()
    """The targets in the order the line writes them (the channel holds them sorted)."""
    target_spans: tuple[Span, ...] = ()
    """One per target, in the order written."""
    targets_span: Span | None = None
    """The bracketed target list, brackets included."""

    @property
    def text(self) -> str:
        """The channel as the line writes it: `mass[torso, thigh]`."""
        kind = self.channel.kind
        return f"{kind}[{', '.join(self.written)}]" if self.written else kind


@dataclass(frozen=True)
class Section:
    """One channel's part of a file: its `channel` line (None: the implicit gear channel of
    the lines before any `channel` line) and its statements."""

    channel: Channel
    line: ChannelLine | None = None
    bounds: Bounds | None = None
    continuous: bool = False
    final: Final | None = None
    pace: Pace | None = None
    segments: tuple[Segment, ...] = ()


@dataclass(frozen=True)
class Program:
    """A whole `.sched` file: its file-level directives, and each channel's section in order."""

    name: str | None = None
    description: str | None = None
    lets: tuple[Let, ...] = ()
    extinction: Extinction | None = None
    pace: Pace | None = None
    """A `pace` line before the first `channel` line of a file with channels: every channel's
    without one of its own (in a file without `channel` lines, `pace` is the gear section's)."""
    sections: tuple[Section, ...] = field(default_factory=tuple)
