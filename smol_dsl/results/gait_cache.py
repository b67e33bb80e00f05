"""The explorer's gait cache: rendered gaits on disk, in a directory of the user's own, keyed
by everything a gait depends on, bounded in size.

A gait is a GIF and a JSON of what its rollouts gave (each body's fitness and descriptor).
Its key (`gait_key`) hashes what it depends on: the run's archive, config, schedule and
environment files' contents (`RunFiles.digest`), the cell, the bodies' factors, the GIF's
size, the replay's program note and smol-dsl's version; a run trained again into the same
directory gets new keys. The archive's own fitness and descriptor are never read from the
cache, and an entry that does not parse as a gait's is rendered again.

The directory (`private_directory`) is the user's cache directory by default (`smol-dsl/
explore` in `$XDG_CACHE_HOME` or `~/.cache`, `~/Library/Caches` on macOS), made mode 0700; a
symlink, a directory of another user or one that others may write is refused, and no link
inside it is followed. Past `most_bytes` the least recently used gaits are removed.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import stat
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from smol_dsl.errors import UserInputError
from smol_dsl.rundir import ARCHIVE_FILE, CONFIG_FILE, ENVIRONMENT_FILE, SCHEDULE_FILE, atomic_write
from smol_dsl.rundir.files import temporary_path

DEFAULT_CACHE_MB = 256
"""The cache's bound by default, in MB (a gait of the quick preset is about 150 kB)."""
KEY_LENGTH = 32  # hex digits of a key: 128 bits of sha256
KEY_NAME = re.compile(rf"[0-9a-f]{{{KEY_LENGTH}}}\.(gif|json)")
GAIT_INPUTS = (ARCHIVE_FILE, CONFIG_FILE, SCHEDULE_FILE, ENVIRONMENT_FILE)
"""The run's files a gait depends on: its policies and scores, its program's settings, its
bodies (the schedule under the seed) and the layout of the program that scored it."""


class CacheError(UserInputError):
    """A gait cache directory that is not the user's own: its message says what and how to fix it."""


def default_cache_directory() -> Path:
    """`smol-dsl/explore` in the user's cache directory: `$XDG_CACHE_HOME` (or `~/.cache`) on
    Linux and other Unix, `~/Library/Caches` on macOS, `%LOCALAPPDATA%` on Windows."""
    if sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    elif sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    else:
        given = os.environ.get("XDG_CACHE_HOME", "")
        base = Path(given) if os.path.isabs(given) else Path.home() / ".cache"  # the spec ignores a relative one
    return base / "smol-dsl" / "explore"


def private_directory(path: Path) -> Path:
    """`path` made (mode 0700, its parents as usual) or checked: a directory, not a symlink,
    owned by this user and writable by no one else; a CacheError otherwise."""
    path = Path(path)
    hint = "give another with --cache DIR, a directory of your own that only you can write"
    if path.is_symlink():
        raise CacheError(f"{path} is a symbolic link; the gait cache is not kept behind one: remove it, or {hint}")
    if not path.exists():
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.mkdir(mode=0o700)
        except FileExistsError:
            pass  # made meanwhile: checked below like any other
        except OSError as error:
            raise CacheError(f"{path}: cannot make the gait cache there ({error.strerror or error}); {hint}") from None
    info = path.lstat()
    if stat.S_ISLNK(info.st_mode):
        raise CacheError(f"{path} is a symbolic link; the gait cache is not kept behind one: remove it, or {hint}")
    if not stat.S_ISDIR(info.st_mode):
        raise CacheError(f"{path} is not a directory; {hint}")
    if hasattr(os, "getuid") and info.st_uid != os.getuid():
        raise CacheError(f"{path} belongs to another user (uid {info.st_uid}); {hint}")
    if info.st_mode & 0o022:
        raise CacheError(
            f"{path} may be written by others (mode {stat.S_IMODE(info.st_mode):o}), who could plant gaits in it: "
            f"`chmod go-w {path}`, or {hint}"
        )
    return path


@dataclass(frozen=True)
class RunFiles:
    """What a run's gaits depend on, as found on disk: each of GAIT_INPUTS's (device, inode,
    size, mtime) or None. Equal signatures: files not changed since."""

    directory: Path
    signature: tuple[tuple[int, int, int, int] | None, ...]

    @classmethod
    def of(cls, directory: Path) -> RunFiles:
        found = []
        for name in GAIT_INPUTS:
            try:
                info = os.stat(Path(directory) / name)
            except FileNotFoundError:
                found.append(None)
                continue
            found.append((info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns))
        return cls(Path(directory), tuple(found))

    def changed(self) -> list[str]:
        """The files whose signature differs now (changed, removed or written since)."""
        now = RunFiles.of(self.directory).signature
        return [name for name, before, after in zip(GAIT_INPUTS, self.signature, now, strict=True) if before != after]

    def digest(self) -> str:
        """A sha256 over the files' names and contents (read once per signature: memoised)."""
        known = _DIGESTS.get(self.directory)
        if known is not None and known[0] == self.signature:
            return known[1]
        hashing = hashlib.sha256()
        for name, signature in zip(GAIT_INPUTS, self.signature, strict=True):
            hashing.update(f"{name}\0{signature is not None}\0".encode())
            if signature is None:
                continue
            with open(self.directory / name, "rb") as file:
                for block in iter(lambda file=file: file.read(1 << 20), b""):
                    hashing.update(block)
        _DIGESTS[self.directory] = (self.signature, hashing.hexdigest())
        return _DIGESTS[self.directory][1]


