"""MAP-Elites with a changing body: QDax's ask/tell loop, α-aware scoring, re-evaluation.

The pieces are pure and jitted once each, with α a traced argument, so a run of any number
of phases compiles the same few programs:

- `ask`: offspring by iso+line variation of uniformly selected elites (QDax);
- `score`: the task's rollouts at actuator scale α;
- `tell`: insertion into the CVT archive (QDax), after non-finite results are dropped;
- `reevaluate`: at a phase boundary, every filled cell is scored again under the new α,
  elites die with the schedule's extinction probability, and the survivors go into a
  fresh archive (collisions keep the best). It runs in fixed-size chunks over the filled
  cells only, so its cost is proportional to the filled cells, not to the archive's size.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import lru_cache, partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire, compute_cvt_centroids
from qdax.core.emitters.mutation_operators import isoline_variation
from qdax.core.emitters.standard_emitters import MixingEmitter
from qdax.core.map_elites import MAPElites
from qdax.utils.metrics import default_qd_metrics

from smol_dsl.tasks.base import ScoringFn

Metrics = dict[str, jax.Array]


def drop_non_finite(fitnesses: jax.Array, descriptors: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Mark results with a non-finite fitness or descriptor as empty (-inf, never inserted).

    Returns the cleaned fitnesses and descriptors, and which results were finite.
    """
    finite = jnp.isfinite(fitnesses) & jnp.all(jnp.isfinite(descriptors), axis=-1)
    fitnesses = jnp.where(finite, fitnesses, -jnp.inf)
    descriptors = jnp.where(finite[:, None], descriptors, 0.0)
    return fitnesses, descriptors, finite


def make_map_elites(batch_size: int, qd_offset: float, iso_sigma: float, line_sigma: float) -> MAPElites:
    """QDax's MAP-Elites with iso+line variation of uniformly selected elites; it is only
    asked and told (scoring is ours, α-aware)."""
    emitter = MixingEmitter(
        mutation_fn=None,  # type: ignore[arg-type]
        variation_fn=partial(isoline_variation, iso_sigma=iso_sigma, line_sigma=line_sigma),
        variation_percentage=1.0,
        batch_size=batch_size,
    )
    return MAPElites(
        scoring_function=None,
        emitter=emitter,
        metrics_function=partial(default_qd_metrics, qd_offset=qd_offset),
    )


def tell_finite(
    map_elites: MAPElites,
    genotypes: Any,
    fitnesses: jax.Array,
    descriptors: jax.Array,
    repertoire: MapElitesRepertoire,
    emitter_state: Any,
) -> tuple[MapElitesRepertoire, Any, Metrics, jax.Array]:
    """QDax's tell after non-finite results are dropped; also returns how many were dropped."""
    fitnesses, descriptors, finite = drop_non_finite(fitnesses, descriptors)
    repertoire, emitter_state, metrics = map_elites.tell(
        genotypes=genotypes,
        fitnesses=fitnesses,
        descriptors=descriptors,
        repertoire=repertoire,
        emitter_state=emitter_state,
    )
    return repertoire, emitter_state, metrics, jnp.sum(~finite)


def insert_survivors(
    archive: MapElitesRepertoire,
    genotypes: Any,
    fitnesses: jax.Array,
    descriptors: jax.Array,
    valid: jax.Array,
    survives: jax.Array,
) -> tuple[MapElitesRepertoire, jax.Array]:
    """Insert re-evaluated elites that are valid (not padding), survived extinction and
    scored finite; also returns how many valid ones were non-finite."""
    fitnesses, descriptors, finite = drop_non_finite(fitnesses, descriptors)
    fitnesses = jnp.where(valid & survives, fitnesses, -jnp.inf)
    return archive.add(genotypes, descriptors, fitnesses), jnp.sum(valid & ~finite)


def empty_archive(example_genotypes: Any, centroids: jax.Array) -> MapElitesRepertoire:
    """An archive with no elites on these centroids, for genotypes shaped like a batch's."""
    one = jax.tree.map(lambda x: x[0], example_genotypes)
    return MapElitesRepertoire.init_default(genotype=one, centroids=centroids)


