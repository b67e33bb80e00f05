"""The bundled α-aware QD tasks, by name: `make_task("walker2d", episode_length=100)`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from smol_dsl.tasks.base import ScoringFn, Task, scale_gear

TASK_NAMES = ("walker2d", "halfcheetah", "ant_omni")


def make_task(name: str, **options: Any) -> Task:
    """Build a task by name; options go to the task module's `make`."""
    if name not in TASK_NAMES:
        raise ValueError(f"unknown task {name!r}; the tasks are {', '.join(TASK_NAMES)}")
    from importlib import import_module

    module = import_module(f"smol_dsl.tasks.{name}")
    make: Callable[..., Task] = module.make
    return make(**options)


def descriptor_bounds(name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A task's descriptor box (low, high), without building its environment."""
    if name not in TASK_NAMES:
        raise ValueError(f"unknown task {name!r}; the tasks are {', '.join(TASK_NAMES)}")
    from importlib import import_module

    module = import_module(f"smol_dsl.tasks.{name}")
    return module.DESCRIPTOR_LOW, module.DESCRIPTOR_HIGH


__all__ = ["TASK_NAMES", "ScoringFn", "Task", "descriptor_bounds", "make_task", "scale_gear"]
