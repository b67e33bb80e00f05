"""What a run or a sweep will need, by arithmetic, before anything is compiled.

At the paper's scale the numbers decide whether a sweep can run at all: a 1024-cell
ant_omni archive of [256, 256] policies is ~300 MB, so 80 runs hold ~24 GB of archives,
twice that while re-evaluating (each archive and its fresh copy), and every checkpoint
writes them all. `plan_footprint` computes these sizes from the task's shapes (found by
tracing, `task_sizes`), the settings and the device layout; `Footprint.describe` prints
them with the evaluation rate a time budget needs, and `fits` says whether the devices'
memory holds them. `largest_fitting` finds the most seeds (or runs per step) that fit.

The runner holds at most two sets of archives at once: while re-evaluating (each archive
and its fresh copy), while a checkpoint's host copy is made and written (training goes on
generating beside it, and waits for it before the next re-evaluation), and at the end
(every run's archive on its own beside the stacked ones). Where the devices share the
host's memory (CPUs) the peak is what this process already holds, plus the compiled
programs and the runtime (`runtime_bytes`), plus two sets of every device's archives (a
device whose share of a batch is split holds a copy of the run's archive), plus every
device's batches: the peak comes in a generation made while the checkpoint's host copy is
pending, and the batches add to the two sets rather than overlap them.

The working memory of a generation is an estimate: XLA decides the real figure when it
compiles. `POLICY_COPIES` and `STATE_COPIES` were fitted to the compiled generation program
(`memory_analysis`, CPU) of walker2d, halfcheetah and ant_omni at batches of 64 and 256 and
episodes of 100 and 1000 steps: its temporary memory was 5.5 to 5.8 policies' parameters
per offspring (two parents, the offspring, the variation's noise) plus a few environment
states; the estimate came out 0.84 to 0.95 of it, hence slightly on the safe side. The
tests hold it to within a factor of two of the compiled figure. A device that advances its
runs in groups (more local runs than `runs_per_step`) held about twice that working memory
in the host's memory at its peak (`GROUPED_BATCH_COPIES`): the resident memory of 4 ant_omni runs on 2 CPU
devices peaked at 2.07 GB in groups of one and 1.79 GB with both runs at once, although
the compiled ask program's own temporary memory is smaller in groups (149 against 187 MB a
device); the allocator keeps what the loop's buffers freed.

`runtime_bytes` was fitted to the peak resident memory (VmHWM, read from outside) of
`smol-dsl sweep` processes of 1, 2, 4 and 10 ant_omni runs of 256 cells on 2 CPU devices
(a test holds the estimates of 1 and 10 runs within 15%): on jax 0.12 peaks of 1.28, 1.36, 2.07 and
3.10 GB against estimates of 1.3, 1.4, 2.0 and 3.2 GB (0.5 GB of runtime); on jax 0.10
peaks of 1.59, 2.24 and 3.29 GB for 1, 4 and 10 runs against 1.6, 2.3 and 3.5 GB (0.8 GB).
"""

from __future__ import annotations

import math
import os
import shutil
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.runner.config import RunError
from smol_dsl.runner.layout import default_runs_per_step, mesh_shape
from smol_dsl.tasks import task_sizes

if TYPE_CHECKING:
    from smol_dsl.rundir.config import RunConfig

FLOAT_BYTES = 4
POLICY_COPIES = 6  # policy parameters alive per offspring in a generation (measured; see the docstring)
STATE_COPIES = 4  # environment states alive per rollout (measured; see the docstring)
GROUPED_BATCH_COPIES = 2  # a generation's working memory in host memory, runs in groups (measured)
# compiled programs, XLA's runtime and allocator, per jax line (measured; see the docstring)
RUNTIME_BYTES_BY_JAX = {(0, 10): 800_000_000}
RUNTIME_BYTES_LATER = 500_000_000  # jax 0.11 on (measured on 0.12)


def runtime_bytes() -> int:
    """What compiling and running the programs adds to a process, for the installed jax."""
    import jax

    line = tuple(int(part) for part in jax.__version__.split(".")[:2])
    if line in RUNTIME_BYTES_BY_JAX:
        return RUNTIME_BYTES_BY_JAX[line]
    return RUNTIME_BYTES_LATER if line > max(RUNTIME_BYTES_BY_JAX) else RUNTIME_BYTES_BY_JAX[min(RUNTIME_BYTES_BY_JAX)]


BUDGET_HOURS = (1, 24, 72)


@dataclass(frozen=True)
class DeviceMemory:
    """Memory one device offers, whether the devices share the host's memory (CPUs), and the
    host's memory (where checkpoints are copied to)."""

    platform: str
    count: int
    bytes_per_device: int
    shares_host: bool
    host_bytes: int

    @property
    def label(self) -> str:
        return f"{self.count} {self.platform} device{'s' if self.count > 1 else ''}"


