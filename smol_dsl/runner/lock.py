"""One process at a time in a run (or sweep) directory: an OS lock on a file inside it.

Two processes writing one run directory would both append to its metrics.csv and take
turns overwriting its checkpoint. A run (and a sweep, for each run directory it writes)
holds an exclusive `flock` on `DIR/.smol-dsl.lock` for as long as it runs; a second
process is refused at once with a RunError that names the directory and the process
holding it. The kernel releases the lock when the holder exits, even after `kill -9`, so
there is never a stale lock to delete. The lock file stays in the directory (deleting it
would let two processes lock two different files); it holds the holder's pid and host,
for the message only.
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
import warnings
from pathlib import Path

from smol_dsl.rundir import LOCK_FILE
from smol_dsl.runner.config import RunError

try:
    import fcntl
except ImportError:  # not POSIX: runs are not locked
    fcntl = None  # type: ignore[assignment]


# file systems that cannot lock (some network mounts): the run goes on unlocked, with a warning
_CANNOT_LOCK = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS, errno.EINVAL}


class DirectoryLock:
    """An exclusive lock on a directory, held until `release()` (or the end of a `with`)."""

    def __init__(self, directory: Path, descriptor: int | None) -> None:
        self.directory = directory
        self._descriptor = descriptor

    @classmethod
    def acquire(cls, directory: Path, what: str = "run") -> DirectoryLock:
        """Lock `directory` (which must exist) or raise a RunError naming it and its holder.
        `what` ("run" or "sweep") is for the message."""
        if fcntl is None:
            return cls(directory, None)
        path = directory / LOCK_FILE
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(descriptor)
            os.close(descriptor)
            raise RunError(
                f"{directory} is in use by another smol-dsl process{holder}: only one process at a time "
                f"may write a {what} directory. Wait for it to finish (or stop it), then try again; "
                "or give another --out"
            ) from None
        except OSError as error:
            os.close(descriptor)
            if error.errno not in _CANNOT_LOCK:
                raise
            warnings.warn(
                f"{directory}: this file system cannot lock files ({error.strerror}); nothing stops a second "
                "process from writing the same directory",
                stacklevel=2,
            )
            return cls(directory, None)
        with contextlib.suppress(OSError):  # who holds it, for another process's message; a full disk is fine
            os.ftruncate(descriptor, 0)
            os.write(descriptor, f"{os.getpid()} {socket.gethostname()}\n".encode())
        return cls(directory, descriptor)

    @property
    def held(self) -> bool:
        return self._descriptor is not None

    def release(self) -> None:
        if self._descriptor is not None:
            os.close(self._descriptor)  # closing the file releases the flock
            self._descriptor = None

    def __enter__(self) -> DirectoryLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _holder(descriptor: int) -> str:
    with contextlib.suppress(OSError, ValueError, UnicodeDecodeError):
        pid, host = os.pread(descriptor, 200, 0).decode().split()
        return f" (pid {int(pid)} on {host})"
    return ""
