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


__all__ = ["TASK_NAMES", "ScoringFn", "Task", "make_task", "scale_gear"]
