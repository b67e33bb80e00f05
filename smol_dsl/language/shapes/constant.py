"""`constant v`: alpha = v."""

from __future__ import annotations

from typing import TYPE_CHECKING

from smol_dsl.language.shapes.base import Compiled, Line, Shape

if TYPE_CHECKING:
    from smol_dsl.language import tree
    from smol_dsl.language.shapes.base import SegmentContext
    from smol_dsl.language.symbolic import SymbolicSegment


class Constant(Shape):
    keyword = "constant"
    usage = "constant v"
    meaning = "`v`"
    float32_ulps = 1

    def compile(self, segment: SegmentContext, value: tree.Expr) -> Compiled:
        return self.single_piece(segment, segment.value(value, "value"))

    def evaluation(self, segment: SymbolicSegment) -> Line:
        return Line(float(segment.pieces[0].expr))