def host_memory_bytes() -> int:
    """Physical memory, or the container's limit where that is lower (cgroup v2 or v1)."""
    total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    for limit in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(limit).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            total = min(total, int(text))
    return total


def process_bytes() -> int:
    """The memory this process holds now (its resident set): imports, traced tasks and
    whatever the caller has allocated, which a run started from it adds to."""
    try:
        resident_pages = int(Path("/proc/self/statm").read_text().split()[1])
        return resident_pages * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        import resource

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB on Linux, bytes on macOS
        return peak if sys.platform == "darwin" else peak * 1024


def device_memory(devices: list) -> DeviceMemory:
    """What the JAX devices offer: an accelerator's allocator limit, or for CPU devices the
    host's memory, which they share."""
    first = devices[0]
    host = host_memory_bytes()
    stats = first.memory_stats() if hasattr(first, "memory_stats") else None
    if first.platform != "cpu" and stats and stats.get("bytes_limit"):
        return DeviceMemory(first.platform, len(devices), int(stats["bytes_limit"]), False, host)
    return DeviceMemory(first.platform, len(devices), host, True, host)


@dataclass(frozen=True)
class Footprint:
    """Sizes of one process's share of a sweep (a run is a sweep of one)."""

    config: RunConfig
    runs: int
    parameters: int
    observations: int
    actions: int
    archive_bytes: int  # one run's archive
    policy_bytes: int  # one run's generation: parents, offspring and variation noise (on every device of its batch)
    rollout_bytes: int  # one run's generation: environment states and per-step records (split between them)
    along_runs: int  # the device mesh: runs axis x population axis
    along_population: int
    runs_per_step: int | None  # runs a device advances at once (None: all of its runs)
    memory: DeviceMemory
    baseline_bytes: int  # host memory the process holds before the run, and its compiled programs and runtime

    @property
    def batch_bytes(self) -> int:
        """One run's generation on one device."""
        return self.policy_bytes + self.rollout_bytes

    @property
    def local_runs(self) -> int:
        """Runs (padding included) whose archives one device holds."""
        return math.ceil(self.runs / self.along_runs)

    @property
    def parallel_runs(self) -> int:
        """Runs a device rolls out at once."""
        return self.local_runs if self.runs_per_step is None else min(self.runs_per_step, self.local_runs)

    @property
    def archives_bytes(self) -> int:
        return self.runs * self.archive_bytes

    @property
    def checkpoint_bytes(self) -> int:
        return self.archives_bytes

    @property
    def device_archive_bytes(self) -> int:
        """One device's archives while re-evaluating: each archive and its fresh copy."""
        return 2 * self.local_runs * self.archive_bytes

    @property
    def offspring_bytes(self) -> int:
        """One run's offspring batch, the policies it scores in a generation."""
        return self.policy_bytes // POLICY_COPIES

    @property
    def device_batch_bytes(self) -> int:
        """One device's working memory in a generation: making and scoring the offspring of
        `parallel_runs` runs at a time, and the offspring of every other local run, made
        before any is scored."""
        per_run = self.policy_bytes + self.rollout_bytes // self.along_population
        return self.parallel_runs * per_run + (self.local_runs - self.parallel_runs) * self.offspring_bytes

    @property
    def device_bytes(self) -> int:
        return self.device_archive_bytes + self.device_batch_bytes

    @property
    def devices_used(self) -> int:
        return self.along_runs * self.along_population

    @property
    def held_archives_bytes(self) -> int:
        """Every device's archives (padding, and copies where a run's batch is split, included)."""
        return self.devices_used * self.local_runs * self.archive_bytes

    @property
    def host_peak_bytes(self) -> int:
        """The most host memory the process holds at once, where the devices share it (CPUs):
        two sets of archives and every device's batches (or, at the end, one run's host copy)."""
        batches = self.along_runs * self.device_batch_bytes  # a run's batch split over devices: counted once (measured)
        if self.parallel_runs < self.local_runs:  # in groups: the host allocator keeps what the loop freed (measured)
            batches *= GROUPED_BATCH_COPIES
        return self.baseline_bytes + 2 * self.held_archives_bytes + max(batches, self.archive_bytes)

    @property
    def host_bytes(self) -> int:
        """The host memory the process needs: with devices of their own (accelerators), what it
        holds before the run and the checkpoint's host copy (and one run's, at the end)."""
        if self.memory.shares_host:
            return self.host_peak_bytes
        return self.baseline_bytes + self.checkpoint_bytes + self.archive_bytes

    @property
    def needed_bytes(self) -> int:
        """What the memory that is checked must hold: per device on accelerators; on CPUs,
        the process's peak in the host memory they share."""
        return self.host_peak_bytes if self.memory.shares_host else self.device_bytes

    @property
    def available_bytes(self) -> int:
        return self.memory.bytes_per_device

    def fits(self) -> bool:
        return self.needed_bytes <= self.available_bytes and self.host_bytes <= self.memory.host_bytes

    @property
    def reevaluations(self) -> int:
        """At most: every cell re-evaluated at every phase boundary."""
        return (self.config.num_phases - 1) * self.config.num_centroids

    @property
    def evaluations(self) -> int:
        return self.runs * (self.config.evaluations + self.reevaluations)

    def describe(self, out_dir: Path | None = None) -> str:
        """The estimate as the CLI prints it."""
        config = self.config
        boundaries = config.num_phases - 1
        layers = ", ".join(str(size) for size in config.hidden_layer_sizes)
        lines = [
            f"policy: [{layers}] MLP, {self.observations} observations -> {self.actions} actions: "
            f"{self.parameters:,} parameters; archive: {config.num_centroids} cells, "
            f"{byte_size(self.archive_bytes)} per run, {byte_size(self.archives_bytes)} for {self.runs} run(s)",
            self._memory_line(),
            f"checkpoint: {byte_size(self.checkpoint_bytes)}, rewritten in the background at up to "
            f"{boundaries} phase boundaries (at most {byte_size(self.checkpoint_bytes * boundaries)} written in all)"
            + _free_space(out_dir, self.checkpoint_bytes),
            f"evaluations: {self.runs} x ({config.evaluations:,} training + up to {self.reevaluations:,} "
            f"re-evaluation) = {_count(self.evaluations)} ({_count(self.evaluations * config.episode_length)} "
            f"environment steps of {config.episode_length})",
            "to finish in "
            + "; ".join(
                f"{hours} h: {_count(self.evaluations / (3600 * hours))} evals/s "
                f"({_count(self.evaluations * config.episode_length / (3600 * hours))} steps/s)"
                for hours in BUDGET_HOURS
            ),
        ]
        return "\n".join(lines)

    def _memory_line(self) -> str:
        layout = f"runs split {self.along_runs} way(s), each batch {self.along_population} way(s)"
        batches = f"for batches of {self.config.batch_size} ({self.parallel_runs} run(s) at once)"
        held = f"{byte_size(self.baseline_bytes)} for this process, its compiled programs and runtime"
        if self.memory.shares_host:
            archives = self.held_archives_bytes
            return (
                f"memory ({self.memory.label} sharing the host's; {layout}): {held} + {byte_size(2 * archives)} of "
                f"archives held twice (re-evaluating, or beside the checkpoint's host copy) + "
                f"{byte_size(self.host_peak_bytes - self.baseline_bytes - 2 * archives)} {batches} "
                f"= {byte_size(self.needed_bytes)} of {byte_size(self.available_bytes)} host memory"
            )
        return (
            f"device memory ({self.memory.label}: {layout}): {byte_size(self.device_archive_bytes)} of archives "
            f"while re-evaluating + {byte_size(self.device_batch_bytes)} {batches} = {byte_size(self.device_bytes)} "
            "per device "
            f"of {byte_size(self.available_bytes)}; host memory: {held} + {byte_size(self.checkpoint_bytes)} for the "
            f"checkpoint's copy + {byte_size(self.archive_bytes)} for one run's = {byte_size(self.host_bytes)} of "
            f"{byte_size(self.memory.host_bytes)}"
        )


