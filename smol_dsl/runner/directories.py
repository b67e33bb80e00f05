"""Run and sweep directories: set up, locked, checked on resume.

A run directory is created with the run's settings, schedule and certificate before
anything trains, and locked (smol_dsl.runner.lock) while a process writes it; resuming
checks that the settings and schedule are the ones it was started with, naming each that
differs. A sweep directory holds sweep.json and one run directory per (schedule, seed).
Every refusal is a RunError that names the path and says what to do; a setting that
differs is named as a `Setting` (a RunConfig field, or `schedules` and `seeds`), which the
CLI words as its option.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.errors import Message
from smol_dsl.rundir import (
    CONFIG_FILE,
    ENVIRONMENT_FILE,
    LOCK_FILE,
    RESUME_COMPARED,
    SCHEDULE_FILE,
    SWEEP_FILE,
    RunConfig,
    environment_differences,
    latest_environment,
    record_environment_change,
    write_run_files,
)
from smol_dsl.rundir.config import setting_differences
from smol_dsl.rundir.files import read_json_object, remove_stale_temporaries
from smol_dsl.rundir.layout import checkpoint_processes
from smol_dsl.rundir.snapshots import SnapshotsError, read_snapshots
from smol_dsl.rundir.sweep import SweepRun, read_sweep_file, sweep_description, sweep_differences, write_sweep_file
from smol_dsl.runner.checkpoint import write_failure
from smol_dsl.runner.config import RunError
from smol_dsl.runner.lock import DirectoryLock

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.runner.plan import PlannedRun


def schedule_stem(schedule: Schedule) -> str:
    """What a run's directory name (`run_name`) calls its schedule: the file's stem, or its name."""
    return Path(schedule.path).stem if schedule.path else schedule.name


def out_path(out_dir: str | Path | None) -> Path | None:
    """out_dir as a Path, refusing an empty one (which would silently mean the current directory)."""
    if out_dir is None:
        return None
    if str(out_dir) == "" or (isinstance(out_dir, str) and not out_dir.strip()):
        raise RunError("--out: empty path; give the directory to write the run to (or leave --out out)")
    if "\0" in str(out_dir):
        raise RunError(f"--out {str(out_dir)!r}: a path cannot hold a NUL character")
    return Path(out_dir)


def prepare_run_directory(
    directory: Path,
    schedule: Schedule,
    config: RunConfig,
    resume: bool,
    environment: dict[str, Any] | None = None,
    allow_environment_change: bool = False,
) -> DirectoryLock:
    """Check a directory to resume, or create one and write the run's settings into it,
    with the `environment` it runs under (`describe_environment`). A run resumed under an
    environment other than the one it recorded is refused, naming what differs, unless
    `allow_environment_change` (the change is then recorded in its environment.json).

    Returns the directory's lock, held: the caller releases it when the run ends (it is a
    context manager). A second process on the same directory is refused with a RunError.
    """
    check_out_dir(directory)
    if resume:
        return _resume_run_directory(directory, schedule, config, environment, allow_environment_change)
    if non_empty(directory):
        raise busy(directory)
    make_directory(directory, "run")
    lock = lock_directory(directory, "run", resume=False)
    try:
        if non_empty(directory):  # another process set it up since we looked
            raise busy(directory)
        set_up(directory, lambda: write_run_files(directory, config, schedule, environment))
    except BaseException:
        lock.release()
        raise
    return lock


def _resume_run_directory(
    directory: Path,
    schedule: Schedule,
    config: RunConfig,
    environment: dict[str, Any] | None,
    allow_environment_change: bool,
) -> DirectoryLock:
    config_path = directory / CONFIG_FILE
    if not config_path.is_file():
        if (directory / SWEEP_FILE).is_file():
            raise RunError(
                f"{directory} is a sweep directory, not a run's: resume it with `smol-dsl sweep ... --resume`, "
                "or resume one of its runs with --out on that run's directory"
            )
        raise RunError(f"{directory} holds no run to resume (no config.json); start it without --resume")
    lock = lock_directory(directory, "run", resume=True)
    try:
        saved = read_json_object(config_path, "run")
        differences = setting_differences(saved, json.loads(config.to_json()), "run")
        if differences:
            raise RunError(
                f"{directory} was started with different settings; resume it with the same ones: "
                + Message.joined("; ", differences)
            )
        schedule_path = directory / SCHEDULE_FILE
        if not schedule_path.is_file():
            raise RunError(
                f"{directory} holds no schedule.sched, so it cannot be resumed: put back, as {schedule_path}, "
                "a copy of the schedule file the run was started with"
            )
        if schedule_path.read_bytes() != schedule.source.encode():
            what = schedule.path or schedule.name
            raise RunError(
                f"{directory} was started with a different schedule: {what} is not the text in {schedule_path}; "
                f"resume it with the schedule it was started with (for instance {schedule_path} itself)"
            )
        _check_snapshots(directory)
        if environment is not None:
            _check_environment(directory, environment, allow_environment_change)
        remove_stale_temporaries(directory)
    except BaseException:
        lock.release()
        raise
    return lock


def _check_snapshots(directory: Path) -> None:
    """Refuse to resume a run whose phases.npz cannot be read: the archives of the phases
    trained so far are only there (a checkpoint holds the current archive alone), so going
    on would silently drop them."""
    try:
        read_snapshots(directory)
    except SnapshotsError as error:
        raise RunError(
            f"{error.path}: {error.reason}. The run's archives through the phases trained so far are kept only "
            "there (its checkpoint holds the latest archive alone), so it is not resumed: remove the file to resume "
            "without them (phases.npz then holds the phases from the checkpoint's on), or rerun the run"
        ) from None


def _check_environment(directory: Path, environment: dict[str, Any], allow_change: bool) -> None:
    """Refuse to resume a run under an environment or scoring layout other than the one it
    last went on under (its numbers would mix two compilations of the physics), or one
    whose environment.json is gone (what it started under is unknown); or, if allowed,
    record the change."""
    recorded = latest_environment(directory)
    if recorded is None:
        if not allow_change:
            raise RunError(
                f"{directory} holds no {ENVIRONMENT_FILE}, so what the run was started under is unknown and resuming "
                "could mix two builds of the physics unseen: put the file back, or pass --allow-environment-change "
                "to go on (a new environment.json records that the start's environment is unknown)"
            )
        record_environment_change(directory, environment, [])
        return
    differences = environment_differences(recorded, environment, RESUME_COMPARED)
    if not differences:
        return
    if not allow_change:
        raise RunError(
            f"{directory} was started under another environment ({ENVIRONMENT_FILE}): "
            + "; ".join(differences)
            + ". Its numbers would mix two builds of the physics: resume it where it was started, or pass "
            "--allow-environment-change to go on (the change is recorded in its environment.json)"
        )
    record_environment_change(directory, environment, differences)


def check_out_dir(directory: Path) -> None:
    """Refuse an output path that cannot be a directory, naming it and saying what to give."""
    try:
        if directory.exists() and not directory.is_dir():
            kind = "a file" if directory.is_file() else "a special file (a device, pipe or socket)"
            raise RunError(
                f"--out {directory}: {directory} is {kind}, not a directory; give the path of a directory "
                "(it is created if missing)"
            )
        parent = next((p for p in directory.parents if p.exists()), None)
    except OSError:
        return  # cannot even look: creating or locking it reports the OS's reason
    if parent is not None and not parent.is_dir():
        raise RunError(
            f"--out {directory}: {parent} is a file, not a directory, so nothing can be created under it; "
            "give another --out"
        )


def busy(directory: Path) -> RunError:
    """The refusal of a new run or sweep in a directory that holds something already."""
    return RunError(f"{directory} already exists and is not empty; use --resume to continue it or another --out")


def non_empty(directory: Path) -> bool:
    """Whether directory exists and holds anything but its lock file (False if it cannot be
    read: creating or locking it then says why)."""
    try:
        return directory.is_dir() and any(path.name != LOCK_FILE for path in directory.iterdir())
    except OSError:
        return False


def make_directory(directory: Path, what: str) -> None:
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        reason = error.strerror or str(error)
        where = f" ({error.filename})" if error.filename not in (None, str(directory)) else ""
        raise RunError(
            f"cannot create the {what} directory {directory}: {reason}{where}; give an --out where you can write"
        ) from None


def lock_directory(directory: Path, what: str, resume: bool) -> DirectoryLock:
    """The directory's lock (see smol_dsl.runner.lock), or a RunError that says why not."""
    try:
        return DirectoryLock.acquire(directory, what)
    except OSError as error:
        reason = error.strerror or str(error)
        if resume:
            fix = (
                f"the {what} cannot go on there: make it writable, or copy the directory somewhere writable "
                "and resume the copy (--out COPY --resume)"
            )
        else:
            fix = "give an --out where you can write"
        raise RunError(f"cannot write in {directory}: {reason}; {fix}") from None


