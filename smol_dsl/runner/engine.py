"""The engine: phased MAP-Elites runs as jitted programs, runs an axis of the computation.

`smol-dsl run` is one run of it and `smol-dsl sweep` many. Every run has the same task and
settings but its own seed, schedule and archive, and all runs reach their phase boundaries
together. So the same programs advance every run by one generation (`RunStep.generation`)
and re-evaluate every archive (`RunStep.pick`, `score`, `insert`), with each run's body (a (C,)
array of the factors of the schedules' channels: plain gear's alpha, mass, friction, ...) a
traced input. A step is compiled in its parts (`RunStep`): choosing the batch, scoring it
and inserting the results, so that generations and re-evaluations share one scoring
program, the rollout, nearly all of the compilation. With `jax.shard_map` over a (runs,
population) device mesh, runs are split across devices (independent: no communication),
and devices left over split each offspring batch (its rollouts are gathered back). On each
device the local runs are either vmapped together (accelerators: one big batch) or their
offspring made and scored in groups one after another inside the program (`runs_per_step`;
CPUs, where rollouts slow down as batches grow past ~128); the programs that update
archives are vmapped, so that donated archives are updated in place.

A single run on several devices splits its population across all of them, so `smol-dsl
run` uses the whole machine. Per run, the programs are the same per-run step with the same
random keys whatever the layout, so a sweep's run follows the same algorithm and random
streams as `smol-dsl run` of that seed."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from functools import lru_cache, partial
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from qdax.utils.metrics import default_qd_metrics

from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.qdax.reevaluation import ReevaluationCounts, kept_in_place, reevaluation_chunks
from smol_dsl.runner.layout import mesh_shape
from smol_dsl.runner.map_elites import RunStep, empty_archive, make_map_elites
from smol_dsl.tasks import make_task
from smol_dsl.tasks.physics import DEFAULT_PHYSICS

if TYPE_CHECKING:
    from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire

    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.tasks.base import Task

RUNS = "runs"
POPULATION = "population"
LANES = "lanes"  # the batch's axis inside a replay's rollout, for picking a few lanes' positions


class Engine:
    """Jitted programs that advance R runs at once, sharded over `devices`.

    The devices form a (runs, population) mesh (`mesh_shape`): runs are split across the
    first axis; along the second, each device scores its share of every offspring batch
    and the shares are gathered, so a sweep with fewer runs than devices still uses them
    all. Every array argument and result has the runs axis first; R must be a multiple of
    the runs axis (`padded_runs`). A run's body is a (channels,) array of the factors of
    `channels`, in that order (`Task.with_channels`). `runs_per_step` is how many of a
    device's runs are scored at once (None: all of them, vmapped), as `fit_sweep` resolves
    it for the devices.
    """

    def __init__(
        self,
        task: Task,
        *,
        batch_size: int,
        iso_sigma: float,
        line_sigma: float,
        devices: list[jax.Device] | None = None,
        runs_per_step: int | None = None,
        num_runs: int | None = None,
        channels: tuple[Channel, ...] = (GEAR,),
    ) -> None:
        if runs_per_step is not None and (isinstance(runs_per_step, bool) or runs_per_step < 1):
            raise ValueError(f"runs_per_step {runs_per_step!r}: a number of runs, at least 1, or None for all")
        self.task = task = task.with_channels(channels)
        self.channels = task.channels
        self.batch_size = batch_size
        devices = list(devices) if devices is not None else jax.local_devices()
        self.runs_per_step = runs_per_step
        along_runs, self.population_devices = mesh_shape(
            len(devices), len(devices) if num_runs is None else num_runs, batch_size
        )
        self.devices = devices[: along_runs * self.population_devices]
        grid = np.asarray(self.devices).reshape(along_runs, self.population_devices)
        self.mesh = Mesh(grid, (RUNS, POPULATION))
        self.sharding = NamedSharding(self.mesh, PartitionSpec(RUNS))
        self.options = task.compiler_options(self.devices[0].platform)  # faster on CPUs, the same results
        map_elites = make_map_elites(batch_size, task.qd_offset, iso_sigma, line_sigma)
        step = RunStep(map_elites, task.init_policies, self._score, batch_size)
        # a generation is ask, score, tell and a re-evaluation pick, score, insert: the same
        # scoring program for both (the rollout is nearly all of the compilation)
        self._ask = self._sharded(self._reseeding_ask(step), ())
        self._scores = self._over_runs(step.score, in_groups=True, reads_archives=False)
        self._tell = self._over_runs(step.tell, donate=(0,))
        self._pick = self._over_runs(step.pick)
        self._insert = self._over_runs(step.insert, donate=(0,))
        self._metrics = self._over_runs(lambda archive: default_qd_metrics(archive, task.qd_offset))
        self._kept = self._over_runs(kept_and_filled)
        template = task.init_policies(jax.random.key(0), 1)
        # made on the devices, each its own runs' share: no host-side or stacked copy
        self._empty = self._over_runs(partial(empty_archive, template))
        self._split = jax.jit(split_in_two, out_shardings=self.sharding)
        self._replays: Any = None  # compiled on first use (`replay`)
        self._choose: Any = None  # compiled on first use (`reevaluate` of some runs only)

    def padded_runs(self, runs: int) -> int:
        """The number of runs rounded up to a multiple of the runs axis."""
        along_runs = self.mesh.shape[RUNS]
        return -(-runs // along_runs) * along_runs

    def put(self, tree: Any) -> Any:
        """Place arrays with a leading runs axis on the devices, split along that axis."""
        return jax.device_put(tree, self.sharding)

    def put_for_every_run(self, tree: Any, runs: int) -> Any:
        """The same arrays for each of `runs` runs, placed as `put` places them: repeated on
        the devices, so the host holds one copy, not one per run."""
        return jax.jit(partial(_repeated, runs=runs), out_shardings=self.sharding)(tree)

    # ------------------------------------------------------------------ per-run programs
    def _over_runs(
        self, run_fn: Any, donate: tuple[int, ...] = (), in_groups: bool = False, reads_archives: bool = True
    ) -> Any:
        """`run_fn` over every local run: vmapped, or, `in_groups`, `runs_per_step` runs at a
        time one group after another (for making and scoring offspring, whose working memory
        grows with the runs at once). Programs that read or update whole archives are
        vmapped, so that a donated archive is updated in place."""
        return self._sharded(self._local(run_fn, in_groups, reads_archives), donate)

    def _local(self, run_fn: Any, in_groups: bool, reads_archives: bool = True) -> Any:
        """`run_fn` over one device's runs (see `_over_runs`); a program that takes no
        archive (`reads_archives` False) scores groups of one run unbatched (`in_run_groups`)."""
        runs_per_step = self.runs_per_step if in_groups else None

        def local(*args: Any) -> Any:
            local_runs = jax.tree.leaves(args)[0].shape[0]
            if runs_per_step is None or runs_per_step >= local_runs:
                return over_runs(run_fn)(*args)
            return in_run_groups(run_fn, args, runs_per_step, unbatched=not reads_archives)

        return local

    def _reseeding_ask(self, step: RunStep) -> Any:
        """Every local run's offspring, with fresh policies for the runs whose archive is
        empty. Mapped over runs, `ask`'s choice between reseeding and offspring is a select
        that makes both every generation, so the reseeding `ask` runs only when some local
        run's archive is empty (the first generation, or after an extinction emptied it)."""
        reseeding, filled = self._local(step.ask, in_groups=True), self._local(step.offspring, in_groups=True)

        def ask(repertoires: MapElitesRepertoire, keys: jax.Array) -> tuple[Any, jax.Array]:
            runs = repertoires.fitnesses.shape[0]
            some_empty = jnp.any(jnp.all(repertoires.fitnesses.reshape(runs, -1) == -jnp.inf, axis=1))
            return jax.lax.cond(some_empty, reseeding, filled, repertoires, keys)

        return ask

    def _sharded(self, local: Any, donate: tuple[int, ...]) -> Any:
        """A function of one device's runs, jitted over the devices' runs."""
        spec = PartitionSpec(RUNS)
        sharded = jax.shard_map(local, mesh=self.mesh, in_specs=spec, out_specs=spec, check_vma=False)
        # every result split along the runs axis as the arguments are, so that a program's
        # results, given to the next one, never make it compile a variant for other shardings
        return jax.jit(sharded, donate_argnums=donate, out_shardings=self.sharding, compiler_options=self.options)

    def _score(self, genotypes: Any, body: jax.Array, start: Any, poses: bool = False) -> tuple[jax.Array, ...]:
        """Score one run's batch in its body; along the population axis each device rolls out
        its share, and the shares are gathered in order. With `poses`, also every step's
        positions and whether it counts (`Task.rollout`)."""
        shares = self.population_devices
        score = partial(self.task.score, poses=True) if poses else self.task.score
        if shares == 1:
            return score(genotypes, body, start)
        size = self.batch_size // shares
        first = jax.lax.axis_index(POPULATION) * size
        mine = jax.tree.map(lambda x: jax.lax.dynamic_slice_in_dim(x, first, size), genotypes)
        gather = partial(jax.lax.all_gather, axis_name=POPULATION, tiled=True)
        return tuple(gather(result) for result in score(mine, body, start))

    def _replay_lanes(self, genotypes: Any, body: jax.Array, start: Any, lanes: jax.Array) -> tuple[jax.Array, ...]:
        """One run's batch rolled out as `_score` rolls it out (the same vmapped rollout, each
        device its share of the batch), keeping the positions of `lanes` (L,) only: their
        fitnesses (L,), positions (L, T, nq) and whether each step counts (L, T). The lanes'
        positions are picked inside the rollout's scan, so no step keeps the whole batch's."""
        shares = self.population_devices
        size = self.batch_size // shares
        first = jax.lax.axis_index(POPULATION) * size if shares > 1 else 0
        mine = genotypes
        if shares > 1:
            mine = jax.tree.map(lambda x: jax.lax.dynamic_slice_in_dim(x, first, size), genotypes)
        local = jnp.clip(lanes - first, 0, size - 1)  # where each lane is in this device's share

        def kept(q: jax.Array) -> jax.Array:  # under the vmap over the share's lanes: the chosen lanes' positions
            return jax.lax.all_gather(q, LANES)[local]

        rollout = jax.vmap(
            partial(self.task.rollout, poses=kept), in_axes=(0, None, None), out_axes=(0, 0, None, 0), axis_name=LANES
        )
        fitnesses, _, positions, valid = rollout(mine, body, start)
        results = (fitnesses[local], jnp.swapaxes(positions, 0, 1), valid[local])
        if shares == 1:
            return results
        owner, which = lanes // size, jnp.arange(lanes.shape[0])  # the device whose share holds each lane
        return tuple(jax.lax.all_gather(result, POPULATION)[owner, which] for result in results)

    # ------------------------------------------------------------------ batched API
    def empty_archives(self, centroids: jax.Array) -> MapElitesRepertoire:
        """One empty archive per run, on its centroids (R, C, D)."""
        return self._empty(self.put(centroids))

    def split(self, keys: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Split every run's key in two, as `state.key, key = split(state.key)` does."""
        return self._split(keys)

    def step(
        self, repertoires: MapElitesRepertoire, bodies: jax.Array, starts: Any, keys: jax.Array
    ) -> tuple[MapElitesRepertoire, dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """One generation of every run in its body, (runs, channels) (the archives are
        donated). Returns the archives, each run's metrics, non-finite results and whether
        it was reseeded."""
        genotypes, reseeded = self._ask(repertoires, keys)
        fitnesses, descriptors = self._scores(genotypes, bodies, starts)
        repertoires, metrics, dropped = self._tell(repertoires, genotypes, fitnesses, descriptors)
        metrics, dropped, reseeded = jax.device_get((metrics, dropped, reseeded))
        return repertoires, metrics, np.asarray(dropped), np.asarray(reseeded)

    def reevaluate(
        self,
        repertoires: MapElitesRepertoire,
        bodies: jax.Array,
        starts: Any,
        extinctions: jax.Array,
        keys: jax.Array,
        only: np.ndarray | None = None,
    ) -> tuple[MapElitesRepertoire, ReevaluationCounts]:
        """Every run's elites re-scored in its new body, thinned by its extinction, in fresh
        archives. Chunks run over the filled cells only (up to the fullest archive).
        Returns the archives, and per run what became of its elites (`ReevaluationCounts`).
        With `only` (runs,) bool, the other runs' archives are returned as they are, none
        of their elites re-scored (their counts are 0)."""
        filled_mask = np.asarray(repertoires.fitnesses) > -np.inf
        filled = [np.flatnonzero(row) for row in filled_mask.reshape(len(filled_mask), -1)]
        if only is not None:
            filled = [cells if chosen else cells[:0] for cells, chosen in zip(filled, only, strict=True)]
        fresh = self.empty_archives(repertoires.centroids)
        non_finite = np.zeros(len(filled), dtype=np.int64)
        died = np.zeros(len(filled), dtype=np.int64)
        for index, valid in reevaluation_chunks(filled, self.batch_size):
            genotypes, keys, death_keys = self._pick(repertoires.genotypes, self.put(jnp.asarray(index)), keys)
            fitnesses, descriptors = self._scores(genotypes, bodies, starts)
            fresh, dropped, dead = self._insert(
                fresh, genotypes, fitnesses, descriptors, self.put(jnp.asarray(valid)), extinctions, death_keys
            )
            non_finite += np.asarray(dropped)
            died += np.asarray(dead)
        kept, after = jax.device_get(self._kept(repertoires, fresh))
        before = np.asarray([len(cells) for cells in filled], dtype=np.int64)
        counts = ReevaluationCounts.of(before, non_finite, died, np.asarray(kept), np.asarray(after))
        if only is not None:
            if self._choose is None:
                self._choose = self._over_runs(choose, donate=(1,))
            fresh = self._choose(self.put(jnp.asarray(only)), fresh, repertoires)
            counts = ReevaluationCounts(*(np.where(only, value, 0) for value in dataclasses.astuple(counts)))
        return fresh, counts

    def score(self, genotypes: Any, bodies: jax.Array, starts: Any) -> tuple[np.ndarray, np.ndarray]:
        """Every run's batch (R, batch_size, ...) scored in its body by the training's own
        scoring program: the fitnesses and descriptors its archive holds, bit for bit, on
        the devices it trained on."""
        return jax.device_get(self._scores(self.put(genotypes), self.put(bodies), self.put(starts)))

    def replay(self, genotypes: Any, bodies: jax.Array, starts: Any, lanes: np.ndarray) -> tuple[np.ndarray, ...]:
        """The batch rolled out as `score` rolls it out (the same rollout on the same
        layout), for drawing the gaits of `lanes` (L,): their fitnesses (R, L), every step's
        positions (R, L, T, nq) and whether it counts (R, L, T). Only those lanes' positions
        are kept and brought to the host; the lanes are a traced input, so one compiled
        program serves any L lanes."""
        if self._replays is None:
            self._replays = self._over_runs(self._replay_lanes, in_groups=True, reads_archives=False)
        runs = jax.tree.leaves(starts)[0].shape[0]
        lanes = np.broadcast_to(np.asarray(lanes, dtype=np.int32), (runs, len(lanes)))
        return jax.device_get(self._replays(self.put(genotypes), self.put(bodies), self.put(starts), self.put(lanes)))

    def metrics(self, repertoires: MapElitesRepertoire) -> dict[str, np.ndarray]:
        """QDax's coverage, max fitness and QD score of every run's archive."""
        return jax.device_get(self._metrics(repertoires))


@lru_cache(maxsize=8)
def _engine(
    task: Task,
    batch_size: int,
    iso_sigma: float,
    line_sigma: float,
    devices: tuple[jax.Device, ...],
    runs_per_step: int | None,
    num_runs: int,
    channels: tuple[Channel, ...],
) -> Engine:
    return Engine(
        task,
        batch_size=batch_size,
        iso_sigma=iso_sigma,
        line_sigma=line_sigma,
        devices=list(devices),
        runs_per_step=runs_per_step,
        num_runs=num_runs,
        channels=channels,
    )


@lru_cache(maxsize=8)
def shared_task(
    name: str, episode_length: int, hidden_layer_sizes: tuple[int, ...], physics: str = DEFAULT_PHYSICS
) -> Task:
    """One task per setting in a process (a task holds no seed: runs of any seed share it)."""
    return make_task(name, episode_length=episode_length, hidden_layer_sizes=hidden_layer_sizes, physics=physics)


def shared_engine(
    task: Task | str,
    config: RunConfig,
    devices: Sequence[jax.Device],
    runs_per_step: int | None,
    num_runs: int,
    channels: Sequence[Channel] = (GEAR,),
) -> Engine:
    """The engine for these settings and channels, shared within a process so that runs and
    sweeps of the same task, settings and channels reuse its compilations; a task given by
    name is built here."""
    if isinstance(task, str):
        task = shared_task(task, config.episode_length, tuple(config.hidden_layer_sizes), config.physics)
    return _engine(
        task,
        config.batch_size,
        config.iso_sigma,
        config.line_sigma,
        tuple(devices),
        runs_per_step,
        num_runs,
        tuple(channels),
    )


def kept_and_filled(before: MapElitesRepertoire, after: MapElitesRepertoire) -> tuple[jax.Array, jax.Array]:
    """A run's cells that kept their elite through a re-evaluation, and its cells filled after."""
    return kept_in_place(before, after), jnp.sum(
        jnp.any((after.fitnesses > -jnp.inf).reshape(len(after.fitnesses), -1), axis=1)
    )


def over_runs(run_fn: Any) -> Any:
    """`vmap(run_fn)` over a leading runs axis; for one run, `run_fn` of that run with the
    axis put back: the same results, bit for bit, and a rollout mapped over an axis of one
    ran ~10% slower on CPUs (XLA lays its arrays out with the extra axis)."""
    mapped = jax.vmap(run_fn)

    def over(*args: Any) -> Any:
        if jax.tree.leaves(args)[0].shape[0] != 1:
            return mapped(*args)
        return jax.tree.map(lambda x: x[None], run_fn(*jax.tree.map(lambda x: x[0], args)))

    return over


def in_run_groups(run_fn: Any, args: tuple[Any, ...], group: int, unbatched: bool = False) -> Any:
    """`vmap(run_fn)(*args)` computed a group of runs at a time (the largest divisor of the
    runs that is at most `group`), in a loop that reads its arguments in place: `lax.map`
    would copy every scanned argument whole, an archive among them. With `unbatched`, groups
    of one call `run_fn` on the run itself (for small arguments, such as a batch to score)."""
    runs = jax.tree.leaves(args)[0].shape[0]
    size = max(d for d in range(1, min(group, runs) + 1) if runs % d == 0)
    # unbatched: a group of one is `run_fn` of that run (`over_runs`); an archive stays
    # vmapped, which reads its slices in place (unbatched, XLA copied a run's slice)
    mapped = over_runs(run_fn) if unbatched else jax.vmap(run_fn)
    shapes = jax.eval_shape(mapped, *jax.tree.map(lambda x: x[:size], args))
    results = jax.tree.map(lambda s: _zeros((runs, *s.shape[1:]), s.dtype), shapes)

    def step(index: jax.Array, results: Any) -> Any:
        first = index * size
        part = mapped(*jax.tree.map(lambda x: jax.lax.dynamic_slice_in_dim(x, first, size), args))
        return jax.tree.map(lambda out, new: jax.lax.dynamic_update_slice_in_dim(out, new, first, 0), results, part)

    return jax.lax.fori_loop(0, runs // size, step, results)


def _repeated(tree: Any, runs: int) -> Any:
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (runs, *x.shape)), tree)


def _zeros(shape: tuple[int, ...], dtype: Any) -> jax.Array:
    if jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key):
        return jax.random.wrap_key_data(jnp.zeros(shape + jax.random.key_data(jax.random.key(0)).shape, jnp.uint32))
    return jnp.zeros(shape, dtype)


def choose(take: jax.Array, new: MapElitesRepertoire, old: MapElitesRepertoire) -> MapElitesRepertoire:
    """One run's archive: `new` where `take`, else `old` as it is."""
    return jax.tree.map(lambda a, b: jnp.where(take, a, b), new, old)


def split_in_two(keys: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Each of a batch of keys split in two: the first halves, and the second."""
    pairs = jax.vmap(jax.random.split)(keys)
    return pairs[:, 0], pairs[:, 1]


def stack_runs(trees: list[Any]) -> Any:
    """Stack per-run pytrees along a new leading runs axis."""
    return jax.tree.map(lambda *x: jnp.stack(x), *trees)


__all__ = ["Engine", "shared_engine", "shared_task", "stack_runs"]
