"""The `smol-dsl` command line: check, plot, run, sweep and report.

Bad input of any kind (a broken file, a missing file, a bad flag) prints one clear error
and exits with status 2, without a Python traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from smol_dsl.errors import UserInputError
from smol_dsl.seeds import check_seed

if TYPE_CHECKING:
    from smol_dsl.rundir import RunConfig
    from smol_dsl.runner.footprint import Footprint
    from smol_dsl.tasks import Anatomy, TaskSpec

T = TypeVar("T")

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2


class UsageError(UserInputError):
    """Bad command-line input that argparse itself does not catch."""


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def _count(text: str) -> int:
    """A whole number of at least 1 (an evaluation budget: no upper limit)."""
    value = _int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _positive_int(text: str) -> int:
    """A whole number from 1 to 100000 (phases, batch sizes, cells, steps)."""
    value = _count(text)
    if value > 100_000:
        raise argparse.ArgumentTypeError(f"must be at most 100000, got {value}")
    return value


def _plot_seed(text: str) -> int:
    """plot --seed: a seed as `run --seed` takes it, 0 to 2**32 - 1 (smol_dsl.seeds)."""
    from smol_dsl.seeds import check_seed

    try:
        return check_seed(_int(text), "")
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error).strip()) from None


def build_parser() -> argparse.ArgumentParser:
    from smol_dsl import __version__

    parser = argparse.ArgumentParser(
        prog="smol-dsl",
        description=(
            "Developmental curricula for quality-diversity robotics. A .sched file describes how "
            "the actuator strength alpha of a robot changes over MAP-Elites training (SMOL). "
            "SCHEDULE arguments are paths, or names of bundled schedules such as `human` or `smol.sched`."
        ),
        epilog="Docs: docs/language.md. Bundled schedules: "
        "vanilla, smol, smol-reverse, human, random, extinction-05, extinction-10, extinction-50; "
        "of several channels: growth, leg-damage, low-gravity.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    check = commands.add_parser(
        "check",
        help="verify schedules symbolically and print their certificates",
        description="Parse, compile and symbolically verify each schedule, and print its certificate, "
        "one per channel (alpha's range, the alpha = 1 tail, monotone pieces, continuity at every join). "
        "With --task, also check that the task's body has the actuators and links the channels name. "
        "Exit status 0 when all are valid, 2 otherwise.",
    )
    check.add_argument("schedules", nargs="+", metavar="SCHEDULE", help="a .sched path or a bundled name")
    check.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    check.add_argument(
        "--task",
        metavar="TASK",
        help="also check the channels' targets against TASK's body, and print its actuators, links and groups",
    )

    plot = commands.add_parser(
        "plot",
        help="plot alpha over training (the paper's Figure 2)",
        description="Plot alpha over training as per-phase steps with the smooth curve, several schedules "
        "overlaid, and a dashed line where alpha becomes 1 for good; one panel per channel when the "
        "schedules scale other parameters too. With no SCHEDULE, plots the paper's "
        "Figure 2 (vanilla, smol, smol-reverse, human).",
    )
    plot.add_argument("schedules", nargs="*", metavar="SCHEDULE", help="a .sched path or a bundled name")
    plot.add_argument(
        "-o",
        "--out",
        metavar="OUT",
        help="output file; .png, .svg or .pdf (default: NAME.png for one schedule, schedules.png for several)",
    )
    plot.add_argument("--phases", type=_positive_int, default=100, metavar="N", help="number of phases (default 100)")
    plot.add_argument(
        "--seed", type=_plot_seed, default=0, metavar="S", help="seed of random segments, 0 to 2**32-1 (default 0)"
    )
    run = commands.add_parser(
        "run",
        help="train locomotion controllers with MAP-Elites under a schedule",
        description="Train MLP controllers for a Brax task with MAP-Elites while the schedule scales the "
        "actuators' gear (phase k of N at alpha_k; the archive is re-evaluated at every phase boundary). "
        "The default preset `quick` finishes in about 2 minutes on 2 CPU cores; `--preset paper` is the "
        "paper's experiment (1e7 evaluations, 100 phases, 1024 cells; for a GPU). Writes a run directory; "
        "see docs/runner.md.",
    )
    run.add_argument("task", metavar="TASK", help=_tasks_help())
    run.add_argument("schedule", metavar="SCHEDULE", help="a .sched path or a bundled name")
    _add_run_options(run)
    run.add_argument("--seed", type=_int, default=None, metavar="S", help="random seed, from 0 to 2**32-1 (default 0)")
    run.add_argument("--out", metavar="DIR", help="run directory (default runs/TASK-SCHEDULE-seedS)")
    run.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_devices_option(run, "split each generation's population across the first D devices")

    sweep = commands.add_parser(
        "sweep",
        help="run several schedules x seeds together as one batched program",
        description="Run every (schedule, seed) pair of a task together: all runs advance generation by "
        "generation in one compiled program, split across the available devices (GPUs, or one CPU device "
        "per core), and each gets a run directory in `run`'s format under --out. Then `smol-dsl report DIR`. "
        "See docs/tutorial.md and docs/scaling.md.",
    )
    sweep.add_argument("task", metavar="TASK", help=_tasks_help())
    sweep.add_argument("schedules", nargs="+", metavar="SCHEDULE", help="a .sched path or a bundled name")
    sweep.add_argument("--seeds", type=_positive_int, default=5, metavar="N", help="seeds per schedule (default 5)")
    sweep.add_argument(
        "--first-seed", type=_int, default=0, metavar="S", help="seeds are S..S+N-1, from 0 to 2**32-1 (default 0)"
    )
    _add_run_options(sweep)
    sweep.add_argument("--out", metavar="DIR", help="sweep directory (default runs/TASK-sweep)")
    sweep.add_argument("--resume", action="store_true", help="continue the sweep in --out from its last checkpoint")
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_devices_option(sweep, "use the first D devices")
    sweep.add_argument(
        "--runs-per-step",
        type=_positive_int,
        default=None,
        metavar="K",
        help="runs a device advances at once (default: 1 on CPUs, where small batches are fastest; all on GPUs)",
    )
    several = sweep.add_argument_group(
        "several machines",
        "share one sweep between processes, e.g. one per machine: each runs every N-th (schedule, seed) pair "
        "on its own devices and writes into the same --out (a shared file system); see docs/scaling.md",
    )
    several.add_argument("--num-processes", type=_positive_int, metavar="N", help="how many processes share the sweep")
    several.add_argument("--process-id", type=_int, metavar="I", help="this process's index, 0..N-1")
    several.add_argument(
        "--cluster",
        action="store_true",
        help="take N and I from the cluster's launcher (Slurm: SLURM_NTASKS, SLURM_PROCID; Open MPI: "
        "OMPI_COMM_WORLD_SIZE, OMPI_COMM_WORLD_RANK)",
    )

    report = commands.add_parser(
        "report",
        help="the paper's U-test table and figures from finished runs",
        description="Collect the finished runs in the given directories (sweep or run directories, searched "
        "recursively), and write the paper's table - median final score per schedule and one-sided "
        "Mann-Whitney U p-values of 'column better than row' - as Markdown and LaTeX, the final scores, and "
        "figures of median and interquartile range over seeds (PNG and PDF) with the final archives.",
    )
    report.add_argument("dirs", nargs="+", metavar="DIR", help="sweep or run directories")
    report.add_argument("-o", "--out", metavar="OUT", help="output directory (default DIR/report for one DIR)")
    report.add_argument(
        "--force",
        action="store_true",
        help="replace the report already in the output directory (without it, an earlier report is kept "
        "and nothing is written)",
    )
    report.add_argument(
        "--metric",
        default=None,
        metavar="NAME",
        help=f"final score: max_fitness, coverage or qd_score (default: the task's, {_default_metrics_help()})",
    )
    return parser


def _tasks_help() -> str:
    """The registered tasks, each with its one-line help (the registry needs no JAX)."""
    from smol_dsl.tasks import task_names, task_spec

    return "; ".join(f"{name}: {task_spec(name).help}" for name in task_names())


def _default_metrics_help() -> str:
    from smol_dsl.tasks import task_names, task_spec

    by_metric: dict[str, list[str]] = {}
    for name in task_names():
        by_metric.setdefault(task_spec(name).default_metric, []).append(name)
    return ", ".join(f"{metric} for {' and '.join(names)}" for metric, names in by_metric.items())


def _check_task(name: str) -> None:
    from smol_dsl.tasks import task_spec

    try:
        task_spec(name)
    except ValueError as error:
        raise UsageError(str(error)) from None


def _add_devices_option(command: argparse.ArgumentParser, what: str) -> None:
    command.add_argument(
        "--devices",
        type=_positive_int,
        default=None,
        metavar="D",
        help=f"{what} (default: all; on a CPU-only machine one device per core)",
    )


def _devices(args: argparse.Namespace) -> list[Any]:
    """The local devices, or the first --devices of them."""
    import jax

    devices = jax.local_devices()
    if args.devices is not None:
        if args.devices > len(devices):
            raise UsageError(f"--devices {args.devices}: this machine has {len(devices)} ({devices[0].platform})")
        devices = devices[: args.devices]
    return devices


def _add_run_options(command: argparse.ArgumentParser) -> None:
    command.add_argument("--preset", default="quick", metavar="NAME", help="quick (default) or paper")
    command.add_argument("--evals", type=_count, default=None, metavar="E", help="training evaluations per run")
    command.add_argument("--phases", type=_positive_int, default=None, metavar="N", help="number of phases")
    command.add_argument("--batch-size", type=_positive_int, default=None, metavar="B", help="offspring per generation")
    command.add_argument("--centroids", type=_positive_int, default=None, metavar="C", help="CVT cells in the archive")
    command.add_argument("--episode-length", type=_positive_int, default=None, metavar="L", help="steps per episode")
    command.add_argument(
        "--dry-run",
        action="store_true",
        help="print what the run would need (memory, checkpoint size, evaluations/s for a time budget), "
        "by arithmetic, and exit without running",
    )


def _load_all(names: Sequence[str]) -> tuple[list, list[str]]:
    from smol_dsl import ScheduleError, load

    loaded, errors = [], []
    for name in names:
        try:
            loaded.append(load(name))
        except ScheduleError as error:
            errors.append(str(error))
    return loaded, errors


def _check(args: argparse.Namespace) -> int:
    schedules, errors = _load_all(args.schedules)
    if args.task is not None:
        from smol_dsl.tasks import task_spec

        _check_task(args.task)
        spec = task_spec(args.task)
        schedules, errors = _check_bodies(schedules, errors, spec)
        if not args.quiet:
            print(_anatomy_text(spec.anatomy, args.task))
    if not args.quiet:
        for schedule in schedules:
            about = f" - {schedule.description}" if schedule.description else ""
            print(f"{schedule.path}: ok: {schedule.name}{about}")
            print(schedule.certificates_text())
    for error in errors:
        print(error, file=sys.stderr)
    return EXIT_USAGE if errors else EXIT_OK


def _check_bodies(schedules: list, errors: list[str], spec: TaskSpec) -> tuple[list, list[str]]:
    """The schedules whose channels the task's body has, and the errors of the others."""
    from smol_dsl import ScheduleError

    fitting = []
    for schedule in schedules:
        try:
            spec.check_schedule(schedule)
            fitting.append(schedule)
        except ScheduleError as error:
            errors.append(str(error))
    return fitting, errors


