"""Statements -> `Program`: the file-level directives, the lets, and each channel's section.

The parser's statements come in file order (`smol_dsl.language.syntax`). Assembly checks each
`channel` line (a known kind; targets only where the kind takes them, none empty or
repeated), then collects the statements: a `channel` line opens its channel's section, and the
lines before the first `channel` line are the gear channel's. A directive is given at most
once where it belongs: `name`, `description` and `extinction` once per file, `bounds`,
`continuous`, `final` and `pace` once per section. A `pace` line before the first `channel`
line of a file with channels is the file's: it paces every channel without one of its own.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Sequence
from typing import Any

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language import tree
from smol_dsl.language.channels import CHANNEL_KINDS, GEAR, Channel
from smol_dsl.language.syntax import parse_statements
from smol_dsl.language.text import check_text


def parse_program(text: str) -> tree.Program:
    """Parse `.sched` text into a `Program`, or raise one `ScheduleError`: the text's checks,
    the parse into statements, and their assembly."""
    check_text(text)
    return assemble(parse_statements(text))


def assemble(statements: Sequence[tree.Statement]) -> tree.Program:
    """Collect a file's statements into a Program; raise ScheduleError on the first one that
    does not fit. Every `channel` line is checked before the statements are collected."""
    checked = [channel_line(s) if isinstance(s, tree.ChannelDecl) else s for s in statements]
    program = _Program()
    for statement in checked:
        _COLLECT[type(statement)](program, statement)
    return program.build()


def channel_line(decl: tree.ChannelDecl) -> tree.ChannelLine:
    """A `channel` line, checked: a known kind, and targets only where the kind takes them,
    none empty or repeated."""
    kind = decl.kind
    if kind.id not in CHANNEL_KINDS:
        close = difflib.get_close_matches(kind.id, list(CHANNEL_KINDS), n=1)
        raise ScheduleError(
            f"unknown channel `{kind.id}`",
            span=kind.span,
            hint=(f"did you mean `{close[0]}`? " if close else "") + "the channels are " + channel_kinds_text(),
        )
    if decl.targets is None:
        return tree.ChannelLine(Channel(kind.id), decl.span, kind.span)
    targets = decl.targets
    part = CHANNEL_KINDS[kind.id].part
    if part is None:
        raise ScheduleError(
            f"`{kind.id}` takes no targets: it scales {CHANNEL_KINDS[kind.id].scales}",
            span=targets.span,
            hint=f"write `channel {kind.id}`; only gear (actuators) and mass (links) are scaled part by part",
        )
    if not targets.names:
        raise ScheduleError(
            f"`{kind.id}[]` names no {part}",
            span=targets.span,
            hint=f"name {part} or groups of the task, e.g. `{kind.id}[left_leg]`, "
            f"or write `channel {kind.id}` for all of them",
        )
    seen: set[str] = set()
    for name in targets.names:
        if name.id in seen:
            raise ScheduleError(
                f"`{name.id}` is named twice in `{kind.id}[...]`",
                span=name.span,
                hint="name each target once",
            )
        seen.add(name.id)
    written = tuple(name.id for name in targets.names)
    spans = tuple(name.span for name in targets.names)
    return tree.ChannelLine(Channel(kind.id, written), decl.span, kind.span, written, spans, targets.span)


def channel_kinds_text() -> str:
    """`` `gear`: the actuators' gear (their strength); `mass`: ... ``: the kinds, for hints."""
    return "; ".join(f"`{keyword}`: {kind.scales}" for keyword, kind in CHANNEL_KINDS.items())


class _Directives:
    """The directives of one scope (the file, or one channel's section), each given at most once."""

    def __init__(self, owner: str) -> None:
        self.owner = owner  # `a schedule` or `channel mass`, for the hint
        self.values: dict[str, Any] = {}
        self.seen: dict[str, Span] = {}

    def give(self, key: str, span: Span, value: Any) -> None:
        if key in self.seen:
            raise ScheduleError(
                f"`{key}` is given twice (first on line {self.seen[key].line})",
                span=span,
                hint=f"{self.owner} has at most one `{key}` line; delete one of them",
            )
        self.seen[key] = span
        self.values[key] = value


