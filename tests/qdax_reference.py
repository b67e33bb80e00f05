"""QDax's own scoring of policies, as a QDax user runs it, in a Brax env whose `sys` may be
edited by hand: the reference of the task tests (test_tasks, test_body).

`create_brax_scoring_fn(env, policy, get_feet_contact_proportion, key)` then `score(params,
key)`. For an edited env the episode start is computed as it computes it (eagerly: `env.reset`
of the key's second half, in the edited env), and the one difference is that the rollout
takes the edited `sys` as an argument instead of baking it into the program, so that every
edit of one env shares one compilation (edits change values of `sys`, never its structure).
XLA compiles the physics differently for a `sys` baked in (folded into the program) and one
passed in: after 50 steps ant_uni's fitnesses differ by up to 0.04 (0.7%) between the two. So
a plain env is scored by QDax exactly as is (the tests compare it at rtol 1e-5), and only
edited ones, compared at rtol 1e-4, take `sys` as an argument.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import qdax.tasks.brax.v2 as qdax_envs
from qdax.tasks.brax.descriptor_extractors import get_feet_contact_proportion
from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn
from qdax.tasks.brax.v2.wrappers.locomotion_wrappers import FeetContactWrapper

KEY = 3  # the key of QDax's deterministic episode start and of its scoring


def qdax_env(qdax_name: str, episode_length: int, feet: tuple[int, ...] | None = None):
    """QDax's env of that name; with `feet`, its feet-contact wrapper told which links are the feet."""
    env = qdax_envs.create(qdax_name, episode_length=episode_length)
    if feet is not None:
        wrapper = env
        while not isinstance(wrapper, FeetContactWrapper):
            wrapper = wrapper.env
        wrapper._feet_idx = jnp.asarray(feet)
    return env


def qdax_scores(qdax_name, task, params, *, episode_length: int, edit=None, feet=None):
    """QDax's fitnesses and descriptors of `params` in env `qdax_name`, its sys changed by `edit`."""
    env = qdax_env(qdax_name, episode_length, feet)
    key = jax.random.key(KEY)
    if edit is None:
        score = create_brax_scoring_fn(
            env, task.policy, get_feet_contact_proportion, key, episode_length=episode_length
        )
        fitnesses, descriptors, _ = score(params, key)
        return np.asarray(fitnesses), np.asarray(descriptors)
    standard = env.unwrapped.sys
    sys = edit(standard)
    # the edit's values in the standard's dtypes (a Python float written in would retrace)
    sys = jax.tree.map(lambda new, old: jnp.asarray(new, old.dtype) if hasattr(old, "dtype") else new, sys, standard)
    env.unwrapped.sys = sys
    _, subkey = jax.random.split(key)
    start = env.reset(subkey)  # eagerly, as create_brax_scoring_fn computes it
    rollout = _rollout(qdax_name, task.policy, episode_length, None if feet is None else tuple(feet))
    fitnesses, descriptors = rollout(sys, start, params, key)
    return np.asarray(fitnesses), np.asarray(descriptors)


@functools.cache
def _rollout(qdax_name, policy, episode_length, feet):
    """QDax's scoring function of (sys, episode start, params, key), jitted once per env."""

    @jax.jit
    def rollout(sys, start, params, key):
        env = qdax_env(qdax_name, episode_length, feet)
        env.unwrapped.sys = sys
        score = create_brax_scoring_fn(
            env,
            policy,
            get_feet_contact_proportion,
            key,
            episode_length=episode_length,
            deterministic=False,
            play_reset_fn=lambda _: start,
        )
        fitnesses, descriptors, _ = score(params, key)
        return fitnesses, descriptors

    return rollout
