"""A sweep: every (schedule, seed) pair of one task, run together as one batched program.

`run_sweep(task, schedules, seeds, config)` advances all runs generation by generation
with `BatchedMapElites` (runs sharded across the local devices) and writes one run
directory per pair, in `run_experiment`'s format, so each can be opened, plotted and
reported like a single run. The sweep's own checkpoint holds every run at the same
boundary, written atomically, so an interrupted sweep resumes exactly.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache, partial
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl import Schedule
from smol_dsl.runner.algorithm import Evaluation, cvt_centroids
from smol_dsl.runner.batched import BatchedMapElites, stack_runs
from smol_dsl.runner.checkpoint import (
    SWEEP_CHECKPOINT,
    CheckpointWriter,
    RunState,
    load_sweep_checkpoint,
    save_sweep_checkpoint,
    sweep_checkpoint_arrays,
)
from smol_dsl.runner.config import RunConfig
from smol_dsl.runner.footprint import fit_sweep
from smol_dsl.runner.run import (
    MetricsLog,
    RunError,
    RunResult,
    check_out_dir,
    finish_run_directory,
    lock_directory,
    make_directory,
    metrics_row,
    non_empty,
    out_path,
    prepare_run_directory,
    read_json_object,
    remove_stale_temporaries,
    schedule_key,
    setting_differences,
    start_key,
    storage_errors,
    write_new_files,
)
from smol_dsl.tasks import Task, make_task

SWEEP_FILE = "sweep.json"


@dataclass(frozen=True)
class SweepRun:
    """One (schedule, seed) pair of a sweep and the name of its run directory."""

    schedule: Schedule
    config: RunConfig
    name: str


def run_name(task: str, schedule: Schedule, seed: int) -> str:
    """A run directory's name: TASK-SCHEDULE-seedS (SCHEDULE: the file's stem, or its name)."""
    stem = Path(schedule.path).stem if schedule.path else schedule.name
    return f"{task}-{stem}-seed{seed}"


def plan_sweep(schedules: Sequence[Schedule], seeds: Sequence[int], config: RunConfig) -> list[SweepRun]:
    """Every (schedule, seed) pair, schedules outermost; refuses repeated names."""
    if not schedules:
        raise RunError("a sweep needs at least one schedule")
    if not seeds:
        raise RunError("a sweep needs at least one seed")
    runs = [
        SweepRun(schedule, dataclasses.replace(config, seed=seed), run_name(config.task, schedule, seed))
        for schedule in schedules
        for seed in seeds
    ]
    names = [run.name for run in runs]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise RunError(
            f"two runs of the sweep would share the directory {repeated[0]}: give each schedule "
            "and seed once, and schedules from different folders different file names"
        )
    return runs


@lru_cache(maxsize=8)
def batched_map_elites(
    task: Task,
    batch_size: int,
    iso_sigma: float,
    line_sigma: float,
    devices: tuple[jax.Device, ...],
    runs_per_step: int | None,
    num_runs: int,
) -> BatchedMapElites:
    """A shared BatchedMapElites per setting, so sweeps in one process reuse compilations."""
    return BatchedMapElites(
        task,
        batch_size=batch_size,
        iso_sigma=iso_sigma,
        line_sigma=line_sigma,
        devices=list(devices),
        runs_per_step=runs_per_step,
        num_runs=num_runs,
    )


def run_sweep(
    task: Task | str,
    schedules: Sequence[Schedule],
    seeds: Sequence[int],
    config: RunConfig,
    *,
    out_dir: str | Path | None = None,
    resume: bool = False,
    progress: Callable[[list[dict[str, Any]], int], None] | None = None,
    stop_after_generation: int | None = None,
    devices: Sequence[jax.Device] | None = None,
    runs_per_step: int | None = -1,
    part: tuple[int, int] = (0, 1),
) -> list[RunResult]:
    """Run every (schedule, seed) pair of `task` together; return one RunResult per pair.

    `config` is shared (its own seed is ignored). With `out_dir`, writes `sweep.json`, the
    sweep checkpoint and one run directory per pair; with `resume`, continues from the
    last checkpoint. `devices` (default: all local devices) share the runs;
    `runs_per_step` is how many runs a device advances at once (-1: one on CPU; on
    accelerators all, or as many as fit in memory; None: all). A sweep whose archives
    cannot fit the devices' memory is refused with a RunError before anything compiles.
    `progress(rows, total)` gets the latest row of every run.
    `part=(k, n)` runs only every n-th pair from the k-th (one process of n sharing a
    sweep, each on its own devices; see docs/scaling.md) and returns those.
    """
    started = time.perf_counter()
    directory = out_path(out_dir)
    every = plan_sweep(schedules, seeds, config)
    index, parts = part
    if not 0 <= index < parts:
        raise RunError(f"part {index} of {parts} does not exist")
    runs = every[index::parts]
    if not runs:
        raise RunError(f"the sweep has {len(every)} runs, too few for {parts} parts (processes)")
    devices = tuple(devices) if devices is not None else tuple(jax.local_devices())
    footprint = fit_sweep(config, len(schedules), seeds, devices, runs_per_step, part)  # before compiling
    if runs_per_step == -1:
        runs_per_step = footprint.runs_per_step
    if isinstance(task, str):
        task = make_task(
            task,
            episode_length=config.episode_length,
            hidden_layer_sizes=config.hidden_layer_sizes,
            init_key=start_key(runs[0].config.seed),
        )
    checkpoint_name = SWEEP_CHECKPOINT if parts == 1 else f"sweep-checkpoint-{index}-of-{parts}.npz"
    with contextlib.ExitStack() as held:
        if directory is not None:  # this process's run directories stay locked until it returns
            held.enter_context(
                _prepare_sweep_directory(directory, every, runs, config, resume, parts > 1, checkpoint_name)
            )
        engine = batched_map_elites(
            task, config.batch_size, config.iso_sigma, config.line_sigma, devices, runs_per_step, len(runs)
        )
        padded = runs + [runs[-1]] * (engine.padded_runs(len(runs)) - len(runs))  # copies; results dropped
        main_keys, init_keys, all_centroids = [], [], {}
        for run in padded:
            seed = run.config.seed
            key, cvt_key, init_key = jax.random.split(jax.random.key(seed), 3)
            main_keys.append(key)
            init_keys.append(init_key)
            if seed not in all_centroids:
                all_centroids[seed] = cvt_centroids(
                    config.num_centroids,
                    task.descriptor_low,
                    task.descriptor_high,
                    config.num_init_cvt_samples,
                    cvt_key,
                )
        starts = {seed: task.start_state(start_key(seed)) for seed in all_centroids}
        starts = engine.put(stack_runs([starts[run.config.seed] for run in padded]))
        alphas = np.stack(
            [run.schedule.checked_phase_alphas(config.num_phases, schedule_key(run.config.seed)) for run in padded]
        )
        extinctions = engine.put(jnp.asarray([r.schedule.extinction for r in padded], dtype=jnp.float32))
        checkpoint = directory / checkpoint_name if directory is not None else None
        owner = _sweep_owner(runs, config)

        def alphas_of(phase: int) -> jax.Array:
            return engine.put(jnp.asarray(alphas[:, phase], dtype=jnp.float32))

        saved = None
        if checkpoint is not None and resume:
            template = task.init_policies(jax.random.key(0), 1)
            descriptors = next(iter(all_centroids.values())).shape[-1]
            saved = load_sweep_checkpoint(checkpoint, template, len(runs), config.num_centroids, descriptors, owner)
        if checkpoint is not None:  # from here on, a file that cannot be written says the checkpoint is intact
            held.enter_context(storage_errors(checkpoint))
        if saved is not None:
            repertoires, keys, states = saved
            extra = len(padded) - len(runs)
            repertoires, keys = jax.tree.map(lambda x: jnp.concatenate([x] + [x[-1:]] * extra), (repertoires, keys))
            repertoires, keys = engine.put(repertoires), engine.put(keys)
        else:
            centroids = jnp.stack([all_centroids[run.config.seed] for run in padded])
            repertoires = engine.empty_archives(centroids)
            repertoires, metrics, dropped, _ = engine.step(
                repertoires, alphas_of(0), starts, engine.put(jnp.stack(init_keys))
            )
            keys = engine.put(jnp.stack(main_keys))
            states = []
            for r in range(len(runs)):
                state = RunState(None, None, None, 0, 0, config.batch_size, 0, int(dropped[r]), [])
                evaluation = Evaluation(config.batch_size, int(dropped[r]))
                state.rows.append(metrics_row(state, _run_metrics(metrics, r), alphas[r, 0], "init", evaluation))
                states.append(state)
            if checkpoint is not None:
                save_sweep_checkpoint(checkpoint, repertoires, keys, states, owner)

        logs = [
            MetricsLog(directory / run.name / "metrics.csv" if directory is not None else None, state.rows)
            for run, state in zip(runs, states, strict=True)
        ]
        total = config.generations
        if progress is not None:
            progress([state.rows[-1] for state in states], total)

        def record(
            metrics: dict[str, np.ndarray], events: list[str], evaluated: np.ndarray, dropped: np.ndarray
        ) -> None:
            for r, (state, log) in enumerate(zip(states, logs, strict=True)):
                evaluation = Evaluation(int(evaluated[r]), int(dropped[r]))
                row = metrics_row(state, _run_metrics(metrics, r), alphas[r, state.phase], events[r], evaluation)
                state.rows.append(row)
                log.append(row)
            if progress is not None:
                progress([state.rows[-1] for state in states], total)

        with CheckpointWriter() as writer:  # checkpoints reach the disk while training goes on
            for generation in range(states[0].generation + 1, total + 1):
                if stop_after_generation is not None and generation > stop_after_generation:
                    break
                phase = config.phase_of_generation(generation)
                if phase != states[0].phase:
                    keys, subkeys = engine.split(keys)
                    repertoires, evaluated, dropped = engine.reevaluate(
                        repertoires, alphas_of(phase), starts, extinctions, subkeys
                    )
                    for r, state in enumerate(states):
                        state.phase = phase
                        state.reevaluations += int(evaluated[r])
                        state.non_finite += int(dropped[r])
                    record(engine.metrics(repertoires), ["reevaluate"] * len(runs), evaluated, dropped)
                    if checkpoint is not None:
                        writer.offer(checkpoint, partial(sweep_checkpoint_arrays, repertoires, keys, states, owner))
                keys, subkeys = engine.split(keys)
                repertoires, metrics, dropped, reseeded = engine.step(repertoires, alphas_of(phase), starts, subkeys)
                for r, state in enumerate(states):
                    state.generation = generation
                    state.evaluations += config.batch_size
                    state.non_finite += int(dropped[r])
                events = ["reseed" if reseeded[r] else "train" for r in range(len(runs))]
                record(metrics, events, np.full(len(runs), config.batch_size), dropped)

        finished = states[0].generation >= total
        results = []
        host_keys = jax.device_get(jax.random.key_data(keys))
        for r, (run, state) in enumerate(zip(runs, states, strict=True)):
            state.repertoire = jax.tree.map(lambda x, r=r: x[r], repertoires)
            state.key = jax.random.wrap_key_data(host_keys[r])
            if directory is not None and finished:
                finish_run_directory(directory / run.name, state, task, run.config, run.schedule)
            results.append(
                RunResult(
                    state.repertoire,
                    state.rows,
                    run.config,
                    alphas[r],
                    directory / run.name if directory is not None else None,
                    time.perf_counter() - started,
                )
            )
        if checkpoint is not None and finished and not all(s.finished for s in states):
            for state in states:
                state.finished = True
            save_sweep_checkpoint(checkpoint, repertoires, keys, states, owner)
        return results


def _run_metrics(metrics: dict[str, np.ndarray], run: int) -> dict[str, float]:
    return {name: float(values[run]) for name, values in metrics.items()}


def _sweep_owner(runs: list[SweepRun], config: RunConfig) -> dict[str, Any]:
    """What a sweep checkpoint records about the runs it holds (see checkpoint.run_owner)."""
    shared = json.loads(config.to_json())
    del shared["seed"]
    return {
        "config": shared,
        "runs": {run.name: run.schedule.source for run in runs},
    }


def _sweep_description(runs: list[SweepRun], config: RunConfig) -> dict[str, Any]:
    shared = json.loads(config.to_json())
    del shared["seed"]
    return {
        "task": config.task,
        "config": shared,
        "runs": [
            {"name": run.name, "schedule": run.schedule.name, "seed": run.config.seed, "source": run.schedule.source}
            for run in runs
        ],
    }


def _prepare_sweep_directory(
    directory: Path,
    every: list[SweepRun],
    runs: list[SweepRun],
    config: RunConfig,
    resume: bool,
    shared: bool,
    checkpoint_name: str,
) -> contextlib.ExitStack:
    """Write or check sweep.json (all runs) and prepare this process's run directories.
    A directory `shared` by several processes may already hold the others' runs.

    Returns the locks this process holds, as one context manager: every run directory it
    writes, and the sweep directory itself unless it is shared, so that no second process
    can write them at the same time.
    """
    check_out_dir(directory)
    description = _sweep_description(every, config)
    sweep_file = directory / SWEEP_FILE
    locks = contextlib.ExitStack()
    try:
        if resume and not sweep_file.is_file():
            if (directory / "config.json").is_file():
                raise RunError(
                    f"{directory} is a run directory, not a sweep's: resume it with `smol-dsl run ... --resume`"
                )
            raise RunError(f"{directory} holds no sweep to resume (no {SWEEP_FILE}); start it without --resume")
        if not resume:
            busy = [d for d in ([directory] if not shared else [directory / r.name for r in runs]) if non_empty(d)]
            if busy:
                raise RunError(
                    f"{busy[0]} already exists and is not empty; use --resume to continue it or another --out"
                )
            make_directory(directory, "sweep")
        if not shared:
            locks.enter_context(lock_directory(directory, "sweep", resume))
            if not resume and non_empty(directory):  # another process started one since we looked
                raise RunError(
                    f"{directory} already exists and is not empty; use --resume to continue it or another --out"
                )
        saved = read_json_object(sweep_file, "sweep") if sweep_file.is_file() else None
        if saved is not None and saved != description and (resume or shared):
            raise RunError(
                f"{directory} was started with different settings, schedules or seeds; resume it with the same "
                "command line: " + "; ".join(_sweep_differences(saved, description, directory))
            )
        if not resume:
            write_new_files(directory, {SWEEP_FILE: json.dumps(description, indent=2)})
        for run in runs:
            run_directory = directory / run.name
            # a run directory deleted since the sweep started is set up again; its checkpoint is the sweep's
            again = resume and not (run_directory / "config.json").exists() and not non_empty(run_directory)
            locks.enter_context(prepare_run_directory(run_directory, run.schedule, run.config, resume and not again))
        if resume:
            _check_process_count(directory, checkpoint_name)
            remove_stale_temporaries(directory, prefix=f"{checkpoint_name}.")
    except BaseException:
        locks.close()
        raise
    return locks


_CHECKPOINT_NAME = re.compile(r"sweep-checkpoint(?:-(\d+)-of-(\d+))?\.npz")


def _check_process_count(directory: Path, checkpoint_name: str) -> None:
    """Refuse to resume a sweep with another number of processes than it was checkpointed
    by: this process's checkpoint would be missing, and its runs would silently start over."""
    if (directory / checkpoint_name).exists():
        return
    ours = _CHECKPOINT_NAME.fullmatch(checkpoint_name)
    parts = int(ours.group(2)) if ours and ours.group(2) else 1
    others = sorted(
        name
        for name in (path.name for path in directory.iterdir())
        if (match := _CHECKPOINT_NAME.fullmatch(name)) and int(match.group(2) or 1) != parts
    )
    if others:
        counts = sorted({int(m.group(2) or 1) for m in map(_CHECKPOINT_NAME.fullmatch, others) if m})
        started = " or ".join(_processes(count) for count in counts)
        raise RunError(
            f"{directory} was checkpointed by {started} ({', '.join(others[:3])}{', ...' if len(others) > 3 else ''}), "
            f"not {_processes(parts)}: resume it with the same --num-processes (or none, for one process); "
            f"otherwise this process's runs would start over"
        )


