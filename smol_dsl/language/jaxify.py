"""Exact sympy expressions -> jittable JAX functions of t: how a formula's piece is evaluated.

A small tree-walking translator over the node types the language can produce, so that the
JAX function is built from the verified sympy object itself (no code generation, no eval).
Shapes with a closed form evaluate themselves (`Shape.evaluation`); `to_jax` serves the rest.
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
import sympy as sp

from smol_dsl.language.symbolic import T

_UNARY: dict[type, Callable[[jnp.ndarray], jnp.ndarray]] = {
    sp.exp: jnp.exp,
    sp.log: jnp.log,
    sp.sin: jnp.sin,
    sp.cos: jnp.cos,
    sp.tanh: jnp.tanh,
    sp.Abs: jnp.abs,
    sp.floor: jnp.floor,
}


def to_jax(expr: sp.Expr) -> Callable[[jnp.ndarray], jnp.ndarray]:
    """Return f(t) evaluating `expr` (a sympy expression in T) with jax.numpy."""

    def evaluate(node: sp.Expr, t: jnp.ndarray) -> jnp.ndarray:
        if node == T:
            return t
        if node.is_Number or node.is_NumberSymbol or (node.is_number and not node.free_symbols):
            return jnp.asarray(float(sp.N(node, 20)), dtype=t.dtype)
        if node.is_Add:
            total = evaluate(node.args[0], t)
            for arg in node.args[1:]:
                total = total + evaluate(arg, t)
            return total
        if node.is_Mul:
            product = evaluate(node.args[0], t)
            for arg in node.args[1:]:
                product = product * evaluate(arg, t)
            return product
        if node.is_Pow:
            base, exponent = node.args
            if exponent.is_Integer:  # lax.integer_pow: repeated squaring, any sign of base
                return jnp.power(evaluate(base, t), int(exponent))
            # Verification proved the base >= 0 over the segment; float rounding at the
            # segment's ends may still make it -1e-9, so clamp rather than return NaN.
            clamped = jnp.maximum(evaluate(base, t), 0.0)
            if exponent == sp.Rational(1, 2):
                return jnp.sqrt(clamped)
            return jnp.power(clamped, evaluate(exponent, t))
        if isinstance(node, sp.log):  # argument proved > 0; clamp away rounding below it
            return jnp.log(jnp.maximum(evaluate(node.args[0], t), jnp.finfo(t.dtype).tiny))
        if isinstance(node, sp.Min):
            return _fold(jnp.minimum, [evaluate(a, t) for a in node.args])
        if isinstance(node, sp.Max):
            return _fold(jnp.maximum, [evaluate(a, t) for a in node.args])
        if type(node) in _UNARY:
            return _UNARY[type(node)](evaluate(node.args[0], t))
        raise TypeError(f"cannot translate {node!r} ({type(node).__name__}) to JAX")

    def function(t: jnp.ndarray) -> jnp.ndarray:
        return evaluate(expr, t)

    return function


def _fold(op: Callable[[jnp.ndarray, jnp.ndarray], jnp.ndarray], values: list[jnp.ndarray]) -> jnp.ndarray:
    result = values[0]
    for value in values[1:]:
        result = op(result, value)
    return result
