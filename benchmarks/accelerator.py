"""The acceptance command for an accelerator: does smol-dsl work on the devices JAX sees, how
fast is it there, and how long would the paper's experiment take.

    python benchmarks/accelerator.py [--small] [--out FILE.json] [--budget SECONDS]

On whatever devices JAX sees (every local GPU, or the CPU split into one device per core, as
the CLI does), it measures, in this order, and prints a Markdown table of each part:

1. the devices, the versions and what `environment.json` would record for a run here;
2. the runner at the paper's settings (`--preset paper`): a few generations of one walker2d
   run (batch 8,192, 1,000 steps), one halfcheetah run (the same), one ant_omni run (batch
   1,024, 100 steps, [256, 256] policies), and the paper's 8 ant_omni conditions as one
   sweep (runs vmapped together on accelerators) against the one run; each timed by the same
   warm-up as `--dry-run` (`smol_dsl.runner.estimate.measure_sweep`: compile, generations,
   a re-evaluation chunk), then one phase-boundary re-evaluation of a full archive (every
   one of the 1,024 cells filled) on the run's own engine; and the peak device memory of
   each (an accelerator's `memory_stats()["peak_bytes_in_use"]`; on CPUs the process's peak
   resident memory, reset before each) beside `--dry-run`'s estimate for the same settings.
   They run in the order of their estimates, smallest first: an accelerator's peak cannot
   be reset, so a peak no higher than the one before is reported as such;
3. the paper's experiment on this machine (`smol-dsl reproduce TASK --preset paper`, 8
   conditions x 10 seeds = 80 runs of each task): the measured rates scaled to 80 runs (a
   generation of R runs taken to cost R/r times that of the r measured: an upper estimate
   where more runs at once use the device better) through the same arithmetic as `--dry-run`
   (`estimate_duration`), the device-hours, the runs per device-hour, and whether the 80
   runs fit in one process here (`fit_sweep`);
4. raw rollouts, `Task.score` jitted alone on the first device: environment steps/s of
   walker2d (1,000-step episodes) and ant_omni (100 steps), the paper's episodes, on each
   physics (`--physics spring` and `mjx`, MJX-JAX), at batches
   from 1,024 to 32,768, for as long as the time budget allows (a batch whose rollout would
   overrun it, predicted from the batch before, is reported as skipped).

Nothing is refused silently: a part that runs out of device memory is reported as "out of
memory" and the tables go on; a part that fails otherwise is reported with its error, and
the command then exits 1. `--small` uses tiny settings (a test runs it on CPUs), named as
such in every table. XLA's compilations are kept in a persistent cache (`--cache`), so a
second try compiles little.

About 5 minutes on one H100/H200-class GPU is the design target, compilation included (not
yet measured on one: see docs/scaling.md).
"""

from __future__ import annotations

import argparse
import datetime
import gc
import json
import math
import os
import platform
import sys
import time
import traceback
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.results.conditions import PAPER_CONDITIONS, PAPER_SEEDS, PAPER_TASKS

warnings.filterwarnings("ignore")
if TYPE_CHECKING:
    import jax

    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.runner.estimate import Measurement
    from smol_dsl.runner.footprint import Footprint

ROLLOUT_TASKS = ("walker2d", "ant_omni")
ROLLOUT_PHYSICS = ("spring", "mjx")  # `--physics`: Brax's spring and MuJoCo's MJX (MJX-JAX)
ROLLOUT_BATCHES = (1024, 4096, 8192, 16384, 32768)
SMALL_ROLLOUT_BATCHES = (16, 32)
SMALL_SETTINGS = dict(
    batch_size=16,
    episode_length=10,
    hidden_layer_sizes=(8, 8),
    num_centroids=32,
    num_init_cvt_samples=320,
    num_phases=10,
    evaluations=512,
)
"""--small: the paper's settings shrunk to what a 2-core CPU measures in about two minutes."""


@dataclass
class RunnerPart:
    """One runner measurement: `runs` runs of `task` under the named schedules."""

    task: str
    runs: int
    config: RunConfig
    schedules: tuple[str, ...]
    status: str = "not run"
    runs_per_step: int | None = None
    estimated_bytes: int | None = None  # --dry-run's estimate of the memory that is checked
    peak_bytes: int | None = None
    peak_is_own: bool = True  # False: no higher than an earlier part's peak (an accelerator's cannot be reset)
    measurement: Measurement | None = None
    full_reevaluation_seconds: float | None = None
    full_reevaluation_cells: int | None = None  # cells filled after the full archive's re-evaluation
    seconds: float = 0.0
    note: str = ""

    @property
    def label(self) -> str:
        return f"{self.task}, {self.runs} run{'s' if self.runs > 1 else ''}"


