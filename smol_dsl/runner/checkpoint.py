"""Atomic checkpoints of a run, and the final archive's `.npz` layout.

A checkpoint is written to a temporary file in the run directory, flushed to disk and
renamed over the previous one, so a run killed at any moment leaves either the old or the
new checkpoint, never a torn one. Runs hand their checkpoints to a `CheckpointWriter`,
which writes them in the background: at paper scale a sweep's checkpoint holds tens of GB
of archives, and training goes on while it reaches the disk.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import threading
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire

from smol_dsl.runner.config import RunError

CHECKPOINT = "checkpoint.npz"


def atomic_write(path: Path, write: Any) -> None:
    """Call write(file) on a temporary file, fsync it, and rename it over path.

    If anything fails (a full disk, say), the temporary file is removed and `path` is left as
    it was; an OSError is raised with `filename` set to `path`, whatever file the OS named.
    """
    temporary = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # processes may share a directory
    try:
        with open(temporary, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException as error:
        with contextlib.suppress(OSError):
            temporary.unlink(missing_ok=True)
        if isinstance(error, OSError) and error.filename != str(path):
            raise OSError(error.errno, error.strerror or str(error), str(path)) from error
        raise
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


def run_owner(config: Any, schedule: Any) -> dict[str, Any]:
    """What a run's checkpoint records about the run that wrote it: its settings and schedule
    text, so that a checkpoint copied from another run is refused rather than continued."""
    return {"config": json.loads(config.to_json()), "schedule": schedule.source}


def checkpoint_arrays(state: RunState, owner: dict[str, Any] | None = None) -> dict[str, np.ndarray]:
    """A run's checkpoint: its archive, key and progress (and `owner`, the run it belongs
    to), copied to host memory."""
    if state.emitter_state is not None:
        raise NotImplementedError("only stateless emitters (iso+line) are checkpointed")
    arrays = _repertoire_arrays(state.repertoire)
    arrays["key"] = host_copy(jax.random.key_data(state.key))
    arrays["progress"] = np.asarray(json.dumps(_progress(state)))
    if owner is not None:
        arrays["owner"] = np.asarray(json.dumps(owner))
    return arrays


def save_checkpoint(directory: Path, state: RunState, owner: dict[str, Any] | None = None) -> None:
    """Write the run's state atomically to directory/checkpoint.npz (now, not in the background)."""
    write_npz(directory / CHECKPOINT, checkpoint_arrays(state, owner))


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
    key_field: str,
    layout: tuple[int | None, ...],
    descriptors: int | None,
    owner: dict[str, Any] | None = None,
) -> tuple[MapElitesRepertoire, jax.Array, Any] | None:
    """An archive, its key(s) and the progress JSON saved at path, or None if there is none.

    `layout` is the leading axes every archive array must have: (cells,) for a run, (runs,
    cells) for a sweep; `descriptors` the descriptor dimension. A file that cannot be read as
    such a checkpoint (truncated, corrupted, from another task) is a RunError naming it, and
    so is one whose recorded `owner` is not the given one (copied from another run).
    """
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            _check_layout(path, data, genotype_template, key_field, layout, descriptors)
            if owner is not None and "owner" in data.files:  # checkpoints before 0.1.0's hardening have none
                _check_owner(path, json.loads(str(data["owner"])), owner)
            repertoire = _repertoire_from(data, genotype_template)
            key = jax.random.wrap_key_data(jax.numpy.asarray(data[key_field]))
            return repertoire, key, json.loads(str(data["progress"]))
    except (ValueError, KeyError, EOFError, TypeError, IndexError, zipfile.BadZipFile) as error:
        raise damaged_checkpoint(path, f"it is damaged ({type(error).__name__}: {error})") from None
    except OSError as error:
        if error.errno is not None:  # could not be read (permissions, I/O): the OS's own error
            raise
        raise damaged_checkpoint(path, f"it is damaged ({error})") from None


