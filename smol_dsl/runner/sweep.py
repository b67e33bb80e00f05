"""The runner's one entry: a training of one run (`run_experiment`) or of every (schedule,
seed) pair of a task (`run_sweep`), planned and checked once, then trained together.

`plan_training` refuses what `smol-dsl run` and `sweep` refuse (settings, schedules, parts,
memory) before anything is created or compiled and sizes the runs for the devices once;
`train_planned` sets up and locks the directories and trains the runs on the engine
(`smol_dsl.runner.training`). A sweep writes one run directory per pair, in a run's format,
so each can be opened, plotted and reported like a single run; its own checkpoint holds
every run at the same boundary, so an interrupted sweep resumes exactly.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax

from smol_dsl.rundir import CHECKPOINT_FILE, describe_environment, scoring_layout
from smol_dsl.rundir.layout import run_name, sweep_checkpoint_file
from smol_dsl.runner.config import RunError
from smol_dsl.runner.directories import out_path, prepare_run_directory, prepare_sweep_directory, schedule_stem
from smol_dsl.runner.engine import shared_engine
from smol_dsl.runner.footprint import Footprint, fit_sweep
from smol_dsl.runner.plan import PlannedRun, check_runs, run_channels
from smol_dsl.runner.training import Progress, RunResult, train

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.tasks.base import Task


def plan_sweep(schedules: Sequence[Schedule], seeds: Sequence[int], config: RunConfig) -> list[PlannedRun]:
    """Every (schedule, seed) pair, schedules outermost; refuses repeated names."""
    if not schedules:
        raise RunError("a sweep needs at least one schedule")
    if not seeds:
        raise RunError("a sweep needs at least one seed")
    runs = [
        PlannedRun(
            schedule, dataclasses.replace(config, seed=seed), run_name(config.task, schedule_stem(schedule), seed)
        )
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


@dataclass(frozen=True)
class TrainingPlan:
    """A run or a sweep, checked and sized for its devices: the runs this process trains
    (`runs`, of the sweep's `every`), where (`directory`: the run's, or the sweep's), how
    many runs a device advances at once and what that needs (`footprint`)."""

    task: Task | str
    config: RunConfig
    every: list[PlannedRun]
    runs: list[PlannedRun]
    devices: tuple[jax.Device, ...]
    part: tuple[int, int]
    footprint: Footprint
    runs_per_step: int | None
    directory: Path | None
    is_sweep: bool

    @property
    def checkpoint(self) -> Path | None:
        """The checkpoint this process writes: the run directory's, or its part's of the sweep's."""
        if self.directory is None:
            return None
        return self.directory / (sweep_checkpoint_file(self.part) if self.is_sweep else CHECKPOINT_FILE)


def plan_training(
    task: Task | str,
    schedules: Sequence[Schedule],
    seeds: Sequence[int],
    config: RunConfig,
    *,
    out_dir: str | Path | None = None,
    devices: Sequence[jax.Device] | None = None,
    runs_per_step: int | None = -1,
    part: tuple[int, int] = (0, 1),
    is_sweep: bool = True,
) -> TrainingPlan:
    """Every (schedule, seed) pair of `task` (a run: one schedule, the config's seed, not a
    sweep), checked as `smol-dsl run` and `sweep` check them (a ConfigError or RunError,
    with the CLI's message) and sized for `devices` (default: all local ones), before
    anything is created or compiled. `runs_per_step` and `part` as in `run_sweep`."""
    directory = out_path(out_dir)
    if is_sweep:
        every = plan_sweep(schedules, seeds, config)
        if directory is not None:
            every = [dataclasses.replace(run, directory=directory / run.name) for run in every]
        runs = sweep_part(every, part)
    else:
        (schedule,) = schedules
        every = runs = [
            PlannedRun(schedule, config, run_name(config.task, schedule_stem(schedule), config.seed), directory)
        ]
    devices = tuple(devices) if devices is not None else tuple(jax.local_devices())
    check_runs(task, list(schedules), config)
    footprint = fit_sweep(config, len(schedules), seeds, devices, runs_per_step, part)  # before compiling
    chosen = footprint.runs_per_step if runs_per_step == -1 else runs_per_step
    return TrainingPlan(task, config, every, runs, devices, part, footprint, chosen, directory, is_sweep)


MJX_CPU_HANG_FIXED = (0, 12)
"""The first jaxlib where MJX on a CPU with several runs per step was seen to finish
(docs/scaling.md, 'A known hang': jaxlib 0.10.2 hangs, 0.12.0.1 does not)."""


def jaxlib_version() -> tuple[int, ...]:
    """The installed jaxlib's version as numbers (0.10.2 -> (0, 10, 2))."""
    import jaxlib

    return tuple(int(part) for part in jaxlib.__version__.split(".")[:3] if part.isdigit())


def known_hang(plan: TrainingPlan) -> str | None:
    """A note where the training is MJX on CPU devices that advance several runs at once,
    under a jaxlib older than MJX_CPU_HANG_FIXED (docs/scaling.md's known hang), else None."""
    if (
        plan.config.physics == "mjx"
        and plan.devices[0].platform == "cpu"
        and plan.footprint.parallel_runs > 1
        and jaxlib_version() < MJX_CPU_HANG_FIXED
    ):
        installed, fixed = (".".join(map(str, version)) for version in (jaxlib_version(), MJX_CPU_HANG_FIXED))
        return (
            f"MJX on a CPU with several runs per step hangs under jaxlib {installed}: its batched Cholesky waits on "
            "XLA:CPU threads that other Cholesky calls hold (docs/scaling.md, 'A known hang'); if the progress stops "
            f"with the CPU idle, use the default, one run at a time, or jax {fixed} or later (Python 3.12 and later)"
        )
    return None


def train_planned(
    plan: TrainingPlan,
    *,
    resume: bool = False,
    progress: Progress | None = None,
    stop_after_generation: int | None = None,
    allow_environment_change: bool = False,
    started: float | None = None,
) -> list[RunResult]:
    """Set up (or check, to `resume`) and lock the plan's directories, then train its runs
    together; one RunResult per run of this process."""
    started = time.perf_counter() if started is None else started
    runs, config = plan.runs, plan.config
    channels = run_channels([run.schedule for run in runs])
    names = [channel.name for channel in channels]
    environments = [
        describe_environment(plan.devices, scoring_layout(len(runs), r, plan.runs_per_step, names), config.physics)
        for r in range(len(runs))
    ]
    with contextlib.ExitStack() as held:
        if plan.directory is not None:  # this process's run directories stay locked until it returns
            held.enter_context(_prepare_directories(plan, resume, environments, allow_environment_change))
        engine = shared_engine(plan.task, config, plan.devices, plan.runs_per_step, len(runs), channels)
        return train(
            engine,
            runs,
            config,
            checkpoint=plan.checkpoint,
            resume=resume,
            progress=progress,
            stop_after_generation=stop_after_generation,
            started=started,
        )


def _prepare_directories(
    plan: TrainingPlan, resume: bool, environments: list[dict[str, Any]], allow_environment_change: bool
) -> contextlib.AbstractContextManager[Any]:
    assert plan.directory is not None and plan.checkpoint is not None
    if not plan.is_sweep:
        (run,) = plan.runs
        return prepare_run_directory(
            plan.directory, run.schedule, run.config, resume, environments[0], allow_environment_change
        )
    return prepare_sweep_directory(
        plan.directory,
        plan.every,
        plan.runs,
        plan.config,
        resume,
        plan.part[1] > 1,
        plan.checkpoint.name,
        environments,
        allow_environment_change,
    )


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
    `runs_per_step` is how many runs a device advances at once (-1: the devices choose,
    one at a time on a CPU, on accelerators all or as many as fit in memory; None: all).
    Settings `smol-dsl sweep` refuses are a ConfigError or RunError with its message, and
    a sweep whose archives cannot fit the devices' memory is a RunError, before anything
    compiles. `progress(rows, total)` gets the latest row of every run.
    `part=(k, n)` runs only every n-th pair from the k-th (one process of n sharing a
    sweep, each on its own devices; see docs/scaling.md) and returns those. Every run
    records what it runs under (environment.json); resuming under another environment is
    refused unless `allow_environment_change`.
    """
    started = time.perf_counter()
    plan = plan_training(
        task, schedules, seeds, config, out_dir=out_dir, devices=devices, runs_per_step=runs_per_step, part=part
    )
    return train_planned(
        plan,
        resume=resume,
        progress=progress,
        stop_after_generation=stop_after_generation,
        allow_environment_change=allow_environment_change,
        started=started,
    )
