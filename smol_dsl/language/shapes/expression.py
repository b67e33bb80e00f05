"""`expr E`: any expression of t (the run's progress) and u (the segment's progress).

The template of a shape given by a formula: the base class's hooks prove it with sympy,
bound its float32 evaluation by the running error analysis, and evaluate it in JAX.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from smol_dsl.language.shapes.base import Compiled, Shape

if TYPE_CHECKING:
    from smol_dsl.language import tree
    from smol_dsl.language.shapes.base import SegmentContext


class Expression(Shape):
    keyword = "expr"
    usage = "expr E"
    meaning = "the expression E in `t` and `u`, below"

    def compile(self, segment: SegmentContext, body: tree.Expr) -> Compiled:
        return self.single_piece(segment, segment.formula(body))
