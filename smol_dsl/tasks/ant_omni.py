"""Ant, "omni": reach anywhere; descriptor = final (x, y); fitness = minus the energy used.

As QDax's `ant_omni`: Brax's ant reward without its forward-velocity term (so the
healthy bonus minus control and contact costs), descriptor the torso's (x, y) after the
episode, clipped to [-30, 30]^2.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.base import PipelineEnv, State

from smol_dsl.tasks.base import Task, deterministic_init_state, last_valid, make_policy
from smol_dsl.tasks.quiet import brax_environment

POSITION_LIMIT = 30.0
DESCRIPTOR_LOW = (-POSITION_LIMIT, -POSITION_LIMIT)
DESCRIPTOR_HIGH = (POSITION_LIMIT, POSITION_LIMIT)
REWARD_OFFSET = 3.0  # QDax's offset for ant_omni


def environment(backend: str = "spring") -> PipelineEnv:
    """The Brax ant env this task scores policies in."""
    return brax_environment("ant", backend=backend, debug=False)


def make(
    episode_length: int = 100,
    hidden_layer_sizes: tuple[int, ...] = (256, 256),
    *,
    init_key: jax.Array | None = None,
    backend: str = "spring",
) -> Task:
    """The ant_omni task."""
    env = environment(backend)
    torso = env.sys.link_names.index("torso")
    low = jnp.full((2,), -POSITION_LIMIT)
    high = jnp.full((2,), POSITION_LIMIT)

    def xy_position(state: State) -> jax.Array:
        return jnp.clip(state.pipeline_state.x.pos[torso][:2], low, high)

    def energy_reward(state: State) -> jax.Array:
        return state.reward - state.metrics["reward_forward"]

    key = jax.random.key(0) if init_key is None else init_key
    return Task(
        name="ant_omni",
        env=env,
        policy=make_policy(hidden_layer_sizes, env.action_size),
        episode_length=episode_length,
        descriptor_size=2,
        descriptor_low=DESCRIPTOR_LOW,
        descriptor_high=DESCRIPTOR_HIGH,
        qd_offset=REWARD_OFFSET * episode_length,
        init_state=deterministic_init_state(env, key),
        state_descriptor=xy_position,
        reward=energy_reward,
        final_descriptor=last_valid,
    )
