"""The phased MAP-Elites run: `run_experiment(task, schedule, config)`, resumable.

Phase k of N trains at alpha_k = schedule.phase_alpha(k, N). At each phase boundary the
whole archive is re-evaluated under the new alpha, thinned by the schedule's extinction
probability and re-inserted into a fresh archive; a checkpoint is written atomically right
after, so an interrupted run resumes from its last boundary and ends with exactly the
archive and metrics of an uninterrupted run of the same seed.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import math
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl import Schedule
from smol_dsl.runner.algorithm import Evaluation, cvt_centroids, phased_map_elites
from smol_dsl.runner.checkpoint import (
    CHECKPOINT,
    CheckpointWriter,
    RunState,
    atomic_write,
    checkpoint_arrays,
    load_checkpoint,
    run_owner,
    save_archive,
    save_checkpoint,
    storage_error,
    write_failure,
)
from smol_dsl.runner.config import RunConfig, RunError
from smol_dsl.runner.footprint import fit_sweep
from smol_dsl.runner.lock import LOCK_FILE, DirectoryLock
from smol_dsl.tasks import Task, make_task

METRIC_FIELDS = (
    "generation",
    "phase",
    "alpha",
    "event",
    "evaluations",
    "reevaluations",
    "coverage",
    "max_fitness",
    "qd_score",
    "non_finite",
)
"""Columns of metrics.csv; `event` is init, train, reevaluate or reseed."""

__all__ = ["METRIC_FIELDS", "MetricsLog", "RunError", "RunResult", "prepare_run_directory", "run_experiment"]


@dataclass(frozen=True)
class RunResult:
    """What a finished run returns: its final archive, its metrics log and where it is."""

    repertoire: Any  # qdax MapElitesRepertoire
    metrics: list[dict[str, Any]]
    config: RunConfig
    alphas: np.ndarray
    out_dir: Path | None
    seconds: float

    @property
    def final(self) -> dict[str, Any]:
        return self.metrics[-1]


def schedule_key(seed: int) -> jax.Array:
    """The key a run draws its schedule's random segments from (one per seed)."""
    return jax.random.fold_in(jax.random.key(seed), 0x5CED)


def start_key(seed: int) -> jax.Array:
    """The key a run's deterministic episode start is drawn from (one per seed)."""
    return jax.random.fold_in(jax.random.key(seed), 0x7A5C)


def metrics_row(
    state: RunState, metrics: dict[str, jax.Array], alpha: float, event: str, evaluation: Evaluation
) -> dict[str, Any]:
    return {
        "generation": state.generation,
        "phase": state.phase,
        "alpha": float(alpha),
        "event": event,
        "evaluations": state.evaluations,
        "reevaluations": state.reevaluations,
        "coverage": float(metrics["coverage"]),
        "max_fitness": float(metrics["max_fitness"]),
        "qd_score": float(metrics["qd_score"]),
        "non_finite": evaluation.non_finite,
    }


class MetricsLog:
    """metrics.csv, appended row by row.

    It starts as exactly the rows of the checkpoint the run starts from, written atomically
    (on resume: rows written after that checkpoint are dropped, and a deleted metrics.csv
    comes back), so a resumed run's metrics.csv never repeats a row. An error names the file.
    """

    def __init__(self, path: Path | None, rows: list[dict[str, Any]]) -> None:
        self.path = path
        if path is not None:
            text = io.StringIO(newline="")
            writer = csv.DictWriter(text, METRIC_FIELDS)
            writer.writeheader()
            writer.writerows(rows)
            atomic_write(path, lambda file: file.write(text.getvalue().encode()))

    def append(self, row: dict[str, Any]) -> None:
        if self.path is not None:
            try:
                with open(self.path, "a", newline="") as file:
                    csv.DictWriter(file, METRIC_FIELDS).writerow(row)
            except OSError as error:  # a full disk fails on close, with no file name
                raise OSError(error.errno, error.strerror or str(error), str(self.path)) from error


