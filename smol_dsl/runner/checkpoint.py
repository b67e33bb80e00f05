"""Atomic checkpoints of a run, and the final archive's `.npz` layout.

A checkpoint is written to a temporary file in the run directory, flushed to disk and
renamed over the previous one, so a run killed at any moment leaves either the old or the
new checkpoint, never a torn one. Runs hand their checkpoints to a `CheckpointWriter`,
which writes them in the background: at paper scale a sweep's checkpoint holds tens of GB
of archives, and training goes on while it reaches the disk.
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire

CHECKPOINT = "checkpoint.npz"


def atomic_write(path: Path, write: Any) -> None:
    """Call write(file) on a temporary file, fsync it, and rename it over path."""
    temporary = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # processes may share a directory
    with open(temporary, "wb") as file:
        write(file)
        file.flush()
        os.fsync(file.fileno())
    os.replace(temporary, path)
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


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
    """Everything a run needs to continue exactly where it stopped."""

    repertoire: MapElitesRepertoire
    emitter_state: Any
    key: jax.Array
    generation: int  # the last generation done (0: the initial population)
    phase: int
    evaluations: int
    reevaluations: int
    non_finite: int
    rows: list[dict[str, Any]]
    finished: bool = False


def host_copy(leaf: Any) -> np.ndarray:
    """A device array's values in host memory that nothing else writes to.

    On a CPU, `np.asarray` of a JAX array can be a view of the device buffer, which the next
    generation reuses (its archive is donated); a checkpoint written in the background needs
    its own copy. From an accelerator, `np.asarray` already copies.
    """
    array = np.asarray(leaf)
    on_cpu = isinstance(leaf, jax.Array) and all(d.platform == "cpu" for d in leaf.sharding.device_set)
    return array.copy() if on_cpu else array


def _repertoire_arrays(repertoire: MapElitesRepertoire) -> dict[str, np.ndarray]:
    """An archive's arrays by name: `genotypes/<param path>`, fitnesses, descriptors, centroids."""
    genotypes = repertoire.genotypes
    arrays = {
        f"genotypes/{name}": host_copy(leaf)
        for name, leaf in zip(_leaf_names(genotypes), jax.tree.leaves(genotypes), strict=True)
    }
    arrays["fitnesses"] = host_copy(repertoire.fitnesses)
    arrays["descriptors"] = host_copy(repertoire.descriptors)
    arrays["centroids"] = host_copy(repertoire.centroids)
    return arrays


def _repertoire_from(data: Any, genotype_template: Any) -> MapElitesRepertoire:
    """The archive saved by _repertoire_arrays, its genotypes shaped like the template's."""
    leaves = [jax.numpy.asarray(data[f"genotypes/{name}"]) for name in _leaf_names(genotype_template)]
    return MapElitesRepertoire(
        genotypes=jax.tree.unflatten(jax.tree.structure(genotype_template), leaves),
        fitnesses=jax.numpy.asarray(data["fitnesses"]),
        descriptors=jax.numpy.asarray(data["descriptors"]),
        centroids=jax.numpy.asarray(data["centroids"]),
        extra_scores={},
        keys_extra_scores=(),
    )


def _progress(state: RunState) -> dict[str, Any]:
    return {
        "generation": state.generation,
        "phase": state.phase,
        "evaluations": state.evaluations,
        "reevaluations": state.reevaluations,
        "non_finite": state.non_finite,
        "finished": state.finished,
        "rows": state.rows,
    }


def _state(progress: dict[str, Any], repertoire: MapElitesRepertoire | None, key: jax.Array | None) -> RunState:
    return RunState(repertoire=repertoire, emitter_state=None, key=key, **progress)


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays atomically as an uncompressed `.npz`."""
    atomic_write(path, lambda file: np.savez(file, **arrays))


def checkpoint_arrays(state: RunState) -> dict[str, np.ndarray]:
    """A run's checkpoint: its archive, key and progress, copied to host memory."""
    if state.emitter_state is not None:
        raise NotImplementedError("only stateless emitters (iso+line) are checkpointed")
    arrays = _repertoire_arrays(state.repertoire)
    arrays["key"] = host_copy(jax.random.key_data(state.key))
    arrays["progress"] = np.asarray(json.dumps(_progress(state)))
    return arrays


def save_checkpoint(directory: Path, state: RunState) -> None:
    """Write the run's state atomically to directory/checkpoint.npz (now, not in the background)."""
    write_npz(directory / CHECKPOINT, checkpoint_arrays(state))


