"""The report's files: `write_report(paths, out_dir)` reads and checks the runs
(`smol_dsl.results.runs.load_runs`), makes the U-test table, Holm's adjustment beside each
p (`smol_dsl.results.statistics`), and compares its raw p-values with the paper's
(`smol_dsl.results.paper`), and writes table.md,
pvalues.tex, scores.csv, the figures (`smol_dsl.results.report_figures`), the gaits and index.html
(`smol_dsl.results.page`): everything is read and drawn before the first file is written,
the files are written together and atomically, and an earlier report is replaced only with
`force=True` (`--force`).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from smol_dsl.results.conditions import ABLATIONS
from smol_dsl.results.output import check_writable_directory, write_files
from smol_dsl.results.page import index_page
from smol_dsl.results.paper import compare_with_paper
from smol_dsl.results.phase_maps import PHASE_MAP_FILES, PhaseMaps, frame_name, phase_map_frames, phase_maps_html
from smol_dsl.results.report_figures import archives_figure, bodies_figure, reevaluation_figure, results_figure
from smol_dsl.results.robustness import Robustness, robustness_figure_and_tables, robustness_for_report
from smol_dsl.results.robustness_tables import robustness_html, robustness_markdown
from smol_dsl.results.runs import METRICS, ReportError, environment_mixing, load_runs, median_run, runs_described
from smol_dsl.results.statistics import SIGNIFICANCE, PValueTable, markdown_escape, pvalue_table
from smol_dsl.rundir import CONFIG_FILE, METRICS_FILE, METRICS_SCHEMA, ROBUSTNESS_FILE, RunRecord, is_run_directory
from smol_dsl.tasks import descriptor_bounds

if TYPE_CHECKING:
    from smol_dsl.results.gaits import ReplayElites
    from smol_dsl.results.paper import Comparison

ROBUSTNESS_REPORT_FILES = ("robustness.tex", "robustness.png", "robustness.pdf")
"""What a report with robustness measurements adds (its tables go into table.md and index.html)."""
FIGURE_STEMS = ("main-results", "ablation-results", "reevaluation", "archives")
REPORT_FILES = (
    "table.md",
    "pvalues.tex",
    "scores.csv",
    "index.html",
    "paper-comparison.md",
    "paper-comparison.tex",
    *(f"{stem}{suffix}" for stem in FIGURE_STEMS for suffix in (".png", ".pdf")),
    *ROBUSTNESS_REPORT_FILES,
)
"""Every file a report may write but its gaits (`gaits-*.gif`) and its phase maps
(`phase-maps-*.png`): an output directory holding any of them holds a report."""
GAIT_FILES = "gaits-*.gif"


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


@dataclass(frozen=True)
class Report:
    """What `write_report` wrote."""

    table: PValueTable
    files: list[Path]
    comparison: Comparison | None = None  # beside the paper's table, for its tasks and metrics
    environment_mixing: list[str] = dataclasses.field(default_factory=list)  # allowed, and written in the report
    notes: list[str] = dataclasses.field(default_factory=list)  # what the report left out and why (also in its files)


def earlier_report(out_dir: str | Path) -> list[str]:
    """The report files already in out_dir (none if it does not exist)."""
    out = Path(out_dir)
    if not out.is_dir():
        return []
    globbed = [p.name for pattern in (GAIT_FILES, PHASE_MAP_FILES) for p in out.glob(pattern)]
    return [name for name in REPORT_FILES if os.path.lexists(out / name)] + sorted(globbed)


def check_output_directory(out_dir: str | Path, force: bool = False) -> list[str]:
    """Refuse (ReportError) an output directory that is a file, cannot be made or written,
    or holds an earlier report (unless `force`). Returns the earlier report's files."""
    out = Path(out_dir)
    if is_run_directory(out):
        raise ReportError(
            f"{out} is a run directory (it holds a run's {CONFIG_FILE} or {METRICS_FILE}); a report goes into "
            "a directory of its own: give another -o"
        )
    check_writable_directory(out, REPORT_FILES, "the report")
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
    robustness: Robustness | None = None,
) -> tuple[dict[str, bytes], list[str]]:
    """Every file of the report by name, in memory, and the notes of what it left out (a
    median run whose phases.npz is damaged leaves the phase maps; the notes are in table.md
    and index.html too): table.md, pvalues.tex, scores.csv,
    paper-comparison.md and .tex (`comparison`: our p-values beside the paper's), the
    figures (PNG and PDF), with `gaits` > 0 a GIF of that many elites of each schedule's
    median run (`gaits-*.gif`: the best, then spread over the archive, rolled out by
    `replay`), and index.html, the page that shows them all and needs nothing but the files
    beside it. With `robustness` (robustness.csv's measurements of these runs), table.md and
    index.html get its section (`smol_dsl.results.robustness`), scores.csv each run's robust
    coverage per perturbation, and robustness.tex, .png and .pdf are written."""
    files: dict[str, bytes] = {}
    low, high = descriptor_bounds(table.task)
    chosen = {name: median_run(runs, table.metric) for name, runs in groups.items()}
    phase_maps = phase_map_frames(chosen, low, high, table.task) if low else PhaseMaps()
    label = METRICS_SCHEMA[table.metric].axis_label
    caption = (
        f"{table.task} ({label}): median final scores and p-values of one-sided Mann-Whitney U tests, with "
        "the alternative that the column schedule is better than the row schedule; beside each p its "
        f"Holm-adjusted value over the table's {table.family} tests, in bold where that is below {SIGNIFICANCE}."
    )
    described = runs_described(groups)
    what_ran = "\n".join(f"- **{heading}**: {markdown_escape(text)}" for heading, text in described)
    notes = "".join(f"\n- note: {note}" for note in [*table.notes(), *phase_maps.notes])
    robust = "" if robustness is None else "\n" + robustness_markdown(robustness, level=2)
    files["table.md"] = f"{caption}\n\n{table.markdown()}{notes}\n{robust}\n## What ran\n\n{what_ran}\n".encode()
    files["pvalues.tex"] = f"% {caption}\n{table.latex()}".encode()
    files["scores.csv"] = scores_csv(groups, robustness)
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
    if low:  # each schedule's run with the median final score, side by side
        files.update({frame_name(index): png for index, (_, png) in enumerate(phase_maps.frames)})
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
    bodies = bodies_figure(groups, f"{table.task}: the bodies trained in (each run, median and IQR over seeds)")
    if bodies is not None:  # some run is paced: its body followed its archive
        figures["bodies"] = bodies
        captions["bodies"] = (
            "Bodies: the factor of every scheduled channel each run trained in at every phase (thin lines), and "
            "per schedule the median and interquartile range over seeds; a paced schedule's runs move on when "
            "their archives meet its condition, so their curves differ."
        )
    for stem, figure in figures.items():
        for suffix in ("png", "pdf"):
            image = io.BytesIO()
            figure.savefig(image, format=suffix, dpi=130)
            files[f"{stem}.{suffix}"] = image.getvalue()
    if robustness is not None:
        files.update(robustness_figure_and_tables(robustness))
    shown = gait_files(groups, table.metric, gaits, replay) if gaits > 0 else []
    files.update({name: data for name, data, _ in shown})
    files["index.html"] = index_page(
        table,
        caption,
        [(stem, captions[stem]) for stem in figures],
        shown,
        described,
        comparison is not None,
        robustness_html(robustness) if robustness is not None else "",
        phase_maps_html([label for label, _ in phase_maps.frames], phase_maps.notes),
    )
    return files, phase_maps.notes


