"""Forward-locomotion tasks described by the duty factor of each foot (QDax's "uni" tasks).

Fitness is the sum of the Brax env's own reward until the body falls (walker2d and hopper:
forward velocity, healthy bonus, control cost; halfcheetah: forward velocity minus control
cost; ant: forward velocity, healthy bonus, control and contact costs); the descriptor is
the proportion of steps each foot (the links the spec's `details["feet"]` names, in link
order, one descriptor each) touches the ground, from the pipeline's contacts (its debug
output). Feet are named as in the spec's body plan, which names the links Brax leaves
unnamed (the ant's lower legs).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from smol_dsl.tasks.base import Task, make_policy, mean_over_valid
from smol_dsl.tasks.physics import DEFAULT_PHYSICS, check_physics
from smol_dsl.tasks.quiet import brax_environment

if TYPE_CHECKING:
    from brax.envs.base import State

    from smol_dsl.tasks.registry import TaskSpec


def make(
    spec: TaskSpec,
    *,
    episode_length: int = 1000,
    hidden_layer_sizes: tuple[int, ...] = (64, 64),
    physics: str = DEFAULT_PHYSICS,
) -> Task:
    """The task of `spec` (walker2d, halfcheetah, hopper, ant_uni): its Brax env with
    contacts recorded."""
    env = brax_environment(spec.environment, backend=check_physics(physics).backend, debug=True)
    feet = spec.details["feet"]
    links = spec.anatomy.links if spec.anatomy is not None else env.sys.link_names
    feet_idx = jnp.asarray([i for i, name in enumerate(links) if name in feet])
    if len(feet_idx) != len(feet) or len(feet) != spec.descriptor_size:
        raise ValueError(f"task {spec.name}: feet {feet} are not {spec.descriptor_size} of its links {links}")

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
        physics=physics,
    )
