"""What a `.sched` text must be before it is parsed: of a schedule's size, without control
characters, and with at least one statement."""

from __future__ import annotations

import re

from smol_dsl.errors import ScheduleError, Span

MAX_SOURCE_CHARS = 1_000_000

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