def reevaluation_chunks(filled: list[np.ndarray], batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Fixed-size chunks over each run's filled cells, up to the fullest run: per chunk,
    cell indices and which of them are real, both (runs, batch_size). A short chunk is
    padded by repeating its cells (padding is not kept); a run with no cells left gets an
    all-invalid row."""
    for start in range(0, max((len(cells) for cells in filled), default=0), batch_size):
        index = np.zeros((len(filled), batch_size), dtype=np.int32)
        valid = np.zeros((len(filled), batch_size), dtype=bool)
        for run, cells in enumerate(filled):
            chunk = cells[start : start + batch_size]
            if len(chunk):
                index[run] = np.resize(chunk, batch_size)
                valid[run, : len(chunk)] = True
        yield index, valid


@dataclass(frozen=True)
class Evaluation:
    """What one scored batch contributed: counts for the metrics log."""

    evaluated: int
    non_finite: int


class PhasedMapElites:
    """The jitted building blocks of a phased MAP-Elites run for one scoring function."""

    def __init__(
        self,
        scoring_fn: ScoringFn,
        init_genotypes: Callable[[jax.Array, int], Any],
        *,
        batch_size: int,
        qd_offset: float,
        iso_sigma: float,
        line_sigma: float,
    ) -> None:
        self.batch_size = batch_size
        self.init_genotypes = init_genotypes
        self.map_elites = make_map_elites(batch_size, qd_offset, iso_sigma, line_sigma)
        # an already-jitted scoring function is used as is, keeping its compilation cache
        self.score = scoring_fn if hasattr(scoring_fn, "lower") else jax.jit(scoring_fn)
        self._tell = jax.jit(partial(tell_finite, self.map_elites))
        self._insert = jax.jit(insert_survivors)
        self.metrics = jax.jit(partial(default_qd_metrics, qd_offset=qd_offset))
        self._gather = jax.jit(lambda tree, index: jax.tree.map(lambda x: x[index], tree))
        # A generation is one program: variation, rollouts and insertion fused, and the
        # archive's buffers donated so that insertion updates them in place.
        self._generation = jax.jit(self._generation_step, donate_argnums=(0,))

    # ------------------------------------------------------------------ training
    def init(
        self, centroids: jax.Array, alpha: jax.Array, key: jax.Array
    ) -> tuple[MapElitesRepertoire, Any, Metrics, Evaluation]:
        """Score a random initial population at alpha and build the first archive."""
        template = self.init_genotypes(jax.random.key(0), 1)  # only its shapes are used
        return self.reseed(self.empty_archive(template, centroids), None, alpha, key)

    def _generation_step(
        self, repertoire: MapElitesRepertoire, emitter_state: Any, alpha: jax.Array, key: jax.Array
    ) -> tuple[MapElitesRepertoire, Any, Metrics, jax.Array]:
        ask_key, score_key = jax.random.split(key)
        genotypes, _ = self.map_elites.ask(repertoire, emitter_state, ask_key)
        fitnesses, descriptors, _ = self.score(genotypes, alpha, score_key)
        return tell_finite(self.map_elites, genotypes, fitnesses, descriptors, repertoire, emitter_state)

    def generation(
        self, repertoire: MapElitesRepertoire, emitter_state: Any, alpha: jax.Array, key: jax.Array
    ) -> tuple[MapElitesRepertoire, Any, Metrics, Evaluation]:
        """One MAP-Elites generation at actuator scale alpha.

        The archive passed in is donated: use only the one returned.
        """
        repertoire, emitter_state, metrics, dropped = self._generation(repertoire, emitter_state, alpha, key)
        return repertoire, emitter_state, metrics, Evaluation(self.batch_size, int(dropped))

    def reseed(
        self, repertoire: MapElitesRepertoire, emitter_state: Any, alpha: jax.Array, key: jax.Array
    ) -> tuple[MapElitesRepertoire, Any, Metrics, Evaluation]:
        """A generation of fresh random policies: the first one, or after extinction emptied the archive."""
        init_key, score_key = jax.random.split(key)
        genotypes = self.init_genotypes(init_key, self.batch_size)
        fitnesses, descriptors, _ = self.score(genotypes, alpha, score_key)
        repertoire, emitter_state, metrics, dropped = self._tell(
            genotypes, fitnesses, descriptors, repertoire, emitter_state
        )
        return repertoire, emitter_state, metrics, Evaluation(self.batch_size, int(dropped))

    # ------------------------------------------------------------------ re-evaluation
    empty_archive = staticmethod(empty_archive)

    def reevaluate(
        self, repertoire: MapElitesRepertoire, alpha: jax.Array, extinction: float, key: jax.Array
    ) -> tuple[MapElitesRepertoire, Evaluation]:
        """Every elite re-scored at alpha, thinned by extinction, in a fresh archive."""
        filled = np.flatnonzero(np.asarray(repertoire.fitnesses).reshape(-1) > -np.inf)
        fresh = self.empty_archive(repertoire.genotypes, repertoire.centroids)
        non_finite = 0
        for indices, valids in reevaluation_chunks([filled], self.batch_size):
            index, valid = indices[0], valids[0]
            genotypes = self._gather(repertoire.genotypes, jnp.asarray(index))
            key, score_key, death_key = jax.random.split(key, 3)
            fitnesses, descriptors, _ = self.score(genotypes, alpha, score_key)
            survives = jax.random.uniform(death_key, (self.batch_size,)) >= extinction
            fresh, dropped = self._insert(fresh, genotypes, fitnesses, descriptors, jnp.asarray(valid), survives)
            non_finite += int(dropped)
        return fresh, Evaluation(len(filled), non_finite)


@lru_cache(maxsize=16)
def phased_map_elites(
    scoring_fn: ScoringFn,
    init_genotypes: Callable[[jax.Array, int], Any],
    batch_size: int,
    qd_offset: float,
    iso_sigma: float,
    line_sigma: float,
) -> PhasedMapElites:
    """A shared PhasedMapElites per setting, so runs in one process reuse compilations."""
    return PhasedMapElites(
        scoring_fn,
        init_genotypes,
        batch_size=batch_size,
        qd_offset=qd_offset,
        iso_sigma=iso_sigma,
        line_sigma=line_sigma,
    )


def cvt_centroids(
    num_centroids: int, low: tuple[float, ...], high: tuple[float, ...], num_samples: int, key: jax.Array
) -> jax.Array:
    """QDax's CVT tessellation of the descriptor box."""
    return compute_cvt_centroids(
        num_descriptors=len(low),
        num_init_cvt_samples=num_samples,
        num_centroids=num_centroids,
        minval=list(low),
        maxval=list(high),
        key=key,
    )
