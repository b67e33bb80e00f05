"""Runner throughput, measured side by side in one process (the machines are noisy).

Prints one `name: value` line per figure:

- run_all_devices_over_one_device: the engine's generation of one run (what `smol-dsl run`
  does) with its population split across every local device, over the same on one device
  (on a CPU, one XLA device per core, as the CLI sets up; target >= 1.6 on 2 cores);
- overhead_ratio: the engine's training evaluations/s on one device over a raw vmapped
  rollout of the same policies and batch (target >= 0.9);
- vs_qdax_ratio: the engine's evaluations/s on one device over QDax's own MAP-Elites loop
  (`update`) with QDax's walker2d_uni scoring at the same settings, jitted as QDax's users
  do (XLA's default options; target >= 1.0);
- vs_qdax_same_options_ratio: the same, QDax's update jitted with the compiler options the
  engine uses (`smol_dsl.qdax.compiler_options`: on CPUs, faster rollouts with the same
  results), so the two differ in nothing but their own code;
- compiles_10_phases, compiles_20_phases: XLA programs compiled (or loaded from a persistent
  compilation cache) for a whole run of 10 and of 20 phases under a three-channel schedule
  (gear, mass, friction: examples/three-channels.sched), each in a fresh process (must be
  equal: every channel's value is traced). 10 is the fewest phases the runner accepts for
  that file: its tail starts at 90%, and a run must end with a phase wholly in it;
- reeval_10pct_over_100pct: time to re-evaluate an archive 10% full over one 100% full
  (target <= 0.2).

The timed programs are interleaved (A, B, C, C, B, A, ...) and each figure is a ratio of
medians, so a busy spell of the machine slows every program alike instead of one; the
order reverses every round, so that no program always follows the same one.

`--small` measures at the test suite's run size (batch 16, 20-step episodes, 32 cells, 3
repeats; the compile counts' runs at tests/small_runs.py's size): every line is printed, but
the figures say nothing about speed (tests/test_benchmarks.py runs it so).

Usage: python benchmarks/runner_throughput.py [--batch-size 128] [--episode-length 100] [--repeats 21] [--small]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

warnings.filterwarnings("ignore")
os.environ.setdefault("JAX_PLATFORMS", "cpu")
if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):  # as the CLI does
    flags = os.environ.get("XLA_FLAGS", "")
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={os.cpu_count() or 1}".strip()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402


def interleaved(programs: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median seconds per call of each program, after one warm-up call each (compilation
    excluded), the programs taking turns: A, B, C, C, B, A, ..."""
    for program in programs.values():
        jax.block_until_ready(program())
    seconds: dict[str, list[float]] = {name: [] for name in programs}
    order = list(programs.items())
    for _ in range(repeats):
        for name, program in order:
            started = time.perf_counter()
            jax.block_until_ready(program())
            seconds[name].append(time.perf_counter() - started)
        order.reverse()  # A, B, C, then C, B, A: no program always runs right after another
    return {name: statistics.median(values) for name, values in seconds.items()}


THREE_CHANNELS = Path(__file__).resolve().parent.parent / "examples" / "three-channels.sched"
PHASES = (10, 20)  # the compile counts' runs: 10 is the fewest THREE_CHANNELS's 90% tail allows

# batch, episode steps, archive cells, timed rounds; the compile counts' run settings, with
# their budget in batches (the initial population and the generations after it)
FULL = dict(batch_size=128, episode_length=100, cells=1024, repeats=21)
SMALL = dict(batch_size=16, episode_length=20, cells=32, repeats=3)
COUNT_FULL = dict(batch_size=32, episode_length=20, num_centroids=128, num_init_cvt_samples=5000, batches=41)
COUNT_SMALL = dict(batch_size=16, episode_length=20, num_centroids=32, batches=21)  # test_channel_runs.py's run


