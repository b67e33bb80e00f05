"""Proving facts about a real function of t on a closed interval, symbolically.

- `extrema`: exact minimum and maximum from sympy's critical points; where sympy cannot
  find them, a rigorous enclosure by interval arithmetic (mpmath's `iv`, outward rounding,
  on sub-intervals refined by bisection where the bound is decided).
- `slope_sign`: monotonicity from the sign of the derivative, by the same two methods.
- `domain_violation`: whether the function is real everywhere on the interval (square
  roots and logarithms of non-negative / positive arguments, no division by zero).

Each method runs under a time budget, so untrusted input cannot hang verification.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import heapq
import math
import operator
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from itertools import pairwise
from typing import Any, Literal

import sympy as sp
from mpmath import iv
from sympy.calculus.util import maximum, minimum

from smol_dsl.language.symbolic import T

EXACT_SECONDS = 2.0
"""Budget for one exact sympy method (extrema, monotonicity, simplification)."""
ENCLOSURE_SECONDS = 10.0
"""Budget for one interval-arithmetic enclosure."""
ENCLOSURE_PIECES = 64
"""Sub-intervals of the first enclosure."""
REFINEMENTS = 256
"""Bisections spent tightening each side of an enclosure."""
RETRY_SECONDS = 0.05
"""CPU time between alarms after a budget has run out, until one stops the method."""
SLOPE_ROUNDING = 1e-12
"""Relative slack for the sign of a slope from interval arithmetic (a few ulps of rounding)."""

Monotone = Literal["constant", "increasing", "decreasing", "random", "neither", "unknown"]


class VerificationTimeoutError(Exception):
    """A symbolic method ran out of its time budget."""


@contextlib.contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Raise VerificationTimeoutError after `seconds` of the main thread's CPU time under the
    limit (main thread only; elsewhere no limit).

    CPU time, not wall-clock time, so that a busy machine gives the same verdicts as an idle
    one: sympy's methods are CPU-bound. The thread's own, because the process's other
    threads (JAX's runtime, say) spend the process's CPU time too; and the garbage collector
    is paused under the limit, because a full collection of a large heap (a long test
    session's) costs seconds that are not the method's. Python ignores an exception raised
    while the signal interrupts a weak-reference callback, so the alarm fires again every
    RETRY_SECONDS of process CPU time until the exception reaches the code under the limit.
    """
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "setitimer"):
        yield
        return
    armed = True
    started = time.thread_time()

    def on_alarm(signum: int, frame: Any) -> None:
        if armed and time.thread_time() - started >= seconds:
            raise VerificationTimeoutError

    collecting = gc.isenabled()
    gc.disable()
    previous = signal.signal(signal.SIGPROF, on_alarm)
    signal.setitimer(signal.ITIMER_PROF, seconds, RETRY_SECONDS)  # process time: never before the thread's
    try:
        yield
    finally:
        try:
            armed = False
        finally:  # even if the alarm raised just before `armed` was cleared
            signal.setitimer(signal.ITIMER_PROF, 0)
            signal.signal(signal.SIGPROF, previous)
            if collecting:
                gc.enable()


_SYMPY_FAILURES = (
    NotImplementedError,
    ValueError,
    TypeError,
    AttributeError,
    RecursionError,
    ArithmeticError,  # OverflowError: sympy's set code lists the roots of sin(1e20*t) as a range
    LookupError,
    VerificationTimeoutError,
)
"""What a sympy method may raise when it cannot handle an expression: the next method takes over."""


def real(value: sp.Expr | None) -> float | None:
    """A finite real float of an exact value, or None."""
    if value is None or value.has(sp.zoo, sp.nan, sp.oo, -sp.oo, sp.AccumBounds):
        return None
    try:
        number = complex(sp.N(value, 30))
    except OverflowError:
        return math.inf if value.is_positive else -math.inf if value.is_negative else None
    except (TypeError, ValueError):
        return None
    if math.isnan(number.real) or abs(number.imag) > 1e-30:
        return None
    return number.real  # may be +-inf for a finite value beyond float64


