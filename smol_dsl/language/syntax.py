"""Text -> typed syntax tree: the Lark parser, its Transformer, and friendly syntax errors."""

from __future__ import annotations

import difflib
import re
import sys
import unicodedata
from fractions import Fraction
from functools import lru_cache
from typing import Any

from lark import Token, Transformer, Tree, v_args
from lark.exceptions import (
    UnexpectedCharacters,
    UnexpectedEOF,
    UnexpectedInput,
    UnexpectedToken,
    VisitError,
)

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language import shapes, tree
from smol_dsl.language.channels import CHANNEL_KINDS, GEAR, Channel
from smol_dsl.language.grammar import grammar_text, parser

MAX_SOURCE_CHARS = 1_000_000
MAX_EXPONENT_DIGITS = 400  # literals beyond 1e±400 are out of float64 range anyway
MAX_NESTING = 100
"""Deepest expression: brackets, calls, and every operator of a chain (`a + b + c` is 2) count."""


FIRST_LINES = ("", "continuous\n", "\ncontinuous\n")
"""What goes before the examples of channel and final lines: a parser state includes the depth
of its stack, which differs on the first statement, on later ones, and after leading blank lines."""

CHANNEL_LINE_HINT = (
    "a channel line is `channel KIND` or `channel KIND[TARGET, ...]`, e.g. `channel mass` or "
    "`channel gear[left_leg]`; the kinds are " + ", ".join(CHANNEL_KINDS)
)


def _example_hints() -> dict[str, list[str]]:
    """Hints for common mistakes, found by Lark's example matching: each hint lists a few
    wrong lines that fail the same way. Each shape's unit gives its own; the first match wins."""
    return {
        "a segment is written `START .. END: SHAPE`, e.g. `0% .. 90%: linear 1.5 -> 1`": [
            "0% .. 90% linear 1 -> 2",
            "0% .. 90% constant 1",
            "0% .. 90% tail",
        ],
        "write a range of the run as `START .. END`, e.g. `0% .. 90%`": [
            "0% - 90%: tail",
            "0% 90%: tail",
            "0% to 90%: tail",
        ],
        **{shape.syntax_hint: list(shape.syntax_mistakes) for shape in shapes.units() if shape.syntax_hint},
        "a range is written `LOW .. HIGH`, e.g. `bounds 0.5 .. 1.5`": [
            "bounds 1 2",
            "bounds 1 -> 2",
        ],
        "`let` binds a name to a constant, e.g. `let peak = 1.4`": [
            "let peak 1.4",
            "let = 1.4",
            "let 1 = 2",
        ],
        CHANNEL_LINE_HINT: [
            first + line
            for first in FIRST_LINES
            for line in (
                "channel",
                "channel\n",
                "channel 1",
                "channel gear left_leg",
                "channel gear[left_leg",
                "channel gear[left_leg\n",
                "channel gear[left_leg,]",
                "channel gear[left_leg right_leg]",
                "channel gear[1]",
                "channel gear(left_leg)",
            )
        ],
        "`final` gives the channel's value over its tail, e.g. `final 0.5`": [
            first + line for first in FIRST_LINES for line in ("final", "final\n")
        ],
        'strings are written in double quotes, e.g. `name "SMOL"`': [
            "name SMOL",
            "description hello",
        ],
        "the segment kinds are " + ", ".join(shapes.keywords()): [
            "0% .. 90%: 1",
            "0% .. 90%: step 1",
            "0% .. 90%: lineal 1 -> 2",
        ],
        "one statement per line; a segment may be followed only by `increasing` or `decreasing`": [
            "0% .. 90%: constant 1 0% .. 100%: tail",
            "0% .. 90%: linear 1 -> 2 monotone",
            "0% .. 90%: tail tail",
        ],
    }


