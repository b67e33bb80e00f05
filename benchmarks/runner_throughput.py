"""Runner throughput, measured side by side in one process (the machines are noisy).

Prints one `name: value` line per figure:

- overhead_ratio: the runner's training evaluations/s over a raw vmapped rollout of the
  same policies and batch (target >= 0.9);
- vs_qdax_ratio: the runner's evaluations/s over QDax's own MAP-Elites loop (`update`)
  with QDax's walker2d_uni scoring at the same settings (target >= 1.0);
- compiles_2_phases, compiles_20_phases: XLA compilations of a whole run of 2 and of 20
  phases, each in a fresh process (must be equal);
- reeval_10pct_over_100pct: time to re-evaluate an archive 10% full over one 100% full
  (target <= 0.2).

Usage: python benchmarks/runner_throughput.py [--batch-size 128] [--episode-length 100]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
import warnings

warnings.filterwarnings("ignore")
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402


def timed(function, repeats: int) -> float:
    """Seconds per call, after one warm-up call (compilation excluded)."""
    jax.block_until_ready(function())
    started = time.perf_counter()
    for _ in range(repeats):
        jax.block_until_ready(function())
    return (time.perf_counter() - started) / repeats


def count_compiles(phases: int, batch_size: int, episode_length: int) -> int:
    """XLA compilations of a complete run, in this (fresh) process."""
    import smol_dsl
    from smol_dsl.runner import preset_config, run_experiment

    compiles: list[str] = []

    def on_event(event: str, duration: float, **kwargs: object) -> None:
        if event.endswith("backend_compile_duration"):
            compiles.append(event)

    jax.monitoring.register_event_duration_secs_listener(on_event)
    config = preset_config(
        "walker2d",
        "quick",
        evaluations=batch_size * (2 * 20 + 1),
        batch_size=batch_size,
        num_phases=phases,
        num_centroids=128,
        episode_length=episode_length,
        num_init_cvt_samples=5000,
    )
    run_experiment("walker2d", smol_dsl.load("vanilla"), config)
    return len(compiles)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--episode-length", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--count-compiles", type=int, metavar="PHASES", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.count_compiles is not None:
        print(count_compiles(args.count_compiles, 32, 20))
        return

    import qdax.tasks.brax.v2 as qdax_envs
    from qdax.core.emitters.mutation_operators import isoline_variation
    from qdax.core.emitters.standard_emitters import MixingEmitter
    from qdax.core.map_elites import MAPElites
    from qdax.tasks.brax.descriptor_extractors import get_feet_contact_proportion
    from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn
    from qdax.utils.metrics import default_qd_metrics

    from smol_dsl.runner.algorithm import PhasedMapElites, cvt_centroids
    from smol_dsl.tasks import make_task

    batch, length = args.batch_size, args.episode_length
    print(f"# walker2d, batch {batch}, {length}-step episodes, {jax.devices()[0].platform}", flush=True)
    task = make_task("walker2d", episode_length=length, init_key=jax.random.key(0))
    score = task.scoring_fn()
    params = task.init_policies(jax.random.key(1), batch)
    alpha = jnp.float32(1.0)

    # raw vmapped rollouts of the same policies and batch
    raw = timed(lambda: score(params, alpha, jax.random.key(0))[0], args.repeats)

    # the runner's generation (ask, score at alpha, drop non-finite, tell)
    algorithm = PhasedMapElites(
        score, task.init_policies, batch_size=batch, qd_offset=task.qd_offset, iso_sigma=0.005, line_sigma=0.05
    )
    centroids = cvt_centroids(1024, task.descriptor_low, task.descriptor_high, 50_000, jax.random.key(2))
    repertoire, _, _, _ = algorithm.init(centroids, alpha, jax.random.key(3))
    state = {"repertoire": repertoire, "key": jax.random.key(4)}

    def runner_generation():
        state["key"], key = jax.random.split(state["key"])
        state["repertoire"], _, metrics, _ = algorithm.generation(state["repertoire"], None, alpha, key)
        return metrics["coverage"]

    ours = timed(runner_generation, args.repeats)

    # QDax's own loop: MAPElites.update with QDax's walker2d_uni scoring
    env = qdax_envs.create("walker2d_uni", episode_length=length)
    qdax_score = create_brax_scoring_fn(
        env, task.policy, get_feet_contact_proportion, jax.random.key(0), episode_length=length
    )
    emitter = MixingEmitter(
        mutation_fn=None,
        variation_fn=lambda a, b, k: isoline_variation(a, b, k, 0.005, 0.05),
        variation_percentage=1.0,
        batch_size=batch,
    )
    map_elites = MAPElites(
        scoring_function=qdax_score, emitter=emitter, metrics_function=lambda r: default_qd_metrics(r, task.qd_offset)
    )
    qdax_repertoire, qdax_emitter_state, _ = map_elites.init(params, centroids, jax.random.key(5))
    update = jax.jit(map_elites.update)
    qdax_state = {"repertoire": qdax_repertoire, "key": jax.random.key(6)}

    def qdax_generation():
        qdax_state["key"], key = jax.random.split(qdax_state["key"])
        qdax_state["repertoire"], _, metrics = update(qdax_state["repertoire"], qdax_emitter_state, key)
        return metrics["coverage"]

    theirs = timed(qdax_generation, args.repeats)
    print(f"raw_rollout_evals_per_s: {batch / raw:.1f}")
    print(f"runner_evals_per_s: {batch / ours:.1f}")
    print(f"qdax_evals_per_s: {batch / theirs:.1f}")
    print(f"overhead_ratio: {raw / ours:.3f}")
    print(f"vs_qdax_ratio: {theirs / ours:.3f}", flush=True)

    # re-evaluation cost: 10% vs 100% full archives of the same size
    trained = state["repertoire"]  # the initial archive was donated to the first generation
    full = trained.replace(fitnesses=jnp.zeros_like(trained.fitnesses))
    full = full.replace(genotypes=jax.tree.map(lambda x: jnp.broadcast_to(x[:1], x.shape), trained.genotypes))
    tenth = full.replace(fitnesses=jnp.where(jnp.arange(1024)[:, None] < 103, 0.0, -jnp.inf))
    reeval_full = timed(lambda: algorithm.reevaluate(full, alpha, 0.0, jax.random.key(7))[0].fitnesses, 2)
    reeval_tenth = timed(lambda: algorithm.reevaluate(tenth, alpha, 0.0, jax.random.key(7))[0].fitnesses, 2)

    compiles = {}
    for phases in (2, 20):
        output = subprocess.run(
            [sys.executable, __file__, "--count-compiles", str(phases)], capture_output=True, text=True, check=True
        ).stdout.split()
        compiles[phases] = int(output[-1])

    print(f"compiles_2_phases: {compiles[2]}")
    print(f"compiles_20_phases: {compiles[20]}")
    print(f"reeval_100pct_s: {reeval_full:.3f}")
    print(f"reeval_10pct_s: {reeval_tenth:.3f}")
    print(f"reeval_10pct_over_100pct: {reeval_tenth / reeval_full:.3f}")


if __name__ == "__main__":
    main()
