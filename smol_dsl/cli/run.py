"""`smol-dsl run` and `smol-dsl sweep`: train under schedules, one run, or every (schedule,
seed) pair together.

Both take the same steps, in `train`: check the task, --out and the seeds; load the schedules;
make the settings; plan the training with the runner's own checks and sizing
(`plan_training`: the settings against each schedule, the processes' parts, the devices'
memory); check the output directory; announce what will run (and print what it needs);
train it with a progress bar (`train_planned`); draw each finished run's figures; print a
summary. `Run` and `Sweep` hold what differs: how seeds are given, where the output goes by
default, what is announced and what the summary says.
"""

from __future__ import annotations

import argparse
import os
import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.cli import common
from smol_dsl.cli.common import EXIT_OK, EXIT_USAGE, UsageError, positive_int, whole_number

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir import RunConfig
    from smol_dsl.runner import RunResult
    from smol_dsl.runner.sweep import TrainingPlan

LARGE_BYTES = 1e9  # a run or sweep this big on a device gets its footprint printed, whatever the preset

CLUSTER_VARIABLES = (("SLURM_NTASKS", "SLURM_PROCID"), ("OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"))


def add_parsers(commands: argparse._SubParsersAction) -> None:
    _add_run_parser(commands)
    _add_sweep_parser(commands)


def _add_run_parser(commands: argparse._SubParsersAction) -> None:
    run = commands.add_parser(
        "run",
        help="train locomotion controllers with MAP-Elites under a schedule",
        description="Train MLP controllers for a Brax task with MAP-Elites while the schedule scales the "
        "actuators' gear (phase k of N at alpha_k; the archive is re-evaluated at every phase boundary). "
        "The default preset `quick` finishes in about 2 minutes on 2 CPU cores; `--preset paper` is the "
        "paper's experiment (1e7 evaluations, 100 phases, 1024 cells; for a GPU). Writes a run directory; "
        "see docs/runner.md.",
    )
    run.add_argument("task", metavar="TASK", help=common.tasks_help())
    run.add_argument("schedules", nargs=1, metavar="SCHEDULE", help="a .sched path or a bundled name")
    common.add_run_options(run)
    run.add_argument(
        "--seed", type=whole_number, default=None, metavar="S", help="random seed, from 0 to 2**32-1 (default 0)"
    )
    run.add_argument("--out", metavar="DIR", help="run directory (default runs/TASK-SCHEDULE-seedS)")
    run.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    run.add_argument(
        "--allow-environment-change",
        action="store_true",
        help="with --resume: go on under other software or hardware than the run started on (recorded)",
    )
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    common.add_devices_option(run, "split each generation's population across the first D devices")
    # a run is one process's whole share, of one schedule and one seed
    run.set_defaults(handle=Run().train, num_processes=None, process_id=None, cluster=False, runs_per_step=None)


def _add_sweep_parser(commands: argparse._SubParsersAction) -> None:
    sweep = commands.add_parser(
        "sweep",
        help="run several schedules x seeds together as one batched program",
        description="Run every (schedule, seed) pair of a task together: all runs advance generation by "
        "generation in one compiled program, split across the available devices (GPUs, or one CPU device "
        "per core), and each gets a run directory in `run`'s format under --out. Then `smol-dsl report DIR`. "
        "See docs/tutorial.md and docs/scaling.md.",
    )
    sweep.add_argument("task", metavar="TASK", help=common.tasks_help())
    sweep.add_argument("schedules", nargs="+", metavar="SCHEDULE", help="a .sched path or a bundled name")
    add_sweep_options(sweep, seeds=5)
    sweep.set_defaults(handle=Sweep().train, seed=None)  # a sweep's shared settings carry no seed