_TERMINAL_WORDS = {
    "NUMBER": "a number",
    "NAME": "a name",
    "STRING": 'a "quoted string"',
    "_NL": "the end of the line",
    "$END": "the end of the file",
    "MONOTONE": "`increasing` or `decreasing`",
}


def _span_of_token(token: Token) -> Span:
    return Span(token.line or 1, token.column or 1, max(1, len(str(token))))


def _span_of_meta(meta: Any) -> Span:
    if getattr(meta, "empty", True):
        return Span(1, 1)
    if meta.line == meta.end_line:
        length = meta.end_column - meta.column
    else:
        length = 1 << 16  # runs to the end of the line; the excerpt clips it
    return Span(meta.line, meta.column, max(1, length))


FLOAT_MAX = Fraction(sys.float_info.max)
FLOAT_MIN = Fraction(sys.float_info.min)


def _number(token: Token) -> tree.Number:
    """A literal as an exact Fraction; it must be 0 or a normal float64 magnitude."""
    text = str(token)
    span = _span_of_token(token)
    out_of_range = ScheduleError(
        f"number {text} is out of range",
        span=span,
        hint="numbers must be 0 or between about 2.2e-308 and 1.8e308 (64-bit floats); "
        "alpha is a modest factor like 1.5",
    )
    mantissa, _, exponent = text.lower().partition("e")
    huge_exponent = exponent and abs(int(exponent)) > MAX_EXPONENT_DIGITS
    if huge_exponent and mantissa.strip("0.") != "":  # refuse before building a huge integer
        raise out_of_range
    value = Fraction(text)
    if value != 0 and not FLOAT_MIN <= value <= FLOAT_MAX:
        raise out_of_range
    return tree.Number(value, text, span)


@v_args(meta=True)
class _ToTree(Transformer):
    """Turns Lark's parse tree into `smol_dsl.language.tree` nodes, one method per grammar rule."""

    # expressions ------------------------------------------------------------
    def number(self, meta: Any, children: list[Token]) -> tree.Number:
        return _number(children[0])

    def name(self, meta: Any, children: list[Token]) -> tree.Name:
        return tree.Name(str(children[0]), _span_of_token(children[0]))

    def call(self, meta: Any, children: list[Any]) -> tree.Call:
        function, *args = children
        return tree.Call(str(function), tuple(a for a in args if a is not None), _span_of_meta(meta))

    def _binary(op: str):  # noqa: N805 - a method factory used at class creation
        def build(self: _ToTree, meta: Any, children: list[Any]) -> tree.Binary:
            return tree.Binary(op, children[0], children[1], _span_of_meta(meta))  # type: ignore[arg-type]

        return build

    add = _binary("+")
    sub = _binary("-")
    mul = _binary("*")
    div = _binary("/")
    pow = _binary("**")

    def neg(self, meta: Any, children: list[Any]) -> tree.Unary:
        return tree.Unary("-", children[0], _span_of_meta(meta))

    def pos(self, meta: Any, children: list[Any]) -> tree.Unary:
        return tree.Unary("+", children[0], _span_of_meta(meta))

    def percent(self, meta: Any, children: list[Any]) -> tree.Unary:
        return tree.Unary("%", children[0], _span_of_meta(meta))

    # shapes: every KEYWORD_shape rule ---------------------------------------
    def __default__(self, data: Any, children: list[Any], meta: Any) -> Any:
        if str(data).endswith("_shape"):
            return tree.SegmentShape(shapes.unit(str(data).removesuffix("_shape")), tuple(children))
        return super().__default__(data, children, meta)

    # statements -------------------------------------------------------------
    def segment(self, meta: Any, children: list[Any]) -> tree.Segment:
        start, end, shape, monotone = children
        return tree.Segment(
            start=start,
            end=end,
            shape=shape,
            monotone=str(monotone) if monotone is not None else None,  # type: ignore[arg-type]
            span=_span_of_meta(meta),
        )

    def name_decl(self, meta: Any, children: list[Token]) -> tuple[str, Any, Span]:
        return ("name", str(children[0])[1:-1], _span_of_meta(meta))

    def description_decl(self, meta: Any, children: list[Token]) -> tuple[str, Any, Span]:
        return ("description", str(children[0])[1:-1], _span_of_meta(meta))

    def let_decl(self, meta: Any, children: list[Any]) -> tree.Let:
        return tree.Let(str(children[0]), children[1], _span_of_meta(meta))

    def bounds_decl(self, meta: Any, children: list[Any]) -> tree.Bounds:
        return tree.Bounds(children[0], children[1], _span_of_meta(meta))

    def extinction_decl(self, meta: Any, children: list[Any]) -> tree.Extinction:
        return tree.Extinction(children[0], _span_of_meta(meta))

    def continuous_decl(self, meta: Any, children: list[Any]) -> tuple[str, Any, Span]:
        return ("continuous", True, _span_of_meta(meta))

    def final_decl(self, meta: Any, children: list[Any]) -> tree.Final:
        return tree.Final(children[0], _span_of_meta(meta))

    def channel_targets(self, meta: Any, children: list[Any]) -> tuple[Span, list[Token]]:
        return _span_of_meta(meta), [child for child in children if child is not None]

    def channel_decl(self, meta: Any, children: list[Any]) -> tree.ChannelLine:
        kind, targets = children
        return _channel_line(kind, targets, _span_of_meta(meta))

    def start(self, meta: Any, children: list[Any]) -> tree.Program:
        return _assemble(children)


