"""archive.npz: a finished run's final archive, written from host arrays, loaded with its
policies (`load_archive`) or read and checked without them (`read_final_archive`)."""

from __future__ import annotations

import contextlib
import os
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.rundir.files import write_npz
from smol_dsl.rundir.layout import ARCHIVE_FILE, CONFIG_FILE, METRICS_FILE, RunDirectoryError, leave_out
from smol_dsl.tasks import task_spec

if TYPE_CHECKING:
    from smol_dsl.rundir.config import RunConfig


ARCHIVE_ARRAYS = ("fitnesses", "descriptors", "centroids", "filled")
"""archive.npz's arrays besides the policies (`genotypes/<parameter path>`) and lanes."""
GENOTYPES = "genotypes/"
LANES = "lanes"
"""archive.npz's (C,) int32 array of each elite's lane, its position in the batch it was
scored in (-1 where unknown: archives written before runs kept them); a replay in the same
program and lane gives the archive's fitness bit for bit (`smol_dsl.rescoring.replay`)."""


def policy_shapes(task: str, config: RunConfig, cells: int) -> dict[str, tuple[int, ...]] | None:
    """The arrays of `cells` policies of the task's network (QDax's MLP: `Dense_i`'s kernel
    and bias, observations -> hidden_layer_sizes -> one action per actuator), by archive name;
    None for a task whose spec does not give its observation size and anatomy."""
    spec = task_spec(task)
    if spec.observation_size is None or spec.anatomy is None:
        return None
    sizes = (spec.observation_size, *config.hidden_layer_sizes, len(spec.anatomy.actuators))
    shapes: dict[str, tuple[int, ...]] = {}
    for i, (inputs, outputs) in enumerate(pairwise(sizes)):
        shapes[f"{GENOTYPES}params/Dense_{i}/kernel"] = (cells, inputs, outputs)
        shapes[f"{GENOTYPES}params/Dense_{i}/bias"] = (cells, outputs)
    return shapes


