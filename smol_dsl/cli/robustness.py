"""`smol-dsl robustness`: how much of finished runs' final archives survives a change of
body, of episode start or of the program that scores them."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from smol_dsl.cli.common import EXIT_OK, UsageError, count
from smol_dsl.errors import counted

if TYPE_CHECKING:
    import argparse

    from smol_dsl.rescoring.perturbations import Perturbations


def add_parser(commands: argparse._SubParsersAction) -> None:
    from smol_dsl.rescoring.perturbations import DEFAULT_BODIES, DEFAULT_STARTS, MOST_SAMPLES
    from smol_dsl.tasks.physics import PHYSICS_NAMES

    command = commands.add_parser(
        "robustness",
        help="re-score final archives under changes of body, start and program: what survives",
        description="Re-score every elite of the final archives of finished runs (sweep or run directories, "
        "searched recursively) under perturbations, each into a fresh archive: body factors around the final "
        "body, the same body in another layout of the program (the float path), other episode starts and, when asked, "
        "another physics. "
        "Writes robustness.csv (per run, perturbation and sample: the cells still filled, the elites that kept "
        "their cell, moved, collided or died, and each perturbation's robust coverage, share and max fitness, "
        "QDax's corrected-repertoire median over its samples, an odd number of them), robustness.md and .tex "
        "(median and IQR per schedule, one-sided tests paired by seed, Holm-adjusted) and robustness.png and .pdf. "
        "`smol-dsl report` adds them to its page when robustness.csv is in a DIR it reports on. "
        "See docs/robustness.md.",
    )
    command.add_argument("dirs", nargs="+", metavar="DIR", help="sweep or run directories of finished runs")
    command.add_argument(
        "-o", "--out", metavar="OUT", help="output directory (default: DIR, beside the runs, for one DIR)"
    )
    command.add_argument(
        "--body",
        action="append",
        metavar="CHANNEL=FACTORS",
        help="a family of factors of a channel of the schedules, times the final body's, whose corrected archive "
        "takes each elite's median over them: a list (gear=0.9,0.95,0.99) or LOW:HIGH:N, N factors evenly spaced "
        "(gear=0.8:0.98:7); an odd number of them, and x1 (the final body, a control) only alone; repeat for "
        "other families or channels (default: "
        + " ".join(f"{channel}=" + ",".join(f"{f:g}" for f in factors) for channel, factors in DEFAULT_BODIES)
        + ")",
    )
    command.add_argument("--no-body", action="store_true", help="no body perturbation")
    command.add_argument(
        "--starts",
        type=count,
        default=DEFAULT_STARTS,
        metavar="K",
        help=f"other episode starts, drawn from the task's reset distribution: an odd number, at most "
        f"{MOST_SAMPLES} (default {DEFAULT_STARTS})",
    )
    command.add_argument("--no-starts", action="store_true", help="no other episode starts")
    command.add_argument("--no-float-path", action="store_true", help="no re-scoring by another program layout")
    command.add_argument(
        "--other-physics",
        action="append",
        default=[],
        metavar="PHYSICS",
        help="also re-score every elite in its final body, from its own start, on this physics, one the runs did "
        f"not train on ({', '.join(PHYSICS_NAMES)}): how much of an archive carries over to another simulator; "
        "repeat for several",
    )
    command.add_argument("--force", action="store_true", help="replace earlier robustness files in the output")
    command.add_argument(
        "--finished-only",
        action="store_true",
        help="measure the finished runs below DIR and leave out those that have not finished (or started)",
    )
    command.add_argument(
        "--allow-mixed-environments",
        action="store_true",
        help="measure runs produced under different software or hardware (environment.json) together",
    )
    command.add_argument("--no-progress", action="store_true", help="print nothing while measuring")
    command.set_defaults(handle=measure_robustness)


def body_factors(spec: str) -> tuple[str, tuple[float, ...]]:
    """`CHANNEL=F1,F2,...` or `CHANNEL=LOW:HIGH:N` as (channel name, factors); a UsageError
    saying what a --body takes otherwise."""
    from smol_dsl.rescoring.perturbations import MOST_SAMPLES

    example = "e.g. --body gear=0.9,0.95,0.99 or --body gear=0.8:0.98:7"
    channel, equals, factors = spec.partition("=")
    if not equals or not channel.strip() or not factors.strip():
        raise UsageError(f"--body {spec}: give CHANNEL=FACTORS, {example}")
    try:
        if ":" in factors:
            low, high, number = factors.split(":")
            steps = int(number)
            if not 1 <= steps <= MOST_SAMPLES:
                raise UsageError(f"--body {spec}: N is a number of factors from 1 to {MOST_SAMPLES}, not {steps}")
            start, stop = float(low), float(high)
            values = [start] if steps == 1 else [start + (stop - start) * k / (steps - 1) for k in range(steps)]
        else:
            values = [float(part) for part in factors.split(",")]
    except ValueError:
        raise UsageError(f"--body {spec}: the factors are numbers, {example}") from None
    bad = next((value for value in values if not math.isfinite(value) or value <= 0), None)
    if bad is not None:
        raise UsageError(f"--body {spec}: factor {bad:g} is not a finite number above 0, {example}")
    return channel.strip(), tuple(round(value, 12) for value in values)


def perturbations_of(args: argparse.Namespace) -> Perturbations:
    """The perturbations the command line asks for."""
    from smol_dsl.rescoring.perturbations import Perturbations

    if args.no_body and args.body:
        raise UsageError("--no-body and --body: give one of them")
    bodies = (
        () if args.no_body else tuple(body_factors(spec) for spec in args.body) if args.body else Perturbations.bodies
    )
    starts = 0 if args.no_starts else args.starts
    return Perturbations(
        bodies=bodies, starts=starts, float_path=not args.no_float_path, physics=tuple(args.other_physics)
    )


def measure_robustness(args: argparse.Namespace) -> int:
    from smol_dsl.results import robustness as results_robustness
    from smol_dsl.results.robustness_tables import summary_markdown

    if args.out is None and len(args.dirs) > 1:
        raise UsageError("with several DIRs, say where robustness.csv goes with -o OUT")
    if args.out is not None and not args.out.strip():
        raise UsageError("-o: empty path; give the directory robustness.csv goes into (or leave -o out for DIR)")
    out = Path(args.out) if args.out is not None else Path(args.dirs[0])
    perturbations = perturbations_of(args)
    from smol_dsl.cli.run import use_cpu_cores_as_devices

    use_cpu_cores_as_devices()  # as the runs trained: their scoring programs (see `smol-dsl render`)
    progress = None if args.no_progress else (lambda line: print(f"robustness: {line}", file=sys.stderr, flush=True))
    report = results_robustness.measure_and_write(
        args.dirs,
        out,
        perturbations,
        force=args.force,
        allow_mixed_environments=args.allow_mixed_environments,
        finished_only=args.finished_only,
        progress=progress,
    )
    robustness = report.robustness
    runs = len({row.directory for row in robustness.rows})
    left_out = f" ({counted(len(report.left_out), 'unfinished run')} left out)" if report.left_out else ""
    print(f"{robustness.task}, {counted(runs, 'run')}{left_out}:\n")
    print(summary_markdown(robustness))
    print(f"wrote {', '.join(str(f) for f in report.files)}")
    return EXIT_OK