def count_compiles(phases: int, small: bool) -> int:
    """XLA programs a complete run under THREE_CHANNELS compiles or loads from a persistent
    cache (JAX's compile event covers both), in this (fresh) process."""
    import smol_dsl
    from smol_dsl.runner import preset_config, run_experiment

    compiles: list[str] = []

    def on_event(event: str, duration: float, **kwargs: object) -> None:
        if event.endswith("backend_compile_duration"):
            compiles.append(event)

    jax.monitoring.register_event_duration_secs_listener(on_event)
    sizes = dict(COUNT_SMALL if small else COUNT_FULL)
    evaluations = sizes["batch_size"] * sizes.pop("batches")
    config = preset_config("walker2d", "quick", evaluations=evaluations, num_phases=phases, **sizes)
    run_experiment("walker2d", smol_dsl.load(THREE_CHANNELS), config)
    return len(compiles)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch-size", type=int, help="default 128 (16 with --small)")
    parser.add_argument("--episode-length", type=int, help="default 100 (20 with --small)")
    parser.add_argument("--repeats", type=int, help="timed rounds, default 21 (3 with --small)")
    parser.add_argument("--small", action="store_true", help="the tests' tiny sizes: checks the script, times nothing")
    parser.add_argument("--count-compiles", type=int, metavar="PHASES", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.count_compiles is not None:
        print(count_compiles(args.count_compiles, args.small))
        return
    sizes = SMALL if args.small else FULL
    batch = args.batch_size or sizes["batch_size"]
    length = args.episode_length or sizes["episode_length"]
    repeats, cells = args.repeats or sizes["repeats"], sizes["cells"]

    import qdax.tasks.brax.v2 as qdax_envs
    from qdax.core.emitters.mutation_operators import isoline_variation
    from qdax.core.emitters.standard_emitters import MixingEmitter
    from qdax.core.map_elites import MAPElites
    from qdax.tasks.brax.descriptor_extractors import get_feet_contact_proportion
    from qdax.tasks.brax.v2.env_creators import create_brax_scoring_fn
    from qdax.utils.metrics import default_qd_metrics

    from smol_dsl.qdax.scoring import cvt_centroids
    from smol_dsl.runner.engine import Engine, stack_runs
    from smol_dsl.tasks import make_task
    from smol_dsl.tasks.base import deterministic_init_state

    devices = jax.local_devices()
    print(
        f"# walker2d, batch {batch}, {length}-step episodes, {len(devices)} {devices[0].platform} device(s)", flush=True
    )
    task = make_task("walker2d", episode_length=length)
    score = task.scoring_fn()
    params = task.init_policies(jax.random.key(1), batch)
    start = deterministic_init_state(task.env, jax.random.key(0))  # QDax's start for key 0
    body = jnp.ones(1)  # plain gear at 1: the standard body
    centroids = cvt_centroids(cells, task.descriptor_low, task.descriptor_high, 50_000, jax.random.key(2))

    def engine_generation(engine: Engine) -> tuple[Callable[[], object], dict]:
        """One run's generations on `engine`, from an archive of one generation, and the
        state they update (its archive)."""
        put = engine.put
        state = {"archive": engine.empty_archives(centroids[None]), "key": jax.random.key(4)}
        inputs = (put(jnp.ones((1, 1), jnp.float32)), put(stack_runs([start])))  # one run, its body (gear,)

        def generation() -> object:
            state["key"], key = jax.random.split(state["key"])
            state["archive"], metrics, _, _ = engine.step(state["archive"], *inputs, put(key[None]))
            return metrics["coverage"]

        generation()  # the initial population
        return generation, state

    settings = dict(batch_size=batch, iso_sigma=0.005, line_sigma=0.05, num_runs=1)
    one = Engine(task, devices=devices[:1], **settings)
    every = Engine(task, devices=devices, **settings)

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

    def qdax_loop(options: dict[str, str] | None) -> Callable[[], object]:
        """QDax's generation, its update jitted with these compiler options."""
        update = jax.jit(map_elites.update, compiler_options=options)
        state = {"repertoire": qdax_repertoire, "key": jax.random.key(6)}

        def generation() -> object:
            state["key"], key = jax.random.split(state["key"])
            state["repertoire"], _, metrics = update(state["repertoire"], qdax_emitter_state, key)
            return metrics["coverage"]

        return generation

    one_generation, one_state = engine_generation(one)
    medians = interleaved(
        {
            "raw": lambda: score(params, body, start)[0],
            "one_device": one_generation,
            "all_devices": engine_generation(every)[0],
            "qdax": qdax_loop(None),
            "qdax_same_options": qdax_loop(task.compiler_options("cpu")),
        },
        repeats,
    )
    print(f"raw_rollout_evals_per_s: {batch / medians['raw']:.1f}")
    print(f"run_one_device_evals_per_s: {batch / medians['one_device']:.1f}")
    print(f"run_all_devices_evals_per_s: {batch / medians['all_devices']:.1f}")
    print(f"qdax_evals_per_s: {batch / medians['qdax']:.1f}")
    print(f"run_all_devices_over_one_device: {medians['one_device'] / medians['all_devices']:.3f}")
    print(f"overhead_ratio: {medians['raw'] / medians['one_device']:.3f}")
    print(f"vs_qdax_ratio: {medians['qdax'] / medians['one_device']:.3f}")
    print(f"qdax_same_options_evals_per_s: {batch / medians['qdax_same_options']:.1f}")
    print(f"vs_qdax_same_options_ratio: {medians['qdax_same_options'] / medians['one_device']:.3f}", flush=True)

    # re-evaluation cost: 10% vs 100% full archives of the same size (one device)
    for _ in range(3):
        one_generation()
    trained = jax.tree.map(lambda x: x[0], one_state["archive"])
    full = trained.replace(fitnesses=jnp.zeros_like(trained.fitnesses))
    full = full.replace(genotypes=jax.tree.map(lambda x: jnp.broadcast_to(x[:1], x.shape), trained.genotypes))
    tenth = full.replace(fitnesses=jnp.where(jnp.arange(cells)[:, None] < math.ceil(cells / 10), 0.0, -jnp.inf))
    put = one.put
    reeval_inputs = (put(jnp.ones((1, 1), jnp.float32)), put(stack_runs([start])), put(jnp.zeros((1,), jnp.float32)))

    def reevaluate(archive: object) -> Callable[[], object]:
        stacked = put(stack_runs([archive]))
        return lambda: one.reevaluate(stacked, *reeval_inputs, put(jax.random.key(7)[None]))[0].fitnesses

    reeval = interleaved({"full": reevaluate(full), "tenth": reevaluate(tenth)}, 3)

    compiles = {}
    for phases in PHASES:
        command = [sys.executable, __file__, "--count-compiles", str(phases), *(["--small"] if args.small else [])]
        compiles[phases] = int(subprocess.run(command, capture_output=True, text=True, check=True).stdout.split()[-1])

    for phases, count in compiles.items():
        print(f"compiles_{phases}_phases: {count}")
    print(f"reeval_100pct_s: {reeval['full']:.3f}")
    print(f"reeval_10pct_s: {reeval['tenth']:.3f}")
    print(f"reeval_10pct_over_100pct: {reeval['tenth'] / reeval['full']:.3f}")


if __name__ == "__main__":
    main()