def _anatomy_text(anatomy: Anatomy | None, task: str) -> str:
    """What `check --task` says of the task's body: the parts channels can name."""
    if anatomy is None:
        return f"{task}: its body is not listed; only channels without targets (`channel gear`) can be checked"
    return "\n".join(f"{task}: {text}" for text in anatomy.listing().values())


def _plot(args: argparse.Namespace) -> int:
    from smol_dsl.language.channels import GEAR
    from smol_dsl.results.figures import FIGURE_FORMATS, PAPER_FIGURE, save_figure, schedule_figure

    names = args.schedules or list(PAPER_FIGURE)
    if args.out is None:
        out = Path(f"{Path(names[0]).stem}.png" if len(names) == 1 else "schedules.png")
    else:
        out = Path(args.out)
    if out.suffix.lower() not in FIGURE_FORMATS:
        raise UsageError(f"cannot write {out}: the format is chosen by the suffix, one of {', '.join(FIGURE_FORMATS)}")
    if not out.parent.is_dir():
        raise UsageError(f"cannot write {out}: no such directory {out.parent}")
    if out.is_dir():
        raise UsageError(f"cannot write {out}: it is a directory; give -o a file name, such as {out / 'schedules.png'}")
    schedules, errors = _load_all(names)
    if errors:
        for error in errors:
            print(error, file=sys.stderr)
        return EXIT_USAGE
    for schedule in schedules:
        if schedule.tail_phases(args.phases) == 0:
            final = "alpha = 1" if schedule.final_body == {GEAR: 1.0} else "its final body"
            print(
                f"smol-dsl plot: note: with {args.phases} phases no phase of {schedule.name} runs wholly "
                f"at {final} (its tail starts at {float(schedule.tail_start) * 100:g}%); "
                f"a run needs at least one phase at {final} to compare schedules on the same body",
                file=sys.stderr,
            )
    import jax

    figure = schedule_figure(schedules, num_phases=args.phases, key=jax.random.key(args.seed))
    try:
        save_figure(figure, out)  # atomically: a failure leaves no half-written file
    except OSError as error:
        raise UsageError(f"cannot write {out}: {error.strerror or error}") from None
    shown = ", ".join(s.name for s in schedules) if len(schedules) <= 8 else f"{len(schedules)} schedules"
    print(f"wrote {out} ({shown}; {args.phases} phases)")
    return EXIT_OK


