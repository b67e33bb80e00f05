"""`smol-dsl check`: verify schedules symbolically and print their certificates."""

from __future__ import annotations

from typing import TYPE_CHECKING

from smol_dsl.cli.common import (
    EXIT_OK,
    EXIT_USAGE,
    UsageError,
    add_physics_option,
    check_task,
    load_all,
    positive_int,
    print_errors,
)
from smol_dsl.errors import ScheduleError
from smol_dsl.rundir.presets import QUICK_COMMON

if TYPE_CHECKING:
    import argparse

    from smol_dsl.language.schedule import Schedule
    from smol_dsl.tasks import Anatomy, TaskSpec


def add_parser(commands: argparse._SubParsersAction) -> None:
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
    add_physics_option(check, "with --task: prove the factor ranges the task takes on")
    check.add_argument(
        "--phases",
        type=positive_int,
        default=QUICK_COMMON["num_phases"],
        metavar="N",
        help="for a paced schedule, print the envelope over N phases: per phase the earliest and latest "
        "development step and value whatever the run's metrics do (default %(default)s, the quick preset's; "
        "the paper's is 100)",
    )
    check.set_defaults(handle=check_schedules)


def check_schedules(args: argparse.Namespace) -> int:
    from smol_dsl.tasks.physics import DEFAULT_PHYSICS

    if args.task is None and args.physics != DEFAULT_PHYSICS:
        raise UsageError(f"--physics {args.physics} needs --task: it proves the factors a task takes on that physics")
    schedules, errors = load_all(args.schedules)
    if args.task is not None:
        from smol_dsl.tasks import task_spec

        check_task(args.task)
        spec = task_spec(args.task)
        schedules, errors = _check_bodies(schedules, errors, spec, args.physics)
        if not args.quiet:
            print(_anatomy_text(spec.anatomy, args.task))
            print(_ranges_text(spec, args.physics))
    if not args.quiet:
        for schedule in schedules:
            about = f" - {schedule.description}" if schedule.description else ""
            print(f"{schedule.path}: ok: {schedule.name}{about}")
            print(schedule.certificates_text())
            if schedule.is_paced:
                problem = schedule.tail_problem(args.phases)
                if problem is not None:
                    errors.append(f"{schedule.path}: {problem.worded({'num_phases': '--phases'})}")
                else:
                    print(schedule.envelope_text(args.phases))
    print_errors(errors)
    return EXIT_USAGE if errors else EXIT_OK


def _check_bodies(
    schedules: list[Schedule], errors: list[str], spec: TaskSpec, physics: str
) -> tuple[list[Schedule], list[str]]:
    """The schedules whose channels the task's body has and whose factors stay within what
    it takes on `physics`, and the errors of the others."""
    fitting = []
    for schedule in schedules:
        try:
            spec.check_schedule(schedule, physics)
            fitting.append(schedule)
        except ScheduleError as error:
            errors.append(str(error))
    return fitting, errors


def _anatomy_text(anatomy: Anatomy | None, task: str) -> str:
    """What `check --task` says of the task's body: the parts channels can name."""
    if anatomy is None:
        return f"{task}: its body is not listed; only channels without targets (`channel gear`) can be checked"
    return "\n".join(f"{task}: {text}" for text in anatomy.listing().values())


def _ranges_text(spec: TaskSpec, physics: str) -> str:
    """The factors the task takes on `physics`, per kind of channel, and how each was found."""
    from smol_dsl.language.channels import CHANNEL_KINDS
    from smol_dsl.tasks.ranges import factor_range

    ranges = spec.ranges(physics)
    lines = [f"{spec.name} on {physics} takes these factors (a part's factor: the product of its channels'):"]
    for kind in CHANNEL_KINDS:
        allowed = factor_range(ranges, kind)
        lines.append(f"  {kind}: {allowed.low:g} .. {allowed.high:g} ({allowed.found})")
    return "\n".join(lines)
