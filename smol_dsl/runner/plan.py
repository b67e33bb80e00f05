"""What is to be trained, before anything is: `PlannedRun` (a run's schedule, settings, name
and directory), the channels runs trained together share (`run_channels`), and the checks
`smol-dsl run` and `sweep` make of the runs before anything is created or compiled
(`check_runs`). Imports no JAX: the core, the loop and the sizing all build on it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from smol_dsl.errors import Setting
from smol_dsl.runner.config import ConfigError, check_config
from smol_dsl.tasks import task_spec

if TYPE_CHECKING:
    from smol_dsl.language.channels import Channel
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.tasks.base import Task


@dataclass(frozen=True)
class PlannedRun:
    """One run to train: its schedule, settings (with its seed), name and run directory."""

    schedule: Schedule
    config: RunConfig
    name: str
    directory: Path | None = None


def run_channels(schedules: list[Schedule]) -> tuple[Channel, ...]:
    """Every channel the schedules declare, in order of first appearance: the traced body of
    runs trained together (a run's value for a channel its schedule lacks is 1)."""
    return tuple(dict.fromkeys(channel for schedule in schedules for channel in schedule.channels))


def check_runs(task: Task | str, schedules: list[Schedule], config: RunConfig) -> None:
    """What `smol-dsl run` and `sweep` refuse, refused for the Python API alike, before anything
    is created or compiled: a located ScheduleError for a schedule whose channels name parts
    the task's body lacks, a ConfigError (`check_config`) for settings that cannot make a fair
    run, and one for a task that is not the config's (its name, physics or episode length)."""
    spec = task_spec(task) if isinstance(task, str) else task.spec
    if spec.name != config.task:
        raise ConfigError(
            f"the task is {spec.name} but the config's is {config.task}; make the config for {spec.name} "
            f"(preset_config({spec.name!r}, ...)) or pass task={config.task!r}"
        )
    if not isinstance(task, str) and task.physics != config.physics:
        raise ConfigError(
            f"the task is simulated on {task.physics} but the config's "
            + Setting("physics")
            + f" is {config.physics}; build the task with physics={config.physics!r}, or pass the task by name"
        )
    if not isinstance(task, str) and task.episode_length != config.episode_length:
        raise ConfigError(
            f"the task's episodes are {task.episode_length} steps but the config's "
            + Setting("episode_length")
            + f" is {config.episode_length}; build the task with the config's, or pass the task by name"
        )
    for schedule in schedules:
        check_config(config, schedule)  # the schedule against the task's body too: the config's task is this one
