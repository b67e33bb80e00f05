"""A paced run's clocks on the host: the metrics a decision reads, each run's decision at a
phase boundary, and the state a checkpoint's rows replay to.

The decision itself is the schedule's (`smol_dsl.language.pacing.Pacing.decide`, pure and
jittable), jitted once per pacing and phase count here. It reads the metrics of the rows
the runner logs through `smol_dsl.qdax.pacing.pace_metrics` (as a QDax loop does), each
converted to float32 as the archive's metrics were, so that a resumed run, replaying its
checkpoint's rows, decides exactly as it did (bit-exact resume needs no state of its own in
the checkpoint).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import lru_cache
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from smol_dsl.qdax.pacing import pace_metrics
from smol_dsl.rundir import BOUNDARY_EVENTS

if TYPE_CHECKING:
    from smol_dsl.language.channels import Channel
    from smol_dsl.language.pacing import PaceState, Pacing
    from smol_dsl.language.schedule import Schedule


@lru_cache(maxsize=32)
def _decide(pacing: Pacing, tail_phase: int) -> Any:
    return jax.jit(lambda state, metrics, phase: pacing.decide(state, metrics, phase, tail_phase))


@lru_cache(maxsize=32)
def _settle(pacing: Pacing) -> Any:
    return jax.jit(pacing.settle)


def initial(schedule: Schedule, row: Mapping[str, Any]) -> PaceState | None:
    """A run's pacing after its initial population (`row`: its init row), None if unpaced."""
    if schedule.pacing is None:
        return None
    return jax.device_get(schedule.pacing.initial(pace_metrics(row)))


def decide(schedule: Schedule, state: PaceState, row: Mapping[str, Any], phase: int, num_phases: int) -> PaceState:
    """A paced run's state for the phase after `phase`, from `row`: the metrics at its end."""
    assert schedule.pacing is not None
    decided = _decide(schedule.pacing, schedule.tail_phase(num_phases))(state, pace_metrics(row), phase)
    return jax.device_get(decided)


def settle(schedule: Schedule, previous: PaceState, decided: PaceState, row: Mapping[str, Any]) -> PaceState:
    """`decided` with the metrics after the boundary (`row`) remembered by the clocks that moved."""
    assert schedule.pacing is not None
    return jax.device_get(_settle(schedule.pacing)(previous, decided, pace_metrics(row)))


def indices(
    schedule: Schedule, state: PaceState | None, phase: int, num_phases: int, channels: Sequence[Channel]
) -> np.ndarray:
    """Per channel of `channels`, the open-loop phase whose value a run has in `phase`: the
    phase itself for an unpaced run (`state` None)."""
    if state is None:
        return np.full(len(channels), phase, dtype=np.int64)
    return np.asarray(schedule.phase_indices(state.development, phase, num_phases, channels), dtype=np.int64)


def development_columns(state: PaceState | None) -> dict[str, int]:
    """A paced run's development columns of a metrics row, one per clock (none for an
    unpaced run)."""
    from smol_dsl.rundir import development_names

    if state is None:
        return {}
    steps = np.asarray(state.development)
    return {name: int(step) for name, step in zip(development_names(len(steps)), steps, strict=True)}


def replayed(schedule: Schedule, rows: Sequence[Mapping[str, Any]], num_phases: int) -> PaceState | None:
    """A paced run's state after `rows` (its metrics rows from the start, as a checkpoint
    holds them): every boundary decided again from the row before it, as training did."""
    if schedule.pacing is None:
        return None
    state = initial(schedule, rows[0])
    for previous, row in pairwise(rows):
        if row["event"] not in BOUNDARY_EVENTS:
            continue
        decided = decide(schedule, state, previous, previous["phase"], num_phases)
        state = settle(schedule, state, decided, row)
    return state


__all__ = [
    "decide",
    "development_columns",
    "indices",
    "initial",
    "replayed",
    "settle",
]
