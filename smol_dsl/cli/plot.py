"""`smol-dsl plot`: schedules over training, as in the paper's Figure 2."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from smol_dsl.cli.common import EXIT_OK, EXIT_USAGE, UsageError, load_all, positive_int, print_errors, whole_number
from smol_dsl.rundir.layout import is_run_directory
from smol_dsl.seeds import check_seed, schedule_key


def add_parser(commands: argparse._SubParsersAction) -> None:
    plot = commands.add_parser(
        "plot",
        help="plot alpha over training (the paper's Figure 2)",
        description="Plot alpha over training as per-phase steps with the smooth curve, several schedules "
        "overlaid, and a dashed line where alpha becomes 1 for good; one panel per channel when the "
        "schedules scale other parameters too; a paced schedule with its envelope (the values a run can have "
        "in each phase whatever its metrics; its slowest run dotted). With no SCHEDULE, plots the paper's "
        "Figure 2 (vanilla, smol, smol-reverse, human).",
    )
    plot.add_argument(
        "schedules",
        nargs="*",
        metavar="SCHEDULE",
        help="a .sched path or a bundled name, or a run directory: the bodies that run trained in (a paced run's, "
        "those its archive let it reach), drawn over the given schedules at its number of phases",
    )
    plot.add_argument(
        "-o",
        "--out",
        metavar="OUT",
        help="output file; .png, .svg or .pdf (default: NAME.png for one schedule, schedules.png for several)",
    )
    plot.add_argument("--phases", type=positive_int, default=100, metavar="N", help="number of phases (default 100)")
    plot.add_argument(
        "--seed", type=_seed, default=0, metavar="S", help="seed of random segments, 0 to 2**32-1 (default 0)"
    )
    plot.set_defaults(handle=plot_schedules)


def _seed(text: str) -> int:
    """plot --seed: a seed as `run --seed` takes it, 0 to 2**32 - 1 (smol_dsl.seeds)."""

    try:
        return check_seed(whole_number(text), "")
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error).strip()) from None


def plot_schedules(args: argparse.Namespace) -> int:
    from smol_dsl.results.figures import save_figure
    from smol_dsl.results.schedule_figures import PAPER_FIGURE, schedule_figure

    names = args.schedules or list(PAPER_FIGURE)
    out = _figure_path(args.out, names)
    runs = [name for name in names if is_run_directory(Path(name))]
    schedules, errors = load_all([name for name in names if name not in runs])
    if errors:
        print_errors(errors)
        return EXIT_USAGE
    trajectories, phases = _trajectories(runs, args.phases)
    _note_phase_counts(schedules, phases)
    # `run --seed`'s draws
    figure = schedule_figure(schedules, num_phases=phases, key=schedule_key(args.seed), trajectories=trajectories)
    try:
        save_figure(figure, out)  # atomically: a failure leaves no half-written file
    except OSError as error:
        raise UsageError(f"cannot write {out}: {error.strerror or error}") from None
    shown = ", ".join(s.name for s in schedules) if len(schedules) <= 8 else f"{len(schedules)} schedules"
    shown = ", ".join([shown] * bool(schedules) + [run.label for run in trajectories])
    print(f"wrote {out} ({shown}; {phases} phases)")
    return EXIT_OK


def _trajectories(runs: list[str], phases: int) -> tuple[list, int]:
    """The bodies each run directory's run trained in (a paced run's, those it reached), and
    the phases to draw: the runs' (which must agree), else `phases`."""
    from smol_dsl.results.schedule_figures import Trajectory
    from smol_dsl.rundir import read_run

    records = [read_run(Path(run)) for run in runs]
    counts = sorted({record.config.num_phases for record in records})
    if len(counts) > 1:
        raise UsageError(f"the runs trained {' and '.join(map(str, counts))} phases; plot runs of one phase count")
    trajectories = [
        Trajectory(f"{record.schedule} ({Path(run).name})", record.channels, record.phase_bodies())
        for run, record in zip(runs, records, strict=True)
    ]
    return trajectories, counts[0] if counts else phases


def _figure_path(given: str | None, names: list[str]) -> Path:
    """-o's file, or NAME.png for one schedule and schedules.png for several; refused unless
    its suffix names a format and its folder exists."""
    from smol_dsl.results.figures import FIGURE_FORMATS
    from smol_dsl.rundir.files import check_output_file

    if given is None:
        out = Path(f"{Path(names[0]).stem}.png" if len(names) == 1 else "schedules.png")
    else:
        out = Path(given)
    return check_output_file(out, FIGURE_FORMATS, "schedules.png", UsageError)


def _note_phase_counts(schedules: list, phases: int) -> None:
    """Note each schedule that, at this many phases, has no phase wholly on its final body."""
    from smol_dsl.language.channels import GEAR

    for schedule in schedules:
        if schedule.tail_phases(phases) == 0:
            final = "alpha = 1" if schedule.final_body == {GEAR: 1.0} else "its final body"
            print(
                f"smol-dsl plot: note: with {phases} phases no phase of {schedule.name} runs wholly "
                f"at {final} (its tail starts at {float(schedule.tail_start) * 100:g}%); "
                f"a run needs at least one phase at {final} to compare schedules on the same body",
                file=sys.stderr,
            )
