"""QD locomotion tasks on Brax v2 with a changing body: the shared rollout and `Task`.

A task scores a batch of MLP policies in a Brax environment in a *body*: a (C,) array of
factors, one per channel of `Task.channels` (by default `(GEAR,)`: every actuator's gear
times the paper's alpha; `Task.with_channels` gives the task under other channels: gear of
some actuators, mass, friction, gravity; see body.py). The body is a traced argument of the
scoring function, so a new body never recompiles: the environment's `sys` (Brax keeps
physics parameters there) is replaced inside the traced computation, by the task's hook.

Rollouts follow QDax's `scoring_function_brax_envs` exactly (same deterministic initial
state, same masking after the first `done`, descriptors from the state *before* each
step), so at α = 1 fitnesses and descriptors equal QDax's `walker2d_uni`,
`halfcheetah_uni` and `ant_omni` for the same policy parameters.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp

from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.tasks.body import Modulate, Modulation, check_channels, modulation_for
from smol_dsl.tasks.compiling import compiler_options
from smol_dsl.tasks.physics import DEFAULT_PHYSICS, check_physics
from smol_dsl.tasks.quiet import import_brax

import_brax()  # before Brax's modules, so that MJX's Warp lines are not printed (see quiet.py)

if TYPE_CHECKING:
    from brax.base import System
    from brax.envs.base import PipelineEnv, State

    from smol_dsl.tasks.registry import TaskSpec

ScoringFn = Callable[[Any, jax.Array, "State"], tuple[jax.Array, jax.Array]]
"""(policy params batch, body (C,), episode start) -> (fitnesses (B,), descriptors (B, D))."""

EPISODE_START = 0x7A5C  # folded into a run's seed for its episode start


def with_sys(env: PipelineEnv, sys: System) -> PipelineEnv:
    """A shallow copy of a Brax env that steps with another `sys` (inside jit too: Brax's
    pipelines read every physics parameter from `sys`)."""
    changed = copy.copy(env)
    changed.sys = sys
    return changed


def start_in_body(start: State, sys: System, standard: System) -> State:
    """An episode start made in the `standard` body, moved into the body `sys`.

    Brax's spring and positional pipelines compute each link's simulated mass
    (`mass ** (1 - spring_mass_scale)`) at reset, keep it in the pipeline state and never
    recompute it; every other field of the start is recomputed by `step` (inverse inertia,
    contacts) or depends on geometry only. Links whose simulated mass `sys` leaves unchanged
    keep the start's, bit for bit.
    """
    pipeline = start.pipeline_state
    if not hasattr(pipeline, "mass"):  # the generalized and MJX pipelines read sys at each step
        return start
    simulated = sys.link.inertia.mass ** (1 - sys.spring_mass_scale)
    standard_simulated = standard.link.inertia.mass ** (1 - standard.spring_mass_scale)
    mass = jnp.where(simulated == standard_simulated, pipeline.mass, simulated)
    return start.replace(pipeline_state=pipeline.replace(mass=mass))


@dataclass(frozen=True, eq=False)  # compared and hashed by identity: it holds arrays
class Task:
    """A QD task: environment, policy network, descriptor space, and scoring in a body.

    Built from its registry spec (`smol_dsl.tasks.make_task`), which holds its name,
    descriptor box, reward offset and anatomy. `physics` names what simulates it (`spring`
    or `mjx`, `tasks.physics`; the env is built with that Brax backend). A body is a (C,)
    array of factors for `channels`; `modulation(anatomy, channels)` makes the hook that
    turns it into `sys` (`modulate`): by default the physics' own (`body.modulation_for`),
    so a task of your own changes its body by its own `modulation`, for any channels. The
    episode start is not part of the task: it comes from a run's seed (`episode_start`), so
    every way of starting a run starts alike.
    """

    spec: TaskSpec
    env: PipelineEnv
    policy: Any  # a flax module mapping observations to actions in [-1, 1]
    episode_length: int
    state_descriptor: Callable[[State], jax.Array]  # per-step descriptor of a state
    reward: Callable[[State], jax.Array]  # per-step fitness reward of a (post-step) state
    final_descriptor: Callable[[jax.Array, jax.Array], jax.Array]  # (per-step, valid mask)
    channels: tuple[Channel, ...] = (GEAR,)  # what the body's factors scale, in order
    modulation: Modulation | None = None  # (anatomy, channels) -> the hook `modulate`; None: the physics' own
    physics: str = DEFAULT_PHYSICS  # what simulates the env: "spring" or "mjx" (`tasks.physics`)

    def __post_init__(self) -> None:
        check_physics(self.physics)
        object.__setattr__(self, "channels", check_channels(self.spec.anatomy, self.channels))

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def descriptor_low(self) -> tuple[float, ...]:
        return self.spec.descriptor_low

    @property
    def descriptor_high(self) -> tuple[float, ...]:
        return self.spec.descriptor_high

    @property
    def descriptor_size(self) -> int:
        return self.spec.descriptor_size

    @property
    def qd_offset(self) -> float:
        """Added per filled cell to the QD score so that it is positive."""
        return self.spec.reward_offset * self.episode_length

    @functools.cached_property
    def observation_size(self) -> int:
        """The length of an observation, found by tracing a reset (`jax.eval_shape`): Brax's
        `env.observation_size` runs a whole reset op by op, each time it is asked."""
        return int(jax.eval_shape(self.env.reset, jax.random.key(0)).obs.shape[-1])

    def init_policies(self, key: jax.Array, batch_size: int) -> Any:
        """A batch of freshly initialised policy parameters."""
        keys = jax.random.split(key, batch_size)
        dummy = jnp.zeros((self.observation_size,))
        return jax.vmap(self.policy.init, in_axes=(0, None))(keys, dummy)

    def episode_start(self, seed: int) -> State:
        """The deterministic start of every episode of the run with this seed."""
        return deterministic_init_state(self.env, jax.random.fold_in(jax.random.key(seed), EPISODE_START))

    @functools.cached_property
    def modulate(self) -> Modulate:
        """The hook that turns a body of this task's channels into the `sys` a rollout runs in."""
        return (self.modulation or modulation_for(self.physics))(self.spec.anatomy, self.channels)

    def with_channels(self, channels: Sequence[Channel | str]) -> Task:
        """This task with a body under `channels` (Channel or names like "gear[left_leg]"):
        its `score` and `scoring_fn` take a (C,) array of factors, one per channel. The same
        channels give the same Task (and so one compilation); a ValueError for channels
        the task's anatomy lacks."""
        key = tuple(Channel.parse(c) if isinstance(c, str) else c for c in channels)
        if key == self.channels:
            return self
        cached = self._channel_tasks.get(key)
        if cached is None:
            cached = self._channel_tasks[key] = replace(self, channels=key)
        return cached

    @functools.cached_property
    def _channel_tasks(self) -> dict[tuple[Channel, ...], Task]:
        return {}

    def rollout(
        self,
        params: Any,
        body: jax.Array,
        start: State,
        *,
        transitions: bool = False,
        poses: bool | Callable[[jax.Array], jax.Array] = False,
    ) -> tuple[jax.Array, ...]:
        """Fitness and descriptor of one policy in `body`, a (C,) array of factors for
        `channels`; with `transitions`, also every step's QDax `QDTransition`, as QDax's
        Brax scoring records them (`dones` and `truncations` as Brax's `EpisodeWrapper` sets
        them: the last step ends the episode); with `poses`, also the generalized positions
        `q` reached by every step (T, nq) and whether the step counts (T,): what a renderer
        draws (`smol_dsl.results.gaits`); a callable `poses` keeps what it returns of each
        step's `q` instead (under a named vmap, a few lanes' positions: the engine's replay)."""
        if jnp.shape(body) != (len(self.channels),):
            names = ", ".join(channel.name for channel in self.channels)
            raise ValueError(
                f"a body of task {self.name} is a ({len(self.channels)},) array, one factor per channel ({names}), "
                f"not of shape {jnp.shape(body)}"
            )
        sys = self.modulate(self.env.sys, body)
        env = with_sys(self.env, sys)
        start = start_in_body(start, sys, self.env.sys)
        last = self.episode_length - 1

        def step(carry: tuple[State, jax.Array], index: jax.Array | None) -> tuple[tuple[State, jax.Array], tuple]:
            state, ended = carry
            descriptor = self.state_descriptor(state)
            action = self.policy.apply(params, state.obs)
            next_state = env.step(state, action)
            reward = self.reward(next_state)
            out: tuple = (reward, descriptor, ended)
            if index is not None:
                next_descriptor = self.state_descriptor(next_state)
                out += (_transition(state, action, next_state, reward, descriptor, next_descriptor, index == last),)
            if poses:
                q = next_state.pipeline_state.q
                out += (poses(q) if callable(poses) else q,)
            return (next_state, ended | (next_state.done > 0)), out

        steps = jnp.arange(self.episode_length) if transitions else None
        _, (rewards, descriptors, ended, *recorded) = jax.lax.scan(
            step, (start, jnp.asarray(False)), steps, length=self.episode_length
        )
        valid = ~ended  # a step counts until and including the one that ends the episode
        fitness = jnp.sum(jnp.where(valid, rewards, 0.0))
        return (fitness, self.final_descriptor(descriptors, valid), *recorded, *((valid,) if poses else ()))

    def score(
        self, params: Any, body: jax.Array, start: State, *, transitions: bool = False, poses: bool = False
    ) -> tuple[jax.Array, ...]:
        """Fitnesses (B,) and descriptors (B, D) of a batch of policies in `body` (and, with
        `transitions`, their (B, episode_length) `QDTransition`s; with `poses`, every step's
        positions and whether it counts, as `rollout`); not jitted: for use inside other
        traced programs, such as the runner's per-run step."""
        rollout = partial(self.rollout, transitions=transitions, poses=poses)
        return jax.vmap(rollout, in_axes=(0, None, None))(params, body, start)

    def scoring_fn(self) -> ScoringFn:
        """`score`, jitted once per task: the body and the start are traced, so any body and
        any episode start share one compilation per batch shape."""
        return self._scoring_fn

    @functools.cached_property
    def _scoring_fn(self) -> ScoringFn:
        return jax.jit(self.score, compiler_options=self.compiler_options())

    def compiler_options(self, platform: str | None = None) -> dict[str, str] | None:
        """The XLA options its programs compile with on `platform` (default: JAX's default
        backend): faster on CPUs, the same results bit for bit (`tasks.compiling`), where that
        was measured: on spring; on MJX, XLA's defaults."""
        if self.physics != DEFAULT_PHYSICS:
            return None
        return compiler_options(self.name, platform or jax.default_backend())


def _transition(
    state: State,
    action: jax.Array,
    next_state: State,
    reward: jax.Array,
    descriptor: jax.Array,
    next_descriptor: jax.Array,
    last: jax.Array,
) -> Any:
    """One step as QDax's `QDTransition`: the episode is done at its last step, which is a
    truncation unless the environment ended it there. `next_obs` is always the state the
    step reached (QDax's env restarts an ended episode within the step, so its `next_obs`
    at an end is the restart's; TD3 ignores it there: a truncation is not bootstrapped)."""
    from qdax.core.neuroevolution.buffers.buffer import QDTransition

    done = next_state.done
    return QDTransition(
        obs=state.obs,
        next_obs=next_state.obs,
        rewards=reward,
        dones=jnp.where(last, jnp.ones_like(done), done),
        truncations=jnp.where(last, 1 - done, jnp.zeros_like(done)),
        actions=action,
        state_desc=descriptor,
        next_state_desc=next_descriptor,
    )


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
