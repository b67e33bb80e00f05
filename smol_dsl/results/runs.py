"""Finished runs to report on: found below the given paths, read and checked, grouped.

`load_runs(paths)` finds run directories (written by `smol-dsl run` or `sweep`), reads and
checks every one of them (`smol_dsl.rundir.read_run`: its config.json, certificate and
schedule, every row of metrics.csv, and its final archive.npz), checks that they can be
compared (one task, the same settings and environment, finished, the same final body, no
run counted twice), and groups them by schedule in the paper's order
(`smol_dsl.results.conditions`). `final_scores`, `median_run` and `runs_described` read
the groups.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.errors import UserInputError, counted
from smol_dsl.results.conditions import ORDER
from smol_dsl.rundir import (
    CONFIG_FILE,
    METRICS_FILE,
    SCORES,
    RunDirectoryError,
    RunRecord,
    environment_differences,
    is_run_directory,
    read_run,
)
from smol_dsl.tasks import task_spec
from smol_dsl.tasks.anatomy import resolved_names, same_body
from smol_dsl.tasks.physics import PHYSICS_NAMES

if TYPE_CHECKING:
    from smol_dsl.tasks.anatomy import Anatomy

METRICS = SCORES
"""The final scores a report can compare (`--metric`); each task has its default."""
SEED_MODULUS = 2**32
"""JAX takes a seed modulo 2**32: seeds S and S + 2**32 give the same run."""
MOST_PROBLEMS = 5
"""How many unusable run directories one error lists."""


class ReportError(UserInputError):
    """Run directories that cannot be reported on together, or an output directory that
    cannot take the report, with what to do instead."""


def find_run_directories(paths: Iterable[str | Path]) -> list[Path]:
    """Run directories given, or found anywhere below the given directories, each once."""
    found: dict[Path, None] = {}
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise ReportError(f"{path}: no such directory")
        if not path.is_dir():
            raise ReportError(f"{path} is not a directory; give run or sweep directories")
        if is_run_directory(path):
            candidates = [path]
        else:
            # rglob does not descend into links: nothing reached through a link inside `path` is found
            below = {p.parent for name in (CONFIG_FILE, METRICS_FILE) for p in path.rglob(name)}
            candidates = sorted(below)
        for candidate in candidates:
            if is_run_directory(candidate):
                found.setdefault(candidate.resolve(), None)
    return list(found)


def load_runs(paths: Sequence[str | Path], allow_mixed_environments: bool = False) -> dict[str, list[RunRecord]]:
    """Finished runs below `paths`, grouped by schedule name in the paper's order; where the
    runs were simulated on several physics (`allow_mixed_environments` let them through),
    by schedule and physics (`SMOL on mjx`, `condition_name`), so that no group pools two
    simulators and a seed may be in each.

    Every run directory is read and checked first (`read_run`); then refuses (ReportError)
    no runs, unfinished runs, runs of several tasks or settings, runs produced under
    different environments (environment.json: other package versions, devices or
    processor; unless `allow_mixed_environments`), two schedules with one name, schedules
    that end on different bodies (a declared `final` factor), and a (schedule, seed) given
    twice, seeds that JAX takes as equal (S and S + 2**32) included.
    """
    directories = find_run_directories(paths)
    if not directories:
        raise ReportError(
            f"no run directories in {', '.join(str(p) for p in paths)} (a run directory holds config.json "
            "and metrics.csv); make some with `smol-dsl sweep` or `smol-dsl run`"
        )
    runs = _read_runs(directories)
    _check_one_task(runs)
    _check_finished(runs)
    _check_same_settings(runs)
    if not allow_mixed_environments:
        _check_same_environment(runs)
    groups = _group_by_condition(runs)
    _check_final_bodies(groups)
    ordered = sorted(groups, key=lambda name: _paper_order(groups[name][0]))
    return {name: sorted(groups[name], key=lambda r: r.seed) for name in ordered}


def simulated_physics(runs: Iterable[RunRecord]) -> list[str]:
    """The physics the runs were simulated on, in the order of `PHYSICS_NAMES`."""
    used = {run.config.physics for run in runs}
    return [name for name in PHYSICS_NAMES if name in used]


def condition_name(run: RunRecord, several_physics: bool) -> str:
    """What a report calls the condition of a run: its schedule's name, and where the runs
    reported on were simulated on several physics, the run's physics too (`SMOL on mjx`)."""
    return f"{run.schedule} on {run.config.physics}" if several_physics else run.schedule


