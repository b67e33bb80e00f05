"""Gaits: an archive's elites chosen (a cell, the nearest to a descriptor, or spread over
the archive), rolled out in a body and drawn by MuJoCo's renderer.

`render_gaits(run, archive, cells, bodies, replay=...)` draws elites of a finished run as
`replay` rolls them out (`smol_dsl.rescoring.replay.replay_elites`, which the caller hands down:
the runner's own rollout, the run's episode start, a body of its schedule), with
`mujoco.Renderer` through the model's tracking camera: a `Gait` (its frames, fitness and
descriptor) per elite and body, which `smol_dsl.results.gait_video` tiles and writes.

Frames are the environment's steps, subsampled so that every frame lasts at least 20 ms and a
whole number of 10 ms (GIF delays are centiseconds; browsers slow down shorter ones): the
gaits play in real time. Without a display the GL backend is chosen before MuJoCo loads one:
`MUJOCO_GL` if set, else EGL, then OSMesa, each tried in a subprocess (`gl_backend`).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from smol_dsl.errors import UserInputError

if TYPE_CHECKING:
    from smol_dsl.rundir.archive import Archive
    from smol_dsl.rundir.record import RunRecord

GL_BACKENDS = ("egl", "osmesa")
GL_PACKAGES = {"egl": "libegl1 libgl1-mesa-dri", "osmesa": "libosmesa6"}
MIN_FRAME_MS = 20.0
FRAME_UNIT_MS = 10.0  # GIF delays are whole centiseconds
_PROBE = (
    "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=\"1\"/></worldbody></mujoco>')\n"
    "r = mujoco.Renderer(m, 8, 8); d = mujoco.MjData(m); mujoco.mj_forward(m, d)\n"
    "r.update_scene(d); r.render(); r.close()"
)


class RenderError(UserInputError):
    """A gait that cannot be rendered: a bad cell or body, a run without an archive, no GL."""


class ReplayElites(Protocol):
    """How `render_gaits` has elites rolled out: `smol_dsl.rescoring.replay.replay_elites`,
    handed down by the caller, since rolling out needs the runner's engine. It returns `model`
    (the task's MuJoCo model), `dt` (seconds per environment step), `inexact` (why fitnesses
    may differ from the archive's by rounding, or None) and, by (cell, the body's index),
    `rollouts`: each with `fitness`, `descriptor`, `poses` (the episode start's positions, then
    every step's until the episode ends) and `scored` (the poses' rollout reached the scored
    fitness, bit for bit)."""

    def __call__(
        self,
        run: RunRecord,
        archive: Archive,
        cells: Sequence[int],
        bodies: Sequence[tuple[str, dict[str, float]]],
        *,
        steps: int | None = None,
    ) -> Any: ...


@dataclass(frozen=True)
class Gait:
    """One elite rolled out in one body: what the tile shows and the figures printed beside it."""

    cell: int
    physics: str  # what simulated it: "spring" or "mjx" (the run's)
    body_label: str  # "final", "phase 3", or "given"
    body: dict[str, float]  # the factor of each of the schedule's channels
    fitness: float  # the replay's, over the run's episode, in this body
    archive_fitness: float  # the archive's (scored in the final body)
    descriptor: np.ndarray
    frames: list[np.ndarray]  # (height, width, 3) uint8 each
    frame_ms: float
    frames_scored: bool = True  # the frames' rollout reached the scored fitness, bit for bit
    inexact: str | None = None  # why the fitness may differ from the archive's by rounding; None: replayed exactly

    @property
    def label(self) -> str:
        return " · ".join(self.label_lines)

    @property
    def label_lines(self) -> tuple[str, str]:
        """The tile's label: the elite, its body and the physics; the factors and its fitness."""
        factors = ", ".join(f"{name} {value:.3g}" for name, value in self.body.items())
        return f"cell {self.cell} · {self.body_label} body · {self.physics}", f"{factors} · fitness {self.fitness:.2f}"


