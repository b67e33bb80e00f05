"""Syntax-tree expressions -> exact sympy, under a `Scope` of names.

Expressions are built node by node from the syntax tree; no text from a `.sched` file is
ever handed to `eval`, `sympify` or `parse_expr`. The scope holds the built-in functions and
constants and the file's `let` constants; its methods refuse, with a located error, a name
that is not defined, a call of the wrong arity, a division by zero, a power far beyond any
sensible value, and a constant that is not a finite real number.
"""

from __future__ import annotations

import difflib
import math
import operator
from collections.abc import Callable
from typing import Any

import sympy as sp

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language import tree
from smol_dsl.language.symbolic import percent

MAX_EXPONENT = 10_000
PACING_NAMES = ("coverage", "max_fitness", "qd_score", "waited", "before", "after")
"""The names a `pace` condition reads (`smol_dsl.language.pacing.NAMES`), built in."""

FUNCTIONS: dict[str, tuple[Callable[..., sp.Expr], int | None]] = {
    "exp": (sp.exp, 1),
    "log": (sp.log, 1),
    "sqrt": (sp.sqrt, 1),
    "sin": (sp.sin, 1),
    "cos": (sp.cos, 1),
    "tanh": (sp.tanh, 1),
    "abs": (sp.Abs, 1),
    "min": (sp.Min, None),
    "max": (sp.Max, None),
}
CONSTANTS: dict[str, sp.Expr] = {"pi": sp.pi, "e": sp.E}

Variables = dict[str, sp.Expr]
"""The variables an expression may use besides the constants: `t` and `u` inside an `expr` segment."""


class Scope:
    """Builds sympy expressions from syntax-tree expressions, with the constants defined so far.

    `reserved` are the language's keywords (`smol_dsl.language.grammar.reserved_words`): no
    `let` may take one as its name.
    """

    def __init__(self, reserved: frozenset[str]) -> None:
        self.reserved = reserved
        self.constants: dict[str, sp.Expr] = dict(CONSTANTS)

    def define(self, let: tree.Let) -> None:
        """Add a `let` constant, refusing a reserved word, a built-in name or a name given twice."""
        if let.name in self.reserved:
            raise ScheduleError(
                f"`{let.name}` is a reserved word",
                span=let.span,
                hint="choose another name for this constant; reserved: " + ", ".join(sorted(self.reserved)),
            )
        if let.name in self.constants or let.name in FUNCTIONS or let.name in ("t", "u") or let.name in PACING_NAMES:
            what = "a built-in name" if let.name not in self.constants or let.name in CONSTANTS else "already defined"
            raise ScheduleError(
                f"`{let.name}` is {what}",
                span=let.span,
                hint="choose another name for this constant",
            )
        self.constants[let.name] = self.constant(let.value, what=f"`let {let.name}`")

    def constant(self, node: tree.Expr, *, what: str) -> sp.Expr:
        """A constant real number (no t): the value of a let, a position, an alpha level."""
        return _finite_real(self.build(node, variables={}), node, what)

    def position(self, node: tree.Expr, what: str) -> sp.Rational:
        """An exact position in the run: a rational constant in [0, 1]."""
        value = self.constant(node, what=what)
        if not value.is_Rational:
            raise ScheduleError(
                f"{what} must be a plain percentage or fraction, not {value}",
                span=node.span,
                hint="write positions like `90%` or `0.9`",
            )
        if value < 0 or value > 1:
            raise ScheduleError(
                f"{what} is {percent(value)}, outside the run",
                span=node.span,
                hint="positions are fractions of the run from 0% to 100%: write `90%` or `0.9`, not `90`",
            )
        return value

    def build(self, node: tree.Expr, variables: Variables) -> sp.Expr:
        """The exact sympy expression of a syntax-tree expression."""
        build = _BUILD.get(type(node))
        if build is None:
            raise TypeError(f"unknown expression node {node!r}")
        return build(self, node, variables)

    def unknown_name(self, node: tree.Name, variables: Variables) -> ScheduleError:
        known = list(self.constants) + list(variables)
        close = difflib.get_close_matches(node.id, known, n=1)
        if node.id in ("t", "u"):
            hint = f"`{node.id}` is only defined inside an `expr` segment"
        elif node.id in self.reserved:
            hint = f"`{node.id}` is a keyword of the language, not a value" + (
                "; alpha = 1 is written `1`" if node.id == "tail" else ""
            )
        elif node.id.lower() in ("nan", "inf", "infinity"):
            hint = "alpha and positions must be finite numbers"
        elif close:
            hint = f"did you mean `{close[0]}`?"
        else:
            hint = "define it first with `let " + node.id + " = ...`"
        return ScheduleError(f"unknown name `{node.id}`", span=node.span, hint=hint)