class CheckpointWriter:
    """Writes checkpoints atomically in a background thread, one at a time.

    Training goes on while a checkpoint reaches the disk; it waits only for the copy of the
    archives to host memory. A checkpoint `offer`ed while the previous one is still being
    written is skipped, so a slow disk makes checkpoints rarer instead of training slower
    (a resumed run restarts from an earlier boundary, with the same results). `flush` waits
    for the write in flight and raises its error, if any; runs flush before they return,
    also when interrupted, so their last checkpoint is whole on disk.

    >>> writer = CheckpointWriter()
    >>> writer.offer(directory / CHECKPOINT, lambda: checkpoint_arrays(state))  # doctest: +SKIP
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
        """Wait for the write in flight; raise its error, if it failed."""
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
        except BaseException as error:  # raised in the training thread by flush()
            self._error = error


def _load(path: Path, genotype_template: Any, key_field: str) -> tuple[MapElitesRepertoire, jax.Array, Any] | None:
    """An archive, its key(s) and the progress JSON saved at path, or None if there is none."""
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as data:
        repertoire = _repertoire_from(data, genotype_template)
        key = jax.random.wrap_key_data(jax.numpy.asarray(data[key_field]))
        return repertoire, key, json.loads(str(data["progress"]))


def load_checkpoint(directory: Path, genotype_template: Any) -> RunState | None:
    """The state saved in directory, shaped like genotype_template, or None if there is none."""
    loaded = _load(directory / CHECKPOINT, genotype_template, "key")
    if loaded is None:
        return None
    repertoire, key, progress = loaded
    return _state(progress, repertoire, key)


def save_archive(path: Path, repertoire: MapElitesRepertoire) -> None:
    """The final archive as `.npz`: `genotypes/<param path>` (C, ...), `fitnesses` (C,),
    `descriptors` (C, D), `centroids` (C, D), `filled` (C,); empty cells have fitness -inf."""
    arrays = _repertoire_arrays(repertoire)
    fitnesses = arrays["fitnesses"].reshape(-1)
    arrays.update(fitnesses=fitnesses, filled=fitnesses > -np.inf)
    write_npz(path, arrays)


@dataclass(frozen=True)
class Archive:
    """A saved archive: policy parameters as a nested dict (flax layout) and its scores."""

    genotypes: dict[str, Any]
    fitnesses: np.ndarray
    descriptors: np.ndarray
    centroids: np.ndarray
    filled: np.ndarray

    def elite(self, cell: int) -> dict[str, Any]:
        """The policy parameters in one cell, ready for `policy.apply(params, obs)`."""
        return jax.tree.map(lambda x: x[cell], self.genotypes)

    @property
    def best_cell(self) -> int:
        return int(np.argmax(self.fitnesses))


def load_archive(path: str | os.PathLike[str]) -> Archive:
    """Load `archive.npz` from a run directory (or its path)."""
    path = Path(path)
    if path.is_dir():
        path = path / "archive.npz"
    with np.load(path, allow_pickle=False) as data:
        genotypes: dict[str, Any] = {}
        for name in data.files:
            if not name.startswith("genotypes/"):
                continue
            node = genotypes
            *parents, leaf = name.split("/")[1:]
            for part in parents:
                node = node.setdefault(part, {})
            node[leaf] = data[name]
        return Archive(
            genotypes=genotypes,
            fitnesses=data["fitnesses"],
            descriptors=data["descriptors"],
            centroids=data["centroids"],
            filled=data["filled"],
        )


SWEEP_CHECKPOINT = "sweep-checkpoint.npz"


def sweep_checkpoint_arrays(
    repertoires: MapElitesRepertoire, keys: jax.Array, states: list[RunState]
) -> dict[str, np.ndarray]:
    """Every run of a sweep, for one file: the archives stacked along a runs axis (only the
    first len(states) runs: padding is not saved) and each run's counters and metrics rows,
    copied to host memory. All runs are at the same generation."""
    runs = len(states)
    arrays = {name: values[:runs] for name, values in _repertoire_arrays(repertoires).items()}
    arrays["keys"] = host_copy(jax.random.key_data(keys))[:runs]
    arrays["progress"] = np.asarray(json.dumps([_progress(state) for state in states]))
    return arrays


def save_sweep_checkpoint(
    path: Path, repertoires: MapElitesRepertoire, keys: jax.Array, states: list[RunState]
) -> None:
    """Write every run of a sweep atomically to one file (now, not in the background)."""
    write_npz(path, sweep_checkpoint_arrays(repertoires, keys, states))


def load_sweep_checkpoint(
    path: Path, genotype_template: Any
) -> tuple[MapElitesRepertoire, jax.Array, list[RunState]] | None:
    """The stacked archives, keys and per-run states saved by save_sweep_checkpoint, or None."""
    loaded = _load(path, genotype_template, "keys")
    if loaded is None:
        return None
    repertoires, keys, progress = loaded
    return repertoires, keys, [_state(p, None, None) for p in progress]
