"""`smol-dsl reproduce TASK`: the paper's experiment for a task in one command.

The paper's eight conditions (`smol_dsl.results.conditions`) x `--seeds` (10, as in the paper) as one
sweep in the paper's settings (`--preset paper`, the default on an accelerator; `quick` on
CPUs, where the paper's budget would take weeks), resumable with `--resume` and taking
every option of `sweep`; then the report, with the paper's table beside ours
(paper-comparison.md) and, where the settings are not the paper's, the deviations named.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from smol_dsl.cli import common
from smol_dsl.cli.common import UsageError
from smol_dsl.cli.run import Sweep, add_sweep_options, use_cpu_cores_as_devices
from smol_dsl.results.conditions import PAPER_CONDITIONS, PAPER_SEEDS, PAPER_TASKS

if TYPE_CHECKING:
    from smol_dsl.cli.run import Plan
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir import RunConfig
    from smol_dsl.runner import RunResult


def add_parsers(commands: argparse._SubParsersAction) -> None:
    reproduce = commands.add_parser(
        "reproduce",
        help="the paper's experiment for a task: its eight conditions, its seeds, then the report",
        description=f"Run the paper's eight conditions ({', '.join(c.name for c in PAPER_CONDITIONS)}) "
        "x --seeds as one sweep, then write the report with the paper's table "
        "beside ours (paper-comparison.md: every p-value, ours and the paper's, and a verdict). The default "
        "preset is the paper's on an accelerator and `quick` on CPUs; other settings are named in the "
        "comparison, which then compares only directions and significance. Takes sweep's options.",
    )
    reproduce.add_argument("task", metavar="TASK", help=f"one of the paper's tasks: {', '.join(PAPER_TASKS)}")
    add_sweep_options(reproduce, seeds=PAPER_SEEDS)
    reproduce.add_argument(
        "--robustness",
        action="store_true",
        help="before the report, measure how much of every final archive survives a change of body, program "
        "and start (`smol-dsl robustness` with its defaults), so that the report shows it",
    )
    reproduce.set_defaults(handle=Reproduce().train, seed=None, preset=None)


class Reproduce(Sweep):
    """`smol-dsl reproduce`: `sweep` of the paper's conditions, then `report`."""

    command = "reproduce"
    gaits = 0  # elites of each condition's median run its report draws (`_gaits`)
    robustness = False  # measure robustness before the report (--robustness)

    def train(self, args: argparse.Namespace) -> int:
        if args.task not in PAPER_TASKS:
            raise UsageError(
                f"the paper ran {', '.join(PAPER_TASKS)}, not {args.task!r}; "
                f"use `smol-dsl sweep {args.task} SCHEDULE...` for other tasks"
            )
        if args.preset is None:
            use_cpu_cores_as_devices()  # before JAX starts: the devices a sweep here would use
            args.preset = "quick" if common.devices(args)[0].platform == "cpu" else "paper"
        args.schedules = [condition.schedule for condition in PAPER_CONDITIONS]
        self.gaits = 0 if args.dry_run else self._gaits()
        self.robustness = bool(args.robustness)
        return super().train(args)  # the report is written when the sweep has ended (`summary`)

    def _gaits(self) -> int:
        """1 (the report draws the best elite of each condition's median run, as `report`
        does) where MuJoCo can render here, else 0 and a note, checked before training."""
        import sys

        from smol_dsl.results.gaits import RenderError, gl_backend

        try:
            gl_backend()
        except RenderError as error:
            print(f"smol-dsl reproduce: note: the report will have no gaits: {error}", file=sys.stderr)
            return 0
        return 1

    def default_out(self, args: argparse.Namespace, schedules: list[Schedule], config: RunConfig) -> Path:
        return Path("runs") / f"{common.physics_label(args.task, config.physics)}-reproduce"

    def summary(self, plan: Plan, results: list[RunResult]) -> str:
        """The sweep's first line, then the report of the sweep in OUT/report; a process
        sharing a sweep leaves the report to `smol-dsl report`."""
        from smol_dsl.runner.progress import sweep_summary

        done = sweep_summary(results, plan.out).split("\n")[0]
        if plan.part != (0, 1):
            return done
        print(done)  # before the report, which may fail
        return self.report(plan.out)

    def report(self, out: Path) -> str:
        """Write the report of the sweep in `out` into out/report; what to print of it."""
        from smol_dsl.rescoring.replay import replay_elites
        from smol_dsl.results import report as results_report

        replay = replay_elites if self.gaits else None
        if self.robustness:  # robustness.csv beside the runs: the report adds it
            import sys

            from smol_dsl.results.robustness import measure_and_write

            measure_and_write(
                [out], out, force=True, progress=lambda line: print(f"robustness: {line}", file=sys.stderr, flush=True)
            )
        written = results_report.write_report([out], out / "report", force=True, gaits=self.gaits, replay=replay)
        lines = [f"{written.table.task}, final {written.table.metric}:\n\n{written.table.markdown()}"]
        if written.comparison is not None:
            lines.append(written.comparison.summary())
        lines.append(f"report: {out / 'report'} (paper-comparison.md: our p-values beside the paper's)")
        return "\n".join(lines)
