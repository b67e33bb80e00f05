"""What the commands share: option types and options, the loading of schedules, and the
turning of every error a user can cause into one message and exit status 2."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from smol_dsl.errors import ScheduleError, UserInputError

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2


class UsageError(UserInputError):
    """Bad command-line input that argparse itself does not catch."""


class Options(dict[str, str]):
    """The command line's name for each setting the library's messages name (see
    `smol_dsl.errors.Setting`); a RunConfig field without an option of its own is set by
    the preset."""

    def __missing__(self, name: str) -> str:
        return f"{name} (set by --preset)"


OPTIONS = Options(
    task="TASK",
    evaluations="--evals",
    batch_size="--batch-size",
    num_phases="--phases",
    num_centroids="--centroids",
    episode_length="--episode-length",
    physics="--physics",
    seed="--seed",
    preset="--preset",
    schedule="SCHEDULE",
    schedules="SCHEDULE",
    seeds="--first-seed/--seeds",
)


# -- option types ---------------------------------------------------------------------------


def whole_number(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def count(text: str) -> int:
    """A whole number of at least 1 (an evaluation budget: no upper limit)."""
    value = whole_number(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def positive_int(text: str) -> int:
    """A whole number from 1 to 100000 (phases, batch sizes, cells, steps)."""
    value = count(text)
    if value > 100_000:
        raise argparse.ArgumentTypeError(f"must be at most 100000, got {value}")
    return value


# -- options of `run` and `sweep` -------------------------------------------------------------


def add_run_options(command: argparse.ArgumentParser) -> None:
    """The settings of a run: a preset, and the fields it sets that an option overrides."""
    command.add_argument("--preset", default="quick", metavar="NAME", help="quick (default) or paper")
    command.add_argument("--evals", type=count, default=None, metavar="E", help="training evaluations per run")
    command.add_argument("--phases", type=positive_int, default=None, metavar="N", help="number of phases")
    command.add_argument("--batch-size", type=positive_int, default=None, metavar="B", help="offspring per generation")
    command.add_argument("--centroids", type=positive_int, default=None, metavar="C", help="CVT cells in the archive")
    command.add_argument("--episode-length", type=positive_int, default=None, metavar="L", help="steps per episode")
    add_physics_option(command, "simulate the task with")
    command.add_argument(
        "--dry-run",
        action="store_true",
        help="print what the run would need (memory, checkpoint size, evaluations/s for a time budget) by "
        "arithmetic; then build and compile its engine, time an untimed and up to 3 timed generations of every "
        "run at once and a re-evaluation chunk, and print the measured throughput, the compile time and the "
        "estimated wall time; exit without running or writing anything (it takes the compile and a few "
        "generations)",
    )
    command.add_argument(
        "--no-measure",
        action="store_true",
        help="with --dry-run: print the arithmetic only, without compiling or timing anything (seconds)",
    )


def add_physics_option(command: argparse.ArgumentParser, what: str) -> None:
    """--physics: spring (the paper's, the default) or mjx (`smol_dsl.tasks.physics`)."""
    from smol_dsl.tasks.physics import DEFAULT_PHYSICS, PHYSICS, PHYSICS_NAMES

    command.add_argument(
        "--physics",
        choices=PHYSICS_NAMES,
        default=DEFAULT_PHYSICS,
        help=f"{what}: "
        + "; ".join(f"{physics.name}, {physics.help}" for physics in PHYSICS.values())
        + f" (default {DEFAULT_PHYSICS})",
    )


def physics_label(task: str, physics: str) -> str:
    """How default output directories name a task on a physics: the task alone on the
    default physics (spring), `TASK-PHYSICS` on another, so that the two never share one."""
    from smol_dsl.tasks.physics import DEFAULT_PHYSICS

    return task if physics == DEFAULT_PHYSICS else f"{task}-{physics}"


def add_devices_option(command: argparse.ArgumentParser, what: str) -> None:
    command.add_argument(
        "--devices",
        type=positive_int,
        default=None,
        metavar="D",
        help=f"{what} (default: all; on a CPU-only machine one device per core)",
    )


def devices(args: argparse.Namespace) -> list[Any]:
    """The local devices, or the first --devices of them."""
    import jax

    found = jax.local_devices()
    if args.devices is not None:
        if args.devices > len(found):
            raise UsageError(f"--devices {args.devices}: this machine has {len(found)} ({found[0].platform})")
        found = found[: args.devices]
    return found


def check_out(out: str | None) -> None:
    """Refuse `--out ""`, which would otherwise mean the current directory."""
    if out is not None and not out.strip():
        raise UsageError("--out: empty path; give the directory to write to (or leave --out out for the default)")


# -- tasks and schedules --------------------------------------------------------------------


def tasks_help() -> str:
    """The registered tasks, each with its one-line help (the registry needs no JAX)."""
    from smol_dsl.tasks import task_names, task_spec

    return "; ".join(f"{name}: {task_spec(name).help}" for name in task_names())


def check_task(name: str) -> None:
    from smol_dsl.tasks import task_spec

    try:
        task_spec(name)
    except ValueError as error:
        raise UsageError(str(error)) from None


def load_all(names: Sequence[str]) -> tuple[list[Schedule], list[str]]:
    """The schedules that load, and the located error of each that does not."""
    from smol_dsl import load

    loaded, errors = [], []
    for name in names:
        try:
            loaded.append(load(name))
        except ScheduleError as error:
            errors.append(str(error))
    return loaded, errors


def print_errors(errors: Sequence[str]) -> None:
    for error in errors:
        print(error, file=sys.stderr)


# -- errors to exit statuses ----------------------------------------------------------------


def exit_status(command: str, handle: Callable[[], int]) -> int:
    """handle()'s exit status; every error a user or the environment can cause is one
    message and exit status 2, a bug one line that says so and 1."""
    try:
        return handle()
    except UserInputError as error:
        print(usage_message(command, error), file=sys.stderr)
        return EXIT_USAGE
    except RecursionError:
        print(f"smol-dsl {command}: error: input nested too deeply to read", file=sys.stderr)
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
        print(f"smol-dsl {command}: error: {os_error_text(error)}", file=sys.stderr)
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


def usage_message(command: str, error: UserInputError) -> str:
    """What the command prints for a user's error: the library's settings named as options."""
    if isinstance(error, ScheduleError):  # already "FILE:LINE:COL: error: ..." with an excerpt
        return str(error)
    return f"smol-dsl {command}: error: {error.worded(OPTIONS)}"


def os_error_text(error: OSError) -> str:
    reason = error.strerror or type(error).__name__
    if error.filename is not None:
        return f"{error.filename}: {reason}"
    return str(error) or reason
