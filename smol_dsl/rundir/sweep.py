"""sweep.json: what a sweep was started with (its task, shared settings, and every run's
directory name, schedule, seed and schedule text), written when it starts and compared on
resume, so that a sweep goes on only with the command line it was started with.

    description = sweep_description(config, [SweepRun(name, schedule, seed, source), ...])
    write_sweep_file(directory, description)
    sweep_differences(read_sweep_file(directory), description, directory)   # [] if the same
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

from smol_dsl.errors import Message, Setting
from smol_dsl.rundir.config import RunConfig, setting_differences
from smol_dsl.rundir.files import read_json_object, write_text
from smol_dsl.rundir.layout import SCHEDULE_FILE, SWEEP_FILE, schedule_of_run_name


class SweepRun(NamedTuple):
    """One run of a sweep as sweep.json records it."""

    name: str  # its run directory (`run_name`)
    schedule: str  # the schedule's name
    seed: int
    source: str  # the schedule's text


def sweep_description(config: RunConfig, runs: Sequence[SweepRun]) -> dict[str, Any]:
    """sweep.json's object: the task, the settings shared by every run (all but the seed),
    and the runs."""
    shared = json.loads(config.to_json())
    del shared["seed"]
    return {"task": config.task, "config": shared, "runs": [run._asdict() for run in runs]}


def write_sweep_file(directory: Path, description: dict[str, Any]) -> None:
    """Write sweep.json (atomically)."""
    write_text(directory / SWEEP_FILE, json.dumps(description, indent=2))


def read_sweep_file(directory: Path) -> dict[str, Any] | None:
    """The sweep.json of `directory`, or None if it has none; a damaged one is a
    RunDirectoryError."""
    path = directory / SWEEP_FILE
    return read_json_object(path, "sweep") if path.is_file() else None


def sweep_differences(saved: dict[str, Any], description: dict[str, Any], directory: Path) -> list[Message | str]:
    """What differs between a saved sweep.json and this sweep's description, one line per
    setting (the schedules, seeds and a schedule's text too); never empty for two that
    differ."""
    if saved == description:
        return []
    saved_config = saved.get("config")
    lines: list[Message | str] = []
    lines += setting_differences(saved_config if isinstance(saved_config, dict) else {}, description["config"], "sweep")
    saved_runs = (
        [r for r in saved.get("runs", []) if isinstance(r, dict)] if isinstance(saved.get("runs"), list) else []
    )
    task = str(saved.get("task", description["task"]))
    old_stems, new_stems = _stems(saved_runs, task), _stems(description["runs"], description["task"])
    if old_stems != new_stems:
        lines.append(
            Setting("schedules") + f": the sweep was started with {', '.join(old_stems)}, not {', '.join(new_stems)}"
        )
    old_seeds, new_seeds = _seeds(saved_runs), _seeds(description["runs"])
    if old_seeds != new_seeds:
        lines.append(
            Setting("seeds")
            + f": the sweep was started with seeds {_seed_list(old_seeds)}, not {_seed_list(new_seeds)}"
        )
    if not lines:
        sources = {r.get("name"): r.get("source") for r in saved_runs}
        for run in description["runs"]:
            if run["name"] in sources and sources[run["name"]] != run["source"]:
                stem = _stems([run], description["task"])[0]
                lines.append(
                    Setting("schedule")
                    + f" {stem}: its text is not the one the sweep was started with "
                    + f"(kept in {directory / run['name'] / SCHEDULE_FILE})"
                )
                break
    return lines or [f"{directory / SWEEP_FILE} does not describe this sweep"]


def _stems(runs: list[dict[str, Any]], task: str) -> list[str]:
    """The schedules of `runs`, in order, each once: the stems of their directory names."""
    stems: list[str] = []
    for run in runs:
        stem = schedule_of_run_name(str(run.get("name", "")), task)
        if stem is None:
            stem = str(run.get("schedule"))
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
