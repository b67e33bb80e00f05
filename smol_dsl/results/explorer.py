"""`smol-dsl explore`: finished runs' archives through their phases, served to a browser.

`Explorer(paths, replay=..., cache=...)` reads every run below `paths` (its record, its
phases.npz and its final archive; a run that cannot be read is left out with a note) and
answers the page's questions as JSON; `smol_dsl.results.explorer_app.create_app` serves
them. A request names a run by its number in the list and a cell by its index (ASCII digits
only), never a path, so nothing outside the run directories and the gait cache is read. In
the list, each schedule's run that the report shows (its median, `median_run`) is marked.

A click on a cell renders the final archive's elite in that cell (the snapshots hold no
policies) in the bodies asked for (`final`, `phase:K`: the bodies the run trained in, each
once), through the same rollout as `render` (`smol_dsl.rescoring.replay.replay_elites`,
handed down by the command line), into a GIF kept in the gait cache
(`smol_dsl.results.gait_cache`: keyed by what the gait depends on, bounded in size); a
second click on it is served from there, with the archive's fitness and descriptor read from
the archive. A run whose files changed since the explorer read them is not rendered (restart
it to see the new run). Renders run one at a time in a worker thread; up to `MOST_QUEUED`
wait, and more are refused with a message (HTTP 503), so a burst of clicks keeps the server
answering with bounded memory.
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.results.gait_cache import DEFAULT_CACHE_MB, GaitCache, RunFiles, gait_key
from smol_dsl.results.gaits import RenderError, resolve_bodies
from smol_dsl.results.runs import ReportError, find_run_directories, median_run
from smol_dsl.rundir import RunDirectoryError, RunRecord, load_archive, read_run
from smol_dsl.rundir.layout import SNAPSHOTS_FILE
from smol_dsl.rundir.snapshots import SnapshotsError, read_snapshots
from smol_dsl.tasks import descriptor_bounds, task_spec
from smol_dsl.tasks.physics import DEFAULT_PHYSICS

if TYPE_CHECKING:
    from smol_dsl.results.gaits import ReplayElites

MOST_QUEUED = 8
"""Renders waiting at most; a click beyond them is answered 503 with a message."""
MOST_BODIES = 4
GAIT_SIZE = (240, 180)
NUMBER = r"[0-9]{1,9}"
"""A number of the page's (a run, a cell, a phase): ASCII digits only, at most 9."""
BODY = re.compile(rf"final|phase:({NUMBER})")
"""The bodies a click may ask for: the final one, or a phase's (ASCII digits)."""


