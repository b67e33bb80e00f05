"""environment.json: the software and hardware a run was produced by.

The same seed trains to different numbers under another jax (XLA compiles the physics
differently), on another device layout, or on a CPU with other vector extensions (XLA
compiles for the host's instruction set). Every run directory records what it ran under
(`describe_environment`), resuming under a different record is refused unless allowed
(the change is then recorded in the file), and a report refuses to put runs of different
records in one table unless told to (`environment_differences` names what differs).

Only what can change the numbers is compared (`COMPARED`): Python, the numerical
packages, smol-dsl's version and commit, the devices and the processor. The operating
system and the host's name are recorded, not compared.
"""

from __future__ import annotations

import functools
import json
import platform
import subprocess
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

from smol_dsl.rundir.files import read_text, write_text
from smol_dsl.rundir.layout import ENVIRONMENT_FILE, RunDirectoryError, leave_out

PACKAGES = ("jax", "jaxlib", "brax", "qdax", "mujoco", "numpy", "flax", "scipy")
"""The packages whose versions are recorded: those the physics and the archives run on."""
VECTOR_EXTENSIONS = (
    "sse4_2",
    "avx",
    "avx2",
    "fma",
    "f16c",
    "avx512f",
    "avx512bw",
    "avx512vl",
    "avx512_vnni",
    "avx512_bf16",
    "amx_tile",
    "asimd",
    "sve",
)
"""The processor's instruction-set extensions that XLA's CPU code generation uses."""
COMPARED = ("python", "smol_dsl", "commit", "packages", "devices", "processor")
"""The entries of a record that can change a run's numbers: the ones compared."""


def describe_environment(devices: Sequence[Any]) -> dict[str, Any]:
    """What a run on `devices` (objects with `platform` and `device_kind`, as JAX's devices)
    runs under, as environment.json records it."""
    kinds = sorted({str(getattr(device, "device_kind", device.platform)) for device in devices})
    return {
        "python": platform.python_version(),
        "smol_dsl": _version("smol-dsl"),
        "commit": _commit(),
        "packages": {name: _version(name) for name in PACKAGES},
        "devices": {"platform": devices[0].platform if devices else None, "kinds": kinds, "count": len(devices)},
        "processor": _processor(),
        "system": platform.platform(),
        "host": platform.node(),
    }


def environment_differences(recorded: dict[str, Any], current: dict[str, Any]) -> list[str]:
    """What differs between two records in what can change the numbers, one phrase each
    ("jax 0.10.2 -> 0.12.0"), in `COMPARED`'s order."""
    return [
        f"{name} {_shown(before)} -> {_shown(after)}"
        for name, before, after in _compared(recorded, current)
        if before != after
    ]


def _compared(recorded: dict[str, Any], current: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    pairs = []
    for key in COMPARED:
        before, after = recorded.get(key), current.get(key)
        if isinstance(before, dict) and isinstance(after, dict):
            for inner in sorted(set(before) | set(after), key=lambda k: (k not in before, k)):
                label = inner if key == "packages" else f"{key.replace('_', '-')} {inner}"
                pairs.append((label, before.get(inner), after.get(inner)))
        else:
            pairs.append((key.replace("_", "-"), before, after))
    return pairs


def _shown(value: Any) -> str:
    if value is None:
        return "(none)"
    if isinstance(value, list):
        return ",".join(str(item) for item in value) or "(none)"
    return str(value)


def environment_text(environment: dict[str, Any]) -> str:
    """A new run's environment.json: the record, and no change yet."""
    return json.dumps({"environment": environment, "changes": []}, indent=2)


def record_environment_change(directory: Path, current: dict[str, Any], differences: list[str]) -> None:
    """Note in environment.json that the run went on under `current` (allowed by the user)."""
    data = _environment_file(directory)
    data["changes"].append({"environment": current, "differences": differences})
    write_text(directory / ENVIRONMENT_FILE, json.dumps(data, indent=2))


def read_environment(directory: Path) -> dict[str, Any] | None:
    """The environment a run was started under (None for a run directory without an
    environment.json, written before runs recorded one)."""
    if not (directory / ENVIRONMENT_FILE).is_file():
        return None
    return _environment_file(directory)["environment"]


def read_environment_changes(directory: Path) -> list[dict[str, Any]]:
    """The environments a run was resumed under since it started, with what differed."""
    if not (directory / ENVIRONMENT_FILE).is_file():
        return []
    return _environment_file(directory)["changes"]


def _environment_file(directory: Path) -> dict[str, Any]:
    path = directory / ENVIRONMENT_FILE
    fix = f"it is not the file the run wrote: rerun the run, {leave_out(directory)}"
    try:
        data = json.loads(read_text(path))
    except json.JSONDecodeError as error:
        raise RunDirectoryError(f"{path}:{error.lineno}:{error.colno}: not JSON ({error.msg}); {fix}") from None
    if (
        not isinstance(data, dict)
        or not isinstance(data.get("environment"), dict)
        or not isinstance(data.get("changes"), list)
    ):
        raise RunDirectoryError(f"{path}: expected an object with 'environment' and 'changes'; {fix}")
    return data


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


@functools.lru_cache(maxsize=1)
def _commit() -> str | None:
    """The git commit of the checkout smol-dsl runs from (with "+changes" if its tracked
    files differ from it), or None for an installed package."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        status = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return head.stdout.strip() + ("+changes" if status.stdout.strip() else "")


@functools.lru_cache(maxsize=1)
def _processor() -> dict[str, Any]:
    """The processor's model and vector extensions (from /proc/cpuinfo where there is one)."""
    names: dict[str, str] = {}
    flags: set[str] = set()
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text()
    except OSError:
        cpuinfo = ""
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        key, value = key.strip(), value.strip()
        if key in ("flags", "Features"):
            flags.update(value.split())
        elif key in ("model name", "Model") and value:
            names.setdefault(key, value)
    model = names.get("model name") or names.get("Model") or platform.processor() or platform.machine()
    return {"model": model, "vector_extensions": [name for name in VECTOR_EXTENSIONS if name in flags]}
