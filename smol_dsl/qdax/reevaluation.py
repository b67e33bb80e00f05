"""The paper's phase-boundary step on any QDax repertoire: every elite re-scored in the new
body, thinned by extinction, inserted into a fresh repertoire.

The step runs in fixed-size chunks over the filled cells only (`reevaluation_chunks`), so
its cost follows the filled cells and each chunk size compiles once. Per chunk, the key is
split in three (the next chunk's key, the scoring key, the extinction draws' key:
`pick_chunk`), the survivors' results go into the fresh repertoire (`insert_chunk`) and
collisions keep the best; the runner's engine runs the same two functions over its runs,
so `reevaluate` with the run's batch size and key is the runner's re-evaluation.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl.language.curve import check_key
from smol_dsl.qdax.scoring import LANE, drop_non_finite, lanes

if TYPE_CHECKING:
    from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire

    from smol_dsl.qdax.scoring import Score

DEFAULT_CHUNK = 256  # elites scored per program: small enough for any task's memory, big enough to keep cores busy


def filled_cells(repertoire: MapElitesRepertoire) -> np.ndarray:
    """The indices of a repertoire's filled cells (read on the host: not traceable)."""
    try:
        fitnesses = np.asarray(repertoire.fitnesses)
    except jax.errors.TracerArrayConversionError:
        raise TypeError(
            "reevaluate reads which cells of the repertoire are filled, so it runs outside jit: call it between "
            "jitted updates, at a phase boundary"
        ) from None
    return np.flatnonzero((fitnesses > -np.inf).reshape(len(fitnesses), -1).any(axis=1))


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


def pick_chunk(genotypes: Any, index: jax.Array, key: jax.Array) -> tuple[Any, jax.Array, jax.Array, jax.Array]:
    """The genotypes at `index` to re-score; the next chunk's key, the scoring key and the
    key of this chunk's extinction draws."""
    key, score_key, death_key = jax.random.split(key, 3)
    return jax.tree.map(lambda x: x[index], genotypes), key, score_key, death_key


def insert_chunk(
    fresh: MapElitesRepertoire,
    genotypes: Any,
    fitnesses: jax.Array,
    descriptors: jax.Array,
    valid: jax.Array,
    extinction: jax.Array,
    death_key: jax.Array,
    extra_scores: dict[str, Any] | None = None,
) -> tuple[MapElitesRepertoire, jax.Array, jax.Array]:
    """Re-scored elites that are `valid` (not padding), survive extinction (each dies with
    probability `extinction`) and scored finite, into `fresh`, with the `extra_scores` it
    keeps (the scoring's, and each elite's lane: `LANE`); returns it, how many valid ones
    were non-finite, and how many died (non-finite or by extinction: never inserted)."""
    survives = jax.random.uniform(death_key, jnp.shape(valid)) >= extinction
    fitnesses, descriptors, finite = drop_non_finite(fitnesses, descriptors)
    inserted = valid & survives & finite
    fitnesses = jnp.where(inserted, fitnesses, -jnp.inf)
    extra_scores = {**(extra_scores or {}), LANE: lanes(fitnesses)}
    fresh = fresh.add(genotypes, descriptors, fitnesses, extra_scores)
    return fresh, jnp.sum(valid & ~finite), jnp.sum(valid & ~inserted)


def kept_in_place(before: MapElitesRepertoire, after: MapElitesRepertoire) -> jax.Array:
    """How many cells hold after re-evaluation the elite they held before (the same genotype,
    bit for bit: an elite's re-scored descriptor fell into its own cell and no better one
    took it). Elites are told apart by their genotypes, which no two cells share."""
    cells = before.fitnesses.shape[0]
    same = ((before.fitnesses > -jnp.inf) & (after.fitnesses > -jnp.inf)).reshape(cells, -1).any(axis=1)
    for old, new in zip(jax.tree.leaves(before.genotypes), jax.tree.leaves(after.genotypes), strict=True):
        same &= jnp.all((old == new).reshape(cells, -1), axis=1)
    return jnp.sum(same)


