"""Syntax errors in words: Lark's parse errors as one located `ScheduleError` with a hint.

A hint comes, in this order of preference, from what the offending character or token is (a
`^`, a bracket, a non-ASCII look-alike, a misspelled shape), from a list of known mistakes
that fail in the same parser state (Lark's example matching: each shape's unit adds its own),
or from what the grammar expected there.
"""

from __future__ import annotations

import difflib
import unicodedata
from functools import lru_cache

from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language import shapes
from smol_dsl.language.channels import CHANNEL_KINDS
from smol_dsl.language.grammar import grammar_text, parser

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

_CHARACTER_HINTS = {
    "^": "powers are written with `**`, e.g. `t**2`",
    **dict.fromkeys("[]{}", "group with round brackets `( )`"),
    '"': 'a string ends with `"` on the same line, e.g. `name "SMOL"`',
    "'": 'strings are written in double quotes, e.g. `name "SMOL"`',
}
"""Hints for an unexpected character, whatever the parser state."""

_LOOKALIKES = {"−": "-", "–": "-", "—": "-", "×": "*", "·": "*", "÷": "/", "…": "..", "“": '"', "”": '"'}


def syntax_error(error: UnexpectedInput, text: str) -> ScheduleError:
    """Lark's parse error of `text` as one located ScheduleError with a hint."""
    line, column = _location(error, text)
    example = _example_hint(error)
    if isinstance(error, UnexpectedCharacters):
        return _unexpected_character(error, text, Span(line, column), example)
    if isinstance(error, UnexpectedToken):
        return _unexpected_token(error, line, column, example)
    if isinstance(error, UnexpectedEOF):
        hint = example or f"expected {_expected_in_words(set(error.expected))}"
        return ScheduleError("unexpected end of file", span=Span(line, column), hint=hint)
    return ScheduleError(str(error), span=Span(line, column))


def _location(error: UnexpectedInput, text: str) -> tuple[int, int]:
    """Where the error is: its line and column, or just past the last character at the end."""
    line = getattr(error, "line", None) or 1
    column = getattr(error, "column", None) or 1
    at_end = isinstance(error, UnexpectedEOF) or (isinstance(error, UnexpectedToken) and error.token.type == "$END")
    if line < 1 or at_end:
        lines = text.rstrip("\n").split("\n")
        line, column = len(lines), len(lines[-1].rstrip("\r")) + 1
    return line, column


def _unexpected_character(error: UnexpectedCharacters, text: str, span: Span, example: str | None) -> ScheduleError:
    position = error.pos_in_stream
    char = text[position] if position < len(text) else "?"
    hint = (
        _character_hint(char, text, position) or example or f"expected {_expected_in_words(set(error.allowed or ()))}"
    )
    return ScheduleError(f"unexpected character {char!r}", span=span, hint=hint)


def _character_hint(char: str, text: str, position: int) -> str | None:
    """What an unexpected character is, if it is a known mistake."""
    if not char.isascii() and char.isprintable():
        return _non_ascii_hint(char)
    if char == "." and position > 0 and text[position - 1].isdigit():
        return "a number needs digits after its decimal point (`1.0`, not `1.`); ranges are written `..`"
    return _CHARACTER_HINTS.get(char)


def _non_ascii_hint(char: str) -> str:
    name = unicodedata.name(char, f"U+{ord(char):04X}")
    what = f"{char!r} is {name} (U+{ord(char):04X})"
    if unicodedata.category(char) == "Nd" or char.isdigit():
        return f"{what}: numbers are written with the ASCII digits 0-9 only"
    if char in _LOOKALIKES:
        return f"{what}: write the ASCII `{_LOOKALIKES[char]}`"
    return f"{what}: outside strings and comments a .sched file is ASCII"


def _unexpected_token(error: UnexpectedToken, line: int, column: int, example: str | None) -> ScheduleError:
    token = error.token
    message = _token_words(token.type, str(token))
    example = _misspelled_shape(error) or example
    if token.type in ("LSQB", "RSQB") and example != CHANNEL_LINE_HINT:  # in an expression
        message = f"unexpected character {str(token)!r}"
        example = "group with round brackets `( )`"
    if example is None and "_NL" in error.expected and token.type != "$END":
        example = "one statement per line: end the line before this, or join it to the expression with an operator"
    hint = example or f"expected {_expected_in_words(set(error.expected))}"
    length = len(str(token)) if token.type not in {"$END", "_NL"} else 1
    return ScheduleError(message, span=Span(line, column, max(1, length)), hint=hint)


def _token_words(kind: str, text: str) -> str:
    """`unexpected end of file`, `unexpected end of line` or `unexpected 'TOKEN'`."""
    if kind == "$END":
        return "unexpected end of file"
    if kind == "_NL":
        return "unexpected end of line"
    return f"unexpected {text!r}"


def _misspelled_shape(error: UnexpectedToken) -> str | None:
    """`did you mean `linear`? ...` for a name close to a shape's keyword, where a shape may come."""
    if error.token.type != "NAME":
        return None
    kinds = shapes.keywords()
    close = difflib.get_close_matches(str(error.token), kinds, n=1)
    if close and (error.expected & {kind.upper() for kind in kinds}):
        return f"did you mean `{close[0]}`? The segment kinds are " + ", ".join(kinds)
    return None


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
    """Each known mistake's hint and parse error, for the grammar of the shapes registered now."""
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