class _Section:
    """One channel's statements as they are read: its directives and its segments."""

    def __init__(self, line: tree.ChannelLine | None, first: Span) -> None:
        self.line = line
        self.channel = line.channel if line is not None else GEAR
        self.first = first  # its first line: the `channel` line, or the implicit section's first statement
        self.directives = _Directives("a schedule" if line is None else f"channel {self.channel.name}")
        self.segments: list[tree.Segment] = []

    def build(self) -> tree.Section:
        return tree.Section(self.channel, self.line, segments=tuple(self.segments), **self.directives.values)


class _Program:
    """A file's statements as they are read: its own directives, its lets, its sections."""

    def __init__(self) -> None:
        self.directives = _Directives("a schedule")
        self.lets: list[tree.Let] = []
        self.sections: list[_Section] = []

    def section(self, span: Span) -> _Section:
        """The section a statement at `span` belongs to: the latest, or the implicit gear one."""
        if not self.sections:
            self.sections.append(_Section(None, span))
        return self.sections[-1]

    def open(self, line: tree.ChannelLine) -> None:
        """Start a channel's section, refusing a channel declared a second time (the implicit
        gear channel included)."""
        for section in self.sections:
            if section.channel != line.channel:  # targets in any order: a channel holds them sorted
                continue
            if section.line is None and not section.segments and set(section.directives.seen) <= {"pace"}:
                continue  # only the file's `pace` line came before: no gear section yet
            if section.line is None:
                raise ScheduleError(
                    f"`channel {line.text}` is given twice: the lines before the first `channel` line "
                    f"(from line {section.first.line}) are the gear channel's",
                    span=line.span,
                    hint="move those lines below this `channel gear` line, or delete one of the two",
                )
            again = "" if line.text == section.line.text else f", and here as `{line.text}`"
            raise ScheduleError(
                f"`channel {section.line.text}` is given twice (first on line {section.first.line}{again})",
                span=line.span,
                hint="a file declares each channel once, its targets in any order: merge the two sections",
            )
        self.sections.append(_Section(line, line.span))

    def build(self) -> tree.Program:
        sections = self.sections
        pace = None
        if sections and sections[0].line is None and not sections[0].segments and len(sections) > 1:
            pace = sections[0].directives.values.pop("pace", None)  # the file's: before every channel line
            sections[0].directives.seen.pop("pace", None)
            sections = sections[1:] if not sections[0].directives.seen else sections
        if sections and sections[0].line is None and not sections[0].segments and len(sections) > 1:
            seen = sections[0].directives.seen
            key, span = min(seen.items(), key=lambda item: (item[1].line, item[1].column))
            raise ScheduleError(
                f"`{key}` comes before the first `channel` line, so it is the gear channel's, which has no segments",
                span=span,
                hint="move it below the `channel` line of the channel it is for",
            )
        built = [section.build() for section in sections] or [tree.Section(GEAR)]
        return tree.Program(lets=tuple(self.lets), sections=tuple(built), pace=pace, **self.directives.values)


def _channel(program: _Program, line: tree.ChannelLine) -> None:
    program.open(line)


def _segment(program: _Program, statement: tree.Segment) -> None:
    program.section(statement.span).segments.append(statement)


def _let(program: _Program, statement: tree.Let) -> None:
    program.lets.append(statement)


def _bounds(program: _Program, statement: tree.Bounds) -> None:
    program.section(statement.span).directives.give("bounds", statement.span, statement)


def _final(program: _Program, statement: tree.Final) -> None:
    program.section(statement.span).directives.give("final", statement.span, statement)


def _pace(program: _Program, statement: tree.Pace) -> None:
    program.section(statement.span).directives.give("pace", statement.span, statement)


def _continuous(program: _Program, statement: tree.Continuous) -> None:
    program.section(statement.span).directives.give("continuous", statement.span, True)


def _extinction(program: _Program, statement: tree.Extinction) -> None:
    program.directives.give("extinction", statement.span, statement)


def _string(program: _Program, statement: tree.StringDirective) -> None:
    program.directives.give(statement.key, statement.span, statement.value)


_COLLECT: dict[type, Callable[[_Program, Any], None]] = {
    tree.ChannelLine: _channel,
    tree.Segment: _segment,
    tree.Let: _let,
    tree.Bounds: _bounds,
    tree.Final: _final,
    tree.Continuous: _continuous,
    tree.Pace: _pace,
    tree.Extinction: _extinction,
    tree.StringDirective: _string,
}
"""What each kind of statement does to the program being assembled."""