def write_archive(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """The final archive as `.npz`, atomically, from host arrays: `genotypes/<param path>`
    (C, ...), `fitnesses` (C,) or (C, 1), `descriptors` (C, D), `centroids` (C, D) and
    `lanes` (C,). Fitnesses are stored as (C,), and `filled` (C,) is where they are above -inf."""
    unknown = [name for name in arrays if not name.startswith(GENOTYPES) and name not in (*ARCHIVE_ARRAYS, LANES)]
    if unknown:
        raise ValueError(f"write_archive: unknown array(s) {unknown}")
    fitnesses = np.asarray(arrays["fitnesses"]).reshape(-1)
    write_npz(path, {**arrays, "fitnesses": fitnesses, "filled": fitnesses > -np.inf})


@dataclass(frozen=True)
class Archive:
    """A saved archive: policy parameters as a nested dict (flax layout) and its scores."""

    genotypes: dict[str, Any]
    fitnesses: np.ndarray
    descriptors: np.ndarray
    centroids: np.ndarray
    filled: np.ndarray
    lanes: np.ndarray | None = None  # each elite's lane (`LANES`); None in archives written before they were kept

    def elite(self, cell: int) -> dict[str, Any]:
        """The policy parameters in one cell, ready for `policy.apply(params, obs)`."""

        def take(node: Any) -> Any:
            if isinstance(node, Mapping):
                return {name: take(child) for name, child in node.items()}
            return node[cell]

        return take(self.genotypes)

    @property
    def best_cell(self) -> int:
        return int(np.argmax(self.fitnesses))


def load_archive(path: str | os.PathLike[str]) -> Archive:
    """Load `archive.npz` from a run directory (or its path)."""
    path = Path(path)
    if path.is_dir():
        path = path / ARCHIVE_FILE
    with np.load(path, allow_pickle=False) as data:
        genotypes: dict[str, Any] = {}
        for name in data.files:
            if not name.startswith(GENOTYPES):
                continue
            node = genotypes
            *parents, leaf = name.split("/")[1:]
            for part in parents:
                node = node.setdefault(part, {})
            node[leaf] = data[name]
        lanes = data[LANES] if LANES in data.files else None
        return Archive(genotypes=genotypes, lanes=lanes, **{name: data[name] for name in ARCHIVE_ARRAYS})


@dataclass(frozen=True)
class FinalArchive:
    """A run's final archive.npz without its policies: what the report reads and draws.
    `fitnesses` (C,), -inf in empty cells; `descriptors` and `centroids` (C, D); `filled` (C,)."""

    fitnesses: np.ndarray
    descriptors: np.ndarray
    centroids: np.ndarray
    filled: np.ndarray


def read_final_archive(directory: Path, config: RunConfig) -> FinalArchive:
    """A finished run's archive.npz, checked: it loads, holds every array with the shapes the
    run's config gives (C cells, D descriptors, a policy per cell), and its values agree
    (fitness finite or -inf for an empty cell, `filled` where it is finite). Shapes are read
    from the arrays' headers first; the policies are checked by their shapes only, not read."""
    path = Path(directory) / ARCHIVE_FILE
    again = f"rerun the run (or copy the directory again if it was copied), {leave_out(directory)}"
    if not path.is_file():
        raise RunDirectoryError(
            f"{path}: missing, though {METRICS_FILE} reaches the last generation: the run stopped before writing "
            f"its final archive; resume it with `smol-dsl run ... --resume` (or `sweep ... --resume`), which "
            f"writes it, {leave_out(directory)}"
        )
    headers = _read_headers(path, again)
    policies = [name for name in headers if name.startswith(GENOTYPES)]
    lacking = [name for name in ARCHIVE_ARRAYS if name not in headers] + ([] if policies else ["genotypes/..."])
    if lacking:
        raise RunDirectoryError(f"{path}: lacks the array(s) {', '.join(lacking)}; {again}")
    _check_policies(path, config, policies, again)
    for name in [*ARCHIVE_ARRAYS, *policies]:  # before reading anything: a damaged header may claim any size
        if headers[name] is not None:
            _check_array(path, config, name, *headers[name], again)
    with _reading_archive(path, again), np.load(path, allow_pickle=False) as data:
        arrays = {name: np.asarray(data[name]) for name in ARCHIVE_ARRAYS}
    for name, array in arrays.items():
        _check_array(path, config, name, array.shape, array.dtype, again)
    _check_values(path, arrays, again)
    return FinalArchive(**arrays)


def _check_policies(path: Path, config: RunConfig, names: list[str], again: str) -> None:
    """The policies are the config's network for its task: the same parameters (the shapes
    follow from the headers, `_check_array`)."""
    expected = policy_shapes(config.task, config, config.num_centroids)
    if expected is None or sorted(names) == sorted(expected):
        return
    odd = sorted(set(names) ^ set(expected))
    raise RunDirectoryError(
        f"{path}: its policies' parameters ({', '.join(sorted(names))}) are not those of {config.task}'s "
        f"network in {CONFIG_FILE} (it would have {', '.join(sorted(expected))}; {odd[0]} differs); the archive "
        f"is of another task or network: {again}"
    )


def _check_array(path: Path, config: RunConfig, name: str, shape: tuple[int, ...], dtype: np.dtype, again: str) -> None:
    """An array of archive.npz has the shape and kind the run's config gives: a policy's
    parameters one per cell, `filled` bool (C,), the others float, (C,) or (C, D)."""
    cells = config.num_centroids
    if name.startswith(GENOTYPES):
        if shape[:1] != (cells,):
            raise RunDirectoryError(
                f"{path}: {name} has shape {shape}, not one policy per cell ({cells}, ...); {again}"
            )
        expected = (policy_shapes(config.task, config, cells) or {}).get(name)
        if expected is not None and tuple(shape) != expected:
            layers = " -> ".join(str(size) for size in expected[1:])
            raise RunDirectoryError(
                f"{path}: {name} has shape {tuple(shape)}, but {config.task}'s network in {CONFIG_FILE} gives "
                f"{expected} ({layers} per cell): the archive is of another task or network; {again}"
            )
        if not np.issubdtype(dtype, np.floating):
            raise RunDirectoryError(f"{path}: {name} is a {dtype} array, not float parameters; {again}")
        return
    size = task_spec(config.task).descriptor_size
    expected = {"fitnesses": (cells,), "descriptors": (cells, size), "centroids": (cells, size), "filled": (cells,)}
    kind = np.bool_ if name == "filled" else np.floating
    if shape != expected[name] or not np.issubdtype(dtype, kind):
        raise RunDirectoryError(
            f"{path}: {name} is a {dtype} array of shape {shape}, but {CONFIG_FILE} ({cells} cells, "
            f"{config.task}'s {size} descriptors) gives {'bool' if name == 'filled' else 'float'} of shape "
            f"{expected[name]}; {again}"
        )


def _check_values(path: Path, arrays: Mapping[str, np.ndarray], again: str) -> None:
    """The archive's values agree: fitnesses finite or -inf (an empty cell), `filled` where
    they are finite, the centroids and the filled cells' descriptors finite."""
    fitnesses, filled = arrays["fitnesses"], arrays["filled"]
    if np.isnan(fitnesses).any() or (fitnesses == np.inf).any():
        raise RunDirectoryError(f"{path}: a fitness is NaN or +inf; {again}")
    if not np.array_equal(filled, fitnesses > -np.inf):
        raise RunDirectoryError(f"{path}: `filled` disagrees with the fitnesses (-inf marks an empty cell); {again}")
    if not np.isfinite(arrays["centroids"]).all() or not np.isfinite(arrays["descriptors"][filled]).all():
        raise RunDirectoryError(f"{path}: a centroid or a filled cell's descriptor is not finite; {again}")


def _read_headers(path: Path, again: str) -> dict[str, tuple[tuple[int, ...], np.dtype] | None]:
    """Every array of archive.npz by name, with the shape and dtype its header claims."""
    with _reading_archive(path, again), zipfile.ZipFile(path) as bundle:
        return {
            name.removesuffix(".npy"): _npy_header(bundle, name) for name in bundle.namelist() if name.endswith(".npy")
        }


@contextlib.contextmanager
def _reading_archive(path: Path, again: str) -> Iterator[None]:
    """Turn what reading a damaged or unreadable archive raises into a RunDirectoryError."""
    try:
        yield
    except OSError as error:
        raise RunDirectoryError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {leave_out(path.parent)}"
        ) from None
    except Exception as error:  # zipfile.BadZipFile, EOFError, ValueError...: a file cut short or damaged
        raise RunDirectoryError(
            f"{path}: not a readable archive ({type(error).__name__}: {error}); it is damaged or cut short "
            f"(a full disk, or an unfinished copy): {again}"
        ) from None


def _npy_header(bundle: zipfile.ZipFile, name: str) -> tuple[tuple[int, ...], np.dtype] | None:
    """The shape and dtype in an .npy member's header, without reading its data (None: a
    header version this does not read; the array is checked once loaded)."""
    with bundle.open(name) as member:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(member)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(member)
        else:
            return None
        return shape, dtype
