"""`bell a -> p at m -> z [width w]`: two Gaussian halves, from a at the segment's start to the
peak p at m, then to z at its end; exact at the three points."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import sympy as sp

from smol_dsl.errors import ScheduleError
from smol_dsl.language.prover import Extrema, Monotone, real
from smol_dsl.language.shapes.base import Compiled, Formula, Shape
from smol_dsl.language.symbolic import MIN_SEGMENT, Piece, SymbolicSegment, T, number_text, percent

if TYPE_CHECKING:
    import jax

    from smol_dsl.language import tree
    from smol_dsl.language.shapes.base import SegmentContext

MIN_BELL_WIDTH, MAX_BELL_WIDTH = sp.Rational(1, 2**100), sp.Integer(2**100)


@dataclass(frozen=True)
class BellParams:
    start: sp.Expr
    peak: sp.Expr
    peak_at: sp.Rational
    end: sp.Expr
    width: sp.Expr


def _gaussian(t: sp.Expr, centre: sp.Expr, width: sp.Expr) -> sp.Expr:
    return sp.exp(-((t - centre) ** 2) / (2 * width**2))


def bell_half(a: sp.Expr, p: sp.Expr, m: sp.Expr, w: sp.Expr, x: sp.Expr, t: sp.Expr = T) -> sp.Expr:
    """Half a bell: equals `a` at t = x and `p` at t = m, Gaussian-shaped in between."""
    g_x = _gaussian(x, m, w)
    return a + (p - a) * (_gaussian(t, m, w) - g_x) / (1 - g_x)


class Bell(Shape):
    keyword = "bell"
    usage = "bell a -> p at m -> z [width w]"
    meaning = "two Gaussian halves, below"
    syntax_hint = (
        "`bell` is written `bell START -> PEAK at POSITION -> END [width WIDTH]`, "
        "e.g. `bell 0.7 -> 1.4 at 30% -> 1 width 12%`"
    )
    syntax_mistakes = (
        "0% .. 90%: bell 1 -> 2 -> 1",
        "0% .. 90%: bell 1 2 0.5 1",
        "0% .. 90%: bell 1 -> 2 at 50%",
        "0% .. 90%: bell 1 -> 2 at 50% 1",
    )
    float32_ulps = 32

    def compile(
        self,
        segment: SegmentContext,
        start: tree.Expr,
        peak: tree.Expr,
        peak_at: tree.Expr,
        end: tree.Expr,
        width: tree.Expr | None,
    ) -> Compiled:
        label, s, e = segment.label, segment.start, segment.end
        a, p, z = segment.value(start, "start value"), segment.value(peak, "peak"), segment.value(end, "end value")
        m = segment.position(peak_at, "peak position")
        if not s < m < e:
            raise ScheduleError(
                f"the peak of {label} is at {percent(m)}, outside the segment {percent(s)} .. {percent(e)}",
                span=peak_at.span,
                hint="put the peak strictly inside the segment",
            )
        if min(m - s, e - m) < MIN_SEGMENT:
            raise ScheduleError(
                f"the peak of {label} at {percent(m)} is too close to the segment's end",
                span=peak_at.span,
                hint="progress t is a 32-bit float; keep the peak at least 1e-5% of the run inside the segment",
            )
        if width is None:
            w = (e - s) / 4
        else:
            w = segment.value(width, "width")
            if not w > 0:
                raise ScheduleError(
                    f"the width of {label} must be positive, not {number_text(w)}",
                    span=width.span,
                    hint="the width is a fraction of the run, e.g. `width 15%`",
                )
            if not MIN_BELL_WIDTH <= w <= MAX_BELL_WIDTH:
                raise ScheduleError(
                    f"the width of {label} is {number_text(w)}, outside 1e-30 .. 1e30",
                    span=width.span,
                    hint="the width is a fraction of the run, e.g. `width 15%`; far narrower is a spike no "
                    "phase sees, far wider is the same as a parabola",
                )
        pieces = (
            Piece(bell_half(a, p, m, w, s), s, m, "bell to peak"),
            Piece(bell_half(z, p, m, w, e), m, e, "bell from peak"),
        )
        return Compiled(pieces, params=BellParams(a, p, m, z, w))

    def prove(self, segment: SymbolicSegment, piece: Piece) -> tuple[Extrema, Monotone]:
        # Each half of a bell is a + (p - a) * (G(t) - G(s)) / (1 - G(s)) with G monotone on
        # the half: it runs monotonically from its end value to the peak, so its extrema
        # are those two values, exactly.
        bell: BellParams = segment.params
        rising = piece.end == bell.peak_at
        edge = bell.start if rising else bell.end
        low, high = sorted((real(edge), real(bell.peak)))
        assert low is not None and high is not None
        monotone: Monotone
        if low == high:
            monotone = "constant"
        else:
            monotone = "increasing" if (real(bell.peak) > real(edge)) == rising else "decreasing"
        return Extrema(low, high, True), monotone

    def evaluation(self, segment: SymbolicSegment) -> Formula:
        return Formula(_jax_bell(segment.params, float(segment.start), float(segment.end)))


def _jax_bell(params: BellParams, segment_start: float, segment_end: float) -> Callable[[jax.Array], jax.Array]:
    """f(t) for a bell segment on [start, end], finite for every width the language allows.

    Each half is base + (peak - base) * (G(t) - G(edge)) / (1 - G(edge)) with the Gaussian
    G(t) = exp(-x(t)) and x(t) = ((t - peak_at) / width)**2 / 2. It is computed in three forms:
    directly when G(edge) is small; with expm1 when G(edge) is close to 1 (a wide bell), to
    avoid cancellation; and as its limit 1 - r, r = ((t - peak_at) / (edge - peak_at))**2, when
    x(edge) underflows to 0 (a bell far wider than its segment is a parabola). x may overflow to
    inf for a narrow bell, which exp takes to 0; no form divides 0 by 0 or multiplies inf by 0.
    """
    import jax.numpy as jnp  # here, not at the top: checking a schedule never loads JAX

    start_value, peak, end_value = float(params.start), float(params.peak), float(params.end)
    peak_at, width = float(params.peak_at), float(params.width)

    def function(t: jax.Array) -> jax.Array:
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
