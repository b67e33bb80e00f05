"""The grammar of the `.sched` language: sched.lark, completed from the shape registry.

sched.lark has one rule per segment shape, `KEYWORD_shape`. Loading adds the shapes
registered at run time with their own rule, and the rule that chooses between them,

    ?shape: constant_shape | linear_shape | bell_shape | ...

in the registry's order; it refuses a grammar whose shape rules and registered units differ.
The reserved words are the grammar's keywords, so a new shape's words are reserved with it.
"""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

from lark import Lark

from smol_dsl.language import shapes

GRAMMAR_FILE = Path(__file__).with_name("sched.lark")
_SHAPE_RULE = re.compile(r"^\??(\w+)_shape\s*:", re.MULTILINE)
_COMMENT = re.compile(r"^\s*//.*$", re.MULTILINE)
_KEYWORD = re.compile(r'"([a-z]+)"')


def grammar_text() -> str:
    """The whole Lark grammar, for the shapes registered now."""
    return _assemble(shapes.keywords(), shapes.rules())


def parser() -> Lark:
    """The LALR parser of the grammar (one per set of registered shapes)."""
    return _parser(grammar_text())


def reserved_words() -> frozenset[str]:
    """The keywords of the language: no `let` may take one as its name."""
    return _keywords(grammar_text())


@lru_cache(maxsize=1)
def _file_text() -> str:
    return GRAMMAR_FILE.read_text(encoding="utf-8")


@lru_cache(maxsize=8)
def _assemble(keywords: tuple[str, ...], rules: tuple[str, ...]) -> str:
    text = "\n".join([_file_text().rstrip("\n"), *rules, "?shape: " + " | ".join(f"{k}_shape" for k in keywords)])
    defined = _SHAPE_RULE.findall(_COMMENT.sub("", text))
    if sorted(defined) != sorted(keywords):
        missing = sorted(set(keywords) - set(defined))
        extra = sorted(set(defined) - set(keywords))
        raise RuntimeError(
            f"the grammar's shape rules do not match the shape registry: units without a rule {missing}, "
            f"rules without a unit {extra}, rules given twice {sorted({k for k in defined if defined.count(k) > 1})}"
        )
    return text + "\n"


@lru_cache(maxsize=8)
def _parser(text: str) -> Lark:
    return Lark(text, parser="lalr", propagate_positions=True, maybe_placeholders=True)


@lru_cache(maxsize=8)
def _keywords(text: str) -> frozenset[str]:
    return frozenset(_KEYWORD.findall(_COMMENT.sub("", text)))