def _config(args: argparse.Namespace, seed: int | None) -> RunConfig:
    from smol_dsl.runner import PRESETS, preset_config

    if args.preset not in PRESETS:
        raise UsageError(f"unknown preset {args.preset!r}; the presets are {', '.join(PRESETS)}")
    return preset_config(
        args.task,
        args.preset,
        seed=seed,
        evaluations=args.evals,
        num_phases=args.phases,
        batch_size=args.batch_size,
        num_centroids=args.centroids,
        episode_length=args.episode_length,
    )


def _run(args: argparse.Namespace) -> int:
    from smol_dsl import ScheduleError, load

    _check_task(args.task)
    _check_out(args.out)
    if args.seed is not None:
        check_seed(args.seed, "--seed")
    try:
        schedule = load(args.schedule)
    except ScheduleError as error:
        print(error, file=sys.stderr)
        return EXIT_USAGE
    from smol_dsl.runner import check_config, run_experiment
    from smol_dsl.runner.directories import check_out_dir, non_empty, run_name
    from smol_dsl.runner.footprint import fit_sweep
    from smol_dsl.runner.progress import summary_line

    config = _config(args, seed=args.seed)
    try:
        check_config(config, schedule)
    except ValueError as error:
        raise UsageError(str(error)) from None
    out = Path(args.out) if args.out is not None else Path("runs") / run_name(args.task, schedule, config.seed)
    check_out_dir(out)  # before anything compiles: a file, a device or a path under a file
    if not args.resume and non_empty(out):
        raise UsageError(f"{out} already exists and is not empty; use --resume to continue it or another --out")
    print(
        f"smol-dsl run: {args.task} under {schedule.name} ({args.schedule}), preset {config.preset}: "
        f"{config.evaluations} evaluations in batches of {config.batch_size}, {config.num_phases} phases, "
        f"{config.num_centroids} cells, {config.episode_length}-step episodes, seed {config.seed} -> {out}",
        file=sys.stderr,
    )
    devices = _devices(args)
    fit = partial(fit_sweep, config, 1, [config.seed], devices)
    _announce_footprint("run", config, fit, out, args.dry_run)
    if args.dry_run:
        return EXIT_OK
    if config.preset == "quick":
        print(
            "smol-dsl run: the quick preset is sized for about 2 minutes on 2 CPU cores; "
            "--preset paper runs the paper's experiment (1e7 evaluations; for a GPU)",
            file=sys.stderr,
        )
    result = _with_progress(
        args,
        config,
        lambda progress: run_experiment(
            args.task, schedule, config, out_dir=out, resume=args.resume, progress=progress, devices=devices
        ),
    )
    _draw_figures([result])
    print(summary_line(result, schedule))
    return EXIT_OK


