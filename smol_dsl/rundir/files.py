"""Writing and reading a run directory's files: every write atomic, every failure named.

`atomic_write` writes a temporary file beside the target, fsyncs it and renames it over the
target, so a process killed at any moment leaves the old file or the new one, never a torn
one; an OSError names the file that could not be written. `write_together` does that for a
set of files (a report's), renaming them only once all are written. This module is the only
one of smol-dsl that renames files into place, and names the temporary files
(`temporary_path`: `NAME.PID.tmp`, processes may share a directory) that
`remove_stale_temporaries` deletes after a killed process. `read_text` reads a text file of
a run directory, or raises a RunDirectoryError that says why it cannot be used;
`check_output_file` refuses an output file a command cannot write; `read_json_object`
reads the settings a run or sweep was started with, to resume it.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from smol_dsl.rundir.layout import RunDirectoryError, leave_out

_TEMPORARY = re.compile(r".+\.\d+\.tmp")


def temporary_path(path: Path, hidden: bool = False) -> Path:
    """The temporary file beside `path` that this process writes before renaming it into
    place: `NAME.PID.tmp` (`.NAME.PID.tmp` if `hidden`)."""
    return path.with_name(f"{'.' if hidden else ''}{path.name}.{os.getpid()}.tmp")


def remove_stale_temporaries(directory: Path, prefix: str = "") -> None:
    """Delete the temporary files (`temporary_path`) whose names start with `prefix` that a
    killed process left in a directory this process has locked (a checkpoint's can be as
    big as the checkpoint)."""
    for path in directory.iterdir():
        if path.name.startswith(prefix) and _TEMPORARY.fullmatch(path.name) and path.is_file():
            with contextlib.suppress(OSError):
                path.unlink()


def atomic_write(path: Path, write: Callable[[IO[bytes]], Any]) -> None:
    """Call write(file) on a temporary file beside `path`, fsync it, and rename it over path.

    If anything fails (a full disk, say), the temporary file is removed and `path` is left as
    it was; an OSError is raised with `filename` set to `path`, whatever file the OS named.
    """
    path = Path(path)
    temporary = temporary_path(path)
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


def write_together(directory: Path, files: Mapping[str, bytes]) -> list[Path]:
    """Write files (name -> bytes) into `directory`: every one to a temporary file there first,
    then all renamed into place, so a failure (a full disk) before the renames changes
    nothing and none is ever half-written; temporary files are removed whatever happens. An
    OSError has `filename` set to the file that could not be written."""
    temporaries: dict[str, Path] = {}
    target = directory
    try:
        for name, data in files.items():
            target = directory / name
            temporaries[name] = temporary_path(directory / name, hidden=True)
            _write_bytes(temporaries[name], data)
        for name, temporary in temporaries.items():
            target = directory / name
            os.replace(temporary, target)
    except OSError as error:
        raise OSError(error.errno, error.strerror or str(error), str(target)) from error
    finally:
        for temporary in temporaries.values():
            with contextlib.suppress(OSError):
                temporary.unlink(missing_ok=True)
    return [directory / name for name in files]


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as file:
        file.write(data)


def write_npz(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write arrays atomically as an uncompressed `.npz`."""
    atomic_write(path, lambda file: np.savez(file, **arrays))


def write_text(path: Path, text: str) -> None:
    """Write a UTF-8 text atomically."""
    atomic_write(path, lambda file: file.write(text.encode()))


def check_output_file(
    path: str | os.PathLike[str], formats: Sequence[str], example: str, error: type[Exception]
) -> Path:
    """A file a command is to write (its -o): refused with `error` unless its suffix is one of
    `formats`, its folder exists and takes a new file (tried: what `atomic_write` writes
    first), and it is not a directory (`example` names a file to suggest inside it); so a
    command can check its output before it does any work."""
    out = Path(path)
    if out.suffix.lower() not in formats:
        raise error(f"cannot write {out}: the format is chosen by the suffix, one of {', '.join(formats)}")
    if not out.parent.is_dir():
        raise error(f"cannot write {out}: no such directory {out.parent}")
    if out.is_dir():
        raise error(f"cannot write {out}: it is a directory; give -o a file name, such as {out / example}")
    probe = temporary_path(out)
    try:
        with open(probe, "xb"):
            pass
        probe.unlink()
    except OSError as problem:
        reason = problem.strerror or type(problem).__name__
        raise error(f"cannot write {out}: {reason} in {out.parent}; give -o a file in a folder you can write") from None
    return out


def read_text(path: Path) -> str:
    """A run directory's text file, or a RunDirectoryError saying why it cannot be used."""
    directory = path.parent
    try:
        return path.read_text(encoding="utf-8-sig")  # a byte-order mark is not part of the text
    except FileNotFoundError:
        raise RunDirectoryError(
            f"{path}: missing; every run directory holds it (the runner writes it first), so {directory} is "
            f"incomplete: rerun that run, {leave_out(directory)}"
        ) from None
    except UnicodeDecodeError:
        raise RunDirectoryError(
            f"{path}: not a text file (it is not UTF-8); rerun that run, {leave_out(directory)}"
        ) from None
    except OSError as error:
        raise RunDirectoryError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {leave_out(directory)}"
        ) from None


def read_json_object(path: Path, what: str) -> dict[str, Any]:
    """The JSON object of a file that records the settings a `what` (run or sweep) was started
    with (config.json, sweep.json), for resuming it; a damaged one is a RunDirectoryError."""
    try:
        data = json.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError, RecursionError) as error:
        data, problem = None, f"not JSON: {error}"
    else:
        problem = "not a JSON object"
    if not isinstance(data, dict):
        raise RunDirectoryError(
            f"{path} is damaged ({problem}); it records the settings the {what} was started with, so the {what} "
            f"cannot be resumed without it: put back a good copy, or start the {what} afresh in another --out"
        )
    return data