def _check_layout(
    path: Path, data: Any, template: Any, key_field: str, layout: tuple[int | None, ...], descriptors: int | None
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
    expected["key_data"] = layout[:-1] + tuple(jax.random.key_data(jax.random.key(0)).shape)
    if descriptors is not None:
        expected["descriptors"] = expected["centroids"] = (*layout, descriptors)
    missing = sorted(set(expected) - {"key_data"} - set(data.files)) + ([] if key_field in data.files else [key_field])
    if "progress" not in data.files:
        missing.append("progress")
    if missing:
        raise damaged_checkpoint(
            path, f"it lacks {', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''} (is it from another task?)"
        )
    for name, shape in expected.items():
        actual = data[key_field if name == "key_data" else name].shape
        if name == "fitnesses" and actual == layout:
            continue  # (cells,) is as good as (cells, 1)
        if actual != shape:
            shown = key_field if name == "key_data" else name
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


def load_checkpoint(
    directory: Path,
    genotype_template: Any,
    num_cells: int | None = None,
    num_descriptors: int | None = None,
    owner: dict[str, Any] | None = None,
) -> RunState | None:
    """The state saved in directory, shaped like genotype_template (one policy with a leading
    axis), or None if there is none; a RunError for a damaged one or one from another run."""
    path = directory / CHECKPOINT
    loaded = _load(path, genotype_template, "key", (num_cells,), num_descriptors, owner)
    if loaded is None:
        return None
    repertoire, key, progress = loaded
    try:
        return _state(progress, repertoire, key)
    except (TypeError, AttributeError) as error:
        raise damaged_checkpoint(path, f"its progress record is damaged ({error})") from None


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
    repertoires: MapElitesRepertoire, keys: jax.Array, states: list[RunState], owner: dict[str, Any] | None = None
) -> dict[str, np.ndarray]:
    """Every run of a sweep, for one file: the archives stacked along a runs axis (only the
    first len(states) runs: padding is not saved) and each run's counters and metrics rows,
    copied to host memory. All runs are at the same generation."""
    runs = len(states)
    arrays = {name: values[:runs] for name, values in _repertoire_arrays(repertoires).items()}
    arrays["keys"] = host_copy(jax.random.key_data(keys))[:runs]
    arrays["progress"] = np.asarray(json.dumps([_progress(state) for state in states]))
    if owner is not None:
        arrays["owner"] = np.asarray(json.dumps(owner))
    return arrays


def save_sweep_checkpoint(
    path: Path,
    repertoires: MapElitesRepertoire,
    keys: jax.Array,
    states: list[RunState],
    owner: dict[str, Any] | None = None,
) -> None:
    """Write every run of a sweep atomically to one file (now, not in the background)."""
    write_npz(path, sweep_checkpoint_arrays(repertoires, keys, states, owner))


def load_sweep_checkpoint(
    path: Path,
    genotype_template: Any,
    num_runs: int,
    num_cells: int,
    num_descriptors: int | None = None,
    owner: dict[str, Any] | None = None,
) -> tuple[MapElitesRepertoire, jax.Array, list[RunState]] | None:
    """The stacked archives, keys and per-run states saved by save_sweep_checkpoint for
    `num_runs` runs of `num_cells` cells, or None; a RunError for a damaged one, or one
    another sweep (`owner`) wrote."""
    loaded = _load(path, genotype_template, "keys", (num_runs, num_cells), num_descriptors, owner)
    if loaded is None:
        return None
    repertoires, keys, progress = loaded
    if not isinstance(progress, list) or len(progress) != num_runs:
        raise damaged_checkpoint(path, f"it does not hold progress for {num_runs} runs")
    try:
        return repertoires, keys, [_state(p, None, None) for p in progress]
    except (TypeError, AttributeError) as error:
        raise damaged_checkpoint(path, f"its progress record is damaged ({error})") from None
