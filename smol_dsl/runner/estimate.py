"""How long a sweep will take, from a warm-up timed on this machine (`--dry-run`).

`measure_sweep` builds the engine the sweep itself would build (same task, settings,
devices, runs per step, number of runs and channels, as `run_sweep` and `run_experiment`
do), on the real batch and episode sizes, and times it with a wall clock:

1. the CVT centroids of one seed (every run's archive is made on them here; the sweep
   computes one set per seed);
2. the first generation of every run at once in its schedule's first body, untimed as a
   rate: it builds the task and the engine and compiles the generation's programs;
3. a re-evaluation of that generation's archives in the bodies of the second phase, twice:
   the first compiles its programs, the second is timed. The first generation fills at most
   a batch of cells per run, so each is one chunk, a batch of elites of every run scored and
   inserted (and the archives' metrics, as at a boundary);
4. up to `TIMED_GENERATIONS` more generations of every run, each timed, fewer once they have
   taken `ENOUGH_SECONDS` (one long generation measures its rate well).

The compile time is what the first generation and the first re-evaluation took beyond their
timed repetitions. Nothing is written anywhere: the archives stay in memory and are dropped.

`estimate_duration` is the arithmetic, pure: the compile, the centroids of every seed, every
batch of the budget (the initial population and each generation) at the measured time of a
generation, and at every phase boundary as many chunks as a full archive has (`centroids /
batch`, rounded up) at the measured time of a chunk. A boundary re-scores only the filled
cells, so that part is an upper estimate. Not counted: writing metrics rows, checkpoints (in
the background, beside training) and the figures at the end.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from smol_dsl.runner.config import RunError
from smol_dsl.runner.footprint import _count

if TYPE_CHECKING:
    import jax

    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.runner.plan import PlannedRun

TIMED_GENERATIONS = 3  # generations timed after the first (which compiles)
ENOUGH_SECONDS = 10.0  # stop timing generations once they have taken this long


@dataclass(frozen=True)
class Measurement:
    """What the warm-up measured on this machine, in seconds of wall time, for `runs` runs
    advanced together (this process's share of the sweep) of `seeds` distinct seeds."""

    runs: int
    seeds: int
    batch_size: int
    episode_length: int
    timed_generations: int
    generation_seconds: float  # one generation of every run (the mean of the timed ones)
    chunk_seconds: float  # one re-evaluation chunk: a batch of elites of every run
    centroids_seconds: float  # one seed's CVT centroids
    compile_seconds: float  # building the engine and compiling its programs
    warmup_seconds: float  # the whole measurement

    @property
    def evaluations_per_second(self) -> float:
        """Training evaluations per second over all runs."""
        return self.runs * self.batch_size / self.generation_seconds

    @property
    def steps_per_second(self) -> float:
        """Environment steps per second over all runs."""
        return self.evaluations_per_second * self.episode_length


@dataclass(frozen=True)
class Duration:
    """The estimated wall time of a sweep, in its parts (seconds)."""

    compile_seconds: float
    centroids_seconds: float  # every seed's CVT centroids
    batches: int  # the initial population and every generation
    generation_seconds: float
    boundaries: int
    chunks: int  # re-evaluation chunks at a boundary, every archive full
    chunk_seconds: float

    @property
    def training_seconds(self) -> float:
        return self.batches * self.generation_seconds

    @property
    def reevaluation_seconds(self) -> float:
        """At most: every archive full at every boundary."""
        return self.boundaries * self.chunks * self.chunk_seconds

    @property
    def total_seconds(self) -> float:
        return self.compile_seconds + self.centroids_seconds + self.training_seconds + self.reevaluation_seconds


def estimate_duration(config: RunConfig, measurement: Measurement) -> Duration:
    """The sweep's wall time at the measured rates (see the module's docstring)."""
    return Duration(
        compile_seconds=measurement.compile_seconds,
        centroids_seconds=measurement.seeds * measurement.centroids_seconds,
        batches=config.evaluations // config.batch_size,
        generation_seconds=measurement.generation_seconds,
        boundaries=config.num_phases - 1,
        chunks=math.ceil(config.num_centroids / config.batch_size),
        chunk_seconds=measurement.chunk_seconds,
    )


def warmup_note(runs: int) -> str:
    """What the warm-up does, printed before it starts."""
    return (
        f"measuring: building and compiling the engine, then timing up to {TIMED_GENERATIONS} generations of "
        f"{'the run' if runs == 1 else f'all {runs} runs at once'} after an untimed first one, and a re-evaluation "
        "chunk (--no-measure skips this)"
    )


def describe_estimate(config: RunConfig, measurement: Measurement, device_label: str) -> str:
    """The measurement and the estimate as the CLI prints them."""
    m, duration = measurement, estimate_duration(config, measurement)
    runs = "the run" if m.runs == 1 else f"all {m.runs} runs"
    timed = "timed once" if m.timed_generations == 1 else f"the mean of {m.timed_generations} timed"
    lines = [
        f"compile: {_duration(m.compile_seconds)} (building the task and engine, compiling a generation's and a "
        "re-evaluation's programs)",
        f"throughput: {_count(m.evaluations_per_second)} evals/s ({_count(m.steps_per_second)} steps/s) over "
        f"{runs}: a generation of {m.runs} x {config.batch_size} evaluations of {config.episode_length} steps "
        f"in {_duration(m.generation_seconds)} ({timed} after an untimed first)",
        f"re-evaluation: a chunk of {config.batch_size} elites of every run in {_duration(m.chunk_seconds)}; "
        f"CVT centroids: {_duration(m.centroids_seconds)} a seed",
        f"estimated wall time: {_duration(duration.total_seconds)} = {_duration(m.compile_seconds)} compile + "
        f"{_duration(duration.centroids_seconds)} centroids of {m.seeds} seed(s) + {duration.batches:,} batches x "
        f"{_duration(m.generation_seconds)} ({_duration(duration.training_seconds)}) + up to {duration.boundaries} "
        f"boundaries x {duration.chunks} chunk(s) x {_duration(m.chunk_seconds)} "
        f"({_duration(duration.reevaluation_seconds)})",
        f"  assumes every generation as fast as the timed ones, and every archive full ({config.num_centroids} "
        "cells) at every phase boundary: a boundary re-scores only the filled cells, so that part is an upper "
        "estimate; not counted: writing metrics, checkpoints (in the background) and figures",
        f"  (measured in {_duration(m.warmup_seconds)} on {device_label}; nothing was written)",
    ]
    return "\n".join(lines)


def measure_sweep(
    config: RunConfig,
    schedules: Sequence[Schedule],
    seeds: Sequence[int],
    devices: Sequence[jax.Device],
    runs_per_step: int | None,
    part: tuple[int, int] = (0, 1),
    timed_generations: int = TIMED_GENERATIONS,
    enough_seconds: float = ENOUGH_SECONDS,
    clock: Callable[[], float] = time.perf_counter,
) -> Measurement:
    """Time this process's share of the sweep of `schedules` x `seeds` on `devices` (a run is
    a sweep of one schedule and one seed), with `runs_per_step` as the sweep resolves it
    (None: all of a device's runs at once); see the module's docstring. A RunError if the
    devices run out of memory."""
    import jax

    from smol_dsl.runner.sweep import plan_sweep, sweep_part

    started = clock()
    runs = sweep_part(plan_sweep(schedules, seeds, config), part)
    try:
        warmup = _Warmup(config, runs, devices, runs_per_step, clock)
        first_generation = warmup.first_generation()
        first_reevaluation, timed_reevaluation = warmup.reevaluation(), warmup.reevaluation()
        times: list[float] = []
        while len(times) < max(timed_generations, 1) and sum(times) < enough_seconds:
            times.append(warmup.generation())
    except jax.errors.JaxRuntimeError as error:
        if "RESOURCE_EXHAUSTED" not in str(error):
            raise
        raise RunError(
            f"measuring the sweep ran out of memory on the {devices[0].platform} devices, and the sweep would too: "
            "use fewer --seeds, a smaller --runs-per-step or --batch-size, fewer --centroids, or share the runs "
            "between processes (--num-processes); --no-measure prints the arithmetic alone"
        ) from None
    generation_seconds = max(sum(times) / len(times), 1e-9)
    # with no finite elite to re-score, a chunk is taken to cost what a generation does
    chunks = warmup.chunks
    chunk_seconds = timed_reevaluation / chunks if chunks else generation_seconds
    compile_seconds = max(first_generation - generation_seconds, 0.0)
    compile_seconds += max(first_reevaluation - timed_reevaluation, 0.0)
    return Measurement(
        runs=len(runs),
        seeds=len({run.config.seed for run in runs}),
        batch_size=config.batch_size,
        episode_length=config.episode_length,
        timed_generations=len(times),
        generation_seconds=generation_seconds,
        chunk_seconds=chunk_seconds,
        centroids_seconds=warmup.centroids_seconds,
        compile_seconds=compile_seconds,
        warmup_seconds=clock() - started,
    )


class _Warmup:
    """The sweep's engine, course and state, made by the core's own functions
    (`smol_dsl.runner.core`) but with every archive on one seed's centroids (the CVT is
    timed once and counted per seed); each method times one step of it."""

    def __init__(
        self,
        config: RunConfig,
        runs: list[PlannedRun],
        devices: Sequence[jax.Device],
        runs_per_step: int | None,
        clock: Callable[[], float],
    ) -> None:
        import jax

        from smol_dsl.qdax.scoring import cvt_centroids, seed_keys
        from smol_dsl.runner.core import plan_course
        from smol_dsl.runner.engine import shared_engine
        from smol_dsl.runner.plan import run_channels
        from smol_dsl.tasks import task_spec

        self.clock, self.batch_size = clock, config.batch_size
        began = clock()
        spec = task_spec(config.task)
        _, cvt_key, _ = seed_keys(runs[0].config.seed)
        centroids = cvt_centroids(
            config.num_centroids, spec.descriptor_low, spec.descriptor_high, config.num_init_cvt_samples, cvt_key
        )
        jax.block_until_ready(centroids)
        self.centroids_seconds = clock() - began

        self.setup_began = clock()
        channels = run_channels([run.schedule for run in runs])
        self.engine = engine = shared_engine(config.task, config, list(devices), runs_per_step, len(runs), channels)
        self.course = plan_course(engine, runs, config)
        self.centroids = dict.fromkeys(self.course.seeds, centroids)
        self.next_phase = min(1, config.num_phases - 1)  # the phase the first boundary enters
        self.state: Any = None
        self.chunks = 0

    def first_generation(self) -> float:
        """The initial population of every run, from the engine's set-up on: it compiles the
        generation's programs. Its archives hold at most a batch of elites a run: one
        re-evaluation chunk."""
        import jax
        import numpy as np

        from smol_dsl.qdax.reevaluation import reevaluation_chunks
        from smol_dsl.runner.core import start

        self.state, _ = start(self.engine, self.course, self.centroids)
        took = self.clock() - self.setup_began
        filled = np.asarray(jax.device_get(self.state.repertoires.fitnesses)) > -np.inf
        cells = [np.flatnonzero(row) for row in filled.reshape(len(filled), -1)]
        self.chunks = sum(1 for _ in reevaluation_chunks(cells, self.batch_size))  # 1, or 0 if none scored finite
        return took

    def generation(self) -> float:
        """One generation of every run in its first body (`core.train_generation`)."""
        from smol_dsl.runner.core import train_generation

        began = self.clock()
        self.state, _ = train_generation(self.engine, self.course, self.state)
        return self.clock() - began

    def reevaluation(self) -> float:
        """The archives re-evaluated in the next phase's bodies into fresh ones
        (`core.cross_boundary`, its metrics included), then dropped."""
        import jax

        from smol_dsl.runner.core import cross_boundary

        began = self.clock()
        crossed, _ = cross_boundary(self.engine, self.course, self.state, self.next_phase)
        jax.block_until_ready(crossed.repertoires)
        return self.clock() - began


def _duration(seconds: float) -> str:
    """A wall time as people read it, to the precision of its largest unit but one: 0.42 s,
    8.5 s, 42 s, 4 min 5 s, 3 h 20 min, 2 d 5 h."""
    if seconds < 10:
        return f"{seconds:.2g} s" if seconds < 1 else f"{seconds:.1f} s"
    if seconds >= 86_400 - 1800:
        days, hours = divmod(round(seconds / 3600), 24)
        return f"{days} d {hours} h"
    if seconds >= 3600 - 30:
        hours, minutes = divmod(round(seconds / 60), 60)
        return f"{hours} h {minutes} min"
    minutes, whole = divmod(round(seconds), 60)
    return f"{minutes} min {whole} s" if minutes else f"{whole} s"


__all__ = ["Duration", "Measurement", "describe_estimate", "estimate_duration", "measure_sweep", "warmup_note"]