def _with_progress(args: argparse.Namespace, config: RunConfig, start: Callable[[Any], T]) -> T:
    """start(progress callback or None), with a progress bar unless --no-progress; a
    RunError (bad directory, settings) becomes a usage error."""
    from smol_dsl.runner import RunError
    from smol_dsl.runner.progress import ProgressBar

    bar = None if args.no_progress else ProgressBar(config)
    try:
        return start(bar.update if bar else None)
    except RunError as error:
        raise UsageError(str(error)) from None
    finally:
        if bar is not None:
            bar.close()


def _sweep(args: argparse.Namespace) -> int:
    _check_task(args.task)
    _check_out(args.out)
    _check_seeds(args.first_seed, args.seeds)
    schedules, errors = _load_all(args.schedules)
    if errors:
        for error in errors:
            print(error, file=sys.stderr)
        return EXIT_USAGE
    from smol_dsl.runner import check_config, run_sweep
    from smol_dsl.runner.directories import check_out_dir, non_empty
    from smol_dsl.runner.footprint import fit_sweep
    from smol_dsl.runner.progress import sweep_summary

    config = _config(args, seed=None)
    try:
        for schedule in schedules:
            check_config(config, schedule)
    except ValueError as error:
        raise UsageError(str(error)) from None
    part = _sweep_part(args)
    devices = _devices(args)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    out = Path(args.out) if args.out is not None else Path("runs") / f"{args.task}-sweep"
    check_out_dir(out)
    if not args.resume and part == (0, 1) and non_empty(out):
        raise UsageError(f"{out} already exists and is not empty; use --resume to continue it or another --out")
    runs = len(range(part[0], len(schedules) * len(seeds), part[1]))
    share = f" (process {part[0]} of {part[1]}: {runs} of them)" if part[1] > 1 else ""
    print(
        f"smol-dsl sweep: {args.task}, {len(schedules)} schedule(s) x {len(seeds)} seed(s) = "
        f"{len(schedules) * len(seeds)} runs{share} "
        f"on {len(devices)} {devices[0].platform} device(s), preset {config.preset}: {config.evaluations} "
        f"evaluations per run in batches of {config.batch_size}, {config.num_phases} phases, "
        f"{config.num_centroids} cells, {config.episode_length}-step episodes -> {out}",
        file=sys.stderr,
    )
    runs_per_step = -1 if args.runs_per_step is None else args.runs_per_step
    fit = partial(fit_sweep, config, len(schedules), seeds, devices, runs_per_step, part)
    footprint = _announce_footprint("sweep", config, fit, out, args.dry_run)
    if args.dry_run:
        return EXIT_OK
    results = _with_progress(
        args,
        config,
        lambda progress: run_sweep(
            args.task,
            schedules,
            seeds,
            config,
            out_dir=out,
            resume=args.resume,
            progress=progress,
            devices=devices,
            runs_per_step=footprint.runs_per_step if runs_per_step == -1 else runs_per_step,
            part=part,
        ),
    )
    _draw_figures(results)
    print(sweep_summary(results, out))
    return EXIT_OK