def plan_footprint(
    config: RunConfig,
    runs: int,
    memory: DeviceMemory,
    runs_per_step: int | None = None,
    baseline_bytes: int | None = None,
) -> Footprint:
    """The footprint of `runs` runs of `config` on these devices (runs_per_step None: all of
    a device's runs at once), started from a process that holds `baseline_bytes` (None:
    this process, now) besides the programs it will compile."""
    sizes = task_sizes(config.task, tuple(config.hidden_layer_sizes), config.physics)
    descriptors = sizes.descriptors
    # per cell: the policy, its fitness and lane (4 bytes each), its descriptor and centroid
    archive = config.num_centroids * (sizes.parameters + 2 + 2 * descriptors) * FLOAT_BYTES
    policies = POLICY_COPIES * config.batch_size * sizes.parameters * FLOAT_BYTES
    per_episode = config.episode_length * (descriptors + 2) * FLOAT_BYTES  # rewards, descriptors, ends
    rollouts = config.batch_size * (STATE_COPIES * sizes.state_bytes + per_episode)
    along_runs, along_population = mesh_shape(memory.count, runs, config.batch_size)
    return Footprint(
        config=config,
        runs=runs,
        parameters=sizes.parameters,
        observations=sizes.observations,
        actions=sizes.actions,
        archive_bytes=archive,
        policy_bytes=policies,
        rollout_bytes=rollouts,
        along_runs=along_runs,
        along_population=along_population,
        runs_per_step=runs_per_step,
        memory=memory,
        baseline_bytes=(process_bytes() if baseline_bytes is None else baseline_bytes) + runtime_bytes(),
    )