def _paper_order(run: RunRecord) -> tuple[int, str, int]:
    """Where a run's condition goes: the paper's order of schedules, then the others by
    name; each schedule on its physics in the order of `PHYSICS_NAMES` (spring first)."""
    place = ORDER.index(run.schedule) if run.schedule in ORDER else len(ORDER)
    return place, run.schedule, PHYSICS_NAMES.index(run.config.physics)


def _read_runs(directories: Sequence[Path]) -> list[RunRecord]:
    """Every run directory read and checked (`read_run`); a ReportError lists those that
    cannot be used (up to MOST_PROBLEMS of them), or is the one's own message."""
    runs, problems = [], []
    for directory in directories:
        try:
            runs.append(read_run(directory))
        except RunDirectoryError as error:
            problems.append(str(error))
    if len(problems) == 1:
        raise ReportError(problems[0])
    if problems:
        shown = "\n  ".join(problems[:MOST_PROBLEMS])
        more = f"\n  and {len(problems) - MOST_PROBLEMS} more" if len(problems) > MOST_PROBLEMS else ""
        raise ReportError(f"{len(problems)} of the {len(directories)} run directories cannot be used:\n  {shown}{more}")
    return runs


def _check_one_task(runs: Sequence[RunRecord]) -> None:
    """Refuse runs of several tasks: their scores cannot share a table."""
    tasks = sorted({run.task for run in runs})
    if len(tasks) > 1:
        examples = "; ".join(f"{task}: {next(r.directory for r in runs if r.task == task)}" for task in tasks)
        raise ReportError(
            f"the runs are of different tasks ({', '.join(tasks)}), which cannot share a table ({examples}); "
            "report each task's directories separately"
        )


def _check_finished(runs: Sequence[RunRecord]) -> None:
    """Refuse runs that have not reached their last generation: they have no final scores."""
    unfinished = [run for run in runs if not run.finished]
    if unfinished:
        raise ReportError(
            f"{len(unfinished)} run(s) have not finished, e.g. {unfinished[0].directory} (generation "
            f"{unfinished[0].final['generation']} of {unfinished[0].config.generations}); finish them with "
            "`smol-dsl sweep ... --resume` or `smol-dsl run ... --resume`, or leave them out"
        )


def _check_same_settings(runs: Sequence[RunRecord]) -> None:
    """Refuse runs whose settings (the seed and the physics aside) differ from the first run's,
    or whose metrics.csv logs other generations and phases than the first run's, on the same
    settings."""
    reference = runs[0]
    steps = _steps(reference)
    for run in runs[1:]:
        differing = sorted(
            k for k in run.settings if k != "physics" and run.settings[k] != reference.settings.get(k)
        )  # a physics apart is an environment apart (`environment_mixing`: --allow-mixed-environments)
        if differing:
            raise ReportError(
                f"{run.directory} and {reference.directory} were run with different settings "
                f"({', '.join(differing)}); only runs with the same settings can be compared"
            )
        if _steps(run) != steps:
            raise ReportError(
                f"{run.directory / METRICS_FILE} ({len(run.rows)} rows) and {reference.directory / METRICS_FILE} "
                f"({len(reference.rows)} rows) log different generations and phases although their runs have the "
                "same settings; one of them was cut or edited: rerun it, or move it out of the directories you "
                "report on"
            )


def _check_same_environment(runs: Sequence[RunRecord]) -> None:
    """Refuse runs that mixed environments (`environment_mixing`: each compiles the physics
    its own way, so the same seed trains to other numbers), naming the first and how many."""
    mixing = environment_mixing(runs)
    if mixing:
        more = f" (and {len(mixing) - 1} more)" if len(mixing) > 1 else ""
        raise ReportError(
            f"the runs were not all produced under one environment: {mixing[0]}{more}; their numbers are not "
            "comparable in one table. Report them apart, or pass --allow-mixed-environments to put them together "
            "anyway (the report then lists every difference)"
        )


