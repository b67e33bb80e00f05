"""The `smol-dsl` command line: check, plot, run, sweep, reproduce, report, robustness, render and explore.

One module per command adds its own subparser and does its work (`check`, `plot`, `run` for
both `run` and `sweep`, `report`); `common` holds what they share: option types, the
loading of schedules, and the turning of every error into an exit status. Bad input of any
kind (a broken file, a missing file, a bad flag) prints one clear error and exits with status
2, without a Python traceback.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from smol_dsl.cli import check, explore, plot, render, report, reproduce, robustness, run
from smol_dsl.cli.common import EXIT_INTERNAL, EXIT_OK, EXIT_USAGE, OPTIONS, exit_status

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ["EXIT_INTERNAL", "EXIT_OK", "EXIT_USAGE", "OPTIONS", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The parser of every command, each added by its own module."""
    from smol_dsl import __version__
    from smol_dsl.language.library import library_names

    parser = argparse.ArgumentParser(
        prog="smol-dsl",
        description=(
            "Developmental curricula for quality-diversity robotics. A .sched file describes how "
            "the actuator strength alpha of a robot changes over MAP-Elites training (SMOL). "
            "SCHEDULE arguments are paths, or names of bundled schedules such as `human` or `smol.sched`."
        ),
        epilog=f"Docs: docs/language.md. Bundled schedules: {', '.join(library_names())}.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    check.add_parser(commands)
    plot.add_parser(commands)
    run.add_parsers(commands)
    reproduce.add_parsers(commands)
    report.add_parser(commands)
    robustness.add_parser(commands)
    render.add_parser(commands)
    explore.add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `smol-dsl` console script."""
    args = build_parser().parse_args(argv)  # exits with status 2 on bad flags
    return exit_status(args.command, lambda: args.handle(args))
