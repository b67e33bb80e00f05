"""`tail`: the channel's final value (1, the adult body, unless the channel declares `final`)."""

from __future__ import annotations

from fractions import Fraction
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.language.float32_limits import UNIT
from smol_dsl.language.shapes.base import Compiled, Line, Shape

if TYPE_CHECKING:
    from smol_dsl.language.shapes.base import SegmentContext
    from smol_dsl.language.symbolic import Piece, SymbolicSegment


class Tail(Shape):
    keyword = "tail"
    usage = "tail"
    meaning = "`1`, or the channel's `final` value"

    def compile(self, segment: SegmentContext) -> Compiled:
        return self.single_piece(segment, segment.final)

    def float32_error(self, segment: SymbolicSegment, piece: Piece, low: float, high: float) -> float:
        """0 when the value is a float32 (1, 0.5), else one rounding of it (beyond float32's range
        too: step 7 then refuses the value by its range)."""
        value = piece.expr
        with np.errstate(over="ignore"):
            single = float(np.float32(float(value)))
        if not np.isfinite(single):
            return UNIT * abs(high)
        rounded = Fraction(single)
        exact = value.is_Rational and rounded == Fraction(int(value.p), int(value.q))
        return 0.0 if exact else UNIT * abs(high)

    def evaluation(self, segment: SymbolicSegment) -> Line:
        return Line(float(segment.pieces[0].expr))
