"""What a shape's unit is: the `Shape` base class, the `SegmentContext` the compiler hands it,
and what it hands the compiler and `Schedule` back.

A unit owns everything about one kind of segment shape: its keyword, its values' checks and
their error messages (`compile`, from the values of its grammar rule to exact sympy pieces),
its proof hooks (`prove`, `float32_error`, `is_constant`), how `Schedule` evaluates it in JAX
(`evaluation`), and its line in the docs (`usage`, `meaning`). Its grammar rule,
`KEYWORD_shape`, is in sched.lark (or given to `register` for a shape added at run time).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import sympy as sp

from smol_dsl.language.float32 import UNIT, located_float32_error
from smol_dsl.language.prover import Extrema, Monotone, is_zero
from smol_dsl.language.symbolic import Draws, Piece, SymbolicSegment, T

if TYPE_CHECKING:
    import jax

    from smol_dsl.errors import Span
    from smol_dsl.language import tree
    from smol_dsl.language.expressions import Scope


@dataclass(frozen=True)
class SegmentContext:
    """What a shape's unit compiles its segment with: the segment's place in the file and
    extent, and the constants in scope. Its methods raise located errors that name the segment."""

    index: int
    start: sp.Rational
    end: sp.Rational
    span: Span
    """The whole segment's text."""
    scope: Scope
    owner: str = ""
    """` of mass` when messages name the segment's channel."""
    final: sp.Expr = sp.S.One
    """The channel's final value (what `tail` means)."""

    @property
    def label(self) -> str:
        """`segment 3` (`segment 3 of mass`): how messages name the segment."""
        return f"segment {self.index + 1}{self.owner}"

    @property
    def u(self) -> sp.Expr:
        """Progress within the segment, (t - start) / (end - start): 0 at its start, 1 at its end."""
        return (T - self.start) / (self.end - self.start)

    def value(self, node: tree.Expr, what: str) -> sp.Expr:
        """A constant real value, e.g. `value(node, "peak")` for "the peak of segment 3"."""
        return self.scope.constant(node, what=f"the {what} of {self.label}")

    def position(self, node: tree.Expr, what: str) -> sp.Rational:
        """An exact position in the run (a fraction in [0, 1]), e.g. "the peak position of segment 3"."""
        return self.scope.position(node, f"the {what} of {self.label}")

    def formula(self, node: tree.Expr) -> sp.Expr:
        """An expression of `t` (the run's progress) and `u` (the segment's)."""
        return self.scope.build(node, {"t": T, "u": self.u})


@dataclass(frozen=True)
class Compiled:
    """A unit's compiled segment: its pieces in order, what it keeps for its hooks, its draws."""

    pieces: tuple[Piece, ...]
    params: Any = None
    draws: Draws | None = None


# How Schedule evaluates a segment, with O(len(t)) memory whatever the number of segments:


@dataclass(frozen=True)
class Line:
    """alpha = offset + scale * u, u = (t - start) / (end - start): gathered from tables."""

    offset: float
    scale: float = 0.0


@dataclass(frozen=True)
class Drawn:
    """alpha = offset + scale * draw, t's draw of the segment's `Draws`: gathered from tables."""

    offset: float
    scale: float


@dataclass(frozen=True)
class Formula:
    """alpha = function(t), a JAX function evaluated for every t and put in place with `where`."""

    function: Callable[[jax.Array], jax.Array]


Evaluation = Line | Drawn | Formula


class Shape:
    """One kind of segment shape. Subclass it, set the class attributes, write `compile`.

    The defaults of the hooks suit a shape given by a formula: sympy's general proof of
    each piece, the running float32 error analysis of the formula (`smol_dsl.language.float32`),
    and evaluation of its one piece in JAX (`smol_dsl.language.jaxify`). A built-in shape with
    a closed form overrides them.
    """

    keyword: ClassVar[str]
    """Its word in the language; its grammar rule is `KEYWORD_shape`."""
    usage: ClassVar[str]
    """How it is written, values named as in `meaning`: `linear a -> b`."""
    meaning: ClassVar[str]
    """alpha(t) on [s, e), one line of Markdown for the docs' table of shapes."""
    syntax_hint: ClassVar[str | None] = None
    """The hint for a malformed use of the shape (its `syntax_mistakes`)."""
    syntax_mistakes: ClassVar[tuple[str, ...]] = ()
    """Wrong segment lines that fail to parse the way a malformed use does."""
    float32_ulps: ClassVar[int | None] = None
    """float32 error of its evaluation, in units of roundoff of its largest value; None:
    bounded by the running error analysis of its pieces' formulas."""

    def compile(self, segment: SegmentContext, *args: tree.Expr | None) -> Compiled:
        """Exact pieces from the values of the grammar rule, in order (None: an optional value
        left out); a ScheduleError, located and naming the segment, for a bad value."""
        raise NotImplementedError

    def single_piece(self, segment: SegmentContext, expr: sp.Expr) -> Compiled:
        """A segment of one piece, labelled with the keyword."""
        return Compiled((Piece(expr, segment.start, segment.end, self.keyword),))

    # ------------------------------------------------------------------ proof hooks
    def prove(self, segment: SymbolicSegment, piece: Piece) -> tuple[Extrema, Monotone] | None:
        """Extrema and monotonicity of a piece straight from the shape's parameters, or None
        for the general proof (sympy, then interval arithmetic)."""
        return None

    def float32_error(self, segment: SymbolicSegment, piece: Piece, low: float, high: float) -> float:
        """A bound on |float32 alpha - exact alpha| over the piece, whose exact range is [low, high]."""
        if self.float32_ulps is not None:
            return self.float32_ulps * UNIT * max(abs(low), abs(high))
        return located_float32_error(
            piece.expr, piece.start, piece.end, where=segment.describe(), span=segment.span, quantity=segment.quantity
        )

    def is_constant(self, segment: SymbolicSegment, value: sp.Expr) -> bool:
        """Whether the segment is identically `value` (proven exactly): with the channel's final
        value, whether it may be part of the tail."""
        return all(is_zero(p.expr - value) for p in segment.pieces)

    def is_one(self, segment: SymbolicSegment) -> bool:
        """Whether alpha is identically 1 on the segment (`is_constant(segment, 1)`)."""
        return self.is_constant(segment, sp.Integer(1))

    # ------------------------------------------------------------------ evaluation
    def evaluation(self, segment: SymbolicSegment) -> Evaluation:
        """How `Schedule` evaluates the segment (only called before the alpha == 1 tail)."""
        # jaxify imports JAX: parsing and checking a schedule never load it, evaluating does
        from smol_dsl.language.jaxify import to_jax

        if len(segment.pieces) != 1:
            raise NotImplementedError(f"the `{self.keyword}` shape has several pieces: give it an `evaluation`")
        return Formula(to_jax(segment.pieces[0].expr))

    def __repr__(self) -> str:
        return f"<shape {self.keyword}>"
