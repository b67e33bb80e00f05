"""Atomic checkpoints of runs trained together, and the final archive's `.npz` layout.

One format for `run` and `sweep`: the archives of R runs stacked along a runs axis (R = 1
for a run directory's checkpoint.npz), each run's key, and its progress (counters and
metrics rows) as JSON.

A checkpoint is written to a temporary file in the run directory, flushed to disk and
renamed over the previous one, so a run killed at any moment leaves either the old or the
new checkpoint, never a torn one. Runs hand their checkpoints to a `CheckpointWriter`,
which writes them in the background: at paper scale a sweep's checkpoint holds tens of GB
of archives, and training goes on while it reaches the disk.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import threading
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire

from smol_dsl.qdax.scoring import LANE
from smol_dsl.rundir import LANES, write_npz
from smol_dsl.runner.config import RunError

KEYS = "keys"


def _leaf_names(tree: Any) -> list[str]:
    paths = jax.tree_util.tree_flatten_with_path(tree)[0]
    return ["/".join(_key_name(k) for k in path) for path, _ in paths]


def _key_name(key: Any) -> str:
    for attribute in ("key", "name", "idx"):
        if hasattr(key, attribute):
            return str(getattr(key, attribute))
    return str(key)


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


def host_copy(leaf: Any, rows: int | slice | None = None) -> np.ndarray:
    """A device array's values in host memory that nothing else writes to, made with one
    host copy: all of them, or the rows along the leading axis that `rows` selects (the
    first `rows`, or a slice with step 1).

    On a CPU, `np.asarray` of a JAX array can be a view of the device buffer, which the next
    generation reuses (its archive is donated); a checkpoint written in the background needs
    its own copy. For an array split over several devices, `np.asarray` would assemble a
    host array and keep it cached on the JAX array for as long as that lives (a second host
    copy of every archive); so the copy is filled shard by shard instead, each shard read
    as a view on a CPU (or transferred alone from an accelerator).
    """
    if isinstance(rows, int):
        rows = slice(0, rows)
    if not isinstance(leaf, jax.Array):
        array = np.asarray(leaf)
        return np.array(array[rows] if rows is not None and array.ndim else array)
    if rows is None or not leaf.ndim:
        low, high = 0, leaf.shape[0] if leaf.ndim else 0
    else:
        low, high, _ = rows.indices(leaf.shape[0])
    copy = np.empty((max(high - low, 0), *leaf.shape[1:]) if leaf.ndim else (), dtype=leaf.dtype)
    copied: set[tuple] = set()
    for shard in leaf.addressable_shards:
        bounds = tuple(part.indices(size)[:2] for part, size in zip(shard.index, leaf.shape, strict=True))
        if bounds in copied:  # a replica of a shard already copied
            continue
        copied.add(bounds)
        if not leaf.ndim:
            copy[...] = np.asarray(shard.data)
            continue
        (first, last), rest = bounds[0], bounds[1:]
        start, stop = max(first, low), min(last, high)
        if start < stop:  # some of its rows are kept
            values = np.asarray(shard.data)[start - first : stop - first]
            copy[(slice(start - low, stop - low), *(slice(*b) for b in rest))] = values
    return copy


def archive_arrays(repertoire: MapElitesRepertoire, runs: int | slice | None = None) -> dict[str, np.ndarray]:
    """An archive's arrays by name (`genotypes/<param path>`, fitnesses, descriptors,
    centroids), copied to host memory; of stacked archives, the runs that `runs` selects
    (`host_copy`'s rows) only."""
    genotypes = repertoire.genotypes
    arrays = {
        f"genotypes/{name}": host_copy(leaf, runs)
        for name, leaf in zip(_leaf_names(genotypes), jax.tree.leaves(genotypes), strict=True)
    }
    arrays["fitnesses"] = host_copy(repertoire.fitnesses, runs)
    arrays["descriptors"] = host_copy(repertoire.descriptors, runs)
    arrays["centroids"] = host_copy(repertoire.centroids, runs)
    if LANE in repertoire.extra_scores:
        arrays[LANES] = host_copy(repertoire.extra_scores[LANE], runs)
    return arrays


def _repertoire_from(data: Any, genotype_template: Any) -> MapElitesRepertoire:
    """The archive saved by `archive_arrays`, its genotypes shaped like the template's; the
    lanes of a checkpoint written before archives kept them are unknown (-1)."""
    leaves = [jax.numpy.asarray(data[f"genotypes/{name}"]) for name in _leaf_names(genotype_template)]
    fitnesses = jax.numpy.asarray(data["fitnesses"])
    lanes = data[LANES] if LANES in data.files else np.full(fitnesses.shape[: -1 if fitnesses.ndim > 2 else None], -1)
    return MapElitesRepertoire(
        genotypes=jax.tree.unflatten(jax.tree.structure(genotype_template), leaves),
        fitnesses=fitnesses,
        descriptors=jax.numpy.asarray(data["descriptors"]),
        centroids=jax.numpy.asarray(data["centroids"]),
        extra_scores={LANE: jax.numpy.asarray(lanes, dtype=jax.numpy.int32)},
        keys_extra_scores=(LANE,),
    )


def _progress(state: RunState) -> dict[str, Any]:
    return dataclasses.asdict(state)


class CheckpointWriter:
    """Writes checkpoints atomically in a background thread, one at a time.

    Training goes on while a checkpoint reaches the disk; it waits only for the copy of the
    archives to host memory. A checkpoint `offer`ed while the previous one is still being
    written is skipped (a resumed run restarts from an earlier boundary, with the same
    results). `flush` waits for the write in flight and raises its error, if any; training
    flushes before each re-evaluation (so that the host copy is gone before the archives
    are held twice) and before it returns, also when interrupted, so that its last
    checkpoint is whole on disk.

    >>> writer = CheckpointWriter()
    >>> writer.offer(path, lambda: checkpoint_arrays(archives, keys, states))  # doctest: +SKIP
    True
    >>> writer.flush()
    """

    def __init__(self, background: bool = True) -> None:
        self.background = background
        self.written = 0
        self.skipped = 0
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    def writing(self) -> bool:
        """Whether a checkpoint is being written now."""
        return self._thread is not None and self._thread.is_alive()

    def offer(self, path: Path, arrays: Callable[[], dict[str, np.ndarray]]) -> bool:
        """Write the checkpoint `arrays()` copies to host memory, unless a write is still in
        flight: then skip it and return False."""
        if self.writing():
            self.skipped += 1
            return False
        self.flush()
        host_arrays = arrays()
        if not self.background:
            self._write(path, host_arrays)
        else:
            self._thread = threading.Thread(
                target=self._write, args=(path, host_arrays), name=f"smol-dsl {path.name}", daemon=True
            )
            self._thread.start()
        return True

    def __enter__(self) -> CheckpointWriter:
        return self

    def __exit__(self, kind: Any, error: BaseException | None, traceback: Any) -> None:
        try:
            self.flush()
        except BaseException:
            if error is None:
                raise  # otherwise the error that is leaving the run says more

    def flush(self) -> None:
        """Wait for the write in flight; raise its error, if it failed: a RunError that names
        the file and says that the last checkpoint is intact, for a disk that could not be
        written (the write's temporary file is removed and the previous checkpoint kept)."""
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        error, self._error = self._error, None
        if error is not None:
            raise error

    def _write(self, path: Path, arrays: dict[str, np.ndarray]) -> None:
        try:
            write_npz(path, arrays)
            self.written += 1
        except OSError as error:  # raised in the training thread by flush()
            self._error = storage_error(error, path, fallback=path)
        except BaseException as error:
            self._error = error


_FULL = {errno.ENOSPC, errno.EDQUOT}
_NOT_WRITABLE = {errno.EROFS, errno.EACCES, errno.EPERM}


def write_failure(error: OSError, fallback: Path | None = None) -> tuple[str, str, str]:
    """(the file, the reason, what to do) for an OSError from writing a file."""
    target = str(error.filename) if error.filename is not None else str(fallback or "a file")
    reason = error.strerror or str(error) or type(error).__name__
    if error.errno in _FULL:
        fix = "free some space"
    elif error.errno in _NOT_WRITABLE:
        fix = "make it writable"
    else:
        fix = "fix that"
    return target, reason, fix


def storage_error(error: OSError, checkpoint: Path | None, fallback: Path | None = None) -> RunError:
    """The RunError for a file a run or sweep could not write (a full disk, a read-only file
    system): it names the file (the error's, else `fallback`) and the reason, and says whether
    `checkpoint` - the last one, which atomic writes never tear - is there to `--resume` from."""
    target, reason, fix = write_failure(error, fallback)
    if checkpoint is not None and checkpoint.is_file():
        then = (
            f"the last checkpoint, {checkpoint}, is intact: {fix}, then run the same command with --resume "
            "to continue from it"
        )
    else:
        then = f"nothing was checkpointed yet: {fix}, then run the same command with --resume to start over"
    return RunError(f"cannot write {target}: {reason}; {then}")


def damaged_checkpoint(path: Path, problem: str) -> RunError:
    return RunError(
        f"{path} cannot be resumed from: {problem}. Checkpoints are written whole, so it was changed "
        "outside smol-dsl (a partial copy, a disk error, a file from another run): put back this run's own "
        f"checkpoint, or delete {path.name} and run the same command with --resume to start the run over"
    )


def _load(
    path: Path,
    genotype_template: Any,
    layout: tuple[int | None, ...],
    descriptors: int | None,
    owner: dict[str, Any] | None = None,
) -> tuple[MapElitesRepertoire, jax.Array, Any] | None:
    """An archive, its key(s) and the progress JSON saved at path, or None if there is none.

    `layout` is the leading axes every archive array must have, (runs, cells);
    `descriptors` the descriptor dimension. A file that cannot be read as
    such a checkpoint (truncated, corrupted, from another task) is a RunError naming it, and
    so is one whose recorded `owner` is not the given one (copied from another run).
    """
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            _check_layout(path, data, genotype_template, layout, descriptors)
            if owner is not None and "owner" in data.files:  # a checkpoint that names no owner is not checked
                _check_owner(path, json.loads(str(data["owner"])), owner)
            repertoire = _repertoire_from(data, genotype_template)
            key = jax.random.wrap_key_data(jax.numpy.asarray(data[KEYS]))
            return repertoire, key, json.loads(str(data["progress"]))
    except (ValueError, KeyError, EOFError, TypeError, IndexError, zipfile.BadZipFile) as error:
        raise damaged_checkpoint(path, f"it is damaged ({type(error).__name__}: {error})") from None
    except OSError as error:
        if error.errno is not None:  # could not be read (permissions, I/O): the OS's own error
            raise
        raise damaged_checkpoint(path, f"it is damaged ({error})") from None


def _check_layout(
    path: Path, data: Any, template: Any, layout: tuple[int | None, ...], descriptors: int | None
) -> None:
    """Refuse a checkpoint whose arrays are not shaped like this run's (another task, another
    policy network, another number of cells or runs): loading it would fail deep inside JAX.
    A None in `layout` takes the saved archive's size on that axis."""
    if "fitnesses" in data.files:
        saved = data["fitnesses"].shape
        layout = tuple(saved[i] if n is None and i < len(saved) else n for i, n in enumerate(layout))
    expected = {
        f"genotypes/{name}": layout + tuple(leaf.shape[1:])
        for name, leaf in zip(_leaf_names(template), jax.tree.leaves(template), strict=True)
    }
    expected["fitnesses"] = (*layout, 1)
    if LANES in data.files:  # written since archives keep every elite's lane
        expected[LANES] = layout
    expected["key_data"] = layout[:-1] + tuple(jax.random.key_data(jax.random.key(0)).shape)
    if descriptors is not None:
        expected["descriptors"] = expected["centroids"] = (*layout, descriptors)
    missing = sorted(set(expected) - {"key_data"} - set(data.files)) + ([] if KEYS in data.files else [KEYS])
    if "progress" not in data.files:
        missing.append("progress")
    if missing:
        raise damaged_checkpoint(
            path, f"it lacks {', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''} (is it from another task?)"
        )
    for name, shape in expected.items():
        actual = data[KEYS if name == "key_data" else name].shape
        if name == "fitnesses" and actual == layout:
            continue  # (cells,) is as good as (cells, 1)
        if actual != shape:
            shown = KEYS if name == "key_data" else name
            raise damaged_checkpoint(
                path,
                f"its {shown} has shape {actual}, but this one needs {shape} (is it from another task, or "
                "another run?)",
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


def checkpoint_arrays(
    repertoires: MapElitesRepertoire, keys: jax.Array, states: list[RunState], owner: dict[str, Any] | None = None
) -> dict[str, np.ndarray]:
    """A checkpoint of runs trained together (one, for `smol-dsl run`): the archives stacked
    along a runs axis (only the first len(states) runs: padding is not saved), each run's
    key, counters and metrics rows (all at the same generation), and `owner`, the runs it
    belongs to; copied to host memory."""
    runs = len(states)
    return stacked_checkpoint(
        archive_arrays(repertoires, runs), host_copy(jax.random.key_data(keys), runs), states, owner
    )


def stacked_checkpoint(
    archives: dict[str, np.ndarray], key_data: np.ndarray, states: list[RunState], owner: dict[str, Any] | None = None
) -> dict[str, np.ndarray]:
    """`checkpoint_arrays` of archives and keys already in host memory (`archive_arrays`
    of stacked archives, and the keys' `key_data`), one per state."""
    arrays = dict(archives)
    arrays["keys"] = key_data
    arrays["progress"] = np.asarray(json.dumps([_progress(state) for state in states]))
    if owner is not None:
        arrays["owner"] = np.asarray(json.dumps(owner))
    return arrays


def save_checkpoint(
    path: Path,
    repertoires: MapElitesRepertoire,
    keys: jax.Array,
    states: list[RunState],
    owner: dict[str, Any] | None = None,
) -> None:
    """Write a checkpoint atomically (now, not in the background)."""
    write_npz(path, checkpoint_arrays(repertoires, keys, states, owner))


def load_checkpoint(
    path: Path,
    genotype_template: Any,
    num_runs: int,
    num_cells: int | None,
    num_descriptors: int | None = None,
    owner: dict[str, Any] | None = None,
) -> tuple[MapElitesRepertoire, jax.Array, list[RunState]] | None:
    """The stacked archives, keys and per-run states saved by save_checkpoint for `num_runs`
    runs of `num_cells` cells, or None if there is none; a RunError for a damaged one, or
    one that other runs (`owner`) wrote."""
    loaded = _load(path, genotype_template, (num_runs, num_cells), num_descriptors, owner)
    if loaded is None:
        return None
    repertoires, keys, progress = loaded
    if not isinstance(progress, list) or len(progress) != num_runs:
        raise damaged_checkpoint(path, f"it does not hold progress for {num_runs} run{'s' if num_runs > 1 else ''}")
    try:
        return repertoires, keys, [RunState(**p) for p in progress]
    except (TypeError, AttributeError) as error:
        raise damaged_checkpoint(path, f"its progress record is damaged ({error})") from None
