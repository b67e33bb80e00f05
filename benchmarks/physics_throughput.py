"""Spring and MJX side by side: how fast each physics simulates the paper's tasks, in one run.

For each task (walker2d and ant_omni by default) and each physics (`spring`, `mjx`), at the
quick preset's batch size and episode length, prints one `name: value` line per figure:

- TASK_PHYSICS_raw_steps_per_s: environment steps per second of a raw rollout of a batch of
  random policies in the standard body (the task's jitted `scoring_fn`);
- TASK_PHYSICS_engine_evals_per_s: the runner's training evaluations per second (the
  engine's generation of one run: variation, rollouts, insertion; every local device);
- TASK_mjx_over_spring_raw, TASK_mjx_over_spring_engine: MJX's figure over spring's.

The timed programs are interleaved (A, B, C, D, D, C, B, A, ...) and each figure is a median,
so a busy spell of the machine slows every program alike. Compilation is not timed; its
seconds per physics are printed as TASK_PHYSICS_compile_s (the raw rollout's first call).

`--small` measures at the test suite's run size (batch 16, 20-step episodes, 32 cells, one
timed round): every line is printed, but the figures say nothing about speed
(tests/test_benchmarks.py runs it so, for walker2d).

Usage: python benchmarks/physics_throughput.py [--tasks walker2d ant_omni] [--repeats 5] [--small]
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

warnings.filterwarnings("ignore")
os.environ.setdefault("JAX_PLATFORMS", "cpu")
if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):  # as the CLI does
    flags = os.environ.get("XLA_FLAGS", "")
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={os.cpu_count() or 1}".strip()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from runner_throughput import interleaved  # noqa: E402  # this folder's: the same interleaved medians

PHYSICS = ("spring", "mjx")
SMALL = dict(batch_size=16, episode_length=20, cells=32, repeats=1)


def programs_of(task_name: str, physics: str, batch: int, length: int, cells: int) -> tuple[dict, float]:
    """The raw rollout and the engine's generation of `task_name` on `physics`, both compiled
    (and warmed up), and the seconds the raw rollout took to compile and run once."""
    from smol_dsl.qdax.scoring import cvt_centroids
    from smol_dsl.runner.engine import Engine, stack_runs
    from smol_dsl.tasks import make_task

    task = make_task(task_name, episode_length=length, physics=physics)
    score = task.scoring_fn()
    params = task.init_policies(jax.random.key(1), batch)
    start = task.episode_start(0)
    body = jnp.ones(1)  # plain gear at 1: the standard body

    def raw() -> object:
        return score(params, body, start)[0]

    started = time.perf_counter()
    jax.block_until_ready(raw())
    compile_seconds = time.perf_counter() - started

    devices = jax.local_devices()
    engine = Engine(task, devices=devices, batch_size=batch, iso_sigma=0.005, line_sigma=0.05, num_runs=1)
    centroids = cvt_centroids(cells, task.descriptor_low, task.descriptor_high, 10_000, jax.random.key(2))
    state = {"archive": engine.empty_archives(centroids[None]), "key": jax.random.key(4)}
    inputs = (engine.put(jnp.ones((1, 1), jnp.float32)), engine.put(stack_runs([start])))

    def generation() -> object:
        state["key"], key = jax.random.split(state["key"])
        state["archive"], metrics, _, _ = engine.step(state["archive"], *inputs, engine.put(key[None]))
        return metrics["coverage"]

    jax.block_until_ready(generation())  # the initial population, compiled
    jax.block_until_ready(generation())  # a generation
    return {"raw": raw, "engine": generation}, compile_seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["walker2d", "ant_omni"], metavar="TASK")
    parser.add_argument("--repeats", type=int, help="timed rounds, default 5 (1 with --small)")
    parser.add_argument("--small", action="store_true", help="the tests' tiny sizes: checks the script, times nothing")
    args = parser.parse_args()
    from smol_dsl.tasks import task_spec

    devices = jax.local_devices()
    for task_name in args.tasks:
        quick = task_spec(task_name).presets["quick"]
        batch = SMALL["batch_size"] if args.small else quick["batch_size"]
        length = SMALL["episode_length"] if args.small else quick["episode_length"]
        cells = SMALL["cells"] if args.small else 256
        repeats = args.repeats or (SMALL["repeats"] if args.small else 5)
        print(
            f"# {task_name}, batch {batch}, {length}-step episodes, {len(devices)} {devices[0].platform} device(s)",
            flush=True,
        )
        programs = {}
        for physics in PHYSICS:
            made, compile_seconds = programs_of(task_name, physics, batch, length, cells)
            print(f"{task_name}_{physics}_compile_s: {compile_seconds:.1f}", flush=True)
            programs.update({f"{physics}_{name}": program for name, program in made.items()})
        medians = interleaved(programs, repeats)
        for physics in PHYSICS:
            print(f"{task_name}_{physics}_raw_steps_per_s: {batch * length / medians[f'{physics}_raw']:.0f}")
            print(f"{task_name}_{physics}_engine_evals_per_s: {batch / medians[f'{physics}_engine']:.1f}")
        for name in ("raw", "engine"):
            print(f"{task_name}_mjx_over_spring_{name}: {medians[f'spring_{name}'] / medians[f'mjx_{name}']:.3f}")


if __name__ == "__main__":
    main()