def largest_fitting(candidates: range, footprint_of: Callable[[int], Footprint]) -> int | None:
    """The largest candidate whose footprint fits, or None (footprints grow with it)."""
    for candidate in reversed(candidates):
        if footprint_of(candidate).fits():
            return candidate
    return None


def _free_space(directory: Path | None, needed: int) -> str:
    if directory is None:
        return ""
    existing = directory
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:
        free = shutil.disk_usage(existing).free
    except OSError:
        return ""
    warning = "; not enough for a checkpoint and its replacement" if free < 2 * needed else ""
    return f"; {byte_size(free)} free in {existing}{warning}"


def byte_size(count: float) -> str:
    """A number of bytes as people read it: 1.2 GB, 830.4 kB."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if count >= scale:
            return f"{count / scale:.1f} {unit}"
    return f"{count:.0f} B"


def _count(count: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if count >= scale:
            return f"{count / scale:.1f} {unit}"
    return f"{count:.0f}" if count >= 100 or count == 0 else f"{count:.2g}"  # a small rate is not 0


def fit_sweep(
    config: RunConfig,
    num_schedules: int,
    seeds: Sequence[int],
    devices: Sequence[Any],
    runs_per_step: int | None = -1,
    part: tuple[int, int] = (0, 1),
    baseline_bytes: int | None = None,
) -> Footprint:
    """The footprint of this process's share of a sweep (a run is a sweep of one schedule
    and one seed) on `devices`, or a RunError that says what does not fit and the most
    seeds that would.

    `runs_per_step` as in `run_sweep`: -1 lets the device choose (one run at a time on a
    CPU; on an accelerator as many as fit, all of them if they do), None all of them.
    `baseline_bytes` is the host memory the process holds before the sweep (None: this
    process's, now).
    """
    memory = device_memory(list(devices))
    index, parts = part
    baseline = process_bytes() if baseline_bytes is None else baseline_bytes

    def runs_with(count: int) -> int:
        return len(range(index, num_schedules * count, parts))

    def plan(runs: int, per_step: int | None) -> Footprint:
        return plan_footprint(config, runs, memory, per_step, baseline)

    runs = runs_with(len(seeds))
    automatic = runs_per_step == -1
    chosen = default_runs_per_step(list(devices)) if automatic else runs_per_step
    footprint = plan(runs, chosen)
    if footprint.fits():
        return footprint
    if automatic and chosen is None:  # an accelerator: fewer runs at once
        most = largest_fitting(range(1, footprint.local_runs), lambda k: plan(runs, k))
        if most is not None:
            return plan(runs, most)
    least = plan(runs, 1)
    what = "one run" if runs == 1 else f"{runs} runs"
    where = (
        f"the {byte_size(least.available_bytes)} of host memory that the {memory.label} share"
        if memory.shares_host
        else f"the {byte_size(least.available_bytes)} of one {memory.platform} device"
    )
    if memory.shares_host:
        twice = 2 * least.held_archives_bytes
        parts_text = (
            f"{byte_size(least.baseline_bytes)} for this process and its compiled programs, {byte_size(twice)} of "
            f"archives held twice (while re-evaluating, or beside the checkpoint's host copy), and "
            f"{byte_size(least.host_peak_bytes - least.baseline_bytes - twice)} for batches of {config.batch_size}"
        )
    else:
        parts_text = (
            f"{byte_size(least.archive_bytes)} of archive per run, held twice while it is re-evaluated "
            f"({byte_size(least.device_archive_bytes)} per device), plus {byte_size(least.device_batch_bytes)} for "
            f"batches of {config.batch_size}"
        )
    if least.needed_bytes <= least.available_bytes:  # the devices hold it, the host does not
        where = f"the {byte_size(memory.host_bytes)} of host memory"
        parts_text = f"{byte_size(least.host_bytes)} for the process and the checkpoint's host copy"
        total = least.host_bytes
    else:
        total = least.needed_bytes
    message = f"{what} of {config.task} need more than {where}: {parts_text}, {byte_size(total)} in all. "
    most_seeds = largest_fitting(range(1, len(seeds)), lambda count: plan(runs_with(count), 1))
    if most_seeds is not None:
        message += (
            f"At most --seeds {most_seeds} fits with {num_schedules} schedule(s) on {memory.label}; "
            "or share the runs between processes on more devices (--num-processes, see docs/scaling.md)."
        )
    else:
        message += "Not even one run fits: use fewer --centroids or a smaller --batch-size."
    raise RunError(message)
