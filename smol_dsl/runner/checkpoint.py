"""Checkpoints of runs trained together: their archives and keys copied from the devices
into a checkpoint's arrays, written in the background, and loaded back onto the devices.

The file's format is the run directory's (`smol_dsl.rundir.checkpoint`: the archives of R
runs stacked along a runs axis, R = 1 for a run directory's checkpoint.npz, each run's key,
and its progress as JSON); this module moves the arrays between it and JAX.

A checkpoint is written to a temporary file in the run directory, flushed to disk and
renamed over the previous one, so a run killed at any moment leaves either the old or the
new checkpoint, never a torn one. Runs hand their checkpoints to a `CheckpointWriter`,
which writes them in the background: at paper scale a sweep's checkpoint holds tens of GB
of archives, and training goes on while it reaches the disk.
"""

from __future__ import annotations

import errno
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire

from smol_dsl.qdax.scoring import LANE
from smol_dsl.rundir import GENOTYPES, LANES, write_npz
from smol_dsl.rundir.checkpoint import KEYS, RunState, checkpoint_contents, open_checkpoint
from smol_dsl.runner.config import RunError


def _leaf_names(tree: Any) -> list[str]:
    paths = jax.tree_util.tree_flatten_with_path(tree)[0]
    return ["/".join(_key_name(k) for k in path) for path, _ in paths]


def _key_name(key: Any) -> str:
    for attribute in ("key", "name", "idx"):
        if hasattr(key, attribute):
            return str(getattr(key, attribute))
    return str(key)


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
        f"{GENOTYPES}{name}": host_copy(leaf, runs)
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
    leaves = [jnp.asarray(data[f"{GENOTYPES}{name}"]) for name in _leaf_names(genotype_template)]
    fitnesses = jnp.asarray(data["fitnesses"])
    lanes = data[LANES] if LANES in data else np.full(fitnesses.shape[: -1 if fitnesses.ndim > 2 else None], -1)
    return MapElitesRepertoire(
        genotypes=jax.tree.unflatten(jax.tree.structure(genotype_template), leaves),
        fitnesses=fitnesses,
        descriptors=jnp.asarray(data["descriptors"]),
        centroids=jnp.asarray(data["centroids"]),
        extra_scores={LANE: jnp.asarray(lanes, dtype=jax.numpy.int32)},
        keys_extra_scores=(LANE,),
    )


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


def checkpoint_arrays(
    repertoires: MapElitesRepertoire, keys: jax.Array, states: list[RunState], owner: dict[str, Any] | None = None
) -> dict[str, np.ndarray]:
    """A checkpoint of runs trained together (one, for `smol-dsl run`): the archives stacked
    along a runs axis (only the first len(states) runs: padding is not saved), each run's
    key, counters and metrics rows (all at the same generation), and `owner`, the runs it
    belongs to; copied to host memory."""
    runs = len(states)
    return checkpoint_contents(
        archive_arrays(repertoires, runs), host_copy(jax.random.key_data(keys), runs), states, owner
    )


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
    runs of `num_cells` cells (None: as saved), shaped like `genotype_template`'s policies,
    or None if there is none; a RunDirectoryError for a damaged one, or one that other runs
    (`owner`) wrote."""
    genotypes = {
        name: tuple(leaf.shape[1:])
        for name, leaf in zip(_leaf_names(genotype_template), jax.tree.leaves(genotype_template), strict=True)
    }
    key_shape = tuple(jax.random.key_data(jax.random.key(0)).shape)
    with open_checkpoint(path, genotypes, (num_runs, num_cells), num_descriptors, key_shape, owner) as saved:
        if saved is None:
            return None
        data, states = saved
        return _repertoire_from(data, genotype_template), jax.random.wrap_key_data(jnp.asarray(data[KEYS])), states
