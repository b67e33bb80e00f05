"""QDax's CMA-ME (a pool of CMA-ES improvement emitters) under a schedule of three channels.

Run: python examples/qdax_cma_me.py [schedule] (walker2d under examples/three-channels.sched by
default: random gear, a body that gains mass, ground that starts twice as grippy; a few
minutes on 2 CPU cores)

CMA-ES searches a flat vector of parameters, so the genotypes are the policies' parameters
flattened (`ravel_pytree`'s order); smol-dsl's scoring takes such (batch, parameters) arrays
as it takes policies. CMA emitters rank offspring by their improvement over the fitnesses
the repertoire had at the last `tell`: at a phase boundary `smol.new_phase` sets those to
the re-evaluated repertoire's, and keeps the search distribution.
"""

from __future__ import annotations

import sys
from functools import partial
from pathlib import Path
from typing import Any

import jax
from jax.flatten_util import ravel_pytree
from qdax.core.emitters.cma_improvement_emitter import CMAImprovementEmitter
from qdax.core.emitters.cma_pool_emitter import CMAPoolEmitter
from qdax.core.map_elites import MAPElites
from qdax.utils.metrics import default_qd_metrics

import smol_dsl
from smol_dsl import qdax as smol
from smol_dsl.tasks import make_task

THREE_CHANNELS = Path(__file__).resolve().with_name("three-channels.sched")


def main(
    schedule_name: str | Path = THREE_CHANNELS,
    *,
    task_name: str = "walker2d",
    seed: int = 0,
    evaluations: int = 12_800,
    batch_size: int = 128,
    num_phases: int = 20,
    num_centroids: int = 256,
    episode_length: int = 100,
    hidden_layer_sizes: tuple[int, ...] = (8,),
    num_init_cvt_samples: int = 50_000,
    pool_size: int = 4,
    sigma_g: float = 0.05,
) -> tuple[Any, Any, list[dict[str, Any]]]:
    """Train; return the final repertoire, the emitter's state and every generation's
    metrics, with its phase and body."""
    task = make_task(task_name, episode_length=episode_length, hidden_layer_sizes=hidden_layer_sizes)
    schedule = smol_dsl.load(schedule_name)
    score = smol.scoring_function(task, schedule, seed=seed, transitions=False)  # CMA-ME needs no transitions
    bodies = smol.phase_bodies(schedule, num_phases, smol.schedule_key(seed))
    start = smol.run_start(
        task, seed, batch_size=batch_size, num_centroids=num_centroids, num_init_cvt_samples=num_init_cvt_samples
    )
    genotypes = jax.vmap(lambda policy: ravel_pytree(policy)[0])(start.genotypes)  # (batch, parameters)

    # QDax's CMA-ME, as in its examples
    emitter = CMAPoolEmitter(
        num_states=pool_size,
        emitter=CMAImprovementEmitter(
            batch_size=batch_size, genotype_dim=genotypes.shape[1], centroids=start.centroids, sigma_g=sigma_g
        ),
    )
    metrics_function = partial(default_qd_metrics, qd_offset=task.qd_offset)

    def cma_me(body: jax.Array) -> MAPElites:
        return MAPElites(partial(score, body=body), emitter, metrics_function)

    fast = smol.compiler_options(task)  # XLA's options for the rollouts on CPUs (the same results)
    init = jax.jit(
        lambda genotypes, centroids, key, body: cma_me(body).init(genotypes, centroids, key), compiler_options=fast
    )
    update = jax.jit(
        lambda repertoire, state, key, body: cma_me(body).update(repertoire, state, key), compiler_options=fast
    )

    def row(generation: int, phase: int, metrics: dict[str, jax.Array]) -> dict[str, Any]:
        body = dict(zip((c.name for c in schedule.channels), map(float, bodies[phase]), strict=True))
        return {"generation": generation, "phase": phase, "body": body, **{k: float(v) for k, v in metrics.items()}}

    repertoire, emitter_state, metrics = init(genotypes, start.centroids, start.init_key, bodies[0])
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
            emitter_state = smol.new_phase(emitter_state, repertoire)  # CMA ranks against the new fitnesses
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
