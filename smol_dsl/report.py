"""The paper's analysis of finished runs: the U-test table and the figures.

`load_runs(paths)` finds run directories (written by `smol-dsl run` or `sweep`), checks
that they can be compared (one task, the same settings, finished, no run counted twice),
and groups them by schedule. `pvalue_table` gives, for every pair of schedules, the
one-sided Mann-Whitney U test (scipy) of "the column's final scores are higher than the
row's", in the layout of the paper's `tables/pvalues.tex`; `write_report` writes it as
Markdown and LaTeX with the figures.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smol_dsl.errors import UserInputError
from smol_dsl.runner.config import RunConfig
from smol_dsl.runner.run import alpha_one_evaluations

METRICS = ("max_fitness", "coverage", "qd_score")
METRIC_LABELS = {"max_fitness": "max fitness", "coverage": "coverage (%)", "qd_score": "QD score"}
DEFAULT_METRIC = {"walker2d": "max_fitness", "halfcheetah": "max_fitness", "ant_omni": "coverage"}
"""The paper's final score per task."""

COLUMNS = ("SMOL", "SMOL-Reverse", "SMOL-Human")
"""The paper's table compares every schedule (rows) with these curricula (columns)."""
MAIN = ("Vanilla MAP-Elites", "SMOL", "SMOL-Reverse", "SMOL-Human")
ABLATIONS = ("Random", "Extinction 5%", "Extinction 10%", "Extinction 50%")
ORDER = ("SMOL", "SMOL-Reverse", "SMOL-Human", "Vanilla MAP-Elites", *ABLATIONS)
SIGNIFICANCE = 0.05


class ReportError(UserInputError):
    """Run directories that cannot be reported on together, with what to do instead."""


@dataclass(frozen=True)
class RunRecord:
    """A finished run directory: its settings, schedule and metrics log."""

    directory: Path
    config: RunConfig
    schedule: str  # the schedule's name
    schedule_source: str
    tail_start: float
    rows: list[dict[str, Any]]

    @property
    def task(self) -> str:
        return self.config.task

    @property
    def seed(self) -> int:
        return self.config.seed

    @property
    def settings(self) -> dict[str, Any]:
        """The run's configuration without its seed: what runs compared must share."""
        settings = dataclasses.asdict(self.config)
        del settings["seed"]
        return settings

    @property
    def final(self) -> dict[str, Any]:
        return self.rows[-1]

    @property
    def finished(self) -> bool:
        return self.final["generation"] >= self.config.generations

    def curve(self, metric: str) -> tuple[np.ndarray, np.ndarray]:
        """Training evaluations and the metric, one point per logged row."""
        evaluations = np.asarray([row["evaluations"] for row in self.rows], dtype=float)
        return evaluations, np.asarray([row[metric] for row in self.rows], dtype=float)

    def alpha_one_evaluations(self) -> float | None:
        """Training evaluations when alpha becomes 1 for good (the first tail phase starts)."""
        phases = self.config.num_phases
        first_tail = next(k for k in range(phases + 1) if k == phases or k / phases >= self.tail_start)
        return alpha_one_evaluations(self.rows, first_tail)


def is_run_directory(path: Path) -> bool:
    return (path / "config.json").is_file() and (path / "metrics.csv").is_file()


def find_run_directories(paths: Iterable[str | Path]) -> list[Path]:
    """Run directories given, or found anywhere below the given directories, each once."""
    found: dict[Path, None] = {}
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise ReportError(f"{path}: no such directory")
        if not path.is_dir():
            raise ReportError(f"{path} is not a directory; give run or sweep directories")
        candidates = [path] if is_run_directory(path) else sorted(p.parent for p in path.rglob("config.json"))
        for candidate in candidates:
            if is_run_directory(candidate):
                found.setdefault(candidate.resolve(), None)
    return list(found)


