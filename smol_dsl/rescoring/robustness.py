"""How much of a finished run's final archive survives a change: of body, of episode start,
or of the compiled program that scores it (`smol-dsl robustness`).

Each perturbation is a family of samples; each sample re-scores every elite of the final
archive once and inserts the results into a fresh archive on the same centroids (QDax's
`MapElitesRepertoire.add`: collisions keep the best), which says how many elites kept
their cell, moved, collided or died (`smol_dsl.rundir.RobustnessRow`). Then, as QDax's
`reevaluation_function` builds its corrected repertoire, each elite's median fitness and
descriptor over the family's samples (`median_of_samples`: an odd number of them, NaN
samples left out) go into one more fresh archive: its coverage and max fitness are the
robust ones (the row whose sample is `median`).

- `body CHANNEL xLOW-HIGH`: a family of body factors, the final body with that channel's
  factor times each (default `perturbations.DEFAULT_BODIES`: one family each way, the
  paper's SMOL step of 0.56%, 5% and 10%);
- `float path`: the same body in another layout of the program (a batch of twice the
  run's, elites in the order of the filled cells, as the runner's own re-evaluation lays
  them out), as another machine would score it;
- `physics NAME`: the same body, from the same start, on another physics than the run
  trained on (`--physics`), in the same layout: how much of the archive carries over to
  another simulator;
- `starts`: other episode starts drawn from the task's reset distribution, K of them.

Bodies and starts are scored by the very program the run trained with, rebuilt from
environment.json's layout with every elite in its lane (`smol_dsl.rescoring.replay`), the body
and the start traced inputs: one compilation for every factor and start, and a body factor
of 1 reproduces the archive bit for bit, so that what a sample measures is its
perturbation and nothing else. The runs of a sweep are scored together, as they trained.
Importing this module imports no JAX; measuring does.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.errors import counted
from smol_dsl.rescoring.lanes import lane_chunks
from smol_dsl.rescoring.perturbations import (
    DEFAULT_PERTURBATIONS,
    FLOAT_PATH,
    STARTS,
    Perturbations,
    body_name,
    check_perturbations,
    physics_name,
)
from smol_dsl.rundir import MEDIAN, RobustnessRow, load_archive

if TYPE_CHECKING:
    from smol_dsl.language.channels import Channel
    from smol_dsl.rundir import Archive, RunRecord
    from smol_dsl.runner.engine import Engine

OTHER_STARTS = 0x5A27  # folded into a run's seed (with the start's number) for its other episode starts


def measure_robustness(
    runs: Sequence[RunRecord],
    perturbations: Perturbations = DEFAULT_PERTURBATIONS,
    *,
    progress: Callable[[str], None] | None = None,
) -> list[RobustnessRow]:
    """Every finished run's final archive re-scored under `perturbations` (checked first:
    `check_perturbations`): a row per run, perturbation and sample, and per perturbation its
    corrected archive's (`MEDIAN`), in the order of `runs`. `progress` is told each sample
    as it starts."""
    check_perturbations(runs, perturbations)
    order = {id(run): number for number, run in enumerate(runs)}
    rows: dict[int, list[RobustnessRow]] = {}
    for program in scoring_programs(runs):
        for placed in program.passes:
            measured = _measure_pass(program, placed, perturbations, progress)
            for position, run_rows in measured.items():
                rows[order[id(placed[position])]] = run_rows
    return [row for number in sorted(rows) for row in rows[number]]


@dataclass(frozen=True)
class ScoringProgram:
    """Runs that share a scoring program (their task, settings, devices and layout), in
    passes: each a {position among the program's runs: run}, no two runs in one position."""

    config: Any  # the runs' RunConfig (its seed is the first run's)
    devices: list[Any]
    runs: int
    runs_per_step: int | None
    channels: tuple[Channel, ...]
    passes: list[dict[int, RunRecord]]


def scoring_programs(runs: Sequence[RunRecord]) -> list[ScoringProgram]:
    """The runs grouped by the program that scored their archives (`replay_layout`); runs
    whose program cannot be built again here (`inexact`) share one program of their own
    settings, laid out for all of them."""
    from smol_dsl.rescoring.replay import replay_layout
    from smol_dsl.runner.layout import default_runs_per_step

    exact: dict[str, tuple[Any, list[tuple[int, RunRecord]]]] = {}
    loose: dict[str, list[RunRecord]] = {}
    for run in runs:
        layout = replay_layout(run)
        settings = json.dumps(run.settings, sort_keys=True, default=str)
        if layout.inexact is not None:
            loose.setdefault(settings, []).append(run)
            continue
        key = json.dumps(
            [settings, len(layout.devices), layout.runs, layout.runs_per_step, [c.name for c in layout.channels]]
        )
        exact.setdefault(key, (layout, []))[1].append((layout.index, run))
    programs = []
    for layout, placed in exact.values():
        passes: list[dict[int, RunRecord]] = []
        for index, run in placed:
            free = next((p for p in passes if index not in p), None)
            if free is None:
                free = {}
                passes.append(free)
            free[index] = run
        config = placed[0][1].config
        programs.append(
            ScoringProgram(config, layout.devices, layout.runs, layout.runs_per_step, layout.channels, passes)
        )
    for group in loose.values():
        devices = replay_layout(group[0]).devices
        channels = tuple(dict.fromkeys(channel for run in group for channel in run.channels))
        passes = [dict(enumerate(group))]
        programs.append(
            ScoringProgram(group[0].config, devices, len(group), default_runs_per_step(devices), channels, passes)
        )
    return programs


@dataclass
class _Slots:
    """One pass's runs laid out in their program's positions (padding repeats a run)."""

    engine: Engine
    runs: list[RunRecord]  # per position (padding: the first run)
    real: list[bool]  # whether the position holds its own run (not padding)
    archives: list[Archive]
    filled: list[np.ndarray]  # each position's filled cells
    bodies: np.ndarray  # (positions, channels): each run's final body
    starts: Any  # each run's own episode start, stacked


def _measure_pass(
    program: ScoringProgram,
    placed: dict[int, RunRecord],
    perturbations: Perturbations,
    progress: Callable[[str], None] | None,
) -> dict[int, list[RobustnessRow]]:
    from smol_dsl.runner.engine import shared_engine, stack_runs

    engine = shared_engine(
        program.config.task, program.config, program.devices, program.runs_per_step, program.runs, program.channels
    )
    positions = engine.padded_runs(program.runs)
    first = next(iter(placed.values()))
    runs = [placed.get(position, first) for position in range(positions)]
    archives = {id(run): load_archive(run.directory) for run in placed.values()}
    own_starts = {seed: engine.task.episode_start(seed) for seed in dict.fromkeys(run.config.seed for run in runs)}
    slots = _Slots(
        engine=engine,
        runs=runs,
        real=[position in placed for position in range(positions)],
        archives=[archives[id(run)] for run in runs],
        filled=[np.flatnonzero(archives[id(run)].filled) for run in runs],
        bodies=np.asarray([_final_body(run, engine.channels) for run in runs], dtype=np.float32),
        starts=stack_runs([own_starts[run.config.seed] for run in runs]),
    )
    samples = _samples(program, slots, perturbations)
    total = sum(len(sampled) for _, sampled in samples)
    rows: dict[int, list[RobustnessRow]] = {position: [] for position in placed}
    done = 0
    for perturbation, sampled in samples:
        scores = []
        for label, factor, score in sampled:
            done += 1
            if progress is not None:
                progress(f"{perturbation} {label} ({done}/{total}, {counted(len(placed), 'run')})")
            fitnesses, descriptors = score()
            scores.append((fitnesses, descriptors))
            for position in placed:
                rows[position].append(
                    _row(slots, position, perturbation, label, factor, fitnesses[position], descriptors[position])
                )
        fitness_samples = np.stack([fitnesses for fitnesses, _ in scores])
        descriptor_samples = np.stack([descriptors for _, descriptors in scores])
        for position in placed:  # the corrected archive: each elite's median over the samples
            fitness, descriptor = median_of_samples(fitness_samples[:, position], descriptor_samples[:, position])
            rows[position].append(_row(slots, position, perturbation, MEDIAN, math.nan, fitness, descriptor))
    return {position: _counted(run_rows) for position, run_rows in rows.items()}


def _counted(rows: list[RobustnessRow]) -> list[RobustnessRow]:
    """The rows with each perturbation's number of samples (its `samples` column)."""
    count = {perturbation: 0 for perturbation in dict.fromkeys(row.perturbation for row in rows)}
    for row in rows:
        count[row.perturbation] += row.sample != MEDIAN
    return [dataclasses.replace(row, samples=count[row.perturbation]) for row in rows]


def median_of_samples(fitnesses: np.ndarray, descriptors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each elite's place in the corrected archive, from its K samples (`fitnesses` (K, N),
    `descriptors` (K, N, D)): its median fitness and its median descriptor, coordinate by
    coordinate, over the samples where both are finite, as QDax's `reevaluation_function`
    takes them with its default `median` extractors. Families have an odd K
    (`check_families`), so with every sample finite each is one sample's value (a
    descriptor's coordinates may come from different samples, as QDax's median does). A
    sample that is NaN or infinite is left out of the elite's median, not the elite out of
    the archive: the elite is dead (NaN fitness) only where most of its samples are (over
    K / 2), and where an even number of them are finite, its median is the midpoint of the
    middle two (numpy's)."""
    fitnesses = np.asarray(fitnesses, dtype=np.float32)
    descriptors = np.asarray(descriptors, dtype=np.float32)
    finite = np.isfinite(fitnesses) & np.isfinite(descriptors).all(axis=-1)
    alive = 2 * finite.sum(axis=0) > len(fitnesses)
    fitness = np.full(fitnesses.shape[1:], np.nan, dtype=np.float32)
    descriptor = np.full(descriptors.shape[1:], np.nan, dtype=np.float32)
    if alive.any():
        kept_f = np.where(finite, fitnesses, np.nan)[:, alive]
        kept_d = np.where(finite[..., None], descriptors, np.nan)[:, alive]
        fitness[alive] = np.nanmedian(kept_f, axis=0)
        descriptor[alive] = np.nanmedian(kept_d, axis=0)
    return fitness, descriptor


def _final_body(run: RunRecord, channels: Sequence[Channel]) -> list[float]:
    """The run's final body as a row of the program's channels (1 where its schedule has none)."""
    final = run.last_phase_body()
    return [final.get(channel, 1.0) for channel in channels]


Sample = tuple[str, float, Callable[[], tuple[np.ndarray, np.ndarray]]]


def _samples(program: ScoringProgram, slots: _Slots, perturbations: Perturbations) -> list[tuple[str, list[Sample]]]:
    """Each perturbation with its samples: a label, a body factor (NaN where none) and a
    function that scores every position's elites (fitnesses and descriptors by cell)."""
    from smol_dsl.language.channels import Channel

    in_lanes = _lane_chunks(slots, slots.engine.batch_size)
    samples: list[tuple[str, list[Sample]]] = []
    for name, factors in perturbations.bodies:
        column = slots.engine.channels.index(Channel.parse(name))
        sampled = []
        for factor in factors:
            bodies = slots.bodies.copy()
            bodies[:, column] *= np.float32(factor)
            sampled.append(
                (f"x{factor:g}", float(factor), _scorer(slots.engine, slots, bodies, lambda: slots.starts, in_lanes))
            )
        samples.append((body_name(Channel.parse(name).name, factors), sampled))
    if perturbations.float_path:
        other = _float_path_engine(program)
        chunks = list(_cell_chunks(slots, other.batch_size))
        scorer = _scorer(other, slots, slots.bodies, lambda: slots.starts, chunks)
        samples.append((FLOAT_PATH, [(f"batch {other.batch_size}", math.nan, scorer)]))
    for physics in perturbations.physics:
        simulator = _physics_engine(program, physics)
        starts = functools.partial(_own_starts, simulator, slots)
        scorer = _scorer(simulator, slots, slots.bodies, starts, in_lanes)
        samples.append((physics_name(physics), [(f"on {physics}", math.nan, scorer)]))
    if perturbations.starts:
        sampled = []
        for number in range(perturbations.starts):  # each start drawn when it is scored: K of them are not held
            starts = functools.partial(_other_starts, slots, number)
            sampled.append((f"start {number}", math.nan, _scorer(slots.engine, slots, slots.bodies, starts, in_lanes)))
        samples.append((STARTS, sampled))
    return samples


def _float_path_engine(program: ScoringProgram) -> Engine:
    """The program with a batch twice the run's: another layout of the same computation."""
    from smol_dsl.runner.engine import shared_engine

    config = dataclasses.replace(program.config, batch_size=2 * program.config.batch_size)
    return shared_engine(config.task, config, program.devices, program.runs_per_step, program.runs, program.channels)


def _physics_engine(program: ScoringProgram, physics: str) -> Engine:
    """The program on another physics: the same task, settings, channels and layout."""
    from smol_dsl.runner.engine import shared_engine

    config = dataclasses.replace(program.config, physics=physics)
    return shared_engine(config.task, config, program.devices, program.runs_per_step, program.runs, program.channels)


def _own_starts(engine: Engine, slots: _Slots) -> Any:
    """Every position's own episode start (its seed's), on `engine`'s physics."""
    from smol_dsl.runner.engine import stack_runs

    made = {seed: engine.task.episode_start(seed) for seed in dict.fromkeys(run.config.seed for run in slots.runs)}
    return stack_runs([made[run.config.seed] for run in slots.runs])


def _other_starts(slots: _Slots, number: int) -> Any:
    """Every position's episode start number `number` of the `starts` perturbation: a draw
    from the task's reset distribution keyed by the run's seed (made eagerly, as a run's own)."""
    import jax

    from smol_dsl.runner.engine import stack_runs
    from smol_dsl.tasks.base import deterministic_init_state

    env = slots.engine.task.env
    made = {}
    for run in slots.runs:
        if run.config.seed not in made:
            key = jax.random.fold_in(jax.random.key(run.config.seed), OTHER_STARTS + number)
            made[run.config.seed] = deterministic_init_state(env, key)
    return stack_runs([made[run.config.seed] for run in slots.runs])


def _lane_chunks(slots: _Slots, batch_size: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Batches of every position's filled cells with each elite in its lane (`lane_chunks`)."""
    return lane_chunks(slots.filled, [archive.lanes for archive in slots.archives], batch_size)


def _cell_chunks(slots: _Slots, batch_size: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Batches of every position's filled cells in cell order (`reevaluation_chunks`)."""
    from smol_dsl.qdax.reevaluation import reevaluation_chunks

    return list(reevaluation_chunks(slots.filled, batch_size))


def _scorer(
    engine: Engine,
    slots: _Slots,
    bodies: np.ndarray,
    starts_of: Callable[[], Any],
    chunks: list[tuple[np.ndarray, np.ndarray]],
) -> Callable[[], tuple[np.ndarray, np.ndarray]]:
    """Scores every position's elites in its body and start (made by `starts_of` when
    scored), batch by batch: (positions, cells) fitnesses and (positions, cells, D)
    descriptors, NaN where a cell is empty."""

    def score() -> tuple[np.ndarray, np.ndarray]:
        starts = starts_of()
        cells, dimensions = slots.archives[0].descriptors.shape
        fitnesses = np.full((len(slots.runs), cells), np.nan, dtype=np.float32)
        descriptors = np.full((len(slots.runs), cells, dimensions), np.nan, dtype=np.float32)
        for index, valid in chunks:
            genotypes = _gathered([archive.genotypes for archive in slots.archives], index)
            scored_fitnesses, scored_descriptors = engine.score(genotypes, bodies, starts)
            for position in range(len(slots.runs)):
                mine = valid[position]
                fitnesses[position, index[position, mine]] = scored_fitnesses[position, mine]
                descriptors[position, index[position, mine]] = scored_descriptors[position, mine]
        return fitnesses, descriptors

    return score


def _gathered(trees: list[Any], index: np.ndarray) -> Any:
    """The genotypes at `index[position]` of each position's archive, stacked (positions, B, ...)."""
    if isinstance(trees[0], dict):
        return {name: _gathered([tree[name] for tree in trees], index) for name in trees[0]}
    return np.stack([np.asarray(leaf)[row] for leaf, row in zip(trees, index, strict=True)])


def _row(
    slots: _Slots,
    position: int,
    perturbation: str,
    sample: str,
    factor: float,
    fitnesses: np.ndarray,
    descriptors: np.ndarray,
) -> RobustnessRow:
    """What became of a position's elites scored `fitnesses` and `descriptors` (by cell)."""
    run, archive, before = slots.runs[position], slots.archives[position], slots.filled[position]
    finite = np.zeros(len(fitnesses), dtype=bool)
    finite[before] = np.isfinite(fitnesses[before]) & np.isfinite(descriptors[before]).all(axis=1)
    holder, best = reinserted(
        archive.centroids, np.where(finite, fitnesses, -np.inf), np.where(finite[:, None], descriptors, 0)
    )
    filled = best > -np.inf
    kept = int(np.sum(filled & (holder == np.arange(len(holder)))))
    count = int(filled.sum())
    died = len(before) - int(finite.sum())
    return RobustnessRow(
        directory=str(run.directory),
        schedule=run.schedule,
        seed=run.config.seed,
        perturbation=perturbation,
        sample=sample,
        factor=factor,
        samples=0,  # counted once the perturbation's rows are all there (`_counted`)
        cells=len(before),
        filled=count,
        kept=kept,
        moved=count - kept,
        collided=len(before) - died - count,
        died=died,
        coverage=100.0 * count / len(holder),
        max_fitness=float(best.max()) if count else -math.inf,
    )


def reinserted(centroids: np.ndarray, fitnesses: np.ndarray, descriptors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every cell's elite (-inf fitness: none) inserted into a fresh archive on `centroids`
    by QDax's `MapElitesRepertoire.add`: for each cell of the fresh archive, the cell whose
    elite it holds and that elite's fitness (-inf where it is empty)."""
    holder, best = _reinsert_program()(
        np.asarray(centroids, np.float32), fitnesses.astype(np.float32), descriptors.astype(np.float32)
    )
    return np.asarray(holder), np.asarray(best).reshape(-1)


_PROGRAMS: dict[str, Any] = {}


def _reinsert_program() -> Any:
    if "reinsert" not in _PROGRAMS:
        import jax
        import jax.numpy as jnp
        from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire

        def reinsert(centroids: jax.Array, fitnesses: jax.Array, descriptors: jax.Array) -> tuple[jax.Array, jax.Array]:
            cells = centroids.shape[0]
            fresh = MapElitesRepertoire.init_default(genotype=jnp.zeros((), jnp.int32), centroids=centroids)
            fresh = fresh.add(jnp.arange(cells, dtype=jnp.int32), descriptors, fitnesses)
            return fresh.genotypes, fresh.fitnesses

        _PROGRAMS["reinsert"] = jax.jit(reinsert)
    return _PROGRAMS["reinsert"]
