"""The paper's analysis of finished runs: the U-test table, and the report's files.

`load_runs(paths)` finds run directories (written by `smol-dsl run` or `sweep`), reads and
checks every one of them (`smol_dsl.rundir.read_run`: its config.json, certificate
and schedule, every row of metrics.csv, and its final archive.npz), checks that they can be
compared (one task, the same settings, finished, no run counted twice), and groups them by
schedule. `pvalue_table` gives, for every pair of schedules, the one-sided Mann-Whitney U
test (scipy) of "the column's final scores are higher than the row's", in the layout of the
paper's `tables/pvalues.tex`; `write_report` writes it as Markdown and LaTeX with the
figures (`smol_dsl.results.figures`): everything is read and drawn before the first file is
written, every file is written atomically, and an earlier report is replaced only with
`force=True` (`--force`).
"""

from __future__ import annotations

import csv
import dataclasses
import html
import io
import math
import os
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.errors import UserInputError, counted
from smol_dsl.results.figures import archives_figure, reevaluation_figure, results_figure
from smol_dsl.results.paper import compare_with_paper
from smol_dsl.rundir import (
    CONFIG_FILE,
    METRICS_FILE,
    METRICS_SCHEMA,
    SCORES,
    RunDirectoryError,
    RunRecord,
    environment_differences,
    is_run_directory,
    read_run,
)
from smol_dsl.tasks import descriptor_bounds, task_spec
from smol_dsl.tasks.anatomy import resolved_names, same_body

if TYPE_CHECKING:
    from smol_dsl.results.gaits import ReplayElites
    from smol_dsl.results.paper import Comparison
    from smol_dsl.tasks.anatomy import Anatomy

METRICS = SCORES
"""The final scores a report can compare (`--metric`); each task has its default."""

COLUMNS = ("SMOL", "SMOL-Reverse", "SMOL-Human")
"""The paper's table compares every schedule (rows) with these curricula (columns)."""
ABLATIONS = ("Random", "Extinction 5%", "Extinction 10%", "Extinction 50%")
ORDER = ("SMOL", "SMOL-Reverse", "SMOL-Human", "Vanilla MAP-Elites", *ABLATIONS)
SIGNIFICANCE = 0.05

SEED_MODULUS = 2**32
"""JAX takes a seed modulo 2**32: seeds S and S + 2**32 give the same run."""
FIGURE_STEMS = ("main-results", "ablation-results", "reevaluation", "archives")
REPORT_FILES = (
    "table.md",
    "pvalues.tex",
    "scores.csv",
    "index.html",
    "paper-comparison.md",
    "paper-comparison.tex",
    *(f"{stem}{suffix}" for stem in FIGURE_STEMS for suffix in (".png", ".pdf")),
)
"""Every file a report may write but its gaits (`gaits-*.gif`): an output directory holding
any of them holds a report."""
GAIT_FILES = "gaits-*.gif"
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
            below = {p.parent for name in (CONFIG_FILE, METRICS_FILE) for p in path.rglob(name)}
            candidates = sorted(below)
        for candidate in candidates:
            if is_run_directory(candidate):
                found.setdefault(candidate.resolve(), None)
    return list(found)


def load_runs(paths: Sequence[str | Path], allow_mixed_environments: bool = False) -> dict[str, list[RunRecord]]:
    """Finished runs below `paths`, grouped by schedule name in the paper's order.

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
    groups = _group_by_schedule(runs)
    _check_final_bodies(groups)
    ordered = sorted(groups, key=lambda name: (ORDER.index(name) if name in ORDER else len(ORDER), name))
    return {name: sorted(groups[name], key=lambda r: r.seed) for name in ordered}


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
    """Refuse runs whose settings (the seed aside) differ from the first run's, or whose
    metrics.csv logs other generations and phases than the first run's, on the same settings."""
    reference = runs[0]
    steps = _steps(reference)
    for run in runs[1:]:
        if run.settings != reference.settings:
            differing = sorted(k for k in run.settings if run.settings[k] != reference.settings.get(k))
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
    """Every way the runs' environments (environment.json) differ, one sentence each: a run
    started under another record than the first run that has one, a run resumed under another
    environment (its recorded changes), and a run with no record, or one whose start is unknown,
    beside runs that have one. Empty when the runs share one record (or none has any)."""
    recorded = [run for run in runs if run.environment]
    mixing = []
    for run in runs:
        if not run.environment and recorded:
            what = "has no environment.json" if run.environment is None else "was started under an unknown environment"
            mixing.append(f"{run.directory} {what}, unlike {recorded[0].directory}")
        elif run.environment and run is not recorded[0]:
            differences = environment_differences(dict(recorded[0].environment), dict(run.environment))
            if differences:
                mixing.append(
                    f"{run.directory} was started under another environment than {recorded[0].directory} "
                    f"({'; '.join(differences)})"
                )
        for change in run.environment_changes:
            mixing.append(f"{run.directory} was resumed under another environment ({'; '.join(change['differences'])})")
    return mixing


