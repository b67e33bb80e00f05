"""Walker2d, "uni": run forward; descriptor = each foot's duty factor (QDax `walker2d_uni`)."""

from __future__ import annotations

import jax
from brax.envs.base import PipelineEnv

from smol_dsl.tasks.base import Task
from smol_dsl.tasks.feet import duty_factor_bounds, feet_environment, feet_task

FEET = ("foot", "foot_left")
DESCRIPTOR_LOW, DESCRIPTOR_HIGH = duty_factor_bounds(len(FEET))
REWARD_OFFSET = 1.413  # QDax's offset for walker2d_uni: keeps per-step rewards positive


def environment(backend: str = "spring") -> PipelineEnv:
    """The Brax walker2d env this task scores policies in."""
    return feet_environment("walker2d", backend)


def make(
    episode_length: int = 1000,
    hidden_layer_sizes: tuple[int, ...] = (64, 64),
    *,
    init_key: jax.Array | None = None,
    backend: str = "spring",
) -> Task:
    """The walker2d task; fitness = sum of Brax's walker2d reward (forward velocity,
    healthy bonus, control cost) until the walker falls."""
    return feet_task("walker2d", FEET, REWARD_OFFSET, episode_length, hidden_layer_sizes, init_key, backend)
