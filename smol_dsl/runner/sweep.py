"""A sweep: every (schedule, seed) pair of one task, trained together on the engine.

`run_sweep(task, schedules, seeds, config)` trains all runs generation by generation
(runs sharded across the local devices) and writes one run directory per pair, in
`run_experiment`'s format, so each can be opened, plotted and reported like a single run.
The sweep's own checkpoint holds every run at the same boundary, written atomically, so an
interrupted sweep resumes exactly.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import jax

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.tasks.base import Task

from smol_dsl.rundir import SWEEP_CHECKPOINT_FILE, describe_environment, scoring_layout
from smol_dsl.runner.config import RunError
from smol_dsl.runner.directories import out_path, prepare_sweep_directory, run_name
from smol_dsl.runner.engine import shared_engine
from smol_dsl.runner.footprint import fit_sweep
from smol_dsl.runner.training import PlannedRun, Progress, RunResult, check_runs, run_channels, train


def plan_sweep(schedules: Sequence[Schedule], seeds: Sequence[int], config: RunConfig) -> list[PlannedRun]:
    """Every (schedule, seed) pair, schedules outermost; refuses repeated names."""
    if not schedules:
        raise RunError("a sweep needs at least one schedule")
    if not seeds:
        raise RunError("a sweep needs at least one seed")
    runs = [
        PlannedRun(schedule, dataclasses.replace(config, seed=seed), run_name(config.task, schedule, seed))
        for schedule in schedules
        for seed in seeds
    ]
    names = [run.name for run in runs]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise RunError(
            f"two runs of the sweep would share the directory {repeated[0]}: give each schedule "
            "and seed once, and schedules from different folders different file names"
        )
    return runs


def sweep_part(every: list[PlannedRun], part: tuple[int, int]) -> list[PlannedRun]:
    """The runs of process k of n sharing a sweep: every n-th from the k-th."""
    index, parts = part
    if not 0 <= index < parts:
        raise RunError(f"part {index} of {parts} does not exist")
    runs = every[index::parts]
    if not runs:
        raise RunError(f"the sweep has {len(every)} runs, too few for {parts} parts (processes)")
    return runs


def run_sweep(
    task: Task | str,
    schedules: Sequence[Schedule],
    seeds: Sequence[int],
    config: RunConfig,
    *,
    out_dir: str | Path | None = None,
    resume: bool = False,
    progress: Progress | None = None,
    stop_after_generation: int | None = None,
    devices: Sequence[jax.Device] | None = None,
    allow_environment_change: bool = False,
    runs_per_step: int | None = -1,
    part: tuple[int, int] = (0, 1),
) -> list[RunResult]:
    """Run every (schedule, seed) pair of `task` together; return one RunResult per pair.

    `config` is shared (its own seed is ignored). With `out_dir`, writes `sweep.json`, the
    sweep checkpoint and one run directory per pair; with `resume`, continues from the
    last checkpoint. `devices` (default: all local devices) share the runs;
    `runs_per_step` is how many runs a device advances at once (-1: one on CPU; on
    accelerators all, or as many as fit in memory; None: all). A sweep whose archives
    cannot fit the devices' memory is refused with a RunError before anything compiles.
    `progress(rows, total)` gets the latest row of every run.
    `part=(k, n)` runs only every n-th pair from the k-th (one process of n sharing a
    sweep, each on its own devices; see docs/scaling.md) and returns those. Every run
    records what it runs under (environment.json); resuming under another environment is
    refused unless `allow_environment_change`.
    """
    started = time.perf_counter()
    directory = out_path(out_dir)
    every = plan_sweep(schedules, seeds, config)
    if directory is not None:
        every = [dataclasses.replace(run, directory=directory / run.name) for run in every]
    runs = sweep_part(every, part)
    devices = tuple(devices) if devices is not None else tuple(jax.local_devices())
    check_runs(task, list(schedules), config)
    footprint = fit_sweep(config, len(schedules), seeds, devices, runs_per_step, part)  # before compiling
    if runs_per_step == -1:
        runs_per_step = footprint.runs_per_step
    index, parts = part
    checkpoint_name = SWEEP_CHECKPOINT_FILE if parts == 1 else f"sweep-checkpoint-{index}-of-{parts}.npz"
    channels = run_channels([run.schedule for run in runs])
    names = [channel.name for channel in channels]
    environments = [
        describe_environment(devices, scoring_layout(len(runs), r, runs_per_step, names)) for r in range(len(runs))
    ]
    with contextlib.ExitStack() as held:
        if directory is not None:  # this process's run directories stay locked until it returns
            held.enter_context(
                prepare_sweep_directory(
                    directory,
                    every,
                    runs,
                    config,
                    resume,
                    parts > 1,
                    checkpoint_name,
                    environments,
                    allow_environment_change,
                )
            )
        engine = shared_engine(task, config, devices, runs_per_step, len(runs), channels)
        checkpoint = directory / checkpoint_name if directory is not None else None
        return train(
            engine,
            engine.task,
            runs,
            config,
            checkpoint=checkpoint,
            resume=resume,
            progress=progress,
            stop_after_generation=stop_after_generation,
            started=started,
        )