_DIGESTS: dict[Path, tuple[tuple[Any, ...], str]] = {}


def gait_key(files: RunFiles, cell: int, bodies: list[tuple[str, dict[str, float]]], size: Any, program: Any) -> str:
    """The cache's name for a gait: a hash of everything it depends on (see the module)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        ours = version("smol-dsl")
    except PackageNotFoundError:
        ours = "unknown"
    shown = [[label, sorted(body.items())] for label, body in bodies]
    material = json.dumps(["smol-dsl explore gait 2", ours, files.digest(), cell, shown, list(size), program])
    return hashlib.sha256(material.encode()).hexdigest()[:KEY_LENGTH]


class GaitCache:
    """Gaits by key in a private directory (`private_directory`), at most `most_bytes` of
    them (least recently used removed first); no link inside it is followed."""

    def __init__(self, directory: Path, most_bytes: int) -> None:
        self.directory = Path(directory)
        self.most_bytes = most_bytes

    def get(self, key: str, cell: int, labels: list[str], descriptors: int) -> dict[str, Any] | None:
        """The rendered gait of `key` ({"gaits", "seconds"}) if both its files are there and
        its JSON is a gait's of that cell and those bodies; None otherwise (render it)."""
        try:
            text = self._read(f"{key}.json")
            if not self._is_file(f"{key}.gif"):
                return None
            answer = json.loads(text)
        except (OSError, ValueError):
            return None
        if not _is_rendered(answer, cell, labels, descriptors):
            return None
        with contextlib.suppress(OSError):  # used now: the last to be removed
            os.utime(self.directory / f"{key}.json", follow_symlinks=False)
        return {"gaits": answer["gaits"], "seconds": answer["seconds"]}

    def put(self, key: str, rendered: dict[str, Any], image: bytes) -> None:
        """Keep a gait (its GIF, then its JSON), then remove the least recently used ones
        past the bound."""
        self._write(f"{key}.gif", image)
        self._write(f"{key}.json", json.dumps(rendered, allow_nan=False).encode())
        self.evict(keep=key)

    def image(self, key: str) -> bytes:
        """A gait's GIF (an OSError if there is none, or only a link)."""
        return self._read(f"{key}.gif", binary=True)

    def evict(self, keep: str | None = None) -> list[str]:
        """Remove the least recently used gaits (by their JSON's time) until the cache holds
        at most `most_bytes`; returns the keys removed. Only files named as gaits are
        counted or touched: anything else in the directory is left alone."""
        entries: dict[str, list[os.stat_result]] = {}
        with os.scandir(self.directory) as found:
            for entry in found:
                if KEY_NAME.fullmatch(entry.name):
                    with contextlib.suppress(OSError):
                        entries.setdefault(entry.name.split(".")[0], []).append(entry.stat(follow_symlinks=False))
        total = sum(info.st_size for infos in entries.values() for info in infos)
        removed = []
        for key in sorted(entries, key=lambda k: max(info.st_mtime_ns for info in entries[k])):
            if total <= self.most_bytes:
                break
            if key == keep:
                continue
            for suffix in ("json", "gif"):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.directory / f"{key}.{suffix}")
            total -= sum(info.st_size for info in entries[key])
            removed.append(key)
        return removed

    def _is_file(self, name: str) -> bool:
        with contextlib.suppress(OSError):
            return stat.S_ISREG(os.lstat(self.directory / name).st_mode)
        return False

    def _read(self, name: str, binary: bool = False) -> Any:
        """A file of the cache, opened without following a link (O_NOFOLLOW)."""
        flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
        descriptor = os.open(self.directory / name, flags)
        with os.fdopen(descriptor, "rb") as file:
            if not stat.S_ISREG(os.fstat(file.fileno()).st_mode):
                raise OSError(f"{name} is not a regular file")
            data = file.read()
        return data if binary else data.decode()

    def _write(self, name: str, data: bytes) -> None:
        """Write a file of the cache atomically (`atomic_write`), removing first a link where
        its temporary file goes, so that no link is written through."""
        path = self.directory / name
        temporary = temporary_path(path)
        if temporary.is_symlink():
            temporary.unlink()
        atomic_write(path, lambda file: file.write(data))


def _is_rendered(answer: Any, cell: int, labels: list[str], descriptors: int) -> bool:
    """Whether a cached JSON is a gait's answer for `cell` in the bodies `labels`."""
    if not isinstance(answer, dict) or answer.get("cell") != cell or not _number(answer.get("seconds")):
        return False
    gaits = answer.get("gaits")
    if not isinstance(gaits, list) or [g.get("body") if isinstance(g, dict) else None for g in gaits] != labels:
        return False
    for gait in gaits:
        descriptor, factors, inexact = gait.get("descriptor"), gait.get("factors"), gait.get("inexact")
        if not _number(gait.get("fitness"), None) or not isinstance(descriptor, list) or len(descriptor) != descriptors:
            return False
        if not all(_number(x, None) for x in descriptor) or not isinstance(factors, dict):
            return False
        if not all(isinstance(k, str) and _number(v) for k, v in factors.items()):
            return False
        if inexact is not None and not isinstance(inexact, str):
            return False
    return True


def _number(value: Any, *allowed: None) -> bool:
    """A finite number (or one of `allowed`: None where a rollout's value was not finite)."""
    if value is None:
        return bool(allowed)
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