def read_run(directory: Path) -> RunRecord:
    """Read a run directory's config, schedule, certificate and metrics.csv."""
    certificate = json.loads((directory / "certificate.json").read_text())
    with open(directory / "metrics.csv", newline="") as file:
        rows = [_typed_row(row) for row in csv.DictReader(file)]
    return RunRecord(
        directory=directory,
        config=RunConfig.from_json((directory / "config.json").read_text()),
        schedule=certificate["name"],
        schedule_source=(directory / "schedule.sched").read_text(),
        tail_start=float(certificate["tail_start"]),
        rows=rows,
    )


def _typed_row(row: dict[str, str]) -> dict[str, Any]:
    typed: dict[str, Any] = {}
    for name, value in row.items():
        if name == "event":
            typed[name] = value
        elif name in ("alpha", "coverage", "max_fitness", "qd_score"):
            typed[name] = float(value)
        else:
            typed[name] = int(value)
    return typed


def load_runs(paths: Sequence[str | Path]) -> dict[str, list[RunRecord]]:
    """Finished runs below `paths`, grouped by schedule name in the paper's order.

    Refuses (ReportError) no runs, unfinished runs, runs of several tasks or settings,
    two schedules with one name, and a (schedule, seed) given twice.
    """
    directories = find_run_directories(paths)
    if not directories:
        raise ReportError(
            f"no run directories in {', '.join(str(p) for p in paths)} (a run directory holds config.json "
            "and metrics.csv); make some with `smol-dsl sweep` or `smol-dsl run`"
        )
    runs = [read_run(d) for d in directories]
    tasks = sorted({run.task for run in runs})
    if len(tasks) > 1:
        examples = "; ".join(f"{task}: {next(r.directory for r in runs if r.task == task)}" for task in tasks)
        raise ReportError(
            f"the runs are of different tasks ({', '.join(tasks)}), which cannot share a table ({examples}); "
            "report each task's directories separately"
        )
    unfinished = [run for run in runs if not run.finished]
    if unfinished:
        raise ReportError(
            f"{len(unfinished)} run(s) have not finished, e.g. {unfinished[0].directory} (generation "
            f"{unfinished[0].final['generation']} of {unfinished[0].config.generations}); finish them with "
            "`smol-dsl sweep ... --resume` or `smol-dsl run ... --resume`, or leave them out"
        )
    reference = runs[0]
    for run in runs[1:]:
        if run.settings != reference.settings:
            differing = sorted(k for k in run.settings if run.settings[k] != reference.settings.get(k))
            raise ReportError(
                f"{run.directory} and {reference.directory} were run with different settings "
                f"({', '.join(differing)}); only runs with the same settings can be compared"
            )
    groups: dict[str, list[RunRecord]] = {}
    for run in runs:
        group = groups.setdefault(run.schedule, [])
        if group and group[0].schedule_source != run.schedule_source:
            raise ReportError(
                f"two different schedules are both named {run.schedule!r} ({group[0].directory} and "
                f"{run.directory}); give them different `name`s"
            )
        twin = next((other for other in group if other.seed == run.seed), None)
        if twin is not None:
            raise ReportError(
                f"{run.schedule} seed {run.seed} is there twice ({twin.directory} and {run.directory}); "
                "each run must count once"
            )
        group.append(run)
    ordered = sorted(groups, key=lambda name: (ORDER.index(name) if name in ORDER else len(ORDER), name))
    return {name: sorted(groups[name], key=lambda r: r.seed) for name in ordered}


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
        """Warnings about the table's power: with few runs no p-value can fall below 0.05."""
        notes = []
        for row in self.rows:
            for column in self.columns:
                if row != column and smallest_p(self.runs[column], self.runs[row]) >= SIGNIFICANCE:
                    notes.append(
                        f"{column} ({self.runs[column]} runs) vs {row} ({self.runs[row]} runs): the smallest "
                        f"possible p-value is {smallest_p(self.runs[column], self.runs[row]):.3g}, so this pair "
                        f"cannot reach p < {SIGNIFICANCE}; run more seeds (the paper used 7 to 10)"
                    )
        return notes

    @property
    def best(self) -> set[str]:
        """The schedules with the highest median (several when they tie)."""
        top = max(self.medians[name] for name in self.rows)
        return {name for name in self.rows if self.medians[name] == top}

    def markdown(self) -> str:
        header = ["schedule", "runs", "median score", *(f"p: {c} better" for c in self.columns)]
        lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
        for row in self.rows:
            median = _number(self.medians[row])
            cells = [row, str(self.runs[row]), f"**{median}**" if row in self.best else median]
            for column in self.columns:
                p = self.pvalues[row][column]
                cells.append("-" if p is None else (f"**{p:.3e}**" if p < SIGNIFICANCE else f"{p:.3e}"))
            lines.append("| " + " | ".join(cells) + " |")
        return "\n".join(lines) + "\n"

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
            median = _number(self.medians[row])
            cells = [_latex_escape(row), f"\\textbf{{{median}}}" if row in self.best else median]
            for column in self.columns:
                p = self.pvalues[row][column]
                cells.append("-" if p is None else (f"\\textbf{{{p:.3e}}}" if p < SIGNIFICANCE else f"{p:.3e}"))
            lines.append(" & ".join(cells) + " \\\\")
        lines += ["\\bottomrule", "\\end{tabular}"]
        return "\n".join(lines) + "\n"


