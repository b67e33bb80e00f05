"""MAP-Elites with a changing body: one run's step, on QDax's ask/tell and archive.

`RunStep` is the single per-run step both `smol-dsl run` and `sweep` use (through
`smol_dsl.runner.engine`, which maps it over runs and devices). It is pure, with the body
(the factor of every scheduled channel: α, mass, friction, ...) a traced argument, so a
run of any number of phases compiles the same few programs:

- `generation`: offspring by iso+line variation of uniformly selected elites (QDax's
  `ask`), or fresh policies when the archive is empty (reseeding); the task's rollouts in
  the body; insertion into the CVT archive (QDax's `tell`) after non-finite results are
  dropped;
- re-evaluation: at a phase boundary, every filled cell is scored again in the new body,
  elites die with the schedule's extinction probability, and the survivors go into a fresh
  archive (collisions keep the best): `pick` a chunk of elites, `score` it, `insert` the
  survivors. It runs in fixed-size chunks over the filled cells only
  (`reevaluation_chunks`), so its cost is proportional to the filled cells.

Both are a choice of batch, the same scoring and an insertion (`RunStep`'s parts), which
the engine compiles separately so that the scoring is compiled once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire
from qdax.core.emitters.mutation_operators import isoline_variation
from qdax.core.emitters.standard_emitters import MixingEmitter
from qdax.core.map_elites import MAPElites
from qdax.utils.metrics import default_qd_metrics

from smol_dsl.qdax.reevaluation import insert_chunk, pick_chunk
from smol_dsl.qdax.scoring import LANE, drop_non_finite, initial_key, lanes

Metrics = dict[str, jax.Array]


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
) -> tuple[MapElitesRepertoire, Metrics, jax.Array]:
    """QDax's tell after non-finite results are dropped, every elite with its lane; also
    returns how many were dropped. (Iso+line variation of uniformly chosen elites keeps no
    emitter state.)"""
    fitnesses, descriptors, finite = drop_non_finite(fitnesses, descriptors)
    repertoire, _, metrics = map_elites.tell(
        genotypes=genotypes,
        fitnesses=fitnesses,
        descriptors=descriptors,
        repertoire=repertoire,
        emitter_state=None,
        extra_scores={LANE: lanes(fitnesses)},
    )
    return repertoire, metrics, jnp.sum(~finite)


def empty_archive(example_genotypes: Any, centroids: jax.Array) -> MapElitesRepertoire:
    """An archive with no elites on these centroids, for genotypes shaped like a batch's,
    that keeps every elite's lane (`smol_dsl.qdax.scoring.LANE`)."""
    one = jax.tree.map(lambda x: x[0], example_genotypes)
    lane = {LANE: jnp.zeros((), jnp.int32)}
    return MapElitesRepertoire.init_default(
        genotype=one, centroids=centroids, one_extra_score=lane, keys_extra_scores=(LANE,)
    )


@dataclass(frozen=True)
class RunStep:
    """One run's step of phased MAP-Elites, traced (not jitted): the engine maps it over
    runs and devices. `score(genotypes, body, start)` is the task's scoring of a batch in a
    body, the factors of the scheduled channels (the engine's, split across devices where it
    has several).

    Each step is three parts: choosing a batch (`ask` offspring, or `pick` elites to
    re-evaluate), `score` and inserting the results (`tell`, or `insert` survivors). The
    engine compiles each part as its own program, so that the rollout, nearly all of the
    compilation, is one program that generations and re-evaluations share; `generation`
    is the whole generation as one function (for loops of your own, as QDax's)."""

    map_elites: MAPElites
    init_policies: Callable[[jax.Array, int], Any]
    score: Callable[[Any, jax.Array, Any], tuple[jax.Array, jax.Array]]
    batch_size: int

    def ask(self, repertoire: MapElitesRepertoire, key: jax.Array) -> tuple[Any, jax.Array]:
        """Offspring of the archive's elites by iso+line variation, or fresh random policies
        if the archive is empty (the first generation, or after extinction emptied it);
        also whether it was empty."""
        ask_key = initial_key(key)  # as QDax's `MAPElites.update` asks with `key` (scoring is deterministic)
        empty = ~jnp.any(repertoire.fitnesses > -jnp.inf)
        genotypes = jax.lax.cond(
            empty,
            lambda: self.init_policies(ask_key, self.batch_size),
            lambda: self.map_elites.ask(repertoire, None, ask_key)[0],
        )
        return genotypes, empty

    def offspring(self, repertoire: MapElitesRepertoire, key: jax.Array) -> tuple[Any, jax.Array]:
        """`ask` for an archive known to hold elites: the same offspring, without making the
        fresh policies a reseed would need (under `vmap`, `ask`'s `cond` becomes a select
        that computes both branches every generation)."""
        return self.map_elites.ask(repertoire, None, initial_key(key))[0], jnp.asarray(False)

    def tell(
        self, repertoire: MapElitesRepertoire, genotypes: Any, fitnesses: jax.Array, descriptors: jax.Array
    ) -> tuple[MapElitesRepertoire, Metrics, jax.Array]:
        """The scored batch into the archive; returns it, QDax's metrics and how many results
        were non-finite (dropped)."""
        return tell_finite(self.map_elites, genotypes, fitnesses, descriptors, repertoire)

    def generation(
        self, repertoire: MapElitesRepertoire, body: jax.Array, start: Any, key: jax.Array
    ) -> tuple[MapElitesRepertoire, Metrics, jax.Array, jax.Array]:
        """One generation in `body`: asked, scored and told. Returns the archive, QDax's
        metrics, how many results were non-finite and whether it reseeded."""
        genotypes, empty = self.ask(repertoire, key)
        fitnesses, descriptors = self.score(genotypes, body, start)
        repertoire, metrics, dropped = self.tell(repertoire, genotypes, fitnesses, descriptors)
        return repertoire, metrics, dropped, empty

    def pick(self, source: Any, index: jax.Array, key: jax.Array) -> tuple[Any, jax.Array, jax.Array]:
        """The genotypes of `source` at `index`, to re-evaluate; the run's next key, and the
        key of this chunk's extinction draws."""
        genotypes, key, _, death_key = pick_chunk(source, index, key)  # episodes start deterministically
        return genotypes, key, death_key

    def insert(
        self,
        fresh: MapElitesRepertoire,
        genotypes: Any,
        fitnesses: jax.Array,
        descriptors: jax.Array,
        valid: jax.Array,
        extinction: jax.Array,
        death_key: jax.Array,
    ) -> tuple[MapElitesRepertoire, jax.Array, jax.Array]:
        """Re-scored elites that are `valid` (not padding), survive extinction and scored
        finite, into `fresh`; returns it, how many valid ones were non-finite and how many
        died (non-finite or by extinction)."""
        return insert_chunk(fresh, genotypes, fitnesses, descriptors, valid, extinction, death_key)
