"""Exact sympy expressions -> jittable JAX functions: how a formula's piece (of t) and a pace
condition's sides (of the run's metrics) are evaluated.

A small tree-walking translator over the node types the language can produce, so that the
JAX function is built from the verified sympy object itself (no code generation, no eval).
Shapes with a closed form evaluate themselves (`Shape.evaluation`); `to_jax` serves the rest.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import jax.numpy as jnp
import sympy as sp

from smol_dsl.language.symbolic import T

_UNARY: dict[type, Callable[[jnp.ndarray], jnp.ndarray]] = {
    sp.exp: jnp.exp,
    sp.sin: jnp.sin,
    sp.cos: jnp.cos,
    sp.tanh: jnp.tanh,
    sp.Abs: jnp.abs,
    sp.floor: jnp.floor,
}


class _Inputs(NamedTuple):
    """The values of an expression's symbols, and the dtype of its constants."""

    values: Mapping[sp.Symbol, jnp.ndarray]
    dtype: Any


def to_jax(expr: sp.Expr) -> Callable[[jnp.ndarray], jnp.ndarray]:
    """Return f(t) evaluating `expr` (a sympy expression in T) with jax.numpy."""

    def function(t: jnp.ndarray) -> jnp.ndarray:
        return _evaluate(expr, _Inputs({T: t}, t.dtype))

    return function


def evaluate(expr: sp.Expr, values: Mapping[sp.Symbol, jnp.ndarray], dtype: Any) -> jnp.ndarray:
    """`expr` evaluated with jax.numpy, each of its symbols given by `values`, its constants
    in `dtype`."""
    return _evaluate(expr, _Inputs(values, dtype))


def _evaluate(node: sp.Expr, t: _Inputs) -> jnp.ndarray:
    if node.is_Symbol:
        return t.values[node]
    if node.is_Number or node.is_NumberSymbol or (node.is_number and not node.free_symbols):
        return jnp.asarray(float(sp.N(node, 20)), dtype=t.dtype)
    for kind, translate in _TRANSLATIONS:
        if isinstance(node, kind):
            return translate(node, t)
    raise TypeError(f"cannot translate {node!r} ({type(node).__name__}) to JAX")


def _add(node: sp.Expr, t: _Inputs) -> jnp.ndarray:
    total = _evaluate(node.args[0], t)
    for arg in node.args[1:]:
        total = total + _evaluate(arg, t)
    return total


def _mul(node: sp.Expr, t: _Inputs) -> jnp.ndarray:
    product = _evaluate(node.args[0], t)
    for arg in node.args[1:]:
        product = product * _evaluate(arg, t)
    return product


def _pow(node: sp.Expr, t: _Inputs) -> jnp.ndarray:
    base, exponent = node.args
    if exponent.is_Integer:  # lax.integer_pow: repeated squaring, any sign of base
        return jnp.power(_evaluate(base, t), int(exponent))
    # Verification proved the base >= 0 over the segment; float rounding at the
    # segment's ends may still make it -1e-9, so clamp rather than return NaN.
    clamped = jnp.maximum(_evaluate(base, t), 0.0)
    if exponent == sp.Rational(1, 2):
        return jnp.sqrt(clamped)
    return jnp.power(clamped, _evaluate(exponent, t))


def _log(node: sp.Expr, t: _Inputs) -> jnp.ndarray:
    # the argument is proved > 0; clamp away rounding below it
    return jnp.log(jnp.maximum(_evaluate(node.args[0], t), jnp.finfo(t.dtype).tiny))


def _min(node: sp.Expr, t: _Inputs) -> jnp.ndarray:
    return _fold(jnp.minimum, [_evaluate(a, t) for a in node.args])


def _max(node: sp.Expr, t: _Inputs) -> jnp.ndarray:
    return _fold(jnp.maximum, [_evaluate(a, t) for a in node.args])


def _applied(function: Callable[[jnp.ndarray], jnp.ndarray]) -> Callable[[sp.Expr, _Inputs], jnp.ndarray]:
    def translate(node: sp.Expr, t: _Inputs) -> jnp.ndarray:
        return function(_evaluate(node.args[0], t))

    return translate


_TRANSLATIONS: tuple[tuple[type, Callable[[sp.Expr, _Inputs], jnp.ndarray]], ...] = (
    (sp.Add, _add),
    (sp.Mul, _mul),
    (sp.Pow, _pow),
    (sp.log, _log),
    (sp.Min, _min),
    (sp.Max, _max),
    *((kind, _applied(function)) for kind, function in _UNARY.items()),
)
"""How each kind of node (other than t and constants) is evaluated, in the order they are tried."""


def _fold(op: Callable[[jnp.ndarray, jnp.ndarray], jnp.ndarray], values: list[jnp.ndarray]) -> jnp.ndarray:
    result = values[0]
    for value in values[1:]:
        result = op(result, value)
    return result
