"""QDax's PGA-ME (policy-gradient and iso+line emitters, a TD3 critic) under a smol-dsl schedule.

Run: python examples/qdax_pga_me.py [schedule] (walker2d under human.sched by default; several
minutes on 2 CPU cores)

PGA-ME learns from the transitions of every evaluation: smol-dsl's scoring returns them in
`extra_scores["transitions"]`, as QDax's Brax scoring does, and `smol.env_sizes(task)` is
the `env` its emitter reads the observation, action and state-descriptor sizes from. At a
phase boundary the replay buffer keeps the transitions of the previous bodies (see
`smol_dsl.qdax.emitters` for why); `smol.new_phase(..., replay="clear")` would empty it.
QDax 0.5's PGA-ME module imports a Brax v1 module that Brax 0.14 lacks, for one annotation:
importing `smol_dsl.qdax` first registers a stand-in (`smol_dsl.qdax.compat`).
"""

from __future__ import annotations

import sys
from functools import partial
from typing import Any

import jax
from qdax.core.emitters.mutation_operators import isoline_variation
from qdax.core.map_elites import MAPElites
from qdax.utils.metrics import default_qd_metrics

import smol_dsl
from smol_dsl import qdax as smol
from smol_dsl.tasks import make_task


def main(
    schedule_name: str = "human",
    *,
    task_name: str = "walker2d",
    seed: int = 0,
    evaluations: int = 12_800,
    batch_size: int = 128,
    num_phases: int = 20,
    num_centroids: int = 256,
    episode_length: int = 100,
    hidden_layer_sizes: tuple[int, ...] = (64, 64),
    num_init_cvt_samples: int = 50_000,
    critic_hidden_layer_size: tuple[int, ...] = (256, 256),
    training_steps: int = 100,
    replay_buffer_size: int = 100_000,
) -> tuple[Any, Any, list[dict[str, Any]]]:
    """Train; return the final repertoire, the emitter's state and every generation's
    metrics, with its phase and the body it trained in."""
    # imported after smol_dsl.qdax, which makes it importable with Brax v2 (smol_dsl.qdax.compat)
    from qdax.core.emitters.pga_me_emitter import PGAMEConfig, PGAMEEmitter

    task = make_task(task_name, episode_length=episode_length, hidden_layer_sizes=hidden_layer_sizes)
    schedule = smol_dsl.load(schedule_name)
    score = smol.scoring_function(task, schedule, seed=seed)  # extra_scores["transitions"] included
    bodies = smol.phase_bodies(schedule, num_phases, smol.schedule_key(seed))
    start = smol.run_start(
        task, seed, batch_size=batch_size, num_centroids=num_centroids, num_init_cvt_samples=num_init_cvt_samples
    )

    # QDax's PGA-ME, as in its examples: half the batch by policy gradient, half by iso+line
    config = PGAMEConfig(
        env_batch_size=batch_size,
        proportion_mutation_ga=0.5,
        critic_hidden_layer_size=critic_hidden_layer_size,
        num_critic_training_steps=training_steps,
        num_pg_training_steps=training_steps,
        replay_buffer_size=replay_buffer_size,
        batch_size=min(256, replay_buffer_size),
    )
    emitter = PGAMEEmitter(
        config=config,
        policy_network=task.policy,
        env=smol.env_sizes(task),
        variation_fn=partial(isoline_variation, iso_sigma=0.005, line_sigma=0.05),
    )
    metrics_function = partial(default_qd_metrics, qd_offset=task.qd_offset)

    def pga_me(body: jax.Array) -> MAPElites:
        return MAPElites(partial(score, body=body), emitter, metrics_function)

    fast = smol.compiler_options(task)  # XLA's options for the rollouts on CPUs (the same results)
    init = jax.jit(
        lambda genotypes, centroids, key, body: pga_me(body).init(genotypes, centroids, key), compiler_options=fast
    )
    update = jax.jit(
        lambda repertoire, state, key, body: pga_me(body).update(repertoire, state, key), compiler_options=fast
    )

    def row(generation: int, phase: int, metrics: dict[str, jax.Array]) -> dict[str, Any]:
        body = dict(zip((c.name for c in schedule.channels), map(float, bodies[phase]), strict=True))
        return {"generation": generation, "phase": phase, "body": body, **{k: float(v) for k, v in metrics.items()}}

    repertoire, emitter_state, metrics = init(start.genotypes, start.centroids, start.init_key, bodies[0])
    history = [row(0, 0, metrics)]
    key, phase = start.key, 0
    generations = evaluations // batch_size - 1
    for generation in range(1, generations + 1):
        if smol.phase_of_generation(generation, generations, num_phases) != phase:
            phase = smol.phase_of_generation(generation, generations, num_phases)
            key, subkey = jax.random.split(key)
            repertoire = smol.reevaluate(
                repertoire, score, bodies[phase], subkey, schedule.extinction, batch_size=batch_size
            )
            emitter_state = smol.new_phase(emitter_state, repertoire)  # the replay buffer is kept
        key, subkey = jax.random.split(key)
        repertoire, emitter_state, metrics = update(repertoire, emitter_state, subkey, bodies[phase])
        history.append(row(generation, phase, metrics))
    return repertoire, emitter_state, history


if __name__ == "__main__":
    _, _, history = main(*sys.argv[1:2])
    for entry in history[:: max(1, len(history) // 10)] + history[-1:]:
        body = ", ".join(f"{name} {value:.3f}" for name, value in entry["body"].items())
        print(
            f"generation {entry['generation']:4d}  phase {entry['phase']:3d}  ({body})  "
            f"coverage {entry['coverage']:.1f}%  max fitness {entry['max_fitness']:.2f}  "
            f"QD score {entry['qd_score']:.1f}"
        )
