"""The phase loop: runs trained together on the engine, logged, checkpointed, resumable.

`train` is what `run_experiment` (one run) and `run_sweep` (many) both do once their
directories are set up. Phase k of N trains in the body of each run's schedule at phase k:
every scheduled channel's factor at t = k / N (`Schedule.checked_phase_values`; `(GEAR,)`,
the paper's alpha, for a file that declares no channels), a traced (channels,) array per
run. At each phase boundary every archive is re-evaluated under its new body, thinned by
its schedule's extinction probability and re-inserted into a fresh archive; a checkpoint
is handed to the background writer right after, so an interrupted training resumes from
its last boundary and ends with exactly the archives and metrics of an uninterrupted one.
The next boundary waits for that write to end (when a whole phase was not long enough for
it), so that no host copy of the archives is alive while they are held twice: at most two
sets of archives are in memory at any time, what `footprint` sizes."""

from __future__ import annotations

import contextlib
import functools
import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl import rundir
from smol_dsl.errors import Setting
from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.rundir import CHECKPOINT_FILE, MetricsLog
from smol_dsl.runner.checkpoint import (
    CheckpointWriter,
    RunState,
    archive_arrays,
    checkpoint_arrays,
    load_checkpoint,
    save_checkpoint,
    stacked_checkpoint,
    storage_error,
)
from smol_dsl.runner.config import ConfigError, RunError, check_config
from smol_dsl.runner.engine import stack_runs
from smol_dsl.runner.map_elites import cvt_centroids
from smol_dsl.seeds import schedule_key
from smol_dsl.tasks import task_spec

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.runner.engine import Engine
    from smol_dsl.tasks.base import Task

RANDOM_STREAMS = "keys split as QDax's MAPElites.update splits them"
"""How a run's key becomes its offspring's, recorded in checkpoints: a checkpoint of another
way is refused rather than resumed into a run that follows neither."""

Progress = Callable[[list[dict[str, Any]], int], None]
"""progress(the latest metrics row of every run, total generations)."""


@dataclass(frozen=True)
class PlannedRun:
    """One run to train: its schedule, settings (with its seed), name and run directory."""

    schedule: Schedule
    config: RunConfig
    name: str
    directory: Path | None = None


@dataclass(frozen=True)
class RunResult:
    """What a finished run returns: its final archive, its metrics log, the body it trained in
    at every phase and where it is."""

    repertoire: Any  # qdax MapElitesRepertoire
    metrics: list[dict[str, Any]]
    config: RunConfig
    bodies: np.ndarray  # (phases, channels): the body of every phase, a factor per channel
    channels: tuple[Channel, ...]  # the schedule's channels, the columns of `bodies`
    out_dir: Path | None
    seconds: float

    @property
    def final(self) -> dict[str, Any]:
        return self.metrics[-1]

    @property
    def alphas(self) -> np.ndarray:
        """(phases,): plain gear's factor per phase, the paper's alpha (1 when not scheduled)."""
        if GEAR in self.channels:
            return self.bodies[:, self.channels.index(GEAR)]
        return np.ones(len(self.bodies), self.bodies.dtype)


def run_channels(schedules: list[Schedule]) -> tuple[Channel, ...]:
    """Every channel the schedules declare, in order of first appearance: the traced body of
    runs trained together (a run's value for a channel its schedule lacks is 1)."""
    return tuple(dict.fromkeys(channel for schedule in schedules for channel in schedule.channels))


def check_runs(task: Task | str, schedules: list[Schedule], config: RunConfig) -> None:
    """What `smol-dsl run` and `sweep` refuse, refused for the Python API alike, before anything
    is created or compiled: a located ScheduleError for a schedule whose channels name parts
    the task's body lacks, a ConfigError (`check_config`) for settings that cannot make a fair
    run, and one for a task that is not the config's (its name or episode length)."""
    spec = task_spec(task) if isinstance(task, str) else task.spec
    if spec.name != config.task:
        raise ConfigError(
            f"the task is {spec.name} but the config's is {config.task}; make the config for {spec.name} "
            f"(preset_config({spec.name!r}, ...)) or pass task={config.task!r}"
        )
    if not isinstance(task, str) and task.episode_length != config.episode_length:
        raise ConfigError(
            f"the task's episodes are {task.episode_length} steps but the config's "
            + Setting("episode_length")
            + f" is {config.episode_length}; build the task with the config's, or pass the task by name"
        )
    for schedule in schedules:
        check_config(config, schedule)  # the schedule against the task's body too: the config's task is this one


