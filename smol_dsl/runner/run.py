"""The phased MAP-Elites run: `run_experiment(task, schedule, config)`, resumable.

Phase k of N trains at alpha_k = schedule.phase_alpha(k, N). At each phase boundary the
whole archive is re-evaluated under the new alpha, thinned by the schedule's extinction
probability and re-inserted into a fresh archive; a checkpoint is written atomically right
after, so an interrupted run resumes from its last boundary and ends with exactly the
archive and metrics of an uninterrupted run of the same seed.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl.errors import UserInputError
from smol_dsl.runner.algorithm import Evaluation, cvt_centroids, phased_map_elites
from smol_dsl.runner.checkpoint import (
    CHECKPOINT,
    CheckpointWriter,
    RunState,
    atomic_write,
    checkpoint_arrays,
    load_checkpoint,
    save_archive,
    save_checkpoint,
)
from smol_dsl.runner.config import RunConfig
from smol_dsl.runner.footprint import fit_sweep
from smol_dsl.schedule import Schedule
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


class RunError(UserInputError):
    """A run that cannot start: bad settings, or an output directory that would be lost."""


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
    """metrics.csv, appended row by row; rewritten from the checkpoint on resume."""

    def __init__(self, path: Path | None, rows: list[dict[str, Any]]) -> None:
        self.path = path
        if path is not None:
            with open(path, "w", newline="") as file:
                writer = csv.DictWriter(file, METRIC_FIELDS)
                writer.writeheader()
                writer.writerows(rows)

    def append(self, row: dict[str, Any]) -> None:
        if self.path is not None:
            with open(self.path, "a", newline="") as file:
                csv.DictWriter(file, METRIC_FIELDS).writerow(row)


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
    checkpoints, and at the end archive.npz and figures); with `resume`, continues from its
    last checkpoint. `progress(row, total_generations)` is called after every row.
    `stop_after_generation` stops early (as an interruption would), for tests.
    """
    started = time.perf_counter()
    fit_sweep(config, 1, [config.seed], jax.devices()[:1])  # refuses a run that cannot fit, before compiling
    if isinstance(task, str):
        task = make_task(
            task,
            episode_length=config.episode_length,
            hidden_layer_sizes=config.hidden_layer_sizes,
            init_key=start_key(config.seed),
        )
    directory = Path(out_dir) if out_dir is not None else None
    if directory is not None:
        prepare_run_directory(directory, schedule, config, resume)

    algorithm = phased_map_elites(
        task.scoring_fn(), task.init_policies, config.batch_size, task.qd_offset, config.iso_sigma, config.line_sigma
    )
    key = jax.random.key(config.seed)
    key, cvt_key, init_key = jax.random.split(key, 3)
    centroids = cvt_centroids(
        config.num_centroids, task.descriptor_low, task.descriptor_high, config.num_init_cvt_samples, cvt_key
    )
    alphas = np.asarray(schedule.phase_alphas(config.num_phases, schedule_key(config.seed)))

    state = None
    if directory is not None and resume:
        template = task.init_policies(jax.random.key(0), 1)
        state = load_checkpoint(directory, template)
    if state is None:
        repertoire, emitter_state, metrics, evaluation = algorithm.init(centroids, jnp.float32(alphas[0]), init_key)
        state = RunState(repertoire, emitter_state, key, 0, 0, evaluation.evaluated, 0, evaluation.non_finite, [])
        state.rows.append(metrics_row(state, metrics, alphas[0], "init", evaluation))
        if directory is not None:
            save_checkpoint(directory, state)
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
                    writer.offer(directory / CHECKPOINT, partial(checkpoint_arrays, state))
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


def finish_run_directory(directory: Path, state: RunState, task: Task, config: RunConfig, schedule: Schedule) -> None:
    """Mark the run finished in its checkpoint and write archive.npz and the figures."""
    if not state.finished:
        state.finished = True
        save_checkpoint(directory, state)
    save_archive(directory / "archive.npz", state.repertoire)
    from smol_dsl.runner.figures import save_run_figures

    save_run_figures(directory, state.rows, state.repertoire, task, config, schedule)


def prepare_run_directory(directory: Path, schedule: Schedule, config: RunConfig, resume: bool) -> None:
    """Check a directory to resume, or create one and write the run's settings into it."""
    config_path = directory / "config.json"
    if resume:
        if not config_path.is_file():
            raise RunError(f"{directory} holds no run to resume (no config.json); start it without --resume")
        saved = RunConfig.from_json(config_path.read_text())
        if saved != config:
            raise RunError(
                f"{directory} was started with different settings; resume it with the same ones "
                f"(saved: {saved.to_json()})"
            )
        saved_schedule = (directory / "schedule.sched").read_text()
        if saved_schedule != schedule.source:
            raise RunError(f"{directory} was started with a different schedule")
        return
    if directory.exists() and any(directory.iterdir()):
        raise RunError(f"{directory} already exists and is not empty; use --resume to continue it or another --out")
    directory.mkdir(parents=True, exist_ok=True)
    atomic_write(config_path, lambda f: f.write(config.to_json().encode()))
    atomic_write(directory / "schedule.sched", lambda f: f.write(schedule.source.encode()))
    certificate = {"name": schedule.name, "tail_start": float(schedule.tail_start), **schedule.certificate.to_dict()}
    atomic_write(directory / "certificate.json", lambda f: f.write(json.dumps(certificate, indent=2).encode()))
    atomic_write(directory / "certificate.txt", lambda f: f.write(str(schedule.certificate).encode()))


def alpha_one_evaluations(rows: list[dict[str, Any]], first_tail_phase: int) -> float | None:
    """Training evaluations at the start of the first phase of the alpha = 1 tail."""
    for row in rows:
        if row["phase"] >= first_tail_phase:
            return float(row["evaluations"])
    return None


def format_duration(seconds: float) -> str:
    minutes, whole = divmod(math.ceil(seconds), 60)
    return f"{minutes}m{whole:02d}s" if minutes else f"{whole}s"