def _processes(count: int) -> str:
    return "one process" if count == 1 else f"{count} processes (--num-processes {count})"


def _sweep_differences(saved: dict[str, Any], description: dict[str, Any], directory: Path) -> list[str]:
    """What differs between a saved sweep.json and this sweep, one line per setting."""
    saved_config = saved.get("config")
    lines = setting_differences(saved_config if isinstance(saved_config, dict) else {}, description["config"], "sweep")
    saved_runs = (
        [r for r in saved.get("runs", []) if isinstance(r, dict)] if isinstance(saved.get("runs"), list) else []
    )
    task = str(saved.get("task", description["task"]))
    old_stems, new_stems = _stems(saved_runs, task), _stems(description["runs"], description["task"])
    if old_stems != new_stems:
        lines.append(f"SCHEDULE: the sweep was started with {', '.join(old_stems)}, not {', '.join(new_stems)}")
    old_seeds, new_seeds = _seeds(saved_runs), _seeds(description["runs"])
    if old_seeds != new_seeds:
        lines.append(
            f"--first-seed/--seeds: the sweep was started with seeds {_seed_list(old_seeds)}, "
            f"not {_seed_list(new_seeds)}"
        )
    if not lines:
        sources = {r.get("name"): r.get("source") for r in saved_runs}
        for run in description["runs"]:
            if run["name"] in sources and sources[run["name"]] != run["source"]:
                stem = _stems([run], description["task"])[0]
                lines.append(
                    f"SCHEDULE {stem}: its text is not the one the sweep was started with "
                    f"(kept in {directory / run['name'] / 'schedule.sched'})"
                )
                break
    return lines or [f"{directory / SWEEP_FILE} does not describe this sweep"]


def _stems(runs: list[dict[str, Any]], task: str) -> list[str]:
    stems: list[str] = []
    for run in runs:
        match = re.fullmatch(rf"{re.escape(task)}-(.*)-seed-?\d+", str(run.get("name", "")))
        stem = match.group(1) if match else str(run.get("schedule"))
        if stem not in stems:
            stems.append(stem)
    return stems


def _seeds(runs: list[dict[str, Any]]) -> list[Any]:
    return sorted({run.get("seed") for run in runs}, key=str)


def _seed_list(seeds: list[Any]) -> str:
    if seeds and all(isinstance(s, int) for s in seeds):
        seeds = sorted(seeds)
        if len(seeds) > 2 and seeds == list(range(seeds[0], seeds[-1] + 1)):
            return f"{seeds[0]}..{seeds[-1]}"
    shown = ", ".join(str(s) for s in seeds[:10])
    return shown + (", ..." if len(seeds) > 10 else "")