def scores_csv(groups: dict[str, list[RunRecord]], robustness: Robustness | None = None) -> bytes:
    """scores.csv: every run's final scores, its changes of body (the boundaries at which it
    was re-evaluated: every one for an open-loop schedule, those it moved on at for a paced
    one) and its coverage at the end of the last phase before the final-body tail (empty for
    a run all in its tail), robust coverage per perturbation where measured, its directory."""
    scores = io.StringIO(newline="")
    writer = csv.writer(scores)
    perturbations = robustness.perturbations if robustness is not None else []
    robust_columns = [f"robust coverage ({p})" for p in perturbations]
    writer.writerow(["schedule", "seed", *METRICS, *PHASE_COLUMNS, *robust_columns, "directory"])
    for name, runs in groups.items():
        for run in runs:
            robust = [robustness.robust_coverage(run.directory, p) for p in perturbations] if robustness else []
            before = run.coverage_before_tail()
            phases = [run.body_changes, "" if before is None else before]
            writer.writerow([name, run.seed, *(run.final[m] for m in METRICS), *phases, *robust, str(run.directory)])
    return scores.getvalue().encode()


PHASE_COLUMNS = ("body changes", "coverage before the tail")
"""scores.csv's columns of how a run went through its phases (a paced run moves on when its
archive lets it)."""


