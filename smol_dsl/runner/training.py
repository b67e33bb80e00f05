"""The host loop: runs trained together by the core, logged, checkpointed, resumable.

`train` is what `run_experiment` (one run) and `run_sweep` (many) both do once their
directories are set up. The algorithm is `smol_dsl.runner.core`'s (pure functions on one
state of every run); `HostLoop` sequences them and does every side effect: each run's
metrics.csv rows and the progress after every step, its archive's snapshots at every phase's
start and end (phases.npz, rewritten at each boundary), a checkpoint handed to the background
writer right after each phase boundary (so an interrupted training resumes from its last
boundary and ends with exactly the archives and metrics of an uninterrupted one), and at
the end the runs' results and final archives. The next boundary waits for the write in
flight to end (when a whole phase was not long enough for it), so that no host copy of
the archives is alive while they are held twice: at most two sets of archives are in
memory at any time, what `footprint` sizes.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from smol_dsl import rundir
from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.qdax.phases import phase_of_generation
from smol_dsl.rundir import CHECKPOINT_FILE, MetricsLog
from smol_dsl.rundir.checkpoint import RunState, checkpoint_contents
from smol_dsl.rundir.snapshots import END, START, Snapshot, read_snapshots, snapshots_until, write_snapshots
from smol_dsl.runner import pacing
from smol_dsl.runner.checkpoint import (
    CheckpointWriter,
    archive_arrays,
    checkpoint_arrays,
    load_checkpoint,
    save_checkpoint,
    storage_error,
)
from smol_dsl.runner.config import RunError
from smol_dsl.runner.core import (
    Course,
    Outcome,
    TrainingState,
    cross_boundary,
    failed_runs,
    plan_course,
    restore,
    start,
    train_generation,
)

if TYPE_CHECKING:
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.runner.engine import Engine
    from smol_dsl.runner.plan import PlannedRun

RANDOM_STREAMS = "keys split as QDax's MAPElites.update splits them"
"""How a run's key becomes its offspring's, recorded in checkpoints: a checkpoint of another
way is refused rather than resumed into a run that follows neither."""

Progress = Callable[[list[dict[str, Any]], int], None]
"""progress(the latest metrics row of every run, total generations)."""


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


@contextlib.contextmanager
def storage_errors(checkpoint: Path) -> Iterator[None]:
    """Turn an OSError from writing a run's files (a full disk, a file system gone read-only)
    into a RunError that names the file and says that `checkpoint` is intact to --resume from."""
    try:
        yield
    except OSError as error:
        raise storage_error(error, checkpoint, fallback=checkpoint.parent) from None


class HostLoop:
    """The side effects around the core's training (`smol_dsl.runner.core`): each run's
    metrics rows (metrics.csv, appended as they come), progress, checkpoints (offered to a
    background writer after each boundary) and the runs' results and final archives."""

    def __init__(
        self,
        course: Course,
        runs: list[PlannedRun],
        config: RunConfig,
        checkpoint: Path | None,
        progress: Progress | None,
    ) -> None:
        self.course, self.runs, self.config = course, runs, config
        self.checkpoint, self.progress = checkpoint, progress
        self.owner = owner(runs, config)
        channels = course.engine.channels
        self.schemas = [rundir.schedule_schema(run.schedule) for run in runs]
        # each run's own bodies, the columns of its schedule's channels (its metrics.csv columns and result)
        self.own_bodies = [
            course.bodies[r][:, [channels.index(c) for c in run.schedule.channels]] for r, run in enumerate(runs)
        ]
        self.rows: list[list[dict[str, Any]]] = [[] for _ in runs]
        self.snapshots: list[list[Snapshot]] = [[] for _ in runs]
        self.logs: list[MetricsLog] = []
        self.was_finished = False  # resumed from the checkpoint of a finished training

    def load(self) -> tuple[Any, Any, list[RunState]] | None:
        """The checkpoint's archives, keys and states, or None if there is none yet; a
        RunDirectoryError for a damaged one or one of other runs."""
        if self.checkpoint is None:
            return None
        task = self.course.engine.task
        template = task.init_policies(jax.random.key(0), 1)
        return load_checkpoint(
            self.checkpoint, template, len(self.runs), self.config.num_centroids, task.descriptor_size, self.owner
        )

    def begin(self, state: TrainingState, saved_rows: list[list[dict[str, Any]]] | None, first: Outcome | None) -> None:
        """(Re)write every run's metrics.csv: the rows a checkpoint saved, or the initial
        population's row (then checkpointed)."""
        if saved_rows is not None:
            self.rows = [list(rows) for rows in saved_rows]
            self.snapshots = [
                snapshots_until(read_snapshots(run.directory), state.generation) if run.directory is not None else []
                for run in self.runs
            ]
        else:
            assert first is not None
            self.rows = [[self.row(state, first, r)] for r in range(len(self.runs))]
            self.snapshot(state, START)
            self.write_snapshots()
            if self.checkpoint is not None:
                save_checkpoint(self.checkpoint, state.repertoires, state.keys, self.run_states(state), self.owner)
        self.logs = [
            MetricsLog(run.directory / rundir.METRICS_FILE if run.directory is not None else None, rows, schema)
            for run, rows, schema in zip(self.runs, self.rows, self.schemas, strict=True)
        ]
        self.show()

    def row(self, state: TrainingState, outcome: Outcome, r: int) -> dict[str, Any]:
        """Run r's metrics.csv row after `outcome`."""
        event, metrics, non_finite, counts = outcome.of(r)
        return rundir.metrics_row(
            self.schemas[r],
            generation=state.generation,
            phase=state.phase,
            **self.columns(r, state),
            **pacing.development_columns(state.pace(r)),
            event=event,
            evaluations=int(state.evaluations[r]),
            reevaluations=int(state.reevaluations[r]),
            coverage=metrics["coverage"],
            max_fitness=metrics["max_fitness"],
            qd_score=metrics["qd_score"],
            non_finite=non_finite,
            **(counts or dict.fromkeys(rundir.REEVALUATION_FIELDS)),
        )

    def record(self, state: TrainingState, outcome: Outcome) -> None:
        """Every run's row after `outcome`, logged; then progress."""
        for r, (rows, log) in enumerate(zip(self.rows, self.logs, strict=True)):
            row = self.row(state, outcome, r)
            rows.append(row)
            log.append(row)
        self.show()

    def snapshot(self, state: TrainingState, moment: int) -> None:
        """Every run's archive as it is now (its fitnesses and descriptors, to the host), a
        snapshot of `moment` (`START` or `END`) of the current phase."""
        fitnesses, descriptors = jax.device_get((state.repertoires.fitnesses, state.repertoires.descriptors))
        for r, snapshots in enumerate(self.snapshots):
            cells = np.asarray(fitnesses[r]).reshape(self.config.num_centroids)
            body = self.body(r, state) if self.runs[r].schedule.is_paced else None
            snapshots.append(Snapshot(state.generation, state.phase, moment, cells, np.asarray(descriptors[r]), body))

    def write_snapshots(self) -> None:
        """Every run's phases.npz, with the snapshots taken so far."""
        for run, snapshots in zip(self.runs, self.snapshots, strict=True):
            if run.directory is not None:
                write_snapshots(run.directory, snapshots)

    def show(self) -> None:
        if self.progress is not None:
            self.progress([rows[-1] for rows in self.rows], self.config.generations)

    def columns(self, run: int, state: TrainingState) -> dict[str, float]:
        """A run's metrics.csv body columns in the state's phase (its schedule's channels):
        in a paced course, the body its clocks have reached."""
        return rundir.body_columns(self.runs[run].schedule.channels, self.body(run, state))

    def body(self, run: int, state: TrainingState) -> np.ndarray:
        """A run's body in the state's phase, (its schedule's channels,)."""
        if state.indices is None:
            return self.own_bodies[run][state.phase]
        channels = self.course.engine.channels
        own = [channels.index(c) for c in self.runs[run].schedule.channels]
        return self.course.bodies[run, state.indices[run][own], own]

    def trained_bodies(self, run: int) -> np.ndarray:
        """(phases, channels): the body a run trained in at every phase, as its rows log it
        (a paced run's realised bodies; phases not reached yet: the open-loop ones)."""
        schedule = self.runs[run].schedule
        if schedule.is_paced:
            return rundir.trained_bodies(self.own_bodies[run], schedule.channels, self.rows[run])
        return self.own_bodies[run]

    def run_states(self, state: TrainingState, finished: bool = False) -> list[RunState]:
        """What a checkpoint records of each run's progress (`RunState`)."""
        return [
            RunState(
                state.generation,
                state.phase,
                int(state.evaluations[r]),
                int(state.reevaluations[r]),
                int(state.non_finite[r]),
                self.rows[r],
                finished,
            )
            for r in range(len(self.runs))
        ]

    def check_phase(self, state: TrainingState) -> None:
        """Stop with a RunError if, in the phase that is ending, every evaluation of a run was
        NaN or infinite (`core.failed_runs`): the physics cannot simulate the run's body, and
        its archive would learn nothing (the checkpoint of the phase's start is kept)."""
        for r in failed_runs(state):
            body = ", ".join(f"{name} {value:.4g}" for name, value in self.columns(r, state).items())
            raise RunError(
                f"{self.runs[r].name}: all {int(state.phase_evaluations[r])} evaluations of phase {state.phase} scored "
                f"NaN or infinity, under the body {body}: the physics of {self.config.task} cannot simulate it, and "
                f"training would go on with an empty archive; change the schedule (`smol-dsl check --task "
                f"{self.config.task}` proves every actuator's and link's factor within the range the task's physics "
                "takes)"
            )

    def train(self, state: TrainingState, stop_after_generation: int | None = None) -> TrainingState:
        """Train every run to the end of its budget (or to `stop_after_generation`, as an
        interruption would stop it, for tests); checkpoints reach the disk meanwhile."""
        engine, course = self.course.engine, self.course
        with CheckpointWriter() as writer:
            for generation in range(state.generation + 1, self.config.generations + 1):
                if stop_after_generation is not None and generation > stop_after_generation:
                    break
                phase = phase_of_generation(generation, self.config.generations, self.config.num_phases)
                if phase != state.phase:
                    self.check_phase(state)
                    # the last checkpoint's host copy is let go before the archives are held
                    # twice, so that memory never holds both (the sizing counts on it)
                    writer.flush()
                    self.snapshot(state, END)
                    state, outcome = cross_boundary(engine, course, state, phase)
                    self.record(state, outcome)
                    self.snapshot(state, START)
                    self.write_snapshots()
                    if self.checkpoint is not None:
                        states = self.run_states(state)
                        arrays = partial(checkpoint_arrays, state.repertoires, state.keys, states, self.owner)
                        writer.offer(self.checkpoint, arrays)
                state, outcome = train_generation(engine, course, state)
                self.record(state, outcome)
            if state.generation >= self.config.generations:
                self.check_phase(state)
        return state

    def results(self, state: TrainingState, started: float) -> list[RunResult]:
        """Every run's result; when training is finished, its run directory gets archive.npz
        and, the first time, its checkpoint marked finished (and so does a sweep's own
        checkpoint)."""
        finished = state.generation >= self.config.generations
        newly_finished = finished and not self.was_finished
        last = self.snapshots[0][-1] if self.snapshots[0] else None
        if finished and (last is None or (last.moment, last.generation) != (END, state.generation)):
            self.snapshot(state, END)  # the final archive
            self.write_snapshots()
        run_checkpoints = {run.directory / CHECKPOINT_FILE for run in self.runs if run.directory is not None}
        states = self.run_states(state, finished=finished or self.was_finished)
        if newly_finished and self.checkpoint is not None and self.checkpoint not in run_checkpoints:
            # a sweep's own checkpoint first, before every run's archive is also held apart
            save_checkpoint(self.checkpoint, state.repertoires, state.keys, states, self.owner)
        host_keys = jax.device_get(jax.random.key_data(state.keys))
        results = []
        for r, (run, run_state) in enumerate(zip(self.runs, states, strict=True)):
            repertoire = jax.tree.map(lambda x, r=r: run_of(x, r), state.repertoires)
            if run.directory is not None and finished:
                arrays = archive_arrays(state.repertoires, slice(r, r + 1))  # one host copy of one run at a time
                if newly_finished:
                    single = checkpoint_contents(arrays, host_keys[r : r + 1], [run_state], owner([run], run.config))
                    rundir.write_npz(run.directory / CHECKPOINT_FILE, single)
                rundir.write_archive(
                    run.directory / rundir.ARCHIVE_FILE, {name: values[0] for name, values in arrays.items()}
                )
            seconds = time.perf_counter() - started
            results.append(
                RunResult(
                    repertoire,
                    self.rows[r],
                    run.config,
                    self.trained_bodies(r),
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


def train(
    engine: Engine,
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
    course = plan_course(engine, runs, config)
    loop = HostLoop(course, runs, config, checkpoint, progress)
    saved = loop.load() if resume else None
    with storage_errors(checkpoint) if checkpoint is not None else contextlib.nullcontext():
        if saved is not None:
            repertoires, keys, run_states = saved
            state = restore(engine, course, repertoires, keys, run_states)
            loop.was_finished = all(run.finished for run in run_states)
            loop.begin(state, [run.rows for run in run_states], None)
        else:
            state, first = start(engine, course)
            loop.begin(state, None, first)
        state = loop.train(state, stop_after_generation)
        return loop.results(state, started)