@dataclass(frozen=True)
class ReevaluationCounts:
    """What one re-evaluation did to every run's archive (arrays with a value per run).

    Every elite re-scored (`reevaluated`: the cells filled before) either `died` (scored
    NaN or infinite, `non_finite` of them, or removed by extinction), was `kept` in its own
    cell, `moved` to another cell, or `collided`: lost the cell its new descriptor fell in
    to a better elite. The cells filled after are `kept + moved`."""

    reevaluated: np.ndarray
    non_finite: np.ndarray
    died: np.ndarray
    kept: np.ndarray
    moved: np.ndarray
    collided: np.ndarray

    @classmethod
    def of(
        cls, reevaluated: np.ndarray, non_finite: np.ndarray, died: np.ndarray, kept: np.ndarray, filled: np.ndarray
    ) -> ReevaluationCounts:
        """The counts, from the elites re-scored, the non-finite and dead ones, the cells
        that kept their elite and the cells filled after."""
        survived = reevaluated - died
        return cls(reevaluated, non_finite, died, kept, filled - kept, survived - filled)

    @classmethod
    def none(cls, runs: int) -> ReevaluationCounts:
        """The counts of `runs` archives none of which was re-evaluated."""
        zeros = np.zeros(runs, dtype=np.int64)
        return cls(zeros, zeros, zeros, zeros, zeros, zeros)

    @property
    def filled(self) -> np.ndarray:
        """The cells filled after the re-evaluation."""
        return self.kept + self.moved


def emptied(repertoire: MapElitesRepertoire) -> MapElitesRepertoire:
    """The repertoire with no elites, on a copy of its centroids (what `init_default` makes;
    sharing no buffer with `repertoire`, so that it can be donated)."""
    return repertoire.replace(
        centroids=jnp.array(repertoire.centroids, copy=True),
        genotypes=jax.tree.map(jnp.zeros_like, repertoire.genotypes),
        fitnesses=jnp.full_like(repertoire.fitnesses, -jnp.inf),
        descriptors=jnp.zeros_like(repertoire.descriptors),
        extra_scores=jax.tree.map(jnp.zeros_like, repertoire.extra_scores),
    )


def _chunk(
    score: Score,
    source: Any,
    fresh: MapElitesRepertoire,
    index: jax.Array,
    valid: jax.Array,
    body: jax.Array,
    extinction: jax.Array,
    key: jax.Array,
) -> tuple[MapElitesRepertoire, jax.Array]:
    genotypes, key, score_key, death_key = pick_chunk(source, index, key)
    fitnesses, descriptors, extra_scores = score(genotypes, score_key, body)
    fresh, _, _ = insert_chunk(fresh, genotypes, fitnesses, descriptors, valid, extinction, death_key, extra_scores)
    return fresh, key


@cache
def _chunk_program(options: tuple[tuple[str, str], ...]) -> Any:
    """`_chunk` jitted with these compiler options (the scoring function's: its rollout is
    compiled into the chunk's program)."""
    return jax.jit(_chunk, static_argnames=("score",), donate_argnames=("fresh",), compiler_options=dict(options))


def reevaluate(
    repertoire: MapElitesRepertoire,
    score: Score,
    body: jax.Array,
    key: jax.Array,
    extinction: float = 0.0,
    *,
    batch_size: int = DEFAULT_CHUNK,
) -> MapElitesRepertoire:
    """Every filled cell of `repertoire` re-scored by `score` (from `scoring_function`) in
    `body`, each elite dying with probability `extinction`, the survivors inserted into a
    fresh repertoire on the same centroids (collisions keep the best; non-finite results are
    dropped). Runs outside jit, `batch_size` elites per compiled program; with the run's
    batch size and the key of `key, sub = split(key)` at the boundary it is `smol-dsl run`'s
    re-evaluation. A repertoire left empty must be reseeded before the next `emit`. A key
    that is not one JAX random key is a TypeError."""
    if not 0.0 <= float(extinction) <= 1.0:
        raise ValueError(f"extinction {extinction!r}: a probability from 0 to 1")
    check_key(key, none_allowed=False)
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size {batch_size!r}: a whole number of elites per program, at least 1")
    filled = filled_cells(repertoire)
    fresh = emptied(repertoire)
    body = jnp.asarray(body, jnp.float32)
    rate = jnp.asarray(extinction, jnp.float32)
    chunk = _chunk_program(tuple(sorted((getattr(score, "compiler_options", None) or {}).items())))
    for index, valid in reevaluation_chunks([filled], batch_size):
        fresh, key = chunk(score, repertoire.genotypes, fresh, index[0], valid[0], body, rate, key)
    return fresh
