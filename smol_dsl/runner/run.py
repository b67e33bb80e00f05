"""`run_experiment(task, schedule, config)`: one phased MAP-Elites run, resumable.

A run is a sweep of one (`smol_dsl.runner.sweep`): the same checks, the same engine, the
same per-run step and random streams, the same checkpoint format; it writes its run
directory at `out_dir` itself. Its population is split across every local device (on a
CPU, one XLA device per core when started by `smol-dsl`), so a single run uses the whole
machine.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.runner.config import RunError
from smol_dsl.runner.sweep import plan_training, train_planned
from smol_dsl.runner.training import RunResult
from smol_dsl.seeds import schedule_key

if TYPE_CHECKING:
    import jax

    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.tasks.base import Task

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
    A directory that cannot be used, or a disk that cannot be written, is a RunError that
    names the file and says what to do (a RunDirectoryError for a damaged file of it);
    settings `smol-dsl run` refuses, a ConfigError naming the fields (`check_config`); a
    schedule whose channels name parts the task's body lacks, a located ScheduleError. All
    are raised before anything is written.
    """
    started = time.perf_counter()
    plan = plan_training(task, [schedule], [config.seed], config, out_dir=out_dir, devices=devices, is_sweep=False)
    (result,) = train_planned(
        plan,
        resume=resume,
        progress=(lambda rows, total: progress(rows[0], total)) if progress is not None else None,
        stop_after_generation=stop_after_generation,
        allow_environment_change=allow_environment_change,
        started=started,
    )
    return result
