"""Proof that the float32 program evaluating an `expr` segment is finite and close to exact.

Verification proves facts about the exact alpha(t); the runner evaluates it in float32 (JAX's
default), where `(1e20*t)**2` overflows and `1/(t - 0.5 + 1e-30)` divides by a rounded 0.
This module bounds the float32 program that `smol_dsl.language.jaxify.to_jax` builds from the same
sympy tree, node by node, by a running error analysis over interval arithmetic:

- every node's exact value lies in an interval (mpmath `iv`, outward rounding), and the float32
  value differs from it by at most an absolute error bound carried along;
- every intermediate value, plus its error, stays within `SAFE_MAX` (2**120, float32 overflows
  at 2**128);
- every divisor, logarithm argument and base of a negative power stays at least `SAFE_MIN`
  (2**-120) away from 0 *after* its rounding error is taken off, so cancellation cannot make
  it 0 (float32 flushes values below 2**-126 to 0 on CPUs);
- rounding is float32's unit roundoff per operation, XLA's transcendental functions within
  `FUNCTION_ULPS` units, and every underflow an absolute `TINY`.

The segment is split into sub-intervals (bisected where a bound fails) so that interval
arithmetic's overestimation does not reject sensible expressions. The result is the largest
error over the segment; `smol_dsl.language.segment_rules` requires alpha minus that error to
stay positive. `located_float32_error` is the proof as a shape's hook uses it (`Shape.float32_error`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import sympy as sp
from mpmath import iv

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language.float32_limits import SAFE_MAX, SAFE_MIN, TINY, UNIT
from smol_dsl.language.prover import ENCLOSURE_SECONDS, VerificationTimeoutError, time_limit
from smol_dsl.language.symbolic import T

FUNCTION_ULPS = 8
"""Error of XLA's float32 exp, log, sin, cos, tanh and pow, in units of roundoff (generous)."""
PIECES = 16
"""Sub-intervals of a segment checked first."""
MAX_DEPTH = 10
"""Bisections of a sub-interval before a failing bound counts as a failure."""


class Float32RangeError(Exception):
    """The float32 program of an expression cannot be shown finite: which node, and why."""

    def __init__(self, node: sp.Expr, reason: str, where: tuple[float, float]) -> None:
        super().__init__(reason)
        self.node = node
        self.reason = reason
        self.where = where


@dataclass(frozen=True)
class _Value:
    """A node over a sub-interval: its exact values lie in `exact`, float32 is within `error`."""

    exact: Any  # mpmath iv.mpf
    error: float

    @property
    def low(self) -> float:
        return float(self.exact.a)

    @property
    def high(self) -> float:
        return float(self.exact.b)

    @property
    def magnitude(self) -> float:
        """The largest |value| the float32 program can hold."""
        return max(abs(self.low), abs(self.high)) + self.error

    @property
    def distance_from_zero(self) -> float:
        """How far the float32 value is certain to stay from 0 (<= 0 if it may reach 0)."""
        if self.low > 0:
            return self.low - self.error
        if self.high < 0:
            return -self.high - self.error
        return -1.0


def _rounded(value: float) -> float:
    """One float32 rounding of a value of this magnitude, plus a possible underflow."""
    return UNIT * value + TINY


def _slack(error: float) -> float:
    return error * (1 + 1e-9)  # the float64 arithmetic of the bound itself


def float32_error(expr: sp.Expr, start: sp.Rational, end: sp.Rational) -> float:
    """The largest |float32 - exact| of `expr` over t in [start, end].

    Raises `Float32RangeError` naming the sub-expression that may overflow, or divide by a value
    that rounds to 0, somewhere on the interval.
    """
    start_f, end_f = _iv_rational(start), _iv_rational(end)
    width = end_f - start_f
    worst = 0.0
    for k in range(PIECES):
        a = start_f + width * k / PIECES
        b = start_f + width * (k + 1) / PIECES if k + 1 < PIECES else end_f
        worst = max(worst, _checked(expr, a, b, 0))
    return worst


def located_float32_error(
    expr: sp.Expr, start: sp.Rational, end: sp.Rational, *, where: str, span: Span, quantity: str = "alpha"
) -> float:
    """`float32_error` within the enclosure time budget, or a ScheduleError at `span` that names
    the segment (`where`) and the sub-expression that fails; `quantity` is what the hint calls
    the channel's value."""
    try:
        with time_limit(ENCLOSURE_SECONDS):
            return float32_error(expr, start, end)
    except Float32RangeError as failure:
        part = _short(failure.node)
        low, high = failure.where
        at = "" if not failure.node.has(T) else f" for t in {low:.4g} .. {high:.4g}"
        raise ScheduleError(
            f"{where} cannot be evaluated safely in float32: `{part}` {failure.reason}{at}",
            span=span,
            hint=f"{quantity} is computed in 32-bit floats (JAX's default): keep every part of the expression between "
            "about 1e-36 and 1e36 in size, and divisors and logarithm arguments well away from 0 "
            "(e.g. rescale `(1e20*t)**2 / 1e40` as `t**2`)",
        ) from None
    except VerificationTimeoutError:
        raise ScheduleError(
            f"could not bound the float32 evaluation of {where} within the time limit",
            span=span,
            hint="simplify the expression or split the segment",
        ) from None


