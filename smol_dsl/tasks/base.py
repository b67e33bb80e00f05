"""α-aware QD locomotion tasks on Brax v2: the shared rollout and the `Task` record.

A task scores a batch of MLP policies in a Brax environment whose actuator gear is
multiplied by α. α is a traced argument of the scoring function, so a new α never
recompiles: the environment's `sys` (Brax keeps physics parameters there) is replaced by
one with `actuator.gear * alpha` inside the traced computation.

Rollouts follow QDax's `scoring_function_brax_envs` exactly (same deterministic initial
state, same masking after the first `done`, descriptors from the state *before* each
step), so at α = 1 fitnesses and descriptors equal QDax's `walker2d_uni`,
`halfcheetah_uni` and `ant_omni` for the same policy parameters.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import PipelineEnv, State

ScoringFn = Callable[[Any, jax.Array, jax.Array], tuple[jax.Array, jax.Array, dict[str, jax.Array]]]
"""(policy params batch, alpha, key) -> (fitnesses (B,), descriptors (B, D), extra)."""


def scale_gear(env: PipelineEnv, alpha: jax.Array) -> PipelineEnv:
    """A shallow copy of a Brax env whose actuators' gear is multiplied by alpha.

    Works inside jit with a traced alpha: only `sys` changes, and Brax's pipelines read
    every physics parameter from `sys`.
    """
    scaled = copy.copy(env)
    sys = env.sys
    scaled.sys = sys.replace(actuator=sys.actuator.replace(gear=sys.actuator.gear * alpha))
    return scaled


@dataclass(frozen=True, eq=False)  # compared and hashed by identity: it holds arrays
class Task:
    """A QD task: environment, policy network, descriptor space and α-aware scoring."""

    name: str
    env: PipelineEnv
    policy: Any  # a flax module mapping observations to actions in [-1, 1]
    episode_length: int
    descriptor_size: int
    descriptor_low: tuple[float, ...]
    descriptor_high: tuple[float, ...]
    qd_offset: float  # added per filled cell to the QD score so that it is positive
    init_state: State  # the deterministic start of every episode
    state_descriptor: Callable[[State], jax.Array]  # per-step descriptor of a state
    reward: Callable[[State], jax.Array]  # per-step fitness reward of a (post-step) state
    final_descriptor: Callable[[jax.Array, jax.Array], jax.Array]  # (per-step, valid mask)

    def init_policies(self, key: jax.Array, batch_size: int) -> Any:
        """A batch of freshly initialised policy parameters."""
        keys = jax.random.split(key, batch_size)
        dummy = jnp.zeros((self.env.observation_size,))
        return jax.vmap(self.policy.init, in_axes=(0, None))(keys, dummy)

    def start_state(self, init_key: jax.Array) -> State:
        """The deterministic episode start for another init key (QDax: env.reset of a split key)."""
        return deterministic_init_state(self.env, init_key)

    def rollout(self, params: Any, alpha: jax.Array, start: State | None = None) -> tuple[jax.Array, jax.Array]:
        """Fitness and descriptor of one policy at actuator scale alpha, from `start`
        (default: the task's own init_state)."""
        env = scale_gear(self.env, alpha)
        start = self.init_state if start is None else start

        def step(carry: tuple[State, jax.Array], _: None) -> tuple[tuple[State, jax.Array], tuple]:
            state, ended = carry
            descriptor = self.state_descriptor(state)
            action = self.policy.apply(params, state.obs)
            next_state = env.step(state, action)
            return (next_state, ended | (next_state.done > 0)), (self.reward(next_state), descriptor, ended)

        _, (rewards, descriptors, ended) = jax.lax.scan(
            step, (start, jnp.asarray(False)), None, length=self.episode_length
        )
        valid = ~ended  # a step counts until and including the one that ends the episode
        fitness = jnp.sum(jnp.where(valid, rewards, 0.0))
        return fitness, self.final_descriptor(descriptors, valid)

    def score(self, params: Any, alpha: jax.Array, start: State | None = None) -> tuple[jax.Array, jax.Array]:
        """Fitnesses (B,) and descriptors (B, D) of a batch of policies (not jitted: for
        use inside other traced programs, such as a sweep's per-run step)."""
        return jax.vmap(self.rollout, in_axes=(0, None, None))(params, alpha, start)

    def scoring_fn(self) -> ScoringFn:
        """The jitted (params, alpha, key) -> (fitnesses, descriptors, extra) for batches.

        Built once per task, so every run and re-evaluation with this task shares one
        compilation per batch shape. Episodes start from the task's deterministic state,
        so `key` is unused; it is kept for QDax's scoring-function convention.
        """
        return self._scoring_fn

    @functools.cached_property
    def _scoring_fn(self) -> ScoringFn:
        @jax.jit
        def score(params: Any, alpha: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array, dict]:
            del key
            fitnesses, descriptors = self.score(params, alpha)
            return fitnesses, descriptors, {}

        return score


def mean_over_valid(per_step: jax.Array, valid: jax.Array) -> jax.Array:
    """The average of per-step descriptors over the valid steps (duty factors)."""
    weights = valid.astype(per_step.dtype)[:, None]
    return jnp.sum(jnp.where(weights > 0, per_step, 0.0), axis=0) / jnp.sum(weights)


def last_valid(per_step: jax.Array, valid: jax.Array) -> jax.Array:
    """The per-step descriptor of the last valid step (a final position)."""
    last = jnp.sum(valid.astype(jnp.int32)) - 1
    return per_step[last]


def make_policy(hidden_layer_sizes: tuple[int, ...], action_size: int) -> Any:
    """QDax's MLP policy: tanh hidden layers, tanh output in [-1, 1]."""
    from qdax.core.neuroevolution.networks.networks import MLP

    return MLP(
        layer_sizes=(*hidden_layer_sizes, action_size),
        kernel_init=jax.nn.initializers.lecun_uniform(),
        activation=jnp.tanh,
        final_activation=jnp.tanh,
    )


def deterministic_init_state(env: PipelineEnv, key: jax.Array) -> State:
    """The start state QDax uses for deterministic scoring: env.reset of a split key.

    Computed eagerly, as QDax does: a jitted reset can differ in the last bit, and
    locomotion is chaotic enough for that to show after a few hundred steps.
    """
    _, subkey = jax.random.split(key)
    return env.reset(subkey)