def simplified(expr: sp.Expr) -> sp.Expr:
    """sympy's simplification of expr if it finishes in time and is no more complex."""
    if not expr.has(T) or expr.is_polynomial(T):
        return expr
    try:
        with time_limit(EXACT_SECONDS):
            candidate = sp.simplify(expr)
    except _SYMPY_FAILURES:
        return expr
    return candidate if sp.count_ops(candidate) <= sp.count_ops(expr) else expr


def is_zero(expr: sp.Expr) -> bool:
    """Whether expr is identically zero, as far as sympy can prove within the budget."""
    if expr.is_zero:
        return True
    try:
        with time_limit(EXACT_SECONDS):
            return bool(sp.simplify(expr) == 0)
    except _SYMPY_FAILURES:
        return False


# ---------------------------------------------------------------- interval arithmetic


class _NoEnclosureError(Exception):
    """Interval arithmetic cannot bound this expression (e.g. a log of an interval reaching 0)."""


def _iv_exact(value: sp.Rational) -> Any:
    return iv.mpf(int(value.p)) / iv.mpf(int(value.q))


IntervalFunction = Callable[[Any], Any]
"""An expression of t compiled for interval arithmetic: the interval of t to the interval of
the expression."""
CompileOperation = Callable[[sp.Expr, tuple[IntervalFunction, ...]], IntervalFunction]
"""An operation's compiler: from the expression and its arguments' functions, its own."""


@functools.lru_cache(maxsize=64)
def interval_function(expr: sp.Expr) -> IntervalFunction:
    """expr compiled once for rigorous interval arithmetic (mpmath.iv, outward rounding): its
    tree walked and its constants converted here, not at each of the many sub-intervals an
    enclosure evaluates. A _NoEnclosureError for an operation the arithmetic lacks."""
    if expr == T:
        return _identity
    constant = _iv_constant(expr)
    if constant is not None:
        return lambda x: constant
    args = tuple(interval_function(arg) for arg in expr.args)
    for kind, compile_operation in _IV_OPERATIONS:
        if isinstance(expr, kind):
            return compile_operation(expr, args)
    raise _NoEnclosureError(type(expr).__name__)


def _identity(x: Any) -> Any:
    return x


def _iv_constant(expr: sp.Expr) -> Any | None:
    """The interval of a number the language writes (a rational, a float, pi, e); None otherwise."""
    if expr.is_Rational:
        return _iv_exact(expr)
    if expr.is_Float:
        return iv.mpf(str(expr))
    if expr == sp.pi:
        return iv.pi
    if expr == sp.E:
        return iv.e
    return None


def _iv_power(expr: sp.Expr, args: tuple[IntervalFunction, ...]) -> IntervalFunction:
    base, exponent = args
    power = expr.args[1]
    if power.is_Integer:
        n = int(power)
        if n >= 0:
            return lambda x: base(x) ** n
        return lambda x: 1 / base(x) ** -n
    if power == sp.Rational(1, 2):
        return lambda x: iv.sqrt(base(x))

    def general(x: Any) -> Any:
        b, e = base(x), exponent(x)  # both evaluated, in order, as for every operation
        return iv.exp(e * iv.log(b))

    return general


def _iv_min_max(expr: sp.Expr, args: tuple[IntervalFunction, ...]) -> IntervalFunction:
    pick = min if isinstance(expr, sp.Min) else max

    def extreme(x: Any) -> Any:
        values = [f(x) for f in args]
        return iv.mpf([pick(a.a for a in values), pick(a.b for a in values)])

    return extreme


def _iv_reduce(combine: Callable[[Any, Any], Any]) -> CompileOperation:
    def compile_operation(expr: sp.Expr, args: tuple[IntervalFunction, ...]) -> IntervalFunction:
        return lambda x: functools.reduce(combine, [f(x) for f in args])

    return compile_operation


def _iv_unary(apply: Callable[[Any], Any]) -> CompileOperation:
    def compile_operation(expr: sp.Expr, args: tuple[IntervalFunction, ...]) -> IntervalFunction:
        (arg,) = args
        return lambda x: apply(arg(x))

    return compile_operation


