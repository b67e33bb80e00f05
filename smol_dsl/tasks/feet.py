"""Forward-locomotion tasks whose descriptor is the duty factor of each foot."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.base import PipelineEnv, State

from smol_dsl.tasks.base import Task, deterministic_init_state, make_policy, mean_over_valid
from smol_dsl.tasks.quiet import brax_environment


def duty_factor_bounds(feet: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The descriptor box of duty factors: [0, 1] per foot."""
    return (0.0,) * feet, (1.0,) * feet


def feet_environment(env_name: str, backend: str = "spring") -> PipelineEnv:
    """The Brax env, with the pipeline's debug output (contacts) that duty factors need."""
    return brax_environment(env_name, backend=backend, debug=True)


def feet_task(
    env_name: str,
    feet: tuple[str, ...],
    reward_offset: float,
    episode_length: int,
    hidden_layer_sizes: tuple[int, ...],
    init_key: jax.Array | None,
    backend: str,
) -> Task:
    """A Brax env scored by its own reward, described by the proportion of steps each
    foot touches the ground (contacts need the pipeline's debug output)."""
    env = feet_environment(env_name, backend)
    feet_idx = jnp.asarray([i for i, name in enumerate(env.sys.link_names) if name in feet])

    def feet_contact(state: State) -> jax.Array:
        contact = state.pipeline_state.contact
        touching = (contact.link_idx[1][None, :] == feet_idx[:, None]) & (contact.dist[None, :] <= 0)
        return jnp.any(touching, axis=-1).astype(jnp.float32)

    key = jax.random.key(0) if init_key is None else init_key
    return Task(
        name=env_name,
        env=env,
        policy=make_policy(hidden_layer_sizes, env.action_size),
        episode_length=episode_length,
        descriptor_size=len(feet),
        descriptor_low=duty_factor_bounds(len(feet))[0],
        descriptor_high=duty_factor_bounds(len(feet))[1],
        qd_offset=reward_offset * episode_length,
        init_state=deterministic_init_state(env, key),
        state_descriptor=feet_contact,
        reward=lambda state: state.reward,
        final_descriptor=mean_over_valid,
    )
