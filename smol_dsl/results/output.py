"""A command's output directory: checked before any work (`check_writable_directory`),
then its files written together and atomically (`write_files`); every problem a
ReportError that names the path and what to do."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from smol_dsl.results.runs import ReportError
from smol_dsl.rundir.files import write_together


def check_writable_directory(out_dir: str | Path, files: Sequence[str], what: str) -> Path:
    """Refuse (ReportError) an output directory that is a file, cannot be made or written,
    or holds a directory where one of `files` goes; `what` names the output in messages
    ("the report")."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ReportError(
            f"{out} is a file, not a directory: {what} is several files ({', '.join(files[:3])}, ...) and -o "
            "names the directory they go into; give another -o"
        )
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ReportError(f"cannot create {out}: {existing} is a file, not a directory; give another -o")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ReportError(f"cannot write into {existing} (permission denied); give another -o")
    blocked = [name for name in files if (out / name).is_dir()]
    if blocked:
        raise ReportError(f"{out / blocked[0]} is a directory, where {what} writes a file; move it, or give another -o")
    return out


def write_files(out_dir: str | Path, files: dict[str, bytes], remove: Sequence[str] = ()) -> list[Path]:
    """Write files into out_dir (made if need be), together and atomically
    (`smol_dsl.rundir.files.write_together`), then remove the files named in `remove`."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ReportError(f"cannot create {out} ({error.strerror or error}); give another -o") from None
    try:
        written = write_together(out, files)
        for name in remove:
            (out / name).unlink(missing_ok=True)
    except OSError as error:
        raise ReportError(
            f"cannot write {error.filename} ({error.strerror or error}); free some space or give another -o"
        ) from None
    return written
