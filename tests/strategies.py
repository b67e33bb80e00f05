"""Hypothesis strategies for `.sched` texts, together with the ground truth they were built from.

`valid_schedules()` draws a `ScheduleSpec`: a model of a schedule (exact `Fraction` segment
boundaries on a grid, segment kinds with random parameters, lets, bounds, directives and a
layout), which renders to text, and for every segment the truth: its value as a float
function of t, its exact range and end values, its pieces (a bell has two), and which
monotonicity declarations are true. All of it is computed here, independently of smol_dsl.

`invalid_schedules()` draws an `InvalidCase`: a valid schedule with exactly one rule broken
(a gap, an overlap, a missing or short tail, alpha <= 0, alpha outside the declared bounds, a
false monotone or continuity claim, an unknown name, bad syntax, ...), with the line the error
must point at.

`multi_channel_schedules()` draws a `MultiChannelSpec`: a file of several channels (random
kinds, targets and final values), each channel's section a `ScheduleSpec` whose tail is its
final value; `invalid_multi_channel_schedules()` breaks one rule of one channel, or of a
`channel` or `final` line.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from fractions import Fraction
from itertools import pairwise
from typing import Any

from hypothesis import strategies as st

MIN_TAIL = Fraction(1, 10)
ALPHA_GRID = 200  # alpha values are multiples of 1/200 ...
ALPHA_LOW, ALPHA_HIGH = 60, 400  # ... in [0.3, 2.0]
POSITION_DENOMINATORS = (8, 20, 40, 100, 200)  # segment boundaries are multiples of 1/D
DEFAULT_EVERY = Fraction(1, 100)
RANDOM_EVERY: tuple[Fraction | None, ...] = (None, Fraction(1, 100), Fraction(1, 40), Fraction(1, 20))
BELL_WIDTHS = (None, Fraction(1, 200), Fraction(1, 100), Fraction(1, 40), Fraction(1, 10), Fraction(3, 10))

KEYWORDS = frozenset(
    "name description let bounds extinction continuous constant linear bell at width random every expr tail "
    "increasing decreasing channel final".split()
)
BUILTINS = frozenset("exp log sqrt sin cos tanh abs min max pi e t u".split())
RESERVED = KEYWORDS | BUILTINS

# Mixes of segment kinds for the body of a schedule (before its alpha == 1 tail). Verifying a
# bell takes seconds and an `expr` about one, so most tests use the cheaper mixes.
ALL_KINDS = {"constant": 3, "linear": 3, "bell": 1, "random": 2, "expr": 3}
NO_BELLS = {"constant": 3, "linear": 3, "random": 2, "expr": 1}
CHEAP_KINDS = {"constant": 2, "linear": 3, "random": 3}
EXACT_KINDS = frozenset({"constant", "linear", "random", "tail"})  # verified without enclosures

# alpha == 1 shapes for the final segment(s); the last is equal to 1 only symbolically.
ONE_SHAPES = (
    "tail",
    "tail",
    "tail",
    "constant {one}",
    "linear {one} -> {one}",
    "random {one} .. {one}",
    "random {one} .. {one} every 5%",
    "expr 1",
    "expr u - u + 1",
    "expr (1 + t) / (1 + t)",
    "expr exp(t) * exp(-t)",
    "bell {one} -> {one} at {mid} -> {one}",
    "expr sin(t)**2 + cos(t)**2",
)

# Monotone easings from 0 at u = 0 to 1 at u = 1, for `expr a + (b - a) * EASE`: (text, float function).
EASINGS: dict[str, tuple[str, Callable[[float], float]]] = {
    "quad": ("u**2", lambda x: x * x),
    "cos": ("(1 - cos(pi * u)) / 2", lambda x: (1 - math.cos(math.pi * x)) / 2),
    "sqrt": ("sqrt(u)", math.sqrt),
    "log": ("log(1 + (e - 1) * u)", lambda x: math.log1p((math.e - 1) * x)),
    "min": ("min(2 * u, 1)", lambda x: min(2 * x, 1.0)),
    "max": ("max(2 * u - 1, 0)", lambda x: max(2 * x - 1, 0.0)),
    "tanh": ("tanh(3 * u) / tanh(3)", lambda x: math.tanh(3 * x) / math.tanh(3)),
    "exp": ("(exp(-2 * u) - 1) / (exp(-2) - 1)", lambda x: math.expm1(-2 * x) / math.expm1(-2)),
}

# Shapes identically equal to a final value other than 1 ({one}), for the tail of a channel with `final`.
FINAL_SHAPES = (
    "tail",
    "tail",
    "constant {one}",
    "linear {one} -> {one}",
    "random {one} .. {one} every 5%",
    "expr {one}",
    "expr u - u + {one}",
    "expr {one_wrapped} * (sin(t)**2 + cos(t)**2)",
)

# ----------------------------------------------------------------------------- number text


def decimal_text(value: Fraction) -> str | None:
    """The exact decimal text of `value` (`0.125`, `-1.5`, `2`), or None if it has none."""
    for k in range(13):
        scaled = value * 10**k
        if scaled.denominator == 1:
            n = scaled.numerator
            sign = "-" if n < 0 else ""
            digits = str(abs(n)).rjust(k + 1, "0")
            if k == 0:
                return sign + digits
            whole, frac = digits[:-k], digits[-k:].rstrip("0")
            return sign + whole + ("." + frac if frac else "")
    return None


def fraction_text(value: Fraction) -> str:
    return str(value.numerator) if value.denominator == 1 else f"{value.numerator}/{value.denominator}"


def position_text(value: Fraction) -> str:
    percent = decimal_text(value * 100)
    return percent + "%" if percent is not None else fraction_text(value)


def numeric_forms(value: Fraction) -> list[str]:
    """Texts denoting exactly `value`: 0.125, 12.5%, 1/8, 125e-3, -0.125 + 0.25."""
    forms: list[str] = []
    decimal = decimal_text(value)
    if decimal is not None:
        forms.append(decimal)
    percent = decimal_text(value * 100)
    if percent is not None:
        forms.append(percent + "%")
    if value.denominator != 1:
        forms.append(fraction_text(value))
    for k in range(1, 13):
        scaled = value * 10**k
        if scaled.denominator == 1:
            if scaled.numerator >= 0:
                forms.append(f"{scaled.numerator}e-{k}")
            break
    rest = decimal_text(value - Fraction(1, 4))
    if rest is not None:
        forms.append(f"{rest} + 0.25")
    return forms or [fraction_text(value)]


def _needs_parens(text: str) -> bool:
    return any(c in text for c in " +-*/")


def both_ways() -> frozenset[str]:
    return frozenset({"increasing", "decreasing"})


def ways(a: Fraction, b: Fraction) -> frozenset[str]:
    """The true monotonicity declarations of a shape that moves monotonically from a to b."""
    return frozenset(({"increasing"} if b >= a else set()) | ({"decreasing"} if b <= a else set()))


# ----------------------------------------------------------------------------- the model


@dataclass(frozen=True)
class RandomTruth:
    low: Fraction
    high: Fraction
    every: Fraction
    count: int


@dataclass(frozen=True)
class PieceTruth:
    """A smooth piece of alpha: [start, end], its exact range, its true monotone declarations."""

    start: Fraction
    end: Fraction
    low: Fraction
    high: Fraction
    allowed: frozenset[str]


@dataclass(frozen=True)
class SegmentSpec:
    """One segment: where it is, its text, and the truth about it."""

    start: Fraction
    end: Fraction
    start_text: str
    end_text: str
    kind: str  # constant, linear, bell, random, expr, tail (`template` names the expr)
    shape: str  # the shape text, e.g. "linear 1.5 -> 1"
    low: Fraction  # the exact range of alpha over the closed segment
    high: Fraction
    allowed: frozenset[str]  # the monotone declarations that are true
    declared: str | None = None
    first: Fraction | None = None  # exact alpha at the start / end (None: a random draw)
    last: Fraction | None = None
    function: Callable[[float], float] | None = field(default=None, compare=False, repr=False)
    random: RandomTruth | None = None
    template: str = ""
    peak_at: Fraction | None = None  # a bell's peak position
    pieces: tuple[PieceTruth, ...] = ()

    @property
    def is_one(self) -> bool:
        return self.low == 1 and self.high == 1

    def value(self, t: float | Fraction, draws: Sequence[float] | None = None) -> float:
        """The true alpha at t (inside this segment); a random segment needs its draws."""
        if self.random is not None:
            r = self.random
            assert draws is not None
            k = min(math.floor((Fraction(t) - self.start) / r.every), r.count - 1)  # exact
            return float(r.low) + float(r.high - r.low) * float(draws[k])
        assert self.function is not None
        return self.function(float(t))


@dataclass(frozen=True)
class Let:
    name: str
    text: str
    value: Fraction


@dataclass(frozen=True)
class Layout:
    newline: str = "\n"
    final_newline: bool = True
    compact: bool = False
    preamble: str | None = None
    blank_lines: bool = False
    trailing_comment: str | None = None
    order: tuple[str, ...] = ("name", "description", "lets", "bounds", "extinction", "continuous")
    footer: frozenset[str] = frozenset()


@dataclass(frozen=True)
class ScheduleSpec:
    """A schedule as built, and everything true about it."""

    segments: tuple[SegmentSpec, ...]
    lets: tuple[Let, ...] = ()
    name: str | None = None
    description: str | None = None
    bounds: tuple[str, str, Fraction, Fraction] | None = None  # (low text, high text, low, high)
    extinction: tuple[str, Fraction] | None = None
    continuous: bool = False
    layout: Layout = Layout()
    extra_lines: tuple[str, ...] = ()  # appended verbatim (invalid variants)
    final: Fraction = Fraction(1)  # the value of the tail (a channel's `final`)

    # -------------------------------------------------------------- rendering
    def render(self) -> tuple[str, dict[str, int]]:
        """The text, and the 1-based line of each statement ("segment 0", "bounds", "let x", ...)."""
        lay = self.layout
        lines: list[str] = []
        where: dict[str, int] = {}

        def emit(key: str, line: str) -> None:
            lines.append(line)
            where[key] = len(lines)
            if lay.blank_lines:
                lines.append("")

        def directives(keys: Sequence[str]) -> None:
            for key in keys:
                if key == "name" and self.name is not None:
                    emit("name", f'name "{self.name}"')
                elif key == "description" and self.description is not None:
                    emit("description", f'description "{self.description}"')
                elif key == "lets":
                    for let in self.lets:
                        emit(f"let {let.name}", f"let {let.name} = {let.text}")
                elif key == "bounds" and self.bounds is not None:
                    emit("bounds", f"bounds {self.bounds[0]} .. {self.bounds[1]}")
                elif key == "extinction" and self.extinction is not None:
                    emit("extinction", f"extinction {self.extinction[0]}")
                elif key == "continuous" and self.continuous:
                    emit("continuous", "continuous")

        if lay.preamble is not None:
            lines += ["# " + lay.preamble, ""]
        directives([k for k in lay.order if k not in lay.footer])
        for i, seg in enumerate(self.segments):
            emit(f"segment {i}", self.segment_line(seg))
        directives([k for k in lay.order if k in lay.footer])
        for i, extra in enumerate(self.extra_lines):
            emit(f"extra {i}", extra)
        return lay.newline.join(lines) + (lay.newline if lay.final_newline else ""), where

    def segment_line(self, seg: SegmentSpec, *, comment: bool = True) -> str:
        if self.layout.compact:
            line = f"{seg.start_text}..{seg.end_text}:{seg.shape}"
        else:
            line = f"{seg.start_text} .. {seg.end_text}:   {seg.shape}"
        if seg.declared:
            line += f" {seg.declared}"
        if comment and self.layout.trailing_comment is not None:
            line += "  # " + self.layout.trailing_comment
        return line

    @property
    def text(self) -> str:
        return self.render()[0]

    def line_of(self, key: str) -> int:
        return self.render()[1][key]

    # -------------------------------------------------------------- truth
    @property
    def low(self) -> Fraction:
        return min(s.low for s in self.segments)

    @property
    def high(self) -> Fraction:
        return max(s.high for s in self.segments)

    @property
    def pieces(self) -> list[tuple[int, PieceTruth]]:
        """(segment index, piece) for every piece, in order."""
        return [(i, p) for i, s in enumerate(self.segments) for p in s.pieces]

    @property
    def tail_start(self) -> Fraction:
        start = Fraction(1)
        for seg in reversed(self.segments):
            if not seg.low == seg.high == self.final:
                break
            start = seg.start
        return start

    def join_continuous(self, i: int) -> bool:
        """Whether alpha is continuous where segment i meets segment i + 1."""
        before, after = self.segments[i], self.segments[i + 1]
        return before.last is not None and after.first is not None and before.last == after.first

    @property
    def truly_continuous(self) -> bool:
        return all(self.join_continuous(i) for i in range(len(self.segments) - 1))

    def segment_at(self, t: Fraction) -> int:
        """The segment that owns t: segments own [start, end), the last one [start, 1]."""
        return max(i for i, s in enumerate(self.segments) if s.start <= t)

    def alpha(self, t: float | Fraction, draws: Sequence[Sequence[float] | None] | None = None) -> float:
        j = self.segment_at(Fraction(t))
        return self.segments[j].value(t, None if draws is None else draws[j])

    def boundaries(self) -> list[Fraction]:
        return [s.start for s in self.segments] + [Fraction(1)]

    def random_edges(self) -> list[tuple[Fraction, Fraction]]:
        """(edge, resolution) for every bin edge of every random segment."""
        return [
            (seg.start + k * seg.random.every, seg.random.every)
            for seg in self.segments
            if seg.random is not None
            for k in range(seg.random.count + 1)
        ]


# ----------------------------------------------------------------------------- drawing

names = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,7}", fullmatch=True).filter(lambda n: n not in RESERVED)
free_text = st.text(
    alphabet=st.characters(codec="utf-8", exclude_categories=("Cc", "Cs", "Zl", "Zp"), exclude_characters='"'),
    max_size=24,
)


def _weighted(options: dict[str, int]) -> st.SearchStrategy[str]:
    return st.sampled_from([k for k, w in sorted(options.items()) for _ in range(w)])


def bell_function(a: float, p: float, m: float, z: float, w: float, s: float, e: float) -> Callable[[float], float]:
    """The bell's definition: G(x) = exp(-(x - m)^2 / (2 w^2)); on [s, m) alpha goes from a to p as
    (G(t) - G(s)) / (1 - G(s)), on [m, e] from p to z as (G(t) - G(e)) / (1 - G(e))."""

    def half(base: float, edge: float, t: float) -> float:
        at_edge = (edge - m) ** 2 / (2 * w * w)  # -log G(edge)
        at_t = (t - m) ** 2 / (2 * w * w)
        shape = math.exp(-at_t) * -math.expm1(at_t - at_edge) / -math.expm1(-at_edge)
        return base + (p - base) * shape

    return lambda t: half(a, s, t) if t < m else half(z, e, t)


class _Builder:
    """Draws the parts of one schedule; keeps the lets it creates along the way."""

    def __init__(self, draw: Callable, let_level: int) -> None:
        self.draw = draw
        self.let_level = let_level  # out of 10: how often a value is written as a let name
        self.lets: list[Let] = []
        self.final = Fraction(1)  # the tail's value in the schedule being drawn

    # -- values ------------------------------------------------------------
    def alpha(self, low: int = ALPHA_LOW, high: int = ALPHA_HIGH) -> Fraction:
        return Fraction(self.draw(st.integers(low, high)), ALPHA_GRID)

    def let_for(self, value: Fraction) -> str:
        same = [let for let in self.lets if let.value == value]
        if same and self.draw(st.booleans()):
            return self.draw(st.sampled_from(same)).name
        taken = {let.name for let in self.lets}
        name = self.draw(names.filter(lambda n: n not in taken))
        forms = numeric_forms(value)
        if self.lets and self.draw(st.booleans()):  # in terms of an earlier let
            other = self.draw(st.sampled_from(self.lets))
            difference = decimal_text(value - other.value)
            if difference is not None:
                forms.append(f"{other.name} + {difference}")
        self.lets.append(Let(name, self.draw(st.sampled_from(forms)), value))
        return name

    def number(self, value: Fraction, *, wrap: bool = False, allow_let: bool = True) -> str:
        """Text for an exact value: a decimal, a percentage, a fraction, ... or a let name."""
        if allow_let and self.let_level and self.draw(st.integers(0, 9)) < self.let_level:
            return self.let_for(value)
        text = self.draw(st.sampled_from(numeric_forms(value)))
        return f"({text})" if wrap and _needs_parens(text) else text

    def declare(self, allowed: frozenset[str]) -> str | None:
        return self.draw(st.sampled_from([None, *sorted(allowed)])) if allowed else None

    # -- segments ----------------------------------------------------------
    def segment(
        self, start: Fraction, end: Fraction, kind: str, first: Fraction | None = None, last: Fraction | None = None
    ) -> SegmentSpec:
        """A segment of `kind` on [start, end]; `first` / `last` pin its end values (for chaining)."""
        where = dict(start=start, end=end, start_text=self.number(start), end_text=self.number(end), kind=kind)
        s, n = float(start), float(end - start)
        if kind == "constant":
            v = first if first is not None else last if last is not None else self.alpha()
            return self._make(where, f"constant {self.number(v)}", v, v, both_ways(), v, v, lambda t, v=float(v): v)
        if kind == "linear":
            a = first if first is not None else self.alpha()
            b = last if last is not None else self.alpha()
            shape = f"linear {self.number(a)} -> {self.number(b)}"

            def linear(t: float, a: float = float(a), b: float = float(b)) -> float:
                return a + (b - a) * (t - s) / n

            return self._make(where, shape, min(a, b), max(a, b), ways(a, b), a, b, linear)
        if kind == "bell":
            a = first if first is not None else self.alpha()
            z = last if last is not None else self.alpha()
            p = self.alpha()
            parts = self.draw(st.sampled_from((2, 4, 8)))
            m = start + (end - start) * self.draw(st.integers(1, parts - 1)) / parts
            width = self.draw(st.sampled_from(BELL_WIDTHS))
            w = (end - start) / 4 if width is None else width
            shape = f"bell {self.number(a)} -> {self.number(p)} at {self.number(m)} -> {self.number(z)}"
            if width is not None:
                shape += f" width {self.number(width)}"
            rise, fall = ways(a, p), ways(p, z)
            pieces = (
                PieceTruth(start, m, min(a, p), max(a, p), rise),
                PieceTruth(m, end, min(p, z), max(p, z), fall),
            )
            function = bell_function(float(a), float(p), float(m), float(z), float(w), s, float(end))
            seg = self._make(where, shape, min(a, p, z), max(a, p, z), rise & fall, a, z, function)
            return replace(seg, peak_at=m, pieces=pieces)
        if kind == "random":
            lo, hi = sorted((self.alpha(), self.alpha()))
            every = self.draw(st.sampled_from(RANDOM_EVERY))
            step = DEFAULT_EVERY if every is None else every
            shape = f"random {self.number(lo)} .. {self.number(hi)}"
            if every is not None:
                shape += f" every {self.number(every)}"
            allowed = both_ways() if lo == hi else frozenset()
            ends = lo if lo == hi == self.final else None  # a join next to a random draw is a jump
            seg = self._make(where, shape, lo, hi, allowed, ends, ends, None)
            return replace(seg, random=RandomTruth(lo, hi, step, math.ceil((end - start) / step)))
        assert kind == "expr", kind
        return self._expression(where, first, last)

    def _expression(self, where: dict[str, Any], first: Fraction | None, last: Fraction | None) -> SegmentSpec:
        start, end = where["start"], where["end"]
        s, n = float(start), float(end - start)

        def u(t: float) -> float:
            return min(max((t - s) / n, 0.0), 1.0)

        pinned = first is not None or last is not None
        template = self.draw(st.sampled_from([*EASINGS, "global", "geometric", *([] if pinned else ["bump", "vee"])]))
        if template in ("bump", "vee"):
            c = self.alpha(ALPHA_LOW, 300)
            room_below, room_above = int(c * ALPHA_GRID) - ALPHA_LOW, ALPHA_HIGH - int(c * ALPHA_GRID)
            if template == "bump":  # c + d sin(pi u): c at both ends, c + d in the middle
                d = Fraction(self.draw(st.integers(-room_below, room_above)), ALPHA_GRID)
                shape = f"expr {self.number(c, wrap=True)} + {self.number(d, wrap=True)} * sin(pi * u)"
                low, high, ends = min(c, c + d), max(c, c + d), c

                def function(t: float, c: float = float(c), d: float = float(d)) -> float:
                    return c + d * math.sin(math.pi * u(t))

            else:  # c + d |2u - 1|: c + d at both ends, c in the middle
                d = Fraction(self.draw(st.integers(0, room_above)), ALPHA_GRID)
                shape = f"expr {self.number(c, wrap=True)} + {self.number(d, wrap=True)} * abs(2 * u - 1)"
                low, high, ends = c, c + d, c + d

                def function(t: float, c: float = float(c), d: float = float(d)) -> float:
                    return c + d * abs(2 * u(t) - 1)

            allowed = both_ways() if low == high else frozenset()
            return self._make(where, shape, low, high, allowed, ends, ends, function, template)
        a = first if first is not None else self.alpha()
        b = last if last is not None else self.alpha()
        a_text, b_text = self.number(a, wrap=True), self.number(b, wrap=True)
        if template == "global":  # written in the run's progress t
            s_text, e_text = self.number(start, wrap=True), self.number(end, wrap=True)
            shape = f"expr {a_text} + ({b_text} - {a_text}) * (t - {s_text}) / ({e_text} - {s_text})"
            ease: Callable[[float], float] = lambda x: x  # noqa: E731
        elif template == "geometric":  # a (b / a)^u
            shape = f"expr {a_text} * ({b_text} / {a_text}) ** u"
            ratio = float(b) / float(a)
            ease = (lambda x: (ratio**x - 1) / (ratio - 1)) if a != b else (lambda x: x)
        else:
            body, ease = EASINGS[template]
            shape = f"expr {a_text} + ({b_text} - {a_text}) * {body}"

        def eased(t: float, a: float = float(a), b: float = float(b), ease=ease) -> float:
            return a + (b - a) * ease(u(t))

        return self._make(where, shape, min(a, b), max(a, b), ways(a, b), a, b, eased, template)

    def _make(self, where, shape, low, high, allowed, first, last, function, template="") -> SegmentSpec:
        piece = PieceTruth(where["start"], where["end"], low, high, frozenset(allowed))
        return SegmentSpec(
            **where,
            shape=shape,
            low=low,
            high=high,
            allowed=frozenset(allowed),
            declared=self.declare(frozenset(allowed)),
            first=first,
            last=last,
            function=function,
            template=template,
            pieces=(piece,),
        )

    def one_segment(self, start: Fraction, end: Fraction, shapes: Sequence[str]) -> SegmentSpec:
        """A segment that is identically the final value, 1 unless drawing a channel with
        `final` (the tail, or part of it)."""
        mid = (start + end) / 2
        one = self.final
        shape = self.draw(st.sampled_from(shapes)).format(
            one=self.number(one), one_wrapped=self.number(one, wrap=True), mid=self.number(mid)
        )
        kind = shape.split()[0]
        where = dict(start=start, end=end, start_text=self.number(start), end_text=self.number(end), kind=kind)
        seg = self._make(where, shape, one, one, both_ways(), one, one, lambda t, v=float(one): v)
        if kind == "bell":
            whole = both_ways()
            halves = (PieceTruth(start, mid, one, one, whole), PieceTruth(mid, end, one, one, whole))
            seg = replace(seg, peak_at=mid, pieces=halves)
        if kind == "random":
            every = Fraction(1, 20) if "every" in shape else DEFAULT_EVERY
            seg = replace(seg, random=RandomTruth(one, one, every, math.ceil((end - start) / every)))
        return seg


# ----------------------------------------------------------------------------- valid schedules


def _schedule_body(
    draw: Callable,
    builder: _Builder,
    *,
    kinds: dict[str, int] | None,
    max_body: int,
    one_shapes: Sequence[str],
    declare: bool,
    bounds: bool | None,
) -> ScheduleSpec:
    """The segments of one schedule (or channel) ending on `builder.final`, and its true
    `bounds` and `continuous` directives."""
    weights = dict(ALL_KINDS if kinds is None else kinds)
    grid = draw(st.sampled_from(POSITION_DENOMINATORS))
    tail_at = draw(st.integers(0, grid * 9 // 10))  # the tail starts at tail_at / grid <= 90%
    n_body = 0 if tail_at == 0 else draw(st.integers(1, min(max_body, tail_at)))
    cuts = []
    if n_body > 1:
        inner = st.integers(1, tail_at - 1)
        cuts = sorted(draw(st.lists(inner, unique=True, min_size=n_body - 1, max_size=n_body - 1)))
    edges = [Fraction(k, grid) for k in [0, *cuts, tail_at]]
    chained = n_body > 0 and draw(st.integers(0, 3)) == 0  # a continuous body ending at the final value
    segments: list[SegmentSpec] = []
    previous: Fraction | None = None
    for i in range(n_body):
        options = dict(weights)
        first = last = None
        if chained:
            options.pop("random", None)
            first, last = previous, (builder.final if i == n_body - 1 else None)
            if first is not None and last is not None and first != last:
                options.pop("constant", None)
        kind = draw(_weighted(options or {"linear": 1}))
        seg = builder.segment(edges[i], edges[i + 1], kind, first=first, last=last)
        if kind == "bell":
            weights.pop("bell")
        segments.append(seg if declare else replace(seg, declared=None))
        previous = seg.last
    tail_edges = [edges[-1], Fraction(1)]
    if grid - tail_at >= 2 and draw(st.booleans()):
        tail_edges.insert(1, Fraction(draw(st.integers(tail_at + 1, grid - 1)), grid))
    for start, end in pairwise(tail_edges):
        seg = builder.one_segment(start, end, one_shapes)
        segments.append(seg if declare else replace(seg, declared=None))
    spec = ScheduleSpec(segments=tuple(segments), final=builder.final)

    # Directives, each only where it is true.
    declared_bounds = None
    if bounds or (bounds is None and draw(st.booleans())):
        # Tight bounds only where verification is exact (an enclosure is a hair wider).
        exact = all(s.kind in EXACT_KINDS for s in segments)
        lo = spec.low - Fraction(draw(st.integers(0 if exact else 1, 60)), 100)
        hi = spec.high + Fraction(draw(st.integers(0 if exact else 1, 60)), 100)
        declared_bounds = (builder.number(lo), builder.number(hi), lo, hi)
    return replace(spec, bounds=declared_bounds, continuous=spec.truly_continuous and draw(st.booleans()))


@st.composite
def valid_schedules(
    draw: Callable,
    *,
    kinds: dict[str, int] | None = None,
    max_body: int = 3,
    one_shapes: Sequence[str] = ONE_SHAPES,
    declare: bool = True,
    bounds: bool | None = None,
) -> ScheduleSpec:
    """A valid schedule and its ground truth (see `ScheduleSpec`).

    `kinds` weighs the segment kinds of the body (at most one bell per schedule); `declare`
    allows monotonicity declarations; `bounds` forces (True) or forbids (False) a `bounds` line.
    """
    builder = _Builder(draw, draw(st.sampled_from((0, 0, 3))))
    spec = _schedule_body(
        draw, builder, kinds=kinds, max_body=max_body, one_shapes=one_shapes, declare=declare, bounds=bounds
    )
    extinction = None
    if draw(st.integers(0, 3)) == 0:
        p = Fraction(draw(st.integers(0, 100)), 100)
        extinction = (builder.number(p, allow_let=False), p)
    layout = Layout(
        newline=draw(st.sampled_from(("\n", "\n", "\r\n"))),
        final_newline=draw(st.booleans()),
        compact=draw(st.integers(0, 4)) == 0,
        preamble=draw(st.none() | free_text),
        blank_lines=draw(st.booleans()),
        trailing_comment=draw(st.none() | free_text),
        order=tuple(draw(st.permutations(Layout().order))),
        footer=frozenset(draw(st.sets(st.sampled_from(("name", "description", "bounds", "extinction"))))),
    )
    return replace(
        spec,
        lets=tuple(builder.lets),
        name=draw(st.none() | free_text),
        description=draw(st.none() | free_text),
        extinction=extinction,
        layout=layout,
    )


@st.composite
def random_segment_schedules(draw: Callable) -> tuple[ScheduleSpec, int]:
    """A schedule with one random segment, on a 1/200 grid, and N = 200 phases.

    Every phase then starts on a multiple of 0.5%, so each random step (1%, 2.5% or 5%,
    counted from the segment's start) holds a whole number of phases, except a shorter last."""
    builder = _Builder(draw, 0)
    grid = 200
    tail_at = draw(st.integers(2, 180))
    start_at = draw(st.integers(0, tail_at - 1))
    segments = []
    for a, b in pairwise(sorted({0, start_at, tail_at})):
        kind = "random" if a == start_at else draw(st.sampled_from(("constant", "linear")))
        segments.append(builder.segment(Fraction(a, grid), Fraction(b, grid), kind))
    segments.append(builder.one_segment(Fraction(tail_at, grid), Fraction(1), ("tail",)))
    return ScheduleSpec(segments=tuple(segments)), grid


# ----------------------------------------------------------------------------- invalid schedules


@dataclass(frozen=True)
class InvalidCase:
    text: str
    rule: str
    line: int | None  # the line the error must point at
    message: str | None  # words the error message must contain
    spec: ScheduleSpec | None = field(default=None, repr=False)  # the broken schedule, where a spec renders it
    key: str | None = None  # the statement of `spec` the error must point at


def _small_step(limit: Fraction) -> Fraction:
    """A small positive offset below `limit` with a short exact decimal."""
    return min(Fraction(1, 400), limit / 2)


def _case(spec: ScheduleSpec, rule: str, key: str, message: str | None) -> InvalidCase:
    text, where = spec.render()
    return InvalidCase(text, rule, where[key], message, spec, key)


def _break_gap(draw, spec: ScheduleSpec) -> InvalidCase:
    segs = list(spec.segments)
    j = draw(st.integers(-1, len(segs) - 1))  # a gap after segment j: -1 at 0%, the last at 100%
    if j == len(segs) - 1:
        seg = segs[j]
        new_end = seg.end - _small_step(seg.end - (seg.peak_at if seg.peak_at is not None else seg.start))
        segs[j] = replace(seg, end=new_end, end_text=position_text(new_end))
        return _case(replace(spec, segments=tuple(segs)), "gap at the end", f"segment {j}", "uncovered")
    seg = segs[j + 1]
    new_start = seg.start + _small_step((seg.peak_at if seg.peak_at is not None else seg.end) - seg.start)
    segs[j + 1] = replace(seg, start=new_start, start_text=position_text(new_start))
    broken = replace(spec, segments=tuple(segs))
    return _case(broken, "gap", f"segment {j + 1}", "uncovered" if j == -1 else "gap")


def _break_overlap(draw, spec: ScheduleSpec) -> InvalidCase | None:
    segs = list(spec.segments)
    if len(segs) < 2:
        return None
    j = draw(st.integers(1, len(segs) - 1))
    new_start = segs[j].start - _small_step(segs[j - 1].end - segs[j - 1].start)
    segs[j] = replace(segs[j], start=new_start, start_text=position_text(new_start))
    return _case(replace(spec, segments=tuple(segs)), "overlap", f"segment {j}", "overlap")


def _not_one(draw, spec: ScheduleSpec) -> Fraction | None:
    """A positive alpha other than the final value (1), inside the declared bounds if there are any."""
    lo, hi = (Fraction(1, 2), Fraction(2)) if spec.bounds is None else spec.bounds[2:]
    options = [Fraction(k, 100) for k in range(30, 201) if lo <= Fraction(k, 100) <= hi and k != spec.final * 100]
    return draw(st.sampled_from(options)) if options else None


def _constant(start: Fraction, end: Fraction, value: Fraction) -> SegmentSpec:
    return SegmentSpec(
        start, end, position_text(start), position_text(end), "constant", f"constant {decimal_text(value)}",
        value, value, both_ways(), first=value, last=value,
    )  # fmt: skip


def _break_missing_tail(draw, spec: ScheduleSpec) -> InvalidCase | None:
    v = _not_one(draw, spec)
    if v is None:
        return None
    i = next(i for i, s in enumerate(spec.segments) if s.start == spec.tail_start)
    segs = (*spec.segments[:i], _constant(spec.tail_start, Fraction(1), v))
    return _case(replace(spec, segments=segs, continuous=False), "missing tail", f"segment {i}", "final 10%")


def _break_short_tail(draw, spec: ScheduleSpec) -> InvalidCase | None:
    v = _not_one(draw, spec)
    if v is None:
        return None
    x = Fraction(draw(st.integers(901, 999)), 1000)  # the tail would start after 90%
    i = next(i for i, s in enumerate(spec.segments) if s.start == spec.tail_start)
    tail = SegmentSpec(x, Fraction(1), position_text(x), "100%", "tail", "tail", spec.final, spec.final, both_ways())
    segs = (*spec.segments[:i], _constant(spec.tail_start, x, v), tail)
    return _case(replace(spec, segments=segs, continuous=False), "short tail", f"segment {i + 1}", "final 10%")


NOT_POSITIVE = (
    "constant 0",
    "constant -0.5",
    "constant 0%",
    "linear 1.2 -> 0",
    "linear -0.25 -> 1",
    "random 0 .. 1.5",
    "random -1 .. -0.5 every 5%",
    "expr 1.5 * (1 - u)",
    "expr 1 - 2 * u",
    "expr t - 1",
    "expr sin(2 * pi * u)",
)


def _break_positive(draw, spec: ScheduleSpec) -> InvalidCase:
    j = draw(st.integers(0, len(spec.segments) - 1))
    segs = list(spec.segments)
    segs[j] = replace(segs[j], shape=draw(st.sampled_from(NOT_POSITIVE)), declared=None)
    return _case(replace(spec, segments=tuple(segs)), "alpha <= 0", f"segment {j}", "above 0")


def _break_bounds(draw, spec: ScheduleSpec) -> InvalidCase:
    low, high = spec.low, spec.high
    if draw(st.booleans()):  # below the maximum
        hi = high - Fraction(draw(st.integers(1, 20)), 100)
        lo = min(low, hi) - Fraction(draw(st.integers(0, 20)), 100)
    else:  # above the minimum
        lo = low + Fraction(draw(st.integers(1, 20)), 100)
        hi = max(high, lo) + Fraction(draw(st.integers(0, 20)), 100)
    broken = replace(spec, bounds=(decimal_text(lo), decimal_text(hi), lo, hi))
    first = next(i for i, s in enumerate(spec.segments) if s.low < lo or s.high > hi)
    return _case(broken, "out of bounds", f"segment {first}", "bound")


def _break_monotone(draw, spec: ScheduleSpec) -> InvalidCase | None:
    options = [(i, w) for i, s in enumerate(spec.segments) for w in ("increasing", "decreasing") if w not in s.allowed]
    if not options:
        return None
    i, way = draw(st.sampled_from(options))
    segs = list(spec.segments)
    segs[i] = replace(segs[i], declared=way)
    return _case(replace(spec, segments=tuple(segs)), "false monotone", f"segment {i}", way)


def _break_continuous(draw, spec: ScheduleSpec) -> InvalidCase | None:
    jumps = [i for i in range(len(spec.segments) - 1) if not spec.join_continuous(i)]
    if not jumps:
        return None
    return _case(replace(spec, continuous=True), "false continuous", f"segment {jumps[0] + 1}", "continuous")


def _break_unknown_name(draw, spec: ScheduleSpec) -> InvalidCase:
    taken = {let.name for let in spec.lets}
    bad = draw(names.filter(lambda n: n not in taken))
    where = draw(st.sampled_from(("constant", "linear", "expr", "bounds", "let", "position")))
    if where == "bounds":
        return _case(replace(spec, bounds=(bad, "2", Fraction(0), Fraction(2))), "unknown name", "bounds", bad)
    if where == "let":
        name = draw(names.filter(lambda n: n not in taken and n != bad))
        broken = replace(spec, lets=(*spec.lets, Let(name, f"{bad} + 1", Fraction(0))))
        return _case(broken, "unknown name", f"let {name}", bad)
    j = draw(st.integers(0, len(spec.segments) - 1))
    segs = list(spec.segments)
    if where == "position":
        segs[j] = replace(segs[j], start_text=bad)
    else:
        shape = {"constant": f"constant {bad}", "linear": f"linear 1 -> {bad}", "expr": f"expr 1 + {bad} * u"}[where]
        segs[j] = replace(segs[j], shape=shape, declared=None)
    return _case(replace(spec, segments=tuple(segs)), "unknown name", f"segment {j}", bad)


SYNTAX_BREAKS = (
    "no colon",
    "dash range",
    "to range",
    "misspelled kind",
    "stray word",
    "caret power",
    "open paren",
    "two statements",
    "unicode arrow",
    "empty end",
    "brackets",
    "missing arrow",
    "let without =",
    "single quotes",
    "unterminated string",
)


def _break_syntax(draw, spec: ScheduleSpec) -> InvalidCase:
    how = draw(st.sampled_from(SYNTAX_BREAKS))
    segs = spec.segments
    j = draw(st.integers(0, len(segs) - 1))
    seg = segs[j]
    head = f"{seg.start_text} .. {seg.end_text}"
    drop_next = False
    if how == "no colon":
        line = f"{head} {seg.shape}"
    elif how == "dash range":
        line = f"{seg.start_text} - {seg.end_text}: {seg.shape}"
    elif how == "to range":
        line = f"{seg.start_text} to {seg.end_text}: {seg.shape}"
    elif how == "misspelled kind":
        kind, _, rest = seg.shape.partition(" ")
        wrong = {"constant": "constnat", "linear": "lineal", "bell": "bel", "random": "Random", "expr": "exp"}
        line = f"{head}: {wrong.get(kind, 'tial')} {rest}"
    elif how == "stray word":
        line = spec.segment_line(seg, comment=False) + draw(st.sampled_from((" monotone", " tail", " 1", " steady")))
    elif how == "caret power":
        line = f"{head}: expr 1 + (u - 0.5)^2"
    elif how == "open paren":
        line = f"{head}: constant (1.5"
    elif how == "two statements":
        if j + 1 < len(segs):
            after = segs[j + 1]
            line = f"{head}: {seg.shape} {after.start_text} .. {after.end_text}: {after.shape}"
            drop_next = True
        else:
            line = f"{head}: {seg.shape} bounds 0 .. 2"
    elif how == "unicode arrow":
        line = f"{head}: linear 1.2 → 1"
    elif how == "empty end":
        line = f"{seg.start_text} .. : {seg.shape}"
    elif how == "brackets":
        line = f"{head}: constant [1.5]"
    elif how == "missing arrow":
        line = f"{head}: linear 1.5 1"
    else:  # a broken directive, on a new first line
        line = {"let without =": "let child 1.5", "single quotes": "name 'SMOL'", "unterminated string": 'name "SMOL'}[
            how
        ]
        text = spec.text
        return InvalidCase(line + spec.layout.newline + text, f"syntax: {how}", 1, None)
    text, where = spec.render()
    lines = text.split(spec.layout.newline)
    if drop_next:
        del lines[where[f"segment {j + 1}"] - 1]
    lines[where[f"segment {j}"] - 1] = line
    return InvalidCase(spec.layout.newline.join(lines), f"syntax: {how}", where[f"segment {j}"], None)


OTHER_BREAKS = (
    "outside the run",
    "reversed random",
    "peak outside",
    "zero width",
    "division by zero",
    "unknown function",
    "duplicate name",
    "builtin let",
    "extinction above 1",
    "reversed bounds",
    "t in a constant",
    "empty segment",
    "log of a negative",
    "sqrt of a negative inside",
)


def _break_other(draw, spec: ScheduleSpec) -> InvalidCase:
    """Other rules: positions inside the run, well-formed shapes, directives given once, ..."""
    how = draw(st.sampled_from(OTHER_BREAKS))
    segs = list(spec.segments)
    j = draw(st.integers(0, len(segs) - 1))
    seg = segs[j]
    shapes = {
        "reversed random": "random 1.5 .. 0.5",
        "peak outside": f"bell 1 -> 1.5 at {position_text(seg.end)} -> 1",
        "zero width": f"bell 1 -> 1.5 at {position_text((seg.start + seg.end) / 2)} -> 1 width 0",
        "division by zero": "constant 1 / (2 - 2)",
        "unknown function": "expr 1 + lg(u + 1)",
        "t in a constant": "constant 1 + t",
        "log of a negative": "constant log(-1)",
        "sqrt of a negative inside": "expr 1 + sqrt(0.5 - u)",
    }
    key = f"segment {j}"
    if how in shapes:
        segs[j] = replace(seg, shape=shapes[how], declared=None)
        broken = replace(spec, segments=tuple(segs))
    elif how == "outside the run":
        key = f"segment {len(segs) - 1}"
        segs[-1] = replace(segs[-1], end=Fraction(11, 10), end_text="110%")
        broken = replace(spec, segments=tuple(segs))
    elif how == "empty segment":
        segs[j] = replace(seg, end_text=seg.start_text)
        broken = replace(spec, segments=tuple(segs))
    elif how == "duplicate name":
        key = "extra 0"
        broken = replace(spec, name="first", extra_lines=('name "second"',))
    elif how == "builtin let":
        name = draw(st.sampled_from(("pi", "e", "exp", "t", "u", "sqrt")))
        key = f"let {name}"
        broken = replace(spec, lets=(*spec.lets, Let(name, "1.5", Fraction(3, 2))))
    elif how == "extinction above 1":
        key = "extinction"
        broken = replace(spec, extinction=("150%", Fraction(3, 2)))
    else:  # reversed bounds
        key = "bounds"
        broken = replace(spec, bounds=("2", "0.5", Fraction(2), Fraction(1, 2)))
    return _case(broken, f"other: {how}", key, None)


BREAKERS: dict[str, Callable[[Callable, ScheduleSpec], InvalidCase | None]] = {
    "gap": _break_gap,
    "overlap": _break_overlap,
    "missing tail": _break_missing_tail,
    "short tail": _break_short_tail,
    "alpha <= 0": _break_positive,
    "out of bounds": _break_bounds,
    "false monotone": _break_monotone,
    "false continuous": _break_continuous,
    "unknown name": _break_unknown_name,
    "syntax": _break_syntax,
    "other": _break_other,
}


@st.composite
def invalid_schedules(draw: Callable, *, kinds: dict[str, int] | None = None) -> InvalidCase:
    """A schedule that breaks exactly one rule of the language."""
    spec = draw(valid_schedules(kinds=NO_BELLS if kinds is None else kinds))
    rules = list(BREAKERS)
    while True:
        rule = draw(st.sampled_from(rules))
        case = BREAKERS[rule](draw, spec)
        if case is not None:
            return case
        rules.remove(rule)


# ----------------------------------------------------------------------------- multi-channel schedules

CHANNEL_KINDS = ("gear", "mass", "friction", "gravity")
TARGETED_KINDS = frozenset({"gear", "mass"})  # friction and gravity take no targets
FINALS = (Fraction(1), Fraction(1), Fraction(1, 2), Fraction(3, 4), Fraction(5, 4), Fraction(33, 100))


@dataclass(frozen=True)
class ChannelSpec:
    """One channel's section: its kind and targets, how its `channel` line is written, its
    final value (and how, if declared), and its schedule (a `ScheduleSpec` ending on `final`)."""

    kind: str
    targets: tuple[str, ...]
    header: str  # the `channel` line as written, e.g. "channel mass[ torso,thigh ]"
    final_text: str | None  # the value of its `final` line; None: no such line (final 1)
    body: ScheduleSpec
    directive_order: tuple[str, ...] = ("final", "bounds", "continuous")

    @property
    def name(self) -> str:
        """The canonical name: `gear`, `mass[torso,thigh]`."""
        return f"{self.kind}[{','.join(self.targets)}]" if self.targets else self.kind

    @property
    def final(self) -> Fraction:
        return self.body.final

    def same_channel(self, other: ChannelSpec) -> bool:
        return self.kind == other.kind and set(self.targets) == set(other.targets)


@dataclass(frozen=True)
class MultiChannelSpec:
    """A file of several channels, with the truth of each (see `ChannelSpec`).

    With `implicit_gear`, the first channel (plain gear) is written without a `channel` line,
    as a file of one channel is. Lets are global: they are written at the top, or inside the
    first section (`lets_inside`)."""

    channels: tuple[ChannelSpec, ...]
    lets: tuple[Let, ...] = ()
    name: str | None = None
    extinction: tuple[str, Fraction] | None = None
    implicit_gear: bool = False
    indent: str = ""
    newline: str = "\n"
    lets_inside: bool = False
    extra_lines: tuple[str, ...] = ()  # appended verbatim (invalid variants)

    def render(self) -> tuple[str, dict[str, int]]:
        """The text, and the 1-based line of each statement: "0/channel", "1/segment 2", "1/final", ..."""
        lines: list[str] = []
        where: dict[str, int] = {}

        def emit(key: str, line: str) -> None:
            lines.append(line)
            where[key] = len(lines)

        if self.name is not None:
            emit("name", f'name "{self.name}"')
        if self.extinction is not None:
            emit("extinction", f"extinction {self.extinction[0]}")
        if not self.lets_inside:
            for let in self.lets:
                emit(f"let {let.name}", f"let {let.name} = {let.text}")
        for i, channel in enumerate(self.channels):
            if not (i == 0 and self.implicit_gear):
                emit(f"{i}/channel", channel.header)
            if i == 0 and self.lets_inside:
                for let in self.lets:
                    emit(f"let {let.name}", f"{self.indent}let {let.name} = {let.text}")
            body = channel.body
            for directive in channel.directive_order:
                if directive == "final" and channel.final_text is not None:
                    emit(f"{i}/final", f"{self.indent}final {channel.final_text}")
                elif directive == "bounds" and body.bounds is not None:
                    emit(f"{i}/bounds", f"{self.indent}bounds {body.bounds[0]} .. {body.bounds[1]}")
                elif directive == "continuous" and body.continuous:
                    emit(f"{i}/continuous", f"{self.indent}continuous")
            for j, segment in enumerate(body.segments):
                emit(f"{i}/segment {j}", self.indent + body.segment_line(segment))
        for k, extra in enumerate(self.extra_lines):
            emit(f"extra {k}", extra)
        return self.newline.join(lines) + self.newline, where

    @property
    def text(self) -> str:
        return self.render()[0]

    @property
    def tail_start(self) -> Fraction:
        """Where every channel is at its final value for good."""
        return max(channel.body.tail_start for channel in self.channels)

    def with_body(self, index: int, body: ScheduleSpec) -> MultiChannelSpec:
        channels = list(self.channels)
        channels[index] = replace(channels[index], body=body)
        return replace(self, channels=tuple(channels))

    def reordered(self, order: Sequence[int]) -> MultiChannelSpec:
        """The same channels declared in another order (each with its `channel` line)."""
        return replace(self, channels=tuple(self.channels[i] for i in order), implicit_gear=False)


target_names = st.sampled_from(("left_leg", "right_leg", "torso", "thigh", "hip_1", "knee", "foot_left_joint"))


@st.composite
def channel_headers(draw: Callable, kind: str, targets: tuple[str, ...]) -> str:
    """A `channel` line for the channel, with random spacing."""
    if not targets:
        return draw(st.sampled_from(("channel ", "channel  ", "channel\t"))) + kind
    space = st.sampled_from(("", "", " "))
    inside = ",".join(draw(space) + target + draw(space) for target in targets)
    return f"channel {kind}{draw(space)}[{inside}]"


@st.composite
def multi_channel_schedules(
    draw: Callable,
    *,
    kinds: dict[str, int] | None = None,
    max_channels: int = 3,
    max_body: int = 2,
    targets: bool | None = None,
) -> MultiChannelSpec:
    """A valid file of one to `max_channels` distinct channels (random kinds, targets, finals).

    `targets`: True, the first channel names targets; False, no channel does; None, a channel
    of a kind that takes targets names some half the time.
    """
    builder = _Builder(draw, draw(st.sampled_from((0, 0, 3))))
    count = draw(st.integers(1, max_channels))
    channels: list[ChannelSpec] = []
    while len(channels) < count:
        first_targeted = targets is True and not channels
        kind = draw(st.sampled_from(sorted(TARGETED_KINDS) if first_targeted else CHANNEL_KINDS))
        names: tuple[str, ...] = ()
        if kind in TARGETED_KINDS and targets is not False and (first_targeted or draw(st.booleans())):
            names = tuple(draw(st.lists(target_names, min_size=1, max_size=3, unique=True)))
        final = draw(st.sampled_from(FINALS))
        final_text = None if final == 1 and draw(st.booleans()) else builder.number(final)
        builder.final = final
        body = _schedule_body(
            draw,
            builder,
            kinds=CHEAP_KINDS if kinds is None else kinds,
            max_body=max_body,
            one_shapes=ONE_SHAPES if final == 1 else FINAL_SHAPES,
            declare=True,
            bounds=None,
        )
        header = draw(channel_headers(kind, names))
        order = tuple(draw(st.permutations(("final", "bounds", "continuous"))))
        channel = ChannelSpec(kind, names, header, final_text, body, order)
        if not any(channel.same_channel(other) for other in channels):
            channels.append(channel)
    implicit = channels[0].kind == "gear" and not channels[0].targets and draw(st.booleans())
    extinction = None
    if draw(st.integers(0, 3)) == 0:
        p = Fraction(draw(st.integers(0, 100)), 100)
        extinction = (builder.number(p, allow_let=False), p)
    return MultiChannelSpec(
        channels=tuple(channels),
        lets=tuple(builder.lets),
        name=draw(st.none() | free_text),
        extinction=extinction,
        implicit_gear=implicit,
        indent=draw(st.sampled_from(("", "  ", "\t"))),
        newline=draw(st.sampled_from(("\n", "\r\n"))),
        lets_inside=draw(st.booleans()),
    )


BODY_BREAKS = (
    "gap",
    "overlap",
    "missing tail",
    "short tail",
    "alpha <= 0",
    "out of bounds",
    "false monotone",
    "false continuous",
)
CHANNEL_BREAKS = (
    "unknown kind",
    "targets of friction",
    "empty targets",
    "repeated target",
    "channel twice",
    "final not positive",
    "final twice",
)


def _break_channel_line(draw: Callable, multi: MultiChannelSpec, how: str) -> InvalidCase:
    """A broken `channel` or `final` line in a valid multi-channel file."""
    i = draw(st.integers(0, len(multi.channels) - 1))
    channel = multi.channels[i]
    key, message = f"{i}/channel", None
    if how == "unknown kind":
        wrong = draw(st.sampled_from(("strength", "gears", "Mass", "gravit", "density")))
        header = f"channel {wrong}" + (f"[{','.join(channel.targets)}]" if channel.targets else "")
        channel, message = replace(channel, header=header), "unknown channel"
    elif how == "targets of friction":
        kind = draw(st.sampled_from(("friction", "gravity")))
        channel, message = replace(channel, kind=kind, targets=("a",), header=f"channel {kind}[a]"), "takes no targets"
    elif how == "empty targets":
        kind = draw(st.sampled_from(("gear", "mass")))
        channel, message = replace(channel, header=f"channel {kind}[]"), "names no"
    elif how == "repeated target":
        target = draw(target_names)
        kind = draw(st.sampled_from(("gear", "mass")))
        channel, message = replace(channel, header=f"channel {kind}[{target}, {target}]"), "named twice"
    elif how == "channel twice":
        copy = replace(channel, header=f"channel {channel.name}")
        broken = replace(multi, channels=(*multi.channels, copy), implicit_gear=False)
        text, where = broken.render()
        return InvalidCase(text, "channel: channel twice", where[f"{len(multi.channels)}/channel"], "given twice")
    elif how == "final not positive":
        value = draw(st.sampled_from(("0", "-0.5", "1 - 1")))
        channel, key, message = replace(channel, final_text=value), f"{i}/final", "must be above 0"
    else:  # final twice
        order = (*channel.directive_order, "final")
        text = replace(channel, final_text=channel.final_text or "1", directive_order=order)
        broken = replace(multi, implicit_gear=False).reordered(range(len(multi.channels)))
        broken = replace(broken, channels=tuple(text if k == i else c for k, c in enumerate(broken.channels)))
        lines, where = broken.render()
        return InvalidCase(lines, "channel: final twice", where[f"{i}/final"], "given twice")
    broken = replace(multi, implicit_gear=False)
    broken = replace(broken, channels=tuple(channel if k == i else c for k, c in enumerate(multi.channels)))
    text, where = broken.render()
    return InvalidCase(text, f"channel: {how}", where[key], message)


@st.composite
def invalid_multi_channel_schedules(draw: Callable) -> InvalidCase:
    """A multi-channel file that breaks exactly one rule: of one channel's schedule (in its
    section), or of a `channel` or `final` line."""
    multi = draw(multi_channel_schedules(kinds=CHEAP_KINDS))
    if draw(st.integers(0, 2)) == 0:
        return _break_channel_line(draw, multi, draw(st.sampled_from(CHANNEL_BREAKS)))
    i = draw(st.integers(0, len(multi.channels) - 1))
    rules = list(BODY_BREAKS)
    while True:
        rule = draw(st.sampled_from(rules))
        case = BREAKERS[rule](draw, multi.channels[i].body)
        if case is not None:
            break
        rules.remove(rule)
    assert case.spec is not None and case.key is not None
    text, where = multi.with_body(i, case.spec).render()
    return InvalidCase(text, f"channel {i}: {case.rule}", where[f"{i}/{case.key}"], case.message)