def _group_by_schedule(runs: Sequence[RunRecord]) -> dict[str, list[RunRecord]]:
    """The runs by schedule name, in the order given; refuses (ReportError) two schedules
    with one name and a run whose schedule and seed another run has already."""
    groups: dict[str, list[RunRecord]] = {}
    for run in runs:
        group = groups.setdefault(run.schedule, [])
        if group:
            _check_same_schedule(group[0], run)
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
            f"{run.schedule} {same} ({twin.directory} and {run.directory}); each run must count once: "
            "leave one of them out"
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


@dataclass(frozen=True)
class PValueTable:
    """Median final scores and p-values; `pvalues[row][column]` is P(column better than row)."""

    task: str
    metric: str
    rows: list[str]
    columns: list[str]
    medians: dict[str, float]
    runs: dict[str, int]
    pvalues: dict[str, dict[str, float | None]]

    def notes(self) -> list[str]:
        """Warnings about the table's power: with few runs no p-value can fall below 0.05.
        One note per pair of run counts, naming the pairs it concerns (or saying all do)."""
        by_counts: dict[tuple[int, int], list[str]] = {}
        pairs = 0
        for row in self.rows:
            for column in self.columns:
                if row == column:
                    continue
                pairs += 1
                if smallest_p(self.runs[column], self.runs[row]) >= SIGNIFICANCE:
                    counts = tuple(sorted((self.runs[column], self.runs[row])))
                    by_counts.setdefault(counts, []).append(f"{column} vs {row}")
        notes = []
        for (fewer, more), names in by_counts.items():
            runs = f"{counted(fewer, 'run')} each" if fewer == more else f"{fewer} and {counted(more, 'run')}"
            which = (
                "every pair"
                if len(names) == pairs
                else ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
            )
            notes.append(
                f"{which}: with {runs} the smallest possible p-value is {smallest_p(fewer, more):.3g}, so "
                f"{'it cannot' if len(names) == 1 else 'none can'} reach p < {SIGNIFICANCE}; run more seeds (the paper "
                "used 7 to 10)"
            )
        return notes

    @property
    def best(self) -> set[str]:
        """The schedules with the highest median (several when they tie)."""
        top = max(self.medians[name] for name in self.rows)
        return {name for name in self.rows if self.medians[name] == top}

    def _scores(self, row: str, bold: Callable[[str], str]) -> list[str]:
        """A row's median and its p-values as text, the best median and p < SIGNIFICANCE
        marked by `bold` (each format's own markup)."""
        median = _number(self.medians[row])
        cells = [bold(median) if row in self.best else median]
        for column in self.columns:
            p = self.pvalues[row][column]
            cells.append("-" if p is None else (bold(f"{p:.3e}") if p < SIGNIFICANCE else f"{p:.3e}"))
        return cells

    def markdown(self) -> str:
        header = ["schedule", "runs", "median score", *(f"p: {_markdown_escape(c)} better" for c in self.columns)]
        lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
        for row in self.rows:
            cells = [_markdown_escape(row), str(self.runs[row]), *self._scores(row, lambda text: f"**{text}**")]
            lines.append("| " + " | ".join(cells) + " |")
        return "\n".join(lines) + "\n"

    def html(self) -> str:
        """The table as an HTML table (the best median and p < SIGNIFICANCE in bold)."""
        esc = html.escape
        head = "".join(f"<th>p: {esc(c)} better</th>" for c in self.columns)
        rows = []
        for row in self.rows:
            cells = [esc(row), str(self.runs[row]), *self._scores(row, lambda text: f"<b>{text}</b>")]
            rows.append("<tr>" + "".join(f"<td>{cell}</td>" for cell in cells) + "</tr>")
        return (
            '<table id="pvalues" border="1" cellpadding="4" style="border-collapse: collapse">'
            f"<tr><th>schedule</th><th>runs</th><th>median score</th>{head}</tr>" + "".join(rows) + "</table>"
        )

    def latex(self) -> str:
        columns = len(self.columns)
        lines = [
            "\\begin{tabular}{l|c|" + "c|" * columns + "}",
            "\\toprule",
            f" & Median & \\multicolumn{{{columns}}}{{c|}}{{p-values}} \\\\",
            " & score & " + " & ".join(_latex_escape(c) for c in self.columns) + " \\\\",
            "\\midrule",
        ]
        for row in self.rows:
            cells = [_latex_escape(row), *self._scores(row, lambda text: f"\\textbf{{{text}}}")]
            lines.append(" & ".join(cells) + " \\\\")
        lines += ["\\bottomrule", "\\end{tabular}"]
        return "\n".join(lines) + "\n"


