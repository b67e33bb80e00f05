"""The runner's core: every run of a training as one immutable state, and pure functions
that start it, advance it one generation and take it across a phase boundary.

This is the whole algorithm of `smol-dsl run` and `sweep`, in QDax's style (`MAPElites`'s
pure `init` and `update` on immutable state): nothing here writes a file, logs a row or
shows progress. `smol_dsl.runner.training` is the host loop around it, which does those;
`smol_dsl.runner.estimate` times the same functions for `--dry-run`.

    course = plan_course(engine, runs, config)       # bodies, starts, extinctions: fixed
    state, outcome = start(engine, course)            # the initial population of every run
    for generation in range(1, config.generations + 1):
        phase = phase_of_generation(generation, config.generations, config.num_phases)
        if phase != state.phase:                      # a new body: re-evaluate every archive
            state, outcome = cross_boundary(engine, course, state, phase)
        state, outcome = train_generation(engine, course, state)

Pure, but not copying: the archives of the state given to `train_generation` and
`cross_boundary` are donated to XLA (updated in place, as QDax's users donate a
repertoire to a jitted update), so the state given is consumed and only the state returned
may be used afterwards; keep a host copy (`smol_dsl.runner.checkpoint.host_copy`) of any
state you need again.

The state's arrays have the runs axis first, padded to the engine's runs axis with copies
of the last run (`Course.seeds`); its counters are those of the real runs only. Every
function takes the keys as `MAPElites.update` does (`key, sub = split(key)` per generation
and per boundary), so a run's random streams do not depend on the runs trained beside it.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl.qdax.reevaluation import ReevaluationCounts
from smol_dsl.qdax.scoring import cvt_centroids, seed_keys
from smol_dsl.rundir import HOLD, REEVALUATION, REEVALUATION_FIELDS, SCORES
from smol_dsl.runner import pacing
from smol_dsl.runner.engine import stack_runs
from smol_dsl.seeds import schedule_key

if TYPE_CHECKING:
    from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire

    from smol_dsl.language.pacing import PaceState
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.checkpoint import RunState
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.runner.engine import Engine
    from smol_dsl.runner.plan import PlannedRun


@dataclass(frozen=True)
class Course:
    """What the runs train under, fixed for the whole training: each padded run's seed,
    body in every phase (`bodies`: (runs, phases, channels), the engine's channels; 1 for a
    channel a run's schedule lacks) and extinction probability, and the batch size."""

    engine: Engine
    seeds: tuple[int, ...]
    num_runs: int  # the real runs; the rest of `seeds` is padding
    bodies: np.ndarray
    extinctions: jax.Array
    batch_size: int
    num_centroids: int
    num_init_cvt_samples: int
    schedules: tuple[Schedule, ...] = ()  # each padded run's
    num_phases: int = 0
    _placed: dict[Any, jax.Array] = field(default_factory=dict, compare=False, repr=False)

    @property
    def paced(self) -> bool:
        """Whether some run's schedule waits for its archive (`pace`): its body in a phase
        then depends on its metrics, `TrainingState.indices`."""
        return any(schedule.is_paced for schedule in self.schedules)

    @functools.cached_property
    def starts(self) -> Any:
        """Every run's episode start, on the devices; made when first needed (a finished run
        resumed needs none: making them is most of what such a resume costs)."""
        task = self.engine.task
        starts = {seed: task.episode_start(seed) for seed in dict.fromkeys(self.seeds)}
        return self.engine.put(stack_runs([starts[seed] for seed in self.seeds]))

    def bodies_in(self, phase: int, indices: np.ndarray | None = None) -> jax.Array:
        """Every run's body in `phase`, (runs, channels) float32 on the devices; placed once a
        phase, not every generation. A paced course's runs read their bodies at `indices`
        (runs, channels): the open-loop phase of each run's channel (`TrainingState.indices`)."""
        key = phase if indices is None else (phase, indices.tobytes())
        if key not in self._placed:
            self._placed.clear()
            if indices is None:
                values = self.bodies[:, phase]
            else:
                runs, channels = np.arange(len(self.bodies))[:, None], np.arange(self.bodies.shape[2])[None, :]
                values = self.bodies[runs, indices, channels]
            self._placed[key] = self.engine.put(jnp.asarray(values, dtype=jnp.float32))
        return self._placed[key]


def plan_course(engine: Engine, runs: Sequence[PlannedRun], config: RunConfig) -> Course:
    """The course of `runs` (sharing `config` but their seeds) on `engine`: padded to its
    runs axis with copies of the last run, every body checked (`checked_phase_values`)."""
    padded = list(runs) + [runs[-1]] * (engine.padded_runs(len(runs)) - len(runs))
    bodies = np.stack(
        [
            run.schedule.checked_phase_values(config.num_phases, schedule_key(run.config.seed), engine.channels)
            for run in padded
        ]
    )
    extinctions = engine.put(jnp.asarray([run.schedule.extinction for run in padded], dtype=jnp.float32))
    return Course(
        engine,
        tuple(run.config.seed for run in padded),
        len(runs),
        bodies,
        extinctions,
        config.batch_size,
        config.num_centroids,
        config.num_init_cvt_samples,
        tuple(run.schedule for run in padded),
        config.num_phases,
    )


@functools.partial(
    jax.tree_util.register_dataclass,
    data_fields=[
        "repertoires",
        "keys",
        "evaluations",
        "reevaluations",
        "non_finite",
        "phase_evaluations",
        "phase_non_finite",
        "metrics",
        "indices",
        "paces",
    ],
    meta_fields=["generation", "phase"],
)
@dataclass(frozen=True)
class TrainingState:
    """Every run at one point of training: the archives and keys (on the devices, runs axis
    first, padded) and each real run's counters (host arrays): training evaluations so far
    (the initial population included), re-evaluations, results dropped as non-finite, and
    the evaluations of the current phase and how many of them were non-finite; each real
    run's QDax metrics of its archive now, and in a paced course each run's clocks and the
    open-loop phase each of its channels is at."""

    repertoires: MapElitesRepertoire
    keys: jax.Array
    generation: int  # generations done by every run (0: the initial population)
    phase: int
    evaluations: np.ndarray
    reevaluations: np.ndarray
    non_finite: np.ndarray
    phase_evaluations: np.ndarray
    phase_non_finite: np.ndarray
    metrics: dict[str, np.ndarray] = field(default_factory=dict)  # each real run's archive's, now
    indices: np.ndarray | None = None  # paced courses: (padded runs, channels), the open-loop phase of each body
    paces: tuple[PaceState | None, ...] = ()  # paced courses: each real run's clocks (None: unpaced)

    def pace(self, run: int) -> PaceState | None:
        """Run `run`'s pacing state (None: unpaced, or an unpaced course)."""
        return self.paces[run] if self.paces else None


@dataclass(frozen=True)
class Outcome:
    """What one step did to every run, for its metrics row: the event (`init`, `train`,
    `reseed` or `reevaluate`), QDax's metrics of its archive after, the results dropped as
    non-finite, and at a boundary what became of its elites (`REEVALUATION_FIELDS`)."""

    events: tuple[str, ...]
    metrics: dict[str, np.ndarray]
    non_finite: np.ndarray
    reevaluation: dict[str, np.ndarray] | None = None

    def of(self, run: int) -> tuple[str, dict[str, float], int, dict[str, int] | None]:
        """One run's event, metrics, non-finite count and re-evaluation counts."""
        counts = None
        if self.reevaluation is not None and self.events[run] != HOLD:
            counts = {name: int(values[run]) for name, values in self.reevaluation.items()}
        return self.events[run], _row(self.metrics, run), int(self.non_finite[run]), counts


def start(
    engine: Engine, course: Course, centroids: Mapping[int, jax.Array] | None = None
) -> tuple[TrainingState, Outcome]:
    """Every run's initial population scored into an empty archive on its seed's CVT
    centroids (`centroids`, by seed, where already made), in its body of phase 0."""
    runs = course.num_runs
    made = dict(centroids or {})
    main_keys, init_keys = [], []
    for seed in course.seeds:
        key, cvt_key, init_key = seed_keys(seed)
        main_keys.append(key)
        init_keys.append(init_key)
        if seed not in made:
            low, high = engine.task.descriptor_low, engine.task.descriptor_high
            made[seed] = cvt_centroids(course.num_centroids, low, high, course.num_init_cvt_samples, cvt_key)
    archives = engine.empty_archives(jnp.stack([made[seed] for seed in course.seeds]))
    repertoires, metrics, dropped, _ = engine.step(
        archives, course.bodies_in(0), course.starts, engine.put(jnp.stack(init_keys))
    )
    dropped = np.asarray(dropped[:runs], dtype=np.int64)
    state = TrainingState(
        repertoires,
        engine.put(jnp.stack(main_keys)),
        generation=0,
        phase=0,
        evaluations=np.full(runs, course.batch_size, dtype=np.int64),
        reevaluations=np.zeros(runs, dtype=np.int64),
        non_finite=dropped,
        phase_evaluations=np.zeros(runs, dtype=np.int64),
        phase_non_finite=np.zeros(runs, dtype=np.int64),
        metrics=_real(metrics, runs),
    )
    if course.paced:
        paces = tuple(pacing.initial(course.schedules[r], _row(state.metrics, r)) for r in range(runs))
        indices = np.zeros((len(course.seeds), len(engine.channels)), dtype=np.int64)
        state = dataclasses.replace(state, paces=paces, indices=indices)
    return state, Outcome(("init",) * runs, metrics, dropped)


def _real(metrics: Mapping[str, np.ndarray], runs: int) -> dict[str, np.ndarray]:
    return {name: np.asarray(values)[:runs] for name, values in metrics.items()}


def _row(metrics: Mapping[str, np.ndarray], run: int) -> dict[str, float]:
    return {name: float(values[run]) for name, values in metrics.items()}


def restore(
    engine: Engine, course: Course, repertoires: Any, keys: jax.Array, runs: Sequence[RunState]
) -> TrainingState:
    """The state a checkpoint saved (the real runs' archives, keys and progress), padded
    and placed on the devices. A checkpoint is written at a phase boundary, so the phase's
    counts start afresh."""
    extra = len(course.seeds) - course.num_runs

    def placed(x: jax.Array) -> jax.Array:  # leaf by leaf: at most one leaf's padded copy more
        return engine.put(jnp.concatenate([x] + [x[-1:]] * extra) if extra else x)

    repertoires, keys = jax.tree.map(placed, (repertoires, keys))
    count = len(runs)
    last_rows = [run.rows[-1] for run in runs]
    state = TrainingState(
        repertoires,
        keys,
        generation=runs[0].generation,
        phase=runs[0].phase,
        evaluations=np.asarray([run.evaluations for run in runs], dtype=np.int64),
        reevaluations=np.asarray([run.reevaluations for run in runs], dtype=np.int64),
        non_finite=np.asarray([run.non_finite for run in runs], dtype=np.int64),
        phase_evaluations=np.zeros(count, dtype=np.int64),
        phase_non_finite=np.zeros(count, dtype=np.int64),
        metrics={name: np.asarray([row[name] for row in last_rows], np.float32) for name in SCORES},
    )
    if course.paced:  # each run's clocks, decided again from its rows as training decided them
        paces = tuple(pacing.replayed(course.schedules[r], run.rows, course.num_phases) for r, run in enumerate(runs))
        state = dataclasses.replace(state, paces=paces, indices=_indices(course, paces, state.phase))
    return state


def _indices(course: Course, paces: Sequence[PaceState | None], phase: int) -> np.ndarray:
    """Every padded run's (channels,) open-loop phases in `phase` (padding: the last run's)."""
    channels = course.engine.channels
    rows = [
        pacing.indices(course.schedules[r], pace, phase, course.num_phases, channels) for r, pace in enumerate(paces)
    ]
    rows += [rows[-1]] * (len(course.seeds) - len(rows))
    return np.stack(rows)


def train_generation(engine: Engine, course: Course, state: TrainingState) -> tuple[TrainingState, Outcome]:
    """One generation of every run in its body of the state's phase (the archives are
    donated: the state given is used up)."""
    runs = course.num_runs
    keys, subkeys = engine.split(state.keys)
    repertoires, metrics, dropped, reseeded = engine.step(
        state.repertoires, course.bodies_in(state.phase, state.indices), course.starts, subkeys
    )
    dropped = np.asarray(dropped[:runs], dtype=np.int64)
    state = dataclasses.replace(
        state,
        repertoires=repertoires,
        keys=keys,
        metrics=_real(metrics, runs),
        generation=state.generation + 1,
        evaluations=state.evaluations + course.batch_size,
        non_finite=state.non_finite + dropped,
        phase_evaluations=state.phase_evaluations + course.batch_size,
        phase_non_finite=state.phase_non_finite + dropped,
    )
    events = tuple("reseed" if reseeded[r] else "train" for r in range(runs))
    return state, Outcome(events, metrics, dropped)


def cross_boundary(engine: Engine, course: Course, state: TrainingState, phase: int) -> tuple[TrainingState, Outcome]:
    """Every archive re-scored in its run's body of `phase`, thinned by its extinction
    probability, into a fresh archive (`Engine.reevaluate`); the new phase's counts start
    at 0. In a paced course each paced run first decides from its metrics whether its body
    moves on (`smol_dsl.runner.pacing`); a run whose body stays (`hold`) keeps its archive
    as it is, not re-scored. Every run's key is split at every boundary, so that a run's
    random streams do not depend on when the runs beside it move on."""
    runs = course.num_runs
    keys, subkeys = engine.split(state.keys)
    paces, indices, moved = state.paces, state.indices, None
    if course.paced:
        decided = tuple(
            pace
            if pace is None
            else pacing.decide(course.schedules[r], pace, _row(state.metrics, r), state.phase, course.num_phases)
            for r, pace in enumerate(state.paces)
        )
        indices = _indices(course, decided, phase)
        moved = np.any(indices != state.indices, axis=1)
        paces = decided
    if moved is None or moved.all():
        repertoires, counts = engine.reevaluate(
            state.repertoires, course.bodies_in(phase, indices), course.starts, course.extinctions, subkeys
        )
        metrics = engine.metrics(repertoires)
    elif moved.any():
        repertoires, counts = engine.reevaluate(
            state.repertoires, course.bodies_in(phase, indices), course.starts, course.extinctions, subkeys, only=moved
        )
        after = engine.metrics(repertoires)
        metrics = {name: np.where(moved[:runs], after[name][:runs], state.metrics[name]) for name in after}
    else:
        repertoires, counts, metrics = state.repertoires, ReevaluationCounts.none(len(course.seeds)), state.metrics
    real = _real(metrics, runs)
    if moved is not None:
        paces = tuple(
            pace
            if pace is None or not moved[r]
            else pacing.settle(course.schedules[r], state.paces[r], pace, _row(real, r))
            for r, pace in enumerate(paces)
        )
    non_finite = np.asarray(counts.non_finite[:runs], dtype=np.int64)
    state = dataclasses.replace(
        state,
        repertoires=repertoires,
        keys=keys,
        phase=phase,
        reevaluations=state.reevaluations + np.asarray(counts.reevaluated[:runs], dtype=np.int64),
        non_finite=state.non_finite + non_finite,
        phase_evaluations=np.zeros(runs, dtype=np.int64),
        phase_non_finite=np.zeros(runs, dtype=np.int64),
        metrics=real,
        indices=indices,
        paces=paces,
    )
    reevaluation = {name: np.asarray(getattr(counts, name)) for name in REEVALUATION_FIELDS}
    events = tuple(REEVALUATION if moved is None or moved[r] else HOLD for r in range(runs))
    return state, Outcome(events, metrics, non_finite, reevaluation)


def failed_runs(state: TrainingState) -> list[int]:
    """The runs whose every evaluation of the current phase scored NaN or infinity: the
    physics cannot simulate their body, and their archives learn nothing."""
    lost = (state.phase_evaluations > 0) & (state.phase_non_finite == state.phase_evaluations)
    return [int(run) for run in np.flatnonzero(lost)]


__all__ = [
    "Course",
    "Outcome",
    "TrainingState",
    "cross_boundary",
    "failed_runs",
    "plan_course",
    "restore",
    "start",
    "train_generation",
]