def _channel_line(kind: Token, targets: tuple[Span, list[Token]] | None, span: Span) -> tree.ChannelLine:
    """A `channel` line, checked: a known kind, and targets only where the kind takes them,
    none empty or repeated."""
    kind_span = _span_of_token(kind)
    if str(kind) not in CHANNEL_KINDS:
        close = difflib.get_close_matches(str(kind), list(CHANNEL_KINDS), n=1)
        raise ScheduleError(
            f"unknown channel `{kind}`",
            span=kind_span,
            hint=(f"did you mean `{close[0]}`? " if close else "") + "the channels are " + channel_kinds_text(),
        )
    if targets is None:
        return tree.ChannelLine(Channel(str(kind)), span, kind_span)
    targets_span, names = targets
    part = CHANNEL_KINDS[str(kind)].part
    if part is None:
        raise ScheduleError(
            f"`{kind}` takes no targets: it scales {CHANNEL_KINDS[str(kind)].scales}",
            span=targets_span,
            hint=f"write `channel {kind}`; only gear (actuators) and mass (links) are scaled part by part",
        )
    if not names:
        raise ScheduleError(
            f"`{kind}[]` names no {part}",
            span=targets_span,
            hint=f"name {part} or groups of the task, e.g. `{kind}[left_leg]`, "
            f"or write `channel {kind}` for all of them",
        )
    seen: set[str] = set()
    for name in names:
        if str(name) in seen:
            raise ScheduleError(
                f"`{name}` is named twice in `{kind}[...]`",
                span=_span_of_token(name),
                hint="name each target once",
            )
        seen.add(str(name))
    channel = Channel(str(kind), tuple(str(name) for name in names))
    return tree.ChannelLine(channel, span, kind_span, tuple(_span_of_token(n) for n in names), targets_span)


def channel_kinds_text() -> str:
    """`` `gear`: the actuators' gear (their strength); `mass`: ... ``: the kinds, for hints."""
    return "; ".join(f"`{keyword}`: {kind.scales}" for keyword, kind in CHANNEL_KINDS.items())


def _same_channel(a: Channel, b: Channel) -> bool:
    """Whether two channel lines declare the same channel (targets in any order)."""
    return a.kind == b.kind and set(a.targets) == set(b.targets)


