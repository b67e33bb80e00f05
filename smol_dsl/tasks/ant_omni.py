"""Ant, "omni": reach anywhere; descriptor = final (x, y); fitness = minus the energy used.

As QDax's `ant_omni`: Brax's ant reward without its forward-velocity term (so the
healthy bonus minus control and contact costs), descriptor the torso's (x, y) after the
episode, clipped to the spec's descriptor box ([-30, 30]^2).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from smol_dsl.tasks.base import Task, last_valid, make_policy
from smol_dsl.tasks.physics import DEFAULT_PHYSICS, check_physics
from smol_dsl.tasks.quiet import brax_environment

if TYPE_CHECKING:
    from brax.envs.base import State

    from smol_dsl.tasks.registry import TaskSpec


def make(
    spec: TaskSpec,
    *,
    episode_length: int = 100,
    hidden_layer_sizes: tuple[int, ...] = (256, 256),
    physics: str = DEFAULT_PHYSICS,
) -> Task:
    """The ant_omni task."""
    env = brax_environment(spec.environment, backend=check_physics(physics).backend, debug=False)
    torso = env.sys.link_names.index("torso")
    low = jnp.asarray(spec.descriptor_low)
    high = jnp.asarray(spec.descriptor_high)

    def xy_position(state: State) -> jax.Array:
        return jnp.clip(state.pipeline_state.x.pos[torso][:2], low, high)

    def energy_reward(state: State) -> jax.Array:
        return state.reward - state.metrics["reward_forward"]

    return Task(
        spec=spec,
        env=env,
        policy=make_policy(hidden_layer_sizes, env.action_size),
        episode_length=episode_length,
        state_descriptor=xy_position,
        reward=energy_reward,
        final_descriptor=last_valid,
        physics=physics,
    )