def add_sweep_options(sweep: argparse.ArgumentParser, seeds: int) -> None:
    """The options of `sweep` (and `reproduce`) after its task and schedules."""
    sweep.add_argument(
        "--seeds", type=positive_int, default=seeds, metavar="N", help=f"seeds per schedule (default {seeds})"
    )
    sweep.add_argument(
        "--first-seed",
        type=whole_number,
        default=0,
        metavar="S",
        help="seeds are S..S+N-1, from 0 to 2**32-1 (default 0)",
    )
    common.add_run_options(sweep)
    sweep.add_argument("--out", metavar="DIR", help="sweep directory (default runs/TASK-sweep)")
    sweep.add_argument("--resume", action="store_true", help="continue the sweep in --out from its last checkpoint")
    sweep.add_argument(
        "--allow-environment-change",
        action="store_true",
        help="with --resume: go on under other software or hardware than the sweep started on (recorded)",
    )
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar")
    common.add_devices_option(sweep, "use the first D devices")
    sweep.add_argument(
        "--runs-per-step",
        type=positive_int,
        default=None,
        metavar="K",
        help="runs a device advances at once (default: 1 on CPUs, where small batches are fastest; all on GPUs)",
    )
    several = sweep.add_argument_group(
        "several machines",
        "share one sweep between processes, e.g. one per machine: each runs every N-th (schedule, seed) pair "
        "on its own devices and writes into the same --out (a shared file system); see docs/scaling.md",
    )
    several.add_argument("--num-processes", type=positive_int, metavar="N", help="how many processes share the sweep")
    several.add_argument("--process-id", type=whole_number, metavar="I", help="this process's index, 0..N-1")
    several.add_argument(
        "--cluster",
        action="store_true",
        help="take N and I from the cluster's launcher (Slurm: SLURM_NTASKS, SLURM_PROCID; Open MPI: "
        "OMPI_COMM_WORLD_SIZE, OMPI_COMM_WORLD_RANK)",
    )


@dataclass
class Plan:
    """What one `run` or `sweep` command line trains, and where."""

    args: argparse.Namespace
    schedules: list[Schedule]
    config: RunConfig
    seeds: list[int]
    part: tuple[int, int]  # this process's share: (index, number of processes)
    out: Path

    @cached_property
    def devices(self) -> list[Any]:
        """The devices to use (--devices), looked up when first needed."""
        return common.devices(self.args)

    @property
    def runs(self) -> int:
        """The runs of the whole sweep (every process's)."""
        return len(self.schedules) * len(self.seeds)

    @property
    def runs_per_step(self) -> int:
        """--runs-per-step, or -1: as many as the devices take best (see `run_sweep`)."""
        return -1 if self.args.runs_per_step is None else self.args.runs_per_step


class TrainingCommand(ABC):
    """`run` or `sweep`: `train` takes the steps both share; the methods below are what differs."""

    command: str
    is_sweep: bool  # a sweep directory of run directories, or one run directory

    def train(self, args: argparse.Namespace) -> int:
        from smol_dsl.runner.directories import busy, check_out_dir, non_empty
        from smol_dsl.runner.sweep import plan_training

        use_cpu_cores_as_devices()
        common.check_task(args.task)
        common.check_out(args.out)
        self.check_seeds(args)
        if args.no_measure and not args.dry_run:
            raise UsageError("--no-measure goes with --dry-run: it leaves out the dry run's measured warm-up")
        schedules, errors = common.load_all(args.schedules)
        if errors:
            common.print_errors(errors)
            return EXIT_USAGE
        config = _config(args)
        part = sweep_part(args)
        out = Path(args.out) if args.out is not None else self.default_out(args, schedules, config)
        plan = Plan(args, schedules, config, self.seeds(args, config), part, out)
        # every check of the training itself (settings, parts, memory), sized once: --dry-run's too
        training = plan_training(
            args.task,
            schedules,
            plan.seeds,
            config,
            out_dir=out,
            devices=plan.devices,
            runs_per_step=plan.runs_per_step,
            part=part,
            is_sweep=self.is_sweep,
        )
        check_out_dir(out)  # before anything compiles: a file, a device or a path under a file
        if not args.resume and part == (0, 1) and non_empty(out):
            raise busy(out)
        self.announce(plan, training, out)
        footprint = training.footprint
        if args.dry_run or config.preset == "paper" or footprint.device_bytes > LARGE_BYTES:
            print(f"smol-dsl {self.command}: what this will need, by arithmetic before compiling:", file=sys.stderr)
            for line in footprint.describe(out).splitlines():
                print(f"  {line}", file=sys.stderr)
        if args.dry_run:
            if not args.no_measure:  # the warm-up: compiles and times the sweep's own engine, writes nothing
                from smol_dsl.runner.estimate import describe_estimate, measure_sweep, warmup_note

                print(f"smol-dsl {self.command}: {warmup_note(footprint.runs)}", file=sys.stderr)
                measured = measure_sweep(config, schedules, plan.seeds, plan.devices, training.runs_per_step, part)
                print(f"smol-dsl {self.command}: measured on this machine:", file=sys.stderr)
                for line in describe_estimate(config, measured, footprint.memory.label).splitlines():
                    print(f"  {line}", file=sys.stderr)
            return EXIT_OK
        note = self.note(args, config)
        if note:
            print(f"smol-dsl {self.command}: {note}", file=sys.stderr)
        results = _with_progress(args, config, lambda progress: self.start(plan, training, progress))
        _draw_figures(results)
        print(self.summary(plan, results))
        return EXIT_OK

    @abstractmethod
    def check_seeds(self, args: argparse.Namespace) -> None:
        """Refuse seeds outside 0 .. 2**32 - 1, naming the option, before anything loads."""

    @abstractmethod
    def seeds(self, args: argparse.Namespace, config: RunConfig) -> list[int]:
        """The seeds to train, each with every schedule."""

    @abstractmethod
    def default_out(self, args: argparse.Namespace, schedules: list[Schedule], config: RunConfig) -> Path:
        """The output directory without --out."""

    @abstractmethod
    def announcement(self, plan: Plan) -> str:
        """What will run, printed before anything compiles (the output directory follows)."""

    def note(self, args: argparse.Namespace, config: RunConfig) -> str | None:
        """A note printed before training starts, if any."""
        return None

    def announce(self, plan: Plan, training: TrainingPlan, out: Path) -> None:
        """Print what will run and where, before anything compiles, and the known hang's
        note where it applies (`runner.sweep.known_hang`)."""
        from smol_dsl.runner.sweep import known_hang

        print(f"smol-dsl {self.command}: {self.announcement(plan)} -> {out}", file=sys.stderr)
        hang = known_hang(training)
        if hang is not None:
            print(f"smol-dsl {self.command}: note: {hang}", file=sys.stderr)

    def start(self, plan: Plan, training: TrainingPlan, progress: Callable[..., None]) -> list[RunResult]:
        """Train (or resume) the planned runs, reporting every run's rows to `progress`; the
        results of this process's runs."""
        from smol_dsl.runner.sweep import train_planned

        args = plan.args
        return train_planned(
            training, resume=args.resume, progress=progress, allow_environment_change=args.allow_environment_change
        )

    @abstractmethod
    def summary(self, plan: Plan, results: list[RunResult]) -> str:
        """What is printed when training has ended."""