def gait_files(
    groups: dict[str, list[RunRecord]], metric: str, count: int, replay: ReplayElites | None
) -> list[tuple[str, bytes, str]]:
    """Per schedule, a GIF of `count` elites of its median run in the final body, rolled out
    by `replay` (`smol_dsl.rescoring.replay.replay_elites`): (file name, GIF, caption). Imports
    the renderer (MuJoCo) only when called."""
    from smol_dsl.results import gaits as rendering
    from smol_dsl.results.gait_video import gif_bytes
    from smol_dsl.rundir import load_archive

    if replay is None:
        raise ValueError("rendering gaits needs `replay`: give replay=smol_dsl.rescoring.replay.replay_elites")
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
        shown.append((f"gaits-{index:02d}-{slug}.gif", gif_bytes(drawn), caption))
    return shown


def robustness_files_of(
    paths: Sequence[str | Path], robustness: str | Path | Sequence[str | Path] | None
) -> list[Path]:
    """The robustness.csv files a report reads (see `write_report`'s `robustness`)."""
    if robustness is None:
        return []
    if isinstance(robustness, str) and robustness == "auto":
        return [Path(p) / ROBUSTNESS_FILE for p in paths if (Path(p) / ROBUSTNESS_FILE).is_file()]
    return [Path(robustness)] if isinstance(robustness, (str, os.PathLike)) else [Path(p) for p in robustness]


def write_report(
    paths: Sequence[str | Path],
    out_dir: str | Path,
    metric: str | None = None,
    *,
    force: bool = False,
    gaits: int = 0,
    replay: ReplayElites | None = None,
    allow_mixed_environments: bool = False,
    robustness: str | Path | Sequence[str | Path] | None = "auto",
) -> Report:
    """Table (table.md, pvalues.tex), final scores (scores.csv) and figures (PNG and PDF)
    of the runs below `paths`, with index.html showing them and (`gaits` > 0) that many elites
    of each schedule's median run (rolled out by `replay`, which gaits need:
    `smol_dsl.rescoring.replay.replay_elites`), written into out_dir.

    Every run is read and checked, and every file drawn, before the first file is written;
    each file is written atomically. `robustness` adds `smol-dsl robustness`'s measurements of
    these runs: "auto" (the default) those of the robustness.csv in any of `paths` where there
    is one, else the robustness.csv path(s) given, None none. An out_dir that already holds a report is refused
    (ReportError) unless `force`, which replaces it (files of the earlier report that this one
    does not write, such as an ablation figure, are removed)."""
    if gaits > 0 and replay is None:  # before anything is read
        raise ValueError("rendering gaits needs `replay`: give replay=smol_dsl.rescoring.replay.replay_elites")
    earlier = check_output_directory(out_dir, force)
    groups = load_runs(paths, allow_mixed_environments)
    table = pvalue_table(groups, metric).holm_adjusted()  # many tests: Holm beside each p
    comparison = compare_with_paper(table, groups)
    measured = robustness_files_of(paths, robustness)
    robust = robustness_for_report(measured, groups, table.task) if measured else None
    files, notes = render_report(groups, table, gaits, comparison, replay, robust)
    written = write_files(out_dir, files, remove=[name for name in earlier if name not in files])
    mixing = environment_mixing([run for runs in groups.values() for run in runs])
    return Report(table, written, comparison, mixing, notes)
