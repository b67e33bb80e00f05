"""`smol-dsl explore`: finished runs' archives through their phases, served to a browser.

`Explorer(paths, replay=..., cache=...)` reads every run below `paths` (its record, its
phases.npz and its final archive) and answers the page's questions as JSON; `create_app`
wraps it in a Flask app that serves the page (`explorer_page`: one file, its script inline)
and nothing else. A request names a run by its number in the list and a cell by its index,
never a path, so nothing outside the run directories and the gait cache can be reached.
In the list, each schedule's run that the report shows (its median, `median_run`) is marked.

A click on a cell renders the final archive's elite in that cell (the snapshots hold no
policies) in the bodies asked for, through the same rollout as `render`
(`smol_dsl.rescoring.replay.replay_elites`, handed down by the command line), into a GIF cached
on disk by run, cell and bodies: a second click on it is served from the cache. Renders run
one at a time in a worker thread; up to `MOST_QUEUED` wait, and more are refused with a
message (HTTP 503), so a burst of clicks keeps the server answering with bounded memory.
"""

from __future__ import annotations

import hashlib
import math
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.results.gaits import RenderError, resolve_bodies
from smol_dsl.results.runs import ReportError, find_run_directories, median_run
from smol_dsl.rundir import RunDirectoryError, RunRecord, load_archive, read_run
from smol_dsl.rundir.snapshots import read_snapshots
from smol_dsl.tasks import descriptor_bounds, task_spec

if TYPE_CHECKING:
    from flask import Flask

    from smol_dsl.results.gaits import ReplayElites

MOST_QUEUED = 8
"""Renders waiting at most; a click beyond them is answered 503 with a message."""
MOST_BODIES = 4
GAIT_SIZE = (240, 180)


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
    median_of: str = ""  # "SMOL's 10 runs by max_fitness" where it is the run the report shows for its schedule

    @property
    def label(self) -> str:
        median = f", the median of {self.median_of}" if self.median_of else ""
        return f"{self.record.schedule}, seed {self.record.seed} ({self.record.directory.name}){median}"


