"""A run directory's files: their names, what each holds, and what makes a directory a run's.

`FILES` lists every file of a run directory in the order the runner writes them,
`SWEEP_FILES` a sweep directory's own; docs/runner.md's tables are generated from them.
`run_name` names a sweep's run directories (`schedule_of_run_name` reads one back), and
`sweep_checkpoint_file` the checkpoint of each process of a sweep (`checkpoint_processes`
reads the number back). `RunDirectoryError` is the error of a run directory whose files
cannot be used.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from smol_dsl.errors import UserInputError

CONFIG_FILE = "config.json"
ENVIRONMENT_FILE = "environment.json"
SCHEDULE_FILE = "schedule.sched"
CERTIFICATE_FILE = "certificate.json"
CERTIFICATE_TEXT_FILE = "certificate.txt"
METRICS_FILE = "metrics.csv"
CHECKPOINT_FILE = "checkpoint.npz"
ARCHIVE_FILE = "archive.npz"
SNAPSHOTS_FILE = "phases.npz"
METRICS_FIGURE = "metrics.png"
ARCHIVE_FIGURE = "archive.png"
LOCK_FILE = ".smol-dsl.lock"
SWEEP_FILE = "sweep.json"
SWEEP_CHECKPOINT_FILE = "sweep-checkpoint.npz"
ROBUSTNESS_FILE = "robustness.csv"  # `smol-dsl robustness`'s measurements, beside the runs (rundir.robustness)

FILES = (
    (CONFIG_FILE, "the resolved settings (`RunConfig`)"),
    (
        ENVIRONMENT_FILE,
        "the software and hardware the run was produced by (Python, jax, brax, qdax and other versions, smol-dsl's "
        "version and commit, the physics and the package that implements it, the devices, the processor and its "
        "vector extensions), and every resume allowed under another",
    ),
    (SCHEDULE_FILE, "the schedule's source"),
    (
        CERTIFICATE_FILE,
        "what was proven about the schedule, with its `name`, `tail_start` (where α = 1 for good) and "
        "`schedule_sha256` (the text it proves)",
    ),
    (CERTIFICATE_TEXT_FILE, "the same certificate, as `smol-dsl check` prints it"),
    (METRICS_FILE, "one row per generation and per re-evaluation (columns below)"),
    (CHECKPOINT_FILE, "the state at the last checkpointed phase boundary (for `--resume`)"),
    (
        ARCHIVE_FILE,
        "the final archive: `genotypes/<parameter path>` (C, ...), `fitnesses` (C,), `descriptors` (C, D), "
        "`centroids` (C, D), `filled` (C,), `lanes` (C,): each elite's position in the batch it was scored in; "
        "an empty cell's fitness is −inf",
    ),
    (
        SNAPSHOTS_FILE,
        "the archive at every phase's start (after the initial population or the boundary's re-evaluation) and "
        "end (before the next boundary, and the final archive), without policies: `generation`, `phase`, `moment` "
        "(0 start, 1 end) (S,), `fitnesses` (S, C), `descriptors` (S, C, D); rewritten at every boundary",
    ),
    (METRICS_FIGURE, "max fitness, coverage, QD score and every scheduled channel's factor over training evaluations"),
    (
        ARCHIVE_FIGURE,
        "the final archive: a 2-D map of the CVT cells coloured by their elites' fitness (1 descriptor: fitness "
        "along it; more than 2: the best elite over the first two descriptors)",
    ),
    (LOCK_FILE, "the lock of the process writing the directory: its pid and host"),
)
"""Every file of a run directory and what it holds, in the order the runner writes them."""
SWEEP_FILES = (
    (SWEEP_FILE, "the sweep's settings, schedules and seeds"),
    (SWEEP_CHECKPOINT_FILE, "every run's state at the last checkpointed phase boundary, stacked"),
)
"""A sweep directory's own files, beside one run directory per (schedule, seed)."""
RUN_MARKERS = (SCHEDULE_FILE, CERTIFICATE_FILE, ARCHIVE_FILE, CHECKPOINT_FILE)
"""Besides metrics.csv, files that make a directory with a config.json a run directory."""


def run_name(task: str, schedule: str, seed: int) -> str:
    """A run directory's name: TASK-SCHEDULE-seedSEED (SCHEDULE: the schedule file's stem, or
    the schedule's name)."""
    return f"{task}-{schedule}-seed{seed}"


def schedule_of_run_name(name: str, task: str) -> str | None:
    """The SCHEDULE of a `run_name` of `task`, or None for a name that is not one."""
    match = re.fullmatch(rf"{re.escape(task)}-(.*)-seed-?\d+", name)
    return match.group(1) if match else None


_SWEEP_CHECKPOINT = re.compile(r"sweep-checkpoint(?:-(\d+)-of-(\d+))?\.npz")


def sweep_checkpoint_file(part: tuple[int, int] = (0, 1)) -> str:
    """The checkpoint file of the process that runs `part` = (k, n) of a sweep: its k-th of n
    parts (`SWEEP_CHECKPOINT_FILE` for a sweep run by one process)."""
    index, parts = part
    return SWEEP_CHECKPOINT_FILE if parts == 1 else f"sweep-checkpoint-{index}-of-{parts}.npz"


def checkpoint_processes(name: str) -> int | None:
    """How many processes ran the sweep whose checkpoint file is `name` (a
    `sweep_checkpoint_file`), or None for a name that is not one."""
    match = _SWEEP_CHECKPOINT.fullmatch(name)
    if match is None:
        return None
    return int(match.group(2) or 1)


class RunDirectoryError(UserInputError):
    """A run directory whose files cannot be used: the message names the file (and line),
    what is wrong with it and what to do."""


def leave_out(directory: Path) -> str:
    """The other way out that every RunDirectoryError offers: leaving the run out of the report."""
    return f"or move {directory} out of the directories you report on"


def is_run_directory(path: Path) -> bool:
    """Whether path looks like a run directory, whole or not: it holds metrics.csv, or a
    config.json with another file the runner writes. `read_run` says what is wrong with it."""
    if (path / METRICS_FILE).is_file():
        return True
    return (path / CONFIG_FILE).is_file() and any((path / name).is_file() for name in RUN_MARKERS)


def files_markdown(files: Sequence[tuple[str, str]] = FILES) -> str:
    """A table of files and what they hold, in Markdown (docs/runner.md holds FILES')."""
    lines = ["| file | contents |", "| --- | --- |"]
    lines += [f"| `{name}` | {contents} |" for name, contents in files]
    return "\n".join(lines) + "\n"
