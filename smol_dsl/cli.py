"""The `smol-dsl` command line: check and plot schedules.

Bad input of any kind (a broken file, a missing file, a bad flag) prints one clear error
and exits with status 2, without a Python traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2


class UsageError(Exception):
    """Bad command-line input that argparse itself does not catch."""


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    if value > 100_000:
        raise argparse.ArgumentTypeError(f"must be at most 100000, got {value}")
    return value


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    from smol_dsl import __version__

    parser = argparse.ArgumentParser(
        prog="smol-dsl",
        description=(
            "Developmental curricula for quality-diversity robotics. A .sched file describes how "
            "the actuator strength alpha of a robot changes over MAP-Elites training (SMOL). "
            "SCHEDULE arguments are paths, or names of bundled schedules such as `human` or `smol.sched`."
        ),
        epilog="Docs: docs/language.md. Bundled schedules: "
        "vanilla, smol, smol-reverse, human, random, extinction-05, extinction-10, extinction-50.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    check = commands.add_parser(
        "check",
        help="verify schedules symbolically and print their certificates",
        description="Parse, compile and symbolically verify each schedule, and print its certificate "
        "(alpha's range, the alpha = 1 tail, monotone pieces, continuity at every join). "
        "Exit status 0 when all are valid, 2 otherwise.",
    )
    check.add_argument("schedules", nargs="+", metavar="SCHEDULE", help="a .sched path or a bundled name")
    check.add_argument("--quiet", "-q", action="store_true", help="print only errors")

    plot = commands.add_parser(
        "plot",
        help="plot alpha over training (the paper's Figure 2)",
        description="Plot alpha over training as per-phase steps with the smooth curve, several schedules "
        "overlaid, and a dashed line where alpha becomes 1 for good. With no SCHEDULE, plots the paper's "
        "Figure 2 (vanilla, smol, smol-reverse, human).",
    )
    plot.add_argument("schedules", nargs="*", metavar="SCHEDULE", help="a .sched path or a bundled name")
    plot.add_argument(
        "-o",
        "--out",
        metavar="OUT",
        help="output file; .png, .svg or .pdf (default: NAME.png for one schedule, schedules.png for several)",
    )
    plot.add_argument("--phases", type=_positive_int, default=100, metavar="N", help="number of phases (default 100)")
    plot.add_argument("--seed", type=_int, default=0, metavar="S", help="seed of random segments (default 0)")
    return parser


def _load_all(names: Sequence[str]) -> tuple[list, list[str]]:
    from smol_dsl import ScheduleError, load

    loaded, errors = [], []
    for name in names:
        try:
            loaded.append(load(name))
        except ScheduleError as error:
            errors.append(str(error))
    return loaded, errors


def _check(args: argparse.Namespace) -> int:
    schedules, errors = _load_all(args.schedules)
    if not args.quiet:
        for schedule in schedules:
            about = f" - {schedule.description}" if schedule.description else ""
            print(f"{schedule.path}: ok: {schedule.name}{about}")
            print(schedule.certificate)
    for error in errors:
        print(error, file=sys.stderr)
    return EXIT_USAGE if errors else EXIT_OK


def _plot(args: argparse.Namespace) -> int:
    from smol_dsl.plotting import FIGURE_FORMATS, PAPER_FIGURE, save_figure, schedule_figure

    names = args.schedules or list(PAPER_FIGURE)
    if args.out is None:
        out = Path(f"{Path(names[0]).stem}.png" if len(names) == 1 else "schedules.png")
    else:
        out = Path(args.out)
    if out.suffix.lower() not in FIGURE_FORMATS:
        raise UsageError(f"cannot write {out}: the format is chosen by the suffix, one of {', '.join(FIGURE_FORMATS)}")
    if not out.parent.is_dir():
        raise UsageError(f"cannot write {out}: no such directory {out.parent}")
    schedules, errors = _load_all(names)
    if errors:
        for error in errors:
            print(error, file=sys.stderr)
        return EXIT_USAGE
    for schedule in schedules:
        if schedule.tail_phases(args.phases) == 0:
            print(
                f"smol-dsl plot: note: with {args.phases} phases no phase of {schedule.name} runs wholly "
                f"at alpha = 1 (its tail starts at {float(schedule.tail_start) * 100:g}%); "
                "a run needs at least one phase at alpha = 1 to compare schedules on the same body",
                file=sys.stderr,
            )
    import jax

    figure = schedule_figure(schedules, num_phases=args.phases, key=jax.random.key(args.seed))
    try:
        save_figure(figure, out)
    except OSError as error:
        raise UsageError(f"cannot write {out}: {error.strerror}") from None
    print(f"wrote {out} ({', '.join(s.name for s in schedules)}; {args.phases} phases)")
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `smol-dsl` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)  # exits with status 2 on bad flags
    handlers = {"check": _check, "plot": _plot}
    try:
        return handlers[args.command](args)
    except UsageError as error:
        print(f"smol-dsl {args.command}: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("smol-dsl: interrupted", file=sys.stderr)
        return 130
    except Exception as error:  # a bug in smol-dsl, not bad input
        if os.environ.get("SMOL_DSL_DEBUG"):
            raise
        print(
            f"smol-dsl: internal error: {type(error).__name__}: {error}\n"
            "This is a bug in smol-dsl; rerun with SMOL_DSL_DEBUG=1 for the traceback and please report it.",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
