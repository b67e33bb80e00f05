"""The phases of a scheduled training: the body of each, and which phase a generation is in."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from smol_dsl.errors import ScheduleError
from smol_dsl.language.curve import check_key, check_phases
from smol_dsl.qdax.scoring import as_schedule

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule


def phase_bodies(
    schedule: Schedule | str | os.PathLike[str], num_phases: int, key: jax.Array | None = None
) -> jax.Array:
    """The body of every phase, (num_phases, C) float32 (the schedule's channels, in its
    order): the bodies `score` takes, those `smol-dsl run` trains in. `smol-dsl run --seed S`
    draws a schedule's random segments from `schedule_key(S)`, so a schedule with random
    segments needs `key`; one without takes None.

    Refused as `smol-dsl run` refuses them (ValueError): `num_phases` that leave no phase
    wholly in the schedule's final-body tail (training would not end on its final body), a
    random schedule without `key`, and a value that is not finite and positive."""
    schedule = as_schedule(schedule)
    check_phases(num_phases)
    tail = schedule.tail_problem(num_phases)
    if tail is not None:
        raise ValueError(str(tail))
    if key is None and schedule.is_random:
        raise ValueError(
            f"{schedule.name} draws random segments, so its bodies depend on the key: give key=schedule_key(seed) "
            "for those `smol-dsl run --seed seed` trains in"
        )
    try:
        values = schedule.checked_phase_values(num_phases, check_key(key))
    except ScheduleError as error:
        raise ValueError(str(error)) from None
    return jnp.asarray(values, jnp.float32)


def phase_of_generation(generation: int, generations: int, num_phases: int) -> int:
    """The phase that generation `generation` (1 .. `generations`, after the initial
    population) trains in, as `smol-dsl run` splits them: equal shares, in order. A new
    phase begins (and the repertoire is re-evaluated) where this changes."""
    if not 1 <= generation <= generations:
        raise ValueError(f"generation {generation}: generations are counted from 1 to {generations}")
    if not 1 <= num_phases <= generations:
        raise ValueError(f"{num_phases} phases of {generations} generations: each phase needs a generation")
    return ((generation - 1) * num_phases) // generations
