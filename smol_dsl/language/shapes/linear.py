"""`linear a -> b`: a straight line from a at the segment's start to b at its end."""

from __future__ import annotations

from typing import TYPE_CHECKING

import sympy as sp

from smol_dsl.language.shapes.base import Compiled, Line, Shape
from smol_dsl.language.symbolic import T

if TYPE_CHECKING:
    from smol_dsl.language import tree
    from smol_dsl.language.shapes.base import SegmentContext
    from smol_dsl.language.symbolic import SymbolicSegment


class Linear(Shape):
    keyword = "linear"
    usage = "linear a -> b"
    meaning = "`a + (b − a)·(t − s)/(e − s)`"
    syntax_hint = "`linear` takes two values joined by `->`, e.g. `linear 1.5 -> 1`"
    syntax_mistakes = ("0% .. 90%: linear 1 2", "0% .. 90%: linear 1 to 2", "0% .. 90%: linear 1 .. 2")
    float32_ulps = 4

    def compile(self, segment: SegmentContext, start: tree.Expr, end: tree.Expr) -> Compiled:
        a, b = segment.value(start, "start value"), segment.value(end, "end value")
        expr = a + (b - a) * (T - segment.start) / (segment.end - segment.start)
        return self.single_piece(segment, sp.expand(expr))

    def evaluation(self, segment: SymbolicSegment) -> Line:
        at_start = segment.pieces[0].expr.subs(T, segment.start)
        at_end = segment.pieces[0].expr.subs(T, segment.end)
        return Line(float(at_start), float(at_end - at_start))
