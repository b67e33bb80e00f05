"""Our MAP-Elites step (`runner.map_elites.RunStep`) against QDax's own loop, at alpha = 1.

The reference is QDax as a QDax user runs it: `MAPElites(scoring_function, emitter,
metrics).init` then `update` generation after generation, scored by QDax's own walker2d_uni
(`create_brax_scoring_fn`), with the same iso+line emitter, on the same seeds, policies and
centroids. Our loop is `RunStep.generation`, as the engine runs it.

The two loops are given the same key per generation (`key, sub = split(key)`, then a step
with `sub`) and split it alike (both ask with `split(sub)[1]`), so they draw the same offspring
from the same archive and train alike: the test compares the initial archives cell by cell
(the same policies), the metrics of every generation (to float rounding: QDax's env wrappers
may round a reward differently in the last bit, as in test_tasks), the invariants of
MAP-Elites at a fixed body in both loops, and that both improve on their initial archive.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from smol_dsl.qdax.scoring import cvt_centroids, initial_key
from smol_dsl.rundir.config import ISO_SIGMA, LINE_SIGMA
from smol_dsl.runner.map_elites import RunStep, empty_archive, make_map_elites
from smol_dsl.tasks import make_task
from smol_dsl.tasks.base import deterministic_init_state

pytestmark = pytest.mark.slow

SEEDS = 8
GENERATIONS = 24
EPISODE = 20
BATCH = 16
CELLS = 32
METRICS = ("coverage", "max_fitness", "qd_score")


def seed_loops():
    """Per seed: (QDax's, ours) initial archives and the metrics of the initial archive and of
    every generation, jitted over seeds."""
    import qdax.tasks.brax.v2 as qdax_envs
    from qdax.core.map_elites import MAPElites
    from qdax.tasks.brax.descriptor_extractors import get_feet_contact_proportion
    from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn
    from qdax.utils.metrics import default_qd_metrics

    task = make_task("walker2d", episode_length=EPISODE, hidden_layer_sizes=(8, 8))
    env = qdax_envs.create("walker2d_uni", episode_length=EPISODE)
    qdax_score = create_brax_scoring_fn(
        env, task.policy, get_feet_contact_proportion, jax.random.key(3), episode_length=EPISODE
    )
    start = deterministic_init_state(task.env, jax.random.key(3))  # the episode start QDax's scoring uses
    ours = make_map_elites(BATCH, task.qd_offset, ISO_SIGMA, LINE_SIGMA)
    qdax = MAPElites(
        scoring_function=qdax_score,
        emitter=ours._emitter,
        metrics_function=partial(default_qd_metrics, qd_offset=task.qd_offset),
    )
    step = RunStep(ours, task.init_policies, task.score, BATCH)
    body = jnp.ones(1)

    def qdax_loop(key, init_key, centroids):
        genotypes = task.init_policies(initial_key(init_key), BATCH)  # what our first step draws
        first, _, initial = qdax.init(genotypes, centroids, init_key)

        def generation(carry, _):
            repertoire, key = carry
            key, sub = jax.random.split(key)
            repertoire, _, metrics = qdax.update(repertoire, None, sub)
            return (repertoire, key), metrics

        _, metrics = jax.lax.scan(generation, (first, key), None, length=GENERATIONS)
        return first, jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), initial, metrics)

    def our_loop(key, init_key, centroids):
        def next_key(key, _):
            key, sub = jax.random.split(key)
            return key, sub

        _, subs = jax.lax.scan(next_key, key, None, length=GENERATIONS)
        keys = jnp.concatenate([init_key[None], subs])  # the first step seeds the empty archive

        def generation(repertoire, key):
            repertoire, metrics, dropped, reseeded = step.generation(repertoire, body, start, key)
            return repertoire, (repertoire, metrics, dropped, reseeded)

        empty = empty_archive(task.init_policies(jax.random.key(0), 1), centroids)
        _, (archives, metrics, dropped, reseeded) = jax.lax.scan(generation, empty, keys)
        first = jax.tree.map(lambda x: x[0], archives)
        return first, metrics, dropped.sum(), reseeded[0], reseeded[1:]

    # per seed, as a run of that seed splits it: its main key, CVT centroids and initial key
    keys, init_keys, centroids = [], [], []
    for seed in range(SEEDS):
        key, cvt_key, init_key = jax.random.split(jax.random.key(seed), 3)
        keys.append(key)
        init_keys.append(init_key)
        centroids.append(cvt_centroids(CELLS, task.descriptor_low, task.descriptor_high, 2000, cvt_key))
    inputs = (jnp.stack(keys), jnp.stack(init_keys), jnp.stack(centroids))
    options = task.compiler_options()  # the engine's: faster to compile on CPUs, the same results bit for bit
    return (
        jax.jit(jax.vmap(qdax_loop), compiler_options=options)(*inputs),
        jax.jit(jax.vmap(our_loop), compiler_options=options)(*inputs),
    )


@pytest.fixture(scope="module")
def loops():
    return jax.device_get(seed_loops())


def test_the_initial_archives_are_qdax_s(loops):
    """The same initial policies give the same archive: the same cells, fitnesses (to QDax's
    float rounding, as in test_tasks) and descriptors, and the same policies in them."""
    (qdax_first, _), (our_first, _, dropped, reseeded, _) = loops
    assert np.all(reseeded) and np.all(dropped == 0)  # the empty archive was seeded; nothing non-finite
    filled = np.asarray(qdax_first.fitnesses).reshape(SEEDS, CELLS) > -np.inf
    assert filled.any(axis=1).all()
    ours, theirs = (np.asarray(first.fitnesses).reshape(SEEDS, CELLS) for first in (our_first, qdax_first))
    np.testing.assert_array_equal(ours > -np.inf, filled)
    np.testing.assert_allclose(ours[filled], theirs[filled], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(our_first.descriptors[filled], qdax_first.descriptors[filled], atol=1e-6)
    for ours, theirs in zip(jax.tree.leaves(our_first.genotypes), jax.tree.leaves(qdax_first.genotypes), strict=True):
        np.testing.assert_array_equal(ours[filled], theirs[filled])


def test_every_generation_keeps_the_invariants_of_map_elites(loops):
    """At a fixed body an archive only improves: coverage, max fitness and QD score never
    decrease, in either loop; ours never reseeds a filled archive."""
    (_, qdax_metrics), (_, our_metrics, _, _, reseeded) = loops
    assert not np.any(reseeded)
    for metrics in (qdax_metrics, our_metrics):
        for name in METRICS:
            values = np.asarray(metrics[name])  # (seeds, generations)
            assert np.all(np.diff(values, axis=1) >= -1e-4 * np.abs(values[:, 1:])), name


def test_both_loops_train_alike_generation_by_generation(loops):
    """The same keys, the same offspring: coverage, max fitness and QD score agree in every
    generation of every seed, and in every seed both loops improve on their initial archive."""
    (_, qdax_metrics), (_, our_metrics, _, _, _) = loops
    for name in METRICS:
        ours, theirs = np.asarray(our_metrics[name]), np.asarray(qdax_metrics[name])  # (seeds, generations)
        assert ours.shape == theirs.shape == (SEEDS, GENERATIONS + 1)
        np.testing.assert_allclose(ours, theirs, rtol=1e-5, atol=1e-5, err_msg=name)
    for metrics in (qdax_metrics, our_metrics):
        qd = np.asarray(metrics["qd_score"])
        assert np.all(qd[:, -1] > qd[:, 0]), qd[:, [0, -1]]
