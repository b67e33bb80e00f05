"""The phases of a scheduled training: the body of each, and which phase a generation is in."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from smol_dsl.errors import ScheduleError
from smol_dsl.qdax.scoring import as_schedule

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule


def phase_bodies(
    schedule: Schedule | str | os.PathLike[str], num_phases: int, key: jax.Array | None = None
) -> jax.Array:
    """The body of every phase, (num_phases, C) float32 (the schedule's channels, in its
    order): the bodies `score` takes, those `smol-dsl run` trains in. `smol-dsl run --seed S`
    draws a schedule's random segments from `schedule_key(S)`; `key` may be None for a
    schedule without random draws. A ValueError for a value that is not finite and positive."""
    schedule = as_schedule(schedule)
    try:
        values = schedule.checked_phase_values(num_phases, key)
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