class _SectionBuilder:
    """One channel's statements as they are read: its directives given once, its segments."""

    def __init__(self, line: tree.ChannelLine | None, first: Span) -> None:
        self.line = line
        self.channel = line.channel if line is not None else GEAR
        self.first = first  # its first line: the `channel` line, or the implicit section's first statement
        self.fields: dict[str, Any] = {}
        self.seen: dict[str, Span] = {}
        self.segments: list[tree.Segment] = []

    def once(self, key: str, span: Span, value: Any) -> None:
        if key in self.seen:
            owner = "a schedule" if self.line is None else f"channel {self.channel.name}"
            raise ScheduleError(
                f"`{key}` is given twice (first on line {self.seen[key].line})",
                span=span,
                hint=f"{owner} has at most one `{key}` line; delete one of them",
            )
        self.seen[key] = span
        self.fields[key] = value

    def section(self) -> tree.Section:
        return tree.Section(self.channel, self.line, segments=tuple(self.segments), **self.fields)


def _assemble(statements: list[Any]) -> tree.Program:
    """Collect statements into a Program: file-level directives (given once), lets, and each
    channel's section; lines before the first `channel` line are the gear channel's."""
    fields: dict[str, Any] = {}
    seen: dict[str, Span] = {}
    lets: list[tree.Let] = []
    sections: list[_SectionBuilder] = []

    def once(key: str, span: Span, value: Any) -> None:
        if key in seen:
            raise ScheduleError(
                f"`{key}` is given twice (first on line {seen[key].line})",
                span=span,
                hint=f"a schedule has at most one `{key}` line; delete one of them",
            )
        seen[key] = span
        fields[key] = value

    def current(span: Span) -> _SectionBuilder:
        if not sections:
            sections.append(_SectionBuilder(None, span))
        return sections[-1]

    for statement in statements:
        if statement is None:
            continue
        if isinstance(statement, tree.ChannelLine):
            _check_new_channel(statement, sections)
            sections.append(_SectionBuilder(statement, statement.span))
        elif isinstance(statement, tree.Segment):
            current(statement.span).segments.append(statement)
        elif isinstance(statement, tree.Let):
            lets.append(statement)
        elif isinstance(statement, tree.Bounds):
            current(statement.span).once("bounds", statement.span, statement)
        elif isinstance(statement, tree.Final):
            current(statement.span).once("final", statement.span, statement)
        elif isinstance(statement, tree.Extinction):
            once("extinction", statement.span, statement)
        else:
            key, value, span = statement
            if key == "continuous":
                current(span).once(key, span, value)
            else:
                once(key, span, value)
    if sections and sections[0].line is None and not sections[0].segments and len(sections) > 1:
        implicit = sections[0]
        key, span = min(implicit.seen.items(), key=lambda item: (item[1].line, item[1].column))
        raise ScheduleError(
            f"`{key}` comes before the first `channel` line, so it is the gear channel's, which has no segments",
            span=span,
            hint="move it below the `channel` line of the channel it is for",
        )
    built = [section.section() for section in sections] or [tree.Section(GEAR)]
    return tree.Program(lets=tuple(lets), sections=tuple(built), **fields)


def _check_new_channel(line: tree.ChannelLine, sections: list[_SectionBuilder]) -> None:
    """Refuse a channel declared a second time (the implicit gear channel included)."""
    for section in sections:
        if not _same_channel(section.channel, line.channel):
            continue
        if section.line is None:
            raise ScheduleError(
                f"`channel {line.channel.name}` is given twice: the lines before the first `channel` line "
                f"(from line {section.first.line}) are the gear channel's",
                span=line.span,
                hint="move those lines below this `channel gear` line, or delete one of the two",
            )
        raise ScheduleError(
            f"`channel {line.channel.name}` is given twice (first on line {section.first.line})",
            span=line.span,
            hint="a file declares each channel once: merge the two sections",
        )