def _short(node: sp.Expr) -> str:
    text = str(node)
    if len(text) > 40 or any(len(word) > 12 for word in text.replace("*", " ").split()):
        text = str(sp.N(node, 4))
    return text if len(text) <= 60 else text[:57] + "..."


def _iv_rational(value: sp.Rational) -> Any:
    return iv.mpf(int(value.p)) / iv.mpf(int(value.q))


def _checked(expr: sp.Expr, a: Any, b: Any, depth: int) -> float:
    try:
        return _evaluate(expr, iv.mpf([a.a, b.b]), {}).error
    except Float32RangeError:
        if depth >= MAX_DEPTH:
            raise
    middle = (a + b) / 2
    return max(_checked(expr, a, middle, depth + 1), _checked(expr, middle, b, depth + 1))


def _fail(node: sp.Expr, reason: str, x: Any) -> Float32RangeError:
    return Float32RangeError(node, reason, (float(x.a), float(x.b)))


def _evaluate(node: sp.Expr, x: Any, memo: dict[sp.Expr, _Value]) -> _Value:
    if node in memo:
        return memo[node]
    value = _node(node, x, memo)
    if not math.isfinite(value.error) or value.magnitude > SAFE_MAX:
        raise _fail(node, f"reaches about {value.magnitude:.3g}, beyond float32's safe range (2**120)", x)
    memo[node] = value
    return value


def _constant(node: sp.Expr, x: Any) -> _Value:
    if node.is_Rational:
        exact = _iv_rational(node)
    elif node == sp.pi:
        exact = iv.pi
    elif node == sp.E:
        exact = iv.e
    else:
        exact = iv.mpf(str(sp.N(node, 40)))
    magnitude = max(abs(float(exact.a)), abs(float(exact.b)))
    if magnitude > SAFE_MAX:
        raise _fail(node, "is beyond float32's safe range (2**120, about 1.3e36)", x)
    return _Value(exact, _slack(_rounded(magnitude) * 1.01))  # rounded twice: to float64, then float32


def _node(node: sp.Expr, x: Any, memo: dict[sp.Expr, _Value]) -> _Value:
    if node == T:
        return _Value(x, 0.0)  # the float32 t is the input; the exact value is taken at it
    if not node.free_symbols:
        return _constant(node, x)
    if node.is_Add:
        return _add([_evaluate(arg, x, memo) for arg in node.args])
    if node.is_Mul:
        return _mul([_evaluate(arg, x, memo) for arg in node.args], node, x)
    if node.is_Pow:
        return _power(node, x, memo)
    args = [_evaluate(arg, x, memo) for arg in node.args]
    for kind, bound in _FUNCTIONS:
        if isinstance(node, kind):
            return bound(node, args, x)
    raise _fail(node, f"is a {type(node).__name__}, which smol-dsl cannot bound in float32", x)


def _sin_cos(node: sp.Expr, args: list[_Value], x: Any) -> _Value:
    (arg,) = args
    exact = iv.sin(arg.exact) if isinstance(node, sp.sin) else iv.cos(arg.exact)
    # XLA reduces the argument in float32, so its error grows with the argument's size.
    error = arg.error + FUNCTION_ULPS * UNIT * (1 + arg.magnitude)
    return _Value(exact, _slack(min(error, 2.0)))


def _tanh(node: sp.Expr, args: list[_Value], x: Any) -> _Value:
    (arg,) = args
    exact = 1 - 2 / (iv.exp(2 * arg.exact) + 1)
    return _Value(exact, _slack(min(arg.error + FUNCTION_ULPS * UNIT, 2.0)))


def _abs(node: sp.Expr, args: list[_Value], x: Any) -> _Value:
    return _Value(abs(args[0].exact), args[0].error)


def _min_max(node: sp.Expr, args: list[_Value], x: Any) -> _Value:
    pick = min if isinstance(node, sp.Min) else max
    exact = iv.mpf([pick(a.exact.a for a in args), pick(a.exact.b for a in args)])
    return _Value(exact, max(a.error for a in args))


_FUNCTIONS: tuple[tuple[type | tuple[type, ...], Callable[[sp.Expr, list[_Value], Any], _Value]], ...] = (
    (sp.exp, lambda node, args, x: _exp(args[0], node, x)),
    (sp.log, lambda node, args, x: _log(args[0], node, x)),
    ((sp.sin, sp.cos), _sin_cos),
    (sp.tanh, _tanh),
    (sp.Abs, _abs),
    ((sp.Min, sp.Max), _min_max),
)
"""How each function's value and error are bounded from its arguments'."""


