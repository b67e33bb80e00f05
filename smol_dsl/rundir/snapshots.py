"""phases.npz: a run's archive at every phase's start and end, without its policies, so that
what each change of body did to the archive (the collapse at a boundary, the refill after
it) can be seen after the run (`smol-dsl explore`, the report's maps).

A snapshot is every cell's fitness (-inf where empty) and descriptor (and, for a paced run,
the body its clocks had reached: `bodies`), taken after the
initial population and after each boundary's re-evaluation (`START`: the phase's first
archive) and before each boundary and at the end of training (`END`: the phase's last).
The runner rewrites the file atomically at every boundary (`write_snapshots`); on resume it
keeps the snapshots up to the checkpoint's generation (`snapshots_until`), so that a
resumed run writes the file an uninterrupted one writes, bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smol_dsl.rundir.files import write_npz
from smol_dsl.rundir.layout import SNAPSHOTS_FILE, RunDirectoryError, leave_out

START, END = 0, 1
"""A snapshot's `moment` in its phase: its first archive (after the initial population or
the boundary's re-evaluation) or its last (before the next boundary, or the final archive)."""
SNAPSHOT_ARRAYS = ("generation", "phase", "moment", "fitnesses", "descriptors")
BODIES = "bodies"
"""A paced run's phases.npz also holds each snapshot's body (its schedule's channels)."""


@dataclass(frozen=True)
class Snapshot:
    """One run's archive at a moment of a phase: (C,) fitnesses, (C, D) descriptors, and for
    a paced run the body it had reached."""

    generation: int  # generations trained when it was taken
    phase: int
    moment: int  # START or END
    fitnesses: np.ndarray
    descriptors: np.ndarray
    body: np.ndarray | None = None
    """A paced run's body then, (channels,) of its schedule (None: its schedule's phase's)."""

    @property
    def filled(self) -> np.ndarray:
        return self.fitnesses > -np.inf


def write_snapshots(directory: Path, snapshots: Sequence[Snapshot]) -> None:
    """Write phases.npz into a run directory (atomically), every snapshot in order (and a
    paced run's `bodies`, (snapshots, channels), where every snapshot has one)."""
    arrays = {
        "generation": np.asarray([s.generation for s in snapshots], dtype=np.int64),
        "phase": np.asarray([s.phase for s in snapshots], dtype=np.int32),
        "moment": np.asarray([s.moment for s in snapshots], dtype=np.int8),
        "fitnesses": np.stack([np.asarray(s.fitnesses, np.float32) for s in snapshots]),
        "descriptors": np.stack([np.asarray(s.descriptors, np.float32) for s in snapshots]),
    }
    if snapshots and all(s.body is not None for s in snapshots):
        arrays[BODIES] = np.stack([np.asarray(s.body, np.float32) for s in snapshots])
    write_npz(Path(directory) / SNAPSHOTS_FILE, arrays)


class SnapshotsError(RunDirectoryError):
    """A phases.npz that cannot be read: its `path` and the `reason`; the message says what to
    do for the commands that read it (report, explore); resuming says its own."""

    def __init__(self, path: Path, reason: str) -> None:
        self.path, self.reason = path, reason
        super().__init__(
            f"{path}: {reason}; remove it (the run's archives through its phases are then not shown), or rerun "
            f"the run, {leave_out(path.parent)}"
        )


def read_snapshots(directory: Path) -> list[Snapshot]:
    """A run directory's phases.npz, in order ([] where there is none); one that cannot be
    read (cut short, damaged, arrays missing or of shapes that disagree) is a
    SnapshotsError naming it and what to do."""
    path = Path(directory) / SNAPSHOTS_FILE
    if not path.is_file():
        return []
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: np.asarray(data[name]) for name in SNAPSHOT_ARRAYS}
            bodies = np.asarray(data[BODIES]) if BODIES in data.files else None
    except OSError as error:
        raise SnapshotsError(path, f"cannot be read ({error.strerror or error})") from None
    except Exception as error:  # zipfile.BadZipFile, EOFError, zlib.error, ValueError...: cut short or damaged
        raise SnapshotsError(
            path,
            f"not a readable phases file ({type(error).__name__}: {error}); it is damaged or cut short (a full disk, "
            "or an unfinished copy)",
        ) from None
    count = len(arrays["generation"]) if arrays["generation"].ndim == 1 else -1
    fitnesses, descriptors = arrays["fitnesses"], arrays["descriptors"]
    shapes = fitnesses.ndim == 2 and descriptors.ndim == 3 and descriptors.shape[:2] == fitnesses.shape
    if any(values.ndim < 1 or len(values) != count for values in arrays.values()) or not shapes:
        raise SnapshotsError(path, "its arrays do not agree in length or shape")
    if bodies is not None and (bodies.ndim != 2 or len(bodies) != count):
        raise SnapshotsError(path, "its bodies do not agree in length or shape with its snapshots")
    return [
        Snapshot(int(g), int(p), int(m), f, d, None if bodies is None else bodies[i])
        for i, (g, p, m, f, d) in enumerate(zip(*(arrays[name] for name in SNAPSHOT_ARRAYS), strict=True))
    ]


def snapshots_until(snapshots: Sequence[Snapshot], generation: int) -> list[Snapshot]:
    """The snapshots taken by `generation` (a checkpoint's): what a run resumed from it has
    written already; later ones (written before an interruption that lost their checkpoint)
    are taken again."""
    return [snapshot for snapshot in snapshots if snapshot.generation <= generation]