def _expected_in_words(expected: set[str]) -> str:
    terminals = {t.name: t for t in parser().terminals}
    words = set()
    for name in expected:
        if name in _TERMINAL_WORDS:
            words.add(_TERMINAL_WORDS[name])
        elif name in terminals and terminals[name].pattern.type == "str":
            words.add(f"`{terminals[name].pattern.value}`")
        else:
            words.add(name.lower())
    ordered = sorted(words)
    if len(ordered) > 8:
        ordered = [*ordered[:8], "..."]
    return ", ".join(ordered)


def _example_errors() -> list[tuple[str, UnexpectedInput]]:
    return _example_errors_of(grammar_text())


@lru_cache(maxsize=8)
def _example_errors_of(grammar: str) -> list[tuple[str, UnexpectedInput]]:
    errors = []
    for label, examples in _example_hints().items():
        for example in examples:
            try:
                parser().parse(example)
            except UnexpectedInput as error:
                errors.append((label, error))
    return errors


def _token_type(error: UnexpectedInput) -> str | None:
    token = getattr(error, "token", None)
    return token.type if token is not None else None


def _example_hint(error: UnexpectedInput) -> str | None:
    """The hint of the known mistake that fails in the same parser state, if any.

    The idea of Lark's `match_examples`, reimplemented: Lark 1.3.1's version can fail
    while formatting a debug message, and ours prefers an example whose unexpected token
    has the same type.
    """
    fallback = None
    for label, known in _example_errors():
        if type(known) is not type(error) or known.state != error.state:
            continue
        if getattr(known, "accepts", None) != getattr(error, "accepts", None):
            continue
        if _token_type(known) == _token_type(error):
            return label
        fallback = fallback or label
    return fallback


def _syntax_error(error: UnexpectedInput, text: str) -> ScheduleError:
    line = getattr(error, "line", None) or 1
    column = getattr(error, "column", None) or 1
    at_end = isinstance(error, UnexpectedEOF) or (isinstance(error, UnexpectedToken) and error.token.type == "$END")
    if line < 1 or at_end:  # point just past the last character
        lines = text.rstrip("\n").split("\n")
        line, column = len(lines), len(lines[-1].rstrip("\r")) + 1
    example = _example_hint(error)
    if isinstance(error, UnexpectedCharacters):
        char = text[error.pos_in_stream] if error.pos_in_stream < len(text) else "?"
        message = f"unexpected character {char!r}"
        hint = example
        if not char.isascii() and char.isprintable():
            hint = _non_ascii_hint(char)
        elif char == "^":
            hint = "powers are written with `**`, e.g. `t**2`"
        elif char in "[]{}":
            hint = "group with round brackets `( )`"
        elif char == "." and error.pos_in_stream > 0 and text[error.pos_in_stream - 1].isdigit():
            hint = "a number needs digits after its decimal point (`1.0`, not `1.`); ranges are written `..`"
        elif char == '"':
            hint = 'a string ends with `"` on the same line, e.g. `name "SMOL"`'
        elif char == "'":
            hint = 'strings are written in double quotes, e.g. `name "SMOL"`'
        if hint is None:
            hint = f"expected {_expected_in_words(set(error.allowed or ()))}"
        return ScheduleError(message, span=Span(line, column), hint=hint)
    if isinstance(error, UnexpectedToken):
        token = error.token
        if token.type == "$END":
            message = "unexpected end of file"
        elif token.type == "_NL":
            message = "unexpected end of line"
        else:
            message = f"unexpected {str(token)!r}"
            if token.type == "NAME":
                kinds = shapes.keywords()
                close = difflib.get_close_matches(str(token), kinds, n=1)
                if close and (error.expected & {kind.upper() for kind in kinds}):
                    example = f"did you mean `{close[0]}`? The segment kinds are " + ", ".join(kinds)
        if token.type in ("LSQB", "RSQB") and example != CHANNEL_LINE_HINT:  # in an expression
            message = f"unexpected character {str(token)!r}"
            example = "group with round brackets `( )`"
        if example is None and "_NL" in error.expected and token.type != "$END":
            example = "one statement per line: end the line before this, or join it to the expression with an operator"
        hint = example or f"expected {_expected_in_words(set(error.expected))}"
        length = len(str(token)) if token.type not in {"$END", "_NL"} else 1
        return ScheduleError(message, span=Span(line, column, max(1, length)), hint=hint)
    if isinstance(error, UnexpectedEOF):
        hint = example or f"expected {_expected_in_words(set(error.expected))}"
        return ScheduleError("unexpected end of file", span=Span(line, column), hint=hint)
    return ScheduleError(str(error), span=Span(line, column))