class Explorer:
    """The runs below `paths` and the renders of their elites (see the module's docstring)."""

    def __init__(self, paths: Sequence[str | Path], *, replay: ReplayElites | None, cache: Path) -> None:
        directories = find_run_directories(paths)
        runs, problems = [], []
        for directory in directories:
            try:
                record = read_run(directory)
            except RunDirectoryError as error:
                problems.append(str(error))
                continue
            if record.finished:
                runs.append(ExploredRun(record, read_snapshots(directory)))
        if not runs:
            found = f" ({len(problems)} could not be read: {problems[0]})" if problems else ""
            raise ReportError(
                f"no finished runs in {', '.join(str(p) for p in paths)}{found}; train some with `smol-dsl run` or "
                "`smol-dsl sweep`"
            )
        self.runs = _mark_medians(
            sorted(runs, key=lambda r: (r.record.task, r.record.schedule, r.record.seed, str(r.record.directory)))
        )
        self.problems = problems
        self.replay = replay
        self.cache = Path(cache)
        self._renders = ThreadPoolExecutor(max_workers=1, thread_name_prefix="smol-dsl-render")
        self._pending: dict[str, Future[dict[str, Any]]] = {}
        self._lock = threading.Lock()

    def close(self) -> None:
        self._renders.shutdown(wait=False, cancel_futures=True)

    # ------------------------------------------------------------------ answers (JSON)
    def run_list(self) -> list[dict[str, Any]]:
        return [
            {"id": number, "label": run.label, "task": run.record.task, "schedule": run.record.schedule,
             "seed": run.record.seed, "phases": run.record.config.num_phases, "snapshots": len(run.snapshots),
             "median": bool(run.median_of)}
            for number, run in enumerate(self.runs)
        ]  # fmt: skip

    def run(self, number: str | int) -> ExploredRun:
        try:
            index = int(number)
        except (TypeError, ValueError):
            raise RequestError(f"run {number!r}: a run's number from the run list", 404) from None
        if not 0 <= index < len(self.runs):
            raise RequestError(f"run {index}: there are runs 0 to {len(self.runs) - 1}", 404)
        return self.runs[index]

    def run_data(self, number: str | int) -> dict[str, Any]:
        """What the page draws of a run: its cells' centroids, the descriptor box, every
        snapshot's fitnesses (None where empty), the final archive and the metrics curves."""
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
                 "fitnesses": _finite_or_none(s.fitnesses)}
                for s in run.snapshots
            ],
            "final": _finite_or_none(final.fitnesses),
            "generations_per_row": [row["generation"] for row in record.rows],
            "coverage": [row["coverage"] for row in record.rows],
            "max_fitness": [_finite(row["max_fitness"]) for row in record.rows],
            "phases": record.config.num_phases,
        }  # fmt: skip

    def gait(self, number: str | int, cell: str | int, bodies: Sequence[str]) -> dict[str, Any]:
        """The final archive's elite in `cell` rendered in `bodies` (`final`, `phase:K`): its
        fitness and descriptor per body and the cached GIF's name; rendered now (waiting in
        the queue) unless cached."""
        run = self.run(number)
        try:
            index = int(cell)
        except (TypeError, ValueError):
            raise RequestError(f"cell {cell!r}: a cell's index, a whole number") from None
        final = run.record.final_archive()
        if not 0 <= index < len(final.fitnesses):
            raise RequestError(f"cell {index}: the archive has cells 0 to {len(final.fitnesses) - 1}")
        if not final.filled[index]:
            raise RequestError(f"cell {index} is empty in the final archive: click a filled cell")
        bodies = list(bodies) or ["final"]
        if len(bodies) > MOST_BODIES:
            raise RequestError(f"at most {MOST_BODIES} bodies at once")
        try:
            resolved = resolve_bodies(bodies, run.record)
        except RenderError as error:
            raise RequestError(str(error)) from None
        key = hashlib.sha256(repr((str(run.record.directory.resolve()), index, resolved)).encode()).hexdigest()[:24]
        answer = self.cache / f"{key}.json"
        if answer.is_file() and (self.cache / f"{key}.gif").is_file():
            import json

            return {**json.loads(answer.read_text()), "cached": True}
        with self._lock:
            future = self._pending.get(key)
            if future is None:
                if len(self._pending) >= MOST_QUEUED:
                    raise RequestError(f"{len(self._pending)} gaits are being rendered; click again in a moment", 503)
                future = self._renders.submit(self._render, run, index, resolved, key)
                self._pending[key] = future
        try:
            return future.result()
        finally:
            with self._lock:
                self._pending.pop(key, None)

    def _render(
        self, run: ExploredRun, cell: int, bodies: list[tuple[str, dict[str, float]]], key: str
    ) -> dict[str, Any]:
        import json

        from smol_dsl.results.gait_video import gif_bytes
        from smol_dsl.results.gaits import render_gaits
        from smol_dsl.rundir.files import atomic_write

        if self.replay is None:
            raise RequestError("this explorer renders no gaits (no replay given)", 503)
        started = time.perf_counter()
        archive = load_archive(run.record.directory)
        gaits = render_gaits(run.record, archive, [cell], bodies, replay=self.replay, size=GAIT_SIZE)
        self.cache.mkdir(parents=True, exist_ok=True)
        image = gif_bytes(gaits)
        atomic_write(self.cache / f"{key}.gif", lambda file: file.write(image))
        result = {
            "cell": cell,
            "archive_fitness": float(archive.fitnesses[cell]),
            "archive_descriptor": [float(x) for x in archive.descriptors[cell]],
            "gaits": [
                {"body": g.body_label, "factors": g.body, "fitness": float(g.fitness),
                 "descriptor": [float(x) for x in g.descriptor], "inexact": g.inexact}
                for g in gaits
            ],
            "image": f"gaits/{key}.gif",
            "seconds": round(time.perf_counter() - started, 2),
        }  # fmt: skip
        text = json.dumps(result)
        atomic_write(self.cache / f"{key}.json", lambda file: file.write(text.encode()))
        return {**result, "cached": False}

    def gait_file(self, name: str) -> Path:
        """A cached GIF by its name (24 hex digits and .gif), a file of the cache itself (a
        symlink, which could lead out of it, is not served); anything else is a 404."""
        stem = name.removesuffix(".gif")
        if not name.endswith(".gif") or len(stem) != 24 or any(c not in "0123456789abcdef" for c in stem):
            raise RequestError(f"no gait {name!r}", 404)
        path = self.cache / name
        if path.is_symlink():
            raise RequestError(f"no gait {name!r}: the cache's file is a link, not served", 404)
        if not path.is_file():
            raise RequestError(f"no gait {name!r}: click its cell to render it", 404)
        return path