# ---------------------------------------------------------------- one builder per node type


def _number(scope: Scope, node: tree.Number, variables: Variables) -> sp.Expr:
    return sp.Rational(node.value.numerator, node.value.denominator)


def _name(scope: Scope, node: tree.Name, variables: Variables) -> sp.Expr:
    if node.id in variables:
        return variables[node.id]
    if node.id in scope.constants:
        return scope.constants[node.id]
    raise scope.unknown_name(node, variables)


_UNARY: dict[str, Callable[[sp.Expr], sp.Expr]] = {
    "-": operator.neg,
    "%": lambda operand: operand / 100,
    "+": lambda operand: operand,
}


def _unary(scope: Scope, node: tree.Unary, variables: Variables) -> sp.Expr:
    return _UNARY[node.op](scope.build(node.operand, variables))


def _divide(left: sp.Expr, right: sp.Expr, node: tree.Binary) -> sp.Expr:
    if right.is_zero:
        raise ScheduleError("division by zero", span=node.span, hint="the divisor here is 0")
    return left / right


def _power(base: sp.Expr, exponent: sp.Expr, node: tree.Binary) -> sp.Expr:
    # Exact arithmetic would happily try 10**10**10; refuse powers that cannot be a
    # sensible alpha before sympy starts computing them.
    if exponent.is_number:
        magnitude = abs(float(exponent.evalf(20))) if exponent.is_real else math.inf
        if magnitude > MAX_EXPONENT or (
            base.is_number
            and base.is_real
            and not base.is_zero
            and abs(math.log10(abs(float(base.evalf(20))) or 1e-300)) * magnitude > 400
        ):
            raise ScheduleError(
                "power out of range",
                span=node.span,
                hint="the result of this power is far beyond any sensible alpha",
            )
    if base.is_zero and exponent.is_number and exponent.is_negative:
        raise ScheduleError("division by zero", span=node.span, hint="0 raised to a negative power")
    return sp.Pow(base, exponent)


_BINARY: dict[str, Callable[[sp.Expr, sp.Expr, tree.Binary], sp.Expr]] = {
    "+": lambda left, right, node: left + right,
    "-": lambda left, right, node: left - right,
    "*": lambda left, right, node: left * right,
    "/": _divide,
    "**": _power,
}


def _binary(scope: Scope, node: tree.Binary, variables: Variables) -> sp.Expr:
    left = scope.build(node.left, variables)
    right = scope.build(node.right, variables)
    return _BINARY[node.op](left, right, node)


def _call(scope: Scope, node: tree.Call, variables: Variables) -> sp.Expr:
    if node.function not in FUNCTIONS:
        close = difflib.get_close_matches(node.function, list(FUNCTIONS), n=1)
        hint = f"did you mean `{close[0]}`? " if close else ""
        raise ScheduleError(
            f"unknown function `{node.function}`",
            span=Span(node.span.line, node.span.column, len(node.function)),
            hint=hint + "the functions are " + ", ".join(FUNCTIONS),
        )
    function, arity = FUNCTIONS[node.function]
    args = [scope.build(a, variables) for a in node.args]
    if arity is not None and len(args) != arity:
        raise ScheduleError(
            f"`{node.function}` takes {arity} argument, not {len(args)}",
            span=node.span,
            hint=f"write `{node.function}(x)`",
        )
    if arity is None and len(args) < 2:
        raise ScheduleError(
            f"`{node.function}` takes two or more arguments, not {len(args)}",
            span=node.span,
            hint=f"write `{node.function}(a, b)`",
        )
    return function(*args)


_BUILD: dict[type, Callable[[Scope, Any, Variables], sp.Expr]] = {
    tree.Number: _number,
    tree.Name: _name,
    tree.Unary: _unary,
    tree.Binary: _binary,
    tree.Call: _call,
}


def _finite_real(value: sp.Expr, node: tree.Expr, what: str) -> sp.Expr:
    try:
        number = complex(value.evalf(30))
    except (TypeError, ValueError):
        number = complex(math.nan)
    if value.is_real and value.is_finite and not math.isfinite(number.real):
        raise ScheduleError(
            f"{what} is {sp.N(value, 3)}, out of range",
            span=node.span,
            hint="values must stay below about 1e300 in size; alpha is a modest factor like 1.5",
        )
    if value.has(sp.zoo, sp.nan, sp.oo, -sp.oo) or not math.isfinite(number.real) or abs(number.imag) > 0:
        raise ScheduleError(
            f"{what} is not a finite real number (it is {value})",
            span=node.span,
            hint="check for a log or square root of a negative number, or a division by zero",
        )
    if abs(number.real) > 1e300:
        raise ScheduleError(f"{what} is out of range ({number.real:.3g})", span=node.span, hint="use a modest value")
    return value
