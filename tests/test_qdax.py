"""`smol_dsl.qdax`: QDax's scoring convention with a body, the phase-boundary step on QDax
repertoires, and the emitter hook; against QDax's own Brax scoring at alpha = 1."""

from __future__ import annotations

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from budget import examples
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.flatten_util import ravel_pytree
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire
from qdax_reference import KEY, qdax_env
from small_runs import CONFIG, small_task

import smol_dsl
from smol_dsl import qdax as smol
from smol_dsl.tasks import make_task
from smol_dsl.tasks.base import deterministic_init_state

EPISODE = CONFIG.episode_length
BATCH = 16  # the policies' batch, and _one_generation's: one compiled scoring for both


@pytest.fixture(scope="module")
def task():
    return small_task()


@pytest.fixture(scope="module")
def policies(task):
    return task.init_policies(jax.random.key(1), BATCH)


@pytest.fixture(scope="module")
def qdax_start(task):
    return deterministic_init_state(task.env, jax.random.key(KEY))  # the start of QDax's scoring for KEY


@pytest.fixture(scope="module")
def score(task, qdax_start):
    return smol.scoring_function(task, "smol", start=qdax_start)


@pytest.mark.slow
def test_at_alpha_one_fitnesses_descriptors_and_transitions_are_qdax_s(task, policies, score):
    """QDax's walker2d_uni scoring, as a QDax user runs it, and ours in the standard body:
    the same fitnesses and descriptors (to QDax's float rounding, as in test_tasks), and
    the same transitions until the episode ends, its last step done and truncated (at an end
    QDax's env restarts the episode, so its `next_obs` there is the restart's, ours the state
    reached; after an early end ours goes on; both are masked out of the fitness)."""
    from qdax.tasks.brax.descriptor_extractors import get_feet_contact_proportion
    from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn, get_mask_from_transitions

    qdax_score = create_brax_scoring_fn(
        qdax_env("walker2d_uni", EPISODE),
        task.policy,
        get_feet_contact_proportion,
        jax.random.key(KEY),
        episode_length=EPISODE,
    )
    theirs = qdax_score(policies, jax.random.key(KEY))
    ours = score(policies, jax.random.key(0), jnp.ones(1))
    np.testing.assert_allclose(ours[0], theirs[0], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ours[1], theirs[1], atol=1e-6)
    mine, qdax_transitions = ours[2]["transitions"], theirs[2]["transitions"]
    live = np.asarray(get_mask_from_transitions(qdax_transitions)) == 0  # (batch, steps) until the end
    assert live.all(axis=1).any()  # episodes that run to the last step
    np.testing.assert_array_equal(np.asarray(mine.truncations)[live.all(axis=1), -1], 1.0)
    going_on = live & (np.asarray(qdax_transitions.dones) == 0)  # QDax's next_* of an end are the restart's
    for field in ("obs", "next_obs", "rewards", "actions", "state_desc", "next_state_desc", "dones", "truncations"):
        a, b = np.asarray(getattr(mine, field)), np.asarray(getattr(qdax_transitions, field))
        assert a.shape == b.shape, field
        where = going_on if field.startswith("next") else live
        np.testing.assert_allclose(a[where], b[where], rtol=1e-4, atol=1e-4, err_msg=field)


@pytest.mark.slow
def test_flat_genotypes_score_as_the_policies_they_flatten(policies, score):
    flat = jax.vmap(lambda policy: ravel_pytree(policy)[0])(policies)
    body = jnp.asarray([1.2])
    as_policies, as_flat = score(policies, jax.random.key(0), body), score(flat, jax.random.key(0), body)
    np.testing.assert_array_equal(as_policies[0], as_flat[0])
    np.testing.assert_array_equal(as_policies[1], as_flat[1])