def set_up(directory: Path, write: Callable[[], Any]) -> None:
    """Write a new run's or sweep's files (`write` removes those it wrote if one fails); a
    disk that cannot take them is a RunError naming the file: nothing was started."""
    try:
        write()
    except OSError as error:
        target, reason, fix = write_failure(error, fallback=directory)
        raise RunError(
            f"cannot write {target}: {reason}; nothing was started: {fix}, then run the command again"
        ) from None


def prepare_sweep_directory(
    directory: Path,
    every: list[PlannedRun],
    runs: list[PlannedRun],
    config: RunConfig,
    resume: bool,
    shared: bool,
    checkpoint_name: str,
    environments: list[dict[str, Any]] | None = None,
    allow_environment_change: bool = False,
) -> contextlib.ExitStack:
    """Write or check sweep.json (all runs) and prepare this process's run directories,
    each with its environment (`environments`, one per run of `runs`).
    A directory `shared` by several processes may already hold the others' runs.

    Returns the locks this process holds, as one context manager: every run directory it
    writes, and the sweep directory itself unless it is shared, so that no second process
    can write them at the same time.
    """
    check_out_dir(directory)
    description = sweep_description(
        config, [SweepRun(run.name, run.schedule.name, run.config.seed, run.schedule.source) for run in every]
    )
    locks = contextlib.ExitStack()
    try:
        if resume:
            _check_sweep_to_resume(directory)
        else:
            _make_sweep_directory(directory, [directory / run.name for run in runs] if shared else [directory])
        if not shared:
            locks.enter_context(_lock_sweep_directory(directory, resume))
        _check_sweep_file(directory, description, compare=resume or shared)
        if not resume:
            set_up(directory, lambda: write_sweep_file(directory, description))
        for run, environment in zip(runs, environments or [None] * len(runs), strict=True):
            locks.enter_context(
                _prepare_sweep_run(directory / run.name, run, resume, environment, allow_environment_change)
            )
        if resume:
            _check_process_count(directory, checkpoint_name)
            remove_stale_temporaries(directory, prefix=f"{checkpoint_name}.")
    except BaseException:
        locks.close()
        raise
    return locks