class Run(TrainingCommand):
    """`smol-dsl run`: one schedule, one seed (--seed, or the preset's), in one run directory."""

    command = "run"
    is_sweep = False

    def check_seeds(self, args: argparse.Namespace) -> None:
        from smol_dsl.seeds import check_seed

        if args.seed is not None:
            check_seed(args.seed, "--seed")

    def seeds(self, args: argparse.Namespace, config: RunConfig) -> list[int]:
        return [config.seed]

    def default_out(self, args: argparse.Namespace, schedules: list[Schedule], config: RunConfig) -> Path:
        from smol_dsl.rundir.layout import run_name
        from smol_dsl.runner.directories import schedule_stem

        return Path("runs") / run_name(
            common.physics_label(args.task, config.physics), schedule_stem(schedules[0]), config.seed
        )

    def announcement(self, plan: Plan) -> str:
        config, (schedule,) = plan.config, plan.schedules
        return (
            f"{config.task} under {schedule.name} ({plan.args.schedules[0]}), preset {config.preset}: "
            f"{config.evaluations} evaluations in batches of {config.batch_size}, {config.num_phases} phases, "
            f"{config.num_centroids} cells, {config.episode_length}-step episodes, seed {config.seed}"
            + physics_note(config)
        )

    def note(self, args: argparse.Namespace, config: RunConfig) -> str | None:
        sizes = (args.evals, args.phases, args.batch_size, args.centroids, args.episode_length)
        if config.preset != "quick" or any(size is not None for size in sizes):
            return None  # the preset's sizes, as sized: not once they are overridden
        return (
            "the quick preset is sized for about 2 minutes on 2 CPU cores; "
            "--preset paper runs the paper's experiment (1e7 evaluations; for a GPU)"
        )

    def summary(self, plan: Plan, results: list[RunResult]) -> str:
        from smol_dsl.runner.progress import summary_line

        return summary_line(results[0], plan.schedules[0])