class RequestError(ValueError):
    """A request the explorer cannot answer as asked (HTTP 400/404): its message says why."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class ExploredRun:
    """One run as the page knows it."""

    record: RunRecord
    snapshots: list[Any]
    files: RunFiles  # the files its gaits depend on, as read
    median_of: str = ""  # "SMOL's 10 runs by max_fitness" where it is the run the report shows for its schedule

    @property
    def label(self) -> str:
        median = f", the median of {self.median_of}" if self.median_of else ""
        physics = self.record.config.physics
        on = f", on {physics}" if physics != DEFAULT_PHYSICS else ""
        return f"{self.record.schedule}, seed {self.record.seed}{on} ({self.record.directory.name}){median}"


class Explorer:
    """The runs below `paths` and the renders of their elites (see the module's docstring)."""

    def __init__(
        self,
        paths: Sequence[str | Path],
        *,
        replay: ReplayElites | None,
        cache: Path,
        cache_bytes: int = DEFAULT_CACHE_MB * 10**6,
        allow_mixed_environments: bool = False,
    ) -> None:
        directories = find_run_directories(paths)
        runs, problems = [], []
        for directory in directories:
            try:
                files = RunFiles.of(directory)
                record = read_run(directory)
                if record.finished:
                    runs.append(ExploredRun(record, _snapshots_of(record), files))
            except RunDirectoryError as error:
                problems.append(str(error))
        if not runs:
            found = f" ({len(problems)} could not be read: {problems[0]})" if problems else ""
            raise ReportError(
                f"no finished runs in {', '.join(str(p) for p in paths)}{found}; train some with `smol-dsl run` or "
                "`smol-dsl sweep`"
            )
        if not allow_mixed_environments:
            _check_one_physics(runs)
        self.runs = _mark_medians(
            sorted(runs, key=lambda r: (r.record.task, r.record.schedule, r.record.seed, str(r.record.directory)))
        )
        self.problems = problems
        self.replay = replay
        self.cache = GaitCache(Path(cache), cache_bytes)  # a private directory: see gait_cache.private_directory
        self._renders = ThreadPoolExecutor(max_workers=1, thread_name_prefix="smol-dsl-render")
        self._pending: dict[str, Future[dict[str, Any]]] = {}
        self._programs: dict[Path, str | None] = {}  # each run's replay note (`replay_layout`), found once
        self._lock = threading.Lock()

    def close(self) -> None:
        self._renders.shutdown(wait=False, cancel_futures=True)

    # ------------------------------------------------------------------ answers (JSON)
    def run_list(self) -> list[dict[str, Any]]:
        return [
            {"id": number, "label": run.label, "task": run.record.task, "schedule": run.record.schedule,
             "seed": run.record.seed, "physics": run.record.config.physics, "directory": run.record.directory.name,
             "phases": run.record.config.num_phases,
             "snapshots": len(run.snapshots), "median": bool(run.median_of)}
            for number, run in enumerate(self.runs)
        ]  # fmt: skip

    def run(self, number: str | int) -> ExploredRun:
        index = whole_number(number, f"run {number!r}: a run's number from the run list", 404)
        if not 0 <= index < len(self.runs):
            raise RequestError(f"run {index}: there are runs 0 to {len(self.runs) - 1}", 404)
        return self.runs[index]

    def run_data(self, number: str | int) -> dict[str, Any]:
        """What the page draws of a run: its cells' centroids, the descriptor box, every
        snapshot's fitnesses (None where empty), the final archive and the metrics curves
        (coverage, max fitness, and α, the body each row trained in)."""
        run = self.run(number)
        record = run.record
        final = record.final_archive()
        low, high = descriptor_bounds(record.task)
        return {
            "label": run.label,
            "low": list(low),
            "high": list(high),
            "centroids": np.round(final.centroids, 5).tolist(),
            "snapshots": [
                {"phase": s.phase, "moment": "end" if s.moment else "start", "generation": s.generation,
                 "fitnesses": _finite_or_none(s.fitnesses),
                 "body": None if s.body is None else [float(v) for v in s.body]}
                for s in run.snapshots
            ],
            "final": _finite_or_none(final.fitnesses),
            "generations_per_row": [row["generation"] for row in record.rows],
            "coverage": [row["coverage"] for row in record.rows],
            "max_fitness": [_finite(row["max_fitness"]) for row in record.rows],
            "alpha": [row["alpha"] for row in record.rows],  # the body trained in: a paced run's, realised
            "phases": record.config.num_phases,
        }  # fmt: skip

    def gait(self, number: str | int, cell: str | int, bodies: Sequence[str]) -> dict[str, Any]:
        """The final archive's elite in `cell` rendered in `bodies` (`final`, `phase:K`): its
        fitness and descriptor per body, the archive's, and the cached GIF's name; rendered
        now (waiting in the queue) unless cached."""
        run = self.run(number)
        index = whole_number(cell, f"cell {cell!r}: a cell's index, a whole number")
        final = run.record.final_archive()
        if not 0 <= index < len(final.fitnesses):
            raise RequestError(f"cell {index}: the archive has cells 0 to {len(final.fitnesses) - 1}")
        if not final.filled[index]:
            raise RequestError(f"cell {index} is empty in the final archive: click a filled cell")
        resolved = self._bodies(run, list(bodies) or ["final"])
        changed = run.files.changed()
        if changed:
            raise RequestError(
                f"{run.record.directory.name} changed since the explorer read it ({', '.join(changed)}); restart "
                "`smol-dsl explore` to see the run as it is now",
                409,
            )
        if self.replay is None:
            raise RequestError("this explorer renders no gaits (no replay given)", 503)
        key = gait_key(run.files, index, resolved, GAIT_SIZE, self._program(run))
        labels = [label for label, _ in resolved]
        cached = self.cache.get(key, index, labels, final.descriptors.shape[1])
        if cached is not None:
            return self._answer(run, index, key, cached, cached=True)
        with self._lock:
            future = self._pending.get(key)
            if future is None:
                if len(self._pending) >= MOST_QUEUED:
                    raise RequestError(f"{len(self._pending)} gaits are being rendered; click again in a moment", 503)
                future = self._renders.submit(self._render, run, index, resolved, key)
                self._pending[key] = future
        try:
            return self._answer(run, index, key, future.result(), cached=False)
        finally:
            with self._lock:
                self._pending.pop(key, None)

    def _bodies(self, run: ExploredRun, specs: list[str]) -> list[tuple[str, dict[str, float]]]:
        """`final` and `phase:K` (K a phase of the run, in ASCII digits), each once, at most
        MOST_BODIES: the bodies the run trained in, so the renders a run can be asked for are
        bounded."""
        if len(specs) > MOST_BODIES:
            raise RequestError(f"at most {MOST_BODIES} bodies at once")
        phases = run.record.config.num_phases
        seen = set()
        for spec in specs:
            match = BODY.fullmatch(spec)
            if match is None:
                raise RequestError(f"body {spec!r}: give `final` or `phase:K`, K a phase from 0 to {phases - 1}")
            body = spec if match.group(1) is None else int(match.group(1))
            if body in seen:
                raise RequestError(f"body {spec!r} is asked for twice; ask for each body once")
            seen.add(body)
        try:
            return resolve_bodies(specs, run.record)
        except RenderError as error:
            raise RequestError(str(error)) from None

    def _program(self, run: ExploredRun) -> str | None:
        """The replay's note on the program it can build here (`replay_layout`: None where it
        is the one that scored the archive), part of the gait's key."""
        directory = run.record.directory
        if directory not in self._programs:
            from smol_dsl.rescoring.replay import replay_layout

            self._programs[directory] = replay_layout(run.record).inexact
        return self._programs[directory]

    def _answer(self, run: ExploredRun, cell: int, key: str, rendered: dict[str, Any], cached: bool) -> dict[str, Any]:
        """A gait's answer: the rendered rollouts with the archive's own fitness and
        descriptor (from the archive, never from the cache)."""
        final = run.record.final_archive()
        return {
            "cell": cell,
            "archive_fitness": float(final.fitnesses[cell]),
            "archive_descriptor": [float(x) for x in final.descriptors[cell]],
            "gaits": rendered["gaits"],
            "image": f"gaits/{key}.gif",
            "seconds": rendered["seconds"],
            "cached": cached,
        }

    def _render(
        self, run: ExploredRun, cell: int, bodies: list[tuple[str, dict[str, float]]], key: str
    ) -> dict[str, Any]:
        from smol_dsl.results.gait_video import gif_bytes
        from smol_dsl.results.gaits import render_gaits

        assert self.replay is not None
        started = time.perf_counter()
        archive = load_archive(run.record.directory)
        gaits = render_gaits(run.record, archive, [cell], bodies, replay=self.replay, size=GAIT_SIZE)
        rendered = {
            "cell": cell,
            "gaits": [
                {"body": g.body_label, "factors": g.body, "fitness": _finite(g.fitness),
                 "descriptor": [_finite(x) for x in g.descriptor], "inexact": g.inexact}
                for g in gaits
            ],
            "seconds": round(time.perf_counter() - started, 2),
        }  # fmt: skip
        if not run.files.changed():  # the archive rendered is the one the key names
            self.cache.put(key, rendered, gif_bytes(gaits))
        return rendered

    def gait_image(self, name: str) -> bytes:
        """A cached GIF by its name (a key and .gif), read from the cache itself without
        following a link; anything else is a 404."""
        stem = name.removesuffix(".gif")
        if not name.endswith(".gif") or re.fullmatch(r"[0-9a-f]{32}", stem) is None:
            raise RequestError(f"no gait {name!r}", 404)
        try:
            return self.cache.image(stem)
        except OSError:
            raise RequestError(f"no gait {name!r}: click its cell to render it", 404) from None


def whole_number(text: str | int, message: str, status: int = 400) -> int:
    """A number of the page's (a run, a cell): ASCII digits only (no sign, space, `_` or
    other digits, which `int` takes), at most 9 of them; a RequestError with `message`."""
    if isinstance(text, int) and not isinstance(text, bool) and text >= 0:
        return text
    if not isinstance(text, str) or re.fullmatch(NUMBER, text) is None:
        raise RequestError(message, status)
    return int(text)


def _snapshots_of(record: RunRecord) -> list[Any]:
    """A run's phases.npz, checked against its archive's cells (a RunDirectoryError if not)."""
    snapshots = read_snapshots(record.directory)
    cells = record.config.num_centroids
    if any(len(s.fitnesses) != cells for s in snapshots):
        raise SnapshotsError(record.directory / SNAPSHOTS_FILE, f"its archives are not of the run's {cells} cells")
    return snapshots


def _check_one_physics(runs: list[ExploredRun]) -> None:
    """Refuse runs simulated on different physics (a ReportError naming a run of each): their
    archives are not comparable side by side."""
    first: dict[str, Path] = {}
    for run in runs:
        first.setdefault(run.record.config.physics, run.record.directory)
    if len(first) > 1:
        named = "; ".join(f"{physics}: {directory}" for physics, directory in first.items())
        raise ReportError(
            f"the runs were simulated on different physics ({named}), so their archives are not comparable side by "
            "side; explore each physics' runs apart, or pass --allow-mixed-environments to show them together"
        )


def _mark_medians(runs: list[ExploredRun]) -> list[ExploredRun]:
    """`runs` with the run of each task's schedule on each physics (of two runs or more) that
    the report shows marked: the median final score by the task's default metric (`median_run`)."""
    groups: dict[tuple[str, str, str], list[ExploredRun]] = {}
    for run in runs:
        groups.setdefault((run.record.task, run.record.config.physics, run.record.schedule), []).append(run)
    medians: dict[Path, str] = {}
    for (task, _, schedule), group in groups.items():
        if len(group) >= 2:
            metric = task_spec(task).default_metric
            chosen = median_run([run.record for run in group], metric)
            medians[chosen.directory] = f"{schedule}'s {len(group)} runs by {metric}"
    return [replace(run, median_of=medians.get(run.record.directory, "")) for run in runs]


def _finite(value: Any) -> float | None:
    return float(value) if math.isfinite(float(value)) else None


def _finite_or_none(values: np.ndarray) -> list[float | None]:
    return [round(float(v), 4) if math.isfinite(float(v)) else None for v in np.asarray(values).reshape(-1)]
