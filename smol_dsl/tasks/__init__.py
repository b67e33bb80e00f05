"""The bundled α-aware QD tasks, by name: `make_task("walker2d", episode_length=100)`."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from types import ModuleType
from typing import Any

import numpy as np

from smol_dsl.tasks.quiet import import_brax

import_brax()  # first, so that MJX's Warp lines are not printed (see quiet.py)

from smol_dsl.tasks.base import ScoringFn, Task, scale_gear  # noqa: E402

TASK_NAMES = ("walker2d", "halfcheetah", "ant_omni")


def _module(name: str) -> ModuleType:
    if name not in TASK_NAMES:
        raise ValueError(f"unknown task {name!r}; the tasks are {', '.join(TASK_NAMES)}")
    return import_module(f"smol_dsl.tasks.{name}")


def make_task(name: str, **options: Any) -> Task:
    """Build a task by name; options go to the task module's `make`."""
    make: Callable[..., Task] = _module(name).make
    return make(**options)


@dataclass(frozen=True)
class TaskSizes:
    """How big a task's arrays are, found by tracing (`jax.eval_shape`), not by compiling."""

    observations: int
    actions: int
    parameters: int  # of one policy
    state_bytes: int  # one environment's state (Brax's State, pipeline state included)
    descriptors: int


@functools.lru_cache(maxsize=16)
def task_sizes(name: str, hidden_layer_sizes: tuple[int, ...], backend: str = "spring") -> TaskSizes:
    """The sizes of a task's policies and environment states, without compiling anything."""
    import jax
    import jax.numpy as jnp

    from smol_dsl.tasks.base import make_policy

    module = _module(name)
    env = module.environment(backend)
    state = jax.eval_shape(env.reset, jax.random.key(0))
    observations = state.obs.shape[-1]
    policy = make_policy(tuple(hidden_layer_sizes), env.action_size)
    params = jax.eval_shape(policy.init, jax.random.key(0), jnp.zeros((observations,)))
    return TaskSizes(
        observations=observations,
        actions=env.action_size,
        parameters=sum(int(np.prod(leaf.shape)) for leaf in jax.tree.leaves(params)),
        state_bytes=sum(int(np.prod(leaf.shape)) * leaf.dtype.itemsize for leaf in jax.tree.leaves(state)),
        descriptors=len(module.DESCRIPTOR_LOW),
    )


def descriptor_bounds(name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A task's descriptor box (low, high), without building its environment."""
    module = _module(name)
    return module.DESCRIPTOR_LOW, module.DESCRIPTOR_HIGH


__all__ = ["TASK_NAMES", "ScoringFn", "Task", "TaskSizes", "descriptor_bounds", "make_task", "scale_gear", "task_sizes"]
