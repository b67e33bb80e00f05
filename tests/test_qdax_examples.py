"""The QDax examples, run at the run-level tests' size: QDax's MAP-Elites under smol.sched is
`smol-dsl run`; PGA-ME under human.sched and CMA-ME under three channels train and improve."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import jax
import numpy as np
import pytest
from small_runs import SETTINGS, small_config, small_task

import smol_dsl
from smol_dsl.runner import run_experiment

pytestmark = pytest.mark.slow

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SIZES = dict(SETTINGS, hidden_layer_sizes=small_config().hidden_layer_sizes, num_init_cvt_samples=5000)


def example(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def phases_recorded(history, bodies) -> None:
    """Every generation's row names its phase, in order, and every phase was trained in."""
    phases = [row["phase"] for row in history]
    assert phases == sorted(phases) and set(phases) == set(range(len(bodies)))


@pytest.mark.parametrize("schedule", ["smol", "smol-paced"])
def test_qdax_map_elites_under_smol_is_smol_dsl_run(schedule):
    """The same seed and settings: QDax's own `MAPElites.init`/`update` loop with smol-dsl's
    scoring, re-evaluation and first draws ends with `smol-dsl run`'s archive: the same elites
    in the same cells, bit for bit, with the same fitnesses to float32 rounding, and it logs
    its metrics. Both on one device, as the example's loop runs: sharded over two, the
    runner's population is scored by another program, which jax 0.12's CPU compiler can
    round differently, enough to change which of two close candidates keeps a cell (measured
    under SMOL-paced; test_devices holds sharded runs to fitnesses within 1e-5). (The rollout is
    compiled inside QDax's fused `update` there and as the runner's own scoring program here;
    jax 0.12 can round a step's physics differently in the two: 1 ulp of fitness in 1 of 32
    cells, measured.) Under SMOL-paced the loop's pacing decisions (`smol.pace`) take the
    runner's: the same bodies, phase by phase."""
    repertoire, bodies, history = example("qdax_map_elites").main(schedule, seed=2, **SIZES)
    config = small_config(seed=2, num_init_cvt_samples=5000)
    result = run_experiment(small_task(), smol_dsl.load(schedule), config, devices=jax.devices()[:1])
    if schedule == "smol-paced":  # the condition held at some boundaries and not at others
        assert {row["event"] for row in result.metrics} >= {"hold", "reevaluate"}
    np.testing.assert_array_equal(bodies, result.bodies)
    ours = result.repertoire
    theirs_fitness, our_fitness = np.asarray(repertoire.fitnesses), np.asarray(ours.fitnesses)
    np.testing.assert_array_equal(theirs_fitness > -np.inf, our_fitness > -np.inf)
    np.testing.assert_allclose(theirs_fitness, our_fitness, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(repertoire.descriptors), np.asarray(ours.descriptors))
    for theirs, mine in zip(
        (np.asarray(x) for x in jax.tree.leaves(repertoire.genotypes)),
        (np.asarray(x) for x in jax.tree.leaves(ours.genotypes)),
        strict=True,
    ):
        np.testing.assert_array_equal(theirs, mine)
    trained = [row for row in result.metrics if row["event"] not in ("reevaluate", "hold")]
    assert len(trained) == len(history)
    np.testing.assert_allclose([row["qd_score"] for row in history], [row["qd_score"] for row in trained], rtol=1e-6)
    phases_recorded(history, bodies)


