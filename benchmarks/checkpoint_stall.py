"""How long a sweep's checkpoint holds up training, measured side by side in one process.

A paper-preset ant_omni archive (1024 cells of [256, 256] policies, ~307 MB) is stacked
R times (default 8 runs, ~2.5 GB) on the local devices, as a sweep holds its archives, and
its checkpoint is written four ways, each twice (the better time kept):

- sync_npz: `save_checkpoint`, the whole write in the training thread (before);
- async_npz: `CheckpointWriter.offer`, which copies the archives to host memory and writes
  the `.npz` in a background thread (what runs and sweeps do now); `stall` is the time
  until training can go on, `total` until the file is on disk;
- orbax_async: orbax-checkpoint's `StandardCheckpointer` (asynchronous by default), the
  library's own way to save a pytree of device arrays in the background.

While each background write is in flight, a jitted matrix loop stands in for training, and
its rate is compared with the rate without a write (`*_compute_during_write`: 1.0 = no
slowdown), since on a small machine the writer competes for the same cores.

Prints `name: value` lines; the ratios `*_stall_over_sync` are the ones to quote.

Usage: python benchmarks/checkpoint_stall.py [--runs 8] [--cells 1024] [--dir DIR]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

warnings.filterwarnings("ignore")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=8, help="archives in the checkpoint (default 8)")
    parser.add_argument("--cells", type=int, default=1024)
    parser.add_argument("--dir", default=None, help="where to write (default: a temporary folder under .)")
    args = parser.parse_args()

    import jax
    import jax.numpy as jnp

    from smol_dsl.rundir.checkpoint import RunState
    from smol_dsl.runner.checkpoint import CheckpointWriter, checkpoint_arrays, save_checkpoint
    from smol_dsl.runner.engine import stack_runs
    from smol_dsl.runner.map_elites import empty_archive
    from smol_dsl.tasks import make_task

    task = make_task("ant_omni", episode_length=10, hidden_layer_sizes=(256, 256))
    template = task.init_policies(jax.random.key(0), 1)
    centroids = jax.random.uniform(jax.random.key(1), (args.cells, 2))
    one = empty_archive(template, centroids)
    noise = jax.jit(lambda x, k: jax.random.normal(k, x.shape, x.dtype))
    one = one.replace(
        genotypes=jax.tree.map(lambda x: noise(x, jax.random.key(2)), one.genotypes),
        fitnesses=jnp.zeros_like(one.fitnesses),
    )
    archives = jax.block_until_ready(stack_runs([one] * args.runs))
    keys = jax.random.split(jax.random.key(3), args.runs)
    states = [RunState(10, 1, 1000, 0, 0, [{"generation": g} for g in range(50)])] * args.runs
    size = sum(x.nbytes for x in jax.tree.leaves(archives))
    print(f"devices: {len(jax.local_devices())} {jax.local_devices()[0].platform}")
    print(f"checkpoint_gb: {size / 1e9:.2f} ({args.runs} runs x {size / args.runs / 1e6:.0f} MB)")

    root = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="checkpoint-stall-", dir="."))
    root.mkdir(parents=True, exist_ok=True)
    matrix = jnp.ones((512, 512), jnp.float32)
    work = jax.jit(lambda m: jnp.tanh(m @ m / 512.0))
    jax.block_until_ready(work(matrix))

    def compute_rate(seconds: float) -> float:
        """Matrix products per second over `seconds` (the stand-in for training)."""
        done, m, started = 0, matrix, time.perf_counter()
        while time.perf_counter() - started < seconds:
            m = work(m)
            done += 1
            if done % 8 == 0:
                jax.block_until_ready(m)
        jax.block_until_ready(m)
        return done / (time.perf_counter() - started)

    def compute_while(busy) -> float:
        done, m, started = 0, matrix, time.perf_counter()
        while busy():
            m = work(m)
            done += 1
            if done % 8 == 0:
                jax.block_until_ready(m)
        jax.block_until_ready(m)
        return done / max(time.perf_counter() - started, 1e-9)

    results: dict[str, float] = {}
    try:
        for attempt in range(2):
            path = root / f"sync-{attempt}.npz"
            started = time.perf_counter()
            save_checkpoint(path, archives, keys, states)
            results["sync_npz_stall_s"] = min(results.get("sync_npz_stall_s", 1e9), time.perf_counter() - started)
            path.unlink()

        idle_rate = compute_rate(3.0)
        for attempt in range(2):
            writer = CheckpointWriter()
            path = root / f"async-{attempt}.npz"
            started = time.perf_counter()
            writer.offer(path, lambda: checkpoint_arrays(archives, keys, states))
            stall = time.perf_counter() - started
            rate = compute_while(writer.writing)
            writer.flush()
            total = time.perf_counter() - started
            if stall < results.get("async_npz_stall_s", 1e9):
                results.update(async_npz_stall_s=stall, async_npz_total_s=total)
                results["async_npz_compute_during_write"] = rate / idle_rate
            path.unlink()

        try:
            import orbax.checkpoint as ocp
        except ImportError:
            ocp = None
        if ocp is not None:
            for attempt in range(2):
                checkpointer = ocp.StandardCheckpointer()
                path = (root / f"orbax-{attempt}").absolute()
                started = time.perf_counter()
                checkpointer.save(path, {"archives": archives, "keys": jax.random.key_data(keys)})
                stall = time.perf_counter() - started
                finished = {"done": False}

                def wait(c=checkpointer, f=finished) -> None:
                    c.wait_until_finished()
                    f["done"] = True

                waiter = threading.Thread(target=wait)
                waiter.start()
                rate = compute_while(lambda f=finished: not f["done"])
                waiter.join()
                total = time.perf_counter() - started
                checkpointer.close()
                if stall < results.get("orbax_async_stall_s", 1e9):
                    results.update(orbax_async_stall_s=stall, orbax_async_total_s=total)
                    results["orbax_async_compute_during_write"] = rate / idle_rate
                shutil.rmtree(path)
    finally:
        if not args.dir:
            shutil.rmtree(root, ignore_errors=True)

    for name, value in results.items():
        print(f"{name}: {value:.3f}")
    sync = results["sync_npz_stall_s"]
    print(f"async_npz_stall_over_sync: {results['async_npz_stall_s'] / sync:.3f}")
    print(f"async_npz_total_over_sync: {results['async_npz_total_s'] / sync:.3f}")
    if "orbax_async_stall_s" in results:
        print(f"orbax_async_stall_over_sync: {results['orbax_async_stall_s'] / sync:.3f}")
        print(f"orbax_async_total_over_sync: {results['orbax_async_total_s'] / sync:.3f}")
    print(f"sync_npz_gb_per_s: {size / 1e9 / sync:.2f}")


if __name__ == "__main__":
    sys.exit(main())
