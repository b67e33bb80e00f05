"""Exact sympy segment expressions -> jittable JAX functions of t.

A small tree-walking translator over the node types the language can produce, so that the
JAX function is built from the verified sympy object itself (no code generation, no eval).
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
import sympy as sp

from smol_dsl.symbolic import BellParams, T

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


def bell(params: BellParams, segment_start: float, segment_end: float) -> Callable[[jnp.ndarray], jnp.ndarray]:
    """f(t) for a bell segment on [start, end], finite for every width the language allows.

    Each half is base + (peak - base) * (G(t) - G(edge)) / (1 - G(edge)) with the Gaussian
    G(t) = exp(-x(t)) and x(t) = ((t - peak_at) / width)**2 / 2. It is computed in three forms:
    directly when G(edge) is small; with expm1 when G(edge) is close to 1 (a wide bell), to
    avoid cancellation; and as its limit 1 - r, r = ((t - peak_at) / (edge - peak_at))**2, when
    x(edge) underflows to 0 (a bell far wider than its segment is a parabola). x may overflow to
    inf for a narrow bell, which exp takes to 0; no form divides 0 by 0 or multiplies inf by 0.
    """
    start_value, peak, end_value = float(params.start), float(params.peak), float(params.end)
    peak_at, width = float(params.peak_at), float(params.width)

    def function(t: jnp.ndarray) -> jnp.ndarray:
        rising = t < peak_at
        edge = jnp.where(rising, segment_start, segment_end)
        base = jnp.where(rising, start_value, end_value)
        if width >= 2.0**-60:  # 1 / (2 width**2) fits float32
            scale = 1.0 / (2.0 * width**2)
            at_t = scale * (t - peak_at) ** 2  # -log G(t)
            at_edge = scale * (edge - peak_at) ** 2  # -log G(edge)
        else:
            at_t = 0.5 * ((t - peak_at) / width) ** 2
            at_edge = 0.5 * ((edge - peak_at) / width) ** 2
        ratio = jnp.clip(((t - peak_at) / (edge - peak_at)) ** 2, 0.0, 1.0)  # at_t / at_edge
        direct = (jnp.exp(-at_t) - jnp.exp(-at_edge)) / (1.0 - jnp.exp(-at_edge))
        gentle_edge = jnp.clip(at_edge, 1e-30, 1.0)  # only used where at_edge is in this range
        gentle = (
            jnp.exp(-gentle_edge) * jnp.expm1(gentle_edge - jnp.minimum(at_t, gentle_edge)) / -jnp.expm1(-gentle_edge)
        )
        shape = jnp.where(at_edge > 1.0, direct, jnp.where(at_edge > 1e-30, gentle, 1.0 - ratio))
        return base + (peak - base) * jnp.clip(shape, 0.0, 1.0)

    return function