def _add(args: list[_Value]) -> _Value:
    exact = args[0].exact
    for arg in args[1:]:
        exact = exact + arg.exact
    # every partial sum is at most the sum of the magnitudes; each addition rounds once
    partial = sum(a.magnitude for a in args)
    error = sum(a.error for a in args) + (len(args) - 1) * _rounded(partial)
    return _Value(exact, _slack(error))


def _mul(args: list[_Value], node: sp.Expr, x: Any) -> _Value:
    product = args[0]
    for arg in args[1:]:  # left to right, as jaxify multiplies
        exact = product.exact * arg.exact
        a, b = max(abs(float(product.exact.a)), abs(float(product.exact.b))), arg.magnitude - arg.error
        error = a * arg.error + b * product.error + product.error * arg.error
        magnitude = max(abs(float(exact.a)), abs(float(exact.b))) + error
        if not math.isfinite(magnitude) or magnitude > SAFE_MAX:
            raise _fail(node, f"reaches about {magnitude:.3g} in a product, beyond float32's safe range", x)
        product = _Value(exact, _slack(error + _rounded(magnitude)))
    return product


def _reciprocal(value: _Value, node: sp.Expr, x: Any) -> _Value:
    distance = value.distance_from_zero
    if distance < SAFE_MIN:
        # the domain check proved the exact divisor non-zero: reaching 0 here is rounding
        raise _fail(node, "divides by a value that can round to 0 in float32", x)
    exact = 1 / value.exact
    error = value.error / (distance * (distance + value.error)) + _rounded(1 / distance)
    return _Value(exact, _slack(error))


def _power(node: sp.Expr, x: Any, memo: dict[sp.Expr, _Value]) -> _Value:
    base_node, exponent = node.args
    base = _evaluate(base_node, x, memo)
    if exponent.is_Integer:
        n = int(exponent)
        positive = _integer_power(base, abs(n), node, x) if n != 0 else _Value(iv.mpf(1), 0.0)
        return positive if n >= 0 else _reciprocal(positive, node, x)
    if exponent.is_Rational and exponent > 0:
        # x**r for 0 < r: the domain check proved x >= 0 (outward rounding may still give the
        # interval a negative end) and jaxify clamps at 0. Hoelder bounds the error for r <= 1.
        r = float(exponent)
        exact = iv.mpf([0, 0]) if base.high <= 0 else _real_power(base.exact, exponent)
        top = base.magnitude
        error = base.error**r if r <= 1 else r * top ** (r - 1) * base.error
        error += FUNCTION_ULPS * UNIT * top**r + TINY
        return _Value(exact, _slack(error))
    # b**e = exp(e * log(b)) with b proven positive by the domain check
    if base.distance_from_zero < SAFE_MIN:
        raise _fail(node, "raises a value that can round to 0 in float32 to a negative or variable power", x)
    logarithm = _log(base, node, x)
    power = _mul([_evaluate(exponent, x, memo), logarithm], node, x)
    return _exp(power, node, x)


def _real_power(exact: Any, exponent: sp.Rational) -> Any:
    low = max(float(exact.a), 0.0)
    r = iv.mpf(int(exponent.p)) / iv.mpf(int(exponent.q))
    at_low = iv.mpf(0) if low == 0 else iv.exp(r * iv.log(iv.mpf(low)))
    at_high = iv.exp(r * iv.log(iv.mpf(exact.b)))
    return iv.mpf([at_low.a, at_high.b])


def _integer_power(base: _Value, n: int, node: sp.Expr, x: Any) -> _Value:
    exact = base.exact**n
    top = base.magnitude
    if n * math.log2(max(top, 1e-300)) > 120:
        raise _fail(node, f"reaches about {top:.3g}**{n}, beyond float32's safe range", x)
    # |(v + d)**n - v**n| <= (M + d)**n - M**n for |v| <= M; squarings round ~2 log2(n) times
    error = (top**n - (top - base.error) ** n) + 2 * max(1, math.ceil(math.log2(n + 1))) * _rounded(top**n)
    return _Value(exact, _slack(error))


def _exp(arg: _Value, node: sp.Expr, x: Any) -> _Value:
    top = float(arg.exact.b) + arg.error
    if top > math.log(SAFE_MAX):
        raise _fail(node, f"is exp of up to {top:.3g}, beyond float32's safe range (exp(83))", x)
    exact = iv.exp(arg.exact)
    largest = math.exp(top)
    error = math.exp(float(arg.exact.b)) * math.expm1(arg.error) + FUNCTION_ULPS * _rounded(largest)
    return _Value(exact, _slack(error))


def _log(arg: _Value, node: sp.Expr, x: Any) -> _Value:
    distance = arg.distance_from_zero
    if arg.low <= 0 or distance < SAFE_MIN:
        raise _fail(node, "takes the logarithm of a value that can round to 0 in float32", x)
    exact = iv.log(arg.exact)
    magnitude = max(abs(float(exact.a)), abs(float(exact.b)))
    error = -math.log1p(-arg.error / float(arg.exact.a)) + FUNCTION_ULPS * _rounded(magnitude)
    return _Value(exact, _slack(error))
