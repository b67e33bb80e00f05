"""Text -> the statements of a `.sched` file: the Lark parse and its Transformer.

The Transformer builds `smol_dsl.language.tree` nodes, one per grammar rule, and checks only
what a node needs to exist: a number literal within float64's range. A parse error becomes
one located error with a hint (`smol_dsl.language.hints`); program assembly
(`smol_dsl.language.assembly`) checks the statements and collects them into a `Program`.
"""

from __future__ import annotations

import sys
from fractions import Fraction
from typing import Any

from lark import Token, Transformer, Tree, v_args
from lark.exceptions import UnexpectedInput, VisitError

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language import shapes, tree
from smol_dsl.language.grammar import parser
from smol_dsl.language.hints import syntax_error

MAX_EXPONENT_DIGITS = 400  # literals beyond 1e±400 are out of float64 range anyway
MAX_NESTING = 100
"""Deepest expression: brackets, calls, and every operator of a chain (`a + b + c` is 2) count."""


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

    def name_decl(self, meta: Any, children: list[Token]) -> tree.StringDirective:
        return tree.StringDirective("name", str(children[0])[1:-1], _span_of_meta(meta))

    def description_decl(self, meta: Any, children: list[Token]) -> tree.StringDirective:
        return tree.StringDirective("description", str(children[0])[1:-1], _span_of_meta(meta))

    def let_decl(self, meta: Any, children: list[Any]) -> tree.Let:
        return tree.Let(str(children[0]), children[1], _span_of_meta(meta))

    def bounds_decl(self, meta: Any, children: list[Any]) -> tree.Bounds:
        return tree.Bounds(children[0], children[1], _span_of_meta(meta))

    def extinction_decl(self, meta: Any, children: list[Any]) -> tree.Extinction:
        return tree.Extinction(children[0], _span_of_meta(meta))

    def continuous_decl(self, meta: Any, children: list[Any]) -> tree.Continuous:
        return tree.Continuous(_span_of_meta(meta))

    def final_decl(self, meta: Any, children: list[Any]) -> tree.Final:
        return tree.Final(children[0], _span_of_meta(meta))

    def comparison(self, meta: Any, children: list[Any]) -> tree.Comparison:
        left, op, right = children
        return tree.Comparison(str(op), left, right, _span_of_meta(meta))  # type: ignore[arg-type]

    def either(self, meta: Any, children: list[Any]) -> tree.Logical:
        return tree.Logical("or", children[0], children[1], _span_of_meta(meta))

    def both(self, meta: Any, children: list[Any]) -> tree.Logical:
        return tree.Logical("and", children[0], children[1], _span_of_meta(meta))

    def pace_decl(self, meta: Any, children: list[Any]) -> tree.Pace:
        return tree.Pace(children[0], children[1], _span_of_meta(meta))

    def channel_targets(self, meta: Any, children: list[Token | None]) -> tree.Targets:
        names = tuple(tree.Name(str(child), _span_of_token(child)) for child in children if child is not None)
        return tree.Targets(names, _span_of_meta(meta))

    def channel_decl(self, meta: Any, children: list[Any]) -> tree.ChannelDecl:
        kind, targets = children
        return tree.ChannelDecl(tree.Name(str(kind), _span_of_token(kind)), targets, _span_of_meta(meta))

    def start(self, meta: Any, children: list[Any]) -> tuple[tree.Statement, ...]:
        return tuple(child for child in children if child is not None)


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


def parse_statements(text: str) -> tuple[tree.Statement, ...]:
    """Parse `.sched` text into its statements, in order, or raise one located `ScheduleError`."""
    try:
        parsed = parser().parse(text)
        _check_nesting(parsed)  # a located error for deep expressions, before the Transformer recurses
        return _ToTree().transform(parsed)
    except UnexpectedInput as error:
        raise syntax_error(error, text) from None
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