@pytest.mark.slow
def test_the_body_is_traced_one_compilation_for_every_phase(policies, score):
    """smol.sched's bodies, one per phase, all scored by the program of the first call."""
    bodies = list(smol.phase_bodies("smol", 10))
    first = score(policies, jax.random.key(0), bodies[0])[0]
    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kwargs: compiles.append(event) if event.endswith("backend_compile_duration") else None
    )
    results = [first] + [score(policies, jax.random.key(0), body)[0] for body in bodies[1:]]
    assert compiles == []  # the first call compiled the one program
    assert len({np.asarray(r).tobytes() for r in results}) > 1  # the bodies differ, and so do the scores


@pytest.mark.slow
def test_the_score_is_the_runner_s_rollout_in_the_body(task, policies, qdax_start):
    """`score` is `Task.score` (what the engine trains with), its non-finite results dropped."""
    body = jnp.asarray([0.8])
    fitnesses, descriptors, extra = smol.scoring_function(task, "smol", start=qdax_start, transitions=False)(
        policies, jax.random.key(0), body
    )
    expected = task.scoring_fn()(policies, body, qdax_start)
    np.testing.assert_array_equal(fitnesses, expected[0])
    np.testing.assert_array_equal(descriptors, expected[1])
    assert extra == {}


def test_bad_bodies_genotypes_and_schedules_are_value_errors(task, policies):
    score = smol.scoring_function(task, "smol")  # refusals come before its episode start is made
    with pytest.raises(ValueError, match=r"a \(1,\) array, one factor per channel \(gear\)"):
        score(policies, jax.random.key(0), jnp.ones(2))
    other = make_task("walker2d", episode_length=EPISODE, hidden_layer_sizes=(8,)).init_policies(jax.random.key(0), 4)
    with pytest.raises(ValueError, match="not a batch of walker2d's policies"):
        score(other, jax.random.key(0), jnp.ones(1))
    with pytest.raises(ValueError, match=r"flat genotypes are \(batch, 5702\)"):
        score(jnp.zeros((4, 7)), jax.random.key(0), jnp.ones(1))
    missing = smol_dsl.parse("channel gear[hip_1]\n  0% .. 90%: linear 0.5 -> 1 increasing\n  90% .. 100%: tail\n")
    with pytest.raises(ValueError, match="hip_1"):
        smol.scoring_function(task, missing)
    heavy = smol_dsl.parse("channel mass\n  0% .. 90%: constant 1e-30\n  90% .. 100%: tail\n")
    with pytest.raises(ValueError, match="mass"):
        smol.scoring_function(task, heavy)
    with pytest.raises(TypeError, match="a smol_dsl Task"):
        smol.scoring_function(42, "smol")


def _one_generation(task, score, body):
    genotypes = task.init_policies(jax.random.key(5), BATCH)  # `score`'s program of `policies`
    fitnesses, descriptors, _ = score(genotypes, jax.random.key(0), body)
    centroids = smol.run_start(task, 0, batch_size=1, num_centroids=32, num_init_cvt_samples=2000).centroids
    return MapElitesRepertoire.init(genotypes, fitnesses, descriptors, centroids)


@pytest.mark.slow
def test_reevaluation_in_the_same_body_keeps_every_elite_and_extinction_one_none(task, score):
    body = jnp.asarray([1.5])
    repertoire = _one_generation(task, score, body)
    filled = np.asarray(repertoire.fitnesses) > -np.inf
    assert filled.sum() > 1
    same = smol.reevaluate(repertoire, score, body, jax.random.key(1), batch_size=5)  # chunks of 5, padded
    # the same elites in the same cells; the fitnesses to float rounding (XLA compiles a batch of
    # 5 and one of BATCH differently)
    np.testing.assert_array_equal(np.asarray(same.fitnesses) > -np.inf, filled)
    np.testing.assert_allclose(np.asarray(same.fitnesses)[filled], np.asarray(repertoire.fitnesses)[filled], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(same.descriptors), np.asarray(repertoire.descriptors))
    gone = smol.reevaluate(repertoire, score, body, jax.random.key(1), extinction=1.0, batch_size=5)
    assert not np.any(np.asarray(gone.fitnesses) > -np.inf)
    weaker = smol.reevaluate(repertoire, score, jnp.asarray([0.5]), jax.random.key(1), batch_size=5)
    assert not np.array_equal(np.asarray(weaker.fitnesses), np.asarray(repertoire.fitnesses))
    with pytest.raises(TypeError, match="outside jit"):
        jax.jit(lambda r: smol.reevaluate(r, score, body, jax.random.key(1)).fitnesses)(repertoire)
    with pytest.raises(ValueError, match="extinction"):
        smol.reevaluate(repertoire, score, body, jax.random.key(1), extinction=1.5)