def _mark_medians(runs: list[ExploredRun]) -> list[ExploredRun]:
    """`runs` with the run of each task's schedule (of two runs or more) that the report shows
    marked: the median final score by the task's default metric (`median_run`)."""
    groups: dict[tuple[str, str], list[ExploredRun]] = {}
    for run in runs:
        groups.setdefault((run.record.task, run.record.schedule), []).append(run)
    medians: dict[Path, str] = {}
    for (task, schedule), group in groups.items():
        if len(group) >= 2:
            metric = task_spec(task).default_metric
            chosen = median_run([run.record for run in group], metric)
            medians[chosen.directory] = f"{schedule}'s {len(group)} runs by {metric}"
    return [replace(run, median_of=medians.get(run.record.directory, "")) for run in runs]


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(float(value)) else None


def _finite_or_none(values: np.ndarray) -> list[float | None]:
    return [round(float(v), 4) if math.isfinite(float(v)) else None for v in np.asarray(values).reshape(-1)]


def create_app(explorer: Explorer) -> Flask:
    """The Flask app that serves the page, the runs' data and the cached gaits, and nothing
    else: every other path is a 404, a malformed request a 400 with its reason as JSON."""
    from flask import Flask, jsonify, request, send_file
    from werkzeug.exceptions import HTTPException

    from smol_dsl.results.explorer_page import explorer_page

    app = Flask("smol-dsl-explore")
    app.json.sort_keys = False  # type: ignore[attr-defined]

    @app.get("/")
    def page() -> Any:
        return explorer_page(), 200, {"Content-Type": "text/html; charset=utf-8", "Cache-Control": "no-store"}

    @app.get("/api/runs")
    def runs() -> Any:
        return jsonify(explorer.run_list())

    @app.get("/api/runs/<number>")
    def run(number: str) -> Any:
        return jsonify(explorer.run_data(number))

    @app.get("/api/runs/<number>/gait")
    def gait(number: str) -> Any:
        return jsonify(explorer.gait(number, request.args.get("cell", ""), request.args.getlist("body")))

    @app.get("/gaits/<name>")
    def gait_image(name: str) -> Any:
        return send_file(explorer.gait_file(name), mimetype="image/gif", max_age=3600)

    @app.errorhandler(RequestError)
    def refused(error: RequestError) -> Any:
        return jsonify({"error": str(error)}), error.status

    @app.errorhandler(HTTPException)
    def http_error(error: HTTPException) -> Any:
        return jsonify({"error": error.description}), error.code

    @app.errorhandler(RenderError)
    def render_error(error: RenderError) -> Any:
        return jsonify({"error": str(error)}), 503

    @app.errorhandler(Exception)
    def internal(error: Exception) -> Any:  # never a traceback to the browser, never a stopped server
        return jsonify({"error": f"internal error: {type(error).__name__}: {error}"}), 500

    return app