def _check_sweep_to_resume(directory: Path) -> None:
    """Refuse to resume a directory that holds no sweep, saying what it holds instead."""
    if (directory / SWEEP_FILE).is_file():
        return
    if (directory / CONFIG_FILE).is_file():
        raise RunError(f"{directory} is a run directory, not a sweep's: resume it with `smol-dsl run ... --resume`")
    raise RunError(f"{directory} holds no sweep to resume (no {SWEEP_FILE}); start it without --resume")


def _make_sweep_directory(directory: Path, own: list[Path]) -> None:
    """Create a new sweep's directory, refusing if any directory this process would write
    (`own`: the sweep's, or its runs' where processes share it) holds something already."""
    taken = next((path for path in own if non_empty(path)), None)
    if taken is not None:
        raise busy(taken)
    make_directory(directory, "sweep")


def _lock_sweep_directory(directory: Path, resume: bool) -> DirectoryLock:
    """The sweep directory's lock, held; a new sweep's directory must still be empty once
    locked (another process may have started one there since it was looked at)."""
    lock = lock_directory(directory, "sweep", resume)
    if not resume and non_empty(directory):
        lock.release()
        raise busy(directory)
    return lock


def _check_sweep_file(directory: Path, description: dict[str, Any], compare: bool) -> None:
    """Read sweep.json if there is one (a damaged one is refused); with `compare`, refuse
    one that describes another sweep, naming what differs."""
    saved = read_sweep_file(directory)
    if compare and saved is not None and saved != description:
        raise RunError(
            f"{directory} was started with different settings, schedules or seeds; resume it with the same "
            "command line: " + Message.joined("; ", sweep_differences(saved, description, directory))
        )


def _prepare_sweep_run(
    run_directory: Path,
    run: PlannedRun,
    resume: bool,
    environment: dict[str, Any] | None,
    allow_environment_change: bool,
) -> DirectoryLock:
    """Prepare one run directory of the sweep; on resume, one deleted since the sweep started
    is set up again (the sweep's checkpoint holds its state)."""
    again = resume and not (run_directory / CONFIG_FILE).exists() and not non_empty(run_directory)
    return prepare_run_directory(
        run_directory, run.schedule, run.config, resume and not again, environment, allow_environment_change
    )


def _check_process_count(directory: Path, checkpoint_name: str) -> None:
    """Refuse to resume a sweep with another number of processes than it was checkpointed
    by: this process's checkpoint would be missing, and its runs would silently start over."""
    if (directory / checkpoint_name).exists():
        return
    parts = checkpoint_processes(checkpoint_name) or 1
    found = {path.name: checkpoint_processes(path.name) for path in directory.iterdir()}
    others = sorted(name for name, count in found.items() if count is not None and count != parts)
    if others:
        counts = sorted({found[name] for name in others})
        started = " or ".join(_processes(count) for count in counts)
        raise RunError(
            f"{directory} was checkpointed by {started} ({', '.join(others[:3])}{', ...' if len(others) > 3 else ''}), "
            f"not {_processes(parts)}: resume it with the same --num-processes (or none, for one process); "
            f"otherwise this process's runs would start over"
        )


def _processes(count: int) -> str:
    return "one process" if count == 1 else f"{count} processes (--num-processes {count})"
