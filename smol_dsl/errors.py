"""The errors a user can cause: `UserInputError`, the base of every error the CLI reports
with exit status 2, and `ScheduleError` for everything a `.sched` file can get wrong.

A message that names a setting (a `RunConfig` field such as `evaluations`, an argument such
as `schedules`) is a `Message` holding a `Setting`: `str(error)` names the setting as the
library does, and `error.worded(names)` as a front end spells it. The CLI passes its
options, so the same refusal reads "num_phases must be at least 1" in Python and "--phases
must be at least 1" on the command line.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class Setting:
    """A setting that a message names: shown as `name` by `str()`, and as `names[name]` by
    `worded(names)`. Joined to text with `+`, it makes a `Message`."""

    name: str

    def __str__(self) -> str:
        return self.name

    def __add__(self, other: str | Setting | Message) -> Message:
        return Message((self,)) + other

    def __radd__(self, other: str) -> Message:
        return Message((other, self))


@dataclass(frozen=True)
class Message:
    """A message as text and the settings it names, in order; built with `+` from strings,
    settings and messages. `str()` names each setting by its own name."""

    parts: tuple[str | Setting, ...] = ()

    def __add__(self, other: str | Setting | Message) -> Message:
        if isinstance(other, Message):
            return Message(self.parts + other.parts)
        return Message((*self.parts, other))

    def __radd__(self, other: str) -> Message:
        return Message((other, *self.parts))

    @staticmethod
    def joined(separator: str, items: Iterable[str | Setting | Message]) -> Message:
        """The items with `separator` between them, as `separator.join` joins strings."""
        message = Message()
        for index, item in enumerate(items):
            message = message + separator + item if index else message + item
        return message

    def worded(self, names: Mapping[str, str] | None = None) -> str:
        """The text, each setting spelled as `names[setting]` where `names` has it (a mapping
        may supply a default with `__missing__`), otherwise by its own name."""
        return "".join(part if isinstance(part, str) else _spelled(part.name, names) for part in self.parts)

    def __str__(self) -> str:
        return self.worded()


def _spelled(name: str, names: Mapping[str, str] | None) -> str:
    if names is None:
        return name
    try:
        return names[name]
    except KeyError:
        return name


@dataclass(frozen=True)
class Span:
    """A place in a source text: 1-based line and column, and the length to underline."""

    line: int
    column: int
    length: int = 1


class UserInputError(Exception):
    """Bad input or a bad environment, not a bug: a file, option or directory that cannot be used.

    The message names the file or option and says what to do. The library raises subclasses
    (`ScheduleError`, `smol_dsl.runner.RunError`, `smol_dsl.results.ReportError`,
    `smol_dsl.rundir.RunDirectoryError`); the CLI prints the message and exits with
    status 2, without a traceback. The message is a string or a `Message`.
    """

    def worded(self, names: Mapping[str, str]) -> str:
        """The message with each setting it names spelled as `names` spells it (see `Message`);
        the same as `str(self)` for a message that names none."""
        message = self.args[0] if len(self.args) == 1 else None
        return message.worded(names) if isinstance(message, Message) else str(self)


class ScheduleError(UserInputError):
    """A schedule file that cannot be parsed, compiled or verified.

    The message names the file, line and column, shows the offending line with a caret
    under the offending text, and ends with a hint on how to fix it.
    """

    def __init__(
        self,
        message: str,
        *,
        span: Span | None = None,
        hint: str | None = None,
        source: str | None = None,
        path: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.span = span
        self.hint = hint
        self.source = source
        self.path = path

    @property
    def line(self) -> int | None:
        return self.span.line if self.span else None

    @property
    def column(self) -> int | None:
        return self.span.column if self.span else None

    def located(self, source: str | None, path: str | None) -> ScheduleError:
        """Return this error with the source text and file name filled in where missing."""
        return ScheduleError(
            self.message,
            span=self.span,
            hint=self.hint,
            source=self.source if self.source is not None else source,
            path=self.path if self.path is not None else path,
        )

    def __str__(self) -> str:
        where = self.path or "<schedule>"
        if self.span is not None:
            where += f":{self.span.line}:{self.span.column}"
        lines = [f"{where}: error: {self.message}"]
        excerpt = self._excerpt()
        if excerpt:
            lines.extend(excerpt)
        if self.hint:
            lines.append(f"hint: {self.hint}")
        return "\n".join(lines)

    def _excerpt(self) -> list[str]:
        if self.span is None or self.source is None:
            return []
        source_lines = self.source.split("\n")  # lines as the parser counts them
        if not 1 <= self.span.line <= len(source_lines):
            return []
        text = source_lines[self.span.line - 1].rstrip("\r").expandtabs(1)
        printable = "".join(ch if ch.isprintable() else "?" for ch in text)
        # Long lines are cut around the caret so the message stays one screen wide.
        start = max(0, self.span.column - 1 - 60)
        shown = printable[start : start + 120]
        caret_at = self.span.column - 1 - start
        width = max(1, min(self.span.length, len(shown) - caret_at))
        prefix = "...  " if start else "     "
        return [f"{prefix}{shown}", " " * (5 + caret_at) + "^" * width]


def counted(count: int, noun: str, plural: str | None = None) -> str:
    """`count` and the noun in its number, for messages: "1 run", "3 runs", "1 was" / "2 were"."""
    return f"{count} {noun if count == 1 else (plural or noun + 's')}"
