"""`smol-dsl report`: the paper's U-test table and figures from finished runs."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

from smol_dsl.cli.common import EXIT_OK, UsageError, positive_int
from smol_dsl.errors import counted

if TYPE_CHECKING:
    import argparse

ASKED = "asked"  # --robustness given without a file


def add_parser(commands: argparse._SubParsersAction) -> None:
    report = commands.add_parser(
        "report",
        help="the paper's U-test table and figures from finished runs",
        description="Collect the finished runs in the given directories (sweep or run directories, searched "
        "recursively), and write the paper's table - median final score per schedule and one-sided "
        "Mann-Whitney U p-values of 'column better than row' - as Markdown and LaTeX, the final scores, and "
        "figures of median and interquartile range over seeds (PNG and PDF) with the final archives, the gaits "
        "of each schedule's median run, and index.html, a page showing them all that opens offline.",
    )
    report.add_argument("dirs", nargs="+", metavar="DIR", help="sweep or run directories")
    report.add_argument("-o", "--out", metavar="OUT", help="output directory (default DIR/report for one DIR)")
    report.add_argument(
        "--force",
        action="store_true",
        help="replace the report already in the output directory (without it, an earlier report is kept "
        "and nothing is written)",
    )
    report.add_argument(
        "--metric",
        default=None,
        metavar="NAME",
        help=f"final score: max_fitness, coverage or qd_score (default: the task's, {_default_metrics_help()})",
    )
    report.add_argument(
        "--allow-mixed-environments",
        action="store_true",
        help="put runs produced under different software or hardware (environment.json) in one table",
    )
    robust = report.add_mutually_exclusive_group()
    robust.add_argument(
        "--robustness",
        nargs="?",
        const=ASKED,
        default="auto",
        metavar="CSV",
        help="add `smol-dsl robustness`'s measurements of these runs (robust coverage, its U-tests, the figure): "
        "from CSV, or (the default) from the robustness.csv of any DIR that has one",
    )
    robust.add_argument("--no-robustness", action="store_true", help="leave robustness measurements out")
    gaits = report.add_mutually_exclusive_group()
    gaits.add_argument(
        "--gaits",
        type=positive_int,
        default=1,
        metavar="N",
        help="render N elites of each schedule's median run into the report (default 1: the best; needs OpenGL)",
    )
    gaits.add_argument("--no-gaits", action="store_true", help="write the report without rendering any gait")
    report.set_defaults(handle=write_report)


def _default_metrics_help() -> str:
    from smol_dsl.tasks import task_names, task_spec

    by_metric: dict[str, list[str]] = {}
    for name in task_names():
        by_metric.setdefault(task_spec(name).default_metric, []).append(name)
    return ", ".join(f"{metric} for {' and '.join(names)}" for metric, names in by_metric.items())


def write_report(args: argparse.Namespace) -> int:
    from smol_dsl.results import report as results_report

    if args.metric is not None and args.metric not in results_report.METRICS:
        raise UsageError(f"unknown metric {args.metric!r}; the metrics are {', '.join(results_report.METRICS)}")
    if args.out is None and len(args.dirs) > 1:
        raise UsageError("with several DIRs, say where the report goes with -o OUT")
    if args.out is not None and not args.out.strip():
        raise UsageError("-o: empty path; give the directory the report goes into (or leave -o out for DIR/report)")
    out = Path(args.out) if args.out is not None else Path(args.dirs[0]) / "report"
    gaits = 0 if args.no_gaits else args.gaits
    replay = None
    if gaits:
        from smol_dsl.cli.run import use_cpu_cores_as_devices
        from smol_dsl.rescoring.replay import replay_elites

        use_cpu_cores_as_devices()  # as the runs trained: their scoring programs (see `smol-dsl render`)
        replay = replay_elites
    robustness = None if args.no_robustness else args.robustness
    if robustness == ASKED:  # --robustness without a file: the DIRs must hold one
        robustness = results_report.robustness_files_of(args.dirs, "auto")
        if not robustness:
            raise UsageError(
                f"--robustness: no robustness.csv in {', '.join(args.dirs)}; measure first with `smol-dsl robustness "
                f"{' '.join(args.dirs)}{' -o DIR' if len(args.dirs) > 1 else ''}`, or name the file: --robustness CSV"
            )
    report = results_report.write_report(
        args.dirs,
        out,
        args.metric,
        force=args.force,
        gaits=gaits,
        replay=replay,
        allow_mixed_environments=args.allow_mixed_environments,
        robustness=robustness,
    )
    table = report.table
    print(f"{table.task}, final {table.metric} ({counted(sum(table.runs.values()), 'run')}):\n")
    print(table.markdown())
    for note in table.notes():
        print(f"note: {note}", file=sys.stderr)
    for mixing in report.environment_mixing:
        print(f"note: allowed to mix environments: {mixing}", file=sys.stderr)
    for note in report.notes:
        print(f"note: {note}", file=sys.stderr)
    print(f"wrote {', '.join(str(f) for f in report.files)}")
    return EXIT_OK
