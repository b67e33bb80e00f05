"""Sweep throughput, measured side by side in one process (the machines are noisy).

Eight walker2d runs (4 schedules x 2 seeds, the runner's quick batch and episodes, a
short budget of 10 phases: the fewest that SMOL's 90% tail allows, since a run must end
with a phase wholly in it) are timed three ways, after one warm-up of each so that
compilation is left out:

- sequential: `run_experiment` eight times, one after another (as eight `smol-dsl run`s);
- sweep: `run_sweep` of the eight, on every local device (what `smol-dsl sweep` does:
  on a CPU-only machine one XLA device per core);
- sweep_one_device: `run_sweep` on the first device only.

Prints `name: value` lines, among them:

- batched_over_sequential: sequential time over sweep time (target >= 1.2 on a 2-core CPU);
- batched_one_device_over_sequential: the same with the sweep held to one device;
- two_devices_over_one: sweep_one_device time over the sweep's time on two devices;
- one_run_two_devices_over_one: one run as a sweep on one device over the same run on two
  devices, which split its population.

`--small` runs four runs (vanilla and SMOL x 2 seeds) at the test suite's run size
(tests/small_runs.py: 12 generations, batch 16, 20-step episodes, 32 cells; the sweep of
tests/test_explorer.py): every line is printed, but the figures say nothing about speed
(tests/test_benchmarks.py runs it so).

Usage: python benchmarks/sweep_throughput.py [--generations 40] [--devices 2] [--small]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
import warnings

warnings.filterwarnings("ignore")

PHASES = 10  # the fewest that SMOL, SMOL-Reverse and SMOL-Human (tails from 90%) allow
SCHEDULES, SMALL_SCHEDULES = ("vanilla", "smol", "smol-reverse", "human"), ("vanilla", "smol")
FULL = dict(generations=40, batch_size=128, episode_length=100, num_centroids=256, num_init_cvt_samples=10_000)
SMALL = dict(generations=12, batch_size=16, episode_length=20, num_centroids=32, num_init_cvt_samples=50_000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generations", type=int, help="generations per run after the first (default 40, at least 10)")
    parser.add_argument("--batch-size", type=int, help="default 128")
    parser.add_argument("--episode-length", type=int, help="default 100")
    parser.add_argument("--devices", type=int, default=2, help="CPU devices to split the host into (default 2)")
    parser.add_argument("--small", action="store_true", help="the tests' tiny sizes: checks the script, times nothing")
    args = parser.parse_args()
    sizes = dict(SMALL if args.small else FULL)
    for name in ("generations", "batch_size", "episode_length"):
        sizes[name] = getattr(args, name) or sizes[name]
    os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={args.devices}")

    import jax

    import smol_dsl
    from smol_dsl.runner import RunConfig, preset_config, run_experiment, run_sweep
    from smol_dsl.tasks import make_task

    devices = jax.local_devices()
    evaluations = sizes["batch_size"] * (sizes.pop("generations") + 1)
    config = preset_config("walker2d", "quick", evaluations=evaluations, num_phases=PHASES, **sizes)
    schedules = [smol_dsl.load(name) for name in (SMALL_SCHEDULES if args.small else SCHEDULES)]
    seeds = [0, 1]
    runs = len(schedules) * len(seeds)
    print(
        f"# walker2d, {runs} runs of {config.evaluations} evaluations (batch {config.batch_size}, "
        f"{config.episode_length}-step episodes, {config.num_phases} phases); {len(devices)} "
        f"{devices[0].platform} device(s), {os.cpu_count()} cores",
        flush=True,
    )
    task = make_task("walker2d", episode_length=config.episode_length, hidden_layer_sizes=config.hidden_layer_sizes)
    warm = dataclasses.replace(config, evaluations=config.batch_size * (config.num_phases + 2))

    def sequential(cfg: RunConfig) -> float:
        started = time.perf_counter()
        for schedule in schedules:
            for seed in seeds:
                run_experiment(task, schedule, dataclasses.replace(cfg, seed=seed))
        return time.perf_counter() - started

    def sweep(on: list, cfg: RunConfig, runs: slice = slice(None)) -> float:
        started = time.perf_counter()
        run_sweep(task, schedules[runs], seeds[runs], cfg, devices=on)
        return time.perf_counter() - started

    one = slice(0, 1)  # one schedule, one seed: a single run
    sequential(warm)
    for on in (devices, devices[:1]):
        sweep(on, warm)
        sweep(on, warm, one)

    times = {
        "sequential": sequential(config),
        "sweep": sweep(devices, config),
        "sweep_one_device": sweep(devices[:1], config),
    }
    single = {"one_run_one_device": sweep(devices[:1], config, one), "one_run_two_devices": sweep(devices, config, one)}
    total = runs * config.evaluations
    for name, seconds in times.items():
        print(f"{name}_s: {seconds:.2f}  ({total / seconds:.0f} training evals/s)")
    print(f"batched_over_sequential: {times['sequential'] / times['sweep']:.3f}")
    print(f"batched_one_device_over_sequential: {times['sequential'] / times['sweep_one_device']:.3f}")
    for name, seconds in single.items():
        print(f"{name}_s: {seconds:.2f}  ({config.evaluations / seconds:.0f} training evals/s)")
    if len(devices) >= 2:
        print(f"two_devices_over_one: {times['sweep_one_device'] / times['sweep']:.3f}")
        print(f"one_run_two_devices_over_one: {single['one_run_one_device'] / single['one_run_two_devices']:.3f}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
