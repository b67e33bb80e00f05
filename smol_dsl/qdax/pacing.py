"""A paced schedule (`pace when ... within N phases`) in a plain QDax loop: the decision at
each phase end as a pure function of the run's pacing state and QDax's metrics, and the body
the state reaches. Every function is jittable and works for any schedule (one without `pace`
has no clocks, and its body moves on at every boundary, as `phase_bodies` says).

>>> import smol_dsl
>>> from smol_dsl import qdax as smol
>>> schedule = smol_dsl.load("smol-paced")  # a step once coverage is back to 90% of before
>>> metrics = {"coverage": 50.0, "max_fitness": 300.0, "qd_score": 4e4}  # QDax's, coverage in %
>>> state = smol.pacing_start(schedule, metrics)
>>> decided = smol.pace(schedule, state, {**metrics, "coverage": 40.0}, phase=0, num_phases=20)
>>> int(decided.development[0]), bool(smol.body_moves(schedule, state, decided, 1, 20))
(0, False)
>>> decided = smol.pace(schedule, state, {**metrics, "coverage": 46.0}, phase=0, num_phases=20)
>>> int(decided.development[0]), round(float(smol.phase_body(schedule, decided, 1, 20)[0]), 4)
(1, 1.4722)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from smol_dsl.language.pacing import METRICS, PaceState

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule


def pace_metrics(metrics: Mapping[str, jax.typing.ArrayLike]) -> dict[str, jax.Array]:
    """What a pacing decision reads of QDax's `default_qd_metrics` (or a metrics.csv row):
    coverage as a share (QDax's % over 100, in float32), max fitness and QD score in float32."""
    missing = [name for name in METRICS if name not in metrics]
    if missing:
        raise ValueError(
            f"a pacing decision reads the metrics {', '.join(METRICS)} (QDax's default_qd_metrics, coverage in %); "
            f"missing {', '.join(missing)}"
        )
    values = {name: jnp.asarray(metrics[name], jnp.float32) for name in METRICS}
    values["coverage"] = values["coverage"] / jnp.float32(100)
    return values


def pacing_start(schedule: Schedule, metrics: Mapping[str, jax.typing.ArrayLike]) -> PaceState:
    """The pacing state after the initial population, whose QDax metrics are `metrics`:
    every clock at 0, before and after both the initial archive's."""
    return _pacing(schedule).initial(pace_metrics(metrics))


def pace(
    schedule: Schedule,
    state: PaceState,
    metrics: Mapping[str, jax.typing.ArrayLike],
    phase: jax.typing.ArrayLike,
    num_phases: int,
) -> PaceState:
    """The decision at the end of `phase` (of `num_phases`), from the repertoire's QDax
    metrics then: the state for the next phase (each clock one step on where its condition
    holds or its bound is reached; every clock at the phase itself from the tail on)."""
    return _pacing(schedule).decide(state, pace_metrics(metrics), phase, schedule.tail_phase(num_phases))


def settle(
    schedule: Schedule, previous: PaceState, decided: PaceState, metrics: Mapping[str, jax.typing.ArrayLike]
) -> PaceState:
    """`decided` remembering `metrics` (QDax's, of the repertoire re-evaluated in the new
    body) as `after` for the clocks that moved since `previous`."""
    return _pacing(schedule).settle(previous, decided, pace_metrics(metrics))


def phase_body(
    schedule: Schedule, state: PaceState, phase: jax.typing.ArrayLike, num_phases: int, key: jax.Array | None = None
) -> jax.Array:
    """The (C,) body of `phase` that the clocks of `state` have reached: each channel the
    curve's value at its clock's step (a row of `phase_bodies` for a schedule without
    `pace`). `key` is the run's schedule key, for random segments of unpaced channels."""
    values = schedule.phase_values(num_phases, key)
    indices = schedule.phase_indices(state.development, phase, num_phases)
    return values[indices, jnp.arange(values.shape[1])]


def body_moves(
    schedule: Schedule, previous: PaceState, decided: PaceState, phase: jax.typing.ArrayLike, num_phases: int
) -> jax.Array:
    """Whether the body changes as `phase` starts (the state went from `previous` to
    `decided` at the end of the phase before): re-evaluate the repertoire where it does,
    keep it as it is where it does not."""
    before = schedule.phase_indices(previous.development, jnp.asarray(phase) - 1, num_phases)
    after = schedule.phase_indices(decided.development, phase, num_phases)
    return jnp.any(before != after)


def _pacing(schedule: Schedule):
    from smol_dsl.language.pacing import Pacing

    return schedule.pacing if schedule.pacing is not None else Pacing((), ())


__all__ = ["body_moves", "pace", "pace_metrics", "pacing_start", "phase_body", "settle"]