def smallest_p(runs_a: int, runs_b: int) -> float:
    """The smallest p-value an exact one-sided U test can give with these sample sizes."""
    return 1 / math.comb(runs_a + runs_b, runs_a)


def _number(value: float) -> str:
    return f"{value:.1f}"


def _latex_escape(text: str) -> str:
    for char in "\\&%$#_{}":
        text = text.replace(char, "\\" + char)
    return text


def pvalue_table(groups: dict[str, list[RunRecord]], metric: str | None = None) -> PValueTable:
    """The paper's table: rows every schedule, columns the SMOL curricula present (all
    schedules when none is), each cell the one-sided Mann-Whitney U p-value of "column
    better than row" on final scores."""
    from scipy.stats import mannwhitneyu

    task = next(iter(groups.values()))[0].task
    metric = metric or DEFAULT_METRIC[task]
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


def results_figure(groups: dict[str, list[RunRecord]], names: Sequence[str], title: str) -> Any:
    """Median (line) and interquartile range (band) over seeds of max fitness, coverage
    and QD score against training evaluations, one colour per schedule; a dashed line
    from where alpha is 1 for every schedule shown."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=(13, 3.8), layout="constrained")
    axes = figure.subplots(1, len(METRICS))
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    # where alpha is 1 for every schedule shown (the paper's fair-comparison line)
    alpha_one = max((x for name in names if (x := groups[name][0].alpha_one_evaluations()) is not None), default=None)
    for ax, metric in zip(axes, METRICS, strict=True):
        for i, name in enumerate(names):
            runs = groups[name]
            evaluations = runs[0].curve(metric)[0]
            values = np.stack([run.curve(metric)[1] for run in runs])
            values[~np.isfinite(values)] = np.nan  # max fitness of an archive emptied by extinction
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a moment when every archive is empty
                low, median, high = np.nanpercentile(values, [25, 50, 75], axis=0)
            color = ORDER_COLORS.get(name, colors[(i + len(ORDER_COLORS)) % len(colors)])
            ax.plot(evaluations, median, color=color, lw=1.5, label=f"{name} ({len(runs)})")
            ax.fill_between(evaluations, low, high, color=color, alpha=0.2, lw=0)
        if alpha_one is not None:
            ax.axvline(alpha_one, color="0.3", ls="--", lw=1.0)
        ax.set_xlabel("evaluations")
        ax.set_ylabel(METRIC_LABELS[metric])
        ax.grid(alpha=0.25)
    axes[0].legend(fontsize=8, title="schedule (runs)", title_fontsize=8)
    figure.suptitle(title)
    return figure


ORDER_COLORS = {
    "Vanilla MAP-Elites": "#4d4d4d",
    "SMOL": "#1f77b4",
    "SMOL-Reverse": "#ff7f0e",
    "SMOL-Human": "#2ca02c",
    "Random": "#9467bd",
    "Extinction 5%": "#8c564b",
    "Extinction 10%": "#e377c2",
    "Extinction 50%": "#bcbd22",
}


def archives_figure(groups: dict[str, list[RunRecord]], metric: str, title: str) -> Any:
    """Final archives side by side, one per schedule: the run with the median final score
    (the lower one for an even number of runs), on one colour scale."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from smol_dsl.runner.checkpoint import load_archive
    from smol_dsl.runner.figures import draw_archive
    from smol_dsl.tasks import descriptor_bounds

    chosen = {}
    for name, runs in groups.items():
        ranked = sorted(runs, key=lambda run: run.final[metric])
        chosen[name] = ranked[(len(ranked) - 1) // 2]
    archives = {name: load_archive(run.directory) for name, run in chosen.items()}
    filled = np.concatenate([a.fitnesses[a.filled] for a in archives.values()])
    vmin, vmax = (float(filled.min()), float(filled.max())) if filled.size else (None, None)
    low, high = descriptor_bounds(next(iter(chosen.values())).task)
    figure = Figure(figsize=(3.6 * len(archives) + 1.0, 3.6), layout="constrained")
    axes = np.atleast_1d(figure.subplots(1, len(archives)))
    shown = None
    for ax, (name, archive) in zip(axes, archives.items(), strict=True):
        shown = draw_archive(ax, archive.centroids, archive.fitnesses, low, high, pixels=300, vmin=vmin, vmax=vmax)
        coverage = 100 * archive.filled.mean()
        ax.set_title(f"{name}, seed {chosen[name].seed}\ncoverage {coverage:.1f}%", fontsize=9)
    if shown is not None:
        figure.colorbar(shown, ax=list(axes), label="fitness")
    figure.suptitle(title)
    return figure


# ---------------------------------------------------------------------------- report
@dataclass(frozen=True)
class Report:
    """What `write_report` wrote."""

    table: PValueTable
    files: list[Path]


def write_report(paths: Sequence[str | Path], out_dir: str | Path, metric: str | None = None) -> Report:
    """Table (table.md, pvalues.tex), final scores (scores.csv) and figures (PNG and PDF)
    of the runs below `paths`, written into out_dir."""
    groups = load_runs(paths)
    table = pvalue_table(groups, metric)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    label = METRIC_LABELS[table.metric]
    caption = (
        f"{table.task} ({label}): median final scores and p-values of one-sided Mann-Whitney U tests, with "
        f"the alternative that the column schedule is better than the row schedule; p < {SIGNIFICANCE} in bold."
    )
    (out / "table.md").write_text(f"{caption}\n\n{table.markdown()}")
    (out / "pvalues.tex").write_text(f"% {caption}\n{table.latex()}")
    files += [out / "table.md", out / "pvalues.tex"]
    with open(out / "scores.csv", "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["schedule", "seed", *METRICS, "directory"])
        for name, runs in groups.items():
            for run in runs:
                writer.writerow([name, run.seed, *(run.final[m] for m in METRICS), str(run.directory)])
    files.append(out / "scores.csv")
    for stem, names in figure_groups(list(groups)).items():
        what = "main results" if stem == "main-results" else "ablations"
        figure = results_figure(groups, names, f"{table.task}: {what} (median and IQR over seeds)")
        for suffix in (".png", ".pdf"):
            figure.savefig(out / f"{stem}{suffix}", dpi=130)
            files.append(out / f"{stem}{suffix}")
    if _descriptor_size(groups) == 2:
        by = table.metric.replace("_", " ")
        figure = archives_figure(groups, table.metric, f"{table.task}: final archives (median run by {by})")
        for suffix in (".png", ".pdf"):
            figure.savefig(out / f"archives{suffix}", dpi=130)
            files.append(out / f"archives{suffix}")
    return Report(table, files)


def _descriptor_size(groups: dict[str, list[RunRecord]]) -> int:
    from smol_dsl.tasks import descriptor_bounds

    return len(descriptor_bounds(next(iter(groups.values()))[0].task)[0])
