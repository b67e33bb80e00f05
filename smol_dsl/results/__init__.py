"""Finished runs, read from their run directories (`smol_dsl.rundir`): the paper's statistics
and report, and every figure.

- `conditions`: the paper's tasks, seeds and eight conditions (schedule, name, colour,
  role), the one table every other module reads;
- `runs`: `load_runs(paths)` finds and checks run directories and groups comparable runs
  by schedule;
- `statistics`: `pvalue_table(groups)` is the paper's table of one-sided Mann-Whitney U
  tests;
- `paper`: that table beside the paper's (paper_table.json);
- `report`: `write_report(paths, out_dir)` writes the table with the figures and
  `page`'s index.html (`smol-dsl report`), into a directory `output` checks and writes;
- `robustness`: `measure_and_write(paths, out_dir)` re-scores final archives under
  perturbations (`smol_dsl.rescoring.robustness`) and writes robustness.csv, its tables
  (`robustness_tables`: paired tests, Holm-adjusted) and its figure (`robustness_figure`)
  (`smol-dsl robustness`), which the report adds to its own;
- `figures`: what every figure shares (line styles, legends, `save_figure`);
- `run_figures`: `save_run_figures(directory)` draws a finished run directory's metrics.png
  and archive.png from its files, and is what the CLI calls after `run` and `sweep` have
  trained; `archive_maps` draws an archive as a map, for it and the report;
- `schedule_figures`: `schedule_figure(schedules)` is the paper's Figure 2 (`smol-dsl plot`);
- `report_figures`: `results_figure` and `archives_figure` are the report's;
- `gaits` chooses elites and draws them rolled out (`render_gaits`), and `gait_video`
  writes them as GIF, MP4 or a web page (`smol-dsl render`).

The names below load their module on first use, so `import smol_dsl.results` loads nothing
else; `report` and the modules it uses import no JAX, Brax or QDax, so reporting on runs does not
load them, and `schedule_figures` imports JAX only to evaluate schedules (`schedule_figure`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from smol_dsl.lazy import lazy_names

if TYPE_CHECKING:
    from smol_dsl.results.report import write_report
    from smol_dsl.results.report_figures import archives_figure, results_figure
    from smol_dsl.results.run_figures import save_run_figures
    from smol_dsl.results.runs import ReportError, load_runs
    from smol_dsl.results.schedule_figures import schedule_figure
    from smol_dsl.results.statistics import pvalue_table

_LAZY = {
    "ReportError": "smol_dsl.results.runs",
    "load_runs": "smol_dsl.results.runs",
    "pvalue_table": "smol_dsl.results.statistics",
    "write_report": "smol_dsl.results.report",
    "archives_figure": "smol_dsl.results.report_figures",
    "results_figure": "smol_dsl.results.report_figures",
    "save_run_figures": "smol_dsl.results.run_figures",
    "schedule_figure": "smol_dsl.results.schedule_figures",
}

__all__ = [
    "ReportError",
    "archives_figure",
    "load_runs",
    "pvalue_table",
    "results_figure",
    "save_run_figures",
    "schedule_figure",
    "write_report",
]

__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