class Sweep(TrainingCommand):
    """`smol-dsl sweep`: every (schedule, seed) pair, --seeds seeds from --first-seed, in one
    sweep directory (or this process's share of them)."""

    command = "sweep"
    is_sweep = True

    def check_seeds(self, args: argparse.Namespace) -> None:
        """--first-seed and every seed up to --first-seed + --seeds - 1 must give distinct runs."""
        from smol_dsl.seeds import SEED_MAX, check_seed

        first, count = args.first_seed, args.seeds
        check_seed(first, "--first-seed")
        last = first + count - 1
        if last > SEED_MAX:
            raise UsageError(
                f"--first-seed {first} with --seeds {count}: the seeds would run up to {last}, past the largest "
                f"seed, {SEED_MAX}; use --first-seed {SEED_MAX - count + 1} or less, or fewer --seeds"
            )

    def seeds(self, args: argparse.Namespace, config: RunConfig) -> list[int]:
        return list(range(args.first_seed, args.first_seed + args.seeds))

    def default_out(self, args: argparse.Namespace, schedules: list[Schedule], config: RunConfig) -> Path:
        return Path("runs") / f"{common.physics_label(args.task, config.physics)}-sweep"

    def announcement(self, plan: Plan) -> str:
        config, (index, parts), devices = plan.config, plan.part, plan.devices
        share = f" (process {index} of {parts}: {len(range(index, plan.runs, parts))} of them)" if parts > 1 else ""
        return (
            f"{config.task}, {len(plan.schedules)} schedule(s) x {len(plan.seeds)} seed(s) = {plan.runs} runs{share} "
            f"on {len(devices)} {devices[0].platform} device(s), preset {config.preset}: {config.evaluations} "
            f"evaluations per run in batches of {config.batch_size}, {config.num_phases} phases, "
            f"{config.num_centroids} cells, {config.episode_length}-step episodes" + physics_note(config)
        )

    def summary(self, plan: Plan, results: list[RunResult]) -> str:
        from smol_dsl.runner.progress import sweep_summary

        return sweep_summary(results, plan.out)


def _config(args: argparse.Namespace) -> RunConfig:
    """The preset's settings with the options given (a run's --seed; a sweep's config has none)."""
    from smol_dsl.runner import PRESETS, preset_config

    if args.preset not in PRESETS:
        raise UsageError(f"unknown preset {args.preset!r}; the presets are {', '.join(PRESETS)}")
    return preset_config(
        args.task,
        args.preset,
        seed=args.seed,
        evaluations=args.evals,
        num_phases=args.phases,
        batch_size=args.batch_size,
        num_centroids=args.centroids,
        episode_length=args.episode_length,
        physics=args.physics,
    )


def _with_progress(
    args: argparse.Namespace, config: RunConfig, start: Callable[[Any], list[RunResult]]
) -> list[RunResult]:
    """start(progress callback), with a progress bar unless --no-progress; without one, a
    re-evaluation that leaves under half the cells filled is still reported."""
    from smol_dsl.runner.progress import ProgressBar, ReevaluationWarnings

    if args.no_progress:
        return start(ReevaluationWarnings(config).update)
    bar = ProgressBar(config)
    try:
        return start(bar.update)
    finally:
        bar.close()


def _draw_figures(results: Sequence[RunResult]) -> None:
    """Each finished run directory's metrics.png and archive.png, after training."""
    from smol_dsl.results.run_figures import save_run_figures

    for result in results:
        if result.out_dir is not None and result.final["generation"] >= result.config.generations:
            save_run_figures(result.out_dir)


def sweep_part(args: argparse.Namespace) -> tuple[int, int]:
    """This process's share of the sweep: (index, number of processes)."""
    if args.cluster:
        if args.num_processes is not None or args.process_id is not None:
            raise UsageError(
                "--cluster takes --num-processes and --process-id from the launcher; give one or the other"
            )
        for count, index in CLUSTER_VARIABLES:
            if count in os.environ and index in os.environ:
                return _checked_part(int(os.environ[index]), int(os.environ[count]))
        names = " or ".join(f"{count} and {index}" for count, index in CLUSTER_VARIABLES)
        raise UsageError(
            f"--cluster: no cluster launcher found ({names} are not set); use --num-processes and --process-id"
        )
    if args.num_processes is None and args.process_id is None:
        return 0, 1
    if args.num_processes is None or args.process_id is None:
        raise UsageError("give --num-processes and --process-id together")
    return _checked_part(args.process_id, args.num_processes)


def _checked_part(index: int, count: int) -> tuple[int, int]:
    if not 0 <= index < count:
        raise UsageError(f"process {index} of {count}: the index must be from 0 to {count - 1}")
    return index, count


def use_cpu_cores_as_devices() -> None:
    """Before JAX starts: split a CPU into one XLA device per core (unless XLA_FLAGS
    already says how many), so that a run's population and a sweep's runs use every core. It changes nothing
    on GPUs, whose devices JAX prefers."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={cores}".strip()


def physics_note(config: RunConfig) -> str:
    """What an announcement adds for a run on another physics than the default (spring)."""
    from smol_dsl.tasks.physics import DEFAULT_PHYSICS, PHYSICS

    return "" if config.physics == DEFAULT_PHYSICS else f", on {PHYSICS[config.physics].title}"