def smallest_p(runs_a: int, runs_b: int) -> float:
    """The smallest p-value an exact one-sided U test can give with these sample sizes."""
    return 1 / math.comb(runs_a + runs_b, runs_a)


def _number(value: float) -> str:
    return f"{value:.1f}"


def _markdown_escape(text: str) -> str:
    """A name as one table cell: a | would start another cell, a line break another row."""
    return "".join(char if char.isprintable() else " " for char in text).replace("|", "\\|")


LATEX_SPECIAL = {
    **{char: "\\" + char for char in "&%$#_{}"},
    "\\": "\\textbackslash{}",
    "^": "\\textasciicircum{}",
    "~": "\\textasciitilde{}",
}


def _latex_escape(text: str) -> str:
    """A name as LaTeX text: its special characters escaped, control characters as spaces."""
    return "".join(LATEX_SPECIAL.get(char, char if char.isprintable() else " ") for char in text)


def pvalue_table(groups: dict[str, list[RunRecord]], metric: str | None = None) -> PValueTable:
    """The paper's table: rows every schedule, columns the SMOL curricula present (all
    schedules when none is), each cell the one-sided Mann-Whitney U p-value of "column
    better than row" on final scores."""
    from scipy.stats import mannwhitneyu

    task = next(iter(groups.values()))[0].task
    metric = metric or task_spec(task).default_metric
    scores = final_scores(groups, metric)
    names = list(groups)
    columns = [name for name in COLUMNS if name in groups] or names
    rows = columns + [name for name in names if name not in columns]
    pvalues: dict[str, dict[str, float | None]] = {}
    for row in rows:
        pvalues[row] = {}
        for column in columns:
            if row == column:
                pvalues[row][column] = None
            else:
                result = mannwhitneyu(scores[column], scores[row], alternative="greater")
                pvalues[row][column] = float(result.pvalue)
    return PValueTable(
        task=task,
        metric=metric,
        rows=rows,
        columns=columns,
        medians={name: float(np.median(scores[name])) for name in names},
        runs={name: len(groups[name]) for name in names},
        pvalues=pvalues,
    )


# ---------------------------------------------------------------------------- figures
def figure_groups(names: Sequence[str]) -> dict[str, list[str]]:
    """The paper's two figures: main results (the curricula and vanilla, and any other
    schedule) and ablations (SMOL against random and extinction), where present."""
    ablations = [name for name in names if name in ABLATIONS]
    main = [name for name in names if name not in ABLATIONS]
    figures = {}
    if main:
        figures["main-results"] = main
    if ablations:
        figures["ablation-results"] = (["SMOL"] if "SMOL" in names else []) + ablations
    return figures