def initial_in_final_body(task, schedule_name, seed, trained, flat=False, transitions=True):
    """QDax's metrics of the run's initial population, scored in the schedule's final body:
    what the trained repertoire (in that body) must beat. At this size (32 cells, 20-step
    episodes, 12 generations) re-evaluations in new bodies gather the few elites into one or
    two cells, so the trained repertoire is held to a better best policy, not to coverage.

    The initial policies are scored by the example's own compiled re-evaluation program (its
    scoring function, `transitions` as the example asks, and its batch size; loaded, not
    compiled again): each placed in a cell of its own of the `trained` repertoire's
    structure, then `smol.reevaluate` with no extinction scores them all in the final body
    and inserts them into a fresh repertoire on the run's centroids, collisions keeping the
    best: what `MapElitesRepertoire.init` of the policies and their final-body scores is."""
    import jax
    import jax.numpy as jnp
    from jax.flatten_util import ravel_pytree
    from qdax.utils.metrics import default_qd_metrics

    from smol_dsl import qdax as smol

    schedule = smol_dsl.load(schedule_name)
    batch = SIZES["batch_size"]
    start = smol.run_start(
        task,
        seed,
        batch_size=batch,
        num_centroids=SIZES["num_centroids"],
        num_init_cvt_samples=SIZES["num_init_cvt_samples"],
    )
    np.testing.assert_array_equal(start.centroids, trained.centroids)  # the run's centroids
    final = smol.phase_bodies(schedule, SIZES["num_phases"], smol.schedule_key(seed))[-1]
    genotypes = jax.vmap(lambda p: ravel_pytree(p)[0])(start.genotypes) if flat else start.genotypes
    cells = len(trained.fitnesses)
    assert cells >= batch  # a cell of its own for every initial policy
    placed = trained.replace(
        genotypes=jax.tree.map(lambda cell, policy: cell.at[:batch].set(policy), trained.genotypes, genotypes),
        fitnesses=jnp.where(
            (jnp.arange(cells) < batch).reshape((cells,) + (1,) * (trained.fitnesses.ndim - 1)), 0.0, -jnp.inf
        ).astype(trained.fitnesses.dtype),
    )
    score = smol.scoring_function(task, schedule, seed=seed, transitions=transitions)
    scored = smol.reevaluate(placed, score, final, jax.random.key(0), batch_size=batch)
    return {name: float(value) for name, value in default_qd_metrics(scored, task.qd_offset).items()}


def test_qdax_pga_me_under_human_improves_and_records_its_body_per_phase():
    """In the final body, the trained repertoire beats the initial population; every
    generation's transitions reached the replay buffer, which phase boundaries keep."""
    repertoire, emitter_state, history = example("qdax_pga_me").main(
        "human", seed=1, **SIZES, critic_hidden_layer_size=(16, 16), training_steps=4, replay_buffer_size=8192
    )
    bodies = smol_dsl.load("human").checked_phase_values(SIZES["num_phases"], smol_dsl.qdax.schedule_key(1))
    phases_recorded(history, bodies)
    for row in history:
        assert row["body"] == {"gear": pytest.approx(float(bodies[row["phase"], 0]))}
    assert history[-1]["body"] == {"gear": 1.0}
    initial = initial_in_final_body(small_task(), "human", 1, repertoire)
    print({"initial population in the final body": initial, "final": history[-1]})
    assert history[-1]["max_fitness"] > initial["max_fitness"]
    buffer = emitter_state.emitter_states[0].replay_buffer  # the policy-gradient emitter's
    assert int(buffer.current_size) == len(history) * SIZES["batch_size"] * SIZES["episode_length"]
    assert np.all(np.isfinite(np.asarray(repertoire.fitnesses)[np.asarray(repertoire.fitnesses) > -np.inf]))


def test_qdax_cma_me_under_three_channels_improves_and_ranks_against_the_new_body():
    from smol_dsl.tasks import make_task

    sizes = {**SIZES, "hidden_layer_sizes": (4,)}
    repertoire, emitter_state, history = example("qdax_cma_me").main(seed=0, **sizes)
    schedule = smol_dsl.load(EXAMPLES / "three-channels.sched")
    bodies = schedule.checked_phase_values(SIZES["num_phases"], smol_dsl.qdax.schedule_key(0))
    phases_recorded(history, bodies)
    assert history[-1]["body"] == {"gear": 1.0, "mass": 1.0, "friction": 1.0}
    task = make_task("walker2d", episode_length=SIZES["episode_length"], hidden_layer_sizes=(4,))
    initial = initial_in_final_body(
        task, EXAMPLES / "three-channels.sched", 0, repertoire, flat=True, transitions=False
    )
    print({"initial population in the final body": initial, "final": history[-1]})
    assert history[-1]["max_fitness"] > initial["max_fitness"]
    assert emitter_state.emitter_states.previous_fitnesses.shape[1:] == repertoire.fitnesses.shape
