"""`tail`: alpha = 1, the adult body every schedule ends with."""

from __future__ import annotations

from typing import TYPE_CHECKING

import sympy as sp

from smol_dsl.language.shapes.base import Compiled, Line, Shape

if TYPE_CHECKING:
    from smol_dsl.language.compiler import SegmentContext
    from smol_dsl.language.symbolic import SymbolicSegment


class Tail(Shape):
    keyword = "tail"
    usage = "tail"
    meaning = "`1`"
    float32_ulps = 0

    def compile(self, segment: SegmentContext) -> Compiled:
        return self.single_piece(segment, sp.Integer(1))

    def evaluation(self, segment: SymbolicSegment) -> Line:
        return Line(1.0)