def run_experiment(
    task: Task | str,
    schedule: Schedule,
    config: RunConfig,
    *,
    out_dir: str | Path | None = None,
    resume: bool = False,
    progress: Callable[[dict[str, Any], int], None] | None = None,
    stop_after_generation: int | None = None,
) -> RunResult:
    """Run phased MAP-Elites of `task` under `schedule`; return the archive and metrics.

    With `out_dir`, writes the run directory (config, schedule, certificate, metrics.csv,
    checkpoints, and at the end archive.npz and figures), locked for the run's duration;
    with `resume`, continues from its last checkpoint. `progress(row, total_generations)` is
    called after every row. `stop_after_generation` stops early (as an interruption would),
    for tests. A directory that cannot be used, a damaged checkpoint or a disk that cannot be
    written is a RunError that names the file and says what to do.
    """
    started = time.perf_counter()
    directory = out_path(out_dir)
    fit_sweep(config, 1, [config.seed], jax.devices()[:1])  # refuses a run that cannot fit, before compiling
    if isinstance(task, str):
        task = make_task(
            task,
            episode_length=config.episode_length,
            hidden_layer_sizes=config.hidden_layer_sizes,
            init_key=start_key(config.seed),
        )
    with contextlib.ExitStack() as held:
        if directory is not None:  # locked until the run returns: one process at a time
            held.enter_context(prepare_run_directory(directory, schedule, config, resume))

        algorithm = phased_map_elites(
            task.scoring_fn(),
            task.init_policies,
            config.batch_size,
            task.qd_offset,
            config.iso_sigma,
            config.line_sigma,
        )
        key = jax.random.key(config.seed)
        key, cvt_key, init_key = jax.random.split(key, 3)
        centroids = cvt_centroids(
            config.num_centroids, task.descriptor_low, task.descriptor_high, config.num_init_cvt_samples, cvt_key
        )
        alphas = schedule.checked_phase_alphas(config.num_phases, schedule_key(config.seed))

        state, owner = None, run_owner(config, schedule)
        if directory is not None and resume:
            template = task.init_policies(jax.random.key(0), 1)
            state = load_checkpoint(directory, template, config.num_centroids, centroids.shape[-1], owner)
        if directory is not None:  # from here on, a file that cannot be written says the checkpoint is intact
            held.enter_context(storage_errors(directory / CHECKPOINT))
        if state is None:
            repertoire, emitter_state, metrics, evaluation = algorithm.init(centroids, jnp.float32(alphas[0]), init_key)
            state = RunState(repertoire, emitter_state, key, 0, 0, evaluation.evaluated, 0, evaluation.non_finite, [])
            state.rows.append(metrics_row(state, metrics, alphas[0], "init", evaluation))
            if directory is not None:
                save_checkpoint(directory, state, owner)
        log = MetricsLog(directory / "metrics.csv" if directory is not None else None, state.rows)
        total = config.generations
        if progress is not None:
            for row in state.rows:
                progress(row, total)

        def record(metrics: dict[str, jax.Array], event: str, evaluation: Evaluation) -> None:
            row = metrics_row(state, metrics, alphas[state.phase], event, evaluation)
            state.rows.append(row)
            log.append(row)
            if progress is not None:
                progress(row, total)

        with CheckpointWriter() as writer:  # checkpoints reach the disk while training goes on
            for generation in range(state.generation + 1, total + 1):
                if stop_after_generation is not None and state.generation >= stop_after_generation:
                    break
                phase = config.phase_of_generation(generation)
                if phase != state.phase:
                    state.key, key = jax.random.split(state.key)
                    state.repertoire, evaluation = algorithm.reevaluate(
                        state.repertoire, jnp.float32(alphas[phase]), schedule.extinction, key
                    )
                    state.phase = phase
                    state.reevaluations += evaluation.evaluated
                    state.non_finite += evaluation.non_finite
                    record(algorithm.metrics(state.repertoire), "reevaluate", evaluation)
                    if directory is not None:
                        writer.offer(directory / CHECKPOINT, partial(checkpoint_arrays, state, owner))
                state.key, key = jax.random.split(state.key)
                empty = not bool(jnp.any(state.repertoire.fitnesses > -jnp.inf))
                step = algorithm.reseed if empty else algorithm.generation
                state.repertoire, state.emitter_state, metrics, evaluation = step(
                    state.repertoire, state.emitter_state, jnp.float32(alphas[phase]), key
                )
                state.generation = generation
                state.evaluations += evaluation.evaluated
                state.non_finite += evaluation.non_finite
                record(metrics, "reseed" if empty else "train", evaluation)

        if directory is not None and state.generation >= total:
            finish_run_directory(directory, state, task, config, schedule)
    return RunResult(state.repertoire, state.rows, config, alphas, directory, time.perf_counter() - started)


@contextlib.contextmanager
def storage_errors(checkpoint: Path) -> Iterator[None]:
    """Turn an OSError from writing a run's files (a full disk, a file system gone read-only)
    into a RunError that names the file and says that `checkpoint` is intact to --resume from."""
    try:
        yield
    except OSError as error:
        raise storage_error(error, checkpoint, fallback=checkpoint.parent) from None


def out_path(out_dir: str | Path | None) -> Path | None:
    """out_dir as a Path, refusing an empty one (which would silently mean the current directory)."""
    if out_dir is None:
        return None
    if str(out_dir) == "" or (isinstance(out_dir, str) and not out_dir.strip()):
        raise RunError("--out: empty path; give the directory to write the run to (or leave --out out)")
    if "\0" in str(out_dir):
        raise RunError(f"--out {str(out_dir)!r}: a path cannot hold a NUL character")
    return Path(out_dir)


def finish_run_directory(directory: Path, state: RunState, task: Task, config: RunConfig, schedule: Schedule) -> None:
    """Mark the run finished in its checkpoint and write archive.npz and the figures."""
    if not state.finished:
        state.finished = True
        save_checkpoint(directory, state, run_owner(config, schedule))
    save_archive(directory / "archive.npz", state.repertoire)
    from smol_dsl.runner.figures import save_run_figures

    save_run_figures(directory, state.rows, state.repertoire, task, config, schedule)