@pytest.mark.slow
def test_new_phase_ranks_cma_against_the_new_fitnesses_and_keeps_or_clears_replay(task, score):
    from qdax.core.emitters.cma_improvement_emitter import CMAImprovementEmitter
    from qdax.core.emitters.cma_pool_emitter import CMAPoolEmitter
    from qdax.core.neuroevolution.buffers.buffer import QDTransition, ReplayBuffer

    repertoire = _one_generation(task, score, jnp.asarray([1.0]))
    flat = jax.vmap(lambda g: ravel_pytree(g)[0])(repertoire.genotypes)
    repertoire = repertoire.replace(genotypes=flat)
    emitter = CMAPoolEmitter(3, CMAImprovementEmitter(4, flat.shape[1], repertoire.centroids, 0.05))
    state = emitter.init(jax.random.key(0), repertoire, flat[:4], None, None, {})
    assert not np.array_equal(state.emitter_states.previous_fitnesses[0], repertoire.fitnesses)
    updated = smol.new_phase(state, repertoire)
    assert updated.emitter_states.previous_fitnesses.shape == state.emitter_states.previous_fitnesses.shape
    for pooled in updated.emitter_states.previous_fitnesses:
        np.testing.assert_array_equal(pooled, repertoire.fitnesses)
    np.testing.assert_array_equal(updated.emitter_states.cmaes_state.mean, state.emitter_states.cmaes_state.mean)

    buffer = ReplayBuffer.init(10, QDTransition.init_dummy(observation_dim=3, action_dim=2, descriptor_dim=2))
    buffer = buffer.insert(QDTransition.init_dummy(observation_dim=3, action_dim=2, descriptor_dim=2))
    kept, cleared = (smol.new_phase((buffer, None), repertoire, replay=r)[0] for r in ("keep", "clear"))
    assert int(kept.current_size) == 1 and int(cleared.current_size) == 0
    assert smol.new_phase(None, repertoire) is None
    with pytest.raises(ValueError, match="replay"):
        smol.new_phase(state, repertoire, replay="drop")


@settings(max_examples=examples(200), deadline=None)
@given(st.integers(1, 400), st.data())
def test_phase_of_generation_gives_every_phase_an_equal_share_in_order(generations, data):
    num_phases = data.draw(st.integers(1, generations))
    phases = [smol.phase_of_generation(generation, generations, num_phases) for generation in range(1, generations + 1)]
    assert phases == sorted(phases) and phases[0] == 0 and phases[-1] == num_phases - 1
    shares = np.bincount(phases, minlength=num_phases)
    assert shares.min() >= 1 and shares.max() - shares.min() <= 1


def test_phase_bodies_are_the_runner_s_float32_bodies():
    bodies = smol.phase_bodies("growth", 20, smol.schedule_key(3))
    assert bodies.shape == (20, 2) and bodies.dtype == jnp.float32
    expected = smol_dsl.load("growth").checked_phase_values(20, smol.schedule_key(3))
    np.testing.assert_array_equal(bodies, expected.astype(np.float32))


def test_importing_it_imports_no_runner():
    code = "import sys, smol_dsl.qdax; print(sorted(m for m in sys.modules if m.startswith('smol_dsl.r')))"
    output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert output.strip() == "[]"
