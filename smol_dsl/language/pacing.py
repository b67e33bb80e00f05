"""Pacing: curves that wait for the archive (`pace when CONDITION within N phases`).

A paced channel's curve is read on a *development clock* instead of the budget's: the clock
starts at 0 and, at each phase's end, moves one phase on where the condition holds over the
run's metrics, or where the body has been held `within` phases; otherwise it stands still
and the next phase trains in the same body (nothing re-evaluated). A channel is in phase p in
its body of open-loop phase `d`, the clock's reading, so d <= p always and d >= floor(p / N).
The final-body tail stays pinned to the budget: from the file's first tail phase every clock
reads the phase itself, so the run ends on the final body whatever its metrics did (where
development has not finished by then, the rest of the curve is skipped: the tail jump).

This module owns the clause from the parsed tree on: compiling a condition to exact sympy
(`compile_pace`), the proof that it can hold and can fail (interval arithmetic over what
each metric can be), its evaluation in JAX (`Pacing.holds`), the decision as a pure,
jittable function of a run's `PaceState` (`Pacing.initial`, `decide`, `settle`) and each
channel's phase index (`Pacing.indices`); `pacing_certificate` says what `check` prints.

The condition's names, at a phase's end:

- `coverage` (the share of the archive's cells filled, 0 to 1: write `50%` for half),
  `max_fitness` and `qd_score`, as metrics.csv logs them (coverage there is in %);
- `before(x)` and `after(x)` of each: its value at the phase end just before the clock last
  moved and just after that boundary's re-evaluation (before any move: after the initial
  population, both);
- `waited`: the phases the body has been held so far, the one ending included (1 to N - 1
  where the condition decides: at N the clock moves anyway).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import sympy as sp
from sympy.calculus.accumulationbounds import AccumBounds

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language import tree
from smol_dsl.language.symbolic import number_text

if TYPE_CHECKING:
    import jax

    from smol_dsl.language.expressions import Scope

METRICS = ("coverage", "max_fitness", "qd_score")
"""The metrics a condition reads at a phase's end, in `PaceState`'s order."""
WAITED = "waited"
MEMORIES = ("before", "after")
SYMBOLS: dict[str, sp.Symbol] = {
    **{name: sp.Symbol(name, real=True) for name in METRICS},
    **{f"{when}({name})": sp.Symbol(f"{when}({name})", real=True) for when in MEMORIES for name in METRICS},
    WAITED: sp.Symbol(WAITED, integer=True, positive=True),
}
"""Each name a condition may use, as a sympy symbol (`before(coverage)` is one name)."""
NAMES = (*METRICS, WAITED, *MEMORIES)
"""The names pacing defines: no `let` may take one."""
_FUNCTIONS = ("min", "max", "abs")
_RANGES: dict[str, tuple[sp.Expr, sp.Expr]] = {
    "coverage": (sp.Integer(0), sp.Integer(1)),
    "max_fitness": (-sp.oo, sp.oo),
    "qd_score": (-sp.oo, sp.oo),
}
_COMPARE: dict[str, Callable[[sp.Expr, sp.Expr], sp.Basic]] = {">=": sp.Ge, "<=": sp.Le, ">": sp.Gt, "<": sp.Lt}
MIN_WITHIN, MAX_WITHIN = 2, 1000


@dataclass(frozen=True)
class Clock:
    """One `pace` line: its condition (exact sympy, over `SYMBOLS`), the most phases a body is
    held (`within`), and where it is written."""

    condition: sp.Basic
    within: int
    span: Span
    condition_span: Span

    def holds(self, values: Mapping[str, jax.Array]) -> jax.Array:
        """Whether the condition holds for `values` (each name of `SYMBOLS` to an array; a
        comparison with NaN is false); traceable, elementwise."""
        return _evaluate_condition(self.condition, values)

    def slowest(self, phase: int) -> int:
        """The lowest development step in `phase` (0-based): a step every `within` phases."""
        return phase // self.within


def compile_pace(scope: Scope, pace: tree.Pace) -> Clock:
    """A `pace` line's condition and bound, checked: known names, arithmetic the decision
    evaluates exactly, a bound from 2 to 1000 phases, and a condition that can both hold
    and fail (where interval arithmetic proves it cannot, one located error)."""
    within_value = scope.constant(pace.within, what="the pace bound")
    if not (within_value.is_Integer and MIN_WITHIN <= int(within_value) <= MAX_WITHIN):
        shown = number_text(within_value)
        hint = "a body is held at most this many phases: a whole number from 2 to 1000, e.g. `within 3 phases`"
        if within_value.is_Integer and int(within_value) == 1:
            hint = "with `within 1 phases` the body moves on at every phase end, as without `pace`: delete the line"
        raise ScheduleError(
            f"the pace bound is {shown}, not a whole number of phases from 2 to 1000",
            span=_expr_span(pace.within),
            hint=hint,
        )
    within = int(within_value)
    condition = _condition(scope, pace.condition)
    verdict = _decided(condition, within)
    if verdict is not None:
        always = "always holds" if verdict else "can never hold"
        raise ScheduleError(
            f"the pace condition {always}, so the curve would "
            + ("never wait" if verdict else f"wait {within} phases every step"),
            span=pace.condition.span,
            hint=(
                "write a condition that can fail (or delete the `pace` line)"
                if verdict
                else "write a condition that can hold (or drop `pace` for a fixed pace)"
            )
            + f"; at a phase's end {_ranges_text(within)}",
        )
    return Clock(condition, within, pace.span, pace.condition.span)


def _ranges_text(within: int) -> str:
    return (
        "coverage, before(coverage) and after(coverage) run from 0 to 1 (write 50% for half the cells), "
        "max_fitness and qd_score are any number, and waited runs from 1 to "
        f"{within - 1} (at {within} the body moves on anyway)"
    )


def _expr_span(node: tree.Expr | tree.Condition) -> Span:
    return node.span


# ---------------------------------------------------------------- compiling a condition


def _condition(scope: Scope, node: tree.Condition) -> sp.Basic:
    if isinstance(node, tree.Logical):
        left, right = _condition(scope, node.left), _condition(scope, node.right)
        return sp.And(left, right) if node.op == "and" else sp.Or(left, right)
    left, right = (_value(scope, side) for side in (node.left, node.right))
    return _COMPARE[node.op](left, right)


def _value(scope: Scope, node: tree.Expr) -> sp.Expr:
    """One side of a comparison, exact: `before(x)`/`after(x)` read as their names."""
    value = scope.build(_named_memories(scope, node), variables=dict(SYMBOLS))
    for power in value.atoms(sp.Pow):
        if not power.exp.is_Integer:
            raise ScheduleError(
                f"`{power}` is not a whole power",
                span=node.span,
                hint="a pace condition uses + - * / and whole powers (`**2`), min, max and abs",
            )
    return value


def _named_memories(scope: Scope, node: tree.Expr) -> tree.Expr:
    """`node` with each `before(x)`/`after(x)` call turned into the name `before(x)`, every
    name known and every function one a condition evaluates exactly."""
    if isinstance(node, tree.Name):
        if node.id not in SYMBOLS and node.id not in scope.constants:
            if node.id in MEMORIES:
                hint = f"`{node.id}` takes a metric: `{node.id}(coverage)`"
            else:
                hint = "a pace condition reads " + ", ".join(f"`{name}`" for name in (*METRICS, WAITED))
                hint += ", `before(...)` and `after(...)` of a metric, and `let` constants"
            raise ScheduleError(f"unknown name `{node.id}` in a pace condition", span=node.span, hint=hint)
        return node
    if isinstance(node, tree.Call):
        if node.function in MEMORIES:
            if len(node.args) != 1 or not isinstance(node.args[0], tree.Name) or node.args[0].id not in METRICS:
                raise ScheduleError(
                    f"`{node.function}(...)` takes one metric",
                    span=node.span,
                    hint=f"write `{node.function}(coverage)`, `{node.function}(max_fitness)` "
                    f"or `{node.function}(qd_score)`",
                )
            return tree.Name(f"{node.function}({node.args[0].id})", node.span)
        if node.function not in _FUNCTIONS:
            raise ScheduleError(
                f"`{node.function}` is not evaluated in a pace condition",
                span=Span(node.span.line, node.span.column, len(node.function)),
                hint="a pace condition uses + - * / and whole powers, "
                + ", ".join(f"`{name}`" for name in _FUNCTIONS)
                + ", and `before(...)`/`after(...)` of a metric",
            )
        return tree.Call(node.function, tuple(_named_memories(scope, arg) for arg in node.args), node.span)
    if isinstance(node, tree.Unary):
        return tree.Unary(node.op, _named_memories(scope, node.operand), node.span)
    if isinstance(node, tree.Binary):
        return tree.Binary(node.op, _named_memories(scope, node.left), _named_memories(scope, node.right), node.span)
    return node


# ---------------------------------------------------------------- the proof: can it hold, can it fail?


def _bounds(within: int) -> dict[sp.Symbol, AccumBounds]:
    ranges = {SYMBOLS[name]: AccumBounds(*_RANGES[name]) for name in METRICS}
    for when in MEMORIES:
        ranges.update({SYMBOLS[f"{when}({name})"]: AccumBounds(*_RANGES[name]) for name in METRICS})
    ranges[SYMBOLS[WAITED]] = AccumBounds(1, within - 1)
    return ranges


def _decided(condition: sp.Basic, within: int) -> bool | None:
    """True where the condition holds for every value the names can take, False where it
    holds for none, None where interval arithmetic cannot tell (three-valued and/or)."""
    if condition is sp.true or condition is sp.false:
        return bool(condition)
    if isinstance(condition, sp.And):
        verdicts = [_decided(part, within) for part in condition.args]
        return False if False in verdicts else (True if all(v is True for v in verdicts) else None)
    if isinstance(condition, sp.Or):
        verdicts = [_decided(part, within) for part in condition.args]
        return True if True in verdicts else (False if all(v is False for v in verdicts) else None)
    difference = sp.expand(condition.lhs - condition.rhs)  # the comparison is difference OP 0
    if difference.is_number:
        low = high = difference
    else:
        try:
            bounded = difference.subs(_bounds(within))
        except (TypeError, ValueError):
            return None
        if isinstance(bounded, AccumBounds):
            low, high = bounded.min, bounded.max
        elif bounded.is_number:
            low = high = bounded
        else:
            return None
    if low.has(sp.nan) or high.has(sp.nan):
        return None
    op = type(condition)
    if op in (sp.Ge, sp.Gt):
        always = bool(low >= 0) if op is sp.Ge else bool(low > 0)
        never = bool(high < 0) if op is sp.Ge else bool(high <= 0)
    else:
        always = bool(high <= 0) if op is sp.Le else bool(high < 0)
        never = bool(low > 0) if op is sp.Le else bool(low >= 0)
    return True if always else (False if never else None)


# ---------------------------------------------------------------- evaluation in JAX


def _evaluate_condition(condition: sp.Basic, values: Mapping[str, jax.Array]) -> jax.Array:
    import jax.numpy as jnp

    from smol_dsl.language.jaxify import evaluate

    if condition is sp.true or condition is sp.false:
        return jnp.asarray(bool(condition))
    if isinstance(condition, (sp.And, sp.Or)):
        parts = [_evaluate_condition(part, values) for part in condition.args]
        combine = jnp.logical_and if isinstance(condition, sp.And) else jnp.logical_or
        result = parts[0]
        for part in parts[1:]:
            result = combine(result, part)
        return result
    inputs = {SYMBOLS[name]: jnp.asarray(value, jnp.float32) for name, value in values.items()}
    left = evaluate(condition.lhs, inputs, jnp.float32)
    right = evaluate(condition.rhs, inputs, jnp.float32)
    compare = {sp.GreaterThan: jnp.greater_equal, sp.StrictGreaterThan: jnp.greater}
    compare |= {sp.LessThan: jnp.less_equal, sp.StrictLessThan: jnp.less}
    return compare[type(condition)](left, right)


# ---------------------------------------------------------------- a run's pacing state and the decision


class PaceState(NamedTuple):
    """One run's pacing, a pytree (stack runs on a leading axis, as QDax stacks repertoires):
    per clock its development step, the phases its body has been held, and the metrics
    (`METRICS` order) at the phase end before its last move and after that re-evaluation."""

    development: jax.Array  # (K,) int32
    waited: jax.Array  # (K,) int32
    before: jax.Array  # (K, 3) float32
    after: jax.Array  # (K, 3) float32


@dataclass(frozen=True)
class Pacing:
    """A schedule's pacing: its clocks (one per `pace` line) and, per channel of the schedule
    in order, the clock it reads (None: the budget's) and the first phase wholly in its tail
    is the schedule's own `tail_start`, given with the number of phases when deciding."""

    clocks: tuple[Clock, ...]
    channel_clocks: tuple[int | None, ...]

    def initial(self, metrics: Mapping[str, jax.typing.ArrayLike]) -> PaceState:
        """The state after the initial population: every clock at 0, nothing waited, before
        and after both the initial archive's `metrics` (coverage as a share, 0 to 1)."""
        import jax.numpy as jnp

        row = _metric_row(metrics)
        count = len(self.clocks)
        stacked = jnp.broadcast_to(row, (count, len(METRICS)))
        zeros = jnp.zeros((count,), jnp.int32)
        return PaceState(zeros, zeros, stacked, stacked)

    def decide(
        self,
        state: PaceState,
        metrics: Mapping[str, jax.typing.ArrayLike],
        phase: jax.typing.ArrayLike,
        tail_phase: int,
    ) -> PaceState:
        """The state for the phase after `phase`, from the metrics at its end: each clock
        moves one step where its condition holds or its body has been held `within` phases;
        from `tail_phase` on (the first phase wholly in the file's tail), it reads the phase
        itself. A clock that moved has waited 0 and remembers `metrics` as `before`; `settle`
        adds `after`. Pure and jittable (`phase` may be traced)."""
        import jax.numpy as jnp

        row = _metric_row(metrics)
        waited = state.waited + 1
        steps = []
        for index, clock in enumerate(self.clocks):
            values = {name: row[i] for i, name in enumerate(METRICS)}
            values |= {f"before({name})": state.before[index, i] for i, name in enumerate(METRICS)}
            values |= {f"after({name})": state.after[index, i] for i, name in enumerate(METRICS)}
            values[WAITED] = waited[index]
            steps.append(jnp.logical_or(clock.holds(values), waited[index] >= clock.within))
        step = jnp.stack(steps).astype(jnp.int32) if steps else jnp.zeros((0,), jnp.int32)
        following = jnp.asarray(phase, jnp.int32) + 1
        development = jnp.where(following >= tail_phase, following, state.development + step)
        moved = development != state.development
        return PaceState(
            development.astype(jnp.int32),
            jnp.where(moved, 0, waited).astype(jnp.int32),
            jnp.where(moved[:, None], row, state.before),
            state.after,
        )

    def settle(self, previous: PaceState, decided: PaceState, metrics: Mapping[str, jax.typing.ArrayLike]) -> PaceState:
        """`decided` with `after` set to `metrics` (the archive after the boundary's
        re-evaluation) for the clocks that moved since `previous`."""
        import jax.numpy as jnp

        moved = decided.development != previous.development
        return decided._replace(after=jnp.where(moved[:, None], _metric_row(metrics), decided.after))

    def indices(
        self, development: jax.typing.ArrayLike, phase: jax.typing.ArrayLike, tail_phases: Sequence[int]
    ) -> jax.Array:
        """Each channel's open-loop phase during `phase` (its body is the curve's in that
        phase), given the clocks' `development` (K,) and each channel's first phase wholly
        in its own tail: the clock's step, or the phase itself for an unpaced channel and
        from its tail on."""
        import jax.numpy as jnp

        phase = jnp.asarray(phase, jnp.int32)
        development = jnp.asarray(development, jnp.int32)
        columns = []
        for clock, tail_phase in zip(self.channel_clocks, tail_phases):
            if clock is None:
                columns.append(phase)
            else:
                columns.append(jnp.where(phase >= tail_phase, phase, development[clock]))
        return jnp.stack(columns)


def _metric_row(metrics: Mapping[str, jax.typing.ArrayLike]) -> jax.Array:
    import jax.numpy as jnp

    missing = [name for name in METRICS if name not in metrics]
    if missing:
        raise KeyError(f"pacing reads the metrics {', '.join(METRICS)}; missing {', '.join(missing)}")
    return jnp.stack([jnp.asarray(metrics[name], jnp.float32) for name in METRICS])


__all__ = [
    "METRICS",
    "NAMES",
    "Clock",
    "PaceState",
    "Pacing",
    "compile_pace",
]