def median_run(runs: Sequence[RunRecord], metric: str) -> RunRecord:
    """The run with the median final score (the lower one for an even number of runs)."""
    ranked = sorted(runs, key=lambda run: run.final[metric])
    return ranked[(len(ranked) - 1) // 2]


# ---------------------------------------------------------------------------- what ran
def runs_described(groups: Mapping[str, Sequence[RunRecord]]) -> list[tuple[str, str]]:
    """What the report's runs are, as (heading, text) lines for table.md and index.html: the
    runs and seeds, their shared settings and budget, the environment they ran under, and
    every way their environments differ (`environment_mixing`, which `--allow-mixed-environments`
    let through)."""
    runs = [run for group in groups.values() for run in group]
    config = runs[0].config
    seeds = sorted({run.seed for run in runs})
    seeds_text = ", ".join(str(seed) for seed in seeds[:10]) + (f" .. {seeds[-1]}" if len(seeds) > 10 else "")
    lines = [
        (
            "runs",
            f"{counted(len(runs), 'run')} of {config.task}: {counted(len(groups), 'schedule')} x "
            f"{counted(len(seeds), 'seed')} ({seeds_text})",
        ),
        (
            "budget",
            f"{config.evaluations:,} evaluations per run ({config.generations:,} generations of {config.batch_size:,} "
            f"after the initial population) in {counted(config.num_phases, 'phase')}, episodes of "
            f"{config.episode_length:,} steps; re-evaluations at phase boundaries counted apart",
        ),
        (
            "settings",
            f"preset {config.preset}; {config.num_centroids:,} cells ({config.num_init_cvt_samples:,} CVT samples); "
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


# ---------------------------------------------------------------------------- report
@dataclass(frozen=True)
class Report:
    """What `write_report` wrote."""

    table: PValueTable
    files: list[Path]
    comparison: Comparison | None = None  # beside the paper's table, for its tasks and metrics
    environment_mixing: list[str] = dataclasses.field(default_factory=list)  # allowed, and written in the report


def earlier_report(out_dir: str | Path) -> list[str]:
    """The report files already in out_dir (none if it does not exist)."""
    out = Path(out_dir)
    if not out.is_dir():
        return []
    return [name for name in REPORT_FILES if os.path.lexists(out / name)] + sorted(p.name for p in out.glob(GAIT_FILES))


def check_output_directory(out_dir: str | Path, force: bool = False) -> list[str]:
    """Refuse (ReportError) an output directory that is a file, cannot be made or written,
    or holds an earlier report (unless `force`). Returns the earlier report's files."""
    out = Path(out_dir)
    if is_run_directory(out):
        raise ReportError(
            f"{out} is a run directory (it holds a run's {CONFIG_FILE} or {METRICS_FILE}); a report goes into "
            "a directory of its own: give another -o"
        )
    if out.exists() and not out.is_dir():
        raise ReportError(
            f"{out} is a file, not a directory: the report is several files (table.md, pvalues.tex, scores.csv, "
            "figures) and -o names the directory they go into; give another -o"
        )
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ReportError(f"cannot create {out}: {existing} is a file, not a directory; give another -o")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ReportError(f"cannot write into {existing} (permission denied); give another -o")
    blocked = [name for name in REPORT_FILES if (out / name).is_dir()]
    if blocked:
        raise ReportError(
            f"{out / blocked[0]} is a directory, where the report writes a file; move it, or give another -o"
        )
    earlier = earlier_report(out)
    if earlier and not force:
        raise ReportError(
            f"{out} already holds a report ({', '.join(earlier)}); give --force to replace it "
            "(force=True in Python), or another output directory with -o"
        )
    return earlier


def render_report(
    groups: dict[str, list[RunRecord]],
    table: PValueTable,
    gaits: int = 0,
    comparison: Comparison | None = None,
    replay: ReplayElites | None = None,
) -> dict[str, bytes]:
    """Every file of the report by name, in memory: table.md, pvalues.tex, scores.csv,
    paper-comparison.md and .tex (`comparison`: our p-values beside the paper's), the
    figures (PNG and PDF), with `gaits` > 0 a GIF of that many elites of each schedule's
    median run (`gaits-*.gif`: the best, then spread over the archive, rolled out by
    `replay`), and index.html, the page that shows them all and needs nothing but the files
    beside it."""
    files: dict[str, bytes] = {}
    label = METRICS_SCHEMA[table.metric].axis_label
    caption = (
        f"{table.task} ({label}): median final scores and p-values of one-sided Mann-Whitney U tests, with "
        f"the alternative that the column schedule is better than the row schedule; p < {SIGNIFICANCE} in bold."
    )
    described = runs_described(groups)
    what_ran = "\n".join(f"- **{heading}**: {_markdown_escape(text)}" for heading, text in described)
    notes = "".join(f"\n- note: {note}" for note in table.notes())
    files["table.md"] = f"{caption}\n\n{table.markdown()}{notes}\n\n## What ran\n\n{what_ran}\n".encode()
    files["pvalues.tex"] = f"% {caption}\n{table.latex()}".encode()
    scores = io.StringIO(newline="")
    writer = csv.writer(scores)
    writer.writerow(["schedule", "seed", *METRICS, "directory"])
    for name, runs in groups.items():
        for run in runs:
            writer.writerow([name, run.seed, *(run.final[m] for m in METRICS), str(run.directory)])
    files["scores.csv"] = scores.getvalue().encode()
    if comparison is not None:  # a task and metric of the paper's table
        files["paper-comparison.md"] = comparison.markdown().encode()
        files["paper-comparison.tex"] = comparison.latex().encode()
    figures, captions = {}, {}
    for stem, names in figure_groups(list(groups)).items():
        what = "main results" if stem == "main-results" else "ablations"
        figures[stem] = results_figure(groups, names, f"{table.task}: {what} (median and IQR over seeds)")
        captions[stem] = (
            f"{what.capitalize()}: max fitness, coverage and QD score of {', '.join(names)} against training "
            "evaluations, the median (line) and interquartile range (band) over seeds; the dashed line is where "
            "every schedule shown has its final body for good."
        )
    low, high = descriptor_bounds(table.task)
    if low:  # each schedule's run with the median final score, side by side
        chosen = {name: median_run(runs, table.metric) for name, runs in groups.items()}
        panels = [(name, run.seed, run.final_archive()) for name, run in chosen.items()]
        by = table.metric.replace("_", " ")
        figures["archives"] = archives_figure(panels, low, high, f"{table.task}: final archives (median run by {by})")
        captions["archives"] = (
            f"Final archives: each schedule's run with the median final {by} ("
            + ", ".join(f"{name} seed {run.seed}" for name, run in chosen.items())
            + "), every cell's elite coloured by its fitness."
        )
    reevaluation = reevaluation_figure(
        groups, f"{table.task}: what each re-evaluation kept (median and IQR over seeds)"
    )
    if reevaluation is not None:  # runs that count their re-evaluations
        figures["reevaluation"] = reevaluation
        captions["reevaluation"] = (
            "Re-evaluations: at every phase boundary, the elites that kept their own cell and the cells filled "
            "after re-evaluating the archive in the new body, in % of the cells filled before (median and "
            "interquartile range over seeds)."
        )
    for stem, figure in figures.items():
        for suffix in ("png", "pdf"):
            image = io.BytesIO()
            figure.savefig(image, format=suffix, dpi=130)
            files[f"{stem}.{suffix}"] = image.getvalue()
    shown = gait_files(groups, table.metric, gaits, replay) if gaits > 0 else []
    files.update({name: data for name, data, _ in shown})
    files["index.html"] = index_page(
        table, caption, [(stem, captions[stem]) for stem in figures], shown, described, comparison is not None
    )
    return files


def gait_files(
    groups: dict[str, list[RunRecord]], metric: str, count: int, replay: ReplayElites | None
) -> list[tuple[str, bytes, str]]:
    """Per schedule, a GIF of `count` elites of its median run in the final body, rolled out
    by `replay` (`smol_dsl.runner.replay.replay_elites`): (file name, GIF, caption). Imports
    the renderer (MuJoCo) only when called."""
    from smol_dsl.results import gaits as rendering
    from smol_dsl.rundir import load_archive

    if replay is None:
        raise ValueError("rendering gaits needs `replay`: give replay=smol_dsl.runner.replay.replay_elites")
    shown = []
    for index, (name, runs) in enumerate(groups.items()):
        run = median_run(runs, metric)
        archive = load_archive(run.directory)
        if not archive.filled.any():
            continue
        cells = rendering.spread_cells(archive, min(count, int(archive.filled.sum())))
        drawn = rendering.render_gaits(run, archive, cells, rendering.resolve_bodies(["final"], run), replay=replay)
        slug = re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") or "schedule"
        described = "; ".join(f"cell {g.cell}: fitness {g.fitness:.2f}" for g in drawn)
        caption = f"{name}, median run (seed {run.seed}) by {metric.replace('_', ' ')}, final body: {described}"
        shown.append((f"gaits-{index:02d}-{slug}.gif", rendering.gif_bytes(drawn), caption))
    return shown


def index_page(
    table: PValueTable,
    caption: str,
    figures: Sequence[tuple[str, str]],
    gaits: Sequence[tuple[str, bytes, str]],
    described: Sequence[tuple[str, str]] = (),
    compared_with_paper: bool = False,
) -> bytes:
    """index.html: the table, what ran (`runs_described`), the figures (stem, caption) and
    the gaits, every image and link a file beside it (no script, style sheet or font from
    anywhere)."""
    esc = html.escape
    images = "\n".join(
        f'<figure id="{esc(stem)}"><img src="{esc(stem)}.png" alt="{esc(text)}" style="max-width: 100%">'
        f'<figcaption>{esc(text)} (<a href="{esc(stem)}.pdf">PDF</a>)</figcaption></figure>'
        for stem, text in figures
    )
    moving = "\n".join(
        f'<figure><img src="{esc(name)}" alt="{esc(text)}"><figcaption>{esc(text)}</figcaption></figure>'
        for name, _, text in gaits
    )
    notes = "".join(f"<li>{esc(note)}</li>" for note in table.notes())
    ran = "".join(f"<li><b>{esc(heading)}</b>: {esc(text)}</li>" for heading, text in described)
    links = [
        '<a href="table.md">table.md</a>',
        '<a href="pvalues.tex">pvalues.tex</a>',
        '<a href="scores.csv">scores.csv</a>',
    ]
    if compared_with_paper:
        links += [
            '<a href="paper-comparison.md">paper-comparison.md</a> (these p-values beside the paper\'s)',
            '<a href="paper-comparison.tex">paper-comparison.tex</a>',
        ]
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{esc(table.task)}: smol-dsl report</title></head>
<body style="font-family: sans-serif; max-width: 1400px">
<h1>{esc(table.task)}: final {esc(table.metric.replace("_", " "))}</h1>
<p>{esc(caption)}</p>
{table.html()}
{f"<ul>{notes}</ul>" if notes else ""}
<h2>What ran</h2>
<ul id="what-ran">{ran}</ul>
<h2>Figures</h2>
{images}
{f"<h2>Gaits</h2>{moving}" if gaits else ""}
<p>Also here: {", ".join(links)}.</p>
</body></html>
"""
    return page.encode("utf-8")


def write_files(out_dir: str | Path, files: dict[str, bytes], remove: Sequence[str] = ()) -> list[Path]:
    """Write files into out_dir (made if need be), each atomically: all are written to
    temporary files in out_dir first and then renamed into place, so a failure (a full disk)
    leaves no file half-written and, before the renames, changes nothing; temporary files are
    removed whatever happens. Then remove the files named in `remove`."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ReportError(f"cannot create {out} ({error.strerror or error}); give another -o") from None
    temporaries: dict[str, Path] = {}
    name = ""
    try:
        for name, data in files.items():
            temporaries[name] = out / f".{name}.{os.getpid()}.tmp"
            _write_bytes(temporaries[name], data)
        for name, temporary in temporaries.items():
            os.replace(temporary, out / name)
        for name in remove:
            (out / name).unlink(missing_ok=True)
    except OSError as error:
        raise ReportError(
            f"cannot write {out / name} ({error.strerror or error}); free some space or give another -o"
        ) from None
    finally:
        for temporary in temporaries.values():
            try:
                temporary.unlink(missing_ok=True)
            except OSError:
                pass
    return [out / name for name in files]


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as file:
        file.write(data)


def write_report(
    paths: Sequence[str | Path],
    out_dir: str | Path,
    metric: str | None = None,
    *,
    force: bool = False,
    gaits: int = 0,
    replay: ReplayElites | None = None,
    allow_mixed_environments: bool = False,
) -> Report:
    """Table (table.md, pvalues.tex), final scores (scores.csv) and figures (PNG and PDF)
    of the runs below `paths`, with index.html showing them and (`gaits` > 0) that many elites
    of each schedule's median run (rolled out by `replay`, which gaits need:
    `smol_dsl.runner.replay.replay_elites`), written into out_dir.

    Every run is read and checked, and every file drawn, before the first file is written;
    each file is written atomically. An out_dir that already holds a report is refused
    (ReportError) unless `force`, which replaces it (files of the earlier report that this one
    does not write, such as an ablation figure, are removed)."""
    if gaits > 0 and replay is None:  # before anything is read
        raise ValueError("rendering gaits needs `replay`: give replay=smol_dsl.runner.replay.replay_elites")
    earlier = check_output_directory(out_dir, force)
    groups = load_runs(paths, allow_mixed_environments)
    table = pvalue_table(groups, metric)
    comparison = compare_with_paper(table, groups)
    files = render_report(groups, table, gaits, comparison, replay)
    written = write_files(out_dir, files, remove=[name for name in earlier if name not in files])
    return Report(table, written, comparison, environment_mixing([run for runs in groups.values() for run in runs]))