def environment_mixing(runs: Sequence[RunRecord]) -> list[str]:
    """Every way the runs' environments (environment.json) differ, one sentence each: the runs
    started under another record than the first run that has one (one sentence per set of
    differences, naming its first run and how many share it), a run resumed under another
    environment (its recorded changes), and a run with no record, or one whose start is
    unknown, beside runs that have one. Empty when the runs share one record (or none has any)."""
    recorded = [run for run in runs if run.environment]
    mixing = []
    started: dict[str, list[Path]] = {}  # each set of differences from the first record: its runs
    for run in runs:
        if not run.environment and recorded:
            what = "has no environment.json" if run.environment is None else "was started under an unknown environment"
            mixing.append(f"{run.directory} {what}, unlike {recorded[0].directory}")
        elif run.environment and run is not recorded[0]:
            differences = environment_differences(dict(recorded[0].environment), dict(run.environment))
            if differences:
                started.setdefault("; ".join(differences), []).append(run.directory)
        for change in run.environment_changes:
            mixing.append(f"{run.directory} was resumed under another environment ({'; '.join(change['differences'])})")
    for differences, directories in started.items():
        more = f" (and {counted(len(directories) - 1, 'other run')} alike)" if len(directories) > 1 else ""
        mixing.append(
            f"{directories[0]}{more} was started under another environment than {recorded[0].directory} ({differences})"
        )
    return mixing


def _group_by_condition(runs: Sequence[RunRecord]) -> dict[str, list[RunRecord]]:
    """The runs by condition (`condition_name`), in the order given; refuses (ReportError)
    two schedules with one name and a run whose condition and seed another run has already."""
    several_physics = len(simulated_physics(runs)) > 1
    groups: dict[str, list[RunRecord]] = {}
    named: dict[str, RunRecord] = {}  # the first run of each schedule name, on any physics
    for run in runs:
        _check_same_schedule(named.setdefault(run.schedule, run), run)
        group = groups.setdefault(condition_name(run, several_physics), [])
        if group:
            _check_new_seed(group, run)
        group.append(run)
    return groups


def _check_same_schedule(first: RunRecord, run: RunRecord) -> None:
    """Refuse a run whose schedule has the name of another schedule's runs."""
    if first.schedule_source != run.schedule_source:
        raise ReportError(
            f"two different schedules are both named {run.schedule!r} ({first.directory} and "
            f"{run.directory}); give them different `name`s"
        )


def _check_new_seed(group: Sequence[RunRecord], run: RunRecord) -> None:
    """Refuse a run of a seed its schedule's runs have already, or one that JAX takes as the
    same (S and S + 2**32): each run must count once."""
    twin = next((other for other in group if other.seed % SEED_MODULUS == run.seed % SEED_MODULUS), None)
    if twin is not None:
        same = (
            f"seed {run.seed} is there twice"
            if twin.seed == run.seed
            else f"seeds {twin.seed} and {run.seed} are the same run (JAX takes seeds modulo 2**32)"
        )
        raise ReportError(
            f"{run.schedule} on {run.config.physics}: {same} ({twin.directory} and {run.directory}); each run "
            "must count once: leave one of them out"
        )


def _check_final_bodies(groups: dict[str, list[RunRecord]]) -> None:
    """Refuse schedules whose final bodies differ, part by part (each actuator's gear, each
    link's mass, friction, gravity: the product of the channels that reach it, however the
    files spell them): their final scores are of different robots."""
    first_name, first = next(iter(groups.items()))
    for name, group in groups.items():
        body, reference = group[0].body, first[0].body
        if same_body(body, reference):
            continue
        kind, part, mine, theirs = _first_difference(body, reference, task_spec(first[0].task).anatomy)
        raise ReportError(
            f"{name} and {first_name} end on different bodies: {part}'s {kind} factor ends at {mine:g} in {name} "
            f"({group[0].directory}) and at {theirs:g} in {first_name} ({first[0].directory}); final scores are only "
            "comparable on the same final body: report them separately, or give the schedules the same `final`"
        )