def gl_backend() -> str:
    """The GL backend MuJoCo renders with, set in `MUJOCO_GL` before MuJoCo is imported:
    the user's choice, else the first of EGL and OSMesa that renders in a subprocess."""
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    if chosen:
        return chosen
    failures = []
    for backend in GL_BACKENDS:
        probe = subprocess.run(
            [sys.executable, "-c", _PROBE],
            env={**os.environ, "MUJOCO_GL": backend, "PYOPENGL_PLATFORM": backend},
            capture_output=True,
            text=True,
            timeout=120,
        )
        if probe.returncode == 0:
            if "mujoco" in sys.modules:
                _switch_loaded_mujoco(backend)
            os.environ["MUJOCO_GL"] = backend
            return backend
        last = (probe.stderr.strip().splitlines() or ["failed"])[-1]
        failures.append(f"{backend}: {last}")
    packages = " ".join(GL_PACKAGES.values())
    raise RenderError(
        f"no OpenGL backend for MuJoCo's renderer on this machine ({'; '.join(failures)}); install one, "
        f"e.g. on Debian or Ubuntu `apt-get install {packages}` (software rendering, no display or GPU "
        "needed), or set MUJOCO_GL to a backend that works here"
    )


def _switch_loaded_mujoco(backend: str) -> None:
    """Point an already imported MuJoCo at `backend` (it read `MUJOCO_GL` when imported)."""
    from mujoco.rendering.classic import gl_context

    os.environ["PYOPENGL_PLATFORM"] = backend
    if backend == "egl":
        from mujoco.egl import GLContext
    else:
        from mujoco.osmesa import GLContext
    gl_context.GLContext = GLContext


def frame_stride(dt: float) -> int:
    """Environment steps per frame: the fewest that last at least MIN_FRAME_MS, preferring a
    whole number of FRAME_UNIT_MS (so GIF delays are exact) within four times that."""
    step_ms = dt * 1000.0
    first = max(1, math.ceil(MIN_FRAME_MS / step_ms - 1e-9))
    for stride in range(first, 4 * first + 1):
        if abs(stride * step_ms / FRAME_UNIT_MS - round(stride * step_ms / FRAME_UNIT_MS)) < 1e-6:
            return stride
    return first


# ---------------------------------------------------------------------------------- choosing
def nearest_cell(archive: Archive, descriptor: Sequence[float]) -> tuple[int, float]:
    """The filled cell whose elite's descriptor is nearest `descriptor`, and its distance;
    a RenderError for a point of another dimension or with a value that is not finite."""
    shown = ",".join(str(x) for x in descriptor)
    point = np.asarray(descriptor, dtype=np.float64)
    if point.shape != archive.descriptors.shape[1:]:
        raise RenderError(
            f"--at {shown}: this archive's descriptors have {archive.descriptors.shape[1]} value(s), comma-separated"
        )
    if not np.isfinite(point).all():
        raise RenderError(f"--at {shown}: give finite descriptor values, e.g. --at {','.join(['0.5'] * point.size)}")
    filled = np.flatnonzero(archive.filled)
    distances = np.linalg.norm(archive.descriptors[filled] - point, axis=1)
    nearest = int(np.argmin(distances))
    return int(filled[nearest]), float(distances[nearest])


def spread_cells(archive: Archive, count: int) -> list[int]:
    """`count` filled cells spread over the archive: the best, then each next the filled cell
    farthest (in descriptor space) from those chosen; a RenderError if it holds fewer."""
    filled = np.flatnonzero(archive.filled)
    if count > len(filled):
        raise RenderError(
            f"--cells {count}: the archive holds {len(filled)} elite(s); give --cells {len(filled)} or fewer"
        )
    chosen = [archive.best_cell]
    while len(chosen) < count:
        gaps = np.min(
            np.linalg.norm(archive.descriptors[filled][:, None] - archive.descriptors[chosen][None], axis=2), axis=1
        )
        chosen.append(int(filled[np.argmax(gaps)]))
    return chosen


def check_cell(archive: Archive, cell: int, directory: Path) -> int:
    cells = len(archive.fitnesses)
    if not 0 <= cell < cells:
        raise RenderError(f"--cell {cell}: {directory}'s archive has cells 0 to {cells - 1}")
    if not archive.filled[cell]:
        best = archive.best_cell
        raise RenderError(f"--cell {cell}: that cell of {directory}'s archive is empty; the best elite is in {best}")
    return cell


def resolve_bodies(specs: Sequence[str], run: RunRecord) -> list[tuple[str, dict[str, float]]]:
    """Each of `specs` (`resolve_body`), the run's phase bodies computed once; a body given
    twice, or factors outside what the run's task's physics takes (`TaskSpec.body_problem`,
    as `check --task` proves schedules), is refused."""
    from smol_dsl.language.channels import Channel
    from smol_dsl.tasks import task_spec

    names, bodies = tuple(channel.name for channel in run.channels), run.phase_bodies()
    resolved = []
    for index, spec in enumerate(specs):
        if spec.strip() in (earlier.strip() for earlier in specs[:index]):
            raise RenderError(f"--body {spec} is given twice; give each body once")
        label, body = resolve_body(spec, names, bodies)
        factors = {Channel.parse(name): value for name, value in body.items()}
        problem = task_spec(run.task).body_problem(factors, run.config.physics)
        if problem is not None:
            raise RenderError(f"--body {spec}: {problem}")
        resolved.append((label, body))
    return resolved