def owner(runs: list[PlannedRun], config: RunConfig) -> dict[str, Any]:
    """What a checkpoint records about the runs it holds: the shared settings, and each
    run's seed and schedule text, so that a checkpoint of other runs is refused."""
    shared = json.loads(config.to_json())
    del shared["seed"]
    return {
        "config": shared,
        "runs": [{"seed": run.config.seed, "schedule": run.schedule.source} for run in runs],
        "random_streams": RANDOM_STREAMS,
    }


def metrics_row(
    state: RunState,
    metrics: dict[str, float],
    body: dict[str, float],
    event: str,
    non_finite: int,
    schema: rundir.MetricsSchema = rundir.METRICS_SCHEMA,
    reevaluation: dict[str, int] | None = None,
) -> dict[str, Any]:
    """The metrics.csv row of a run's state after an event; `body` holds the body's columns
    (`rundir.body_columns`: `alpha`, and a factor per other channel of the run's schedule),
    `reevaluation` a re-evaluation's counts (`rundir.REEVALUATION_FIELDS`; empty otherwise)."""
    counts = reevaluation or dict.fromkeys(rundir.REEVALUATION_FIELDS)
    return rundir.metrics_row(
        schema,
        generation=state.generation,
        phase=state.phase,
        **body,
        event=event,
        evaluations=state.evaluations,
        reevaluations=state.reevaluations,
        coverage=metrics["coverage"],
        max_fitness=metrics["max_fitness"],
        qd_score=metrics["qd_score"],
        non_finite=non_finite,
        **counts,
    )


@contextlib.contextmanager
def storage_errors(checkpoint: Path) -> Iterator[None]:
    """Turn an OSError from writing a run's files (a full disk, a file system gone read-only)
    into a RunError that names the file and says that `checkpoint` is intact to --resume from."""
    try:
        yield
    except OSError as error:
        raise storage_error(error, checkpoint, fallback=checkpoint.parent) from None