OPTIONS = {
    "task": "TASK",
    "evaluations": "--evals",
    "batch_size": "--batch-size",
    "num_phases": "--phases",
    "num_centroids": "--centroids",
    "episode_length": "--episode-length",
    "seed": "--seed",
    "preset": "--preset",
}
"""The command-line option that sets each RunConfig field; the preset sets the others."""


def prepare_run_directory(directory: Path, schedule: Schedule, config: RunConfig, resume: bool) -> DirectoryLock:
    """Check a directory to resume, or create one and write the run's settings into it.

    Returns the directory's lock, held: the caller releases it when the run ends (it is a
    context manager). A second process on the same directory is refused with a RunError.
    """
    check_out_dir(directory)
    if resume:
        return _resume_run_directory(directory, schedule, config)
    if non_empty(directory):
        raise RunError(f"{directory} already exists and is not empty; use --resume to continue it or another --out")
    make_directory(directory, "run")
    lock = lock_directory(directory, "run", resume=False)
    try:
        if non_empty(directory):  # another process set it up since we looked
            raise RunError(f"{directory} already exists and is not empty; use --resume to continue it or another --out")
        certificate = {
            "name": schedule.name,
            "tail_start": float(schedule.tail_start),
            **schedule.certificate.to_dict(),
        }
        write_new_files(
            directory,
            {
                "config.json": config.to_json(),
                "schedule.sched": schedule.source,
                "certificate.json": json.dumps(certificate, indent=2),
                "certificate.txt": str(schedule.certificate),
            },
        )
    except BaseException:
        lock.release()
        raise
    return lock


def _resume_run_directory(directory: Path, schedule: Schedule, config: RunConfig) -> DirectoryLock:
    config_path = directory / "config.json"
    if not config_path.is_file():
        if (directory / "sweep.json").is_file():
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
                + "; ".join(differences)
            )
        schedule_path = directory / "schedule.sched"
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
        remove_stale_temporaries(directory)
    except BaseException:
        lock.release()
        raise
    return lock


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


def write_new_files(directory: Path, texts: dict[str, str]) -> None:
    """Write each text atomically as directory/name; if one fails (a full disk), remove those
    written and raise a RunError naming the file: nothing is left half set up."""
    written: list[Path] = []
    try:
        for name, text in texts.items():
            atomic_write(directory / name, lambda file, text=text: file.write(text.encode()))
            written.append(directory / name)
    except OSError as error:
        for path in written:
            with contextlib.suppress(OSError):
                path.unlink()
        target, reason, fix = write_failure(error, fallback=directory)
        raise RunError(
            f"cannot write {target}: {reason}; nothing was started: {fix}, then run the command again"
        ) from None


def read_json_object(path: Path, what: str) -> dict[str, Any]:
    """The JSON object in path (a run's config.json, a sweep's sweep.json), or a RunError
    that names the file as damaged."""
    try:
        data = json.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError) as error:
        data, problem = None, f"not JSON: {error}"
    else:
        problem = "not a JSON object"
    if not isinstance(data, dict):
        raise RunError(
            f"{path} is damaged ({problem}); it records the settings the {what} was started with, so the {what} "
            f"cannot be resumed without it: put back a good copy, or start the {what} afresh in another --out"
        )
    return data


_MISSING = object()


def setting_differences(saved: dict[str, Any], requested: dict[str, Any], what: str) -> list[str]:
    """One line per setting that differs between a saved config.json and the one requested,
    naming the option: "--batch-size: the run was started with 64, not 128"."""
    order = [field.name for field in dataclasses.fields(RunConfig)]
    names = order + sorted((set(saved) | set(requested)) - set(order))
    lines = []
    for name in names:
        old, new = saved.get(name, _MISSING), requested.get(name, _MISSING)
        if old == new:
            continue
        option = OPTIONS.get(name, f"{name} (set by --preset)")
        lines.append(f"{option}: the {what} was started with {_shown(old)}, not {_shown(new)}")
    return lines


def _shown(value: Any) -> str:
    if value is _MISSING:
        return "no such setting"
    if isinstance(value, list):
        return "[" + ", ".join(str(v) for v in value) + "]"
    return str(value)


_TEMPORARY = re.compile(r".+\.\d+\.tmp")


def remove_stale_temporaries(directory: Path, prefix: str = "") -> None:
    """Delete the temporary files a killed process left in a directory this process has
    locked (a checkpoint's can be as big as the checkpoint)."""
    for path in directory.iterdir():
        if path.name.startswith(prefix) and _TEMPORARY.fullmatch(path.name) and path.is_file():
            with contextlib.suppress(OSError):
                path.unlink()


def alpha_one_evaluations(rows: list[dict[str, Any]], first_tail_phase: int) -> float | None:
    """Training evaluations at the start of the first phase of the alpha = 1 tail."""
    for row in rows:
        if row["phase"] >= first_tail_phase:
            return float(row["evaluations"])
    return None


def format_duration(seconds: float) -> str:
    minutes, whole = divmod(math.ceil(seconds), 60)
    return f"{minutes}m{whole:02d}s" if minutes else f"{whole}s"
