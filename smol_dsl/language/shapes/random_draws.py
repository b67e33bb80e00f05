"""`random lo .. hi [every d]`: a fresh uniform draw in [lo, hi] every d of the run, from a JAX key.

(Not `random.py`, which would read as the standard library's module.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import TYPE_CHECKING

import sympy as sp

from smol_dsl.errors import ScheduleError
from smol_dsl.language.prover import Extrema, Monotone, real
from smol_dsl.language.shapes.base import Compiled, Drawn, Shape
from smol_dsl.language.symbolic import MAX_RANDOM_DRAWS, Draws, Piece, SymbolicSegment, T, number_text

if TYPE_CHECKING:
    from smol_dsl.language import tree
    from smol_dsl.language.shapes.base import SegmentContext

DEFAULT_RANDOM_EVERY = sp.Rational(1, 100)  # "a new alpha every schedule step" (1%)


@dataclass(frozen=True)
class Uniform:
    """alpha = low + (high - low) * u[k], u[k] ~ U[0, 1), k = the draw of t."""

    low: sp.Expr
    high: sp.Expr


class Random(Shape):
    keyword = "random"
    usage = "random lo .. hi [every d]"
    meaning = "`lo + (hi − lo)·u_k`, a fresh uniform draw for each step of length d, below"
    syntax_hint = "`random` is written `random LOW .. HIGH [every STEP]`, e.g. `random 0.5 .. 1.5 every 1%`"
    syntax_mistakes = ("0% .. 90%: random 1 2", "0% .. 90%: random 1 -> 2", "0% .. 90%: random 1 .. 2 every")
    float32_ulps = 4

    def compile(self, segment: SegmentContext, low: tree.Expr, high: tree.Expr, every: tree.Expr | None) -> Compiled:
        label = segment.label
        lo, hi = segment.value(low, "low end"), segment.value(high, "high end")
        if hi < lo:
            raise ScheduleError(
                f"the range of {label} is reversed: {number_text(lo)} .. {number_text(hi)}",
                span=low.span,
                hint=f"write `random {number_text(hi)} .. {number_text(lo)}`",
            )
        if every is None:
            step = DEFAULT_RANDOM_EVERY
        else:
            step = segment.position(every, "resolution")
            if step <= 0:
                raise ScheduleError(
                    f"the resolution of {label} must be positive",
                    span=every.span,
                    hint="`every 1%` draws a new alpha every 1% of the run",
                )
        length = segment.end - segment.start
        count = math.ceil(Fraction(int(length.p), int(length.q)) / Fraction(int(step.p), int(step.q)))
        if count > MAX_RANDOM_DRAWS:
            raise ScheduleError(
                f"{label} would need {count} random draws",
                span=every.span if every is not None else segment.span,
                hint=f"use a coarser resolution; at most {MAX_RANDOM_DRAWS} draws per segment",
            )
        draw = sp.Function(f"u_{segment.index + 1}")
        expr = lo + (hi - lo) * draw(sp.floor((T - segment.start) / step))
        return Compiled(
            (Piece(expr, segment.start, segment.end, self.keyword),),
            params=Uniform(lo, hi),
            draws=Draws(step, count, draw),
        )

    def prove(self, segment: SymbolicSegment, piece: Piece) -> tuple[Extrema, Monotone]:
        low, high = real(segment.params.low), real(segment.params.high)
        assert low is not None and high is not None
        return Extrema(low, high, True), "constant" if low == high else "random"

    def is_constant(self, segment: SymbolicSegment, value: sp.Expr) -> bool:
        return bool(segment.params.low == value and segment.params.high == value)

    def evaluation(self, segment: SymbolicSegment) -> Drawn:
        return Drawn(float(segment.params.low), float(segment.params.high - segment.params.low))