class Training:
    """Runs of one task and settings trained together on an engine, generation by generation.

    All runs reach their phase boundaries together. Per run: its own seed (CVT centroids,
    episode start, keys), schedule (its body per phase, extinction) and archive; the batched
    arrays (archives, keys, bodies, starts) have the runs axis first, padded to the engine's
    runs axis with copies of the last run whose results are dropped. A body has a factor for
    each of `channels` (`run_channels` of the runs' schedules; 1 for a channel a run's
    schedule lacks), the engine's task's channels.
    """

    def __init__(
        self,
        engine: Engine,
        task: Task,
        runs: list[PlannedRun],
        config: RunConfig,
        checkpoint: Path | None,
        progress: Progress | None = None,
        channels: tuple[Channel, ...] | None = None,
    ) -> None:
        self.engine, self.task, self.runs, self.config = engine, task, runs, config
        self.checkpoint, self.progress = checkpoint, progress
        self.owner = owner(runs, config)
        self.channels = channels if channels is not None else run_channels([run.schedule for run in runs])
        padded = runs + [runs[-1]] * (engine.padded_runs(len(runs)) - len(runs))
        seeds = [run.config.seed for run in padded]
        self.bodies = np.stack(  # (runs, phases, channels)
            [
                run.schedule.checked_phase_values(config.num_phases, schedule_key(run.config.seed), self.channels)
                for run in padded
            ]
        )
        self._placed_bodies: tuple[int, jax.Array | None] = (-1, None)  # the phase whose bodies are on the devices
        self.schemas = [rundir.metrics_schema(run.schedule.channels) for run in runs]
        # each run's own bodies, the columns of its schedule's channels (its metrics.csv columns and result)
        self._own_bodies = [
            self.bodies[r][:, [self.channels.index(c) for c in run.schedule.channels]] for r, run in enumerate(runs)
        ]
        self.extinctions = engine.put(jnp.asarray([run.schedule.extinction for run in padded], dtype=jnp.float32))
        self._seeds = seeds
        self._phase_evaluations = np.zeros(len(runs), dtype=np.int64)  # the current phase's training batches
        self._phase_non_finite = np.zeros(len(runs), dtype=np.int64)  # ... and how many of them were non-finite
        self.repertoires: Any = None
        self.keys: Any = None
        self.states: list[RunState] = []
        self.logs: list[MetricsLog] = []

    @functools.cached_property
    def starts(self) -> Any:
        """Every run's episode start, on the devices; made when first needed (a finished run
        resumed needs none: making them is most of what such a resume would cost)."""
        starts = {seed: self.task.episode_start(seed) for seed in dict.fromkeys(self._seeds)}
        return self.engine.put(stack_runs([starts[seed] for seed in self._seeds]))

    # ------------------------------------------------------------------ start
    def start(self, saved: tuple[Any, Any, list[RunState]] | None) -> None:
        """Continue from a loaded checkpoint, or score every run's initial population; then
        (re)write every run's metrics.csv."""
        if saved is not None:
            repertoires, keys, self.states = saved
            extra = len(self._seeds) - len(self.runs)

            def placed(x: jax.Array) -> jax.Array:  # leaf by leaf: at most one leaf's padded copy more
                return self.engine.put(jnp.concatenate([x] + [x[-1:]] * extra) if extra else x)

            self.repertoires, self.keys = jax.tree.map(placed, (repertoires, keys))
        else:
            self._initial_population()
        self.logs = [
            MetricsLog(run.directory / rundir.METRICS_FILE if run.directory is not None else None, state.rows, schema)
            for run, state, schema in zip(self.runs, self.states, self.schemas, strict=True)
        ]
        self._show()

    def load(self) -> tuple[Any, Any, list[RunState]] | None:
        """The checkpoint's archives, keys and states, or None if there is none yet; a
        RunError for a damaged one or one of other runs."""
        if self.checkpoint is None:
            return None
        template = self.task.init_policies(jax.random.key(0), 1)
        return load_checkpoint(
            self.checkpoint, template, len(self.runs), self.config.num_centroids, self.task.descriptor_size, self.owner
        )

    def _initial_population(self) -> None:
        main_keys, init_keys, centroids = [], [], {}
        for seed in self._seeds:
            key, cvt_key, init_key = jax.random.split(jax.random.key(seed), 3)
            main_keys.append(key)
            init_keys.append(init_key)
            if seed not in centroids:
                centroids[seed] = cvt_centroids(
                    self.config.num_centroids,
                    self.task.descriptor_low,
                    self.task.descriptor_high,
                    self.config.num_init_cvt_samples,
                    cvt_key,
                )
        archives = self.engine.empty_archives(jnp.stack([centroids[seed] for seed in self._seeds]))
        self.repertoires, metrics, dropped, _ = self.engine.step(
            archives, self._bodies_of(0), self.starts, self.engine.put(jnp.stack(init_keys))
        )
        self.keys = self.engine.put(jnp.stack(main_keys))
        batch = self.config.batch_size
        self.states = []
        for r in range(len(self.runs)):
            state = RunState(0, 0, batch, 0, int(dropped[r]), [])
            row = metrics_row(state, _run_metrics(metrics, r), self._columns(r, 0), "init", dropped[r], self.schemas[r])
            state.rows.append(row)
            self.states.append(state)
        if self.checkpoint is not None:
            save_checkpoint(self.checkpoint, self.repertoires, self.keys, self.states, self.owner)

    # ------------------------------------------------------------------ training
    def train(self, stop_after_generation: int | None = None) -> None:
        """Train every run to the end of its budget (or to `stop_after_generation`, as an
        interruption would stop it, for tests); checkpoints reach the disk meanwhile."""
        with CheckpointWriter() as writer:
            for generation in range(self.states[0].generation + 1, self.config.generations + 1):
                if stop_after_generation is not None and generation > stop_after_generation:
                    break
                phase = self.config.phase_of_generation(generation)
                if phase != self.states[0].phase:
                    self.check_phase()
                    # the last checkpoint's host copy is let go before the archives are held
                    # twice, so that memory never holds both (the sizing counts on it)
                    writer.flush()
                    self.reevaluate(phase)
                    if self.checkpoint is not None:
                        arrays = partial(checkpoint_arrays, self.repertoires, self.keys, self.states, self.owner)
                        writer.offer(self.checkpoint, arrays)
                self.generation(generation, phase)
            if self.finished:
                self.check_phase()

    def check_phase(self) -> None:
        """Stop with a RunError if, in the phase that is ending, every evaluation of a run was
        NaN or infinite: the physics cannot simulate the run's body, and its archive would
        learn nothing (the checkpoint of the phase's start is kept). Then count afresh."""
        for r, run in enumerate(self.runs):
            evaluated, lost = int(self._phase_evaluations[r]), int(self._phase_non_finite[r])
            if evaluated and lost == evaluated:
                phase = self.states[r].phase
                body = ", ".join(f"{name} {value:.4g}" for name, value in self._columns(r, phase).items())
                raise RunError(
                    f"{run.name}: all {evaluated} evaluations of phase {phase} scored NaN or infinity, under the body "
                    f"{body}: the physics of {self.config.task} cannot simulate it, and training would go on with an "
                    f"empty archive; change the schedule (`smol-dsl check --task {self.config.task}` proves every "
                    "actuator's and link's factor within the range the task's physics takes)"
                )
        self._phase_evaluations[:] = 0
        self._phase_non_finite[:] = 0

    def reevaluate(self, phase: int) -> None:
        """Every archive re-scored in its run's body of `phase`, thinned by extinction; its
        row counts what became of the elites."""
        self.keys, subkeys = self.engine.split(self.keys)
        self.repertoires, counts = self.engine.reevaluate(
            self.repertoires, self._bodies_of(phase), self.starts, self.extinctions, subkeys
        )
        for r, state in enumerate(self.states):
            state.phase = phase
            state.reevaluations += int(counts.reevaluated[r])
            state.non_finite += int(counts.non_finite[r])
        per_run = [
            {name: int(getattr(counts, name)[r]) for name in rundir.REEVALUATION_FIELDS} for r in range(len(self.runs))
        ]
        self._record(self.engine.metrics(self.repertoires), ["reevaluate"] * len(self.runs), counts.non_finite, per_run)

    def generation(self, generation: int, phase: int) -> None:
        """One generation of every run in its body of `phase`."""
        self.keys, subkeys = self.engine.split(self.keys)
        self.repertoires, metrics, dropped, reseeded = self.engine.step(
            self.repertoires, self._bodies_of(phase), self.starts, subkeys
        )
        for r, state in enumerate(self.states):
            state.generation = generation
            state.evaluations += self.config.batch_size
            state.non_finite += int(dropped[r])
            self._phase_evaluations[r] += self.config.batch_size
            self._phase_non_finite[r] += int(dropped[r])
        self._record(metrics, ["reseed" if reseeded[r] else "train" for r in range(len(self.runs))], dropped)

    def _bodies_of(self, phase: int) -> jax.Array:
        """Every run's body in `phase`: (runs, channels) float32, put on the devices once a
        phase rather than every generation."""
        if self._placed_bodies[0] != phase:
            self._placed_bodies = (phase, self.engine.put(jnp.asarray(self.bodies[:, phase], dtype=jnp.float32)))
        return self._placed_bodies[1]

    def _columns(self, run: int, phase: int) -> dict[str, float]:
        """A run's metrics.csv body columns in a phase (its schedule's channels)."""
        return rundir.body_columns(self.runs[run].schedule.channels, self._own_bodies[run][phase])

    def _record(
        self,
        metrics: dict[str, np.ndarray],
        events: list[str],
        dropped: np.ndarray,
        reevaluations: list[dict[str, int]] | None = None,
    ) -> None:
        for r, (state, log) in enumerate(zip(self.states, self.logs, strict=True)):
            columns = self._columns(r, state.phase)
            counts = reevaluations[r] if reevaluations is not None else None
            row = metrics_row(state, _run_metrics(metrics, r), columns, events[r], dropped[r], self.schemas[r], counts)
            state.rows.append(row)
            log.append(row)
        self._show()

    def _show(self) -> None:
        if self.progress is not None:
            self.progress([state.rows[-1] for state in self.states], self.config.generations)

    # ------------------------------------------------------------------ end
    @property
    def finished(self) -> bool:
        return self.states[0].generation >= self.config.generations

    def results(self, started: float) -> list[RunResult]:
        """Every run's result; when training is finished, its run directory gets archive.npz
        and, the first time, its checkpoint marked finished (and so does a sweep's own
        checkpoint)."""
        newly_finished = self.finished and not all(state.finished for state in self.states)
        if newly_finished:
            for state in self.states:
                state.finished = True
        run_checkpoints = {run.directory / CHECKPOINT_FILE for run in self.runs if run.directory is not None}
        if newly_finished and self.checkpoint is not None and self.checkpoint not in run_checkpoints:
            # a sweep's own checkpoint first, before every run's archive is also held apart
            save_checkpoint(self.checkpoint, self.repertoires, self.keys, self.states, self.owner)
        host_keys = jax.device_get(jax.random.key_data(self.keys))
        results = []
        for r, (run, state) in enumerate(zip(self.runs, self.states, strict=True)):
            repertoire = jax.tree.map(lambda x, r=r: run_of(x, r), self.repertoires)
            if run.directory is not None and self.finished:
                arrays = archive_arrays(self.repertoires, slice(r, r + 1))  # one host copy of one run at a time
                if newly_finished:
                    single = stacked_checkpoint(arrays, host_keys[r : r + 1], [state], owner([run], run.config))
                    rundir.write_npz(run.directory / CHECKPOINT_FILE, single)
                rundir.write_archive(
                    run.directory / rundir.ARCHIVE_FILE, {name: values[0] for name, values in arrays.items()}
                )
            seconds = time.perf_counter() - started
            results.append(
                RunResult(
                    repertoire,
                    state.rows,
                    run.config,
                    self._own_bodies[r],
                    run.schedule.channels,
                    run.directory,
                    seconds,
                )
            )
        return results


