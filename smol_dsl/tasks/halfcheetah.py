"""HalfCheetah, "uni": run forward; descriptor = each foot's duty factor (QDax `halfcheetah_uni`)."""

from __future__ import annotations

import jax
from brax.envs.base import PipelineEnv

from smol_dsl.tasks.base import Task
from smol_dsl.tasks.feet import duty_factor_bounds, feet_environment, feet_task

FEET = ("bfoot", "ffoot")
DESCRIPTOR_LOW, DESCRIPTOR_HIGH = duty_factor_bounds(len(FEET))
REWARD_OFFSET = 9.231  # QDax's offset for halfcheetah_uni


def environment(backend: str = "spring") -> PipelineEnv:
    """The Brax halfcheetah env this task scores policies in."""
    return feet_environment("halfcheetah", backend)


def make(
    episode_length: int = 1000,
    hidden_layer_sizes: tuple[int, ...] = (64, 64),
    *,
    init_key: jax.Array | None = None,
    backend: str = "spring",
) -> Task:
    """The halfcheetah task; fitness = sum of Brax's halfcheetah reward (forward velocity
    minus control cost)."""
    return feet_task("halfcheetah", FEET, REWARD_OFFSET, episode_length, hidden_layer_sizes, init_key, backend)
