"""A checkpoint's file: the state of runs trained together at a phase boundary, one format for
`run` (checkpoint.npz, one run) and `sweep` (`sweep_checkpoint_file`, every run of a process).

Its arrays: the archives stacked along a runs axis (archive.npz's names: `genotypes/<param
path>`, fitnesses, descriptors, centroids, lanes), `keys` (each run's key data), `progress`
(JSON: each run's `RunState`) and `owner` (JSON: the runs it belongs to). `open_checkpoint`
checks a file against the shapes its reader needs and the owner it expects before anything
is loaded: a truncated or foreign file is a RunDirectoryError that names it and says what
to do, not an error deep inside JAX. Host arrays only: the runner puts them on devices.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smol_dsl.rundir.archive import GENOTYPES, LANES
from smol_dsl.rundir.layout import RunDirectoryError

KEYS = "keys"
PROGRESS = "progress"
OWNER = "owner"


@dataclass
class RunState:
    """One run's progress: what, besides its archive and key, it needs to continue exactly
    where it stopped (its counters and every metrics row so far)."""

    generation: int  # the last generation done (0: the initial population)
    phase: int
    evaluations: int
    reevaluations: int
    non_finite: int
    rows: list[dict[str, Any]]
    finished: bool = False


def checkpoint_contents(
    archives: Mapping[str, np.ndarray],
    key_data: np.ndarray,
    states: list[RunState],
    owner: dict[str, Any] | None = None,
) -> dict[str, np.ndarray]:
    """A checkpoint's arrays: stacked archives (archive.npz's names), one key's data and one
    `RunState` per run, and the runs it belongs to (`owner`)."""
    arrays = dict(archives)
    arrays[KEYS] = key_data
    arrays[PROGRESS] = np.asarray(json.dumps([dataclasses.asdict(state) for state in states]))
    if owner is not None:
        arrays[OWNER] = np.asarray(json.dumps(owner))
    return arrays


def damaged_checkpoint(path: Path, problem: str) -> RunDirectoryError:
    """The error of a checkpoint that cannot be resumed from, saying why and what to do."""
    return RunDirectoryError(
        f"{path} cannot be resumed from: {problem}. Checkpoints are written whole, so it was changed "
        "outside smol-dsl (a partial copy, a disk error, a file from another run): put back this run's own "
        f"checkpoint, or delete {path.name} and run the same command with --resume to start the run over"
    )


@contextlib.contextmanager
def open_checkpoint(
    path: Path,
    genotypes: Mapping[str, tuple[int, ...]],
    layout: tuple[int, int | None],
    descriptors: int | None,
    key_shape: tuple[int, ...],
    owner: dict[str, Any] | None = None,
) -> Iterator[tuple[Mapping[str, np.ndarray], list[RunState]] | None]:
    """A checkpoint, checked and open: its arrays by name (each read when taken, so that the
    reader holds one host copy at a time) and its runs' states; None if there is no file at
    `path`.

    The file must hold `layout[0]` runs of `layout[1]` cells each (None: as saved), every
    policy parameter of `genotypes` (path -> shape of one policy's), `descriptors`
    descriptors (None: any), keys of `key_shape` (a key's data) and, where it names one,
    `owner`. Anything else, or an array that cannot be read or used inside the `with`, is a
    RunDirectoryError naming the file (`damaged_checkpoint`).
    """
    if not path.is_file():
        yield None
        return
    try:
        with np.load(path, allow_pickle=False) as data:
            _check_layout(path, data, genotypes, layout, descriptors, key_shape)
            if owner is not None and OWNER in data.files:  # a checkpoint that names no owner is not checked
                _check_owner(path, json.loads(str(data[OWNER])), owner)
            states = _states(path, json.loads(str(data[PROGRESS])), layout[0])
            yield data, states
    except (ValueError, KeyError, EOFError, TypeError, IndexError, zipfile.BadZipFile) as error:
        raise damaged_checkpoint(path, f"it is damaged ({type(error).__name__}: {error})") from None
    except OSError as error:
        if error.errno is not None:  # could not be read (permissions, I/O): the OS's own error
            raise
        raise damaged_checkpoint(path, f"it is damaged ({error})") from None


def _states(path: Path, progress: Any, runs: int) -> list[RunState]:
    if not isinstance(progress, list) or len(progress) != runs:
        raise damaged_checkpoint(path, f"it does not hold progress for {runs} run{'s' if runs > 1 else ''}")
    try:
        return [RunState(**state) for state in progress]
    except (TypeError, AttributeError) as error:
        raise damaged_checkpoint(path, f"its progress record is damaged ({error})") from None


def _check_layout(
    path: Path,
    data: Any,
    genotypes: Mapping[str, tuple[int, ...]],
    layout: tuple[int, int | None],
    descriptors: int | None,
    key_shape: tuple[int, ...],
) -> None:
    """Refuse a checkpoint whose arrays are not shaped like this run's (another task, another
    policy network, another number of cells or runs)."""
    axes: tuple[int | None, ...] = layout
    if "fitnesses" in data.files:
        saved = data["fitnesses"].shape
        axes = tuple(saved[i] if n is None and i < len(saved) else n for i, n in enumerate(axes))
    expected = {f"{GENOTYPES}{name}": axes + tuple(shape) for name, shape in genotypes.items()}
    expected["fitnesses"] = (*axes, 1)
    if LANES in data.files:  # written since archives keep every elite's lane
        expected[LANES] = axes
    expected[KEYS] = axes[:-1] + tuple(key_shape)
    if descriptors is not None:
        expected["descriptors"] = expected["centroids"] = (*axes, descriptors)
    missing = sorted(set(expected) - {KEYS} - set(data.files)) + ([] if KEYS in data.files else [KEYS])
    if PROGRESS not in data.files:
        missing.append(PROGRESS)
    if missing:
        raise damaged_checkpoint(
            path, f"it lacks {', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''} (is it from another task?)"
        )
    for name, shape in expected.items():
        actual = data[name].shape
        if name == "fitnesses" and actual == axes:
            continue  # (cells,) is as good as (cells, 1)
        if actual != shape:
            raise damaged_checkpoint(
                path,
                f"its {name} has shape {actual}, but this one needs {shape} (is it from another task, or another run?)",
            )


def _check_owner(path: Path, saved: Any, owner: dict[str, Any]) -> None:
    if saved == owner:
        return
    differences = []
    if isinstance(saved, dict):
        for part in sorted(set(saved) | set(owner)):
            old, new = saved.get(part), owner.get(part)
            if isinstance(old, dict) and isinstance(new, dict):
                differences += [
                    f"{name} {_brief(old.get(name))}, not {_brief(new.get(name))}"
                    for name in sorted(set(old) | set(new))
                    if old.get(name) != new.get(name)
                ]
            elif old != new:
                differences.append(f"another {part}")
    shown = "; ".join(differences[:4]) or "another run"
    raise damaged_checkpoint(path, f"it was written by another run ({shown})")


def _brief(value: Any) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= 40 else text[:37] + "..."
