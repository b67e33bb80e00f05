"""How runs and their populations are laid out on devices: plain arithmetic, no JAX.

The engine shards runs over a (runs, population) mesh of devices (`mesh_shape`) and steps a
device's runs all at once or one at a time (`default_runs_per_step`); the footprint uses the
same decisions to size a sweep before anything is compiled.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import jax


def mesh_shape(devices: int, runs: int, batch_size: int) -> tuple[int, int]:
    """How to lay `devices` out as (runs axis, population axis).

    Runs are split first: the runs axis gets the largest divisor of the device count that
    is at most the number of runs. The devices left over split each run's population,
    when the batch divides evenly; otherwise they stay idle.
    """
    along_runs = max(d for d in range(1, devices + 1) if devices % d == 0 and d <= max(runs, 1))
    along_population = devices // along_runs
    if batch_size % along_population:
        along_population = 1
    return along_runs, along_population


def default_runs_per_step(devices: Sequence[jax.Device]) -> int | None:
    """How many runs a device advances at once: all of them (None) on accelerators, one
    at a time on CPUs, where a bigger batch lowers rollout throughput."""
    return 1 if devices[0].platform == "cpu" else None
