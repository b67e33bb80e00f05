"""Forward-locomotion tasks described by the duty factor of each foot (QDax's "uni" tasks).

Fitness is the sum of the Brax env's own reward until the body falls (walker2d: forward
velocity, healthy bonus, control cost; halfcheetah: forward velocity minus control cost);
the descriptor is the proportion of steps each foot (the spec's `details["feet"]`) touches
the ground, from the pipeline's contacts (its debug output).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from smol_dsl.tasks.base import Task, make_policy, mean_over_valid
from smol_dsl.tasks.quiet import brax_environment
from smol_dsl.tasks.registry import TaskSpec

if TYPE_CHECKING:
    from brax.envs.base import State


def make(
    spec: TaskSpec,
    *,
    episode_length: int = 1000,
    hidden_layer_sizes: tuple[int, ...] = (64, 64),
    backend: str = "spring",
) -> Task:
    """The task of `spec` (walker2d, halfcheetah): its Brax env with contacts recorded."""
    env = brax_environment(spec.environment, backend=backend, debug=True)
    feet = spec.details["feet"]
    feet_idx = jnp.asarray([i for i, name in enumerate(env.sys.link_names) if name in feet])

    def feet_contact(state: State) -> jax.Array:
        contact = state.pipeline_state.contact
        touching = (contact.link_idx[1][None, :] == feet_idx[:, None]) & (contact.dist[None, :] <= 0)
        return jnp.any(touching, axis=-1).astype(jnp.float32)

    return Task(
        spec=spec,
        env=env,
        policy=make_policy(hidden_layer_sizes, env.action_size),
        episode_length=episode_length,
        state_descriptor=feet_contact,
        reward=lambda state: state.reward,
        final_descriptor=mean_over_valid,
    )