def _first_difference(
    body: Mapping[str, tuple[float, ...]], reference: Mapping[str, tuple[float, ...]], anatomy: Anatomy | None
) -> tuple[str, str, float, float]:
    """(kind, part, factor in body, factor in reference) of the first part that differs."""
    for kind in dict.fromkeys([*body, *reference]):
        names = resolved_names(anatomy, kind)
        mine, theirs = body.get(kind, (1.0,) * len(names)), reference.get(kind, (1.0,) * len(names))
        for part, a, b in zip(names, mine, theirs, strict=True):
            if not same_body({kind: (a,)}, {kind: (b,)}):
                return kind, (part if part != kind else "the body"), a, b
    raise AssertionError("the bodies differ")


def _steps(run: RunRecord) -> list[tuple[int, int, int]]:
    """What a run's rows log, whatever its results: (generation, phase, evaluations) per row."""
    return [(row["generation"], row["phase"], row["evaluations"]) for row in run.rows]


def final_scores(groups: dict[str, list[RunRecord]], metric: str) -> dict[str, np.ndarray]:
    """Each schedule's final value of the metric, one per run (seed order)."""
    if metric not in METRICS:
        raise ReportError(f"unknown metric {metric!r}; the metrics are {', '.join(METRICS)}")
    return {name: np.asarray([run.final[metric] for run in runs], dtype=float) for name, runs in groups.items()}


def median_run(runs: Sequence[RunRecord], metric: str) -> RunRecord:
    """The run with the median final score (the lower one for an even number of runs)."""
    ranked = sorted(runs, key=lambda run: run.final[metric])
    return ranked[(len(ranked) - 1) // 2]


def runs_described(groups: Mapping[str, Sequence[RunRecord]]) -> list[tuple[str, str]]:
    """What the report's runs are, as (heading, text) lines for table.md and index.html: the
    runs and seeds, their shared settings and budget, the environment they ran under, and
    every way their environments differ (`environment_mixing`, which `--allow-mixed-environments`
    let through)."""
    runs = [run for group in groups.values() for run in group]
    config = runs[0].config
    seeds = sorted({run.seed for run in runs})
    simulated = simulated_physics(runs)
    physics = " and ".join(simulated)
    schedules = counted(len({run.schedule for run in runs}), "schedule") + (
        f" on {physics}" if len(simulated) > 1 else ""
    )
    seeds_text = ", ".join(str(seed) for seed in seeds[:10]) + (f" .. {seeds[-1]}" if len(seeds) > 10 else "")
    lines = [
        (
            "runs",
            f"{counted(len(runs), 'run')} of {config.task}: {schedules} x {counted(len(seeds), 'seed')} ({seeds_text})",
        ),
        (
            "budget",
            f"{config.evaluations:,} evaluations per run ({config.generations:,} generations of {config.batch_size:,} "
            f"after the initial population) in {counted(config.num_phases, 'phase')}, episodes of "
            f"{config.episode_length:,} steps; re-evaluations at phase boundaries counted apart",
        ),
        (
            "settings",
            f"physics {physics}; preset {config.preset}; {config.num_centroids:,} cells "
            f"({config.num_init_cvt_samples:,} CVT samples); "
            f"policy hidden layers {list(config.hidden_layer_sizes)}; iso sigma {config.iso_sigma:g}, line sigma "
            f"{config.line_sigma:g}",
        ),
    ]
    recorded = next((run.environment for run in runs if run.environment), None)
    lines.append(("environment", _environment_line(recorded) if recorded else "not recorded (no environment.json)"))
    lines += [("mixed environment", text) for text in environment_mixing(runs)]
    return lines


def _environment_line(environment: Mapping[str, object]) -> str:
    """An environment.json record in one line: Python, smol-dsl and its commit, the numerical
    packages, the devices and the processor."""
    packages = environment.get("packages") or {}
    devices = environment.get("devices") or {}
    processor = environment.get("processor") or {}
    versions = ", ".join(f"{name} {version}" for name, version in dict(packages).items() if version)
    kinds = ", ".join(dict(devices).get("kinds") or []) or "?"
    extensions = ", ".join(dict(processor).get("vector_extensions") or []) or "none recorded"
    return (
        f"Python {environment.get('python')}, smol-dsl {environment.get('smol_dsl')} (commit "
        f"{environment.get('commit') or 'unknown'}), {versions}; {dict(devices).get('count')} "
        f"{dict(devices).get('platform')} device(s) ({kinds}); processor {dict(processor).get('model')} "
        f"({extensions})"
    )