_IV_OPERATIONS: tuple[tuple[type | tuple[type, ...], CompileOperation], ...] = (
    (sp.Add, _iv_reduce(operator.add)),
    (sp.Mul, _iv_reduce(operator.mul)),
    (sp.Pow, _iv_power),
    (sp.exp, _iv_unary(iv.exp)),
    (sp.log, _iv_unary(iv.log)),
    (sp.sin, _iv_unary(iv.sin)),
    (sp.cos, _iv_unary(iv.cos)),
    # tanh(x) = 1 - 2 / (exp(2x) + 1): x appears once, so the enclosure stays tight
    (sp.tanh, _iv_unary(lambda a: 1 - 2 / (iv.exp(2 * a) + 1))),
    (sp.Abs, _iv_unary(abs)),
    ((sp.Min, sp.Max), _iv_min_max),
)
"""Each operation of the language on intervals: from its arguments' compiled functions, its own."""


def interval_value(expr: sp.Expr, start: sp.Rational, end: sp.Rational) -> tuple[float, float] | None:
    """(low, high) enclosing expr(t) for every t in [start, end], or None if it cannot be bounded."""
    x = iv.mpf([_iv_exact(start).a, _iv_exact(end).b])
    try:
        value = interval_function(expr)(x)
    except (_NoEnclosureError, ValueError, ZeroDivisionError, TypeError):
        return None
    low, high = float(value.a), float(value.b)
    if not (math.isfinite(low) and math.isfinite(high)):
        return None
    return low, high


def enclosure(expr: sp.Expr, start: sp.Rational, end: sp.Rational) -> tuple[float, float] | None:
    """Rigorous (low, high) with low <= expr(t) <= high for t in [start, end], or None.

    Starts from ENCLOSURE_PIECES sub-intervals, then bisects the sub-interval that decides
    the lower bound, and the one that decides the upper bound, REFINEMENTS times each.
    """
    edges = [start + (end - start) * sp.Rational(k, ENCLOSURE_PIECES) for k in range(ENCLOSURE_PIECES + 1)]
    pieces: list[tuple[sp.Rational, sp.Rational, float, float]] = []
    for a, b in pairwise(edges):
        bounds = interval_value(expr, a, b)
        if bounds is None:
            return None
        pieces.append((a, b, *bounds))

    def refine(side: int) -> float:
        sign = 1 if side == 2 else -1  # a heap on low ascending, or on high descending
        heap = [(sign * p[side], i, p) for i, p in enumerate(pieces)]
        heapq.heapify(heap)
        counter = len(heap)
        for _ in range(REFINEMENTS):
            _, _, (a, b, low, high) = heapq.heappop(heap)
            middle = (a + b) / 2
            for left, right in ((a, middle), (middle, b)):
                bounds = interval_value(expr, left, right) or (low, high)
                # a child's bound is never looser than its parent's
                child = (left, right, max(bounds[0], low), min(bounds[1], high))
                heapq.heappush(heap, (sign * child[side], counter, child))
                counter += 1
        return sign * heap[0][0]

    return refine(2), refine(3)


# ---------------------------------------------------------------- the facts


@dataclass(frozen=True)
class Extrema:
    low: float
    high: float
    exact: bool  # False: an enclosure (low <= min, max <= high), not the extrema themselves


def extrema(expr: sp.Expr, start: sp.Rational, end: sp.Rational) -> Extrema | None:
    """Minimum and maximum of expr over [start, end]; None if not finite and real there."""
    if not expr.has(T):
        value = real(expr)
        return None if value is None else Extrema(value, value, True)
    interval = sp.Interval(start, end)
    try:
        with time_limit(EXACT_SECONDS):
            low, high = real(minimum(expr, T, interval)), real(maximum(expr, T, interval))
        if low is not None and high is not None:
            return Extrema(low, high, True)
    except _SYMPY_FAILURES:
        pass
    with time_limit(ENCLOSURE_SECONDS):  # a time-out here is reported as one
        enclosed = enclosure(expr, start, end)
    return None if enclosed is None else Extrema(*enclosed, False)