def _draw_figures(results: Sequence[Any]) -> None:
    """Each finished run directory's metrics.png and archive.png, after training."""
    from smol_dsl.results.figures import save_run_figures

    for result in results:
        if result.out_dir is not None and result.final["generation"] >= result.config.generations:
            save_run_figures(result.out_dir)


def _check_out(out: str | None) -> None:
    """Refuse `--out ""`, which would otherwise mean the current directory."""
    if out is not None and not out.strip():
        raise UsageError("--out: empty path; give the directory to write to (or leave --out out for the default)")


def _check_seeds(first: int, count: int) -> None:
    """--first-seed and every seed up to --first-seed + --seeds - 1 must give distinct runs."""
    from smol_dsl.seeds import SEED_MAX

    check_seed(first, "--first-seed")
    last = first + count - 1
    if last > SEED_MAX:
        raise UsageError(
            f"--first-seed {first} with --seeds {count}: the seeds would run up to {last}, past the largest "
            f"seed, {SEED_MAX}; use --first-seed {SEED_MAX - count + 1} or less, or fewer --seeds"
        )


LARGE_BYTES = 1e9  # a run or sweep this big on a device gets its footprint printed, whatever the preset


def _announce_footprint(
    command: str, config: RunConfig, fit: Callable[[], Footprint], out: Path, dry_run: bool
) -> Footprint:
    """Check that the run(s) fit the devices' memory, and print what they will need for the
    paper preset or anything large; before anything compiles."""
    from smol_dsl.runner import RunError

    try:
        footprint = fit()
    except RunError as error:
        raise UsageError(str(error)) from None
    if dry_run or config.preset == "paper" or footprint.device_bytes > LARGE_BYTES:
        print(f"smol-dsl {command}: what this will need, by arithmetic before compiling:", file=sys.stderr)
        for line in footprint.describe(out).splitlines():
            print(f"  {line}", file=sys.stderr)
    return footprint


