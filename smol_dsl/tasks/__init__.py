"""The bundled α-aware QD tasks, by name: `make_task("walker2d", episode_length=100)`.

Importing this package imports neither JAX nor Brax: the registry holds specs (plain data
and a factory), and a task's environment is built only by `make_task`. A new task is a
factory and a `TaskSpec`, registered in one line below (or by `register` from user code).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

from smol_dsl.lazy import lazy_names
from smol_dsl.tasks.anatomy import Anatomy
from smol_dsl.tasks.catalog import ANT_OMNI, ANT_UNI, HALFCHEETAH, HOPPER, WALKER2D
from smol_dsl.tasks.registry import PRESET_NAMES, TaskSpec, make_task, register, task_names, task_spec

if TYPE_CHECKING:
    from smol_dsl.tasks.base import Task

register(WALKER2D)
register(HALFCHEETAH)
register(ANT_OMNI)
register(HOPPER)
register(ANT_UNI)

TASK_NAMES = task_names()  # the bundled tasks; `task_names()` includes any registered since


@dataclass(frozen=True)
class TaskSizes:
    """How big a task's arrays are, found by tracing (`jax.eval_shape`), not by compiling."""

    observations: int
    actions: int
    parameters: int  # of one policy
    state_bytes: int  # one environment's state (Brax's State, pipeline state included)
    descriptors: int


@functools.lru_cache(maxsize=16)
def task_sizes(name: str, hidden_layer_sizes: tuple[int, ...], physics: str = "spring") -> TaskSizes:
    """The sizes of a task's policies and environment states, without compiling anything."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    task = make_task(name, episode_length=1, hidden_layer_sizes=tuple(hidden_layer_sizes), physics=physics)
    state = jax.eval_shape(task.env.reset, jax.random.key(0))
    observations = int(state.obs.shape[-1])  # Task.observation_size, from the reset traced here
    params = jax.eval_shape(task.policy.init, jax.random.key(0), jnp.zeros((observations,)))
    return TaskSizes(
        observations=observations,
        actions=task.env.action_size,
        parameters=sum(int(np.prod(leaf.shape)) for leaf in jax.tree.leaves(params)),
        state_bytes=sum(int(np.prod(leaf.shape)) * leaf.dtype.itemsize for leaf in jax.tree.leaves(state)),
        descriptors=task.descriptor_size,
    )


def descriptor_bounds(name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A task's descriptor box (low, high), without building its environment."""
    spec = task_spec(name)
    return spec.descriptor_low, spec.descriptor_high


__all__ = [
    "PRESET_NAMES",
    "TASK_NAMES",
    "Anatomy",
    "Task",
    "TaskSizes",
    "TaskSpec",
    "descriptor_bounds",
    "make_task",
    "register",
    "task_names",
    "task_sizes",
    "task_spec",
]

__getattr__, __dir__ = lazy_names(__name__, {"Task": "smol_dsl.tasks.base"}, __all__)  # with JAX and Brax