_LOOKALIKES = {"−": "-", "–": "-", "—": "-", "×": "*", "·": "*", "÷": "/", "…": "..", "“": '"', "”": '"'}


def _non_ascii_hint(char: str) -> str:
    name = unicodedata.name(char, f"U+{ord(char):04X}")
    what = f"{char!r} is {name} (U+{ord(char):04X})"
    if unicodedata.category(char) == "Nd" or char.isdigit():
        return f"{what}: numbers are written with the ASCII digits 0-9 only"
    if char in _LOOKALIKES:
        return f"{what}: write the ASCII `{_LOOKALIKES[char]}`"
    return f"{what}: outside strings and comments a .sched file is ASCII"


def _check_nesting(parsed: Tree) -> None:
    """Refuse expressions nested deeper than MAX_NESTING, before anything recursive sees them."""
    stack: list[tuple[Any, int]] = [(parsed, 0)]
    while stack:
        node, depth = stack.pop()
        if not isinstance(node, Tree):
            continue
        if depth > MAX_NESTING:
            raise ScheduleError(
                f"expression nested too deeply (more than {MAX_NESTING} levels)",
                span=_span_of_meta(node.meta),
                hint="brackets, function calls and each operator of a chain count as a level; "
                "split the expression with `let` constants",
            )
        stack.extend((child, depth + 1) for child in node.children)


_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def check_text(text: str) -> None:
    """Reject text that is not a plausible `.sched` file before parsing it."""
    if len(text) > MAX_SOURCE_CHARS:
        raise ScheduleError(
            f"file is too large ({len(text)} characters)",
            span=Span(1, 1),
            hint=f"a schedule is a few lines; the limit is {MAX_SOURCE_CHARS} characters",
        )
    bad = _CONTROL.search(text)
    if bad:
        before = text[: bad.start()]
        line = before.count("\n") + 1
        column = bad.start() - (before.rfind("\n") + 1) + 1
        raise ScheduleError(
            f"control character {bad.group()!r} in the text",
            span=Span(line, column),
            hint="a .sched file is plain UTF-8 text; is this a binary file?",
        )
    if not text.strip() or all(not line.split("#", 1)[0].strip() for line in text.split("\n")):
        raise ScheduleError(
            "empty schedule: the file has no statements",
            span=Span(1, 1),
            hint="a schedule needs segments covering 0%..100%, e.g.\n"
            "    0% .. 90%: linear 1.5 -> 1\n    90% .. 100%: tail",
        )


def parse_program(text: str) -> tree.Program:
    """Parse `.sched` text into a `Program`, or raise one `ScheduleError`."""
    check_text(text)
    try:
        parsed = parser().parse(text)
        _check_nesting(parsed)  # a located error for deep expressions, before the Transformer recurses
        return _ToTree().transform(parsed)
    except UnexpectedInput as error:
        raise _syntax_error(error, text) from None
    except VisitError as error:
        if isinstance(error.orig_exc, ScheduleError):
            raise error.orig_exc from None
        raise
    except RecursionError:
        raise ScheduleError(
            "expression nested too deeply",
            span=Span(1, 1),
            hint="split it with `let` constants",
        ) from None