def run_of(stacked: jax.Array, run: int) -> jax.Array:
    """One run's slice of an array stacked along the runs axis, on the one device that holds
    it (`stacked[run]` would be a program whose result every device of the mesh holds a copy
    of)."""
    for shard in stacked.addressable_shards:
        first, last, _ = shard.index[0].indices(stacked.shape[0])
        if first <= run < last:
            return shard.data[run - first]
    return stacked[run]


def _run_metrics(metrics: dict[str, np.ndarray], run: int) -> dict[str, float]:
    return {name: float(values[run]) for name, values in metrics.items()}


def train(
    engine: Engine,
    task: Task,
    runs: list[PlannedRun],
    config: RunConfig,
    *,
    checkpoint: Path | None,
    resume: bool,
    progress: Progress | None,
    stop_after_generation: int | None,
    started: float,
) -> list[RunResult]:
    """Train `runs` together from scratch or from `checkpoint`; return one result per run.
    From the first checkpoint on, a file that cannot be written is a RunError that says the
    last checkpoint is intact."""
    training = Training(engine, task, runs, config, checkpoint, progress, engine.channels)
    saved = training.load() if resume else None
    with storage_errors(checkpoint) if checkpoint is not None else contextlib.nullcontext():
        training.start(saved)
        training.train(stop_after_generation)
        return training.results(started)
