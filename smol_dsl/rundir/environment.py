"""environment.json: the software and hardware a run was produced by.

The same seed trains to different numbers under another jax (XLA compiles the physics
differently), on another device layout, or on a CPU with other vector extensions (XLA
compiles for the host's instruction set). Every run directory records what it ran under
(`describe_environment`), resuming under a different record is refused unless allowed
(the change is then recorded in the file), and a report refuses to put runs of different
records in one table unless told to (`environment_differences` names what differs).

Only what can change the numbers is compared (`COMPARED`): Python, the numerical
packages, smol-dsl's version and commit, the physics (`spring` or `mjx`, and the package
that implements it), the devices and the processor. The operating
system and the host's name are recorded, not compared. A run's `layout` (how its scoring
program laid the runs trained together out: `scoring_layout`) is compared when it resumes,
not by a report: a sweep's run and `smol-dsl run` of that seed are the same algorithm in
two programs, whose last bits differ; `render` rebuilds that program to replay an elite
bit for bit.
"""

from __future__ import annotations

import functools
import json
import platform
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

from smol_dsl.rundir.commit import BUILD_COMMIT, checkout_commit
from smol_dsl.rundir.files import read_text, write_text
from smol_dsl.rundir.layout import ENVIRONMENT_FILE, RunDirectoryError, leave_out
from smol_dsl.tasks.physics import DEFAULT_PHYSICS, physics_record

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
COMPARED = ("python", "smol_dsl", "commit", "packages", "physics", "devices", "processor")
"""The entries of a record that can change a run's numbers: the ones a report compares."""
LAYOUT = "layout"
RESUME_COMPARED = (*COMPARED, LAYOUT)
"""What a resume compares: the environment, and the run's place in its scoring program."""


def scoring_layout(runs: int, index: int, runs_per_step: int | None, channels: Sequence[str]) -> dict[str, Any]:
    """How a run was laid out in the program that scored it: the `runs` its process trained
    together (1 for `smol-dsl run`), its `index` among them, the runs a device advanced at
    once (`runs_per_step`; None: all) and the `channels` of the bodies the program took
    (the union of those runs' schedules'). With the record's device count, that program can
    be built again (`smol_dsl.rescoring.replay`)."""
    return {"runs": runs, "index": index, "runs_per_step": runs_per_step, "channels": list(channels)}


def describe_environment(
    devices: Sequence[Any], layout: dict[str, Any] | None = None, physics: str = DEFAULT_PHYSICS
) -> dict[str, Any]:
    """What a run on `devices` (objects with `platform` and `device_kind`, as JAX's devices)
    simulated by `physics` runs under, as environment.json records it, with its `layout`
    (`scoring_layout`) if given."""
    kinds = sorted({str(getattr(device, "device_kind", device.platform)) for device in devices})
    return {
        "python": platform.python_version(),
        "smol_dsl": _version("smol-dsl"),
        "commit": _commit(),
        "packages": {name: _version(name) for name in PACKAGES},
        "physics": physics_record(physics),
        "devices": {"platform": devices[0].platform if devices else None, "kinds": kinds, "count": len(devices)},
        "processor": _processor(),
        "system": platform.platform(),
        "host": platform.node(),
        **({LAYOUT: layout} if layout is not None else {}),
    }


def environment_differences(
    recorded: dict[str, Any], current: dict[str, Any], compared: Sequence[str] = COMPARED
) -> list[str]:
    """What differs between two records in `compared` (by default what can change the
    numbers), one phrase each ("jax 0.10.2 -> 0.12.0"), in that order. A layout is compared
    only where both records hold one (runs recorded before layouts were have none)."""
    return [
        f"{name} {_shown(before)} -> {_shown(after)}"
        for name, before, after in _compared(recorded, current, compared)
        if before != after
    ]


def _compared(recorded: dict[str, Any], current: dict[str, Any], compared: Sequence[str]) -> list[tuple[str, Any, Any]]:
    pairs = []
    for key in compared:
        if key == LAYOUT and (key not in recorded or key not in current):
            continue
        before, after = _entry(recorded, key), _entry(current, key)
        if isinstance(before, dict) and isinstance(after, dict):
            for inner in sorted(set(before) | set(after), key=lambda k: (k not in before, k != "name", k)):
                label = inner if key == "packages" else f"{key.replace('_', '-')} {inner}"
                pairs.append((label, before.get(inner), after.get(inner)))
        else:
            pairs.append((key.replace("_", "-"), before, after))
    return pairs


def _entry(record: dict[str, Any], key: str) -> Any:
    """A record's entry; a record made before runs recorded their physics was made by a
    spring run, with the brax it lists among its packages."""
    if key == "physics" and key not in record and record:
        brax = (record.get("packages") or {}).get("brax") if isinstance(record.get("packages"), dict) else None
        return {"name": "spring", "package": "brax", "version": brax}
    return record.get(key)


def _shown(value: Any) -> str:
    if value is None:
        return "(none)"
    if isinstance(value, list):
        return ",".join(str(item) for item in value) or "(none)"
    return str(value)


def environment_text(environment: dict[str, Any]) -> str:
    """A new run's environment.json: the record, and no change yet."""
    return json.dumps({"environment": environment, "changes": []}, indent=2)


MISSING_RECORD = "environment.json was missing: what the run was started under is unknown"
"""The difference recorded when a run without environment.json is resumed (allowed)."""


def record_environment_change(directory: Path, current: dict[str, Any], differences: list[str]) -> None:
    """Note in environment.json that the run went on under `current` (allowed by the user).
    A run without the file gets one whose start is unknown (an empty record) and this change."""
    if (directory / ENVIRONMENT_FILE).is_file():
        data = _environment_file(directory)
    else:
        data, differences = {"environment": {}, "changes": []}, [MISSING_RECORD]
    data["changes"].append({"environment": current, "differences": differences})
    write_text(directory / ENVIRONMENT_FILE, json.dumps(data, indent=2))


def read_environment(directory: Path) -> dict[str, Any] | None:
    """The environment a run was started under (None for a run directory without an
    environment.json; an empty record where the start is unknown)."""
    if not (directory / ENVIRONMENT_FILE).is_file():
        return None
    return _environment_file(directory)["environment"]


def latest_environment(directory: Path) -> dict[str, Any] | None:
    """The environment a run last went on under: its start's, or its last change's (None
    without an environment.json)."""
    changes = read_environment_changes(directory)
    return changes[-1]["environment"] if changes else read_environment(directory)


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
        or not all(
            isinstance(change, dict)
            and isinstance(change.get("environment"), dict)
            and isinstance(change.get("differences"), list)
            for change in data["changes"]
        )
    ):
        raise RunDirectoryError(
            f"{path}: expected an object with 'environment' and 'changes' (each an 'environment' and its "
            f"'differences'); {fix}"
        )
    return data


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


@functools.lru_cache(maxsize=1)
def _commit() -> str | None:
    """The git commit smol-dsl runs from (with "+changes" if its tracked files differ from
    it): the checkout's, for a checkout or an editable install; the one the package was built
    from (`BUILD_COMMIT`, written by setup.py), for an installed package; None where neither
    is known."""
    package = Path(__file__).resolve().parents[1]
    if (package.parent / ".git").exists():
        return checkout_commit(package.parent)
    try:
        return (package / BUILD_COMMIT).read_text().strip() or None
    except OSError:
        return None


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