def slope_sign(expr: sp.Expr, start: sp.Rational, end: sp.Rational) -> Monotone:
    """'increasing' / 'decreasing' (non-strict) or 'constant' where proven, 'neither' where
    the slope is shown to take both signs, 'unknown' where nothing could be decided.

    Interval arithmetic on the derivative is cheap when it decides; otherwise sympy is
    asked, and last a witness of each sign can prove that the piece is not monotone.
    """
    if not expr.has(T):
        return "constant"
    slope = sp.diff(expr, T)
    if slope.is_zero or simplified(slope) == 0:
        return "constant"
    return _enclosed_sign(slope, start, end) or _sympy_sign(expr, start, end) or _witnessed_sign(slope, start, end)


def _enclosed_sign(slope: sp.Expr, start: sp.Rational, end: sp.Rational) -> Monotone | None:
    """The sign of the slope from an interval enclosure of it, where it decides."""
    try:
        with time_limit(ENCLOSURE_SECONDS):
            enclosed = enclosure(slope, start, end)
    except _SYMPY_FAILURES:
        enclosed = None
    if enclosed is None:
        return None
    # Outward rounding widens an enclosure by a few ulps, so a slope that is exactly 0
    # somewhere (at the end of an ease, say) would never be proven >= 0; accept a sign
    # up to SLOPE_ROUNDING relative to the slope's scale.
    slack = SLOPE_ROUNDING * max(1.0, abs(enclosed[0]), abs(enclosed[1]))
    if enclosed[0] >= -slack:
        return "increasing"
    if enclosed[1] <= slack:
        return "decreasing"
    return None


def _sympy_sign(expr: sp.Expr, start: sp.Rational, end: sp.Rational) -> Monotone | None:
    """sympy's proof of monotonicity on the open interval (a derivative may be infinite at an
    end, as for sqrt); the value is continuous on the closed interval, so that decides it there too."""
    interval = sp.Interval.open(start, end)
    try:
        with time_limit(EXACT_SECONDS):
            if sp.is_increasing(expr, interval, T):
                return "increasing"
            if sp.is_decreasing(expr, interval, T):
                return "decreasing"
    except _SYMPY_FAILURES:
        pass
    return None


def _witnessed_sign(slope: sp.Expr, start: sp.Rational, end: sp.Rational) -> Monotone:
    """'neither' where the slope, evaluated exactly at 31 interior points, takes both signs."""
    signs = set()
    for k in range(1, 32):
        value = real(slope.subs(T, start + (end - start) * sp.Rational(k, 32)))
        if value is not None and value != 0:
            signs.add(value > 0)
    return "neither" if signs == {True, False} else "unknown"


def _requirements(expr: sp.Expr) -> Iterator[tuple[sp.Expr, str, str]]:
    """(argument, rule, what) for every sub-expression that is real only on part of the line."""
    for node in sp.preorder_traversal(expr):
        if not getattr(node, "has", None) or not node.has(T):
            continue
        if isinstance(node, sp.log):
            yield node.args[0], "positive", "a logarithm"
        elif node.is_Pow:
            base, exponent = node.args
            if not base.has(T):
                if not (base.is_positive or base == sp.E):
                    yield base, "positive", "a power with a variable exponent"
                continue
            if exponent.is_integer:
                if exponent.is_negative:
                    yield base, "nonzero", "a division"
            elif exponent.is_positive:
                yield base, "nonnegative", "a square root" if exponent == sp.Rational(1, 2) else "a fractional power"
            else:
                yield base, "positive", "a negative fractional power" if exponent.is_number else "a power"


def domain_violation(expr: sp.Expr, start: sp.Rational, end: sp.Rational) -> str | None:
    """Why expr is not real on all of [start, end], or None when that is proven."""
    for argument, rule, what in _requirements(expr):
        bounds = extrema(argument, start, end)
        if bounds is None:
            return f"the argument of {what} ({argument}) could not be bounded"
        low, high = bounds.low, bounds.high
        proven = {
            "positive": low > 0,
            "nonnegative": low >= 0,
            "nonzero": low > 0 or high < 0,
        }[rule]
        if not proven:
            needs = {"positive": "positive", "nonnegative": "non-negative", "nonzero": "non-zero"}[rule]
            found = f"goes down to {low:.6g}" if rule != "nonzero" else f"ranges over {low:.6g} .. {high:.6g}"
            approx = "" if bounds.exact else " (by interval arithmetic)"
            return f"{what} needs a {needs} argument, but {argument} {found}{approx}"
    return None
