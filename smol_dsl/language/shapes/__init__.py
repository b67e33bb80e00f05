"""The shape registry: one unit per kind of segment shape.

A unit (a `Shape` subclass, one module each) owns its keyword, its values' checks, its sympy
pieces, its proof hooks, its JAX evaluation and its line in the docs; its grammar rule is
`KEYWORD_shape` in sched.lark. Everything else that lists shapes is derived from here: the
`shape` alternatives of the grammar and its reserved words (`smol_dsl.language.grammar`), the
hints for syntax errors (`smol_dsl.language.hints`) and the docs' table of shapes.

Adding a shape given by a formula is one unit plus one grammar rule:

    class Cosine(Shape):
        keyword = "cosine"
        usage = "cosine a -> b"
        meaning = "`a + (b − a)·(1 − cos(π·u))/2`"

        def compile(self, segment, start, end):
            a, b = segment.value(start, "start value"), segment.value(end, "end value")
            return self.single_piece(segment, a + (b - a) * (1 - sp.cos(sp.pi * segment.u)) / 2)

with `cosine_shape: "cosine" expr "->" expr` in sched.lark and the unit in `BUILT_IN` below;
or at run time, `register(Cosine(), 'cosine_shape: "cosine" expr "->" expr')`.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager

from smol_dsl.language.shapes.base import Compiled, Drawn, Evaluation, Formula, Line, SegmentContext, Shape
from smol_dsl.language.shapes.bell import Bell
from smol_dsl.language.shapes.constant import Constant
from smol_dsl.language.shapes.expression import Expression
from smol_dsl.language.shapes.linear import Linear
from smol_dsl.language.shapes.random_draws import Random
from smol_dsl.language.shapes.tail import Tail

__all__ = [
    "BUILT_IN",
    "Compiled",
    "Drawn",
    "Evaluation",
    "Formula",
    "Line",
    "SegmentContext",
    "Shape",
    "keywords",
    "register",
    "registered",
    "rules",
    "unit",
    "units",
    "unregister",
]

BUILT_IN: tuple[Shape, ...] = (Constant(), Linear(), Bell(), Random(), Expression(), Tail())
"""The language's shapes, in the order in which docs and hints list them."""

_UNITS: dict[str, Shape] = {}
_RULES: dict[str, str] = {}  # keyword -> grammar rule, for the shapes registered with one
_KEYWORD = re.compile(r"[a-z][a-z0-9]*")


def register(shape: Shape, rule: str | None = None) -> None:
    """Add a shape to the language. `rule` is its grammar rule, `KEYWORD_shape: ...`, when
    sched.lark does not have it (a shape added at run time)."""
    keyword = shape.keyword
    if not _KEYWORD.fullmatch(keyword):
        raise ValueError(f"a shape's keyword is a lowercase word, not {keyword!r}")
    if keyword in _UNITS:
        raise ValueError(f"a shape `{keyword}` is registered already")
    if rule is not None and not re.match(rf"\s*{keyword}_shape\s*:", rule):
        raise ValueError(f"the grammar rule of `{keyword}` must define `{keyword}_shape`, not {rule!r}")
    _UNITS[keyword] = shape
    if rule is not None:
        _RULES[keyword] = rule.strip()


def unregister(keyword: str) -> None:
    """Remove a shape (and the grammar rule it was registered with)."""
    del _UNITS[keyword]
    _RULES.pop(keyword, None)


@contextmanager
def registered(shape: Shape, rule: str | None = None) -> Iterator[Shape]:
    """The language with one more shape, for the duration of a `with` block."""
    register(shape, rule)
    try:
        yield shape
    finally:
        unregister(shape.keyword)


def units() -> tuple[Shape, ...]:
    """Every registered shape, in order of registration."""
    return tuple(_UNITS.values())


def keywords() -> tuple[str, ...]:
    """The shapes' keywords, in order of registration."""
    return tuple(_UNITS)


def unit(keyword: str) -> Shape:
    """The shape of a keyword."""
    return _UNITS[keyword]


def rules() -> tuple[str, ...]:
    """The grammar rules of the shapes registered with one, in order of registration."""
    return tuple(_RULES.values())


for _shape in BUILT_IN:
    register(_shape)