def resolve_body(spec: str, names: Sequence[str], bodies: np.ndarray) -> tuple[str, dict[str, float]]:
    """`final`, `phase:K`, or factors for the channels `names` in order (comma-separated),
    given the body of every phase (`phase_bodies`): the label and the factor of every channel."""
    text = spec.strip()
    if text == "final":
        return "final", dict(zip(names, bodies[-1].tolist(), strict=True))
    if text.startswith("phase:"):
        try:
            phase = int(text.removeprefix("phase:"))
        except ValueError:
            phase = -1
        if not 0 <= phase < len(bodies):
            raise RenderError(f"--body {spec}: the run has phases 0 to {len(bodies) - 1}, e.g. --body phase:0")
        return f"phase {phase}", dict(zip(names, bodies[phase].tolist(), strict=True))
    try:
        factors = [float(part) for part in text.split(",")]
    except ValueError:
        factors = []
    if len(factors) != len(names) or not all(math.isfinite(f) and f > 0 for f in factors):
        raise RenderError(
            f"--body {spec}: give `final`, `phase:K`, or {len(names)} factor(s) above 0, comma-separated, for "
            f"the schedule's channel(s) {', '.join(names)} (e.g. --body {','.join(['1'] * len(names))})"
        )
    return "given", dict(zip(names, factors, strict=True))


# ---------------------------------------------------------------------------------- rendering
def render_gaits(
    run: RunRecord,
    archive: Archive,
    cells: Sequence[int],
    bodies: Sequence[tuple[str, dict[str, float]]],
    *,
    replay: ReplayElites,
    steps: int | None = None,
    size: tuple[int, int] = (320, 240),
) -> list[Gait]:
    """Every cell in every body (cells × bodies), drawn `size` (width, height) pixels.

    The fitness and descriptor are `replay`'s: the program that scored the archive, each
    elite in its lane, so in the body the archive was scored in they are the archive's, bit
    for bit, where that program can be built again (`Gait.inexact` says why not). The frames
    come from the same rollout compiled to record positions; `steps` (default: the run's
    episode length) renders a longer or shorter episode than the one scored."""
    gl_backend()  # before the replay loads MuJoCo
    replayed = replay(run, archive, cells, bodies, steps=steps)
    stride = frame_stride(replayed.dt)
    gaits = []
    with _Renderer(replayed.model, size) as draw:
        for cell in cells:
            for index, (label, body) in enumerate(bodies):
                rollout = replayed.rollouts[cell, index]
                gaits.append(
                    Gait(
                        cell=int(cell),
                        physics=run.config.physics,
                        body_label=label,
                        body=body,
                        fitness=rollout.fitness,
                        archive_fitness=float(archive.fitnesses[cell]),
                        descriptor=rollout.descriptor,
                        frames=[draw(pose) for pose in rollout.poses[::stride]],
                        frame_ms=stride * replayed.dt * 1000.0,
                        frames_scored=rollout.scored,
                        inexact=replayed.inexact,
                    )
                )
    return gaits


class _Renderer:
    """MuJoCo's renderer of a task's model, through its tracking camera where it has one;
    called with a pose `q`, returns the image; closed on exit."""

    def __init__(self, model: Any, size: tuple[int, int]) -> None:
        import mujoco

        self._mujoco = mujoco
        self.model = model
        names = [self.model.camera(i).name for i in range(self.model.ncam)]
        self.camera = "track" if "track" in names else -1
        width, height = size
        visual = self.model.vis.global_  # MuJoCo's offscreen framebuffer (640x480 unless the model says more)
        visual.offwidth, visual.offheight = max(visual.offwidth, width), max(visual.offheight, height)
        self.renderer = mujoco.Renderer(self.model, height=height, width=width)
        self.data = mujoco.MjData(self.model)

    def __enter__(self) -> Any:
        return self

    def __call__(self, q: np.ndarray) -> np.ndarray:
        self.data.qpos[:] = q
        self._mujoco.mj_forward(self.model, self.data)
        self.renderer.update_scene(self.data, camera=self.camera)
        return np.array(self.renderer.render())

    def __exit__(self, *_: object) -> None:
        self.renderer.close()
