"""`run_experiment(task, schedule, config)`: one phased MAP-Elites run, resumable.

A run is a training of one run on the engine (smol_dsl.runner.training), as a sweep is of
many: the same per-run step, the same random streams, the same checkpoint format. Its
population is split across every local device (on a CPU, one XLA device per core when
started by `smol-dsl`), so a single run uses the whole machine.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.tasks.base import Task

from smol_dsl.rundir import CHECKPOINT_FILE, describe_environment, scoring_layout
from smol_dsl.runner.config import RunError
from smol_dsl.runner.directories import out_path, prepare_run_directory, run_name
from smol_dsl.runner.engine import shared_engine
from smol_dsl.runner.footprint import fit_sweep
from smol_dsl.runner.training import PlannedRun, RunResult, check_runs, train
from smol_dsl.seeds import schedule_key

__all__ = ["RunError", "RunResult", "run_experiment", "schedule_key"]


def run_experiment(
    task: Task | str,
    schedule: Schedule,
    config: RunConfig,
    *,
    out_dir: str | Path | None = None,
    resume: bool = False,
    progress: Callable[[dict[str, Any], int], None] | None = None,
    stop_after_generation: int | None = None,
    devices: Sequence[jax.Device] | None = None,
    allow_environment_change: bool = False,
) -> RunResult:
    """Run phased MAP-Elites of `task` under `schedule`; return the archive and metrics.

    With `out_dir`, writes the run directory (config, schedule, certificate, metrics.csv,
    checkpoints, and at the end archive.npz and figures), locked for the run's duration;
    with `resume`, continues from its last checkpoint. `progress(row, total_generations)` is
    called after every row. `stop_after_generation` stops early (as an interruption would),
    for tests. `devices` (default: every local device) share each generation's population.
    The run records what it runs under (environment.json); resuming under another
    environment is refused unless `allow_environment_change`.
    A directory that cannot be used, a damaged checkpoint or a disk that cannot be written
    is a RunError that names the file and says what to do; settings `smol-dsl run` refuses,
    a ConfigError naming the fields (`check_config`); a schedule whose channels name parts
    the task's body lacks, a located ScheduleError. All are raised before anything is written.
    """
    started = time.perf_counter()
    directory = out_path(out_dir)
    devices = tuple(devices) if devices is not None else tuple(jax.local_devices())
    check_runs(task, [schedule], config)
    footprint = fit_sweep(config, 1, [config.seed], devices)  # refuses a run that cannot fit, before compiling
    run = PlannedRun(schedule, config, run_name(config.task, schedule, config.seed), directory)
    layout = scoring_layout(1, 0, footprint.runs_per_step, [channel.name for channel in schedule.channels])
    environment = describe_environment(devices, layout)
    with contextlib.ExitStack() as held:
        if directory is not None:  # locked until the run returns: one process at a time
            held.enter_context(
                prepare_run_directory(directory, schedule, config, resume, environment, allow_environment_change)
            )
        engine = shared_engine(task, config, devices, footprint.runs_per_step, 1, schedule.channels)
        results = train(
            engine,
            engine.task,
            [run],
            config,
            checkpoint=directory / CHECKPOINT_FILE if directory is not None else None,
            resume=resume,
            progress=(lambda rows, total: progress(rows[0], total)) if progress is not None else None,
            stop_after_generation=stop_after_generation,
            started=started,
        )
    return results[0]
