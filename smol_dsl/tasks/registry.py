"""The task registry: one `TaskSpec` per task, registered in one line (as Brax's `envs`).

A spec is plain data plus a factory, so that the command line, the presets and `report`
can list tasks, check names and read descriptor bounds without importing JAX or Brax; the
factory (a callable, or a ``"module:function"`` path imported on first use) builds the
`Task` only when a run needs it.

>>> from smol_dsl.tasks import task_spec
>>> task_spec("walker2d").descriptor_high
(1.0, 1.0)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import import_module
from typing import TYPE_CHECKING, Any

from smol_dsl.tasks.physics import DEFAULT_PHYSICS, check_physics
from smol_dsl.tasks.ranges import body_problem, check_resolved_factors

if TYPE_CHECKING:
    from smol_dsl.language.channels import Channel
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.tasks.anatomy import Anatomy
    from smol_dsl.tasks.base import Task
    from smol_dsl.tasks.ranges import FactorRange

PRESET_NAMES = ("quick", "paper")


@dataclass(frozen=True)
class TaskSpec:
    """Everything smol-dsl knows about a task before building it.

    `presets` maps "quick" and "paper" to RunConfig fields (batch_size, episode_length,
    hidden_layer_sizes, and for quick the evaluations); `default_metric` is the metrics.csv
    column `report` compares by default.
    """

    name: str
    help: str
    environment: str  # the Brax environment's name
    factory: str | Callable[..., Task]  # (spec, *, episode_length, hidden_layer_sizes, physics) -> Task
    descriptor_low: tuple[float, ...]
    descriptor_high: tuple[float, ...]
    reward_offset: float  # per step, keeps rewards positive: the QD score adds offset * episode_length per cell
    default_metric: str
    presets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    details: Mapping[str, Any] = field(default_factory=dict)  # for the factory, e.g. the feet's link names
    anatomy: Anatomy | None = None  # the actuators and links a schedule's channels can name
    factor_ranges: Mapping[str, Mapping[str, FactorRange]] = field(default_factory=dict)
    """Per physics (`tasks.physics`), per kind of channel, the resolved factors the task's
    physics takes (`tasks.ranges`; float32's safe range for a kind or physics it leaves
    out): `ranges(physics)`."""
    observation_size: int | None = None
    """The length of an observation, where known without building the task (archives'
    policies are checked against it)."""
    step_seconds: float | None = None
    """Seconds per environment step (the env's `dt`), where known without building the task
    (`render` sizes its frames with it before rolling anything out)."""

    def __post_init__(self) -> None:
        if len(self.descriptor_low) != len(self.descriptor_high):
            raise ValueError(f"task {self.name}: descriptor_low and descriptor_high differ in length")
        missing = [name for name in PRESET_NAMES if name not in self.presets]
        if missing:
            raise ValueError(f"task {self.name}: no {' or '.join(missing)} preset")

    @property
    def descriptor_size(self) -> int:
        return len(self.descriptor_low)

    def ranges(self, physics: str = DEFAULT_PHYSICS) -> Mapping[str, FactorRange]:
        """Per kind of channel, the factors the task takes on `physics` (a ValueError for an
        unknown physics)."""
        check_physics(physics)
        return self.factor_ranges.get(physics, {})

    def check_schedule(self, schedule: Schedule, physics: str = DEFAULT_PHYSICS) -> None:
        """Refuse, with a located ScheduleError, a schedule whose channels name actuators or
        links this task's body lacks (or any, for a task without an anatomy), or under which
        an actuator's, link's or the whole body's factor (the product of the channels that
        reach it) may leave what the task takes on `physics` (`ranges`)."""
        anatomy = self.anatomy
        if anatomy is None:
            schedule.check_targets(None, self.name)
        else:
            schedule.check_targets(anatomy.targets(), self.name, anatomy.listing())
        check_resolved_factors(schedule, anatomy, self.ranges(physics), self.name)

    def body_problem(self, body: Mapping[Channel, float], physics: str = DEFAULT_PHYSICS) -> str | None:
        """What is wrong with a body of this task (a factor per channel), in words, or None:
        a factor that is not finite and above 0, or a part's resolved factor outside what the
        task takes on `physics` (`ranges`; `tasks.ranges.body_problem`)."""
        return body_problem(body, self.anatomy, self.ranges(physics), self.name)

    def make(self, **options: Any) -> Task:
        """Build the task (imports JAX and Brax); options (episode_length,
        hidden_layer_sizes, physics) go to the factory."""
        factory = self.factory
        if isinstance(factory, str):
            module, _, function = factory.partition(":")
            factory = getattr(import_module(module), function)
        return factory(self, **options)


_TASKS: dict[str, TaskSpec] = {}


def register(spec: TaskSpec) -> TaskSpec:
    """Add a task to the registry (a name can be registered once)."""
    if spec.name in _TASKS and _TASKS[spec.name] != spec:
        raise ValueError(f"a task named {spec.name!r} is already registered")
    _TASKS[spec.name] = spec
    return spec


def task_names() -> tuple[str, ...]:
    """The registered tasks' names, in registration order."""
    return tuple(_TASKS)


def task_spec(name: str) -> TaskSpec:
    """The spec of a registered task; a ValueError listing the tasks for an unknown name."""
    try:
        return _TASKS[name]
    except KeyError:
        raise ValueError(f"unknown task {name!r}; the tasks are {', '.join(_TASKS)}") from None


def make_task(name: str, **options: Any) -> Task:
    """Build a registered task by name: `make_task("walker2d", episode_length=100)`."""
    return task_spec(name).make(**options)