@dataclass
class RolloutRow:
    task: str
    physics: str
    episode_length: int
    batch_size: int
    status: str = "not run"
    compile_seconds: float | None = None
    seconds: float | None = None
    steps_per_second: float | None = None
    note: str = ""


@dataclass
class ReproduceRow:
    task: str
    runs: int
    scaled_from_runs: int | None = None
    wall_seconds: float | None = None
    device_hours: float | None = None
    runs_per_device_hour: float | None = None
    fits: str = ""
    status: str = "not run"


@dataclass
class Report:
    small: bool
    budget_seconds: float
    started: str
    devices: list[dict[str, Any]] = field(default_factory=list)
    environment: dict[str, Any] = field(default_factory=dict)
    runner: list[RunnerPart] = field(default_factory=list)
    reproduce: list[ReproduceRow] = field(default_factory=list)
    rollouts: list[RolloutRow] = field(default_factory=list)
    elapsed_seconds: float = 0.0
    errors: int = 0


# ---------------------------------------------------------------------------- measuring
def out_of_memory(error: BaseException) -> bool:
    """Whether an error is a device running out of memory (XLA's RESOURCE_EXHAUSTED, or the
    runner's RunError that says so)."""
    text = str(error)
    return "RESOURCE_EXHAUSTED" in text or "out of memory" in text.lower()


def failure(error: BaseException) -> str:
    """An error in one line for a table, its traceback to stderr."""
    traceback.print_exception(error, file=sys.stderr)
    return f"error: {type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"[:300]


def peak_memory(devices: list[jax.Device]) -> int:
    """The peak memory so far: the largest device peak on accelerators; on CPUs the
    process's peak resident memory (VmHWM), which `reset_peak_memory` resets."""
    if devices[0].platform != "cpu":
        peaks = [(device.memory_stats() or {}).get("peak_bytes_in_use", 0) for device in devices]
        return int(max(peaks))
    status = Path("/proc/self/status").read_text()
    line = next(line for line in status.splitlines() if line.startswith("VmHWM:"))
    return int(line.split()[1]) * 1024


def reset_peak_memory(devices: list[jax.Device]) -> bool:
    """Reset the peak where that can be done (a process's VmHWM, Linux's clear_refs 5);
    an accelerator's peak cannot be: False."""
    gc.collect()
    if devices[0].platform != "cpu":
        return False
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def fill_archive(engine: Any, config: RunConfig, seed: int) -> Any:
    """An archive per run (one run here) with every cell filled: random policies, each
    inserted at its cell's centroid, so that a re-evaluation re-scores every cell."""
    import jax
    import jax.numpy as jnp

    from smol_dsl.qdax.scoring import LANE, cvt_centroids
    from smol_dsl.tasks import task_spec

    spec = task_spec(config.task)
    centroids = cvt_centroids(
        config.num_centroids,
        spec.descriptor_low,
        spec.descriptor_high,
        config.num_init_cvt_samples,
        jax.random.key(seed),
    )
    empty = engine.empty_archives(centroids[None])
    policies = engine.task.init_policies(jax.random.key(seed + 1), config.num_centroids)

    def fill(archive: Any, genotypes: Any, centroids: jax.Array) -> Any:
        cells = centroids.shape[0]
        lanes = {LANE: jnp.zeros((cells,), jnp.int32)}
        return archive.add(genotypes, centroids, jnp.zeros((cells,)), lanes)

    stacked = jax.tree.map(lambda x: x[None], policies)
    filled = jax.jit(jax.vmap(fill), out_shardings=engine.sharding)
    return filled(empty, engine.put(stacked), engine.put(centroids[None]))


