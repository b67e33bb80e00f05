"""Many phased MAP-Elites runs as one program: runs are an axis of the computation.

Every run of a sweep has the same task and settings but its own seed, schedule and
archive, and all runs reach their phase boundaries together. So one jitted program
advances every run by one generation, and one re-evaluates every archive, with each run's
α a traced value. With `jax.shard_map` over a (runs, population) device mesh, runs are
split across devices (independent: no communication), and devices left over split each
offspring batch (its rollouts are gathered back). On each device the local runs are
either vmapped together (accelerators: one big batch) or mapped one after another inside
the program (`runs_per_step`; CPUs, where rollouts slow down as batches grow past ~128).

Per run, the programs do exactly what `PhasedMapElites` does for a single run, with the
same random keys, so a sweep's run follows the same algorithm and random streams as
`smol-dsl run` of that seed.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire
from qdax.utils.metrics import default_qd_metrics

from smol_dsl.runner.algorithm import (
    empty_archive,
    insert_survivors,
    make_map_elites,
    reevaluation_chunks,
    tell_finite,
)
from smol_dsl.tasks import Task

RUNS = "runs"
POPULATION = "population"


def mesh_shape(devices: int, runs: int, batch_size: int) -> tuple[int, int]:
    """How to lay `devices` out as (runs axis, population axis).

    Runs are split first: the runs axis gets the largest divisor of the device count that
    is at most the number of runs. The devices left over split each run's population,
    when the batch divides evenly; otherwise they stay idle.
    """
    along_runs = max(d for d in range(1, devices + 1) if devices % d == 0 and d <= max(runs, 1))
    along_population = devices // along_runs
    if batch_size % along_population:
        along_population = 1
    return along_runs, along_population


def default_runs_per_step(devices: list[jax.Device]) -> int | None:
    """How many runs a device advances at once: all of them (None) on accelerators, one
    at a time on CPUs, where a bigger batch lowers rollout throughput."""
    return 1 if devices[0].platform == "cpu" else None


class BatchedMapElites:
    """Jitted programs that advance R runs at once, sharded over `devices`.

    The devices form a (runs, population) mesh (`mesh_shape`): runs are split across the
    first axis; along the second, each device scores its share of every offspring batch
    and the shares are gathered, so a sweep with fewer runs than devices still uses them
    all. Every array argument and result has the runs axis first; R must be a multiple of
    the runs axis (`padded_runs`).
    """

    def __init__(
        self,
        task: Task,
        *,
        batch_size: int,
        iso_sigma: float,
        line_sigma: float,
        devices: list[jax.Device] | None = None,
        runs_per_step: int | None = -1,
        num_runs: int | None = None,
    ) -> None:
        self.task = task
        self.batch_size = batch_size
        devices = list(devices) if devices is not None else jax.local_devices()
        self.runs_per_step = default_runs_per_step(devices) if runs_per_step == -1 else runs_per_step
        along_runs, self.population_devices = mesh_shape(
            len(devices), len(devices) if num_runs is None else num_runs, batch_size
        )
        self.devices = devices[: along_runs * self.population_devices]
        grid = np.asarray(self.devices).reshape(along_runs, self.population_devices)
        self.mesh = Mesh(grid, (RUNS, POPULATION))
        self.sharding = NamedSharding(self.mesh, PartitionSpec(RUNS))
        self.map_elites = make_map_elites(batch_size, task.qd_offset, iso_sigma, line_sigma)
        self._step = self._over_runs(self._run_step, donate=(0,))
        self._reevaluate_chunk = self._over_runs(self._run_reevaluate_chunk, donate=(0,))
        self._metrics = self._over_runs(lambda archive: default_qd_metrics(archive, task.qd_offset))
        self._split = jax.jit(jax.vmap(jax.random.split))

    def padded_runs(self, runs: int) -> int:
        """The number of runs rounded up to a multiple of the runs axis."""
        along_runs = self.mesh.shape[RUNS]
        return -(-runs // along_runs) * along_runs

    def put(self, tree: Any) -> Any:
        """Place arrays with a leading runs axis on the devices, split along that axis."""
        return jax.device_put(tree, self.sharding)

    # ------------------------------------------------------------------ per-run programs
    def _over_runs(self, run_fn: Any, donate: tuple[int, ...] = ()) -> Any:
        runs_per_step = self.runs_per_step

        def local(*args: Any) -> Any:
            local_runs = jax.tree.leaves(args)[0].shape[0]
            if runs_per_step is None or runs_per_step >= local_runs:
                return jax.vmap(run_fn)(*args)
            return jax.lax.map(lambda a: run_fn(*a), args, batch_size=runs_per_step)

        spec = PartitionSpec(RUNS)
        sharded = jax.shard_map(local, mesh=self.mesh, in_specs=spec, out_specs=spec, check_vma=False)
        return jax.jit(sharded, donate_argnums=donate)

    def _score(self, genotypes: Any, alpha: jax.Array, start: Any) -> tuple[jax.Array, jax.Array]:
        """Score one run's batch; along the population axis each device rolls out its
        share, and the shares are gathered in order."""
        shares = self.population_devices
        if shares == 1:
            return self.task.score(genotypes, alpha, start)
        size = self.batch_size // shares
        first = jax.lax.axis_index(POPULATION) * size
        mine = jax.tree.map(lambda x: jax.lax.dynamic_slice_in_dim(x, first, size), genotypes)
        fitnesses, descriptors = self.task.score(mine, alpha, start)
        gather = partial(jax.lax.all_gather, axis_name=POPULATION, tiled=True)
        return gather(fitnesses), gather(descriptors)

    def _run_step(
        self, repertoire: MapElitesRepertoire, alpha: jax.Array, start: Any, key: jax.Array
    ) -> tuple[MapElitesRepertoire, dict[str, jax.Array], jax.Array, jax.Array]:
        """One generation of one run; an empty archive is reseeded with fresh policies."""
        ask_key, score_key = jax.random.split(key)
        del score_key  # episodes start deterministically; split as the single run does
        empty = ~jnp.any(repertoire.fitnesses > -jnp.inf)
        genotypes = jax.lax.cond(
            empty,
            lambda: self.task.init_policies(ask_key, self.batch_size),
            lambda: self.map_elites.ask(repertoire, None, ask_key)[0],
        )
        fitnesses, descriptors = self._score(genotypes, alpha, start)
        repertoire, _, metrics, dropped = tell_finite(
            self.map_elites, genotypes, fitnesses, descriptors, repertoire, None
        )
        return repertoire, metrics, dropped, empty

    def _run_reevaluate_chunk(
        self,
        fresh: MapElitesRepertoire,
        source: Any,
        index: jax.Array,
        valid: jax.Array,
        alpha: jax.Array,
        start: Any,
        extinction: jax.Array,
        key: jax.Array,
    ) -> tuple[MapElitesRepertoire, jax.Array, jax.Array]:
        """Re-score one chunk of one run's elites and insert the survivors into `fresh`."""
        key, score_key, death_key = jax.random.split(key, 3)
        del score_key
        genotypes = jax.tree.map(lambda x: x[index], source)
        fitnesses, descriptors = self._score(genotypes, alpha, start)
        survives = jax.random.uniform(death_key, (self.batch_size,)) >= extinction
        fresh, dropped = insert_survivors(fresh, genotypes, fitnesses, descriptors, valid, survives)
        return fresh, key, dropped

    # ------------------------------------------------------------------ batched API
    def empty_archives(self, centroids: jax.Array) -> MapElitesRepertoire:
        """One empty archive per run, on its centroids (R, C, D)."""
        template = self.task.init_policies(jax.random.key(0), 1)
        archives = [empty_archive(template, c) for c in centroids]
        return self.put(stack_runs(archives))

    def split(self, keys: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Split every run's key in two, as `state.key, key = split(state.key)` does."""
        pairs = self._split(keys)
        return pairs[:, 0], pairs[:, 1]

    def step(
        self, repertoires: MapElitesRepertoire, alphas: jax.Array, starts: Any, keys: jax.Array
    ) -> tuple[MapElitesRepertoire, dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """One generation of every run (the archives are donated). Returns the archives,
        each run's metrics, non-finite results and whether it was reseeded."""
        repertoires, metrics, dropped, reseeded = self._step(repertoires, alphas, starts, keys)
        metrics, dropped, reseeded = jax.device_get((metrics, dropped, reseeded))
        return repertoires, metrics, np.asarray(dropped), np.asarray(reseeded)

    def reevaluate(
        self,
        repertoires: MapElitesRepertoire,
        alphas: jax.Array,
        starts: Any,
        extinctions: jax.Array,
        keys: jax.Array,
    ) -> tuple[MapElitesRepertoire, np.ndarray, np.ndarray]:
        """Every run's elites re-scored at its alpha, thinned by its extinction, in fresh
        archives. Chunks run over the filled cells only (up to the fullest archive).
        Returns the archives, and per run the elites re-evaluated and the non-finite ones."""
        filled_mask = np.asarray(repertoires.fitnesses) > -np.inf
        filled = [np.flatnonzero(row) for row in filled_mask]
        fresh = self.empty_archives(repertoires.centroids)
        non_finite = np.zeros(len(filled), dtype=np.int64)
        for index, valid in reevaluation_chunks(filled, self.batch_size):
            fresh, keys, dropped = self._reevaluate_chunk(
                fresh,
                repertoires.genotypes,
                self.put(jnp.asarray(index)),
                self.put(jnp.asarray(valid)),
                alphas,
                starts,
                extinctions,
                keys,
            )
            non_finite += np.asarray(dropped)
        return fresh, np.asarray([len(f) for f in filled]), non_finite

    def metrics(self, repertoires: MapElitesRepertoire) -> dict[str, np.ndarray]:
        """QDax's coverage, max fitness and QD score of every run's archive."""
        return jax.device_get(self._metrics(repertoires))


def stack_runs(trees: list[Any]) -> Any:
    """Stack per-run pytrees along a new leading runs axis."""
    return jax.tree.map(lambda *x: jnp.stack(x), *trees)


__all__ = ["BatchedMapElites", "default_runs_per_step", "mesh_shape", "stack_runs"]