CLUSTER_VARIABLES = (("SLURM_NTASKS", "SLURM_PROCID"), ("OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"))


def _sweep_part(args: argparse.Namespace) -> tuple[int, int]:
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


def _report(args: argparse.Namespace) -> int:
    from smol_dsl.results.report import METRICS, write_report

    if args.metric is not None and args.metric not in METRICS:
        raise UsageError(f"unknown metric {args.metric!r}; the metrics are {', '.join(METRICS)}")
    if args.out is None and len(args.dirs) > 1:
        raise UsageError("with several DIRs, say where the report goes with -o OUT")
    if args.out is not None and not args.out.strip():
        raise UsageError("-o: empty path; give the directory the report goes into (or leave -o out for DIR/report)")
    out = Path(args.out) if args.out is not None else Path(args.dirs[0]) / "report"
    report = write_report(args.dirs, out, args.metric, force=args.force)  # a ReportError is a usage error
    table = report.table
    print(f"{table.task}, final {table.metric} ({sum(table.runs.values())} runs):\n")
    print(table.markdown())
    for note in table.notes()[:3]:
        print(f"note: {note}", file=sys.stderr)
    if len(table.notes()) > 3:
        more = len(table.notes()) - 3
        print(f"note: and {more} more pair{'s' if more > 1 else ''} like these", file=sys.stderr)
    print(f"wrote {', '.join(str(f) for f in report.files)}")
    return EXIT_OK


def _usage_message(command: str, error: UserInputError) -> str:
    from smol_dsl.errors import ScheduleError

    if isinstance(error, ScheduleError):  # already "FILE:LINE:COL: error: ..." with an excerpt
        return str(error)
    return f"smol-dsl {command}: error: {error}"


def _os_error_text(error: OSError) -> str:
    reason = error.strerror or type(error).__name__
    if error.filename is not None:
        return f"{error.filename}: {reason}"
    return str(error) or reason


def use_cpu_cores_as_devices() -> None:
    """Before JAX starts: split a CPU into one XLA device per core (unless XLA_FLAGS
    already says how many), so that a run's population and a sweep's runs use every core. It changes nothing
    on GPUs, whose devices JAX prefers."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={cores}".strip()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `smol-dsl` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)  # exits with status 2 on bad flags
    if args.command in ("run", "sweep"):
        use_cpu_cores_as_devices()
    handlers = {"check": _check, "plot": _plot, "run": _run, "sweep": _sweep, "report": _report}
    try:
        return handlers[args.command](args)
    except UserInputError as error:
        # Every error a user can cause ends here: one message, exit status 2.
        print(_usage_message(args.command, error), file=sys.stderr)
        return EXIT_USAGE
    except RecursionError:
        print(f"smol-dsl {args.command}: error: input nested too deeply to read", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:
        # stdout closed early (`smol-dsl report ... | head`): the work is done; stop quietly,
        # as a command killed by SIGPIPE would.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 128 + 13
    except OSError as error:
        # The environment, not a bug: a full disk, a read-only file system, a path that is
        # not a directory. Name the file when the OS says which.
        print(f"smol-dsl {args.command}: error: {_os_error_text(error)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("smol-dsl: interrupted", file=sys.stderr)
        return 130
    except Exception as error:  # a bug in smol-dsl, not bad input
        if os.environ.get("SMOL_DSL_DEBUG"):
            raise
        print(
            f"smol-dsl: internal error: {type(error).__name__}: {error}\n"
            "This is a bug in smol-dsl; rerun with SMOL_DSL_DEBUG=1 for the traceback and please report it.",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
