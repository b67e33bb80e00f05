"""The errors a user can cause: `UserInputError`, the base of every error the CLI reports
with exit status 2, and `ScheduleError` for everything a `.sched` file can get wrong."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Span:
    """A place in a source text: 1-based line and column, and the length to underline."""

    line: int
    column: int
    length: int = 1


class UserInputError(Exception):
    """Bad input or a bad environment, not a bug: a file, option or directory that cannot be used.

    The message names the file or option and says what to do. The library raises subclasses
    (`ScheduleError`, `smol_dsl.runner.RunError`, `smol_dsl.results.report.ReportError`,
    `smol_dsl.rundir.RunDirectoryError`); the CLI prints the message and exits with
    status 2, without a traceback.
    """


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