def full_reevaluation(part: RunnerPart, devices: list[jax.Device]) -> None:
    """Time one phase-boundary re-evaluation of a full archive on the run's own engine (the
    one `measure_sweep` built and compiled: the same programs)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import smol_dsl
    from smol_dsl.runner.engine import shared_engine
    from smol_dsl.runner.plan import run_channels

    config = part.config
    schedule = smol_dsl.load(part.schedules[0])
    engine = shared_engine(config.task, config, devices, part.runs_per_step, 1, run_channels([schedule]))
    full = fill_archive(engine, config, config.seed)
    filled = int(np.sum(np.asarray(full.fitnesses) > -np.inf))
    if filled != config.num_centroids:
        raise RuntimeError(f"the filled archive holds {filled} of {config.num_centroids} elites")
    bodies = engine.put(jnp.full((1, len(engine.channels)), 1.1, jnp.float32))
    starts = engine.put(jax.tree.map(lambda x: x[None], engine.task.episode_start(config.seed)))
    extinctions = engine.put(jnp.zeros((1,), jnp.float32))
    keys = engine.put(jax.random.split(jax.random.key(config.seed), 1))
    began = time.perf_counter()
    fresh, _ = engine.reevaluate(full, bodies, starts, extinctions, keys)
    jax.block_until_ready(fresh)
    part.full_reevaluation_seconds = time.perf_counter() - began
    part.full_reevaluation_cells = int(np.sum(np.asarray(fresh.fitnesses) > -np.inf))


def plan_part(part: RunnerPart, devices: list[jax.Device]) -> Footprint | None:
    """--dry-run's footprint for the part, or None and the part's status set if it does not fit."""
    from smol_dsl.runner.config import RunError
    from smol_dsl.runner.footprint import fit_sweep

    seeds = [part.config.seed]
    try:
        footprint = fit_sweep(part.config, len(part.schedules), seeds, devices)
    except RunError as error:
        part.status, part.note = "does not fit", str(error)
        return None
    part.runs_per_step = footprint.runs_per_step
    part.estimated_bytes = footprint.needed_bytes
    return footprint


def measure_part(part: RunnerPart, devices: list[jax.Device], previous_peak: int, timed: int, enough: float) -> int:
    """Measure one runner part (see the module's docstring); the peak memory after it."""
    import smol_dsl
    from smol_dsl.runner.config import check_config
    from smol_dsl.runner.estimate import measure_sweep

    began = time.perf_counter()
    resettable = reset_peak_memory(devices)
    plan_part(part, devices)  # again, from what this process holds now (CPUs: the baseline of the estimate)
    try:
        schedules = [smol_dsl.load(name) for name in part.schedules]
        for schedule in schedules:
            check_config(part.config, schedule)
        part.measurement = measure_sweep(
            part.config,
            schedules,
            [part.config.seed],
            devices,
            part.runs_per_step,
            timed_generations=timed,
            enough_seconds=enough,
        )
        if part.runs == 1:
            full_reevaluation(part, devices)
        part.status = "ok"
    except Exception as error:  # reported in the table; the tables go on
        if out_of_memory(error):
            part.status, part.note = "out of memory", str(error).splitlines()[0][:300]
        else:
            part.status = failure(error)
    gc.collect()
    part.peak_bytes = peak_memory(devices)
    part.peak_is_own = resettable or part.peak_bytes > previous_peak
    part.seconds = time.perf_counter() - began
    return part.peak_bytes


def measure_rollouts(report: Report, devices: list[jax.Device], deadline: float) -> None:
    """Raw rollout throughput by batch size, while the budget lasts (see the module's docstring)."""
    import jax
    import jax.numpy as jnp

    from smol_dsl.rundir.presets import preset_config
    from smol_dsl.tasks import make_task

    batches = SMALL_ROLLOUT_BATCHES if report.small else ROLLOUT_BATCHES
    for name, physics in ((name, physics) for name in ROLLOUT_TASKS for physics in ROLLOUT_PHYSICS):
        paper = preset_config(name, "paper")
        episode = SMALL_SETTINGS["episode_length"] if report.small else paper.episode_length
        hidden = SMALL_SETTINGS["hidden_layer_sizes"] if report.small else tuple(paper.hidden_layer_sizes)
        task = make_task(name, episode_length=episode, hidden_layer_sizes=hidden, physics=physics)
        score = jax.jit(task.score, compiler_options=task.compiler_options(devices[0].platform))
        start = task.episode_start(0)
        body = jnp.ones((1,), jnp.float32)
        rate, compile_seconds, stopped = None, 0.0, ""
        for batch in batches:
            row = RolloutRow(name, physics, episode, batch)
            report.rollouts.append(row)
            if stopped:
                row.status = stopped
                continue
            predicted = compile_seconds + (batch * episode / rate if rate else 0.0)
            if rate and time.perf_counter() + predicted > deadline:
                row.status = f"skipped: would take about {predicted:.0f} s, past the budget (--budget)"
                continue
            try:
                params = task.init_policies(jax.random.key(batch), batch)
                began = time.perf_counter()
                compiled = score.lower(params, body, start).compile()
                row.compile_seconds = compile_seconds = time.perf_counter() - began
                began = time.perf_counter()
                jax.block_until_ready(compiled(params, body, start))
                row.seconds = time.perf_counter() - began
                row.steps_per_second = rate = batch * episode / row.seconds
                row.status = "ok"
                del params, compiled
            except Exception as error:  # reported; the table goes on
                if out_of_memory(error):
                    row.status = "out of memory"
                    stopped = f"not run: batch {batch} ran out of memory"
                else:
                    row.status = failure(error)
            gc.collect()


def estimate_reproduce(report: Report, devices: list[jax.Device]) -> None:
    """The paper's 80 runs of each task on this machine, from the runner's measurements."""
    from smol_dsl.runner.config import RunError
    from smol_dsl.runner.estimate import estimate_duration
    from smol_dsl.runner.footprint import fit_sweep

    by_task: dict[str, RunnerPart] = {}
    for part in report.runner:
        if part.status == "ok" and part.measurement is not None:
            if part.task not in by_task or part.runs > by_task[part.task].runs:
                by_task[part.task] = part
    runs = len(PAPER_CONDITIONS) * PAPER_SEEDS
    for task in PAPER_TASKS:
        row = ReproduceRow(task, runs)
        report.reproduce.append(row)
        part = by_task.get(task)
        if part is None:
            row.status = "not measured: its runner part did not run"
            continue
        measured = part.measurement
        assert measured is not None
        factor = runs / measured.runs
        scaled = replace(
            measured,
            runs=runs,
            seeds=PAPER_SEEDS,
            generation_seconds=measured.generation_seconds * factor,
            chunk_seconds=measured.chunk_seconds * factor,
        )
        duration = estimate_duration(part.config, scaled)
        row.scaled_from_runs = measured.runs
        row.wall_seconds = duration.total_seconds
        row.device_hours = duration.total_seconds / 3600 * len(devices)
        row.runs_per_device_hour = runs / row.device_hours if row.device_hours else None
        try:
            footprint = fit_sweep(part.config, len(PAPER_CONDITIONS), list(range(PAPER_SEEDS)), devices)
            per_step = footprint.runs_per_step
            at_once = "all its runs" if per_step is None else "1 run" if per_step == 1 else f"{per_step} runs"
            row.fits = f"yes ({at_once} at once per device)"
        except RunError as error:
            row.fits = "no: " + str(error).split(". ", 1)[-1]
        row.status = "ok"


# ---------------------------------------------------------------------------- the parts
def runner_parts(small: bool) -> list[RunnerPart]:
    """The runner's parts, at the paper's settings (or --small's)."""
    from smol_dsl.rundir.presets import preset_config

    settings = SMALL_SETTINGS if small else {}
    one = [RunnerPart(task, 1, preset_config(task, "paper", **settings), ("vanilla",)) for task in PAPER_TASKS]
    ant = preset_config("ant_omni", "paper", **settings)
    sweep = RunnerPart("ant_omni", len(PAPER_CONDITIONS), ant, tuple(c.schedule for c in PAPER_CONDITIONS))
    return [*one, sweep]


def describe_devices(devices: list[jax.Device]) -> list[dict[str, Any]]:
    rows = []
    for device in devices:
        stats = device.memory_stats() if device.platform != "cpu" else None
        rows.append(
            {
                "id": device.id,
                "platform": device.platform,
                "kind": device.device_kind,
                "memory_limit_bytes": (stats or {}).get("bytes_limit"),
            }
        )
    return rows


def measure(small: bool, budget: float) -> Report:
    """Every part, in the order of the module's docstring, within `budget` seconds where it can."""
    import jax

    from smol_dsl.rundir.environment import describe_environment

    started = time.perf_counter()
    deadline = started + budget
    devices = jax.local_devices()
    report = Report(small=small, budget_seconds=budget, started=datetime.datetime.now().isoformat(timespec="seconds"))
    report.devices = describe_devices(devices)
    report.environment = describe_environment(devices)
    print(f"devices: {len(devices)} x {devices[0].device_kind} ({devices[0].platform})", file=sys.stderr)
    timed, enough = (2, 2.0) if small else (3, 10.0)
    parts = runner_parts(small)
    footprints = {id(part): plan_part(part, devices) for part in parts}
    parts.sort(key=lambda part: part.estimated_bytes if part.estimated_bytes is not None else math.inf)
    peak = 0
    for part in parts:
        report.runner.append(part)
        if footprints[id(part)] is None:
            continue
        print(f"runner: {part.label} ...", file=sys.stderr)
        peak = measure_part(part, devices, peak, timed, enough)
        print(f"  {part.status} in {part.seconds:.1f} s", file=sys.stderr)
    report.runner.sort(key=lambda part: (PAPER_TASKS.index(part.task), part.runs))
    estimate_reproduce(report, devices)
    print("rollouts ...", file=sys.stderr)
    measure_rollouts(report, devices, deadline)
    report.elapsed_seconds = time.perf_counter() - started
    report.errors = sum(row.status.startswith("error") for row in [*report.runner, *report.rollouts, *report.reproduce])
    return report


# ---------------------------------------------------------------------------- showing
def _size(count: int | None) -> str:
    if count is None:
        return "–"
    for unit, scale in (("GB", 1e9), ("MB", 1e6)):
        if count >= scale:
            return f"{count / scale:.2f} {unit}"
    return f"{count / 1e3:.0f} kB"


def _rate(value: float | None) -> str:
    if value is None:
        return "–"
    for unit, scale in (("M", 1e6), ("k", 1e3)):
        if value >= scale:
            return f"{value / scale:.2f} {unit}"
    return f"{value:.1f}"


def _seconds(value: float | None) -> str:
    if value is None:
        return "–"
    if value >= 3600:
        return f"{value / 3600:.1f} h"
    return f"{value:.2f} s" if value < 10 else f"{value:.0f} s"


def markdown(report: Report) -> str:
    """The report as Markdown tables (see the module's docstring)."""
    from smol_dsl.errors import counted

    devices = report.devices
    settings = "the --small settings (not the paper's)" if report.small else "the paper's settings (--preset paper)"
    env = report.environment
    packages = ", ".join(f"{name} {version}" for name, version in env.get("packages", {}).items() if version)
    memory = devices[0]["memory_limit_bytes"]
    lines = [
        f"# smol-dsl on {len(devices)} x {devices[0]['kind']} ({devices[0]['platform']})",
        "",
        f"- started {report.started}, took {_seconds(report.elapsed_seconds)} (budget {report.budget_seconds:.0f} s)",
        f"- devices: {len(devices)} x {devices[0]['kind']}"
        + (f", {_size(memory)} for JAX each" if memory else " (sharing the host's memory)"),
        f"- Python {env.get('python')}, smol-dsl {env.get('smol_dsl')} (commit {env.get('commit')}); {packages}",
        f"- processor: {env.get('processor')}; system: {env.get('system')}",
        "",
        f"## The runner at {settings}",
        "",
        "| part | batch | steps | runs at once | evals/s | env steps/s | generation | compile "
        "| full re-evaluation | peak memory | --dry-run estimate | peak / estimate | status |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for part in report.runner:
        m = part.measurement
        at_once = "all" if part.runs_per_step is None else str(part.runs_per_step)
        reevaluation = (
            f"{_seconds(part.full_reevaluation_seconds)} ({part.config.num_centroids} cells, "
            f"{part.full_reevaluation_cells} filled after)"
            if part.full_reevaluation_seconds is not None
            else "–"
        )
        peak = _size(part.peak_bytes) + ("" if part.peak_is_own else " (≤, an earlier part's)")
        ratio = (
            f"{part.peak_bytes / part.estimated_bytes:.2f}"
            if part.peak_bytes and part.estimated_bytes and part.peak_is_own
            else "–"
        )
        status = part.status + (f": {part.note}" if part.note else "")
        lines.append(
            f"| {part.label} | {part.config.batch_size} | {part.config.episode_length} | {at_once} | "
            f"{_rate(m.evaluations_per_second if m else None)} | {_rate(m.steps_per_second if m else None)} | "
            f"{_seconds(m.generation_seconds if m else None)} | {_seconds(m.compile_seconds if m else None)} | "
            f"{reevaluation} | {peak} | {_size(part.estimated_bytes)} | {ratio} | {status} |"
        )
    one = next((p for p in report.runner if p.task == "ant_omni" and p.runs == 1 and p.measurement), None)
    many = next((p for p in report.runner if p.task == "ant_omni" and p.runs > 1 and p.measurement), None)
    if one and many and one.measurement and many.measurement:
        gain = many.measurement.evaluations_per_second / one.measurement.evaluations_per_second
        lines += [
            "",
            f"Scaling over runs: {many.runs} ant_omni runs together, {_rate(many.measurement.evaluations_per_second)} "
            f"evals/s, over one run's {_rate(one.measurement.evaluations_per_second)}: **{gain:.2f}x** "
            f"(ideal {many.runs}x where one run leaves the devices idle, 1x where it fills them).",
        ]
    lines += [
        "",
        f"## The paper's experiment here: `smol-dsl reproduce TASK` at {settings}",
        "",
        "| task | runs | scaled from | estimated wall time | device-hours | runs per device-hour "
        "| fits in one process |",
        "| --- | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for row in report.reproduce:
        if row.status != "ok":
            lines.append(f"| {row.task} | {row.runs} | – | {row.status} | – | – | – |")
            continue
        lines.append(
            f"| {row.task} | {row.runs} | {counted(row.scaled_from_runs or 0, 'run')} | {_seconds(row.wall_seconds)} | "
            f"{row.device_hours:.2f} | {row.runs_per_device_hour:.1f} | {row.fits} |"
        )
    lines += [
        "",
        "Scaled linearly from the runs measured together (an upper estimate where more runs at once use the "
        "device better), every archive full at every boundary; not counted: metrics, checkpoints, figures.",
        "",
        "## Raw rollouts (`Task.score` jitted alone, first device; spring and MJX)",
        "",
        "| task | physics | episode | batch | env steps/s | rollout | compile | status |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for rollout in report.rollouts:
        lines.append(
            f"| {rollout.task} | {rollout.physics} | {rollout.episode_length} | {rollout.batch_size} | "
            f"{_rate(rollout.steps_per_second)} | "
            f"{_seconds(rollout.seconds)} | {_seconds(rollout.compile_seconds)} | {rollout.status} |"
        )
    if report.errors:
        lines += ["", f"**{report.errors} part(s) failed**: their errors are above and on stderr."]
    return "\n".join(lines)


def as_json(report: Report) -> dict[str, Any]:
    """The report as JSON: every measured figure, with the settings of each runner part."""

    def part_json(part: RunnerPart) -> dict[str, Any]:
        values = {k: v for k, v in asdict(part).items() if k not in ("config", "measurement")}
        values["config"] = json.loads(part.config.to_json())
        if part.measurement is not None:
            values["measurement"] = asdict(part.measurement)
            values["evaluations_per_second"] = part.measurement.evaluations_per_second
            values["steps_per_second"] = part.measurement.steps_per_second
        return values

    return {
        "small": report.small,
        "budget_seconds": report.budget_seconds,
        "started": report.started,
        "elapsed_seconds": report.elapsed_seconds,
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "host": platform.node(),
        "devices": report.devices,
        "environment": report.environment,
        "runner": [part_json(part) for part in report.runner],
        "reproduce": [asdict(row) for row in report.reproduce],
        "rollouts": [asdict(row) for row in report.rollouts],
        "errors": report.errors,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="benchmarks/accelerator.py",
        description="Check smol-dsl on the devices JAX sees, measure its speed there, and estimate the paper's "
        "experiment on this machine (a Markdown table on stdout; --out writes the figures as JSON).",
    )
    parser.add_argument("--small", action="store_true", help="tiny settings, for CPUs and tests")
    parser.add_argument("--out", type=Path, help="write every figure to this JSON file")
    parser.add_argument(
        "--budget",
        type=float,
        default=300.0,
        help="seconds the whole command may take; the rollouts' larger batches are skipped past it (300)",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=Path.home() / ".cache" / "smol-dsl" / "xla",
        help="XLA's persistent compilation cache (~/.cache/smol-dsl/xla); a second try compiles little",
    )
    parser.add_argument("--no-cache", action="store_true", help="compile everything afresh")
    args = parser.parse_args(argv)
    if args.budget <= 0:
        parser.error(f"--budget {args.budget}: give the seconds the command may take, e.g. --budget 300")
    if args.out is not None and not args.out.parent.is_dir():
        parser.error(f"--out {args.out}: its folder {args.out.parent} does not exist")
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):  # as the CLI does on CPUs
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={os.cpu_count() or 1}".strip()
    import jax

    if not args.no_cache:
        args.cache.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(args.cache))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    report = measure(args.small, args.budget)
    print(markdown(report))
    if args.out is not None:
        args.out.write_text(json.dumps(as_json(report), indent=2, default=str) + "\n")
        print(f"\nfigures: {args.out}", file=sys.stderr)
    return 1 if report.errors else 0


if __name__ == "__main__":
    sys.exit(main())
