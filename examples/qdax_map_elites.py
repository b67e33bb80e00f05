"""QDax's own MAP-Elites (iso+line variation) under a smol-dsl schedule.

Run: python examples/qdax_map_elites.py [schedule] (walker2d under smol.sched by default; a
couple of minutes on 2 CPU cores; `smol-paced` for a schedule that waits for the archive)

The loop is a QDax user's: `MAPElites(scoring_function, emitter, metrics).init`, then
`update` generation after generation. Under a schedule, four things change:

1. the scoring function is smol-dsl's, with the body as an argument
   (`smol.scoring_function`), and the body of each phase comes from the schedule
   (`smol.phase_body`: for a schedule without `pace`, a row of `smol.phase_bodies`);
2. the body is bound inside the jitted step, so one compilation serves every phase;
3. at each phase boundary the schedule decides from the repertoire's metrics whether the
   body moves on (`smol.pace`: always, without `pace`); where it does, the repertoire is
   re-evaluated in the new body (`smol.reevaluate`), the emitter's body-dependent state
   updated (`smol.new_phase`) and the metrics after remembered (`smol.settle`); where it
   does not, the repertoire is kept as it is;
4. the key, centroids and initial population are those of `smol-dsl run --seed`
   (`smol.run_start`), so that this loop follows its random streams: with the same settings
   its final repertoire is `smol-dsl run`'s (tests/test_qdax_examples.py holds them equal,
   for SMOL and SMOL-paced).
"""

from __future__ import annotations

import sys
from functools import partial
from typing import Any

import jax
import numpy as np
from qdax.core.emitters.mutation_operators import isoline_variation
from qdax.core.emitters.standard_emitters import MixingEmitter
from qdax.core.map_elites import MAPElites
from qdax.utils.metrics import default_qd_metrics

import smol_dsl
from smol_dsl import qdax as smol
from smol_dsl.tasks import make_task


def main(
    schedule_name: str = "smol",
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
) -> tuple[Any, np.ndarray, list[dict[str, float]]]:
    """Train; return the final repertoire, the body of every phase and every generation's
    metrics (with its phase)."""
    task = make_task(task_name, episode_length=episode_length, hidden_layer_sizes=hidden_layer_sizes)
    schedule = smol_dsl.load(schedule_name)

    # 1. smol-dsl's scoring, and `smol-dsl run --seed`'s first draws
    score = smol.scoring_function(task, schedule, seed=seed)
    schedule_key = smol.schedule_key(seed)
    start = smol.run_start(
        task, seed, batch_size=batch_size, num_centroids=num_centroids, num_init_cvt_samples=num_init_cvt_samples
    )

    # QDax's MAP-Elites, as in its examples
    emitter = MixingEmitter(
        mutation_fn=None,
        variation_fn=partial(isoline_variation, iso_sigma=0.005, line_sigma=0.05),
        variation_percentage=1.0,
        batch_size=batch_size,
    )
    metrics_function = partial(default_qd_metrics, qd_offset=task.qd_offset)

    # 2. the body bound inside the jitted steps: traced, one compilation for every phase
    def map_elites(body: jax.Array) -> MAPElites:
        return MAPElites(partial(score, body=body), emitter, metrics_function)

    fast = smol.compiler_options(task)  # XLA's options for the rollouts on CPUs (the same results)
    init = jax.jit(
        lambda genotypes, centroids, key, body: map_elites(body).init(genotypes, centroids, key), compiler_options=fast
    )
    update = jax.jit(
        lambda repertoire, state, key, body: map_elites(body).update(repertoire, state, key), compiler_options=fast
    )

    body = smol.phase_bodies(schedule, num_phases, schedule_key)[0]  # phase 0: every clock at 0
    repertoire, emitter_state, metrics = init(start.genotypes, start.centroids, start.init_key, body)
    pacing = smol.pacing_start(schedule, metrics)
    history = [{"generation": 0, "phase": 0, **{k: float(v) for k, v in metrics.items()}}]
    bodies = [body]
    key, phase = start.key, 0
    generations = evaluations // batch_size - 1
    for generation in range(1, generations + 1):
        # 3. a new phase: the schedule decides whether the body moves on, and where it does
        # the repertoire is re-evaluated in the new body
        if smol.phase_of_generation(generation, generations, num_phases) != phase:
            decided = smol.pace(schedule, pacing, metrics, phase, num_phases)
            phase = smol.phase_of_generation(generation, generations, num_phases)
            key, subkey = jax.random.split(key)
            if smol.body_moves(schedule, pacing, decided, phase, num_phases):
                body = smol.phase_body(schedule, decided, phase, num_phases, schedule_key)
                extinction = schedule.extinction
                repertoire = smol.reevaluate(repertoire, score, body, subkey, extinction, batch_size=batch_size)
                emitter_state = smol.new_phase(emitter_state, repertoire)
                decided = smol.settle(schedule, pacing, decided, metrics_function(repertoire))
            pacing = decided
            bodies.append(body)
        key, subkey = jax.random.split(key)
        repertoire, emitter_state, metrics = update(repertoire, emitter_state, subkey, body)
        history.append({"generation": generation, "phase": phase, **{k: float(v) for k, v in metrics.items()}})
    return repertoire, np.asarray(bodies), history


if __name__ == "__main__":
    repertoire, bodies, history = main(*sys.argv[1:2])
    for row in history[:: max(1, len(history) // 10)] + history[-1:]:
        body = ", ".join(f"{value:.3f}" for value in bodies[row["phase"]])
        print(
            f"generation {row['generation']:4d}  phase {row['phase']:3d}  body ({body})  "
            f"coverage {row['coverage']:.1f}%  max fitness {row['max_fitness']:.2f}  QD score {row['qd_score']:.1f}"
        )
