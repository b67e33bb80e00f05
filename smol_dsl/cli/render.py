"""`smol-dsl render`: watch the elites of a finished run, in any body of its schedule."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.cli.common import EXIT_OK, UsageError, positive_int

if TYPE_CHECKING:
    import argparse

    from smol_dsl.tasks import TaskSpec

DEFAULT_SIZE = (320, 240)


def add_parser(commands: argparse._SubParsersAction) -> None:
    render = commands.add_parser(
        "render",
        help="render elites of a finished run as a GIF, MP4 or web page",
        description="Roll out elites of a finished run with the runner's own rollout (the run's episode start, "
        "a body of its schedule) and draw them with MuJoCo's renderer through the tracking camera, in real "
        "time. Several elites, or one elite in several bodies (--body phase:0 --body final: the child and the "
        "adult), play side by side. Works headless: the GL backend is EGL or OSMesa (MUJOCO_GL to choose).",
    )
    render.add_argument("run_dir", metavar="RUN_DIR", help="a finished run directory (or one run of a sweep)")
    render.add_argument(
        "-o", "--out", metavar="OUT", help="output file: .gif, .mp4 or .html (default RUN_DIR/gait.gif)"
    )
    chosen = render.add_mutually_exclusive_group()
    chosen.add_argument(
        "--cell", default="best", metavar="CELL", help="the elite's cell: `best` (default) or a cell index"
    )
    chosen.add_argument(
        "--at", metavar="D1,D2,...", help="the elite whose descriptor is nearest this point (comma-separated)"
    )
    chosen.add_argument(
        "--cells", type=positive_int, metavar="N", help="N elites spread over the archive (the best first)"
    )
    render.add_argument(
        "--body",
        action="append",
        metavar="BODY",
        help="`final` (default: the schedule's final body, the one the archive was scored in), `phase:K`, or "
        "a factor per channel of the schedule, comma-separated; give it twice for two bodies side by side",
    )
    render.add_argument(
        "--steps", type=positive_int, metavar="N", help="steps to render (default: the run's episode length)"
    )
    render.add_argument(
        "--size", type=_size, default=DEFAULT_SIZE, metavar="WxH", help="pixels of each elite's tile (default 320x240)"
    )
    render.set_defaults(handle=render_run)


def _size(text: str) -> tuple[int, int]:
    import argparse

    parts = text.lower().split("x")
    try:
        width, height = (int(part) for part in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give width x height in pixels, e.g. 320x240") from None
    if not (16 <= width <= 4096 and 16 <= height <= 4096):
        raise argparse.ArgumentTypeError(f"{text!r}: each side from 16 to 4096 pixels")
    return width, height


def render_run(args: argparse.Namespace) -> int:
    from smol_dsl.cli.run import use_cpu_cores_as_devices

    use_cpu_cores_as_devices()  # the devices the run trained on: its scoring program, bit for bit
    from smol_dsl.rescoring.replay import replay_elites
    from smol_dsl.results import gait_video, gaits
    from smol_dsl.rundir import RunDirectoryError, load_archive, read_run
    from smol_dsl.tasks import task_spec

    directory = _run_directory(Path(args.run_dir))
    out = gait_video.check_output(args.out if args.out is not None else directory / "gait.gif")
    run = read_run(directory)
    if not run.finished or not (directory / "archive.npz").is_file():
        raise UsageError(
            f"{directory}: the run has not finished (no final archive); resume it with `smol-dsl run ... --resume`"
        )
    try:
        archive = load_archive(directory)
    except (OSError, ValueError) as error:
        raise RunDirectoryError(f"{directory / 'archive.npz'}: cannot be read ({error})") from None
    if not archive.filled.any():
        raise UsageError(f"{directory}: the final archive holds no elite")
    cells = _cells(args, archive, directory, task_spec(run.task))
    bodies = gaits.resolve_bodies(args.body or ["final"], run)
    steps = args.steps or run.config.episode_length
    gait_video.check_canvas(len(cells), len(bodies), args.size, steps, task_spec(run.task).step_seconds, out.suffix)
    started = time.perf_counter()
    rendered = gaits.render_gaits(run, archive, cells, bodies, replay=replay_elites, steps=args.steps, size=args.size)
    title = f"{run.task} on {run.config.physics} under {run.schedule}, seed {run.seed}"
    gait_video.write_gaits(out, rendered, title)
    seconds = time.perf_counter() - started
    for gait in rendered:
        descriptor = ", ".join(f"{x:.4f}" for x in gait.descriptor)
        print(
            f"cell {gait.cell}, {gait.body_label} body ({', '.join(f'{k} {v:.4g}' for k, v in gait.body.items())}): "
            f"fitness {gait.fitness:.4f} (archive {gait.archive_fitness:.4f}), descriptor ({descriptor})"
        )
        if not gait.frames_scored:
            print(
                "  (its frames come from the same rollout compiled with positions recorded, which rounds "
                "differently here: contacts amplify float rounding, so the drawn episode may part from the scored one)"
            )
    if rendered[0].inexact is not None:
        print(
            f"note: not replayed in the program that scored the archive ({rendered[0].inexact}): in the final body "
            "the fitnesses agree with the archive's to float rounding, not bit for bit"
        )
    frames = max(len(gait.frames) for gait in rendered)  # the tiles play together, the longest to its end
    print(f"wrote {out} ({frames} frames of {rendered[0].frame_ms:.0f} ms; rendered in {seconds:.1f} s)")
    return EXIT_OK


def _run_directory(directory: Path) -> Path:
    """The run directory RUN_DIR names, or a UsageError saying what it is instead."""
    from smol_dsl.rundir import is_run_directory

    if not directory.exists():
        raise UsageError(f"{directory}: no such run directory")
    if not directory.is_dir():
        raise UsageError(f"{directory} is a file, not a run directory; give the directory `smol-dsl run` wrote")
    if not is_run_directory(directory):
        from smol_dsl.results.runs import find_run_directories

        runs = find_run_directories([directory])
        shown = ", ".join(str(p) for p in runs[:3]) + (", ..." if len(runs) > 3 else "")
        hint = f"; it holds the runs {shown}: give one of them" if runs else " (one holds config.json and metrics.csv)"
        raise UsageError(f"{directory} is not a run directory{hint}")
    return directory


def _cells(args: argparse.Namespace, archive: object, directory: Path, spec: TaskSpec) -> list[int]:
    from smol_dsl.results import gaits

    if args.at is not None:
        try:
            point = [float(part) for part in args.at.split(",")]
        except ValueError:
            message = f"--at {args.at}: give the descriptor's values, comma-separated, e.g. --at 0.3,0.7"
            raise UsageError(message) from None
        cell, distance = gaits.nearest_cell(archive, point)
        _note_outside(args.at, point, spec, archive.descriptors[cell], cell, distance)
        return [cell]
    if args.cells is not None:
        return gaits.spread_cells(archive, args.cells)
    if args.cell == "best":
        return [archive.best_cell]
    try:
        cell = int(args.cell)
    except ValueError:
        raise UsageError(f"--cell {args.cell}: give `best` or a cell index, e.g. --cell 0") from None
    return [gaits.check_cell(archive, cell, directory)]


def _note_outside(text: str, point: list[float], spec: TaskSpec, found: Any, cell: int, distance: float) -> None:
    """Say so when --at lies outside the task's descriptor space, and which elite it took."""
    bounds = list(zip(spec.descriptor_low, spec.descriptor_high, strict=True))
    if all(low <= x <= high for x, (low, high) in zip(point, bounds, strict=True)):
        return
    space = " x ".join(f"[{low:g}, {high:g}]" for low, high in bounds)
    where = ", ".join(f"{x:.4g}" for x in found)
    print(
        f"note: --at {text} lies outside {spec.name}'s descriptor space ({space}); the nearest elite, in cell {cell}, "
        f"is at ({where}), {distance:.3g} away"
    )
