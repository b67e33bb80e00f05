"""The checks of a run's settings (`check_config`: settings that cannot make a fair run are
refused before anything starts) and the runner's errors. `RunConfig` and the presets are the
run directory's (`smol_dsl.rundir.config`, `smol_dsl.rundir.presets`); `preset_config` and
`PRESETS` are importable from here as well. Imports neither JAX nor Brax."""

from __future__ import annotations

from typing import TYPE_CHECKING

from smol_dsl.errors import Setting, UserInputError
from smol_dsl.rundir.presets import PRESETS, preset_config
from smol_dsl.tasks import task_spec
from smol_dsl.tasks.physics import physics_problem

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig

__all__ = ["LEAST_SETTINGS", "PRESETS", "ConfigError", "RunError", "check_config", "preset_config"]


class RunError(UserInputError):
    """A run that cannot start or go on: bad settings, an output directory that would be lost
    or is in use, a damaged checkpoint, a disk that cannot be written. The message names the
    file or setting and says what to do."""


class ConfigError(RunError, ValueError):
    """Settings that cannot make a fair run; the message names the `RunConfig` fields to
    change (as `Setting`s, so that the CLI can name its options instead)."""


LEAST_SETTINGS = {"evaluations": 1, "batch_size": 1, "num_phases": 1, "num_centroids": 2, "episode_length": 1}
"""The smallest value of each count a run can use."""


def check_config(config: RunConfig, schedule: Schedule) -> None:
    """Raise a ConfigError, naming the settings to change, for settings that cannot make a
    fair run, and a ScheduleError, located, for a channel naming actuators or links the task
    lacks or may give a factor outside what the task takes on the config's physics."""
    problem = physics_problem(config.physics)
    if problem is not None:
        raise ConfigError(Setting("physics") + f": {problem}")
    task_spec(config.task).check_schedule(schedule, config.physics)
    for name, least in LEAST_SETTINGS.items():
        value = getattr(config, name)
        if value < least:
            raise ConfigError(Setting(name) + f" must be at least {least}, not {value}")
    if config.num_init_cvt_samples < config.num_centroids:
        raise ConfigError(
            Setting("num_init_cvt_samples")
            + " must be at least "
            + Setting("num_centroids")
            + f" ({config.num_centroids}), not {config.num_init_cvt_samples}: each cell's centroid is a mean of samples"
        )
    if config.generations < config.num_phases:
        need = (config.num_phases + 1) * config.batch_size
        raise ConfigError(
            f"a budget of {config.evaluations} evaluations at batch size {config.batch_size} gives "
            f"{max(config.generations, 0)} generations after the initial population, fewer than the "
            f"{config.num_phases} phases; use "
            + Setting("evaluations")
            + f" {need} or more, fewer "
            + Setting("num_phases")
            + ", or a smaller "
            + Setting("batch_size")
        )
    tail = schedule.tail_problem(config.num_phases)
    if tail is not None:
        raise ConfigError(tail)
    # The certificates prove every phase's factors finite and positive in float32; evaluate
    # the table anyway before anything is created, so a defect can never waste a run (a
    # ScheduleError naming the file and the phase).
    schedule.checked_phase_values(config.num_phases)
